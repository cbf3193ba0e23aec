"""The default command on the five real files, on any device (issue 33's GPU numbers):
the scene `volrender render FILE --size WxH` loads, rendered with `estimator auto`
resolved for the device, timed as one process does it (brick cache load, plan and bake,
render, PNG write), its kernel and bake times, and its covered-pixel error against a
path-traced reference rendered in the same run (--ref-spp in 8 batches at --ref-size; the
default image box-filtered down to it; the reference's noise removed).

    python bench/volume_default.py prepare DIR [--size 1920x1080]   # where OpenVDB is
    python bench/volume_default.py run DIR [--device nvidia] [--ref-size 960x540]
        [--ref-spp 128] [--out FOLDER] [--tag TAG] [--variant NAME:KEY=VALUE,...]

`prepare` writes DIR/<stem>.npz (the bricks) and DIR/<stem>.pkl (camera, lights,
environment, settings with estimator auto unresolved: the fire's grids, exposure and sky
come from the .vdb's metadata, which an .npz alone does not carry). `run` writes
volume_default_<device>[-TAG].json (bench/results, or --out); with --images the PNGs
and the references (float16 .npy) beside it. --variant (repeatable) adds a variant of
settings to every file, timed and compared like the default (e.g. the light cache's node
spacing and orders: `--variant c1:estimator=march,ms_octaves=4,light_cache=on,light_cache_cell=1`).
"""
from __future__ import annotations

import argparse
import dataclasses
import pickle
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import device_info, find_volume, result_path, write_json  # noqa: E402
from bench.ms_refs import FILES, compare  # noqa: E402

DEFAULTS = ("estimator", "ms_octaves", "spp")      # what auto resolves (volume.auto_estimator)


def size(text):
    w, h = (int(v) for v in text.lower().split("x"))
    return w, h


def prepare(spec: Path, wh, files):
    from volrender.scene import request
    from volrender.volume import VolumeSettings
    spec.mkdir(parents=True, exist_ok=True)
    plain = VolumeSettings()
    for stem in files:
        p = find_volume(stem)
        if p is None:
            print(f"{stem}: not found, skipped")
            continue
        sc = request(p, size=wh).load()
        st = dataclasses.replace(sc.settings, **{k: getattr(plain, k) for k in DEFAULTS})
        sc.content.bricks.save_npz(spec / f"{stem}.npz")
        with open(spec / f"{stem}.pkl", "wb") as f:
            pickle.dump({"camera": sc.camera, "lights": sc.lights, "settings": st,
                         "environment": sc.environment, "notes": sc.notes}, f)
        print(stem, sc.camera.width, sc.camera.height, [n[:60] for n in sc.notes])


def scene_of(spec: Path, stem: str, cam=None):
    """The prepared default scene (bricks read from the .npz, as a user's load)."""
    from volrender import vdb
    from volrender.scene import Scene, VolumeContent
    with open(spec / f"{stem}.pkl", "rb") as f:
        d = pickle.load(f)
    b = vdb.load_npz(spec / f"{stem}.npz")
    return Scene.of(cam or d["camera"], d["lights"], VolumeContent(b, d["settings"]),
                    d["environment"]), d


def box_down(img, shape):
    h, w = shape
    fy, fx = img.shape[0] // h, img.shape[1] // w
    return img[:h * fy, :w * fx].reshape(h, fy, w, fx, -1).mean(axis=(1, 3))


def reference(scene, wh, spp, batches, dev):
    from volrender.render import render
    st = scene.content.settings
    cam = dataclasses.replace(scene.camera, width=wh[0], height=wh[1])
    imgs, ms = [], 0.0
    for k in range(batches):
        sc = _with(scene, cam, dataclasses.replace(
            st, estimator="path", ms_octaves=None, spp=spp, seed=70_000 + k, denoise="off"))
        r = render(sc, dev)
        imgs.append(r.rgba.astype(np.float64))
        ms += r.kernel_ms
    imgs = np.stack(imgs)
    return imgs.mean(0), imgs.var(0, ddof=1) / batches, ms


def _with(scene, cam, settings):
    from volrender.scene import Scene, VolumeContent
    return Scene.of(cam, scene.lights, VolumeContent(scene.content.bricks, settings),
                    scene.environment)


def bake_passes(scene):
    for k, v in scene.content.store.items():
        if isinstance(k, tuple) and k[0] == "light_cache":
            return {"wall_ms": v[1].passes_ms, "cpu_ms": v[1].passes_cpu_ms}
    return None


VARIANTS = {"default": {},
            # the march with the light cache and its orders, where auto picks the path
            # estimator (GPUs): its time and error beside the default's
            "march": {"estimator": "march", "ms_octaves": 4, "light_cache": "on"}}


def variant(text):
    """NAME:KEY=VALUE,... -> (name, {key: value}), values as int, float or text."""
    name, _, rest = text.partition(":")
    over = {}
    for item in filter(None, rest.split(",")):
        key, _, val = item.partition("=")
        for cast in (int, float, str):
            try:
                over[key.strip()] = cast(val)
                break
            except ValueError:
                continue
    return name.strip(), over


