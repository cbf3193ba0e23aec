"""Volume rendering speed on real VDB files, and the speed-up of empty-space skipping
over plain marching at equal image.

    .venv/bin/python bench/volume.py [--device SPEC] [--size 640x480] [--repeat 3]
        [FILE.vdb|FILE.npz ...]

Writes bench/results/volume_<device>.json and .png. Without files it uses the real
files in ../shared/data/vdb (or their converted .npz beside them in bench/data/).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import RESULTS, device_info, device_tag, stats, write_json  # noqa: E402
from volrender import camera, device, vdb  # noqa: E402
from volrender.lights import Sun  # noqa: E402
from volrender.render import VolumeSettings, render_volume  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data" / "vdb"
# density scale per file, chosen so optical depths are cloud-like (see README)
SCALES = {"smoke": 1.0, "wdas_cloud_sixteenth": 0.05, "dragon_with_xform": 1.0,
          "fluid_data_0190": 1.0}


def default_files():
    names = ["smoke", "wdas_cloud_sixteenth", "dragon_with_xform"]
    found = []
    for n in names:
        for cand in (SHARED / f"{n}.vdb", ROOT / "bench" / "data" / f"{n}.npz"):
            if cand.exists():
                found.append(cand)
                break
    return found


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
    return vdb.Bricks.from_dense(dense, m, name="sparse_pair")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="*", type=Path)
    ap.add_argument("--device", default=None)
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--tag", default=None, help="results file suffix (default: from the device)")
    args = ap.parse_args(argv)
    width, height = (int(v) for v in args.size.split("x"))
    dev = device.get(args.device)
    files = args.files or default_files()
    if not files:
        sys.exit("bench/volume.py: no input files (../shared/data/vdb not found)")
    sun = Sun((-0.6, -1.0, -0.5), 6.0)
    rows = []
    for path in [*files, None]:
        stem = path.stem if path else "sparse_pair (synthetic)"
        b = vdb.load_volume(path) if path else sparse_pair()
        cam = camera.frame_bounds(*b.world_bounds(), width, height)
        if path is None:          # end-on view down the long axis
            cam = camera.Camera((-15.0, 1.2, 1.4), (31.0, 1.2, 1.2), (0, 1, 0), 10.0, width, height)
        row = {"file": path.name if path else stem, "density_scale": SCALES.get(stem, 1.0), "dims": b.dims.tolist(),
               "bricks_stored": int(b.n_slots), "bricks_total": int(np.prod(b.dims)),
               "voxel_size": b.voxel_size}
        images = {}
        for skip in (True, False):
            s = VolumeSettings(density_scale=row["density_scale"], skip_empty=skip)
            render_volume(b, cam, [sun], s, dev)                       # warm-up (and build)
            kernel, wall = [], []
            for _ in range(args.repeat):
                r = render_volume(b, cam, [sun], s, dev)
                kernel.append(r["kernel_ms"])
                wall.append(r["wall_ms"])
            key = "skip" if skip else "plain"
            row[key] = {"kernel_ms": stats(kernel), "wall_ms": stats(wall)}
            images[key] = r["rgba"]
        diff = np.abs(images["skip"] - images["plain"])
        row["max_abs_diff"] = float(diff.max())
        row["peak_value"] = float(images["plain"].max())
        row["speedup"] = row["plain"]["kernel_ms"]["median"] / row["skip"]["kernel_ms"]["median"]
        print(f"{row['file']:28s} skip {row['skip']['kernel_ms']['median']:9.1f} ms  "
              f"plain {row['plain']['kernel_ms']['median']:9.1f} ms  x{row['speedup']:.2f}  "
              f"max|diff| {row['max_abs_diff']:.2e}  bricks {row['bricks_stored']}/{row['bricks_total']}",
              flush=True)
        rows.append(row)
    tag = args.tag or device_tag(dev)
    out = write_json(RESULTS / f"volume_{tag}.json",
                     {"benchmark": "volume", "size": [width, height], "spp": 1, "step_voxels": 0.5,
                      "shadow_step_voxels": 1.0, "lights": "1 sun, shadows on", "repeat": args.repeat,
                      **device_info(dev), "results": rows})
    plot(rows, dev, out.with_suffix(".png"), width, height)
    print(f"wrote {out}")


def plot(rows, dev, path, width, height):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 3.5))
    x = np.arange(len(rows))
    for off, key, label in ((-0.2, "skip", "empty-space skipping"), (0.2, "plain", "plain marching")):
        med = [r[key]["kernel_ms"]["median"] for r in rows]
        lo = [m - r[key]["kernel_ms"]["min"] for m, r in zip(med, rows)]
        hi = [r[key]["kernel_ms"]["max"] - m for m, r in zip(med, rows)]
        ax.bar(x + off, med, 0.4, yerr=[lo, hi], label=label)
    ax.set_xticks(x, [r["file"].rsplit(".", 1)[0] for r in rows])
    ax.set_ylabel("kernel ms per frame")
    ax.set_title(f"{width}x{height}, 1 spp, 1 sun with shadows\n{dev.name}", fontsize=9)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
