"""The viewer's frame rate (issue 35): what `volrender view` renders per frame, without a
browser, with a scripted camera.

    .venv/bin/python bench/viewer.py [--device D] [--size 1920x1080] [--spp 64]
                                     [--frames 20] [--volume PATH] [--points SRC] [--tag T]

For a volume (the WDAS cloud, bench/data/wdas_cloud_sixteenth.npz where OpenVDB is
missing) and a point cloud (the Stanford bunny): progressive.Session at the still size,
after one untimed still step and preview (the programs built):

- moving: the camera orbits 2 degrees a frame for --frames frames, each a preview (the
  reduced size the session picks, one sample); per frame the render, the display (tone
  mapping, image.png_pixels, and JPEG at quality 90, what the viewer sends) and the
  preview size; frames/s = 1 / (render + display);
- still: from the last camera, the steps until --spp samples (each at most doubling the
  samples, about progressive.STEP_S long): per step the samples, render and display time,
  and the time to the converged frame (the display of each step counted).

Writes bench/results/viewer_<device>[-TAG].json and .png.
"""
from __future__ import annotations

import argparse
import io
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import (device_info, find_volume, missing_data, result_path,  # noqa: E402
                          shared_data, write_json)


def display_seconds(img) -> float:
    """What the viewer does with a frame before viser sends it: tone map, JPEG."""
    from PIL import Image as PILImage
    from volrender.image import png_pixels
    t0 = time.perf_counter()
    rgb = png_pixels(img.rgba, 0.0, "filmic", background=img.info.background,
                     alpha="opaque")[..., :3]
    PILImage.fromarray(np.ascontiguousarray(rgb)).save(io.BytesIO(), format="JPEG", quality=90)
    return time.perf_counter() - t0


def orbit(camera, degrees):
    """The camera turned about its up vector through the target."""
    import dataclasses
    o, t = np.asarray(camera.origin, np.float64), np.asarray(camera.target, np.float64)
    k = np.asarray(camera.up, np.float64)
    k = k / np.linalg.norm(k)
    v, a = o - t, math.radians(degrees)
    v = v * math.cos(a) + np.cross(k, v) * math.sin(a) + k * np.dot(k, v) * (1 - math.cos(a))
    return dataclasses.replace(camera, origin=tuple(t + v))


def measure(src, dev, size, spp, frames) -> dict:
    import volrender
    from volrender.progressive import Session
    t0 = time.perf_counter()
    scene = volrender.load_scene(str(src), size=size, spp=spp, denoise="off")
    s = Session(scene, dev)
    load = time.perf_counter() - t0
    s.step()                                         # warm: the still program, a first step
    cam = s.camera
    s.set_camera(orbit(cam, 1.0))
    s.step()                                         # warm: a preview
    moving = []
    for i in range(frames):
        cam = orbit(cam, 2.0)
        s.set_camera(cam)
        t1 = time.perf_counter()
        f = s.step()
        render = time.perf_counter() - t1
        assert f is not None and f.state == "preview", f
        moving.append({"render_s": render, "display_s": display_seconds(f.image),
                       "size": [f.image.width, f.image.height], "kernel_ms": f.image.kernel_ms})
    s.changed_at = -math.inf                         # still now
    still, t2 = [], time.perf_counter()
    while True:
        t1 = time.perf_counter()
        f = s.step()
        if f is None:
            break
        render = time.perf_counter() - t1
        still.append({"spp": f.spp, "render_s": render, "display_s": display_seconds(f.image)})
    converged = time.perf_counter() - t2
    per = [x["render_s"] + x["display_s"] for x in moving]
    return {"input": str(src), "kind": scene.kind, "size": list(size), "spp": spp,
            "load_s": load, "moving": moving, "still": still,
            "moving_fps_median": 1.0 / float(np.median(per)),
            "moving_render_fps_median": 1.0 / float(np.median([x["render_s"] for x in moving])),
            "preview_size": moving[-1]["size"], "time_to_converged_s": converged,
            "still_steps": len(still), "settings": {"estimator": scene.settings.estimator}
            if scene.kind == "volume" else {"glass_model": scene.settings.glass_model}}


def plot(results, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for r in results:
        name = Path(r["input"]).name
        axes[0].plot([1e3 * (x["render_s"] + x["display_s"]) for x in r["moving"]],
                     label=f"{name} {r['preview_size'][0]}x{r['preview_size'][1]}")
        t = np.cumsum([x["render_s"] + x["display_s"] for x in r["still"]])
        axes[1].step(t, [x["spp"] for x in r["still"]], where="post", label=name)
    axes[0].set(xlabel="moving frame", ylabel="ms (render + display)", title="moving: 1 spp")
    axes[1].set(xlabel="seconds since still", ylabel="spp shown", yscale="log",
                title="still: samples accumulated")
    for a in axes:
        a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main(argv=None):
    from volrender import device as device_mod
    from volrender.settings import pair
    p = argparse.ArgumentParser(prog="bench/viewer.py", description=__doc__.split("\n")[0])
    p.add_argument("--device", default=None,
                   help="OpenCL device to render on (default: PoCL)")
    p.add_argument("--size", type=pair("--size"), default=(1920, 1080),
                   help="the still frame's size, WxH (default: 1920x1080)")
    p.add_argument("--spp", type=int, default=64,
                   help="samples the still frame converges to (default: 64)")
    p.add_argument("--frames", type=int, default=20,
                   help="camera steps of the scripted orbit (default: 20)")
    p.add_argument("--volume", default=None, help="default: the WDAS cloud")
    p.add_argument("--points", default=None, help="default: the Stanford bunny")
    p.add_argument("--tag", default=None,
                   help="suffix of the result's file name in bench/results/")
    args = p.parse_args(argv)
    dev = device_mod.get(args.device)
    volume = args.volume or find_volume("wdas_cloud_sixteenth", lambda: _openvdb())
    points = args.points or shared_data() / "points" / "bun_zipper.ply"
    if volume is None:
        sys.exit(missing_data("wdas_cloud_sixteenth"))
    results = []
    for src in (volume, points):
        r = measure(src, dev, tuple(args.size), args.spp, args.frames)
        print(f"{Path(src).name}: moving {r['moving_fps_median']:.1f} frames/s at "
              f"{r['preview_size'][0]}x{r['preview_size'][1]} (render alone "
              f"{r['moving_render_fps_median']:.1f}/s); converged {args.spp} spp at "
              f"{args.size[0]}x{args.size[1]} in {r['time_to_converged_s']:.2f} s "
              f"({r['still_steps']} steps)", flush=True)
        results.append(r)
    out = result_path("viewer", dev, args.tag)
    write_json(out, {**device_info(dev), "results": results})
    plot(results, out.with_suffix(".png"))
    print(f"wrote {out}")


def _openvdb() -> bool:
    try:
        from volrender.vdb import import_openvdb
        import_openvdb()
        return True
    except Exception:
        return False


if __name__ == "__main__":
    main()
