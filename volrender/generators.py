"""Seeded point-cloud generators (GENERATOR:COUNT inputs): blob, uniform_box, glass_gather."""
from __future__ import annotations

import math

import numpy as np

from .cloud import PointCloud
from .errors import UserError

#
# Each generator fills a fixed region of about unit size with n points and gives
# every point a radius proportional to the local mean spacing (V/n)^(1/3), so the
# number of overlapping neighbours per sphere stays about the same as n grows.

def _check_n(n, seed):
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise UserError(f"point count must be a positive integer, got {n!r}",
                        fix="pass n >= 1")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise UserError(f"seed must be an integer, got {seed!r}", fix="pass an int seed")
    # numpy refuses negative seeds; --seed -1 is accepted for volumes, so fold it into
    # 64 bits here too (non-negative seeds are unchanged)
    return int(n), np.random.default_rng(int(seed) % (1 << 64) if seed < 0 else int(seed))


def _in_ball(rng, n):
    d = rng.normal(size=(n, 3))
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    return d * rng.random(n)[:, None] ** (1.0 / 3.0)


def _jittered(rng, n, base):
    return base * rng.uniform(0.8, 1.2, n)


def blob(n: int, seed: int = 0) -> PointCloud:
    """Dense, slightly squashed ball of radius ~1; spheres overlap ~10 neighbours."""
    n, rng = _check_n(n, seed)
    p = _in_ball(rng, n) * np.array([1.0, 0.85, 0.95])
    spacing = (4.0 / 3.0 * math.pi * 0.85 * 0.95 / n) ** (1.0 / 3.0)
    return PointCloud(p, _jittered(rng, n, 0.7 * spacing), None,
                      f"blob(n={n}, seed={seed})")


def uniform_box(n: int, seed: int = 0) -> PointCloud:
    """Uniform points in the cube [-1, 1]^3; sparser overlap (~4 neighbours)."""
    n, rng = _check_n(n, seed)
    p = rng.uniform(-1.0, 1.0, size=(n, 3))
    spacing = (8.0 / n) ** (1.0 / 3.0)
    return PointCloud(p, np.full(n, 0.5 * spacing), None,
                      f"uniform_box(n={n}, seed={seed})")


# The gather: a drop of glass hanging from the tip of a blowpipe, stretched
# downwards and a little forward; neck at the tip, bulb near the bottom.
_PIPE_START = np.array([-1.9, 0.75, 0.0])
_PIPE_TIP = np.array([-0.15, 0.55, 0.0])
_PIPE_RADIUS = 0.05
_DROP_AXIS_END = np.array([0.1, -0.95, 0.05])
_DROP_BULB = 0.55   # bulb radius
_DROP_NECK = 0.08   # radius where the drop meets the pipe


def _drop_profile(t):
    """Radius of the drop at t in [0,1] along its axis (0 = pipe tip)."""
    a, b = 1.3, 0.5
    peak = (a / (a + b)) ** a * (b / (a + b)) ** b
    return np.maximum(_DROP_NECK * (1 - t) ** 0.5, _DROP_BULB * t ** a * (1 - t) ** b / peak)


def glass_gather(n: int, seed: int = 0) -> PointCloud:
    """A gather of molten glass on a blowpipe: a drop hanging from a line of points.

    The pipe is a straight line of up to 40 evenly spaced spheres of fixed radius
    0.05 (fewer for tiny n); the rest fill a drop-shaped volume (narrow neck at
    the pipe tip, bulb near the bottom) that sags under gravity (-y).
    """
    n, rng = _check_n(n, seed)
    n_pipe = min(40, n // 5)
    n_drop = n - n_pipe
    axis = _DROP_AXIS_END - _PIPE_TIP
    length = float(np.linalg.norm(axis))
    axis /= length
    u = np.cross(axis, [0.0, 0.0, 1.0])
    u /= np.linalg.norm(u)
    w = np.cross(axis, u)
    pts = np.empty((0, 3))
    while len(pts) < n_drop:           # rejection sampling in the bounding cylinder
        m = 2 * (n_drop - len(pts)) + 16
        t = rng.random(m)
        q = rng.uniform(-1.0, 1.0, size=(m, 2)) * _DROP_BULB
        ok = np.hypot(q[:, 0], q[:, 1]) <= _drop_profile(t)
        t, q = t[ok], q[ok]
        new = _PIPE_TIP + (t * length)[:, None] * axis + q[:, :1] * u + q[:, 1:] * w
        pts = np.concatenate([pts, new])
    pts = pts[:n_drop]
    tt = np.linspace(0.0, 1.0, 2001)
    trapezoid = getattr(np, "trapezoid", None) or np.trapz       # numpy 2 renamed it
    volume = float(trapezoid(math.pi * _drop_profile(tt) ** 2, tt * length))
    radii = _jittered(rng, n_drop, 0.7 * (volume / max(n_drop, 1)) ** (1.0 / 3.0))
    if n_pipe:
        s = np.linspace(0.0, 1.0, n_pipe)[:, None]
        pipe = _PIPE_START + s * (_PIPE_TIP - _PIPE_START)
        pts = np.concatenate([pipe, pts])
        radii = np.concatenate([np.full(n_pipe, _PIPE_RADIUS), radii])
    return PointCloud(pts, radii, None, f"glass_gather(n={n}, seed={seed})")


GENERATORS = {"blob": blob, "uniform_box": uniform_box, "glass_gather": glass_gather}


def generate(name: str, n: int, seed: int = 0) -> PointCloud:
    """Run the generator called ``name`` (see GENERATORS)."""
    if name not in GENERATORS:
        raise UserError(f"unknown point generator '{name}'",
                        fix=f"choose one of: {', '.join(GENERATORS)}")
    return GENERATORS[name](n, seed)
