"""Molten glass against sphere count: support cells vs tree walk vs brute force, fragment
vs tiled dispatch, lit vs unlit, the kernel-specialisation effect (uber-kernel vs only what
is needed), and the two scanned clouds at their look-good settings.

    volrender bench spheres [--device SPEC] [--size 640x480] [--counts 1000,...,1000000]
        [--accel grid,tree,none] [--dispatch fragment,tiled] [--lit lit,unlit] [--repeat 3]
        [--brute-limit 60] [--bounces 2] [--opaque] [--scans bunny,frag,...] [--no-sweep]

Each variant: one warm-up (program builds, first launch), then one timed build of the
acceleration (tree, plus cells for grid) and --repeat timed renders reusing it; kernel time
from OpenCL profiling events, wall time around the launches. Then one render counting the
field's work (GlassSettings variant "stats"): evaluations per pixel, tests per evaluation
(node tests or cell lookups, sphere tests) and the SIMD efficiency of 8x4-pixel warps.
Brute force runs only while one render of it takes under --brute-limit seconds. Lit
variants are compared with the first lit one of their count (brute force where it ran).
Writes bench/results/spheres_<device>[-<tag>].json (every run) and .png and prints a table.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import render_points, CONVERTED, device_info, result_path, shared_data, stats, write_json  # noqa: E402
from volrender import device, generators, glass, points  # noqa: E402
from volrender.dispatch import parse_tile  # noqa: E402
from volrender.lights import Sun  # noqa: E402
from volrender.render import render  # noqa: E402
from volrender.scene import GlassContent, Scene  # noqa: E402

SUN = Sun((-0.5, -1.0, -0.4), 3.0)
COUNTS = [1000, 3000, 10_000, 100_000, 1_000_000]
# scanned clouds (shared_data()/points, or bench/data where that is absent): file and
# settings. "-default" = what a user gets without options; the others are the issue's
# look-good settings (one smooth piece of glass).
SCANS = {
    "bunny": ("bun_zipper.ply", {"radius": 0.002, "blend": 0.004}),
    "bunny-default": ("bun_zipper.ply", {}),
    "frag": ("frag_115.ply", {}),
}
SCAN_SUN = Sun((-0.6, -1.0, -0.5), 6.0)


def ints(text):
    return [int(float(v)) for v in text.split(",") if v]


def words(text):
    return [v for v in text.split(",") if v]


def measure(cloud, cam, settings, dev, repeat, lights, variant=None):
    """One timed build (the scene's acceleration, GlassContent.prepare), a warm-up render at
    a tiny size (the program build), `repeat` timed renders and one stats render, all
    reusing the build (the scene keeps it)."""
    content = GlassContent(cloud, settings)
    t0 = time.perf_counter()
    packed = content.prepare(dev, samples=cam.width * cam.height * settings.spp)
    build_s = time.perf_counter() - t0

    def once(camera, variant):
        return render(Scene.of(camera, lights, content), dev, variant=variant)

    once(dataclasses.replace(cam, width=16, height=16), variant)
    kernel, wall = [], []
    for _ in range(repeat):
        r = once(cam, variant)
        kernel.append(r.kernel_ms)
        wall.append(r.wall_ms)
    counts = once(cam, "stats").rgba
    assert content.builds == 1, "a render rebuilt the scene's acceleration"
    out = {"kernel_ms": stats(kernel), "wall_ms": stats(wall), "accel_used": packed.accel,
           "build": {"total_ms": 1e3 * build_s, "tree_ms": packed.tree_ms,
                     "cells_ms": packed.cells.build_ms if packed.cells is not None else 0.0},
           "work": work_stats(counts)}
    if packed.cells is not None:
        out["cells"] = packed.cells.stats()
        out["bytes_per_sphere"] = packed.cells.nbytes / len(packed.spheres)
    if packed.note:
        out["note"] = packed.note
    return r.rgba, out


def work_stats(counts, block=(8, 4)):
    """Field work per pixel from a stats render: evaluations (mean, p99), node tests (cell
    lookups with cells) and sphere tests per evaluation, and the SIMD efficiency of warps
    shaped as 8x4-pixel blocks (mean over lanes / the slowest lane: a warp runs until its
    last lane finishes)."""
    e = counts[..., 0].astype(np.float64)
    total = max(float(e.sum()), 1.0)
    bw, bh = block
    h, w = (e.shape[0] // bh) * bh, (e.shape[1] // bw) * bw
    blocks = e[:h, :w].reshape(h // bh, bh, w // bw, bw).transpose(0, 2, 1, 3).reshape(-1, bw * bh)
    peak = blocks.max(axis=1)
    work = e + counts[..., 1] + counts[..., 2]           # per pixel: evaluations + tests
    wb = work[:h, :w].reshape(h // bh, bh, w // bw, bw).transpose(0, 2, 1, 3).reshape(-1, bw * bh)
    return {"evals_mean": float(e.mean()), "evals_p99": float(np.percentile(e, 99)),
            "evals_max": float(e.max()),
            "nodes_per_eval": float(counts[..., 1].sum() / total),
            "spheres_per_eval": float(counts[..., 2].sum() / total),
            "simd_efficiency": float(blocks.mean(axis=1).sum() / max(peak.sum(), 1.0)),
            "simd_efficiency_tests": float(wb.mean(axis=1).sum() / max(wb.max(axis=1).sum(), 1.0))}


def variant_name(v):
    return (f"{v['dispatch']}, {v['accel']}, {'lit' if v['lit'] else 'unlit'}"
            + (f", {v['model']}" if v.get("model") else "") + (", uber" if v.get("uber") else ""))


def _compare(row, img, ref):
    diff = np.abs(img - ref).max(axis=-1)
    row["max_abs_diff"] = float(diff.max())
    row["frac_pixels_over_1e-3"] = float((diff > 1e-3).mean())
    row["coverage_equal"] = float((img[..., 3] == ref[..., 3]).mean())


def _print(row):
    t, wk, b = row, row["work"], row["build"]
    extra = f"  max|diff| {row['max_abs_diff']:.1e} ({row['frac_pixels_over_1e-3']:.4f})" \
        if "max_abs_diff" in row else ""
    mem = f" {row['bytes_per_sphere']:.0f} B/sphere" if "bytes_per_sphere" in row else ""
    print(f"{str(row.get('n', row.get('scan'))):>10} {variant_name(row):28s} kernel "
          f"{t['kernel_ms']['median']:9.2f} ms build {b['total_ms']:8.0f} ms (cells "
          f"{b['cells_ms']:.0f}){mem} evals {wk['evals_mean']:.1f} (p99 {wk['evals_p99']:.0f}, "
          f"simd {wk['simd_efficiency']:.2f}) tests/eval {wk['nodes_per_eval']:.1f}+"
          f"{wk['spheres_per_eval']:.0f}{extra}", flush=True)


def scan_path(name):
    for base in (shared_data() / "points", CONVERTED):
        if (base / name).is_file():
            return base / name
    return None


def main(argv=None):
    ap = argparse.ArgumentParser(prog="volrender bench spheres", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default=None, help="OpenCL device (default: PoCL)")
    ap.add_argument("--size", default="640x480", help="image size WxH (default: 640x480)")
    ap.add_argument("--generator", default="blob", choices=sorted(generators.GENERATORS),
                    help="point generator (default: blob)")
    ap.add_argument("--counts", type=ints, default=COUNTS,
                    help="sphere counts, comma-separated (default: 1000 ... 1000000)")
    ap.add_argument("--accel", type=words, default=["grid", "tree", "none"],
                    help="accelerations, comma-separated (default: grid,tree,none)")
    ap.add_argument("--lit", type=words, default=["lit", "unlit"],
                    help="lighting, comma-separated: lit (one sun), unlit (default: both)")
    ap.add_argument("--repeat", type=int, default=3, help="timed renders per variant (default: 3)")
    ap.add_argument("--bounces", type=int, default=2, help="glass surface events per path (default: 2)")
    ap.add_argument("--tile", type=parse_tile, default=(8, 8), help="work-group WxH (default: 8x8)")
    ap.add_argument("--brute-limit", type=float, default=60.0,
                    help="seconds: stop brute force once one render takes longer")
    ap.add_argument("--dispatch", type=words, default=["fragment", "tiled"],
                    help="comma-separated: fragment, tiled, fragment-driver (the driver's local size)")
    ap.add_argument("--tiled-accel", type=words, default=None,
                    help="accelerations the tiled dispatch runs with (default: all of --accel)")
    ap.add_argument("--uber-count", type=int, default=3000,
                    help="sphere count of the uber-kernel comparison (0: skip)")
    ap.add_argument("--opaque", action="store_true",
                    help="opaque spheres (no refraction): one surface hit per primary ray, as in the paper")
    ap.add_argument("--scans", type=words, default=[],
                    help=f"scanned clouds to render too: {', '.join(SCANS)}")
    ap.add_argument("--scan-size", default=None, help="image size of the scans (default: --size)")
    ap.add_argument("--no-sweep", action="store_true", help="only the scans")
    ap.add_argument("--cell-factor", type=float, default=None,
                    help="grid: cell edge = this times the median radius (default: automatic)")
    ap.add_argument("--models", type=words, default=["full"],
                    help="glass models, comma-separated: full (both Fresnel branches), fast "
                         "(one refracted path) (default: full)")
    ap.add_argument("--tag", default=None, help="added to the results' name: spheres_<device>-<tag>.json")
    args = ap.parse_args(argv)
    width, height = (int(v) for v in args.size.lower().split("x"))
    sw, sh = (int(v) for v in (args.scan_size or args.size).lower().split("x"))
    dev = device.get(args.device)
    path = result_path("spheres", dev, "-".join(t for t in (args.tag, "opaque" if args.opaque else None) if t))
    rows, uber_rows, scan_rows = [], [], []
    warm = generators.blob(50, seed=1)        # builds the cells builder's program once
    render_points(warm, glass.default_camera(warm, 8, 8), [], glass.GlassSettings(), dev)

    def save():          # after every row, so a run cut short still leaves its data
        return write_json(path, {"benchmark": "spheres", "size": [width, height],
                                 "scan_size": [sw, sh], "opaque": args.opaque,
                                 "generator": args.generator, "bounces": args.bounces, "spp": 1,
                                 "tile": list(args.tile), "repeat": args.repeat,
                                 **device_info(dev), "rows": rows, "uber": uber_rows,
                                 "scans": scan_rows})

    tiled_accel = args.tiled_accel or args.accel
    brute_ok = {(d, lit): True for d in args.dispatch for lit in ("lit", "unlit")}
    for n in ([] if args.no_sweep else args.counts):
        cloud = generators.generate(args.generator, n, seed=1)
        cam = glass.default_camera(cloud, width, height)
        for lit in args.lit:
            ref = None
            for disp, model in ((d, m) for d in args.dispatch for m in args.models):
                for accel in args.accel:
                    if disp == "tiled" and accel not in tiled_accel:
                        continue
                    if accel == "none" and not brute_ok[(disp, lit)]:
                        continue
                    cell = None
                    if accel == "grid" and args.cell_factor:
                        cell = args.cell_factor * float(np.median(cloud.radii))
                    s = glass.GlassSettings(bounces=args.bounces, accel=accel, dispatch=disp,
                                            tile=args.tile, refraction=not args.opaque,
                                            cell_size=cell, glass_model=model)
                    t0 = time.perf_counter()
                    img, t = measure(cloud, cam, s, dev, args.repeat,
                                     [SUN] if lit == "lit" else [])
                    per_render = (time.perf_counter() - t0) / (args.repeat + 2)
                    if accel == "none" and per_render > args.brute_limit:
                        brute_ok[(disp, lit)] = False
                    row = {"n": n, "dispatch": disp, "accel": accel, "lit": lit == "lit",
                           "opaque": args.opaque, "model": model, **t}
                    if ref is None:
                        ref = img
                        row["reference"] = True
                    else:
                        _compare(row, img, ref)
                    rows.append(row)
                    save()
                    _print(row)
    if args.uber_count and not args.no_sweep:
        cloud = generators.generate(args.generator, args.uber_count, seed=1)
        cam = glass.default_camera(cloud, width, height)
        for lit in args.lit:
            for uber in (False, True):
                s = glass.GlassSettings(bounces=args.bounces, refraction=not args.opaque,
                                        dispatch="fragment", accel=args.accel[0])
                img, t = measure(cloud, cam, s, dev, args.repeat, [SUN] if lit == "lit" else [],
                                 variant="uber" if uber else None)
                uber_rows.append({"n": args.uber_count, "dispatch": "fragment",
                                  "accel": args.accel[0], "lit": lit == "lit", "uber": uber, **t})
                save()
                _print(uber_rows[-1])
    for name in args.scans:
        file, opts = SCANS[name]
        src = scan_path(file)
        if src is None:
            print(f"scan {name}: {file} not found in {shared_data() / 'points'} or {CONVERTED}; "
                  "skipped")
            continue
        cloud = points.load_points(src)
        if cloud.radii is None:
            from volrender.spheres import scan_defaults
            settings0, _ = scan_defaults(cloud, glass.GlassSettings(**opts))
            opts = {**opts, "radius": settings0.radius, "blend": settings0.blend}
        cam = glass.default_camera(cloud, sw, sh, radius=opts["radius"])
        ref = None
        for disp, model in ((d, m) for d in args.dispatch for m in args.models):
            for accel in args.accel:
                if (disp == "tiled" and accel not in tiled_accel) or accel == "none":
                    continue
                s = glass.GlassSettings(accel=accel, dispatch=disp, tile=args.tile,
                                        glass_model=model, **opts)
                img, t = measure(cloud, cam, s, dev, args.repeat, [SCAN_SUN])
                row = {"scan": name, "file": file, "points": len(cloud.centers), **opts,
                       "dispatch": disp, "accel": accel, "lit": True, "model": model, **t}
                if ref is None:
                    ref = img
                    row["reference"] = True
                else:
                    _compare(row, img, ref)
                scan_rows.append(row)
                save()
                _print(row)
    out = save()
    if rows:
        plot(rows, dev, out.with_suffix(".png"), width, height)
    print(table(rows, uber_rows, scan_rows, width, height, dev.name))
    print(f"wrote {out}")
    return 0


def _median(rows, **key):
    for r in rows:
        if all(r.get(k) == v for k, v in key.items()):
            return r["kernel_ms"]["median"]
    return None


def _keys(rows):
    keys = []
    for r in rows:
        key = (r["dispatch"], r["accel"], r["lit"])
        if key not in keys:
            keys.append(key)
    return keys


def table(rows, uber_rows, scan_rows, width, height, name):
    """Markdown tables: kernel ms per sphere count and variant, uber-kernel, scans."""
    lines = []
    if rows:
        counts = sorted({r["n"] for r in rows})
        variants = _keys(rows)
        head = "| spheres | " + " | ".join(f"{d}, {a}, {'lit' if l else 'unlit'}"
                                          for d, a, l in variants) + " |"
        lines += [f"Kernel ms per frame, {width}x{height}, {name}", "", head,
                  "|" + "---|" * (len(variants) + 1)]
        for n in counts:
            cells = []
            for d, a, l in variants:
                v = _median(rows, n=n, dispatch=d, accel=a, lit=l)
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
    if scan_rows:
        lines += ["", "| scan | variant | kernel ms | build ms | bytes / sphere |",
                  "|---|---|---|---|---|"]
        for r in scan_rows:
            lines.append(f"| {r['scan']} | {r['dispatch']}, {r['accel']} | "
                         f"{r['kernel_ms']['median']:.1f} | {r['build']['total_ms']:.0f} | "
                         f"{r.get('bytes_per_sphere', 0):.0f} |")
    return "\n".join(lines)


def plot(rows, dev, path, width, height):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 4.5))
    marks = {"grid": "s", "tree": "o", "none": "x"}
    for d, a, lit in _keys(rows):
        sel = [r for r in rows if (r["dispatch"], r["accel"], r["lit"]) == (d, a, lit)]
        ax.loglog([r["n"] for r in sel], [r["kernel_ms"]["median"] for r in sel],
                  marks.get(a, ".") + {"fragment": "-", "tiled": "--"}.get(d, ":"),
                  label=variant_name({"dispatch": d, "accel": a, "lit": lit}),
                  alpha=1.0 if lit else 0.55)
    ax.set_xlabel("spheres")
    ax.set_ylabel("kernel ms per frame (median)")
    what = "opaque spheres" if rows and rows[0].get("opaque") else "molten glass"
    ax.set_title(f"{what} {width}x{height}, 1 spp\n{dev.name}", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    sys.exit(main())
