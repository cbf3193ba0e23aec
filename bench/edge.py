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
from volrender import cells, device, generators, glass, spheres  # noqa: E402
from volrender.lights import Sun  # noqa: E402
from volrender.render import render  # noqa: E402
from volrender.scene import GlassContent, Scene  # noqa: E402

SUN = Sun((-0.6, -1.0, -0.5), 6.0)
SCANS = {"bunny": ("bun_zipper.ply", {"radius": 0.002, "blend": 0.004}),
         "bunny-default": ("bun_zipper.ply", {}),          # radius and blend from the scan
         "frag": ("frag_115.ply", {})}


def cloud_of(name):
    if name in SCANS:
        from volrender.scene import load_scene
        file, kw = SCANS[name]
        sc = load_scene(str(shared_data() / "points" / file), **kw)
        return sc.content.cloud, sc.content.settings
    gen, n = name.split(":")
    gen = {"gather": "glass_gather"}.get(gen, gen)
    return generators.generate(gen, int(n), 1), glass.GlassSettings()


def timed_render(cloud, settings, cam, dev):
    """(packed, build s, kernel s, per-pixel work: field evaluations, node tests or cell
    lookups, sphere tests, build CPU s, render CPU s). CPU time (the process's, which holds
    PoCL's threads) is what the calibration fits on CPUs: on a shared machine it moves far
    less with the load than wall time."""
    content = GlassContent(cloud, settings)
    t0, c0 = time.perf_counter(), time.process_time()
    packed = content.prepare(dev, samples=cam.width * cam.height)
    build = time.perf_counter() - t0
    build_cpu = time.process_time() - c0
    scene = Scene.of(dataclasses.replace(cam, width=8, height=8), [SUN], content)
    render(scene, dev)                                   # program build
    img = render(Scene.of(cam, [SUN], content), dev)
    work = render(Scene.of(cam, [SUN], content), dev, variant="stats").rgba[..., :3]
    return (packed, build, img.kernel_ms / 1e3, [float(v) for v in work.reshape(-1, 3).mean(0)],
            build_cpu, img.cpu_ms / 1e3)


SAMPLES = (4800, 19200, 76800, 307200, 2073600)      # 80x60 ... 1920x1080 at 1 spp


def whole(rows, samples, cpu):
    """{choice: seconds} of each option for a job of `samples` pixel samples: the build
    plus the render scaled from the measured size (render time is linear in samples)."""
    key = ("build_cpu_s", "render_cpu_s", "tree_build_cpu_s", "tree_render_cpu_s") if cpu \
        else ("build_s", "kernel_s", "tree_build_s", "tree_kernel_s")
    out = {("grid", r["factor"]): r[key[0]] + r[key[1]] * samples / r["samples"] for r in rows}
    out[("tree", 0.0)] = rows[0][key[2]] + rows[0][key[3]] * samples / rows[0]["samples"]
    return out


def rule_choice(rows, samples, per_sample, m_max):
    """cells.choose_edge's rule on measured rows: the finest factor whose estimated cells
    are at most per_sample x samples, else (beyond m_max) the tree walk."""
    for r in sorted(rows, key=lambda r: r["factor"]):
        if r["factor"] <= m_max and r["estimated_cells"] <= per_sample * samples:
            return ("grid", r["factor"])
    return ("tree", 0.0)


