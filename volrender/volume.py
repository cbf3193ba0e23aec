"""Volumes: settings, the VolumeParams record and the render orchestration of the marcher
(single scattering or its multiple-scattering octaves) and the path tracer (multiple
scattering, unbiased; the tracker is it at max depth 1). Each work-item owns its pixel (no
float atomics), so an image depends only on the scene, the settings and the seed."""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from . import blackbody, layout, lights as lights_mod
from .dispatch import Dispatch, Plan, is_gpu
from .environment import env_distribution, env_mode, texels as env_texels
from .errors import UserError
from .features import VolumeFeatures
from .settings import (MAX_VALUE, STRS, VEC, CommonSettings, boolean, floats, in_range, knob,
                       one_of, rgb)

G_MAX = 0.999          # |g| is clamped here: HG at |g| = 1 is a delta
PIXELS_PER_LAUNCH = 1 << 16
# march: jittered ray marching (biased by the step, low noise); track: delta/ratio
# tracking on per-brick majorants, single scattering (unbiased; step and shadow_step are
# unused); path: path tracing, the same walks, up to max_depth scattering events.
ESTIMATORS = ("march", "track", "path")
MAX_DEPTH = 256        # path estimator's default depth: converged (< 0.1%) on the real files at albedo <= 0.99
RR_DEPTH = 4           # path roulette from the 5th scattering event on
MS_OCTAVES_MAX = 16
# octave scales a, b, c: the best of bench error --fit-octaves (3 octaves; within 2% of the
# best objective for 3..8 octaves), docs/error_time.md
MS_SCALES = (0.2, 0.6, 0.5)
# the shadow march of octave k stops once b^k exp(-a^k tau) < this (relative to the light)
MS_CUTOFF = 1e-4
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
    albedo: tuple = knob((0.9,), "albedo sigma_s / sigma_t: one value, or R,G,B for a coloured "
                         "medium", metavar="A|R,G,B", parse=floats(1, 3, "--albedo"),
                         check=rgb(0, 1, n=(1, 3)), toml=("volume", "albedo"), kind=VEC)
    sigma_t_scale: tuple = knob((1.0, 1.0, 1.0), "per-channel scale on sigma_t (tinted smoke: "
                                "e.g. 0.8,1,1.3 lets red through and reddens the light behind)",
                                metavar="R,G,B", parse=floats(1, 3, "--sigma-t-scale"),
                                check=rgb(0, 1e30, n=(1, 3)), toml=("volume", "sigma_t_scale"),
                                kind=VEC)
    phase: tuple = knob((0.6, -0.3, 0.8), "w*HG(g1) + (1-w)*HG(g2); one value = a single "
                        "lobe; g > 0 scatters forward; |g| clamped to 0.999", metavar="G1,G2,W",
                        parse=floats(1, 3, "--phase"), check=_phase_ok, toml=("volume", "phase"),
                        kind=VEC)
    background: tuple = knob((0.0, 0.0, 0.0), "radiance behind the volume (one value = grey)",
                             metavar="R,G,B", parse=floats(1, 3, "--background"),
                             check=rgb(0, MAX_VALUE, n=(1, 3)), toml=("volume", "background"), kind=VEC)
    emission_scale: float = knob(1.0, "emitted radiance per unit length per emission-grid value",
                                 check=in_range(0, MAX_VALUE), toml=("volume", "emission_scale"))
    emission_temperature: float = knob(1500.0, "blackbody colour of the emission, kelvin "
                                       "(without --temperature-grid)", check=in_range(100, 1e5),
                                       toml=("volume", "emission_temperature"))
    temperature_grid: str | None = knob(None, "grid whose values give each voxel's blackbody "
                                        "colour, e.g. temperature (the emission grid gives the "
                                        "intensity)", toml=("volume", "temperature_grid"),
                                        kind=str, show_default=False)
    temperature_scale: float = knob(1.0, "kelvin = offset + scale * temperature-grid value "
                                    "(Blender: 1000, its 0..1 = 0..1000 K)",
                                    check=in_range(-1e6, 1e6), toml=("volume", "temperature_scale"))
    temperature_offset: float = knob(0.0, "kelvin at temperature-grid value 0",
                                     check=in_range(-1e6, 1e6),
                                     toml=("volume", "temperature_offset"))
    step: float = knob(0.5, "primary march step, voxels",
                       check=in_range(MIN_STEP, 1e4), toml=("volume", "step"))
    shadow_step: float = knob(1.0, "shadow-ray march step, voxels",
                              check=in_range(MIN_STEP, 1e4), toml=("volume", "shadow_step"))
    estimator: str = knob("march", "march: ray marching with --step/--shadow-step (biased by the "
                          "step, low noise; single scattering, or --ms-octaves); track: delta/"
                          "ratio tracking on the brick majorants, single scattering (unbiased, "
                          "noisier; the march's reference); path: path tracing, multiple "
                          "scattering up to --max-depth (unbiased)", check=one_of(ESTIMATORS),
                          choices=ESTIMATORS, toml=("volume", "estimator"))
    max_depth: int = knob(MAX_DEPTH, "path estimator: scattering events per path (1 = single "
                          "scattering); Russian roulette from the 5th on",
                          check=in_range(1, 100000, integer=True), toml=("volume", "max_depth"))
    ms_octaves: int = knob(1, "march: multiple-scattering octaves (Wrenninge et al. 2013); "
                           "1 = single scattering", check=in_range(1, MS_OCTAVES_MAX, integer=True),
                           toml=("volume", "ms_octaves"))
    ms_octave_scales: tuple = knob(MS_SCALES, "octave k scales sigma_t by A^k, its light by B^k and "
                                   "g by C^k (fitted by bench error to path-traced images)",
                                   metavar="A,B,C",
                                   parse=floats(3, name="--ms-octave-scales"),
                                   check=rgb(0, 1, n=(3,)), toml=("volume", "ms_octave_scales"))
    hide_env: bool = knob(False, "the camera does not see --env behind the volume (it still "
                          "lights it; --background is seen instead)", check=boolean,
                          toml=("volume", "hide_env"))
    skip_empty: bool = knob(True, "march empty bricks too (the reference for empty-space skipping)",
                            check=boolean, flag="--no-skip", toml=("volume", "skip_empty"))
    skip_runs: bool | None = knob(None, "skipping crosses a whole run of empty bricks in one "
                                  "walk (True) or one brick per sample (False); None: runs on "
                                  "CPUs, bricks on GPUs, the faster on each (README)",
                                  check=lambda v: None if v is None or isinstance(v, bool)
                                  else "must be True, False or None", flag=None,
                                  show_default=False)
    aovs: tuple = knob((), "extra EXR layer (repeatable): depth -> Z (opacity-weighted mean "
                       "distance), transmittance -> T", flag="--aov", choices=AOVS,
                       check=_aovs_ok, toml=("volume", "aov"), kind=STRS, show_default=False)

    def __post_init__(self):
        for name in ("albedo", "sigma_t_scale"):
            v = getattr(self, name)
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                v = (v,)
            if isinstance(v, tuple) and len(v) == 1:
                v = tuple(v) * 3
            object.__setattr__(self, name, v)
        if len(self.phase) == 1:
            object.__setattr__(self, "phase", (float(self.phase[0]), 0.0, 1.0))
        if len(self.background) == 1:
            object.__setattr__(self, "background", tuple(self.background) * 3)
        object.__setattr__(self, "aovs", tuple(dict.fromkeys(self.aovs)))
        super().__post_init__()
        if self.temperature_grid is not None and self.emission_grid is None:
            raise UserError("--temperature-grid colours the emission, but no --emission-grid "
                            "gives it", fix="add --emission-grid (e.g. flame)")

    @property
    def chromatic(self) -> bool:
        """Whether the medium differs between channels (albedo or sigma_t scale)."""
        return len(set(self.albedo)) > 1 or len(set(self.sigma_t_scale)) > 1

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


