"""Volumes: settings, the VolumeParams record and the render orchestration of the marcher and
the tracker. Each work-item owns its pixel (no float atomics), so an image depends only on
the scene, the settings and the seed."""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from . import layout, lights as lights_mod
from .dispatch import Dispatch
from .errors import UserError
from .features import VolumeFeatures
from .settings import (MAX_VALUE, STRS, VEC, CommonSettings, boolean, floats, in_range, knob,
                       one_of, rgb)

G_MAX = 0.999          # |g| is clamped here: HG at |g| = 1 is a delta
PIXELS_PER_LAUNCH = 1 << 16
# march: jittered ray marching (biased by the step, low noise); track: delta/ratio
# tracking on per-brick majorants (unbiased; step and shadow_step are unused).
ESTIMATORS = ("march", "track")
AOVS = ("depth", "transmittance")
# The finest march step, voxels: 50x the default's samples (bench error: finer steps buy
# nothing at 1 spp); a ray also never takes more than layout.MAX_RAY_SAMPLES (check_steps).
MIN_STEP = 0.01


def _phase_ok(v):
    if not (isinstance(v, tuple) and len(v) in (1, 3) and all(map(math.isfinite, v))):
        return "takes g1,g2,w (or one g) as finite numbers"
    if len(v) == 3 and not 0.0 <= v[2] <= 1.0:
        return "weight w must be in [0, 1]"
    return None


def _aovs_ok(v):
    if not isinstance(v, tuple) or any(a not in AOVS for a in v):
        return f"takes layers from {', '.join(AOVS)}"
    return None


@dataclass(frozen=True)
class VolumeSettings(CommonSettings):
    """How a volume is read and rendered (defaults, ranges and CLI/scene names: settings.knob)."""
    grid: str | None = knob(None, "density grid (default: 'density', else the only float "
                            "fog-volume grid)", toml=("volume", "grid"), kind=str,
                            show_default=False)
    emission_grid: str | None = knob(None, "grid emitting light, e.g. flame (off by default)",
                                     toml=("volume", "emission_grid"), kind=str,
                                     show_default=False)
    density_scale: float = knob(1.0, "sigma_t = scale * grid value, per world unit",
                                check=in_range(0, 1e30), toml=("volume", "density_scale"))
    albedo: float = knob(0.9, "single-scattering albedo sigma_s / sigma_t",
                         check=in_range(0, 1), toml=("volume", "albedo"))
    phase: tuple = knob((0.6, -0.3, 0.8), "w*HG(g1) + (1-w)*HG(g2); one value = a single "
                        "lobe; g > 0 scatters forward; |g| clamped to 0.999", metavar="G1,G2,W",
                        parse=floats(1, 3, "--phase"), check=_phase_ok, toml=("volume", "phase"),
                        kind=VEC)
    background: tuple = knob((0.0, 0.0, 0.0), "radiance behind the volume (one value = grey)",
                             metavar="R,G,B", parse=floats(1, 3, "--background"),
                             check=rgb(0, MAX_VALUE, n=(1, 3)), toml=("volume", "background"), kind=VEC)
    emission_scale: float = knob(1.0, "emitted radiance per unit length per emission-grid value",
                                 check=in_range(0, MAX_VALUE), toml=("volume", "emission_scale"))
    emission_temperature: float = knob(1500.0, "blackbody colour of the emission, kelvin",
                                       check=in_range(100, 1e5),
                                       toml=("volume", "emission_temperature"))
    step: float = knob(0.5, "primary march step, voxels",
                       check=in_range(MIN_STEP, 1e4), toml=("volume", "step"))
    shadow_step: float = knob(1.0, "shadow-ray march step, voxels",
                              check=in_range(MIN_STEP, 1e4), toml=("volume", "shadow_step"))
    estimator: str = knob("march", "march: ray marching with --step/--shadow-step (biased by the "
                          "step, low noise); track: delta/ratio tracking on the brick majorants "
                          "(unbiased, noisier; the reference)", check=one_of(ESTIMATORS),
                          choices=ESTIMATORS, toml=("volume", "estimator"))
    skip_empty: bool = knob(True, "march empty bricks too (the reference for empty-space skipping)",
                            check=boolean, flag="--no-skip", toml=("volume", "skip_empty"))
    aovs: tuple = knob((), "extra EXR layer (repeatable): depth -> Z (opacity-weighted mean "
                       "distance), transmittance -> T", flag="--aov", choices=AOVS,
                       check=_aovs_ok, toml=("volume", "aov"), kind=STRS, show_default=False)

    def __post_init__(self):
        if len(self.phase) == 1:
            object.__setattr__(self, "phase", (float(self.phase[0]), 0.0, 1.0))
        if len(self.background) == 1:
            object.__setattr__(self, "background", tuple(self.background) * 3)
        object.__setattr__(self, "aovs", tuple(dict.fromkeys(self.aovs)))
        super().__post_init__()

    @property
    def depth(self) -> bool:
        """Whether the kernel writes the depth layer."""
        return "depth" in self.aovs

    def clamped_phase(self):
        g1, g2, w = self.phase
        c1, c2 = (float(np.clip(g, -G_MAX, G_MAX)) for g in (g1, g2))
        if (c1, c2) != (g1, g2):
            warnings.warn(f"phase g clamped to |g| <= {G_MAX} (HG at |g| = 1 is a delta)")
        return c1, c2, w


