"""Point clouds as molten glass: the settings and each frame's parameters and plan.

Every point is a sphere; the spheres melt together through the order-independent smooth
union of cl/sdf.h (support: sphere i matters only where d_i < min_j d_j + blend). What the
kernel reads about the spheres, the same for every camera, is built by spheres.py.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from . import layout, lights as lights_mod
from .camera import DEFAULT_FOV, frame_bounds
from .dispatch import Dispatch, Plan, is_gpu
from .environment import texels as env_texels
from .errors import UserError
from .features import GlassFeatures
from .render_info import RenderInfo
from .settings import (MAX_VALUE, NUM, CommonSettings, boolean, floats, in_range, knob, one_of,
                       rgb)
from .spheres import (MAX_EXTENT, PackedSpheres, eye_color, material_unit, sphere_bounds,
                      sphere_radii)

PIXELS_PER_LAUNCH = 1 << 14
NV_MAX_REGISTERS = 40         # per work-item, the glass kernel on NVIDIA (build_options)
UBER_BITS = layout.UBER_BITS   # uber-kernel runtime feature bits (VR_BIT_* in cl/structs.h)
ACCELS = ("auto", "grid", "tree", "none")
# --split-events by device (docs/error_time.md, issue 32): on CPUs one split (the camera
# hit's reflection and refraction) then one branch per event: x1.6 less time per sample,
# the same error per unit time within the measurement's spread, so a preview answers in
# seconds; 64 (every event splits) where the device is not known (the probes).
SPLIT_EVENTS_CPU = 1
SPLIT_EVENTS_GPU = 64
SPLIT_ALL = 64
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
    split_events: int | None = knob(None, "--glass-model full: surface events per path at "
                                    "which both Fresnel branches are traced; past them one "
                                    "branch goes on, chosen in proportion to its weight "
                                    "(unbiased, noisier per sample, cheaper); 0 = a path "
                                    "tracer's choice at every event (default: "
                                    f"{SPLIT_EVENTS_CPU} on CPUs, {SPLIT_EVENTS_GPU} on GPUs, "
                                    "docs/error_time.md)",
                                    check=in_range(0, 64, integer=True, allow_none=True),
                                    toml=("render", "split_events"), kind=int,
                                    show_default=False)
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
    relax: float = knob(1.6, "largest over-relaxed sphere tracing factor in [1, 1.9], "
                        "each step's chosen from the field's slope; 1 = plain (misses "
                        "nothing; bench error: x1.3 faster at the same error)",
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
        split_events=SPLIT_ALL if settings.split_events is None else settings.split_events)


def split_events(settings: GlassSettings, device) -> int:
    """--split-events, its default resolved for the device (SPLIT_EVENTS_CPU/GPU)."""
    if settings.split_events is not None:
        return settings.split_events
    return SPLIT_EVENTS_GPU if device is not None and is_gpu(device) else SPLIT_EVENTS_CPU


def describe_model(settings: GlassSettings, device) -> str:
    """The glass model a render used, for the status line."""
    if settings.glass_model != "full" or not settings.refraction:
        return f"glass {settings.glass_model}" if settings.refraction else "opaque"
    k = split_events(settings, device)
    if k >= settings.bounces:
        return "glass full"
    return f"glass full, both branches at {k} event{'s' if k != 1 else ''} then one"


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
    params["split_events"] = split_events(settings, device)
    eye = np.asarray(cam.origin, np.float64) - packed.centre
    if np.all(eye >= packed.box_lo) and np.all(eye <= packed.box_hi):
        params["eye_color"] = eye_color(packed, eye)
    colors = packed.colors if packed.colors is not None else np.zeros((1, 4), np.float32)
    spheres, grid_arrays = kernel_arrays(packed, params, device.context)
    info = RenderInfo(tree_ms=packed.tree_ms, accel=packed.accel, cells_ms=0.0,
                      model=describe_model(settings, device), note=packed.note or None)
    if packed.cells is not None:
        info = info.replace(cells_ms=packed.cells.build_ms, cells=packed.cells.summary())
    inputs = [("cam", scene.camera.pack(w2f, settings.spp, settings.seed)), ("gp", params),
              ("lights", lights_mod.pack(scene.lights, w2f)), ("spheres", spheres),
              ("nodes", packed.nodes), ("env", env), ("colors", colors),
              *zip(("bricks", "cells", "lists", "entries"), grid_arrays)]
    W, H = scene.camera.width, scene.camera.height
    return Plan("render_glass", features, inputs, [("rgba", (H, W, 4))], dispatch,
                PIXELS_PER_LAUNCH, info=info,
                build_options=build_options(features, device) + stack_option(params))


def stack_option(params) -> tuple:
    """The full model's branch stack sized to what can wait: at most one branch per split
    event (private memory: a smaller stack spills less on GPUs)."""
    split = int(params["split_events"][0])
    return (f"-DVR_GLASS_STACK={min(max(split, 1), 4)}",) if split < 4 else ()


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
    """The spheres and the four support-cell arrays the kernel reads (cl/cells.h: bricks,
    cells, the walk's lists and entries), with the grid's fields of the GlassParams record
    `params` set; stand-ins without cells. They stay the builder's device buffers when
    `context` is the builder's (no copy)."""
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
        return packed.spheres, [*grid.buffers[:2], *grid.walk_device]
    return packed.spheres, [grid.bricks, grid.cells, grid.walk, grid.entries]