def emission_color(settings: VolumeSettings) -> np.ndarray:
    """rgb emitted per unit length per emission-grid value without a temperature grid:
    emission_scale x the blackbody colour of emission_temperature (volrender.blackbody)."""
    return settings.emission_scale * blackbody.rgb(settings.emission_temperature)


def track_majorants(bricks, settings: VolumeSettings) -> np.ndarray:
    """Per-slot tracking rate (per world unit) for cl/path_volume.cl: density_scale x the
    largest sigma_t scale x the brick's maximum (which bounds its trilinear density),
    raised to one point per voxel in bricks that emit, so emission where the density is
    zero is still sampled. The marcher skips the same empty bricks."""
    mu = settings.density_scale * max(settings.sigma_t_scale) * np.asarray(bricks.majorant, np.float64)
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


def octave_tau_stop(settings: VolumeSettings) -> float:
    """Grey shadow optical depth past which every octave's light is below MS_CUTOFF of
    the light's (b^k exp(-a^k tau) < MS_CUTOFF for all k; at least the single-scattering
    25), in every channel (divided by the smallest sigma_t scale)."""
    a, b, _ = settings.ms_octave_scales
    stop = 25.0
    for k in range(1, settings.ms_octaves):
        ak, bk = a ** k, b ** k
        if bk > 0:
            stop = max(stop, (math.log(bk) - math.log(MS_CUTOFF)) / max(ak, 1e-30))
    if settings.chromatic:
        stop /= max(min(settings.sigma_t_scale), 1e-30)
    return float(min(stop, 1e30))


