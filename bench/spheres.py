"""Molten glass against sphere count: fragment vs tiled dispatch, tree vs brute force,
lit vs unlit, and the kernel-specialisation effect (uber-kernel vs only what is needed).

    volrender bench spheres [--device SPEC] [--size 640x480] [--counts 1000,...,1000000]
        [--repeat 3] [--brute-limit 60] [--tile 8x8] [--bounces 2]

Each variant: one warm-up (program build, first launch), then --repeat timed renders;
kernel time from OpenCL profiling events, wall time around the launches, tree build time.
Brute force (no tree) runs only while one render of it takes under --brute-limit seconds.
Writes bench/results/spheres_<device>.json (every run) and .png (log-log, one line per
variant) and prints a table in the layout of the paper's Tables 1 and 2.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import (RESULTS, result_path, device_info, device_tag, find_volume, missing_data,  # noqa: E402
                          shared_data, stats, write_json)
from volrender import device, glass, points  # noqa: E402
from volrender.dispatch import parse_tile  # noqa: E402
from volrender.lights import Sun  # noqa: E402

SUN = Sun((-0.5, -1.0, -0.4), 3.0)
COUNTS = [1000, 1500, 2000, 3000, 10_000, 100_000, 1_000_000]
# the paper's consumer-GPU figures (ms), for the printed comparison
PAPER = {("fragment", False, 1000): 56.7, ("fragment", False, 1500): 375.9,
         ("compute", False, 2000): 54.6, ("compute", False, 3000): 238.0,
         ("compute", True, 2000, True): 32.3, ("compute", True, 2000, False): 13.2,
         ("compute", True, 3000, True): 120.7, ("compute", True, 3000, False): 14.3}


def ints(text):
    return [int(float(v)) for v in text.split(",") if v]


def measure(cloud, cam, settings, dev, repeat, lights, variant=None):
    """Warm-up at a tiny size (builds the program), then `repeat` timed renders, then one
    untimed render counting the field's work (work_stats)."""
    glass.render_points(cloud, dataclasses.replace(cam, width=16, height=16), lights, settings, dev,
                        variant=variant)
    kernel, wall, tree = [], [], []
    for _ in range(repeat):
        r = glass.render_points(cloud, cam, lights, settings, dev, variant=variant)
        kernel.append(r["kernel_ms"])
        wall.append(r["wall_ms"])
        tree.append(r["tree_ms"])
    counts = glass.render_points(cloud, cam, lights, settings, dev, variant="stats")["rgba"]
    return r["rgba"], {"kernel_ms": stats(kernel), "wall_ms": stats(wall), "tree_ms": stats(tree),
                       "work": work_stats(counts)}


