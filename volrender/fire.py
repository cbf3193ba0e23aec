"""Fire that glows (issue 33): what a Mantaflow fire cache needs beyond its grids.

* `is_empty(bricks)`: an emission grid that holds only zeros (Mantaflow writes a `flame`
  grid for smoke-only simulations too): the cache is smoke, rendered under the normal sky.
* `exposure(bricks, settings)`: the emission scale that shows a fire. The emission keeps
  its physically based brightness (the blackbody law, blackbody.py: T^4 at 1000 K per
  Mantaflow temperature unit), which is dim at flame temperatures (1500 K: luminance 0.09
  per unit length); like a camera's exposure, one factor brings it into view, chosen from
  the emission's own statistics: the emitted luminance integrated along the grid's voxel
  columns (per axis, the medium's absorption ignored), its EXPOSURE_PERCENTILE-th
  percentile over the columns that emit, on the axis where it is least (the thinnest view
  of the fire; other views come out brighter, never darker), is scaled to EXPOSURE_TARGET.
  It does not depend on the camera, so every frame of a sequence gets the same. The
  hottest columns then sit in the tone curve's shoulder (a
  white-yellow core: 3000 K at luminance 4 is (6.8, 3.5, 1.1), filmic (1.0, 1.0, 0.8)),
  cooler ones below it keep their blackbody red (1500 K is 16x dimmer than 3000 K).
"""
from __future__ import annotations

import math

import numpy as np

from . import blackbody
from .layout import BRICK
from .volume import emission_color

EXPOSURE_PERCENTILE = 99.0
EXPOSURE_TARGET = 4.0        # the percentile column's luminance after the exposure


def is_empty(bricks) -> bool:
    """Whether the volume's emission grid emits nothing (absent, or only zeros)."""
    if bricks.emission is None:
        return True
    if bricks.emission_max is not None:
        return not bool(np.any(np.asarray(bricks.emission_max) > 0))
    return not bool(np.any(np.asarray(bricks.emission) > 0))


def voxel_luminance(bricks, settings) -> np.ndarray:
    """float64 (n, 8, 8, 8): the Rec.709 luminance each brick voxel emits per unit length,
    before emission_scale (the colour, or the blackbody law with a temperature grid)."""
    e = np.asarray(bricks.emission, np.float64)[:, :-1, :-1, :-1]
    if bricks.temperature is None or settings.temperature_grid is None:
        unit = emission_color(settings) / max(settings.emission_scale, 1e-300)
        return e * float(unit @ blackbody.REC709_Y)
    t = settings.temperature_offset + settings.temperature_scale * \
        np.asarray(bricks.temperature, np.float64)[:, :-1, :-1, :-1]
    if settings.blackbody_law:          # luminance 1 colour x INTENSITY_K T^4
        return e * blackbody.INTENSITY_K * np.maximum(t, 0.0) ** 4
    temps = np.geomspace(blackbody.T_MIN, blackbody.T_MAX, 256)
    y = blackbody.rgb(temps) @ blackbody.REC709_Y
    return e * np.interp(np.clip(t, blackbody.T_MIN, blackbody.T_MAX), temps, y)


def column_luminance(bricks, settings, axis: int) -> np.ndarray:
    """The emitted luminance integrated along `axis` (world length: voxel size), one value
    per voxel column of the brick layout: float64 2-D."""
    y = voxel_luminance(bricks, settings).sum(axis=1 + axis) * bricks.voxel_size
    dims = tuple(int(d) for d in bricks.dims)
    slots = np.asarray(bricks.table)
    idx = np.flatnonzero(slots >= 0)
    coords = np.stack(np.unravel_index(idx, dims), axis=1)
    other = [a for a in range(3) if a != axis]
    out = np.zeros((dims[other[0]] * BRICK, dims[other[1]] * BRICK))
    for c, slot in zip(coords, slots[idx]):
        i, j = c[other[0]] * BRICK, c[other[1]] * BRICK
        out[i:i + BRICK, j:j + BRICK] += y[slot]
    return out


def emission_statistic(bricks, settings) -> float:
    """The EXPOSURE_PERCENTILE-th percentile of the emitting columns' luminance, the least
    over the three axes (0 when nothing emits)."""
    if is_empty(bricks):
        return 0.0
    vals = []
    for axis in range(3):
        col = column_luminance(bricks, settings, axis)
        col = col[col > 0]
        if col.size:
            vals.append(float(np.percentile(col, EXPOSURE_PERCENTILE)))
    return float(min(vals)) if vals else 0.0


def exposure(bricks, settings):
    """(emission scale, note): the scale that brings the emission statistic to
    EXPOSURE_TARGET (module docstring); (None, None) when nothing emits."""
    stat = emission_statistic(bricks, settings)
    if not stat > 0 or not math.isfinite(stat):
        return None, None
    scale = EXPOSURE_TARGET / stat
    return scale, (f"fire exposure: emission x{scale:.3g} ({math.log2(scale):+.1f} stops): "
                   f"its brightest columns ({EXPOSURE_PERCENTILE:g}th percentile of the emitted "
                   f"luminance through the grid, least over the axes, {stat:.3g}) to "
                   f"{EXPOSURE_TARGET:g}; "
                   "--emission-scale S sets it")
