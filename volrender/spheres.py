"""The sphere acceleration of molten glass: the spheres' radii and bounds, and what the
kernel reads about them, built once per scene and device (scene.GlassContent.prepare):
the spheres packed in the render frame (world minus the scene centre, float64 on the host,
so clouds far from the origin keep their float32 precision), the partition tree (tree.py
on the host, tree_device.py on GPUs) and the support cells (cells.py).

`settings` below is a glass.GlassSettings (read by field; this module sits below glass).
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np

from . import cells as cells_mod, device as device_mod, layout, tree as tree_mod, tree_device
from .points import nn_distances
from .dispatch import is_gpu
from .errors import UserError

MAX_TREE_DEPTH = layout.MAX_TREE_DEPTH   # deepest tree the host accepts (stacks: depth + 1)
MAX_EXTENT = 1e18            # render-frame coordinates: |x - c|^2 stays finite in float32
SCAN_BLEND = 3.0             # default blend of clouds without radii: times the 90th percentile
SCAN_PERCENTILE = 90         # of the nearest-neighbour spacings (uneven scans melt too)
FALLBACK_RADIUS = 0.5        # a cloud without radii and without two distinct points

# settings the packed spheres, the tree and the cells depend on (GlassContent.prepare)
ACCEL_FIELDS = ("radius", "blend", "leaf_size", "accel", "cell_size", "cell_skip", "epsilon",
                "bounces", "point_colors")


@dataclass(frozen=True)
class PackedSpheres:
    """Everything the kernel reads about the spheres, in the render frame: the same for
    every camera, so a scene builds it once (scene.GlassContent.prepare)."""
    centre: np.ndarray      # float64 (3,): world position of the render-frame origin
    spheres: np.ndarray     # float32 (N, 4): centre - scene centre, radius; tree order
    nodes: np.ndarray       # TreeNode records (one zero record without a tree)
    first_leaf: int         # 2^depth (1 without a tree)
    box_lo: np.ndarray      # float32 (3,): clip box, render frame
    box_hi: np.ndarray
    blend: float
    scale: float            # bounding radius of the spheres
    tree_ms: float
    colors: np.ndarray | None = None   # float32 (N, 4) rgb per sphere, tree order
    margin: float = 0.0     # tiled dispatch: list spheres within this of a tile's frustum
    accel: str = "none"     # what the kernel uses: grid, tree or none
    cells: object = None    # cells.Cells with accel grid
    note: str = ""          # why accel differs from the settings' (a fallback)
    hit_len: float = math.inf   # the hit threshold eps (base + t) stops growing at this
                                # base + t (cells.hit_length: the cells' tau covers it)


@dataclass(eq=False)
class BuildCache:
    """What a scene's glass content builds once and keeps (scene.GlassContent.prepare):
    `dataclasses.replace` of the content and Scene.replace share it, so a new camera or a
    setting outside ACCEL_FIELDS rebuilds nothing."""
    packed: dict = field(default_factory=dict)   # (device, ACCEL_FIELDS values) -> (cloud, packed)
    builds: int = 0                               # how many times pack_scene ran
    spacing: tuple | None = None                  # the cloud's nn spacing: (median, percentile)

    def packed_for(self, cloud, settings, device, build) -> PackedSpheres:
        """The PackedSpheres of `cloud` and `settings` on `device` (a device.Device), from
        `build()` the first time, kept after."""
        key = (device.device.int_ptr, *(getattr(settings, f) for f in ACCEL_FIELDS))
        hit = self.packed.get(key)
        if hit is not None and hit[0] is cloud:
            return hit[1]
        packed = build()
        self.packed[key] = (cloud, packed)
        self.builds += 1
        return packed


def scan_spacing(centers) -> tuple:
    """(median, SCAN_PERCENTILE-th percentile) of the points' exact nearest-neighbour
    spacings (points.nn_distances); (0, 0) when no two points differ."""
    nn = nn_distances(centers)
    if not nn.size:
        return 0.0, 0.0
    s, far = np.percentile(nn, [50, SCAN_PERCENTILE])
    return float(s), float(far)


def scan_radius(median_spacing: float) -> float:
    """The radius of a cloud without radii: half its median spacing (else FALLBACK_RADIUS)."""
    return 0.5 * median_spacing if median_spacing > 0 else FALLBACK_RADIUS


def default_radius(centers) -> float:
    """The radius a render gives points without radii (scan_defaults): half the median
    nearest-neighbour spacing, or FALLBACK_RADIUS when no spacing can be measured."""
    return scan_radius(scan_spacing(centers)[0])


def scan_defaults(cloud, settings, cache: BuildCache | None = None):
    """Radius and blend of a cloud without radii (a scan), from its exact nearest-neighbour
    spacings: radius half the median, blend SCAN_BLEND times the SCAN_PERCENTILE-th
    percentile (neighbours melt into one surface, also where the scan is sparser); the
    settings' own radius and blend win. cache: the cloud's BuildCache (Scene.replace: the
    spacing is measured once). Returns (settings, note)."""
    if cache is not None and cache.spacing is not None:
        s, far = cache.spacing
    else:
        s, far = scan_spacing(cloud.centers)
        if cache is not None:
            cache.spacing = (s, far)
    radius = settings.radius if settings.radius is not None else scan_radius(s)
    blend = settings.blend if settings.blend is not None else \
        (SCAN_BLEND * far if far > 0 else 2.0 * radius)
    settings = dataclasses.replace(settings, radius=radius, blend=blend)
    return settings, (f"{len(cloud.centers)} points without radii, nearest-neighbour spacing "
                      f"{s:.4g} (median), {far:.4g} ({SCAN_PERCENTILE}th percentile): radius "
                      f"{radius:.4g}, blend {blend:.4g}; set --radius, --blend")


def sphere_radii(cloud, settings) -> np.ndarray:
    """Per-point radii: settings.radius if given, else the cloud's own."""
    n = len(cloud.centers)
    if settings.radius is not None:
        return np.full(n, float(settings.radius))
    if cloud.radii is None:
        raise UserError(f"the point cloud {cloud.source or ''} has no radii".replace("  ", " "),
                        fix="give a radius (--radius, or [points].radius)")
    r = np.asarray(cloud.radii, np.float64)
    if not (np.isfinite(r).all() and (r >= 0).all()):
        raise UserError("point radii must be finite and >= 0", fix="repair the radius column")
    return r


