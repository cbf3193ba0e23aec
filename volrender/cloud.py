"""A point cloud: sphere centres with optional per-point radii and colours, and the checks
every reader applies to what it read (volrender/points.py, volrender/ply.py)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import UserError
from .files import check_memory

MAX_COORDINATE = 1e18       # |coordinate| accepted from files (spheres.MAX_EXTENT: float32 squares)


MEMORY_FIX = "load a smaller or decimated cloud, or free memory"


@dataclass(frozen=True)
class PointCloud:
    """Sphere centres with optional per-point radius and colour."""

    centers: np.ndarray                 # float64 (N, 3)
    radii: np.ndarray | None = None     # float64 (N,) or None (renderer picks one radius)
    colors: np.ndarray | None = None    # float32 (N, 3) in 0..1, or None
    source: str = ""
    notes: tuple = ()                   # what the reader chose or left out (said to the user)
    up_axis: str | None = None          # the up axis the format defines (LAS: "z"), else None
    up_axis_reason: str = ""

    def __post_init__(self):
        c = np.ascontiguousarray(self.centers, dtype=np.float64)
        if c.ndim != 2 or c.shape[1] != 3:
            raise ValueError(f"centers must be (N, 3), got {c.shape}")
        object.__setattr__(self, "centers", c)
        if self.radii is not None:
            r = np.ascontiguousarray(self.radii, dtype=np.float64)
            if r.shape != (len(c),):
                raise ValueError(f"radii must be ({len(c)},), got {r.shape}")
            object.__setattr__(self, "radii", r)
        if self.colors is not None:
            k = np.ascontiguousarray(self.colors, dtype=np.float32)
            if k.shape != (len(c), 3):
                raise ValueError(f"colors must be ({len(c)}, 3), got {k.shape}")
            object.__setattr__(self, "colors", k)

    def __len__(self) -> int:
        return len(self.centers)


def finish_cloud(path, centers, radii, colors, notes=(), up_axis=None, up_axis_reason="") -> PointCloud:
    n = len(centers)
    if n == 0:
        raise UserError("the file holds zero points", path=path,
                        fix="give a file with at least one point")
    bad = ~np.isfinite(centers).all(axis=1)
    if bad.any():
        raise UserError(f"{int(bad.sum())} of {n} points have NaN/Inf coordinates "
                        f"(first: point {int(np.argmax(bad))})", path=path,
                        fix="remove or repair those points")
    far = np.abs(centers).max(axis=1) > MAX_COORDINATE
    if far.any():
        i = int(np.argmax(far))
        raise UserError(f"{int(far.sum())} of {n} points lie beyond +-{MAX_COORDINATE:g}, "
                        f"where float32 rendering cannot follow (first: point {i}, "
                        f"{tuple(float(v) for v in centers[i])})", path=path,
                        fix="rescale or recentre the cloud")
    if radii is not None:
        bad = ~np.isfinite(radii) | (radii < 0) | (radii > MAX_COORDINATE)
        if bad.any():
            i = int(np.argmax(bad))
            raise UserError(f"{int(bad.sum())} radii are negative, NaN/Inf or above "
                            f"{MAX_COORDINATE:g} (first: point {i}, radius {radii[i]})",
                            path=path, fix=f"radii must be in [0, {MAX_COORDINATE:g}]")
    if colors is not None:
        if not np.isfinite(colors).all() or colors.min() < 0 or colors.max() > 1:
            raise UserError(f"colours outside 0..1 (range {np.nanmin(colors)}.."
                            f"{np.nanmax(colors)})", path=path,
                            fix="store float colours in 0..1, or as uchar 0..255")
    return PointCloud(centers=centers, radii=radii, colors=colors, source=str(path),
                      notes=tuple(notes), up_axis=up_axis, up_axis_reason=up_axis_reason)


CHUNK_LINES = 1 << 16      # text lines parsed at a time


class Projection:
    """Memory check of a reader that parses a stream in chunks: after each chunk the
    memory still to come is projected from what the chunks so far took per byte or row."""

    def __init__(self, path, total):
        self.path, self.total, self.done, self.used = path, total, 0, 0

    def add(self, done, used):
        self.done += done
        self.used += used
        if self.done and self.total > self.done:
            more = self.used * (self.total - self.done) / self.done
            # the chunks still to come, then one copy of everything (np.concatenate)
            check_memory(int(more + self.used + more), self.path, "reading this point cloud",
                         MEMORY_FIX)