def blackbody_rgb(kelvin: float) -> np.ndarray:
    """Approximate linear-sRGB colour of a blackbody: Planck's law sampled at 610, 550
    and 465 nm, normalised so the largest channel is 1."""
    lam = np.array([610e-9, 550e-9, 465e-9])
    h, c, k = 6.62607015e-34, 2.99792458e8, 1.380649e-23
    with np.errstate(over="ignore"):
        spectral = 1.0 / (lam ** 5 * np.expm1(h * c / (lam * k * kelvin)))
    return spectral / spectral.max()


def track_majorants(bricks, settings: VolumeSettings) -> np.ndarray:
    """Per-slot tracking rate (per world unit) for cl/track_volume.cl: density_scale x the
    brick's maximum (which bounds its trilinear density), raised to one point per voxel in
    bricks that emit, so emission where the density is zero is still sampled."""
    mu = settings.density_scale * np.asarray(bricks.majorant, np.float64)
    if bricks.emission is not None and bricks.emission_max is not None:
        emits = np.asarray(bricks.emission_max) > 0
        mu = np.where(emits, np.maximum(mu, 1.0 / bricks.voxel_size), mu)
    return np.minimum(mu, 1e30).astype(np.float32)


def occupied_bricks(bricks) -> np.ndarray:
    """(n, 4) int32: brick coordinates (bx, by, bz, 0) of the stored (non-empty) bricks,
    the list the tiled kernel culls per tile."""
    idx = np.flatnonzero(np.asarray(bricks.table) >= 0)
    occ = np.zeros((len(idx), 4), np.int32)
    occ[:, :3] = np.stack(np.unravel_index(idx, tuple(int(d) for d in bricks.dims)), axis=1)
    return occ