def sphere_bounds(cloud, radii):
    """(lo, hi) float64 of centre +- radius over all points; radii (N,) or one radius."""
    from .framing import box
    return box(cloud.centers, radii if np.ndim(radii) == 0 else np.asarray(radii, np.float64))


def blend_width(radii, settings) -> float:
    """The smooth-union width k: settings.blend, else twice the median radius."""
    if settings.blend is not None:
        return float(settings.blend)
    if settings.radius is not None:
        return 2.0 * float(settings.radius)
    return 2.0 * float(np.median(radii)) if len(radii) else 0.0


def _outward(a, down: bool):
    """float32 of a float64 array, rounded away from the box interior (inf kept)."""
    a32 = a.astype(np.float32)
    step = np.nextafter(a32, np.float32(-np.inf if down else np.inf))
    return np.where(np.isfinite(a32), step, a32)


def pack_scene(cloud, settings, device=None, samples=None,
               max_runs=None, tree_on="auto") -> PackedSpheres:
    """Spheres, tree and support cells in the render frame, for every camera. The tree is
    built for accel tree and grid (it builds the cells); device: where the cells are built
    (default: the default device); samples (pixels x spp) sets the automatic cell edge's
    and the choice of the tree walk on CPUs (cells.choose_edge); max_runs caps the cells'
    list runs (cells.build). tree_on:
    "device" (tree_device.py), "host" (tree.py's numpy build: the same tree) or "auto",
    the device on GPUs and the host on CPUs, where numpy measured faster (bench build)."""
    centers = np.asarray(cloud.centers, np.float64)
    n = len(centers)
    radii = sphere_radii(cloud, settings) if n else np.zeros(0)
    if not np.isfinite(centers).all():
        raise UserError("point coordinates must be finite", fix="remove NaN/Inf points")
    k = blend_width(radii, settings)
    nodes = layout.record("TreeNode", 1)
    first_leaf, tree_ms = 1, 0.0
    if n == 0:
        centre, lo, hi = np.zeros(3), np.full(3, np.inf), np.full(3, -np.inf)
        return PackedSpheres(centre, np.zeros((0, 4), np.float32), nodes, 1,
                             lo.astype(np.float32), hi.astype(np.float32), k, 1.0, 0.0)
    lo, hi = sphere_bounds(cloud, radii if settings.radius is None else settings.radius)
    centre = 0.5 * (lo + hi)
    order = np.arange(n)
    # float32 render-frame centres: what the kernels read, and the keys the tree splits on
    spheres = np.empty((n, 4), np.float32)
    spheres[:, :3] = centers - centre
    spheres[:, 3] = radii
    accel = settings.accel
    if accel in ("tree", "grid", "auto"):
        depth = tree_mod.tree_depth(n, int(settings.leaf_size))
        if depth > MAX_TREE_DEPTH:
            raise UserError(f"tree depth {depth} exceeds {MAX_TREE_DEPTH}",
                            fix="raise the leaf size (--leaf-size, or [render].leaf_size)")
        dev = device_mod.resolve(device) if device is not None or accel != "tree" \
            or tree_on == "device" else None
        on_device = tree_on == "device" or (tree_on == "auto" and dev is not None and is_gpu(dev))
        t0 = time.perf_counter()
        tree = None
        if on_device:
            try:
                tree, spheres = tree_device.build(dev, spheres[:, :3], spheres,
                                                  int(settings.leaf_size), centre)
            except tree_device.Unsupported:          # pyopencl's scan at this size: numpy
                if tree_on == "device":
                    raise
        if tree is None:
            tree = tree_mod.build(centers, radii, int(settings.leaf_size), 0.0,
                                  keys=spheres[:, :3])
            spheres = spheres[tree.order]
            tree = tree.in_frame(spheres, centre)   # the device build's float32 boxes
        order = tree.order
        tree_ms = 1e3 * (time.perf_counter() - t0)
        first_leaf = tree.first_leaf
        nodes = layout.record("TreeNode", tree.n_nodes)
        # the float32 boxes hold their float32 spheres up to rounding: widen them by one ulp
        # of the largest coordinate, outwards
        ulp = float(np.spacing(np.float32(np.abs(spheres[:, :3]).max() + radii.max())))
        tlo = _outward(tree.lo.astype(np.float64) - ulp, True)
        thi = _outward(tree.hi.astype(np.float64) + ulp, False)
        for a, ax in enumerate("xyz"):
            nodes[f"lo_{ax}"], nodes[f"hi_{ax}"] = tlo[:, a], thi[:, a]
        nodes["start"], nodes["count"] = tree.start, tree.count
    colors = None
    if settings.point_colors and cloud.colors is not None:
        colors = np.zeros((n, 4), np.float32)
        colors[:, :3] = np.asarray(cloud.colors, np.float32)[order]
    # Tiled lists hold spheres within 2k of the frustum: evaluations with m + k <= 2k (up
    # to k outside the nearest sphere, which covers the surface) use the list alone.
    margin = 2.0 * k
    # The union bulges by at most (k/2) ln N over the plain union (N spheres at equal
    # distance), so the clip box grows by that plus the support k.
    bulge = k * (1.0 + 0.5 * np.log(n))
    scale = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-30)
    if not scale + bulge <= MAX_EXTENT:
        raise UserError(f"the point cloud spans {scale + bulge:.3g} units (radius plus blend), "
                        f"beyond float32's reach ({MAX_EXTENT:.0e})",
                        fix="rescale the points (or lower the blend: --blend, or [render].blend)")
    box_lo = _outward(lo - centre - bulge, True)
    box_hi = _outward(hi - centre + bulge, False)
    hit_len = cells_mod.hit_length(scale, box_lo, box_hi, settings.bounces)
    grid, note = None, ""
    if accel in ("grid", "auto"):
        grid, note = _build_cells(spheres, nodes, first_leaf, k, box_lo, box_hi, radii, scale,
                                  settings, device, samples, max_runs)
        accel = "grid" if grid is not None else "tree"
    return PackedSpheres(centre, spheres, nodes, first_leaf, box_lo, box_hi, k, scale, tree_ms,
                         colors, margin, accel, grid, note, hit_len)


