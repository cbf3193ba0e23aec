"""Small synthetic media made by code (issue 33): for tests and benchmarks that must run
where the real files are absent, and for fitting models over optical depth and albedo.

Every medium is about one world unit across, centred on the origin, with grid values of
order 1 (density_scale then sets sigma_t per world unit, so the optical depth across is
about density_scale).
"""
from __future__ import annotations

import numpy as np

from .bricks import Bricks


def _grid(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(voxel-centre coordinates in [-0.5, 0.5] of shape (3, n, n, n), index-to-world)."""
    voxel = 1.0 / n
    m = np.eye(4)
    m[:3, :3] *= voxel
    m[:3, 3] = -0.5 + 0.5 * voxel
    i = np.indices((n, n, n)) * voxel - 0.5 + 0.5 * voxel
    return i, m


def lumpy_ball(n: int = 24, seed: int = 4) -> Bricks:
    """A ball of radius 0.45 filled with smooth noise (mean 1, +-30 %), soft 1.5 voxels at
    its edge."""
    x, m = _grid(n)
    rng = np.random.default_rng(seed)
    v = rng.random((n, n, n))
    for ax in range(3):
        for _ in range(2):
            v = (np.roll(v, 1, ax) + v + np.roll(v, -1, ax)) / 3
    v = 1.0 + (v - v.mean()) / max(v.std(), 1e-12) * 0.3
    r = np.sqrt((x ** 2).sum(0))
    edge = np.clip((0.45 - r) * n / 1.5, 0.0, 1.0)
    return Bricks.from_dense(np.clip(v * edge, 0, None).astype(np.float32), m)


def two_blobs(n: int = 32) -> Bricks:
    """Two overlapping Gaussian blobs (peak 1), the second smaller and to the side: a
    medium with a thick core and thin fringes, lit and shadowed parts."""
    x, m = _grid(n)
    d1 = ((x[0] + 0.12) ** 2 + x[1] ** 2 + x[2] ** 2) / 0.18 ** 2
    d2 = ((x[0] - 0.22) ** 2 + (x[1] - 0.1) ** 2 + (x[2] + 0.05) ** 2) / 0.12 ** 2
    v = np.exp(-d1) + 0.8 * np.exp(-d2)
    v = np.where(v > 0.01, v, 0.0)
    return Bricks.from_dense(v.astype(np.float32), m)


def fire_ball(n: int = 20, hot: float = 3.0, cold: float = 1.2) -> Bricks:
    """A Mantaflow-like fire: a ball of thin smoke (density 0.05) emitting from a `flame`
    grid (1 inside radius 0.4), its `temperature` grid in Blender's units (x 1000 K) from
    `hot` at the centre to `cold` at the rim."""
    x, m = _grid(n)
    r = np.sqrt((x ** 2).sum(0)) / 0.4
    inside = r < 1.0
    flame = inside.astype(np.float32)
    temp = np.where(inside, hot + (cold - hot) * r, 0.0).astype(np.float32)
    dens = (0.05 * inside).astype(np.float32)
    return Bricks.from_dense(dens, m, emission=flame, temperature=temp)
