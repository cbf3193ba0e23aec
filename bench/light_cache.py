"""The light cache (issue 33) on the default command: `volrender render FILE` at 640x480,
cache off (the exact shadow march) against on (the cost model's choice), per file:
wall time as the CLI reports it (set-up, bake included, + launches), kernel time, bake
time and memory, a second render after a camera-only change (the cache reused), and the
error on covered pixels (reference alpha > 0.05) and on the whole image against a
path-traced reference at the reference size (the 640x480 images box-filtered down to it:
a box-filtered pixel is what many samples per pixel converge to), and of the cached
image against the exact one.

    python bench/light_cache.py                          # PoCL, smoke and WDAS
    python bench/light_cache.py --device nvidia --size 1920x1080 --no-reference
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import device_info, find_volume, missing_data, result_path, write_json  # noqa: E402
from volrender.render_info import FIELDS  # noqa: E402

FILES = ("smoke", "wdas_cloud_sixteenth")


def size(text):
    w, h = (int(v) for v in text.lower().split("x"))
    return w, h


def errors(img, ref):
    """Mean ratio and relative RMSE of img against ref (H, W, 4), on covered pixels and on
    the whole image."""
    out = {}
    for where, mask in (("covered", ref[..., 3] > 0.05), ("image", np.ones(ref.shape[:2], bool))):
        a, b = ref[..., :3][mask].astype(np.float64), img[..., :3][mask].astype(np.float64)
        out[where] = {"mean_ratio": float(b.mean() / a.mean()),
                      "rel_rmse": float(np.sqrt(((b - a) ** 2).mean() / (a ** 2).mean())),
                      "pixels": float(mask.mean())}
    return out


def box_down(img, shape):
    h, w = shape
    fy, fx = img.shape[0] // h, img.shape[1] // w
    return img[:h * fy, :w * fx].reshape(h, fy, w, fx, -1).mean(axis=(1, 3))


def timed(scene, dev):
    from volrender.render import render
    t0 = time.perf_counter()
    img = render(scene, dev)
    return img, {"wall_s": img.info.setup_ms / 1e3 + img.wall_ms / 1e3,
                 "host_s": time.perf_counter() - t0, "kernel_ms": img.kernel_ms,
                 **{k: getattr(img.info, k) for k in sorted(FIELDS) if k.startswith("light_cache")}}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("--size", type=size, default=(640, 480))
    ap.add_argument("--files", default=",".join(FILES))
    ap.add_argument("--ref-size", type=size, default=(160, 120))
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--no-reference", action="store_true")
    ap.add_argument("--march", type=int, default=None, metavar="N",
                    help="render with the march and N octave bands whatever auto picks "
                         "(auto may pick the path estimator, which has no cache)")
    ap.add_argument("--out", default=None, help="tag in the result file name")
    args = ap.parse_args(argv)
    import volrender
    from volrender import device
    dev = device.resolve(args.device)
    rows = []
    for name in args.files.split(","):
        path = find_volume(name)
        if path is None:
            sys.exit(missing_data(name))
        extra = {"estimator": "march", "ms_octaves": args.march} if args.march else {}
        from volrender.scene import request
        scene = request(path, size=args.size, **extra).load(device=dev)   # as the CLI
        row = {"file": name, "size": list(args.size), "notes": list(scene.notes), **extra}
        # build the programs first (a tiny render of each variant: PoCL compiles are
        # cached, but their first build is not the renderer's cost)
        from volrender.volume import light_cache_choice, resolved
        choice = light_cache_choice(resolved(scene)[0])
        row["choice"] = choice.note()
        tiny = scene.replace(size=(16, 12))
        volrender.render(tiny.replace(light_cache="off"), dev)
        if choice.cell:
            volrender.render(tiny.replace(light_cache="on", light_cache_cell=choice.cell), dev)
        for key in [k for k in scene.content.store if isinstance(k, tuple)
                    and k[0] == "light_cache"]:
            del scene.content.store[key]                 # the timed render bakes it again
        imgs = {}
        for mode in ("off", "auto"):
            img, t = timed(scene.replace(light_cache=mode), dev)
            imgs[mode] = img.rgba
            row[mode] = t
            print(name, mode, {k: v for k, v in t.items() if k != "light_cache"}, flush=True)
        # the cache baked by the "auto" render above serves a camera-only change
        _, row["auto_camera_moved"] = timed(scene.replace(light_cache="auto", azimuth=30.0), dev)
        row["cached_vs_exact"] = errors(imgs["auto"], imgs["off"])
        if not args.no_reference:
            t0 = time.perf_counter()
            ref = volrender.render(scene.replace(size=args.ref_size, estimator="path",
                                                 spp=args.ref_spp), dev).rgba
            row["reference"] = {"estimator": "path", "spp": args.ref_spp,
                                "size": list(args.ref_size),
                                "seconds": time.perf_counter() - t0}
            for mode in ("off", "auto"):
                row[mode]["error"] = errors(box_down(imgs[mode], ref.shape[:2]), ref)
            print(name, "errors", {m: row[m]["error"]["covered"] for m in ("off", "auto")},
                  flush=True)
        rows.append(row)
    out = write_json(result_path("light_cache", dev, args.out),
                     {**device_info(dev), "rows": rows})
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