# The CPU rule (cells.choose_edge) was fitted on one refracted path per sample (the fast
# model). The full model traces the camera hit's reflection too (x2 paths: FULL_WORK) and,
# splitting at more than one event, about FULL_SPLIT_WORK times the field work (issue 32:
# kernel ms full/fast x3-7 on the H200). The bunny at 320x240 on PoCL, CPU s tree/cells:
# fast 9.7/8.4, full split once 10.5/7.1, split always 25.6/16.3; the rule alone chose the
# tree for all three. Since the walk by key the cells' sample is cheaper still: whole
# command, fast, tree 31.3 / cells 14.1 CPU s (user; PoCL, 2 shared cores), so a refracting
# fast sample weighs as a full one split once (FAST_WORK) until the rule is refitted
# (bench/edge.py).
FULL_WORK = 2.0
FULL_SPLIT_WORK = 4.0
FAST_WORK = 2.0


def sample_work(settings) -> float:
    """A pixel sample's weight in the CPU cell rule: its field work relative to one
    refracted path before the walk by key (FAST_WORK for the fast model since)."""
    if not settings.refraction:
        return 1.0
    if getattr(settings, "glass_model", "fast") != "full":
        return FAST_WORK
    split = getattr(settings, "split_events", None)
    return FULL_SPLIT_WORK if split is not None and split > 1 else FULL_WORK


