"""Point clouds as molten glass: settings, scene packing and the render orchestration.

Every point is a sphere; the spheres melt together through the order-independent smooth
union of cl/sdf.h (support: sphere i matters only where d_i < min_j d_j + blend). The
render frame is world minus the scene centre (float64 on the host), so clouds far from the
origin keep their float32 precision.
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np

from . import layout, lights as lights_mod, tree as tree_mod
from .camera import DEFAULT_FOV, frame_bounds
from .errors import UserError
from .features import GlassFeatures
from .dispatch import Dispatch, run_rows, upload

PIXELS_PER_LAUNCH = 1 << 14
MAX_TREE_DEPTH = 47          # deepest tree the host accepts (the kernel's stack: depth + 1)
TILE_CAP = 512               # tiled dispatch: spheres per tile list (a power of two)
MAX_EXTENT = 1e18            # render-frame coordinates: |x - c|^2 stays finite in float32
UBER_BITS = layout.UBER_BITS   # uber-kernel runtime feature bits (VR_BIT_* in cl/structs.h)


@dataclass(frozen=True)
class GlassSettings:
    """Molten-glass look and tracing knobs. Lengths are world units.

    radius: one radius for every point (None: the cloud's own radii).
    blend: smooth-union width k (None: twice the median radius). 0 gives the plain union.
    absorption: rgb Beer-Lambert coefficient inside glass, per unit length.
    color: rgb colour of the glow (and the diffuse tint when refraction is off).
    reflectivity: scale on the Fresnel-weighted environment reflection.
    glow: hot-glass emission per unit length inside glass (weighted by absorption).
    epsilon: relative hit threshold (times the path length) and ray offset.
    env: None for the procedural sky, or a path to an equirectangular .exr.
    shadow_angle: angular radius of the lights in degrees; 0 gives hard shadows, more
        gives soft ones (a penumbra estimate from the sphere-traced distances).
    point_colors: tint each point's glass with the cloud's own colours, if it has any.
    relax: over-relaxed sphere tracing factor in [1, 1.9] (1: plain); misses nothing, moves
        hits within epsilon. 1.6 (bench error, H200): x1.3 faster at the default knobs
        with the same error against the converged reference.
    dispatch, tile: volrender.dispatch.Dispatch (auto, fragment, or tiled with WxH tiles).
    uber: compile every feature in and choose at run time (the specialisation baseline).
    stats: diagnostics; the image's rgb holds the field evaluations, tree-node tests and
        sphere tests per pixel (summed over its samples), alpha the coverage.
    """
    radius: float | None = None
    blend: float | None = None
    leaf_size: int = 16      # bench spheres: x1.13 faster than 8 at 3000 spheres (H200, PoCL)
    use_tree: bool = True
    bounces: int = 6
    ior: float = 1.5
    absorption: tuple = (0.15, 0.6, 1.6)
    color: tuple = (1.0, 0.42, 0.12)
    reflectivity: float = 1.0
    glow: float = 0.6
    shininess: float = 200.0
    epsilon: float = 1e-4
    max_steps: int = 256
    spp: int = 1
    seed: int = 0
    env: str | None = None
    shadows: bool = True
    refraction: bool = True
    shadow_angle: float = 0.0
    point_colors: bool = True
    relax: float = 1.6
    dispatch: str = "auto"
    tile: tuple = (8, 8)
    uber: bool = False
    stats: bool = False

    def __post_init__(self):
        def check(ok, msg):
            if not ok:
                raise UserError(msg)

        def finite(v):
            return isinstance(v, (int, float, np.floating, np.integer)) and math.isfinite(v)

        def rgb(v):
            return len(v) == 3 and all(finite(c) and c >= 0 for c in v)

        check(self.radius is None or (finite(self.radius) and self.radius >= 0),
              f"--radius must be finite and >= 0, got {self.radius}")
        check(self.blend is None or (finite(self.blend) and self.blend >= 0),
              f"--blend must be finite and >= 0, got {self.blend}")
        check(isinstance(self.leaf_size, (int, np.integer)) and self.leaf_size >= 1,
              f"--leaf-size must be an integer >= 1, got {self.leaf_size}")
        check(isinstance(self.bounces, (int, np.integer)) and 1 <= self.bounces <= 64,
              f"--bounces must be in [1, 64], got {self.bounces}")
        check(finite(self.ior) and 1.0 / 16 <= self.ior <= 16,
              f"--ior must be in [1/16, 16], got {self.ior}")
        check(rgb(self.absorption), f"--absorption takes three finite values >= 0, got {self.absorption}")
        check(rgb(self.color), f"--color takes three finite values >= 0, got {self.color}")
        check(finite(self.reflectivity) and self.reflectivity >= 0,
              f"--reflectivity must be finite and >= 0, got {self.reflectivity}")
        check(finite(self.glow) and self.glow >= 0, f"--glow must be finite and >= 0, got {self.glow}")
        check(finite(self.shininess) and 1 <= self.shininess <= 1e5,
              f"--shininess must be in [1, 1e5], got {self.shininess}")
        check(finite(self.epsilon) and 1e-7 <= self.epsilon <= 1e-1,
              f"--epsilon must be in [1e-7, 0.1], got {self.epsilon}")
        check(isinstance(self.max_steps, (int, np.integer)) and 1 <= self.max_steps <= 1 << 16,
              f"--max-steps must be in [1, 65536], got {self.max_steps}")
        check(isinstance(self.spp, (int, np.integer)) and 1 <= self.spp <= 1 << 16,
              f"--spp must be in [1, 65536], got {self.spp}")
        check(finite(self.relax) and 1 <= self.relax <= 1.9,
              f"--relax must be in [1, 1.9], got {self.relax}")
        check(finite(self.shadow_angle) and 0 <= self.shadow_angle <= 45,
              f"--shadow-angle must be in [0, 45] degrees, got {self.shadow_angle}")
        Dispatch(self.dispatch, tuple(self.tile))


@dataclass(frozen=True)
class GlassScene:
    """Everything the kernel reads about the spheres, in the render frame."""
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


def sphere_radii(cloud, settings: GlassSettings) -> np.ndarray:
    """Per-point radii: settings.radius if given, else the cloud's own."""
    n = len(cloud.centers)
    if settings.radius is not None:
        return np.full(n, float(settings.radius))
    if cloud.radii is None:
        raise UserError(f"the point cloud {cloud.source or ''} has no radii".replace("  ", " "),
                        fix="give a radius (--radius)")
    r = np.asarray(cloud.radii, np.float64)
    if not (np.isfinite(r).all() and (r >= 0).all()):
        raise UserError("point radii must be finite and >= 0", fix="repair the radius column")
    return r


def sphere_bounds(cloud, radii):
    """(lo, hi) float64 of centre +- radius over all points."""
    c = np.asarray(cloud.centers, np.float64)
    return (c - radii[:, None]).min(axis=0), (c + radii[:, None]).max(axis=0)


def blend_width(radii, settings: GlassSettings) -> float:
    """The smooth-union width k: settings.blend, else twice the median radius."""
    if settings.blend is not None:
        return float(settings.blend)
    return 2.0 * float(np.median(radii)) if len(radii) else 0.0


def _outward(a, down: bool):
    """float32 of a float64 array, rounded away from the box interior (inf kept)."""
    a32 = a.astype(np.float32)
    step = np.nextafter(a32, np.float32(-np.inf if down else np.inf))
    return np.where(np.isfinite(a32), step, a32)


def pack_scene(cloud, settings: GlassSettings) -> GlassScene:
    """Spheres and tree in the render frame; builds the tree only when use_tree."""
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
        return GlassScene(centre, np.zeros((0, 4), np.float32), nodes, 1,
                          lo.astype(np.float32), hi.astype(np.float32), k, 1.0, 0.0)
    lo, hi = sphere_bounds(cloud, radii)
    centre = 0.5 * (lo + hi)
    order = np.arange(n)
    if settings.use_tree:
        t0 = time.perf_counter()
        tree = tree_mod.build(centers, radii, int(settings.leaf_size), 0.0)
        tree_ms = 1e3 * (time.perf_counter() - t0)
        if tree.depth > MAX_TREE_DEPTH:
            raise UserError(f"tree depth {tree.depth} exceeds {MAX_TREE_DEPTH}",
                            fix="raise --leaf-size")
        order, first_leaf = tree.order, tree.first_leaf
        nodes = layout.record("TreeNode", tree.n_nodes)
        # float32 sphere centres round by up to half an ulp of their magnitude: widen the
        # boxes by one ulp so every float32 sphere stays inside its node's box
        ulp = float(np.spacing(np.float32(np.abs(centers - centre).max() + radii.max())))
        tlo, thi = tree.lo - centre - ulp, tree.hi - centre + ulp
        tlo, thi = _outward(tlo, True), _outward(thi, False)
        for a, ax in enumerate("xyz"):
            nodes[f"lo_{ax}"], nodes[f"hi_{ax}"] = tlo[:, a], thi[:, a]
        nodes["start"], nodes["count"] = tree.start, tree.count
    spheres = np.empty((n, 4), np.float32)
    spheres[:, :3] = centers[order] - centre
    spheres[:, 3] = radii[order]
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
                        fix="rescale the points (or lower --blend)")
    box_lo = _outward(lo - centre - bulge, True)
    box_hi = _outward(hi - centre + bulge, False)
    return GlassScene(centre, spheres, nodes, first_leaf, box_lo, box_hi, k, scale, tree_ms,
                      colors, margin)