def work_stats(counts, block=(8, 4)):
    """Field work per pixel from a GlassSettings.stats render: evaluations (mean, p99),
    node and sphere tests per evaluation, and the SIMD efficiency of warps shaped as
    8x4-pixel blocks (mean over lanes / the slowest lane: a warp runs until its last
    lane finishes)."""
    e = counts[..., 0].astype(np.float64)
    total = max(float(e.sum()), 1.0)
    bw, bh = block
    h, w = (e.shape[0] // bh) * bh, (e.shape[1] // bw) * bw
    blocks = e[:h, :w].reshape(h // bh, bh, w // bw, bw).transpose(0, 2, 1, 3).reshape(-1, bw * bh)
    peak = blocks.max(axis=1)
    return {"evals_mean": float(e.mean()), "evals_p99": float(np.percentile(e, 99)),
            "evals_max": float(e.max()),
            "nodes_per_eval": float(counts[..., 1].sum() / total),
            "spheres_per_eval": float(counts[..., 2].sum() / total),
            "simd_efficiency": float(blocks.mean(axis=1).sum() / max(peak.sum(), 1.0))}


def variant_name(v):
    return (f"{v['dispatch']}, {'tree' if v['tree'] else 'brute force'}, "
            f"{'lit' if v['lit'] else 'unlit'}" + (", uber" if v.get("uber") else ""))


def main(argv=None):
    ap = argparse.ArgumentParser(prog="volrender bench spheres", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default=None, help="OpenCL device (default: PoCL)")
    ap.add_argument("--size", default="640x480", help="image size WxH (default: 640x480)")
    ap.add_argument("--generator", default="blob", choices=sorted(points.GENERATORS),
                    help="point generator (default: blob)")
    ap.add_argument("--counts", type=ints, default=COUNTS,
                    help="sphere counts, comma-separated (default: 1000 ... 1000000)")
    ap.add_argument("--repeat", type=int, default=3, help="timed renders per variant (default: 3)")
    ap.add_argument("--bounces", type=int, default=2, help="glass surface events per path (default: 2)")
    ap.add_argument("--tile", type=parse_tile, default=(8, 8), help="work-group WxH (default: 8x8)")
    ap.add_argument("--brute-limit", type=float, default=60.0,
                    help="seconds: stop brute force once one render takes longer")
    ap.add_argument("--dispatch", default="fragment,tiled",
                    help="comma-separated: fragment, tiled, fragment-driver (the driver's local size)")
    ap.add_argument("--uber-count", type=int, default=3000,
                    help="sphere count of the uber-kernel comparison (0: skip)")
    ap.add_argument("--opaque", action="store_true",
                    help="opaque spheres (no refraction): one surface hit per primary ray, as in the paper")
    ap.add_argument("--tag", default=None, help="added to the results' name: spheres_<device>-<tag>.json")
    args = ap.parse_args(argv)
    width, height = (int(v) for v in args.size.lower().split("x"))
    dev = device.get(args.device)
    path = result_path("spheres", dev, "-".join(t for t in (args.tag, "opaque" if args.opaque else None) if t))
    rows, uber_rows = [], []
    dispatches = [d for d in args.dispatch.split(",") if d]

    def save():          # after every row, so a run cut short still leaves its data
        return write_json(path, {"benchmark": "spheres", "size": [width, height],
                                 "opaque": args.opaque,
                                 "generator": args.generator, "bounces": args.bounces, "spp": 1,
                                 "tile": list(args.tile), "repeat": args.repeat,
                                 **device_info(dev), "rows": rows, "uber": uber_rows})

    brute_ok = {(d, lit): True for d in dispatches for lit in (True, False)}
    for n in args.counts:
        cloud = points.generate(args.generator, n, seed=1)
        cam = glass.default_camera(cloud, width, height)
        ref = None
        for lit in (True, False):
            for disp in dispatches:
                for use_tree in (True, False):
                    if not use_tree and not brute_ok[(disp, lit)]:
                        continue
                    s = glass.GlassSettings(bounces=args.bounces, use_tree=use_tree,
                                            dispatch=disp, tile=args.tile,
                                            refraction=not args.opaque)
                    t0 = time.perf_counter()
                    img, t = measure(cloud, cam, s, dev, args.repeat, [SUN] if lit else [])
                    if not use_tree and (time.perf_counter() - t0) / args.repeat > args.brute_limit:
                        brute_ok[(disp, lit)] = False
                    if lit and ref is None:
                        ref = img
                    row = {"n": n, "dispatch": disp, "tree": use_tree, "lit": lit,
                           "opaque": args.opaque, **t}
                    if lit:   # every lit variant against the first (fragment, tree)
                        diff = np.abs(img - ref).max(axis=-1)
                        row["max_abs_diff"] = float(diff.max())
                        row["frac_pixels_over_1e-3"] = float((diff > 1e-3).mean())
                    rows.append(row)
                    save()
                    wk = t["work"]
                    print(f"n={n:8d} {variant_name(row):32s} kernel {t['kernel_ms']['median']:10.2f} ms "
                          f"wall {t['wall_ms']['median']:10.2f} ms build {t['tree_ms']['median']:8.1f} ms "
                          f"evals {wk['evals_mean']:.1f} (p99 {wk['evals_p99']:.0f}, simd "
                          f"{wk['simd_efficiency']:.2f}) tests/eval {wk['nodes_per_eval']:.0f}+"
                          f"{wk['spheres_per_eval']:.0f}"
                          + (f"  max|diff| {row['max_abs_diff']:.1e}" if lit else ""), flush=True)
    if args.uber_count:
        cloud = points.generate(args.generator, args.uber_count, seed=1)
        cam = glass.default_camera(cloud, width, height)
        for lit in (True, False):
            for uber in (False, True):
                s = glass.GlassSettings(bounces=args.bounces, refraction=not args.opaque,
                                        dispatch="fragment")
                img, t = measure(cloud, cam, s, dev, args.repeat, [SUN] if lit else [],
                                 variant="uber" if uber else None)
                uber_rows.append({"n": args.uber_count, "dispatch": "fragment", "tree": True,
                                  "lit": lit, "uber": uber, **t})
                save()
                print(f"n={args.uber_count:8d} {variant_name(uber_rows[-1]):32s} kernel "
                      f"{t['kernel_ms']['median']:10.2f} ms", flush=True)
    out = save()
    plot(rows, dev, out.with_suffix(".png"), width, height)
    print(table(rows, uber_rows, width, height, dev.name))
    print(f"wrote {out}")
    return 0


def _median(rows, **key):
    for r in rows:
        if all(r.get(k) == v for k, v in key.items()):
            return r["kernel_ms"]["median"]
    return None


def table(rows, uber_rows, width, height, name):
    """Markdown table: kernel ms per sphere count and variant, like the paper's tables."""
    counts = sorted({r["n"] for r in rows})
    variants = []
    for r in rows:
        key = (r["dispatch"], r["tree"], r["lit"])
        if key not in variants:
            variants.append(key)
    head = "| spheres | " + " | ".join(f"{d}, {'tree' if t else 'no tree'}, {'lit' if l else 'unlit'}"
                                      for d, t, l in variants) + " |"
    lines = [f"Kernel ms per frame, {width}x{height}, {name}", "", head,
             "|" + "---|" * (len(variants) + 1)]
    for n in counts:
        cells = []
        for d, t, l in variants:
            v = _median(rows, n=n, dispatch=d, tree=t, lit=l)
            cells.append("—" if v is None else f"{v:.1f}")
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    if uber_rows:
        lines += ["", "| uber-kernel vs specialised | specialised ms | uber ms | uber / specialised |",
                  "|---|---|---|---|"]
        for lit in (True, False):
            a = _median(uber_rows, lit=lit, uber=False)
            b = _median(uber_rows, lit=lit, uber=True)
            if a and b:
                lines.append(f"| {uber_rows[0]['n']} spheres, {'lit' if lit else 'unlit'} | "
                             f"{a:.1f} | {b:.1f} | {b / a:.2f} |")
    return "\n".join(lines)


def plot(rows, dev, path, width, height):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 4.5))
    keys = []
    for r in rows:
        key = (r["dispatch"], r["tree"], r["lit"])
        if key not in keys:
            keys.append(key)
    for d, t, lit in keys:
        sel = [r for r in rows if (r["dispatch"], r["tree"], r["lit"]) == (d, t, lit)]
        ax.loglog([r["n"] for r in sel], [r["kernel_ms"]["median"] for r in sel],
                  ("o" if t else "x") + {"fragment": "-", "tiled": "--"}.get(d, ":"),
                  label=variant_name({"dispatch": d, "tree": t, "lit": lit}))
    ax.set_xlabel("spheres")
    ax.set_ylabel("kernel ms per frame (median)")
    what = "opaque spheres" if rows and rows[0].get("opaque") else "molten glass"
    ax.set_title(f"{what} {width}x{height}, 1 spp\n{dev.name}", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    sys.exit(main())