def volume_params(bricks, settings: VolumeSettings | None = None):
    """(VolumeParams record, world -> local 4x4) for a Bricks volume and settings."""
    settings = settings or VolumeSettings()
    l2w = np.asarray(bricks.local_to_world, np.float64)
    w2l = np.linalg.inv(l2w)
    vs = float(bricks.voxel_size)
    g1, g2, w = settings.clamped_phase()
    params = layout.record(
        "VolumeParams",
        world_to_local0=[*w2l[0, :3], 0], world_to_local1=[*w2l[1, :3], 0],
        world_to_local2=[*w2l[2, :3], 0],
        local_to_world0=[*l2w[0, :3], 0], local_to_world1=[*l2w[1, :3], 0],
        local_to_world2=[*l2w[2, :3], 0],
        box_hi=[*(np.asarray(bricks.dims) * float(layout.BRICK)), 0], background=[*settings.background, 0],
        emission_color=[*(settings.emission_scale * blackbody_rgb(settings.emission_temperature)), 0],
        phase=[g1, g2, w, 0], dims=[*bricks.dims, 0], density_scale=settings.density_scale,
        albedo=settings.albedo, step=settings.step * vs, shadow_step=settings.shadow_step * vs,
        point_r2_min=(0.5 * vs) ** 2)
    return params, w2l


ENTRIES = {"march": "render_volume", "track": "track_volume"}


def check_steps(bricks, settings):
    """Refuse steps that would give a ray through this volume's box more samples than the
    kernels take (layout.MAX_RAY_SAMPLES, where float32 sample indices stop resolving)."""
    if settings.estimator != "march":
        return
    diag = float(np.linalg.norm(np.asarray(bricks.dims, np.float64) * layout.BRICK))
    for name, step in (("step", settings.step), ("shadow_step", settings.shadow_step)):
        if diag / step > layout.MAX_RAY_SAMPLES:
            raise UserError(f"a ray through this volume ({diag:.0f} voxels across) would take "
                            f"{diag / step:.3g} samples at {name} {step:g} voxels, more than "
                            f"{layout.MAX_RAY_SAMPLES}",
                            fix=f"give a {name} of at least {diag / layout.MAX_RAY_SAMPLES:.3g} "
                                f"(--{name.replace('_', '-')}, or [volume].{name})")


def plan(scene, device, variant=None):
    """The launch of a volume scene (render.render runs it): the marcher or the tracker."""
    from .render import Plan
    if variant is not None:
        raise UserError(f"the {variant!r} variant exists for glass only")
    bricks, settings = scene.content.bricks, scene.content.settings
    check_steps(bricks, settings)
    dispatch = Dispatch(settings.dispatch, tuple(settings.tile)).resolve(device)
    features = VolumeFeatures.from_scene(scene, dispatch)
    params, w2l = volume_params(bricks, settings)
    emission = bricks.emission if bricks.emission is not None else np.zeros(1, np.float32)
    inputs = [scene.camera.pack(w2l, settings.spp, settings.seed), params,
              lights_mod.pack(scene.lights, w2l), np.asarray(bricks.table, np.int32),
              np.asarray(bricks.data, np.float32), np.asarray(emission, np.float32)]
    extra = []
    if settings.estimator == "track":
        inputs.append(track_majorants(bricks, settings))
    else:                             # the occupied bricks, which only tiled culling reads
        occ = occupied_bricks(bricks) if features.tiled and features.skip_empty \
            else np.zeros((0, 4), np.int32)
        extra = [occ, np.int32(len(occ))]
    W, H = scene.camera.width, scene.camera.height
    # depth: (sum, weight) per pixel while samples are split across launches, then
    # (depth, weight); the layer is [..., 0]
    outputs = [("rgba", (H, W, 4)), ("depth", (H, W, 2) if settings.depth else (1,))]
    return Plan(ENTRIES[settings.estimator], features, inputs, outputs, dispatch,
                PIXELS_PER_LAUNCH, extra=extra, aovs=settings.aovs,
                info={"background": tuple(settings.background)})


def render_volume(bricks, camera, lights, settings: VolumeSettings, device, progress=None):
    """Render Bricks with the given camera, lights and settings (a shortcut for tests and
    benchmarks: render.render of the equivalent Scene). Returns render.Image.as_dict()."""
    from .render import render
    from .scene import Scene, VolumeContent
    scene = Scene.of(camera, lights, VolumeContent(bricks, settings))
    return render(scene, device, progress=progress).as_dict()