def dispatch_for(settings: GlassSettings, device) -> Dispatch:
    """settings' dispatch with `auto` resolved (fragment; volrender.dispatch). On glass
    the tile lists cannot pay: shadow and refracted rays leave the tile's frustum, and a
    list holds ~1.6x the spheres a tree visit tests (H200 1080p: tiled x0.85-1.04)."""
    return Dispatch(settings.dispatch, tuple(settings.tile)).resolve(device)


def features_for(scene: GlassScene, lights, settings: GlassSettings) -> GlassFeatures:
    """Compile only what the scene uses (with settings.uber: everything, light counts
    and feature bits read at run time instead)."""
    n_suns, n_points = lights_mod.counts(lights)
    refr = settings.refraction
    tree = settings.use_tree and len(scene.spheres) > 0
    tiled = settings.dispatch == "tiled"
    tiling = dict(tiled=tiled, tile_w=settings.tile[0] if tiled else 0,
                  tile_h=settings.tile[1] if tiled else 0, tile_cap=TILE_CAP if tiled else 0,
                  tree_stack=max(2, int(scene.first_leaf).bit_length()),
                  stats=bool(settings.stats))
    if settings.uber:
        return GlassFeatures(tree=tree, shadows=True, refraction=True, absorption=True,
                             glow=True, env_map=True, colors=True, uber=True, **tiling)
    return GlassFeatures(tree=tree, n_suns=n_suns, n_points=n_points,
                         shadows=settings.shadows and n_suns + n_points > 0,
                         refraction=refr, absorption=refr and any(a > 0 for a in settings.absorption),
                         glow=refr and settings.glow > 0, env_map=settings.env is not None,
                         colors=scene.colors is not None, **tiling)


