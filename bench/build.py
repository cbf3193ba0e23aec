"""Acceleration build time against sphere count: the partition tree (on the device on
GPUs, tree_device.py; numpy on CPUs) and the support cells (cl/build_cells.cl, everything
between levels on the device), with the cells' time split into the build's kernels
(profiling events) and the rest (host work, transfers, launch overhead).

    .venv/bin/python bench/build.py [--device SPEC] [--counts 1000,...] [--size 1920x1080]
        [--repeat 3] [--tag TAG]

--size sets the pixel samples that choose the automatic cell edge (cells.choose_edge on
CPUs; GPUs grow it to cells.GPU_CELLS), as a render of that size would have them. Writes bench/results/build_<device>[-TAG].json and .png.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench.common import device_info, result_path, write_json  # noqa: E402
from volrender import device, generators, glass, spheres  # noqa: E402

COUNTS = [1000, 10000, 100000, 1000000]


def measure(cloud, dev, width, height, repeat):
    """Medians over repeat builds after an untimed one (it compiles the builder for this
    tree depth): total, tree, cells, cells' kernels; the last build's stats."""
    samples = width * height
    spheres.pack_scene(cloud, glass.GlassSettings(accel="grid"), device=dev, samples=samples)
    runs = {"total_ms": [], "tree_ms": [], "cells_ms": [], "kernel_ms": [], "host_ms": []}
    stats = {}
    for _ in range(repeat):
        t0 = time.perf_counter()
        packed = spheres.pack_scene(cloud, glass.GlassSettings(accel="grid"), device=dev,
                                  samples=samples)
        total = 1e3 * (time.perf_counter() - t0)
        if packed.cells is None:
            return {"accel_used": packed.accel, "note": packed.note}
        stats = packed.cells.stats()
        runs["total_ms"].append(total)
        runs["tree_ms"].append(packed.tree_ms)
        runs["cells_ms"].append(stats["build_ms"])
        runs["kernel_ms"].append(stats["build_kernel_ms"])
        runs["host_ms"].append(stats["build_ms"] - stats["build_kernel_ms"])
    row = {k: statistics.median(v) for k, v in runs.items()}
    row["runs"] = runs
    row["cells"] = stats
    row["bytes_per_sphere"] = stats["bytes"] / len(cloud.centers)
    row["accel_used"] = "grid"
    return row


def plot(rows, dev, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rows = [r for r in rows if "cells_ms" in r]
    fig, ax = plt.subplots(figsize=(6, 4))
    n = [r["n"] for r in rows]
    for key, label in (("tree_ms", "tree (host)"), ("kernel_ms", "cells: kernels"),
                       ("host_ms", "cells: host and transfers"), ("total_ms", "total")):
        ax.loglog(n, [r[key] for r in rows], "o-", label=label)
    ax.axhline(500, color="k", lw=0.8, ls=":", label="0.5 s")
    ax.set_xlabel("spheres")
    ax.set_ylabel("build ms (median)")
    ax.set_title(f"acceleration build\n{dev.name}", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="volrender bench build", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default=None, help="OpenCL device (default: PoCL)")
    ap.add_argument("--counts", default=",".join(map(str, COUNTS)),
                    help="sphere counts, comma-separated (default: 1000 ... 1000000)")
    ap.add_argument("--size", default="1920x1080",
                    help="image size WxH whose pixel count sets the cell budget (default: 1920x1080)")
    ap.add_argument("--repeat", type=int, default=3, help="builds per count (default: 3)")
    ap.add_argument("--tag", default=None, help="added to the results' name: build_<device>-<tag>.json")
    ap.add_argument("--profile", type=int, default=0, metavar="N",
                    help="also print cProfile's top 25 functions of one build of N spheres")
    args = ap.parse_args(argv)
    counts = [int(v) for v in args.counts.split(",") if v]
    width, height = (int(v) for v in args.size.lower().split("x"))
    dev = device.get(args.device)
    path = result_path("build", dev, args.tag)
    rows = []
    for n in counts:
        row = {"n": n, **measure(generators.blob(n, seed=1), dev, width, height, args.repeat)}
        rows.append(row)
        if "cells_ms" in row:
            c = row["cells"]
            print(f"{n:>9} total {row['total_ms']:8.0f} ms  tree {row['tree_ms']:7.0f}  cells "
                  f"{row['cells_ms']:7.0f} (kernels {row['kernel_ms']:7.0f}, "
                  f"{c['build_launches']} launches)  edge {c['cell']:.3g}  "
                  f"{row['bytes_per_sphere']:.0f} B/sphere", flush=True)
        else:
            print(f"{n:>9} {row['note']}", flush=True)
        write_json(path, {"benchmark": "build", "size": [width, height],
                          "repeat": args.repeat, **device_info(dev), "rows": rows})
    plot(rows, dev, path.with_suffix(".png"))
    if args.profile:
        import cProfile
        import pstats
        cloud = generators.blob(args.profile, seed=1)
        prof = cProfile.Profile()
        prof.enable()
        spheres.pack_scene(cloud, glass.GlassSettings(accel="grid"), device=dev,
                         samples=width * height)
        prof.disable()
        pstats.Stats(prof).sort_stats("tottime").print_stats(25)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
