"""Numpy oracles of the tests, in one place: phase functions and closed forms, the smooth
union brute force, and the support cells' construction (cl/build_cells.cl) in float64 over
all spheres, with the host's list builder on the tree (cells.py's measured alternative)."""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from volrender import layout

J = layout.CELL_BOUNDS_J      # sub-intervals of [M, U] in the cells' bounds


def hg(mu, g):
    """Henyey-Greenstein phase, mu = cos(light propagation, scattered direction)."""
    mu = np.asarray(mu, np.float64)
    return (1.0 - g * g) / (4.0 * np.pi * (1.0 + g * g - 2.0 * g * mu) ** 1.5)


def phase(mu, g1, g2, w):
    return w * hg(mu, g1) + (1.0 - w) * hg(mu, g2)


def sphere_chord(origin, dirs, centre, radius):
    """Length of each ray (origin + t*dir, unit dirs, t >= 0) inside a sphere."""
    oc = np.asarray(origin, np.float64) - np.asarray(centre, np.float64)
    b = dirs @ oc
    c = oc @ oc - radius * radius
    disc = b * b - c
    root = np.sqrt(np.maximum(disc, 0.0))
    t0, t1 = np.maximum(-b - root, 0.0), np.maximum(-b + root, 0.0)
    return np.where(disc > 0, t1 - t0, 0.0)


def slab_single_scatter_normal(tau, albedo, p, irradiance):
    """Radiance leaving a slab of optical depth tau along its normal when a sun shines
    in along the same normal from the viewer's side (view and light paths coincide):
    L = albedo p E (1 - exp(-2 tau)) / 2."""
    return albedo * p * irradiance * (1.0 - np.exp(-2.0 * tau)) / 2.0


def smooth_union(x, centers, radii, k):
    """Order-independent smooth union of spheres (cl/sdf.h) at points x (M,3), brute force:
    F = m - (k/2) ln(sum_i h_i^2), h_i = max(0, 1 - (d_i - m)/k), m = min_i d_i."""
    x = np.atleast_2d(np.asarray(x, np.float64))
    c = np.asarray(centers, np.float64)
    r = np.broadcast_to(np.asarray(radii, np.float64), (len(c),))
    d = np.linalg.norm(x[:, None, :] - c[None, :, :], axis=2) - r[None, :]
    m = d.min(axis=1)
    if k <= 1e-20:
        return m
    h = np.maximum(0.0, 1.0 - (d - m[:, None]) / k)
    return m - 0.5 * k * np.log((h * h).sum(axis=1))


# --------------------------------------------------------------------------- support cells

def box_distances(centres, radii, lo, hi):
    """lo_i and hi_i (float64, (M, N)) of N spheres against M boxes [lo, hi] (M, 3)."""
    c = np.asarray(centres, np.float64)[None]
    lo, hi = np.asarray(lo, np.float64)[:, None], np.asarray(hi, np.float64)[:, None]
    g = np.maximum(np.maximum(lo - c, c - hi), 0.0)
    f = np.maximum(np.abs(c - lo), np.abs(c - hi))
    r = np.asarray(radii, np.float64)[None]
    return np.linalg.norm(g, axis=2) - r, np.linalg.norm(f, axis=2) - r


def oracle(centres, radii, blend, lo, hi):
    """The construction of cl/build_cells.cl in float64 over all spheres, for boxes
    [lo, hi] (M, 3): (member (M, N) bool: lo_i <= U + k, lower L (M,), upper UF (M,))."""
    dlo, dhi = box_distances(centres, radii, lo, hi)
    M, U = dlo.min(axis=1), dhi.min(axis=1)
    k = float(blend)
    if k <= layout.BLEND_MIN:
        return dlo <= U[:, None], M, U
    member = dlo <= (U + k)[:, None]
    t = M[:, None] + (U - M)[:, None] * (np.arange(J + 1) / J)[None]
    t[:, J] = U
    lower = np.full(len(M), np.inf)
    upper = np.full(len(M), -np.inf)
    for j in range(J):
        shi = (np.where(member, np.maximum(1 - (dlo - t[:, j + 1, None]) / k, 0), 0) ** 2).sum(1)
        slo = (np.where(member, np.maximum(1 - (dhi - t[:, j, None]) / k, 0), 0) ** 2).sum(1)
        lower = np.minimum(lower, t[:, j] - 0.5 * k * np.log(np.maximum(shi, 1.0)))
        upper = np.maximum(upper, t[:, j + 1] - 0.5 * k * np.log(np.maximum(slo, 1.0)))
    return member, lower, upper


def support(x, centres, radii, blend):
    """Boolean (M, N): sphere i matters at point x (d_i < m + k; the nearest when k = 0)."""
    d = np.linalg.norm(np.asarray(x, np.float64)[:, None] - np.asarray(centres, np.float64)[None],
                       axis=2) - np.asarray(radii, np.float64)[None]
    m = d.min(axis=1, keepdims=True)
    return d < m + blend if blend > layout.BLEND_MIN else d <= m


def host_lists(spheres, tree_lo, tree_hi, start, count, depth, blend, lo, hi):
    """The lists of boxes [lo, hi] (M, 3) on the host: the device builder's sets, by
    vectorised numpy queries on the partition tree (frontiers of (box, node) pairs level by
    level, no Python loop per box or sphere). spheres: (N, 4) in tree order; tree_lo,
    tree_hi, start, count: the tree's node arrays in that frame. Returns (offsets (M + 1,),
    sphere indices) with each box's list ascending; U is exact (the minimum of hi_i over a
    first, looser list whose threshold is the nearest centre's hi)."""
    c = np.asarray(spheres[:, :3], np.float64)
    r = np.asarray(spheres[:, 3], np.float64)
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    k = float(blend) if blend > layout.BLEND_MIN else 0.0
    near = cKDTree(c).query(0.5 * (lo + hi))[1]
    u0 = np.linalg.norm(np.maximum(np.abs(c[near] - lo), np.abs(c[near] - hi)), axis=1) - r[near]

    def query(thr):
        b = np.arange(len(lo))
        node = np.ones(len(lo), np.int64)
        for d in range(depth + 1):
            g = np.maximum(np.maximum(tree_lo[node] - hi[b], lo[b] - tree_hi[node]), 0.0)
            keep = (np.linalg.norm(g, axis=1) <= thr[b]) & (count[node] > 0)
            b, node = b[keep], node[keep]
            if d < depth:
                b, node = np.repeat(b, 2), np.stack([2 * node, 2 * node + 1], 1).ravel()
        n = count[node]
        first = np.repeat(np.cumsum(n) - n, n)
        idx = np.repeat(start[node], n) + np.arange(int(n.sum())) - first
        bb = np.repeat(b, n)
        dlo, dhi = (np.linalg.norm(v, axis=1) - r[idx] for v in (
            np.maximum(np.maximum(lo[bb] - c[idx], c[idx] - hi[bb]), 0.0),
            np.maximum(np.abs(c[idx] - lo[bb]), np.abs(c[idx] - hi[bb]))))
        return bb, idx, dlo, dhi

    bb, idx, dlo, dhi = query(u0 + k)
    keep = dlo <= u0[bb] + k
    u = np.full(len(lo), np.inf)
    np.minimum.at(u, bb[keep], dhi[keep])
    keep &= dlo <= u[bb] + k
    bb, idx = bb[keep], idx[keep]
    o = np.lexsort((idx, bb))
    offsets = np.concatenate([[0], np.cumsum(np.bincount(bb, minlength=len(lo)))])
    return offsets, idx[o]