def volume_params(bricks, settings: VolumeSettings | None = None, environment=None):
    """(VolumeParams record, world -> local 4x4) for a Bricks volume and settings."""
    settings = settings or VolumeSettings()
    l2w = np.asarray(bricks.local_to_world, np.float64)
    w2l = np.linalg.inv(l2w)
    vs = float(bricks.voxel_size)
    g1, g2, w = settings.clamped_phase()
    mode = env_mode(environment)
    env_h, env_w = environment.texels.shape[:2] if mode == 2 else (0, 0)
    n = blackbody.TABLE_SIZE
    bb_a = (n - 1) / (1.0 / blackbody.T_MIN - 1.0 / blackbody.T_MAX)
    params = layout.record(
        "VolumeParams",
        world_to_local0=[*w2l[0, :3], 0], world_to_local1=[*w2l[1, :3], 0],
        world_to_local2=[*w2l[2, :3], 0],
        local_to_world0=[*l2w[0, :3], 0], local_to_world1=[*l2w[1, :3], 0],
        local_to_world2=[*l2w[2, :3], 0],
        box_hi=[*(np.asarray(bricks.dims) * float(layout.BRICK)), 0], background=[*settings.background, 0],
        emission_color=[*emission_color(settings), 0],
        phase=[g1, g2, w, 0], dims=[*bricks.dims, 0],
        albedo_rgb=[*settings.albedo, 0], extinction=[*settings.sigma_t_scale, 0],
        env_radiance=[*(environment.uniform if mode == 1 else (0, 0, 0)), 0],
        ms=[*settings.ms_octave_scales, octave_tau_stop(settings)],
        density_scale=settings.density_scale, albedo=settings.albedo[0],
        step=settings.step * vs, shadow_step=settings.shadow_step * vs,
        point_r2_min=(0.5 * vs) ** 2, env_width=env_w, env_height=env_h,
        env_visible=0.0 if settings.hide_env else 1.0, emission_scale=settings.emission_scale,
        temp_scale=settings.temperature_scale, temp_offset=settings.temperature_offset,
        bb_a=bb_a, bb_b=-bb_a / blackbody.T_MAX, bb_n=n,
        max_depth=1 if settings.estimator == "track" else settings.max_depth, rr_depth=RR_DEPTH)
    return params, w2l


ENTRIES = {"march": "render_volume", "track": "path_volume", "path": "path_volume"}


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


def plan(scene, device, variant=None, launch=None):
    """The launch of a volume scene (render.render runs it): the marcher or the path
    tracer (track = path at max depth 1)."""
    if variant is not None:
        raise UserError(f"the {variant!r} variant exists for glass only")
    bricks, settings = scene.content.bricks, scene.content.settings
    check_steps(bricks, settings)
    if settings.temperature_grid is not None and bricks.temperature is None:
        raise UserError(f"--temperature-grid {settings.temperature_grid}: the volume holds no "
                        "temperature grid", fix="load it with temperature_grid= (or convert the "
                        ".vdb again with --temperature-grid)")
    dispatch = Dispatch(settings.dispatch, tuple(settings.tile)).resolve(device)
    features = VolumeFeatures.from_scene(scene, dispatch, is_gpu(device),
                                         launch.tile_cap if launch else None)
    params, w2l = volume_params(bricks, settings, scene.environment)
    content = scene.content
    none = np.zeros(1, np.float32)
    emission = content.buffer(device, "emission") if bricks.emission is not None else none
    temperature = content.buffer(device, "temperature") if features.temperature else none
    env, cdf = (np.zeros((1, 4), np.float32), np.zeros(1, np.float32))
    if features.env == 2:
        env, cdf = env_texels(scene.environment)[0], env_distribution(scene.environment.texels)
    inputs = [scene.camera.pack(w2l, settings.spp, settings.seed), params,
              lights_mod.pack(scene.lights, w2l), content.buffer(device, "table"),
              content.buffer(device, "data"), emission, temperature, blackbody.table(), env, cdf]
    extra = []
    if settings.estimator != "march":
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
