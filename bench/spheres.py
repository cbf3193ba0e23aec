"""Molten-glass speed against sphere count: the partition tree vs brute force (same
image), and the tree's growth from 10^3 to 10^6 spheres at a fixed image size.

    .venv/bin/python bench/spheres.py [--device SPEC] [--size 320x240]
        [--compare 1000,3000,10000] [--growth 1000,10000,100000,1000000] [--repeat 3]

Writes bench/results/spheres_<device>.json and .png.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import RESULTS, device_info, device_tag, stats, write_json  # noqa: E402
from volrender import device, glass, points  # noqa: E402
from volrender.lights import Sun  # noqa: E402

SUN = Sun((-0.5, -1.0, -0.4), 3.0)


def ints(text):
    return [int(float(v)) for v in text.split(",") if v]


def measure(cloud, cam, settings, dev, repeat, lights):
    glass.render_points(cloud, cam, lights, settings, dev)          # warm-up and build
    kernel, wall, tree = [], [], []
    for _ in range(repeat):
        r = glass.render_points(cloud, cam, lights, settings, dev)
        kernel.append(r["kernel_ms"])
        wall.append(r["wall_ms"])
        tree.append(r.get("tree_ms", 0.0))
    return r["rgba"], {"kernel_ms": stats(kernel), "wall_ms": stats(wall), "tree_ms": stats(tree)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default=None)
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--generator", default="blob", choices=sorted(points.GENERATORS))
    ap.add_argument("--compare", type=ints, default=[1000, 3000, 10000])
    ap.add_argument("--growth", type=ints, default=[1000, 10000, 100000, 1000000])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--bounces", type=int, default=2)
    ap.add_argument("--tag", default=None)
    args = ap.parse_args(argv)
    width, height = (int(v) for v in args.size.split("x"))
    dev = device.get(args.device)
    base = glass.GlassSettings(bounces=args.bounces)
    compare, growth = [], []
    tag = args.tag or device_tag(dev)
    path = RESULTS / f"spheres_{tag}.json"

    def save():          # after every row, so a run cut short still leaves its data
        return write_json(path, {"benchmark": "spheres", "size": [width, height],
                                 "generator": args.generator, "bounces": args.bounces, "spp": 1,
                                 "repeat": args.repeat, **device_info(dev),
                                 "compare": compare, "growth": growth})
    for n in args.compare:
        cloud = points.generate(args.generator, n, seed=1)
        cam = glass.default_camera(cloud, width, height)
        img_t, t = measure(cloud, cam, base, dev, args.repeat, [SUN])
        img_b, b = measure(cloud, cam, glass.GlassSettings(bounces=args.bounces, use_tree=False),
                           dev, args.repeat, [SUN])
        row = {"n": n, "tree": t, "brute": b,
               "speedup": b["kernel_ms"]["median"] / t["kernel_ms"]["median"],
               "max_abs_diff": float(np.abs(img_t - img_b).max())}
        compare.append(row)
        save()
        print(f"n={n:8d} tree {t['kernel_ms']['median']:9.1f} ms  brute {b['kernel_ms']['median']:9.1f} ms"
              f"  x{row['speedup']:.1f}  max|diff| {row['max_abs_diff']:.1e}", flush=True)
    for n in args.growth:
        cloud = points.generate(args.generator, n, seed=1)
        cam = glass.default_camera(cloud, width, height)
        for lit in (True, False):
            _, t = measure(cloud, cam, base, dev, args.repeat, [SUN] if lit else [])
            growth.append({"n": n, "lit": lit, "tree": t})
            save()
            print(f"n={n:8d} {'lit  ' if lit else 'unlit'} tree {t['kernel_ms']['median']:9.1f} ms"
                  f"  build {t['tree_ms']['median']:8.1f} ms", flush=True)
    out = save()
    plot(compare, growth, dev, out.with_suffix(".png"), width, height)
    print(f"wrote {out}")


def plot(compare, growth, dev, path, width, height):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.5, 4))
    if compare:
        n = [r["n"] for r in compare]
        ax.loglog(n, [r["brute"]["kernel_ms"]["median"] for r in compare], "o-", label="brute force, lit")
        ax.loglog(n, [r["tree"]["kernel_ms"]["median"] for r in compare], "s-", label="tree, lit (compare)")
    for lit in (True, False):
        rows = [g for g in growth if g["lit"] == lit]
        if rows:
            ax.loglog([g["n"] for g in rows], [g["tree"]["kernel_ms"]["median"] for g in rows],
                      "^--" if lit else "v--", label=f"tree, {'lit' if lit else 'unlit'}")
    ax.set_xlabel("spheres")
    ax.set_ylabel("kernel ms per frame")
    ax.set_title(f"molten glass {width}x{height}, 1 spp\n{dev.name}", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