def uber_bits(scene: GlassScene, lights, settings: GlassSettings) -> int:
    """The runtime feature bits the specialised flags would have compiled in."""
    f = features_for(scene, lights, GlassSettings(**{**settings.__dict__, "uber": False}))
    return sum(bit for name, bit in UBER_BITS.items() if getattr(f, name))


def _env(settings: GlassSettings):
    """(float32 (H*W, 4) texels, width, height); a 1-texel stand-in without a map."""
    if settings.env is None:
        return np.zeros((1, 4), np.float32), 0, 0
    from .image import read_image
    img = np.asarray(read_image(settings.env))
    if img.dtype == np.uint8 or img.ndim != 3 or img.shape[2] < 3:
        raise UserError("the environment must be a float image (.exr or .npy)", path=settings.env,
                        fix="convert it to an equirectangular .exr")
    h, w = img.shape[:2]
    tex = np.zeros((h * w, 4), np.float32)
    tex[:, :3] = np.nan_to_num(img[..., :3].reshape(-1, 3), nan=0.0, posinf=0.0, neginf=0.0)
    return tex, w, h


def default_camera(cloud, width=640, height=480, fov=DEFAULT_FOV, radius=None):
    """Camera framing the spheres' bounds (camera.frame_bounds)."""
    radii = sphere_radii(cloud, GlassSettings(radius=radius))
    lo, hi = sphere_bounds(cloud, radii)
    return frame_bounds(lo, hi, width, height, fov)


def render_points(cloud, camera, lights, settings: GlassSettings, device, progress=None):
    """Render a PointCloud as glass. Returns a dict with 'rgba' (H, W, 4 float32; alpha =
    coverage), 'kernel_ms', 'wall_ms', 'tree_ms', 'flags'."""
    import pyopencl as cl

    scene = pack_scene(cloud, settings)
    dispatch = dispatch_for(settings, device)
    settings = dataclasses.replace(settings, dispatch=dispatch.kind)
    features = features_for(scene, lights, settings)
    kernel = device.kernel("render_glass", features.flags())
    n_suns, n_points = lights_mod.counts(lights)
    w2f = np.eye(4)
    w2f[:3, 3] = -scene.centre
    cam = camera.pack(w2f, settings.spp, settings.seed)
    env, env_w, env_h = _env(settings)
    params = layout.record(
        "GlassParams", box_lo=[*scene.box_lo, 0], box_hi=[*scene.box_hi, 0],
        absorption=[*settings.absorption, 0], color=[*settings.color, 0],
        blend=scene.blend, ior=settings.ior, reflectivity=settings.reflectivity,
        glow=settings.glow, epsilon=settings.epsilon, shininess=settings.shininess,
        scale=scene.scale, n_spheres=len(scene.spheres), first_leaf=scene.first_leaf,
        bounces=settings.bounces, max_steps=settings.max_steps, env_width=env_w,
        env_height=env_h, tile_margin=scene.margin,
        shadow_cone=math.tan(math.radians(settings.shadow_angle)),
        uber=uber_bits(scene, lights, settings) if settings.uber else 0,
        n_suns=n_suns, n_points=n_points, relax=settings.relax)
    light_rec = lights_mod.pack(lights, w2f)

    ctx = device.context
    W, H = camera.width, camera.height
    out = np.empty((H, W, 4), np.float32)
    d_out = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, out.nbytes)
    colors = scene.colors if scene.colors is not None else np.zeros((1, 4), np.float32)
    bufs = [upload(ctx, a) for a in (cam, params, light_rec, scene.spheres, scene.nodes, env,
                                      colors)]
    t_start = time.perf_counter()
    kernel_ms = run_rows(device, kernel, [*bufs, d_out], W, H, PIXELS_PER_LAUNCH, progress,
                         dispatch)
    cl.enqueue_copy(device.queue, out, d_out)
    device.queue.finish()
    return {"rgba": out, "kernel_ms": kernel_ms,
            "wall_ms": 1e3 * (time.perf_counter() - t_start), "tree_ms": scene.tree_ms,
            "flags": features.flags()}
