"""Numpy oracles for tests and benchmarks: phase functions and closed forms."""
from __future__ import annotations

import numpy as np


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
