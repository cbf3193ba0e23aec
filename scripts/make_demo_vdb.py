"""Write scenes/demo_cloud.vdb: a small procedural cloud (seeded, numpy only).

    .venv/bin/python scripts/make_demo_vdb.py [OUTPUT]

A few blended Gaussian blobs, eroded by fractal value noise, with a soft edge.
Float grid 'density' (fog volume), values 0..1, voxel size 0.05, stored as half floats.
"""
import sys
from pathlib import Path

import numpy as np

SHAPE = (80, 56, 72)          # voxels (x, y, z)
VOXEL = 0.05
TRANSLATION = (0.3, 1.2, -0.2)  # world position of index (0, 0, 0)
SEED = 7


def value_noise(shape, cell, rng):
    """Random values on a lattice every `cell` voxels, smoothstep-interpolated."""
    out = rng.random([s // cell + 2 for s in shape])
    for axis, n in enumerate(shape):
        c = np.arange(n) / cell
        i = np.floor(c).astype(int)
        t = c - i
        t = (t * t * (3 - 2 * t)).reshape([-1 if a == axis else 1 for a in range(3)])
        a, b = np.take(out, i, axis=axis), np.take(out, i + 1, axis=axis)
        out = a + (b - a) * t
    return out


def fbm(shape, rng, cells=(16, 8, 4, 2)):
    total, norm = np.zeros(shape), 0.0
    for octave, cell in enumerate(cells):
        amp = 0.5 ** octave
        total += amp * value_noise(shape, cell, rng)
        norm += amp
    return total / norm


def cloud(rng):
    x, y, z = np.meshgrid(*[np.arange(n, dtype=np.float64) for n in SHAPE], indexing="ij")
    blobs = [  # centre (voxels), radius (voxels)
        ((40, 24, 36), 20), ((22, 20, 32), 15), ((58, 20, 40), 15), ((40, 34, 28), 14),
        ((30, 32, 46), 12), ((52, 33, 26), 12), ((14, 17, 40), 9), ((66, 18, 30), 9),
    ]
    field = np.zeros(SHAPE)
    for (cx, cy, cz), r in blobs:
        field += np.exp(-2.0 * ((x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2) / r ** 2)
    field *= np.clip((y - 5) / 8, 0, 1)                  # flatter base
    edge = (field - 0.5) + 1.2 * (fbm(SHAPE, rng, cells=(12, 6, 3, 2)) - 0.5)  # eroded edges
    edge = np.clip(edge * 4.0, 0, 1)
    edge = edge * edge * (3 - 2 * edge)                   # soft falloff
    inner = 0.35 + 0.65 * fbm(SHAPE, rng, cells=(8, 4, 2)) # wispy interior
    v = edge * inner
    v[v < 0.01] = 0
    return v.astype(np.float32)


def main(out):
    import pyopenvdb as vdb
    v = cloud(np.random.default_rng(SEED))
    grid = vdb.FloatGrid()
    grid.copyFromArray(v, ijk=(-SHAPE[0] // 2, 0, -SHAPE[2] // 2))
    grid.name = "density"
    grid.gridClass = vdb.GridClass.FOG_VOLUME
    grid.transform = vdb.createLinearTransform(voxelSize=VOXEL)
    grid.transform.translate(TRANSLATION)
    grid.saveFloatAsHalf = True
    out.parent.mkdir(parents=True, exist_ok=True)
    vdb.write(str(out), grids=[grid], metadata={"creator": "volrender make_demo_vdb.py"})
    print(f"wrote {out}: {grid.activeVoxelCount()} active voxels, "
          f"max {v.max():.3f}, {out.stat().st_size} bytes")


if __name__ == "__main__":
    root = Path(__file__).resolve().parents[1]
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else root / "scenes" / "demo_cloud.vdb")