def _build_cells(spheres, nodes, first_leaf, k, box_lo, box_hi, radii, scale, settings,
                 device, samples=None, max_runs=None):
    """(cells.Cells, "") or (None, why) when the lists would not fit (then: the tree)."""
    device = device_mod.resolve(device)
    cell = settings.cell_size or cells_mod.auto_cell_size(
        radii if settings.radius is None else np.full(1, settings.radius), k)
    budget = None
    if not settings.cell_size:
        if is_gpu(device):
            budget = cells_mod.GPU_CELLS
        else:
            chosen = cells_mod.choose_edge(spheres, k, box_lo, cell,
                                           None if samples is None else samples * sample_work(settings))
            if chosen is None and settings.accel == "auto":
                return None, (f"a job of {samples or cells_mod.DEFAULT_SAMPLES} pixel samples is "
                              "too small for support cells to repay their build on this CPU: "
                              "using the tree walk (--accel grid forces cells)")
            cell = chosen or cell * cells_mod.EDGE_FACTORS[-1]
    tau = cells_mod.threshold(settings.epsilon, settings.bounces, scale, box_lo, box_hi, k,
                              len(spheres))
    # the total of the lists falls about as 1/edge (cells near the surface as 1/edge^2,
    # lists grow as edge): an automatic edge doubles a few times before giving up
    for attempt in range(1 if settings.cell_size else 4):
        try:
            return cells_mod.build(spheres, nodes, first_leaf, k, box_lo, box_hi, cell, tau,
                                   device, classify=settings.cell_skip, max_cells=budget,
                                   max_runs=max_runs), ""
        except cells_mod.TooLarge as exc:
            why = exc
            if "list runs" not in str(exc):
                break
            cell *= 2.0
    return None, f"support cells too large ({why}): using the tree walk"


def eye_color(packed: PackedSpheres, eye) -> np.ndarray:
    """The glow tint of the glass at render-frame point `eye` (the colour blend of
    cl/sdf.h, sum h_i^2 c_i / S, in float64 over every sphere): what the first segment of a
    path from a camera inside coloured glass glows with, the same for every acceleration."""
    out = np.zeros(4, np.float32)
    if packed.colors is None or not len(packed.spheres):
        return out
    s = packed.spheres.astype(np.float64)
    d = np.linalg.norm(s[:, :3] - np.asarray(eye, np.float64), axis=1) - s[:, 3]
    m = d.min()
    if packed.blend > layout.BLEND_MIN:
        h = np.maximum(1.0 - (d - m) / packed.blend, 0.0)
        w = h * h
    else:
        w = (d == m).astype(np.float64)
    out[:3] = (w @ packed.colors[:, :3].astype(np.float64)) / max(w.sum(), 1e-300)
    return out


def material_unit(packed: PackedSpheres, settings) -> float:
    """World length that absorption and glow are per: settings.material_unit, else the
    cloud's bounding radius (packed.scale), so a 15 cm scan and a 3-unit gather look alike."""
    return float(settings.material_unit) if settings.material_unit else float(packed.scale)
