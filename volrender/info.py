"""`volrender info FILE`: what a volume file holds, and a density scale to start from."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from . import glass, vdb, vdb_header
from .camera import View
from .errors import UserError, printable
from .points import load_points
from .render import render
from .scene import POINT_SUFFIXES, Scene, VolumeContent
from .spheres import scan_defaults
from .volume import VolumeSettings

TARGET_DEPTH = 2.0      # suggested scale: median optical depth over the covered pixels


def voxel_stats(bricks) -> dict:
    """Value statistics over the non-zero voxels (each voxel once: no aprons)."""
    own = np.asarray(bricks.data)[:, :-1, :-1, :-1].reshape(-1)
    nz = own[own > 0]
    if nz.size == 0:
        return {"nonzero": 0}
    p50, p90, p99 = np.percentile(nz, [50, 90, 99])
    return {"nonzero": int(nz.size), "min": float(nz.min()), "max": float(nz.max()),
            "p50": float(p50), "p90": float(p90), "p99": float(p99)}


def suggested_density_scale(bricks, device=None, size=(64, 48)) -> float | None:
    """The --density-scale at which the median optical depth over the pixels the volume
    covers, seen from the default camera, is TARGET_DEPTH: one unlit render at a scale
    small enough that alpha = 1 - exp(-tau) is far from saturating."""
    vmax = float(np.max(bricks.majorant)) if len(bricks.majorant) else 0.0
    if vmax <= 0:
        return None
    lo, hi = bricks.world_bounds()
    s0 = 0.1 / (vmax * float(np.linalg.norm(hi - lo)))
    cam = View(size=size).camera(lo, hi, bricks.up_axis)
    scene = Scene(cam, (), VolumeContent(bricks, VolumeSettings(density_scale=s0)))
    alpha = render(scene, device).rgba[..., 3].astype(np.float64)
    tau = -np.log1p(-np.clip(alpha, 0.0, 1.0 - 1e-7)) / s0
    covered = tau[alpha > 1e-6]
    return TARGET_DEPTH / float(np.median(covered)) if covered.size else None


def _box(lo, hi) -> str:
    """Coordinates with 10 significant digits: survey offsets (5e5, 4e6) keep their
    centimetres."""
    return "(" + ", ".join(f"{v:.10g}" for v in lo) + ")..(" + ", ".join(f"{v:.10g}" for v in hi) + ")"


def describe_points(path) -> list[str]:
    """Lines describing a point file: count, bounds, radii, colours, the nearest-neighbour
    spacing, and the radius and blend a render would choose (spheres.scan_defaults)."""
    cloud = load_points(path)
    n = len(cloud.centers)
    lo, hi = cloud.centers.min(axis=0), cloud.centers.max(axis=0)
    lines = [f"{printable(Path(path))}: {n} points, bounds {_box(lo, hi)}",
             *(f"  {note}" for note in cloud.notes)]
    if cloud.radii is not None:
        r = cloud.radii
        lines.append(f"  radii {r.min():.4g}..{r.max():.4g} (median {np.median(r):.4g}); "
                     f"a render's blend: {2 * np.median(r):.4g} (twice the median radius)")
    else:
        settings, note = scan_defaults(cloud, glass.GlassSettings())
        lines.append(f"  no radii: {note}")
    lines.append(f"  colours: {'per point' if cloud.colors is not None else 'none'}")
    return lines


def describe(path, device=None) -> list[str]:
    """Lines describing every grid of a .vdb (or the grid of a .npz cache), or a point
    file (describe_points)."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix in POINT_SUFFIXES:
        return describe_points(p)
    if suffix not in (".vdb", ".npz"):
        raise UserError(f"info describes volume and point files, not {suffix or '(no suffix)'!r}",
                        path=p, fix="give a .vdb, .npz or a point file")
    lines = []
    if suffix == ".npz":
        grids = [None]
        lines.append(f"{printable(p)}: volrender brick cache")
    else:
        grids = vdb.list_grids(p)
        creator = next((g.creator for g in grids if g.creator), "")
        axis, why = vdb_header.up_axis_hint(grids)
        lines.append(f"{printable(p)}: OpenVDB, {len(grids)} grid(s)"
                     + (f", written by {printable(creator)}" if creator else "")
                     + f"; up axis {axis or 'y'}" + (f" ({why})" if why else " (the default)"))
    for g in grids:
        if g is not None and (g.value_type != "float" or g.grid_class == "level set"):
            why = "a level set" if g.grid_class == "level set" else f"{g.value_type} values"
            n = f", {g.active_voxels:,} active voxels" if g.active_voxels is not None else ""
            lines.append(f"  {printable(g.name)}: {printable(g.value_type)}, "
                         f"{printable(g.grid_class)}{n} (not renderable as a density: "
                         f"{printable(why)})")
            continue
        b = vdb.load_volume(p, grid=None if g is None else g.name)
        lo, hi = b.world_bounds()
        st = voxel_stats(b)
        name = printable(b.grid_name)
        head = f"  {name}: float, fog volume, {b.active_voxels:,} active voxels, voxel size {b.voxel_size:.6g}"
        lines.append(head)
        if b.index_box is not None:
            ilo, ihi = b.index_box
            dims = tuple(h - l + 1 for l, h in zip(ilo, ihi))
            lines.append(f"    index box {tuple(ilo)}..{tuple(ihi)} ({' x '.join(map(str, dims))})")
            corners = np.array([[x, y, z, 1.0] for x in (ilo[0], ihi[0]) for y in (ilo[1], ihi[1])
                                for z in (ilo[2], ihi[2])])
            w = (np.asarray(b.index_to_world) @ corners.T)[:3].T
            lo, hi = w.min(axis=0), w.max(axis=0)
            lines.append(f"    world box {_box(lo, hi)} (active voxel centres)")
        else:
            lines.append(f"    world box {_box(lo, hi)} (the brick layout's bounds)")
        if st["nonzero"] == 0:
            lines.append("    all values are zero: nothing to render")
            continue
        lines.append(f"    non-zero voxels {st['nonzero']:,}: values {st['min']:.3g}..{st['max']:.3g}, "
                     f"p50 {st['p50']:.3g}, p90 {st['p90']:.3g}, p99 {st['p99']:.3g}")
        scale = suggested_density_scale(b, device)
        if scale is not None:
            lines.append(f"    suggested --density-scale {scale:.3g} (median optical depth "
                         f"{TARGET_DEPTH:g} over the pixels it covers, default camera)")
    return lines