def timed(spec, stem, dev, overrides, repeat, png):
    """The command's work in this process, `repeat` times (the fastest counts): load the
    bricks, plan (auto, the bake), render, write the PNG."""
    from volrender.render import render
    times, img, scene, d = [], None, None, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        scene, d = scene_of(spec, stem)
        if overrides:
            scene = _with(scene, scene.camera,
                          dataclasses.replace(scene.content.settings, **overrides))
        t1 = time.perf_counter()
        img = render(scene, dev)
        t2 = time.perf_counter()
        if png is not None:
            img.save(png)
        else:                                  # the PNG's encoding, without the file
            img.save(Path(tempfile.gettempdir()) / "volume_default.png")
        t3 = time.perf_counter()
        times.append({"whole_s": t3 - t0, "load_s": t1 - t0, "render_s": t2 - t1,
                      "write_s": t3 - t2, "kernel_ms": img.kernel_ms,
                      "setup_ms": img.info.setup_ms,
                      "bake_ms": getattr(img.info, "light_cache_bake_ms", None) or 0.0})
    info = img.info
    return img, {"runs": times, **min(times, key=lambda t: t["whole_s"]),
                 "size": [scene.camera.width, scene.camera.height],
                 "estimator": info.estimator, "spp": info.spp,
                 "note": getattr(info, "estimator_note", None),
                 "light_cache": getattr(info, "light_cache", None),
                 "light_cache_bytes": getattr(info, "light_cache_bytes", None),
                 "bake_passes": bake_passes(scene), "denoised": bool(info.denoised),
                 "notes": list(d["notes"])}


def run_one(spec, stem, dev, args, out_dir):
    from volrender.render import render
    row = {"file": stem, "variants": {}}
    tiny, _ = scene_of(spec, stem)
    cam = dataclasses.replace(tiny.camera, width=16, height=12)
    t0 = time.perf_counter()
    variants = {**VARIANTS, **dict(args.variant)}
    for over in variants.values():             # builds the programs (not the command's cost)
        render(_with(tiny, cam, dataclasses.replace(tiny.content.settings, **over)), dev)
    row["first_tiny_s"] = time.perf_counter() - t0
    imgs = {}
    for name, over in variants.items():
        if name == "march" and row["variants"]["default"]["estimator"] == "march":
            continue                           # the default is the march already
        img, row["variants"][name] = timed(spec, stem, dev, over, args.repeat,
                                           out_dir / f"{name}_{stem}.png" if args.images
                                           else None)
        imgs[name] = (img.noisy if img.noisy is not None else img.rgba).astype(np.float64)
    scene, _ = scene_of(spec, stem)
    t0 = time.perf_counter()
    ref, var, ms = reference(scene, args.ref_size, args.ref_spp, 8, dev)
    row["reference"] = {"estimator": "path", "spp": 8 * args.ref_spp,
                        "size": list(args.ref_size), "kernel_ms": ms,
                        "s": time.perf_counter() - t0}
    emits = scene.content.bricks.emission is not None
    if args.images:
        np.save(out_dir / f"ref_{stem}.npy", ref.astype(np.float16))
    for name, rgba in imgs.items():
        row["variants"][name]["error"] = compare(box_down(rgba, ref.shape[:2]), ref, var, emits)
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("mode", choices=["prepare", "run"])
    ap.add_argument("spec", help="folder of the prepared scenes")
    ap.add_argument("--size", type=size, default=(1920, 1080), help="prepare: image size")
    ap.add_argument("--files", default=",".join(FILES), help="comma-separated stems")
    ap.add_argument("--device", default=None, help="OpenCL device (default: PoCL)")
    ap.add_argument("--ref-size", type=size, default=(960, 540), help="reference size")
    ap.add_argument("--ref-spp", type=int, default=128, help="reference spp per batch (8)")
    ap.add_argument("--repeat", type=int, default=2, help="whole-command runs (the fastest)")
    ap.add_argument("--out", default=None, help="result folder (default: bench/results)")
    ap.add_argument("--tag", default=None, help="added to the result's name")
    ap.add_argument("--variant", type=variant, action="append", default=[],
                    help="NAME:KEY=VALUE,... settings of an extra variant (repeatable)")
    ap.add_argument("--images", action="store_true",
                    help="also write the PNGs and the references (.npy) beside the JSON (the "
                         "device tool brings back 8 files: the JSON alone by default)")
    args = ap.parse_args(argv)
    spec = Path(args.spec)
    if args.mode == "prepare":
        prepare(spec, args.size, args.files.split(","))
        return 0
    from volrender import device
    dev = device.get(args.device)
    out_dir = Path(args.out) if args.out else None
    path = result_path("volume_default", dev, args.tag)
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        path = out_dir / path.name
    img_dir = out_dir or Path("/tmp")
    res = {"benchmark": "volume_default", **device_info(dev), "rows": []}
    for stem in args.files.split(","):
        if not (spec / f"{stem}.pkl").is_file():
            print(f"{stem}: not prepared, skipped")
            continue
        row = run_one(spec, stem, dev, args, img_dir)
        res["rows"].append(row)
        for name, v in row["variants"].items():
            e = v["error"].get("covered", {})
            print(f"{stem} {name}: {v['estimator']} {v['spp']} spp, whole {v['whole_s']:.3f} s, "
                  f"kernel {v['kernel_ms']:.1f} ms, bake {v['bake_ms']:.1f} ms, covered "
                  f"{e.get('rel_rmse', float('nan')):.1%} x{e.get('mean_ratio', float('nan')):.3f}",
                  flush=True)
        write_json(path, res)                  # after every file: a cut-off run keeps them
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
