"""Point clouds as molten glass: settings, scene packing and the render orchestration.

Every point is a sphere; the spheres melt together through the order-independent smooth
union of cl/sdf.h (support: sphere i matters only where d_i < min_j d_j + blend). The
render frame is world minus the scene centre (float64 on the host), so clouds far from the
origin keep their float32 precision.
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass

import numpy as np

from . import cells as cells_mod, device as device_mod, layout, lights as lights_mod, tree as tree_mod
from . import tree_device
from .camera import DEFAULT_FOV, frame_bounds
from .dispatch import Dispatch, Plan, is_gpu
from .environment import texels as env_texels
from .errors import UserError
from .features import GlassFeatures
from .settings import (MAX_VALUE, NUM, CommonSettings, boolean, floats, in_range, knob, one_of,
                       rgb)

PIXELS_PER_LAUNCH = 1 << 14
MAX_TREE_DEPTH = layout.MAX_TREE_DEPTH   # deepest tree the host accepts (stacks: depth + 1)
MAX_EXTENT = 1e18            # render-frame coordinates: |x - c|^2 stays finite in float32
NV_MAX_REGISTERS = 40         # per work-item, the glass kernel on NVIDIA (build_options)
UBER_BITS = layout.UBER_BITS   # uber-kernel runtime feature bits (VR_BIT_* in cl/structs.h)
SCAN_BLEND = 3.0             # default blend of clouds without radii: times the 90th percentile
SCAN_PERCENTILE = 90         # of the nearest-neighbour spacings (uneven scans melt too)
ACCELS = ("auto", "grid", "tree", "none")
GLASS_MODELS = ("full", "fast")


@dataclass(frozen=True)
class GlassSettings(CommonSettings):
    """Molten-glass look and tracing knobs (defaults, ranges and CLI/scene names:
    settings.knob). Lengths are world units, except that absorption and glow are per
    material_unit (default: the cloud's bounding radius)."""
    radius: float | None = knob(None, "sphere radius for every point (default: the file's "
                                "radii, else half the median nearest-neighbour spacing)",
                                check=in_range(0, MAX_EXTENT, allow_none=True),
                                toml=("points", "radius"), kind=NUM, show_default=False)
    blend: float | None = knob(None, "smooth-union width k; 0 = plain union (default: twice "
                               "the median radius; for points without radii, three times "
                               "the 90th percentile of the nearest-neighbour spacings, so a "
                               "scan melts into one surface)",
                               check=in_range(0, MAX_EXTENT, allow_none=True),
                               toml=("render", "blend"), kind=NUM, show_default=False)
    leaf_size: int = knob(16, "points per tree leaf", check=in_range(1, 1 << 20, integer=True),
                          toml=("render", "leaf_size"))
    accel: str = knob("auto", "how the field finds the spheres near a point: grid = support "
                      "cells (each lists the spheres that can matter in it; rays skip cells away "
                      "from the surface), tree = walk the partition tree, none = brute force "
                      "over all spheres (the reference), auto = grid, or on CPUs the tree walk "
                      "for jobs too small to repay the cells' build (cells.choose_edge)",
                      check=one_of(ACCELS), choices=ACCELS, toml=("render", "accel"))
    use_tree: bool = knob(True, "brute force over all spheres, the reference (= --accel none)",
                          check=boolean, flag="--no-tree", toml=("render", "tree"))
    cell_size: float | None = knob(None, "support-cell edge, world units (default: (median "
                                   "radius + blend / 2) / 4, grown to fit the device's budget)",
                                   check=in_range(0, MAX_EXTENT, allow_none=True),
                                   toml=("render", "cell_size"), kind=NUM, show_default=False)
    cell_skip: bool = knob(True, "support cells: list every cell instead of letting rays skip "
                           "those away from the surface (the same field; tests, benchmarks)",
                           check=boolean, flag="--no-cell-skip", toml=("render", "cell_skip"))
    bounces: int = knob(6, "surface events (reflections, refractions) per path from the "
                        "camera: a path tracer's depth bounces + 1", check=in_range(1, 64, integer=True),
                        toml=("render", "bounces"))
    glass_model: str = knob("full", "full = every surface event reflects and refracts, both "
                            "traced (glass in reflections, exits reflecting inside; the "
                            "reference path tracer's image); fast = one refracted path, "
                            "outer reflections see the environment only (the real-time "
                            "look)", check=one_of(GLASS_MODELS), choices=GLASS_MODELS,
                            toml=("render", "glass_model"))
    roulette: float = knob(0.02, "--glass-model full: a branch weaker than this (its "
                           "largest channel, relative to the camera ray) survives Russian "
                           "roulette with probability weight / roulette, else every branch "
                           "is traced; both models: a highlight whose unshadowed lobe is "
                           "weaker is shadow-tested with that probability; 0 = trace them "
                           "all (slowest, no noise), 1 = the most roulette (noisiest)",
                           check=in_range(0, 1), toml=("render", "roulette"))
    split_events: int = knob(64, "--glass-model full: surface events per path at which both "
                             "Fresnel branches are traced; past them one branch goes on, "
                             "chosen in proportion to its weight (unbiased, noisier, "
                             "cheaper); 0 = a path tracer's choice at every event",
                             check=in_range(0, 64, integer=True),
                             toml=("render", "split_events"))
    ior: float = knob(1.5, "index of refraction", check=in_range(1 / 16, 16),
                      toml=("material", "ior"))
    absorption: tuple = knob((0.25, 1.0, 2.7), "Beer-Lambert coefficient inside glass, per "
                             "--material-unit of length", metavar="R,G,B",
                             parse=floats(3, name="--absorption"), check=rgb(0, MAX_VALUE),
                             toml=("material", "absorption"))
    color: tuple = knob((1.0, 0.42, 0.12), "colour of the glow (and the tint of opaque spheres)",
                        metavar="R,G,B", parse=floats(3, name="--color"), check=rgb(0, MAX_VALUE),
                        toml=("material", "color"))
    reflectivity: float = knob(1.0, "scale on the Fresnel reflection", check=in_range(0, MAX_VALUE),
                               toml=("material", "reflectivity"))
    glow: float = knob(1.0, "hot-glass emission per --material-unit of length inside glass",
                       check=in_range(0, MAX_VALUE), toml=("material", "glow"))
    material_unit: float | None = knob(None, "the length absorption and glow are given per, "
                                       "world units (default: the cloud's bounding radius, so "
                                       "the material looks the same at any scale; 1 = per "
                                       "world unit)", check=in_range(1e-30, MAX_EXTENT,
                                                                     allow_none=True),
                                       toml=("material", "unit"), kind=NUM, show_default=False)
    shininess: float = knob(200.0, "Blinn-Phong exponent of the highlights",
                            check=in_range(1, 1e5), toml=("material", "shininess"))
    epsilon: float = knob(1e-4, "relative hit threshold (times the path length) and ray offset",
                          check=in_range(1e-7, 0.1), toml=("render", "epsilon"))
    max_steps: int = knob(256, "sphere-tracing steps per ray segment",
                          check=in_range(1, 65536, integer=True), toml=("render", "max_steps"))
    relax: float = knob(1.6, "over-relaxed sphere tracing factor in [1, 1.9]; 1 = plain "
                        "(misses nothing; bench error: x1.3 faster at the same error)",
                        check=in_range(1, 1.9), toml=("render", "relax"))
    shadow_angle: float = knob(0.0, "angular radius of the lights, degrees: 0 = hard shadows, "
                               "more = soft", check=in_range(0, 45), metavar="DEG",
                               toml=("render", "shadow_angle"))
    refraction: bool = knob(True, "no refraction: shaded opaque spheres", check=boolean,
                            flag="--opaque", toml=("render", "refraction"))
    point_colors: bool = knob(True, "ignore the cloud's per-point colours (use --color everywhere)",
                              check=boolean, flag="--no-point-colors",
                              toml=("render", "point_colors"))
    # env (the environment) is a CommonSettings knob: volumes read it too

    def __post_init__(self):
        super().__post_init__()
        if self.use_tree is False and self.accel != "none":   # --no-tree means --accel none
            object.__setattr__(self, "accel", "none")


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


def sphere_radii(cloud, settings: GlassSettings) -> np.ndarray:
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
    c = np.asarray(cloud.centers, np.float64)
    if np.ndim(radii) == 0:
        return c.min(axis=0) - float(radii), c.max(axis=0) + float(radii)
    return (c - radii[:, None]).min(axis=0), (c + radii[:, None]).max(axis=0)


def blend_width(radii, settings: GlassSettings) -> float:
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


def pack_scene(cloud, settings: GlassSettings, device=None, samples=None,
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
        built = None
        if on_device:
            try:
                built = tree_device.build(dev, spheres[:, :3], spheres, depth)
            except tree_device.Unsupported:          # pyopencl's scan at this size: numpy
                if tree_on == "device":
                    raise
        if built is not None:
            order, start, count, blo, bhi, spheres, _ = built
        else:
            tree = tree_mod.build(centers, radii, int(settings.leaf_size), 0.0,
                                  keys=spheres[:, :3])
            order, start, count = tree.order, tree.start, tree.count
            spheres = spheres[order]
            blo, bhi = tree_mod.float32_boxes(spheres, start, count, depth)
        tree_ms = 1e3 * (time.perf_counter() - t0)
        first_leaf = 1 << depth
        nodes = layout.record("TreeNode", 2 << depth)
        # the float32 boxes hold their float32 spheres up to rounding: widen them by one ulp
        # of the largest coordinate, outwards
        ulp = float(np.spacing(np.float32(np.abs(spheres[:, :3]).max() + radii.max())))
        tlo = _outward(blo.astype(np.float64) - ulp, True)
        thi = _outward(bhi.astype(np.float64) + ulp, False)
        for a, ax in enumerate("xyz"):
            nodes[f"lo_{ax}"], nodes[f"hi_{ax}"] = tlo[:, a], thi[:, a]
        nodes["start"], nodes["count"] = start, count
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
            chosen = cells_mod.choose_edge(spheres, k, box_lo, cell, samples)
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


def material_unit(packed: PackedSpheres, settings: GlassSettings) -> float:
    """World length that absorption and glow are per: settings.material_unit, else the
    cloud's bounding radius (packed.scale), so a 15 cm scan and a 3-unit gather look alike."""
    return float(settings.material_unit) if settings.material_unit else float(packed.scale)


def dispatch_for(settings: GlassSettings, device) -> Dispatch:
    """settings' dispatch with `auto` resolved (fragment; volrender.dispatch). On glass
    the tile lists cannot pay: shadow and refracted rays leave the tile's frustum, and a
    list holds ~1.6x the spheres a tree visit tests (H200 1080p: tiled x0.85-1.04)."""
    return Dispatch(settings.dispatch, tuple(settings.tile)).resolve(device)


def uber_bits(features: GlassFeatures) -> int:
    """The runtime feature bits of the uber-kernel for what specialised `features` compile."""
    return sum(bit for name, bit in UBER_BITS.items() if getattr(features, name))


def default_camera(cloud, width=640, height=480, fov=DEFAULT_FOV, radius=None):
    """Camera framing the spheres' bounds (camera.frame_bounds)."""
    radii = sphere_radii(cloud, GlassSettings(radius=radius))
    lo, hi = sphere_bounds(cloud, radii)
    return frame_bounds(lo, hi, width, height, fov)


def glass_params(packed: PackedSpheres, settings: GlassSettings, environment=None, lights=(),
                 uber=0):
    """The GlassParams record of packed spheres and settings (the kernels' and the tests'
    probes'); the support-cell fields are set by kernel_arrays."""
    n_suns, n_points = lights_mod.counts(lights)
    env_w, env_h = env_texels(environment)[1:]
    unit = material_unit(packed, settings)
    return layout.record(
        "GlassParams", box_lo=[*packed.box_lo, 0], box_hi=[*packed.box_hi, 0],
        absorption=[*(np.asarray(settings.absorption) / unit), 0], color=[*settings.color, 0],
        blend=packed.blend, ior=settings.ior, reflectivity=settings.reflectivity,
        glow=settings.glow / unit, epsilon=settings.epsilon, shininess=settings.shininess,
        scale=packed.scale, n_spheres=len(packed.spheres), first_leaf=packed.first_leaf,
        bounces=settings.bounces, max_steps=settings.max_steps, env_width=env_w,
        env_height=env_h, tile_margin=packed.margin,
        shadow_cone=math.tan(math.radians(settings.shadow_angle)),
        uber=uber, n_suns=n_suns, n_points=n_points, relax=settings.relax,
        hit_len=min(packed.hit_len, 3e38), roulette=settings.roulette,
        split_events=settings.split_events)


def plan(scene, device, variant=None, launch=None):
    """The launch of a glass scene (render.render runs it): the scene's packed spheres
    (built once per device, scene.GlassContent.prepare) and this frame's parameters.
    variant "uber": every feature compiled in and chosen at run time; "stats": rgb counts
    the field's work per pixel."""
    settings = scene.content.settings
    cam = scene.camera
    packed = scene.content.prepare(device, samples=cam.width * cam.height * settings.spp)
    dispatch = dispatch_for(settings, device)
    features = GlassFeatures.from_scene(scene, packed, dispatch, variant)
    w2f = np.eye(4)
    w2f[:3, 3] = -packed.centre
    env = env_texels(scene.environment)[0]
    bits = uber_bits(GlassFeatures.from_scene(scene, packed, dispatch)) if variant == "uber" else 0
    params = glass_params(packed, settings, scene.environment, scene.lights, bits)
    eye = np.asarray(cam.origin, np.float64) - packed.centre
    if np.all(eye >= packed.box_lo) and np.all(eye <= packed.box_hi):
        params["eye_color"] = eye_color(packed, eye)
    colors = packed.colors if packed.colors is not None else np.zeros((1, 4), np.float32)
    spheres, grid_arrays = kernel_arrays(packed, params, device.context)
    info = {"tree_ms": packed.tree_ms, "accel": packed.accel, "cells_ms": 0.0}
    if packed.cells is not None:
        info.update(cells_ms=packed.cells.build_ms, cells=packed.cells.summary())
    if packed.note:
        info["note"] = packed.note
    inputs = [("cam", scene.camera.pack(w2f, settings.spp, settings.seed)), ("gp", params),
              ("lights", lights_mod.pack(scene.lights, w2f)), ("spheres", spheres),
              ("nodes", packed.nodes), ("env", env), ("colors", colors),
              *zip(("bricks", "cells", "lists", "runs"), grid_arrays)]
    W, H = scene.camera.width, scene.camera.height
    return Plan("render_glass", features, inputs, [("rgba", (H, W, 4))], dispatch,
                PIXELS_PER_LAUNCH, info=info, build_options=build_options(features, device))


def build_options(features, device) -> tuple:
    """Compiler options of the glass kernel: on NVIDIA (cl_nv_compiler_options) registers
    are capped at NV_MAX_REGISTERS ($VOLRENDER_NV_MAX_REGISTERS; 0: no cap), except with
    per-point colours and for opaque spheres without lights, where the cap measured slower
    (docs/DESIGN.md)."""
    text = os.environ.get("VOLRENDER_NV_MAX_REGISTERS", "").strip()
    try:
        cap = int(text) if text else NV_MAX_REGISTERS
    except ValueError:
        raise UserError(f"VOLRENDER_NV_MAX_REGISTERS={text!r} is not an integer",
                        fix="set it to a register count such as 40, or 0 for no cap") from None
    if cap <= 0 or device is None or not device.has_extension("cl_nv_compiler_options"):
        return ()
    if features.colors and not features.uber:
        return ()
    if not features.refraction and not (features.n_suns or features.n_points or features.uber):
        return ()
    return (f"-cl-nv-maxrregcount={cap}",)


def kernel_arrays(packed: PackedSpheres, params, context=None):
    """The spheres and the four support-cell arrays the kernel reads (cl/cells.h), with the
    grid's fields of the GlassParams record `params` set; stand-ins without cells. The
    runs stay the builder's device buffer when `context` is the builder's (no copy)."""
    grid = packed.cells
    if grid is None:
        return packed.spheres, [np.zeros((1, 2), np.int32), np.zeros((1, 2), np.int32),
                                np.zeros((1, 4), np.int32), np.zeros((1, 2), np.int32)]
    params["grid_lo"] = [*grid.lo, grid.cell]
    params["grid_dims"] = [*grid.dims, 0]
    params["brick_dims"] = [*grid.bdims, 0]
    params["grid_inv"] = np.float32(1.0 / grid.cell)
    params["grid_nudge"] = 1e-3 * grid.cell
    params["grid_skips"] = 4 * int(grid.dims.sum() + grid.bdims.sum()) + 64
    same = context is not None and grid.runs_device.context.int_ptr == context.int_ptr
    if same and grid.buffers:
        return packed.spheres, [*grid.buffers, grid.runs_device]
    return packed.spheres, [grid.bricks, grid.cells, grid.lists,
                            grid.runs_device if same else grid.runs]
