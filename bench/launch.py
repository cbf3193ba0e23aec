"""Launch granularity: what the adaptive launches (volrender/dispatch.py) cost, and how
fast a render stops on SIGINT, SIGTERM and SIGHUP.

    .venv/bin/python bench/launch.py [--device SPEC] [--size 320x240] [--spp 4] [--repeat 3]
        [--after 3] [--signal-render "blob:3000 --size 320x240 --spp 256"] [--no-signals]

1. Overhead. Each scene (scenes/demo_cloud.vdb, or its conversion
   bench/data/demo_cloud.npz where present, and blob:2000) renders, interleaved, one
   round per repeat: "adaptive" (the default: launches sized to take about
   dispatch.TARGET_S), "bands" (what volrender did before: one launch per band of the
   plan's pixels with all samples) and "minimal" (one tile row, one sample per launch:
   the worst case). On a GPU "bands" are whole frames (dispatch.GPU_BAND_PIXELS) with
   all samples, as before. Wall-time and process-CPU-time medians (PoCL's threads count in the
   latter, which a loaded machine disturbs less) and their ratios to "bands", the number
   of launches, and whether every image is bit-identical to it.
2. Interrupts. A real `volrender render` subprocess (a render that takes far longer than
   the wait) gets the signal after --after seconds; records the exit status, the time
   from the signal to the exit, the stderr line, whether a temporary file was left and
   whether the existing output is byte-identical.

Writes bench/results/launch_<device>[-<tag>].json.
"""
from __future__ import annotations

import argparse
import os
import signal
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
from volrender import device, dispatch, glass, volume  # noqa: E402
from volrender.render import render  # noqa: E402
from volrender.scene import load_scene  # noqa: E402


def overhead(dev, size, spp, repeat):
    out = []
    npz = ROOT / "bench" / "data" / "demo_cloud.npz"        # where OpenVDB is missing (GPU)
    for source in (npz if npz.is_file() else ROOT / "scenes" / "demo_cloud.vdb", "blob:2000"):
        scene = load_scene(str(source), size=size, spp=spp)
        band = dispatch.GPU_BAND_PIXELS if dispatch.is_gpu(dev) else \
            (volume if scene.kind == "volume" else glass).PIXELS_PER_LAUNCH
        modes = {"adaptive": None, "bands": (max(1, band // size[0]), 1 << 30), "minimal": (1, 1)}
        render(scene, dev)                                    # build the program
        times = {k: [] for k in modes}
        cpu = {k: [] for k in modes}
        images, launches = {}, {}
        for _ in range(repeat):
            for name, fixed in modes.items():
                t, c = time.perf_counter(), time.process_time()
                img = render(scene, dev, launch=dispatch.Launch(fixed=fixed))
                times[name].append(time.perf_counter() - t)
                cpu[name].append(time.process_time() - c)
                images[name] = img.rgba
                launches[name] = img.info.launches
        base = statistics.median(times["bands"])
        base_cpu = statistics.median(cpu["bands"])
        row = {"scene": str(source.name if isinstance(source, Path) else source),
               "size": list(size), "spp": spp}
        for name in modes:
            med = statistics.median(times[name])
            mc = statistics.median(cpu[name])
            row[name] = {"median_s": med, "runs_s": times[name], "ratio_to_bands": med / base,
                         "cpu_median_s": mc, "cpu_runs_s": cpu[name],
                         "cpu_ratio_to_bands": mc / base_cpu,
                         "launches": launches[name],
                         "identical": bool(np.array_equal(images[name], images["bands"]))}
        out.append(row)
        print(row["scene"], {k: (round(row[k]["ratio_to_bands"], 3),
                                 round(row[k]["cpu_ratio_to_bands"], 3), row[k]["launches"],
                                 row[k]["identical"]) for k in modes})
    return out


def interrupts(after, device_spec, render_args):
    out = []
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]))
    for name in ("SIGINT", "SIGTERM", "SIGHUP"):
        with tempfile.TemporaryDirectory() as d:
            old = Path(d) / "o.npy"
            old.write_bytes(b"an earlier render\n")
            argv = [sys.executable, "-m", "volrender", "render", *render_args.split(),
                    "-o", str(old), "--no-progress"]
            if device_spec:
                argv += ["--device", device_spec]
            p = subprocess.Popen(argv, env=env, stderr=subprocess.PIPE, text=True,
                                 preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
            time.sleep(after)
            t = time.perf_counter()
            p.send_signal(getattr(signal, name))
            try:
                err = p.communicate(timeout=120)[1]
            except subprocess.TimeoutExpired:
                p.kill()
                err = p.communicate()[1]
            took = time.perf_counter() - t
            row = {"signal": name, "exit_status": p.returncode, "seconds_to_exit": took,
                   "stderr": err.strip(), "temp_left": sorted(n for n in os.listdir(d) if n != "o.npy"),
                   "old_output_intact": old.read_bytes() == b"an earlier render\n"}
            out.append(row)
            print(name, p.returncode, f"{took:.2f} s", row["temp_left"], row["old_output_intact"])
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default=None, help="OpenCL device (default: PoCL)")
    ap.add_argument("--size", default="320x240", help="image size WxH (default: 320x240)")
    ap.add_argument("--spp", type=int, default=4, help="samples per pixel (default: 4)")
    ap.add_argument("--repeat", type=int, default=3, help="timed renders per variant (default: 3)")
    ap.add_argument("--after", type=float, default=3.0, help="seconds before the signal")
    ap.add_argument("--no-signals", action="store_true", help="skip the interrupt part")
    ap.add_argument("--tag", default=None, help="added to the results' name: launch_<device>-<tag>.json")
    ap.add_argument("--signal-render", default="blob:3000 --size 320x240 --spp 256",
                    help="the render that gets the signals (it must outlast --after)")
    args = ap.parse_args(argv)
    size = tuple(int(v) for v in args.size.split("x"))
    dev = device.get(args.device)
    payload = {"device": device_info(dev), "load_start": os.getloadavg(),
               "target_s": dispatch.TARGET_S, "gpu_target_s": dispatch.GPU_TARGET_S,
               "overhead": overhead(dev, size, args.spp, args.repeat)}
    if not args.no_signals:
        payload["interrupts"] = interrupts(args.after, args.device, args.signal_render)
    payload["load_end"] = os.getloadavg()
    path = write_json(result_path("launch", dev, args.tag), payload)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
