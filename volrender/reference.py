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
