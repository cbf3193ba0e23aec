"""Support-cell edge against build and render time: the data the automatic edge's model
(cells.choose_edge) is calibrated from, and its error.

    .venv/bin/python bench/edge.py [--device SPEC] [--size 160x120] [--factors 1,1.5,2,3,4,6]
        [--clouds blob:3000,blob:100000,gather:3000,bunny,frag] [--tag TAG]

For each cloud: the tree walk's render, then for each factor m the cells at edge m x the
base edge (cells.auto_cell_size): the build's time and cells (in the bricks the surface
passes through: what the build classifies), and the render's kernel time (one sun, the
default glass, 1 spp). The fit: build seconds per built cell, and the cells' speed-up over
the tree walk against m; then the model's predicted whole time (build + render) against
the measured one for every row. Writes bench/results/edge_<device>[-TAG].json.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench.common import device_info, result_path, shared_data, write_json  # noqa: E402
from volrender import cells, device, glass, points  # noqa: E402
from volrender.lights import Sun  # noqa: E402
from volrender.render import render  # noqa: E402
from volrender.scene import GlassContent, Scene  # noqa: E402

SUN = Sun((-0.6, -1.0, -0.5), 6.0)
SCANS = {"bunny": ("bun_zipper.ply", {"radius": 0.002, "blend": 0.004}),
         "frag": ("frag_115.ply", {})}


def cloud_of(name):
    if name in SCANS:
        from volrender.scene import load_scene
        file, kw = SCANS[name]
        sc = load_scene(str(shared_data() / "points" / file), **kw)
        return sc.content.cloud, sc.content.settings
    gen, n = name.split(":")
    gen = {"gather": "glass_gather"}.get(gen, gen)
    return points.generate(gen, int(n), 1), glass.GlassSettings()


def timed_render(cloud, settings, cam, dev):
    content = GlassContent(cloud, settings)
    t0 = time.perf_counter()
    packed = content.prepare(dev, samples=cam.width * cam.height)
    build = time.perf_counter() - t0
    scene = Scene.of(dataclasses.replace(cam, width=8, height=8), [SUN], content)
    render(scene, dev)                                   # program build
    img = render(Scene.of(cam, [SUN], content), dev)
    return packed, build, img.kernel_ms / 1e3


def main(argv=None):
    ap = argparse.ArgumentParser(prog="volrender bench edge", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default=None)
    ap.add_argument("--size", default="160x120")
    ap.add_argument("--factors", default="1,1.5,2,3,4,6")
    ap.add_argument("--clouds", default="blob:3000,blob:30000,blob:100000,gather:3000,bunny")
    ap.add_argument("--tag", default=None)
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.size.lower().split("x"))
    factors = [float(v) for v in args.factors.split(",")]
    dev = device.get(args.device)
    rows = []
    path = result_path("edge", dev, args.tag)
    for name in args.clouds.split(","):
        try:
            cloud, base = cloud_of(name)
        except Exception as exc:                      # a scan missing here: skip it
            print(f"{name}: skipped ({exc})")
            continue
        cam = glass.default_camera(cloud, w, h, radius=base.radius)
        _, tb, tk = timed_render(cloud, dataclasses.replace(base, accel="tree"), cam, dev)
        radii = glass.sphere_radii(cloud, base)
        k = glass.blend_width(radii, base)
        edge0 = cells.auto_cell_size(radii, k)
        for m in factors:
            s = dataclasses.replace(base, cell_size=m * edge0)
            packed, build, kern = timed_render(cloud, s, cam, dev)
            if packed.cells is None:
                continue
            st = packed.cells.stats()
            est = cells.estimate_cells(packed.spheres, packed.blend, packed.box_lo, m * edge0)
            row = {"cloud": name, "n": len(cloud.centers), "factor": m, "edge": m * edge0,
                   "samples": w * h, "build_s": build, "tree_ms": packed.tree_ms,
                   "cells_ms": st["build_ms"], "built_cells": st["mixed_bricks"] * cells.B3,
                   "estimated_cells": est, "listed": st["cells_listed"],
                   "list_mean": st["list_mean"], "kernel_s": kern, "tree_kernel_s": tk,
                   "tree_build_s": tb}
            rows.append(row)
            print(f"{name:14s} m {m:4.1f} build {build:6.2f} s ({row['built_cells']:>9} cells, "
                  f"est {est:>9})  kernel {kern:6.3f} s  tree {tk:6.3f} s  x{tk / kern:4.1f}",
                  flush=True)
        write_json(path, {"benchmark": "edge", "size": [w, h], **device_info(dev),
                          "rows": rows})
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