def fit(rows, cpu=True, kappas=(0.5, 1, 2, 3, 4, 6, 8, 12, 16, 24, 32),
        m_maxes=(1.5, 2, 3, 4, 6, 8)):
    """The (cells per sample, largest factor) minimising the geometric mean of the chosen
    option's whole time over the best option's, over every cloud and job size; with that
    regret (geometric mean, worst) and the per-case table."""
    clouds = {}
    for r in rows:
        clouds.setdefault(r["cloud"], []).append(r)
    best = None
    for kappa in kappas:
        for m_max in m_maxes:
            reg = [t[rule_choice(rs, n, kappa, m_max)] / min(t.values())
                   for rs in clouds.values() for n in SAMPLES for t in [whole(rs, n, cpu)]]
            g = float(np.exp(np.mean(np.log(reg))))
            if best is None or g < best[0]:
                best = (g, kappa, m_max, float(max(reg)))
    g, kappa, m_max, worst = best
    cases = []
    for name, rs in clouds.items():
        for n in SAMPLES:
            t = whole(rs, n, cpu)
            ch = rule_choice(rs, n, kappa, m_max)
            opt = min(t, key=t.get)
            cases.append({"cloud": name, "samples": n, "chosen": list(ch), "best": list(opt),
                          "chosen_s": t[ch], "best_s": t[opt], "tree_s": t[("tree", 0.0)]})
    return {"cells_per_sample": kappa, "max_factor": m_max, "regret_geomean": g,
            "regret_worst": worst, "time": "cpu" if cpu else "wall", "cases": cases}


def main(argv=None):
    ap = argparse.ArgumentParser(prog="volrender bench edge", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default=None, help="OpenCL device (default: PoCL)")
    ap.add_argument("--size", default="160x120", help="image size WxH (default: 160x120)")
    ap.add_argument("--factors", default="1,1.5,2,3,4,6",
                    help="cell edges as multiples of the base edge, comma-separated")
    ap.add_argument("--clouds", default="blob:3000,blob:30000,blob:100000,gather:3000,bunny",
                    help="GENERATOR:COUNT (gather = glass_gather) or a scan (bunny, frag)")
    ap.add_argument("--tag", default=None, help="added to the results' name: edge_<device>-<tag>.json")
    ap.add_argument("--fit", default=None, metavar="EDGE.json",
                    help="fit the rule to an earlier run's rows and write it into that file")
    args = ap.parse_args(argv)
    if args.fit:
        import json
        payload = json.loads(Path(args.fit).read_text())
        payload["fit"] = fit(payload["rows"], cpu="build_cpu_s" in payload["rows"][0])
        f = payload["fit"]
        for c in f["cases"]:
            print(f"{c['cloud']:16s} {c['samples']:>8} chosen {c['chosen'][0]} {c['chosen'][1]:3g}"
                  f" {c['chosen_s']:8.2f} s  best {c['best'][0]} {c['best'][1]:3g} "
                  f"{c['best_s']:8.2f} s  tree {c['tree_s']:8.2f} s")
        print(f"rule: {f['cells_per_sample']} cells per sample, factors up to {f['max_factor']}; "
              f"whole time x{f['regret_geomean']:.3f} of the best choice (geometric mean), "
              f"worst x{f['regret_worst']:.2f}")
        Path(args.fit).write_text(json.dumps(payload, indent=1) + "\n")
        return 0
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
        _, tb, tk, tw, tbc, tkc = timed_render(cloud, dataclasses.replace(base, accel="tree"), cam, dev)
        radii = spheres.sphere_radii(cloud, base)
        k = spheres.blend_width(radii, base)
        edge0 = cells.auto_cell_size(radii, k)
        for m in factors:
            s = dataclasses.replace(base, cell_size=m * edge0)
            packed, build, kern, work, build_cpu, kern_cpu = timed_render(cloud, s, cam, dev)
            if packed.cells is None:
                continue
            st = packed.cells.stats()
            est = cells.estimate_cells(packed.spheres, packed.blend, packed.box_lo, m * edge0)
            row = {"cloud": name, "n": len(cloud.centers), "factor": m, "edge": m * edge0,
                   "samples": w * h, "build_s": build, "tree_ms": packed.tree_ms,
                   "cells_ms": st["build_ms"], "built_cells": st["mixed_bricks"] * cells.B3,
                   "estimated_cells": est, "listed": st["cells_listed"],
                   "list_mean": st["list_mean"], "core_mean": st["core_mean"],
                   "kernel_s": kern, "tree_kernel_s": tk, "tree_build_s": tb,
                   "work": work, "tree_work": tw, "build_cpu_s": build_cpu,
                   "render_cpu_s": kern_cpu, "tree_build_cpu_s": tbc, "tree_render_cpu_s": tkc,
                   }
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
