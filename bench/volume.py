"""Volume rendering speed on real VDB files: the speed-up of empty-space skipping over
plain marching, the fragment vs tiled dispatch (issue #4), each at equal image; the cost
of the multiple-scattering octaves and of the path estimator (issue #12).

    .venv/bin/python bench/volume.py [--device SPEC] [--size 640x480] [--repeat 3]
        [--tiles 8x8,16x16] [--no-dispatch] [--octaves 2,4] [--path-spp 1]
        [--no-synthetic] [FILE.vdb|FILE.npz ...]

Per file it renders, with one sun and shadows: fragment dispatch with skipping ("skip"),
fragment without ("plain"), and unless --no-dispatch fragment with the driver's local
size ("driver"; volrender launches 8x8 blocks) and tiled dispatch (skipping,
tile-frustum culling of the occupied bricks) for each tile size. --octaves N,...: the
marcher with N multiple-scattering octaves ("octaves_N", default scales), timed against
"skip" (single scattering). --path-spp N: the path estimator at its default depth with N
samples per pixel ("path"). The configurations run interleaved, one round per repeat,
so load from other processes spreads over all of them; on a CPU device the process CPU
time of each render is recorded beside the kernel (wall) time, since it is far less
disturbed by a shared machine. Also records, per tile size, how many occupied bricks
the tiles' local lists hold and how many tiles overflow.

Writes bench/results/volume_<device>.json and .png. Without files it uses the five real
files in $VOLRENDER_SHARED_DATA/vdb or ../shared/data/vdb (or their .npz conversions in
bench/data/, e.g. `volrender convert ../shared/data/vdb/smoke.vdb bench/data/smoke.npz`).
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import (render_volume, result_path, device_info, find_volume, missing_data,  # noqa: E402
                          stats, tile_lists, write_json)
from volrender import camera, device, features, vdb  # noqa: E402
from volrender.bricks import Bricks  # noqa: E402
from volrender.dispatch import is_gpu, parse_tile  # noqa: E402
from volrender.lights import Sun  # noqa: E402
from volrender.volume import VolumeSettings  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
# density scale per file, chosen so optical depths are cloud-like (see README)
SCALES = {"smoke": 1.0, "wdas_cloud_sixteenth": 0.05, "dragon_with_xform": 1.0,
          "fluid_data_0190": 1.0, "fluid_data_0056": 200.0}
FILES = ["smoke", "wdas_cloud_sixteenth", "dragon_with_xform", "fluid_data_0190", "fluid_data_0056"]


def default_files():
    return [p for p in (find_volume(n) for n in FILES) if p is not None]


def sparse_pair():
    """Synthetic sparse case: two soft blobs (radius 12 voxels) 600 voxels apart, seen
    end-on, so most of every ray crosses empty bricks."""
    n = 24
    i = np.indices((n, n, n)).astype(np.float64) - (n - 1) / 2
    blob = np.clip(1.0 - np.sqrt((i ** 2).sum(0)) / 12.0, 0.0, None).astype(np.float32)
    dense = np.zeros((624, n, n), np.float32)
    dense[:n] = blob
    dense[-n:] = blob
    m = np.diag([0.1, 0.1, 0.1, 1.0])
    return Bricks.from_dense(dense, m, name="sparse_pair")


def tile_list_stats(dev, b, cam, tile) -> dict:
    """Occupied bricks per tile list (the frustum test without padding, one launch)."""
    cap = features.VOLUME_TILE_CAP
    counts = tile_lists(dev, b, cam, tuple(tile), cap, lists=False)[0].ravel()
    seen = counts[counts > 0]
    return {"tiles": int(counts.size), "tiles_with_bricks": int(seen.size),
            "bricks_per_list_mean": float(seen.mean()) if seen.size else 0.0,
            "bricks_per_list_max": int(counts.max()), "capacity": cap,
            "tiles_overflowed": int((counts > cap).sum())}


def timed(b, cam, lights, s, dev, cpu: bool):
    t = time.process_time()
    r = render_volume(b, cam, lights, s, dev)
    if cpu:
        r = dataclasses.replace(r, cpu_ms=1e3 * (time.process_time() - t))
    return r


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="*", type=Path,
                    help="volume files (default: smoke, wdas_cloud_sixteenth, dragon_with_xform from the shared data)")
    ap.add_argument("--device", default=None, help="OpenCL device (default: PoCL)")
    ap.add_argument("--size", default="640x480", help="image size WxH (default: 640x480)")
    ap.add_argument("--repeat", type=int, default=3, help="timed renders per variant (default: 3)")
    ap.add_argument("--tiles", default="8x8,16x16", help="tile sizes for the tiled dispatch")
    ap.add_argument("--no-dispatch", action="store_true", help="skip the driver/tiled configs")
    ap.add_argument("--octaves", default="", help="octave counts to time against single scattering")
    ap.add_argument("--path-spp", type=int, default=0, help="also time the path estimator at N spp")
    ap.add_argument("--no-synthetic", action="store_true", help="leave out the synthetic sparse pair")
    ap.add_argument("--tag", default=None, help="added to the results' name: volume_<device>-<tag>.json")
    args = ap.parse_args(argv)
    width, height = (int(v) for v in args.size.split("x"))
    tiles = [] if args.no_dispatch else [parse_tile(t) for t in args.tiles.split(",") if t]
    octaves = [int(v) for v in args.octaves.split(",") if v]
    dev = device.get(args.device)
    cpu = not is_gpu(dev)
    files = args.files or default_files()
    if not files:
        sys.exit(f"bench/volume.py: {missing_data('smoke.vdb, wdas_cloud_sixteenth.vdb, dragon_with_xform.vdb')}")
    sun = Sun((-0.6, -1.0, -0.5), 6.0)
    rows = []
    load_start = os.getloadavg()
    for path in [*files] + ([] if args.no_synthetic else [None]):
        stem = path.stem if path else "sparse_pair (synthetic)"
        b = vdb.load_volume(path) if path else sparse_pair()
        cam = camera.frame_bounds(*b.world_bounds(), width, height)
        if path is None:          # end-on view down the long axis
            cam = camera.Camera((-15.0, 1.2, 1.4), (31.0, 1.2, 1.2), (0, 1, 0), 10.0, width, height)
        row = {"file": path.name if path else stem, "density_scale": SCALES.get(stem, 1.0), "dims": b.dims.tolist(),
               "bricks_stored": int(b.n_slots), "bricks_total": int(np.prod(b.dims)),
               "voxel_size": b.voxel_size}
        scale = row["density_scale"]
        configs = {"skip": VolumeSettings(density_scale=scale),
                   "plain": VolumeSettings(density_scale=scale, skip_empty=False),
                   # the two ways of crossing empty bricks (the default picks one per device)
                   "skip_runs": VolumeSettings(density_scale=scale, skip_runs=True),
                   "skip_bricks": VolumeSettings(density_scale=scale, skip_runs=False)}
        if not args.no_dispatch:
            configs["driver"] = VolumeSettings(density_scale=scale, dispatch="fragment-driver")
        for n in octaves:
            configs[f"octaves_{n}"] = VolumeSettings(density_scale=scale, ms_octaves=n)
        if args.path_spp:
            configs["path"] = VolumeSettings(density_scale=scale, estimator="path", spp=args.path_spp)
        for tw, th in tiles:
            configs[f"tiled_{tw}x{th}"] = VolumeSettings(density_scale=scale, dispatch="tiled",
                                                         tile=(tw, th))
        runs = {k: {"kernel_ms": [], "wall_ms": [], "cpu_ms": []} for k in configs}
        images = {}
        for key, s in configs.items():
            images[key] = render_volume(b, cam, [sun], s, dev).rgba   # warm-up (and build)
        for _ in range(args.repeat):          # interleaved: one round of every config
            for key, s in configs.items():
                r = timed(b, cam, [sun], s, dev, cpu)
                for m in runs[key]:
                    runs[key][m].append(getattr(r, m))
                images[key] = r.rgba
        for key in configs:
            row[key] = {m: stats(v) for m, v in runs[key].items() if v}
        diff = np.abs(images["skip"] - images["plain"])
        row["max_abs_diff"] = float(diff.max())
        row["peak_value"] = float(images["plain"].max())
        row["speedup"] = row["plain"]["kernel_ms"]["median"] / row["skip"]["kernel_ms"]["median"]
        if cpu:
            row["speedup_cpu"] = row["plain"]["cpu_ms"]["median"] / row["skip"]["cpu_ms"]["median"]
        row["runs_vs_bricks"] = row["skip_bricks"]["kernel_ms"]["median"] / row["skip_runs"]["kernel_ms"]["median"]
        row["skip_identical"] = all(bool((images[k] == images["plain"]).all())
                                    for k in ("skip", "skip_runs", "skip_bricks"))
        extra = (f"  runs {row['skip_runs']['kernel_ms']['median']:.1f} / bricks "
                 f"{row['skip_bricks']['kernel_ms']['median']:.1f} ms (runs x{row['runs_vs_bricks']:.2f})")
        if "driver" in row:       # fragment in 8x8 blocks vs the driver's local size (> 1: blocks faster)
            row["blocks_vs_driver"] = row["driver"]["kernel_ms"]["median"] / row["skip"]["kernel_ms"]["median"]
            extra += f"  driver-local {row['driver']['kernel_ms']['median']:9.1f} ms"
        print(f"{row['file']:28s} skip {row['skip']['kernel_ms']['median']:9.1f} ms  "
              f"plain {row['plain']['kernel_ms']['median']:9.1f} ms  x{row['speedup']:.2f}"
              + (f" (cpu x{row['speedup_cpu']:.2f})" if cpu else "") + extra +
              f"  max|diff| {row['max_abs_diff']:.2e}  bricks {row['bricks_stored']}/{row['bricks_total']}",
              flush=True)
        for n in octaves:         # octave cost over single scattering (< 2: the issue's target)
            key = f"octaves_{n}"
            row[f"{key}_cost"] = row[key]["kernel_ms"]["median"] / row["skip"]["kernel_ms"]["median"]
            row[f"{key}_mean_gain"] = float(images[key][..., :3].mean() / max(images["skip"][..., :3].mean(), 1e-30))
            print(f"{'':28s} {n} octaves: {row[key]['kernel_ms']['median']:9.1f} ms  x{row[f'{key}_cost']:.2f} "
                  f"single scattering; image mean x{row[f'{key}_mean_gain']:.2f}", flush=True)
        if "path" in configs:
            row["path_cost"] = row["path"]["kernel_ms"]["median"] / row["skip"]["kernel_ms"]["median"]
            print(f"{'':28s} path {args.path_spp} spp: {row['path']['kernel_ms']['median']:9.1f} ms  "
                  f"x{row['path_cost']:.2f} the single-scattering march", flush=True)
        # fragment ("skip") vs tiled, same image
        row["dispatch"] = {}
        for tw, th in tiles:
            key = f"tiled_{tw}x{th}"
            d = {"tile": [tw, th], "max_abs_diff": float(np.abs(images[key] - images["skip"]).max()),
                 "ratio": row["skip"]["kernel_ms"]["median"] / row[key]["kernel_ms"]["median"],
                 "lists": tile_list_stats(dev, b, cam, (tw, th))}
            if cpu:
                d["ratio_cpu"] = row["skip"]["cpu_ms"]["median"] / row[key]["cpu_ms"]["median"]
            row["dispatch"][key] = d
            extra = f"  (cpu x{d['ratio_cpu']:.2f})" if cpu else ""
            print(f"{'':28s} tiled {tw}x{th}: {row[key]['kernel_ms']['median']:9.1f} ms  "
                  f"fragment/tiled x{d['ratio']:.2f}{extra}  max|diff| {d['max_abs_diff']:.2e}  "
                  f"list mean {d['lists']['bricks_per_list_mean']:.1f} max "
                  f"{d['lists']['bricks_per_list_max']}  overflowed {d['lists']['tiles_overflowed']}"
                  f"/{d['lists']['tiles']}", flush=True)
        rows.append(row)
    out = write_json(result_path("volume", dev, args.tag),
                     {"benchmark": "volume", "size": [width, height], "spp": 1, "step_voxels": 0.5,
                      "shadow_step_voxels": 1.0, "lights": "1 sun, shadows on", "repeat": args.repeat,
                      "tiles": [list(t) for t in tiles], "tile_capacity": features.VOLUME_TILE_CAP,
                      "octaves": octaves, "path_spp": args.path_spp,
                      "timing": "configs interleaved per repeat; kernel_ms from OpenCL events (wall), "
                                "cpu_ms = process CPU time per render (CPU devices only)",
                      "load_avg_1min": {"start": load_start[0], "end": os.getloadavg()[0],
                                        "cpus": os.cpu_count()},
                      **device_info(dev), "results": rows})
    note = "" if not cpu else (f", load avg {load_start[0]:.1f}-{os.getloadavg()[0]:.1f} "
                                f"on {os.cpu_count()} CPUs")
    plot(rows, dev, out.with_suffix(".png"), width, height, tiles, note)
    print(f"wrote {out}")


def plot(rows, dev, path, width, height, tiles=(), note=""):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    keys = [("skip", "fragment, empty-space skipping"), ("plain", "fragment, plain marching")]
    keys += [(f"tiled_{tw}x{th}", f"tiled {tw}x{th}, skipping + tile culling") for tw, th in tiles]
    keys += [(k, k.replace("_", " ") + " (marcher)") for k in rows[0] if k.startswith("octaves_")
             and not k.endswith(("_cost", "_gain"))]
    keys += [("path", "path estimator")] if "path" in rows[0] else []
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 4.2), gridspec_kw={"width_ratios": [2, 1]})
    x = np.arange(len(rows))
    w = 0.8 / len(keys)
    for i, (key, label) in enumerate(keys):
        med = [r[key]["kernel_ms"]["median"] for r in rows]
        lo = [m - r[key]["kernel_ms"]["min"] for m, r in zip(med, rows)]
        hi = [r[key]["kernel_ms"]["max"] - m for m, r in zip(med, rows)]
        ax.bar(x + (i - (len(keys) - 1) / 2) * w, med, w, yerr=[lo, hi], label=label)
    names = [r["file"].rsplit(".", 1)[0].replace(" (synthetic)", "").replace("_", "_\n", 1)
             for r in rows]
    ax.set_xticks(x, names, fontsize=8)
    ax.set_ylabel("kernel ms per frame (median, min-max)")
    ax.set_yscale("log")
    ax.legend(fontsize=7)
    ax.set_title(f"{width}x{height}, 1 spp, 1 sun with shadows\n{dev.name}{note}", fontsize=9)
    # ratios: > 1 = the variant is that much faster than the reference configuration
    ratios = [("skipping: plain / skip", [r["speedup"] for r in rows])]
    if "speedup_cpu" in rows[0]:
        ratios.append(("skipping, CPU time", [r["speedup_cpu"] for r in rows]))
    ratios += [(f"tiled {tw}x{th}: fragment / tiled", [r["dispatch"][f"tiled_{tw}x{th}"]["ratio"] for r in rows])
               for tw, th in tiles]
    ratios += [(f"{k[:-5].replace('_', ' ')}: single / octaves", [1 / r[k] for r in rows])
               for k in rows[0] if k.startswith("octaves_") and k.endswith("_cost")]
    w2 = 0.8 / len(ratios)
    for i, (label, vals) in enumerate(ratios):
        ax2.bar(x + (i - (len(ratios) - 1) / 2) * w2, vals, w2, label=label)
    ax2.axhline(1.0, color="grey", lw=0.8)
    ax2.set_ylim(0.0, max(1.4, 1.2 * max(max(v) for _, v in ratios)))
    ax2.set_xticks(x, names, fontsize=8)
    ax2.set_ylabel("time ratio (> 1: the variant is faster)")
    ax2.set_title("same image: skipping, tiling; octaves: their cost", fontsize=9)
    ax2.legend(fontsize=6, loc="upper center", ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
