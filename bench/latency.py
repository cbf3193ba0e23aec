"""Latency of a single command: where the wall time of `volrender render` goes outside
the kernel, and what PNG encoding costs at 1080p.

    .venv/bin/python bench/latency.py [--repeat 5] [--baseline DIR] [--tag TAG]

1. Start: the bare interpreter (`python -c pass`), `import volrender.cli`, and
   `python -X importtime` of a render command: each top-level package's cumulative import
   time (numpy, pyopencl, OpenEXR, PIL, OpenVDB, volrender, and whether dask, scipy or
   matplotlib were imported at all); the OpenCL device's choice and context; and
   volrender.load_scene of the input (--scene; the demo cloud): its wall time and the CPU
   time of the renderer's own process (OpenVDB reads in a reader process).
2. Command: `volrender render scenes/demo_cloud.vdb --size 192x108 --spp 1 -o x.png -v`
   as a process, wall time split by its `-v` time line (load, setup, kernel, launch
   overhead, write), its CPU time (user + system, the OpenVDB reader process's included)
   and the program build it logs; "outside" is the rest (interpreter,
   imports, OpenCL context, option checks, exit). With --baseline DIR (another checkout,
   e.g. `git worktree add DIR COMMIT`) the same command runs from there too, interleaved,
   so before and after come from one run on one (noisy) machine.
3. PNG at 1080p: a 1920x1080 render of the demo cloud (bench/data/latency_frame_1080p.npy,
   rendered once when absent): tone mapping (image.png_pixels), then Pillow's encoding
   at every zlib level (time, size, and whether it decodes to the same pixels), and the
   whole write_image at volrender's level (1, volrender/image.py).

Medians of --repeat runs. Writes bench/results/latency_<device>[-TAG].json and .png.
"""
from __future__ import annotations

import argparse
import io
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench.common import device_info, result_path, write_json  # noqa: E402

SCENE = ROOT / "scenes" / "demo_cloud.vdb"
COMMAND = ["--size", "192x108", "--spp", "1", "-v", "--no-progress"]
FRAME = ROOT / "bench" / "data" / "latency_frame_1080p.npy"
PACKAGES = ("numpy", "pyopencl", "OpenEXR", "PIL", "pyopenvdb", "openvdb", "volrender",
            "dask", "scipy", "matplotlib", "PyOpenColorIO", "png")
STAGES = ("load", "radii", "tree", "cells", "setup", "kernel", "launch overhead", "guides",
          "denoise", "write")


def env_for(root: Path) -> dict:
    return {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(root), *filter(None, [os.environ.get("PYTHONPATH")])])}


