"""The fixed directions the light cache's bake marches along (cl/bake_light.cl) and their
quadratures over the sphere: the environment's integral and first moments per direction's
cell (the sky pass), and the cells' solid angles (the scattering orders' gathers)."""
from __future__ import annotations

import functools
import math

import numpy as np

from .environment import env_mode, uniform

ENV_DIRS = 14                  # cl/light_cache.h's fixed environment directions


def env_dirs() -> np.ndarray:
    """The ENV_DIRS fixed world directions (cl/bake_light.cl marches along them): the 6
    axes and the 8 cube diagonals."""
    axes = np.vstack([np.eye(3), -np.eye(3)])
    diag = np.array([(x, y, z) for x in (1, -1) for y in (1, -1) for z in (1, -1)]) / math.sqrt(3)
    return np.vstack([axes, diag])


def env_quadrature(environment, res=(128, 256)) -> np.ndarray:
    """(ENV_DIRS * 5, 4) float32 for cl/bake_light.cl: per direction its world vector,
    then over its cell of the sphere (the directions nearer to it than to any other) the
    environment's integral / 4 pi (rgb) and its first moments / 4 pi (x, y, z: rgb each),
    summed over the map's texels (or a res grid for a uniform environment). With every
    transmittance 1 the bake then gives the map's own L1 projection exactly; a sun disk in
    the map is integrated, never missed between directions."""
    mode = env_mode(environment)
    out = np.zeros((ENV_DIRS, 5, 4), np.float64)
    dirs = env_dirs()
    out[:, 0, :3] = dirs
    if mode == 0:
        return out.reshape(-1, 4).astype(np.float32)
    if mode == 1:
        h, w = res
        rad = np.broadcast_to(np.asarray(environment.uniform, np.float64), (h, w, 3))
    else:
        rad = np.asarray(environment.texels, np.float64)
        h, w = rad.shape[:2]
    theta = (np.arange(h) + 0.5) / h * math.pi
    phi = ((np.arange(w) + 0.5) / w - 0.5) * 2 * math.pi
    st = np.sin(theta)[:, None]
    d = np.stack([st * np.sin(phi)[None], np.broadcast_to(np.cos(theta)[:, None], (h, w)),
                  -st * np.cos(phi)[None]], -1).reshape(-1, 3)     # cl/env.h vr_env_dir
    da = (np.broadcast_to(st, (h, w)) * (math.pi / h) * (2 * math.pi / w)).reshape(-1)
    cell = np.argmax(d @ dirs.T, axis=1)
    lw = rad.reshape(-1, 3) * (da / (4 * math.pi))[:, None]
    for j in range(ENV_DIRS):
        sel = cell == j
        out[j, 1, :3] = lw[sel].sum(0)
        for a in range(3):
            out[j, 2 + a, :3] = (lw[sel] * d[sel, a:a + 1]).sum(0)
    return out.reshape(-1, 4).astype(np.float32)


@functools.lru_cache(maxsize=1)
def ms_dirs() -> np.ndarray:
    """(ENV_DIRS, 4) float32: the fixed directions and their cells' solid angles / 4 pi
    (env_quadrature of a unit sky), for cl/bake_light.cl's ms_gather. Computed once (a
    32k-texel quadrature: ~15 ms of the H200's 25 ms bake at 4-voxel nodes was this);
    read-only."""
    q = env_quadrature(uniform((1.0, 1.0, 1.0))).reshape(ENV_DIRS, 5, 4)
    out = np.zeros((ENV_DIRS, 4), np.float32)
    out[:, :3] = env_dirs()
    out[:, 3] = q[:, 1, 0] / q[:, 1, 0].sum()
    out.flags.writeable = False
    return out