def wall(argv, root: Path, cpu=None, out=False) -> tuple[float, str]:
    """(wall seconds, stderr) of a process run from checkout `root` (its folder is the
    working directory: `python -c` and `-m` put that first on the path); `cpu` (a list) gets its CPU seconds, user +
    system, its own children's (the OpenVDB reader) included; out: stdout instead: on a shared machine it
    moves far less with the load than wall time."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    p = subprocess.run(argv, capture_output=True, text=True, env=env_for(root), cwd=root)
    took = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if cpu is not None:
        cpu.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    if p.returncode:
        raise SystemExit(f"{' '.join(map(str, argv))}: {p.stderr.strip()[-500:]}")
    return took, p.stdout if out else p.stderr


def import_times(root: Path, out: Path, scene: Path = SCENE, command=None) -> dict:
    """{top-level package: cumulative import ms} of one render command (-X importtime),
    and under "volrender_self" each of volrender's modules' own import ms (what a lazy
    import of a module the command does not use would save)."""
    _, err = wall([sys.executable, "-X", "importtime", "-m", "volrender", "render", str(scene),
                   *(command or COMMAND), "-o", str(out)], root)
    found, own = {}, {}
    for line in err.splitlines():
        m = re.match(r"import time:\s+(\d+) \|\s+(\d+) \| \s*(\S+)$", line)
        if m and "." not in m.group(3):             # a package's own line: imported once
            found.setdefault(m.group(3), int(m.group(2)) / 1e3)
        if m and m.group(3).startswith("volrender."):
            own[m.group(3)[10:]] = int(m.group(1)) / 1e3
    return {**{p: found.get(p) for p in PACKAGES},
            "volrender_self": dict(sorted(own.items(), key=lambda kv: -kv[1]))}


def command_run(root: Path, out: Path, scene=None, command=None) -> dict:
    cpu = []
    took, err = wall([sys.executable, "-m", "volrender", "render", str(scene or SCENE),
                      *(command or COMMAND), "-o", str(out)], root, cpu)
    line = next(ln for ln in err.splitlines() if ln.startswith("volrender: time: "))
    parts = {k: float(v) for k, v in re.findall(r"([a-z ]+?) ([0-9.]+) s", line[17:])}
    parts = {k.strip(" ,"): v for k, v in parts.items()}
    build = [float(v) / 1e3 for v in re.findall(r"built cl/\S+ .* in (\d+) ms", err)]
    row = {"wall_s": took, "cpu_s": cpu[0], **{k: parts.get(k, 0.0) for k in STAGES}, "build_s": sum(build)}
    row["outside_s"] = took - sum(parts.values())
    row["other_stages"] = sorted(set(parts) - set(STAGES))
    return row


def startup(root: Path, repeat: int, scene: Path = SCENE) -> dict:
    bare = [wall([sys.executable, "-c", "pass"], root)[0] for _ in range(repeat)]
    cli = [wall([sys.executable, "-c", "import volrender.cli"], root)[0] for _ in range(repeat)]
    probe = ("import time; t = time.perf_counter(); from volrender import device; "
             "t1 = time.perf_counter(); p, d = device.choose(None); t2 = time.perf_counter(); "
             "device.Device(p, d); t3 = time.perf_counter(); print(t1 - t, t2 - t1, t3 - t2)")
    cl = [wall([sys.executable, "-c", probe], root, out=True)[1].split() for _ in range(repeat)]
    load = ("import time; import volrender; c, t = time.process_time(), "         # OpenVDB's
            f"time.perf_counter(); volrender.load_scene({str(scene)!r}); "     # in a reader
            "print(time.process_time() - c, time.perf_counter() - t)")
    ld = [wall([sys.executable, "-c", load], root, out=True)[1].split() for _ in range(repeat)]
    med = lambda xs: statistics.median(float(x) for x in xs)  # noqa: E731
    return {"interpreter_s": med(bare), "import_cli_s": med(cli),
            "import_device_s": med(c[0] for c in cl), "choose_device_s": med(c[1] for c in cl),
            "context_s": med(c[2] for c in cl),
            "load_own_cpu_s": med(x[0] for x in ld), "load_wall_s": med(x[1] for x in ld)}


def frame(path: Path, scene: Path = SCENE) -> np.ndarray:
    if not path.is_file():
        print(f"rendering {path} (1920x1080, 1 spp, once)", flush=True)
        path.parent.mkdir(parents=True, exist_ok=True)
        wall([sys.executable, "-m", "volrender", "render", str(scene), "--size", "1920x1080",
              "--spp", "1", "--no-progress", "-o", str(path)], ROOT)
    return np.load(path)


def png_levels(rgba: np.ndarray, repeat: int) -> dict:
    from PIL import Image as PILImage
    from volrender import image
    tone = []
    for _ in range(repeat):
        t = time.perf_counter()
        px = image.png_pixels(rgba, alpha="opaque")
        tone.append(time.perf_counter() - t)
    rows = []
    for level in range(10):
        ts = []
        for _ in range(repeat):
            buf = io.BytesIO()
            t = time.perf_counter()
            PILImage.fromarray(px, "RGBA").save(buf, format="PNG", compress_level=level)
            ts.append(time.perf_counter() - t)
        with PILImage.open(io.BytesIO(buf.getvalue())) as im:
            same = bool(np.array_equal(np.asarray(im.convert("RGBA")), px))
        rows.append({"level": level, "encode_s": statistics.median(ts), "runs_s": ts,
                     "bytes": len(buf.getvalue()), "identical_pixels": same})
        print(f"PNG level {level}: {rows[-1]['encode_s']:.3f} s, {rows[-1]['bytes'] / 1e6:.2f} MB, "
              f"identical {same}", flush=True)
    variants = []                   # level 1 as RGB (an opaque image's alpha dropped) and
    rgb = np.ascontiguousarray(px[..., :3])         # with zlib's strategies (compress_type)
    for mode, ctype in (("RGB", -1), ("RGBA", 1), ("RGBA", 2), ("RGBA", 3), ("RGB", 3)):
        ts = []
        for _ in range(repeat):
            buf = io.BytesIO()
            t = time.perf_counter()
            PILImage.fromarray(rgb if mode == "RGB" else px, mode).save(
                buf, format="PNG", compress_level=1, compress_type=ctype)
            ts.append(time.perf_counter() - t)
        variants.append({"level": 1, "mode": mode, "compress_type": ctype,
                         "encode_s": statistics.median(ts), "runs_s": ts,
                         "bytes": len(buf.getvalue())})
        print(f"PNG level 1 {mode} compress_type {ctype}: {variants[-1]['encode_s']:.3f} s, "
              f"{variants[-1]['bytes'] / 1e6:.2f} MB", flush=True)
    whole = []
    with tempfile.TemporaryDirectory() as d:
        for _ in range(repeat):
            t = time.perf_counter()
            image.write_image(Path(d) / "f.png", rgba)
            whole.append(time.perf_counter() - t)
        parts = write_parts(rgba, Path(d), repeat)
    return {"size": list(rgba.shape[1::-1]), "tone_map_s": statistics.median(tone),
            "tone_runs_s": tone, "levels": rows, "variants": variants, "volrender_level": 1,
            "write_image_s": statistics.median(whole), "write_runs_s": whole,
            "write_parts_s": parts}


def write_parts(rgba: np.ndarray, folder: Path, repeat: int) -> dict:
    """write_image's PNG at volrender's level in its steps (medians): tone mapping,
    Pillow's encoding (with the sRGB chunk) into memory, the bytes written plainly, and
    atomically (volrender/atomic.py: a temporary file, fsync, rename, the folder's
    fsync); and, in a fresh interpreter, the first import of Pillow's PNG writer (a
    command pays it at its write)."""
    from PIL import Image as PILImage, PngImagePlugin
    from volrender import atomic, image
    steps = {"tone": [], "encode": [], "plain_write": [], "atomic_write": []}
    for i in range(repeat):
        t0 = time.perf_counter()
        px = image.png_pixels(rgba, alpha="opaque")
        t1 = time.perf_counter()
        info = PngImagePlugin.PngInfo()
        info.add(b"sRGB", b"\x00")
        buf = io.BytesIO()
        PILImage.fromarray(px, "RGBA").save(buf, format="PNG", pnginfo=info, compress_level=1)
        t2 = time.perf_counter()
        (folder / f"plain{i}.png").write_bytes(buf.getvalue())
        t3 = time.perf_counter()
        atomic.write_bytes(folder / f"atomic{i}.png", buf.getvalue())
        t4 = time.perf_counter()
        for k, a, b in (("tone", t0, t1), ("encode", t1, t2), ("plain_write", t2, t3),
                        ("atomic_write", t3, t4)):
            steps[k].append(b - a)
    out = {k: statistics.median(v) for k, v in steps.items()}
    probe = ("import time; t = time.perf_counter(); from PIL import Image, PngImagePlugin; "
             "print(time.perf_counter() - t)")
    try:
        out["pil_import_first"] = float(subprocess.run([sys.executable, "-c", probe],
                                                       capture_output=True, text=True,
                                                       timeout=60).stdout)
    except (ValueError, subprocess.SubprocessError, OSError):
        out["pil_import_first"] = None
    print("PNG write parts: " + ", ".join(f"{k} {v:.3f} s" for k, v in out.items()
                                          if v is not None), flush=True)
    return out


TONE_VIEWS = ("filmic", "clamp", "standard", "aces")
TONE_PROBE = """
import json, sys, time, warnings
import numpy as np
from volrender import image
rgba = np.load(sys.argv[1])
out, codes = {}, {}
for view in VIEWS:
    try:
        image.check_view(view)
    except Exception:                   # OpenColorIO missing here
        continue
    for alpha in ("opaque", "straight"):
        ts = []
        for _ in range(REPEAT):
            t = time.perf_counter()
            px = image.png_pixels(rgba, 0.0, view, alpha=alpha)
            ts.append(time.perf_counter() - t)
        out[f"{view}/{alpha}"] = sorted(ts)[len(ts) // 2]
        out[f"{view}/{alpha} first"] = ts[0]      # a command's one call: tables made
        codes[f"{view}/{alpha}"] = px
np.savez(sys.argv[2], **{k.replace("/", "__"): v for k, v in codes.items()})
print(json.dumps(out))
"""


def tone_times(roots: dict, frame_path: Path, repeat: int, tmp: Path) -> dict:
    """{checkout: {"view/alpha": median s}} of image.png_pixels on the 1080p frame, each
    checkout in its own process, and the codes that differ from this checkout's."""
    import json
    code = TONE_PROBE.replace("VIEWS", repr(TONE_VIEWS)).replace("REPEAT", str(repeat))
    res, px = {}, {}
    for k, r in roots.items():
        _, out = wall([sys.executable, "-c", code, str(frame_path), str(tmp / f"{k}.npz")], r,
                      out=True)
        res[k] = json.loads(out.strip().splitlines()[-1])
        px[k] = np.load(tmp / f"{k}.npz")
        print("tone map", k, {n: round(v, 3) for n, v in res[k].items()}, flush=True)
    if "baseline" in px:
        res["codes_differing_from_baseline"] = {
            n.replace("__", "/"): {"count": int(np.count_nonzero(px["this"][n] != px["baseline"][n])),
                                   "max": int(np.abs(px["this"][n].astype(int) - px["baseline"][n]).max())}
            for n in px["this"].files}
        print("codes differing", res["codes_differing_from_baseline"], flush=True)
    return res


SHARED = Path(os.environ.get("VOLRENDER_SHARED_DATA", ROOT.parent / "shared" / "data"))
FRAMED = ("blob:100000", "blob:1000000", "scenes/demo_cloud.vdb", SHARED / "vdb" / "smoke.vdb",
          SHARED / "points" / "bun_zipper.ply")
FRAMING_PROBE = """
import json, sys, time
import numpy as np
import volrender
out = {}
for src in SOURCES:
    sc = volrender.load_scene(src, size=(1920, 1080))
    c, req = sc.content, sc.request
    lo, hi = c.bounds()
    ext, cam, fit = [], [], []
    for _ in range(REPEAT):
        t = time.perf_counter()
        e = c.extent()
        t1 = time.perf_counter()
        camera = req.view.camera(lo, hi, None, extent=e)
        t2 = time.perf_counter()
        ext.append(t1 - t)
        fit.append(t2 - t1)
    out[src] = {"extent_s": sorted(ext)[len(ext) // 2], "fit_s": sorted(fit)[len(fit) // 2],
                "points": int(np.asarray(e[0]).size // 3), "origin": list(camera.origin),
                "target": list(camera.target)}
print(json.dumps(out))
"""


def framing_times(roots: dict, repeat: int) -> dict:
    """{checkout: {source: extent and fit medians, camera}} and the cameras' distance
    apart (relative to this checkout's camera distance)."""
    import json
    sources = [s if ":" in str(s) else str((ROOT / s).resolve()) for s in FRAMED]
    sources = [s for s in sources if ":" in s or Path(s).is_file()]
    code = FRAMING_PROBE.replace("SOURCES", repr(sources)).replace("REPEAT", str(repeat))
    res = {}
    for k, r in roots.items():
        _, out = wall([sys.executable, "-c", code], r, out=True)
        res[k] = json.loads(out.strip().splitlines()[-1])
        print("framing", k, {Path(n).name: (round(v["extent_s"], 3), round(v["fit_s"], 3))
                             for n, v in res[k].items()}, flush=True)
    if "baseline" in res:
        apart = {}
        for n, v in res["this"].items():
            b = res["baseline"][n]
            d = np.linalg.norm(np.subtract(v["origin"], v["target"]))
            apart[n] = max(np.abs(np.subtract(v[f], b[f])).max() for f in ("origin", "target")) / d
        res["camera_apart_relative"] = apart
        print("cameras apart (relative)", apart, flush=True)
    return res


def plot(payload, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    labels = list(payload["command"])
    keys = ["outside_s", *STAGES]
    bottom = np.zeros(len(labels))
    for k in keys:
        v = np.array([payload["command"][c]["median"][k] for c in labels])
        a.bar(labels, v, bottom=bottom, label=k.replace("_s", ""))
        bottom += v
    a.set_ylabel("s (median)")
    a.set_title("volrender render demo_cloud 192x108 1 spp")
    a.legend(fontsize=7)
    lv = payload["png"]["levels"]
    b.plot([r["bytes"] / 1e6 for r in lv], [r["encode_s"] for r in lv], "o-")
    for r in lv:
        b.annotate(str(r["level"]), (r["bytes"] / 1e6, r["encode_s"]))
    b.axhline(0.1, ls=":", c="k")
    b.set_xscale("log")
    b.set_xlabel("PNG size, MB (log)")
    b.set_ylabel("encode s (median)")
    b.set_title(f"Pillow PNG 1920x1080 by zlib level; tone map {payload['png']['tone_map_s']:.2f} s")
    fig.suptitle(f"{payload['device']['device']} @ {payload['device']['commit']}", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


PARTS = ("start", "command", "png", "tone", "framing")


def bytecode(root: Path) -> dict:
    """Whether the checkout's modules have compiled bytecode beside them (a pip install
    compiles it; with PYTHONDONTWRITEBYTECODE set and none there, every command compiles
    volrender's sources again) and whether pyopencl's has."""
    import importlib.util
    mods = sorted((root / "volrender").glob("*.py"))
    have = sum(Path(importlib.util.cache_from_source(str(m))).is_file() for m in mods)
    spec = importlib.util.find_spec("pyopencl")
    cl = None
    if spec is not None and spec.origin:
        cl = Path(importlib.util.cache_from_source(spec.origin)).is_file()
    return {"volrender_modules": len(mods), "with_bytecode": have, "pyopencl_bytecode": cl,
            "PYTHONDONTWRITEBYTECODE": os.environ.get("PYTHONDONTWRITEBYTECODE")}


def main(argv=None):
    ap = argparse.ArgumentParser(prog="volrender bench latency", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=5, help="runs of each measurement (default: 5)")
    ap.add_argument("--baseline", type=Path, default=None,
                    help="another checkout whose command runs interleaved with this one's")
    ap.add_argument("--frame", type=Path, default=FRAME, help=f"1080p linear frame (.npy; default {FRAME})")
    ap.add_argument("--tag", default=None, help="added to the results' name: latency_<device>-<tag>.json")
    ap.add_argument("--scene", type=Path, default=None,
                    help=f"the command part's input (default: {SCENE.relative_to(ROOT)})")
    ap.add_argument("--args", default=None,
                    help=f"the command part's render options (default: {' '.join(COMMAND)}); "
                         "-v and --no-progress are added")
    ap.add_argument("--only", default=",".join(PARTS),
                    help=f"comma-separated parts to run (default: all of {','.join(PARTS)})")
    args = ap.parse_args(argv)
    parts = set(args.only.split(","))
    scene = args.scene.resolve() if args.scene else SCENE
    command = COMMAND if args.args is None else [*args.args.split(), "-v", "--no-progress"]
    if parts - set(PARTS):
        ap.error(f"--only: unknown part(s) {', '.join(sorted(parts - set(PARTS)))}")
    from volrender import device
    dev = device.get(None)
    roots = {"this": ROOT, **({"baseline": args.baseline.resolve()} if args.baseline else {})}
    tmp = Path(tempfile.mkdtemp())
    payload = {"benchmark": "latency", "device": device_info(dev), "load_start": os.getloadavg(),
               "command_argv": [str(scene), *command], "parts": sorted(parts),
               "bytecode": {k: bytecode(r) for k, r in roots.items()}}
    print("bytecode", payload["bytecode"], flush=True)
    if "start" in parts:
        payload["start"] = {k: startup(r, args.repeat, scene) for k, r in roots.items()}
        payload["imports_ms"] = {k: import_times(r, tmp / "i.png", scene, command)
                                 for k, r in roots.items()}
        for k in roots:
            print(k, {n: round(v, 3) for n, v in payload["start"][k].items()},
                  {n: v and round(v) for n, v in payload["imports_ms"][k].items()
                   if not isinstance(v, dict)}, flush=True)
    if "command" in parts:
        runs = {k: [] for k in roots}
        # warm: programs built, files cached (its row: a first launch, on a fresh machine
        # with cold program caches)
        payload["command_first"] = {k: command_run(r, tmp / "w.png", scene, command)
                                    for k, r in roots.items()}
        for k, v in payload["command_first"].items():
            print(k, "first", {f: round(x, 3) for f, x in v.items() if f != "other_stages"},
                  flush=True)
        for _ in range(args.repeat):
            for k, r in roots.items():
                runs[k].append(command_run(r, tmp / f"{k}.png", scene, command))
        payload["command"] = {k: {"median": {f: statistics.median(x[f] for x in rs) for f in rs[0]
                                             if f != "other_stages"},
                                  "runs": rs} for k, rs in runs.items()}
        for k, v in payload["command"].items():
            print(k, {f: round(x, 3) for f, x in v["median"].items()}, flush=True)
        if args.baseline:
            m = {k: v["median"] for k, v in payload["command"].items()}
            payload["ratio_wall_this_to_baseline"] = m["this"]["wall_s"] / m["baseline"]["wall_s"]
            payload["ratio_cpu_this_to_baseline"] = m["this"]["cpu_s"] / m["baseline"]["cpu_s"]
            print(f"this/baseline: wall {payload['ratio_wall_this_to_baseline']:.3f}, "
                  f"cpu {payload['ratio_cpu_this_to_baseline']:.3f}")
    if "png" in parts:
        payload["png"] = png_levels(frame(args.frame, scene), args.repeat)
        print(f"tone map {payload['png']['tone_map_s']:.3f} s, write_image at level "
              f"{payload['png']['volrender_level']} {payload['png']['write_image_s']:.3f} s")
    if "tone" in parts:
        frame(args.frame, scene)
        payload["tone"] = tone_times(roots, args.frame, args.repeat, tmp)
    if "framing" in parts:
        payload["framing"] = framing_times(roots, args.repeat)
    payload["load_end"] = os.getloadavg()
    path = write_json(result_path("latency", dev, args.tag), payload)
    if {"command", "png"} <= parts:
        plot(payload, path.with_suffix(".png"))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
