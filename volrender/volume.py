"""Volumes: settings, the VolumeParams record and the render orchestration of the marcher
(single scattering or its multiple-scattering octaves) and the path tracer (multiple
scattering, unbiased; the tracker is it at max depth 1). Each work-item owns its pixel (no
float atomics), so an image depends only on the scene, the settings and the seed.

Long file: one idea, the volume integrator's host side; VolumeSettings (160 lines of
knobs: each option's one home) is most of it. The automatic estimator and the octave
constants (auto_*, octave_*) are the seam if it grows further."""
from __future__ import annotations

import dataclasses
import math
import warnings
import weakref
from dataclasses import dataclass, replace

import numpy as np

from . import blackbody, layout, lights as lights_mod
from .dispatch import Dispatch, Plan, is_gpu
from .environment import env_distribution, env_mode, texels as env_texels
from .errors import UserError
from .features import VolumeFeatures
from .lights import counts
from .render_info import RenderInfo
from .settings import (MAX_VALUE, NUM, STRS, VEC, CommonSettings, boolean, floats, in_range,
                       knob, number, one_of, rgb)

G_MAX = 0.999          # |g| is clamped here: HG at |g| = 1 is a delta
PIXELS_PER_LAUNCH = 1 << 16
# march: jittered ray marching (biased by the step, low noise); track: delta/ratio
# tracking on per-brick majorants, single scattering (unbiased; step and shadow_step are
# unused); path: path tracing, the same walks, up to max_depth scattering events.
ESTIMATORS = ("auto", "march", "track", "path")
CACHE_MODES = ("auto", "on", "off")       # --light-cache (light_cache.py)
# auto (auto_estimator): single scattering where a scattered photon scatters again with
# probability < AUTO_MS_PROBABILITY; else the path estimator or the march with AUTO_OCTAVES
# octave bands, by auto_model's predicted error within AUTO_BUDGET_MS
AUTO_OCTAVES = 4
AUTO_MS_PROBABILITY = 0.2
# auto's model of error and cost (auto_model; fitted in docs/error_time.md, "auto", on the
# H200 run of bench/ms_refs.py and bench/auto_cost.py on 2-core PoCL)
AUTO_TARGET = 0.08                  # the path estimator's samples aim at this error
AUTO_BUDGET_MS = 3000.0             # ... within this much kernel time
AUTO_PATH_NOISE = 1.0               # its relative RMSE on covered pixels at 1 spp
# the path estimator only where its predicted error is at most this times the march's:
# the march's own cost is not modelled (it is far cheaper per image), so path tracing must
# buy a clear gain (0190 at 320x240 on a CPU: 9 % in ~7 s of kernel against 12 % in 0.3 s)
AUTO_PATH_GAIN = 0.5
AUTO_MARCH_ERROR = (-2.361, 0.691, 0.162)
# the march with the light cache's scattering orders (--ms-orders, where auto bakes it):
# ln error = c0 + c1 L + c2 n, fitted on the four scattering real files (160x120, weighted
# 3 each) and six synthetic media against the path estimator (0.52 rms in ln;
# docs/error_time.md)
AUTO_ORDERS_ERROR = (-3.837, 0.394, 0.132)
# ... from this many pixels (auto runs before the camera exists, so before the cache's
# cost model: at 640x480 it bakes for the four files, at 160x120 for 0190 alone)
AUTO_ORDERS_PIXELS = 320 * 240
# ... times this where a GPU bakes 1- or 2-voxel nodes for a dense medium (light_cache.gpu_fine):
# WDAS on the H200 at 1080p, 7.1 % (1-voxel nodes, 6 orders) and 13.3 % (2, 6) against
# 22.7 % (4-voxel, 3), the one dense file measured (docs/error_time.md)
AUTO_FINE_ERROR = {1: 0.31, 2: 0.59}
# on a CPU auto's march steps up to AUTO_STEP_MAX voxels in thin media: the step's typical
# optical depth (optical_size's sigma_voxel x the step) at most AUTO_STEP_TAU (PoCL,
# 320x240, 1 spp, the cache on, against the default step at 32 spp, covered pixels: smoke
# step 0.5 / 1 / 2 voxels 0.32 / 0.33 / 0.61 % relative RMSE, kernel 446 / 201 / 93 ms;
# dragon 0.12 / 0.13 / 0.19 %, 241 / 74 / 58 ms; docs/error_time.md); not where the volume
# emits, nor with --step or --shadow-step given, nor on GPUs (their kernels are a few ms),
# nor for single scattering (a thin medium's cheap march: kept as it was)
AUTO_STEP_TAU = 0.16
AUTO_STEP_MAX = 2.0
AUTO_PATH_MS = {"cpu": 2.04e-4, "gpu": 1.16e-6}   # ms per pixel-sample at tau 0
AUTO_CPU_UNITS = 2                  # the compute units AUTO_PATH_MS["cpu"] was measured on
AUTO_PATH_SLOPE = 0.512
EMISSION_LAWS = ("auto", "colour", "blackbody")
ADAPTIVE_MIN_PASSES = 4      # passes before the noise estimate is trusted
ADAPTIVE_MAX_SPP = 1 << 20   # samples per pixel at most, over all passes
ADAPTIVE_CAP_SPP = 4096      # --max-spp's default: where an unreachable --noise-target stops
COVERED_ALPHA = 0.05         # the noise estimate covers pixels above this alpha (the medium's)
MAX_DEPTH = 256        # path estimator's default depth: converged (< 0.1%) on the real files at albedo <= 0.99
RR_DEPTH = 4           # path roulette from the 5th scattering event on
MS_OCTAVES_MAX = 16
# octave parameters D, G, C (cl/march.h): the closing band's depth scale is
# A_inf = min(1, D sqrt(3 (1 - albedo) (1 - g_mean))), a light's bands weigh G albedo and
# scatter with g C^(u_k), the environment's weigh albedo. D and C: fitted by bench error
# --fit-octaves; G by default from OCTAVE_GAIN (octave_gain; docs/error_time.md)
MS_SCALES = (0.5, 2.8, 0.2)
# G = exp(c . (1, g, g^2, L, L g, L n, L g n)) / (1 - A_inf), g the phase's mean cosine,
# L = ln(1 + tau) (optical_size), n = -ln(1 - albedo) (largest channel, albedo <= 0.999):
# least squares in ln G on the gains that best match the path estimator (issue 33,
# bench/ms_refs.py on the H200: 96 sun-lit synthetic media, tau 0.05-19, albedo 0.5-0.99,
# g 0-0.8, and the four scattering real files at their defaults, weighted 6 each)
OCTAVE_GAIN = (0.0109, 1.6805, -2.9341, 0.1176, -0.2697, 0.0309, 0.178)
# the shadow march stops once every band's transmittance is below this
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
    emission_law: str = knob("auto", "colour: the emission grid x scale gives the brightness, the "
                             "blackbody its colour (brightest channel 1); blackbody: brightness "
                             "also rises as T^4 (Stefan-Boltzmann, Blender's blackbody "
                             "intensity: 1500 K -> 0.09, 3000 K -> 1.46 per unit length); auto: "
                             "blackbody with --temperature-grid, else colour",
                             check=one_of(EMISSION_LAWS), choices=EMISSION_LAWS,
                             toml=("volume", "emission_law"))
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
    estimator: str = knob("auto", "auto: single scattering where albedo and optical depth "
                          "make multiple scattering small; else the path estimator where a model "
                          "of error and cost (depth, albedo, pixels, device) predicts it at "
                          "half the error of the march with --ms-octaves 4 within 3 s, else "
                          "that march (the choice and its predicted error are printed); march: "
                          "ray marching with --step/--shadow-step (biased by the step, low "
                          "noise; single scattering, or --ms-octaves); "
                          "track: delta/"
                          "ratio tracking on the brick majorants, single scattering (unbiased, "
                          "noisier; the march's reference); path: path tracing, multiple "
                          "scattering up to --max-depth (unbiased)", check=one_of(ESTIMATORS),
                          choices=ESTIMATORS, toml=("volume", "estimator"))
    max_depth: int = knob(MAX_DEPTH, "path estimator: scattering events per path (1 = single "
                          "scattering); Russian roulette from the 5th on",
                          check=in_range(1, 100000, integer=True), toml=("volume", "max_depth"))
    ms_octaves: int | None = knob(None, "march: multiple-scattering octave bands (energy-"
                                  "conserving, cl/march.h); 1 = single scattering (default: "
                                  "1 with --estimator march, auto's choice with auto)",
                                  check=in_range(1, MS_OCTAVES_MAX, integer=True, allow_none=True),
                                  toml=("volume", "ms_octaves"), kind=int, show_default=False)
    ms_octave_scales: tuple | None = knob(None, "octave bands (cl/march.h): D scales the last "
                                          "band's diffusion depth sqrt(3(1-albedo)(1-g)); a "
                                          "light's bands weigh G x albedo and scatter with g "
                                          "C^(k/(N-1)); a white furnace returns its light at any "
                                          "D, G, C (default: D 0.5, C 0.2, G from the medium's "
                                          "optical depth, albedo and phase, fitted to path-traced "
                                          "images and printed)",
                                          metavar="D,G,C",
                                          parse=floats(3, name="--ms-octave-scales"),
                                          check=lambda v: None if v is None
                                          else rgb(0, 100, n=(3,))(v),
                                          toml=("volume", "ms_octave_scales"), kind=VEC,
                                          show_default=False)
    light_cache: str = knob("auto", "march: bake the light reaching the medium once per scene "
                            "and lights on a coarse grid and read it instead of a shadow march "
                            "per sample per light (volrender/light_cache.py); auto: where the "
                            "cost model says the bake and the short exact marches near each "
                            "sample cost less than the exact march (the choice is printed); "
                            "off: the exact shadow march", check=one_of(CACHE_MODES),
                            choices=CACHE_MODES, toml=("volume", "light_cache"))
    light_cache_cell: int | None = knob(None, "light cache node spacing, voxels (1, 2, 4 or 8; "
                                        "default: the cost model's cheapest)",
                                        check=lambda v: None if v in (None, 1, 2, 4, 8)
                                        else "must be 1, 2, 4 or 8", toml=("volume",
                                        "light_cache_cell"), kind=int, show_default=False)
    ms_orders: int | None = knob(None, "march with the light cache and multiple scattering: "
                          "scattering orders 2 to N+1 propagated over the cache's nodes from "
                          "the baked light (the rest as a geometric tail; "
                          "volrender/light_cache.py) instead of the octave bands; 0: the octave "
                          "bands; default: 3, or 6 on 1- or 2-voxel nodes in a dense medium",
                          check=lambda v: None if v is None or isinstance(v, int) and not
                          isinstance(v, bool) and (v == 0 or 2 <= v <= 16) else "must be 0 (the octave bands) or "
                          "2 to 16 (one order's tail, from the phase-weighted first, overshoots)",
                          toml=("volume", "ms_orders"), kind=int, show_default=False)
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
    noise_target: float | None = knob(None, "render passes until the estimated relative "
                                      "error of the pixels the volume covers (alpha > "
                                      f"{COVERED_ALPHA:g}), the RMS of their standard errors "
                                      "over their RMS value, is below this (e.g. 0.05: 5 per cent; "
                                      "from the spread of independent passes, at least "
                                      f"{ADAPTIVE_MIN_PASSES}), or --max-spp or --time-limit "
                                      "is reached; best with --estimator path",
                                      check=in_range(1e-4, 10, allow_none=True),
                                      toml=("render", "noise_target"), kind=NUM,
                                      parse=number("--noise-target"), show_default=False)
    time_limit: float | None = knob(None, "render passes until this many seconds have passed "
                                    "(with --noise-target: whichever comes first); the first "
                                    "pass is one sample per pixel, then passes are sized to "
                                    "fit, and one that would overrun is dropped",
                                    check=in_range(1e-3, 1e7, allow_none=True),
                                    toml=("render", "time_limit"), kind=NUM,
                                    parse=number("--time-limit"), show_default=False)
    max_spp: int = knob(ADAPTIVE_CAP_SPP, "--noise-target: samples per pixel at most over "
                        "all passes (a target the render cannot reach stops here and says "
                        "what it reached)", check=in_range(1, ADAPTIVE_MAX_SPP, integer=True),
                        toml=("render", "max_spp"))
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
    def octaves(self) -> int:
        """The octave bands the marcher runs (1: single scattering)."""
        return self.ms_octaves or 1

    @property
    def blackbody_law(self) -> bool:
        """Whether emission follows the blackbody intensity law (emission_law)."""
        if self.emission_law == "auto":
            return self.temperature_grid is not None
        return self.emission_law == "blackbody"

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
    emission_scale x the blackbody colour of emission_temperature (volrender.blackbody),
    or its radiance under the intensity law (blackbody.radiance)."""
    if settings.blackbody_law:
        return settings.emission_scale * blackbody.radiance(settings.emission_temperature)
    return settings.emission_scale * blackbody.rgb(settings.emission_temperature)


_NONZERO = {}        # id(bricks) -> (id(data), count, mean) of the non-zero voxels


def optical_size(bricks, settings: VolumeSettings) -> dict:
    """A typical optical depth of the medium: the mean sigma_t over its non-zero voxels
    (largest channel) times the edge of a cube of their volume (world units), the chance
    that a photon scattered inside scatters again, albedo (1 - exp(-tau)), and that mean
    sigma_t times a voxel (sigma_voxel: the optical depth across one)."""
    key = id(bricks.data)
    if _NONZERO.get(id(bricks), (None,))[0] != key:
        own = np.asarray(bricks.data)[:, :-1, :-1, :-1]
        nz = own[own > 0]
        _NONZERO[id(bricks)] = (key, int(nz.size), float(nz.mean()) if nz.size else 0.0)
        weakref.finalize(bricks, _NONZERO.pop, id(bricks), None)
    _, count, mean = _NONZERO[id(bricks)]
    if count == 0:
        return {"tau": 0.0, "probability": 0.0, "albedo": max(settings.albedo), "sigma_voxel": 0.0}
    sigma = settings.density_scale * max(settings.sigma_t_scale) * mean
    size = float(count) ** (1.0 / 3.0) * bricks.voxel_size
    tau = sigma * size
    alb = max(settings.albedo)
    return {"tau": tau, "probability": alb * -math.expm1(-tau), "albedo": alb,
            "sigma_voxel": sigma * bricks.voxel_size}


def path_aim(march_error: float) -> float:
    """The error auto's path samples aim at: AUTO_TARGET, or what the path estimator must
    reach to be chosen (AUTO_PATH_GAIN x the march's) where lower, but not below half of
    AUTO_TARGET (at most 4x its samples)."""
    return max(0.5 * AUTO_TARGET, min(AUTO_TARGET, AUTO_PATH_GAIN * march_error))


def auto_model(bricks, settings: VolumeSettings, pixels: int, gpu: bool = False,
               compute_units: int | None = None) -> dict:
    """auto's model of error and cost (docs/error_time.md, "auto"): for a medium of
    typical optical depth tau and albedo a (optical_size), with L = ln(1 + tau),
    n = -ln(1 - a):
    * the march's error (relative RMSE on covered pixels): with the light cache's
      scattering orders (--ms-orders not 0, --light-cache on, or auto from
      AUTO_ORDERS_PIXELS pixels) exp(AUTO_ORDERS_ERROR . (1, L, n)), x AUTO_FINE_ERROR[c]
      where a GPU bakes c-voxel nodes for it (light_cache.gpu_fine; fine: (c, bake ms)); with the octave bands e^AUTO_MARCH_ERROR[0] L^AUTO_MARCH_ERROR[1]
      e^(AUTO_MARCH_ERROR[2] n);
    * the path estimator's: AUTO_PATH_NOISE / sqrt(spp) (it is unbiased);
    * a path sample's kernel time: pixels x AUTO_PATH_MS[device] (1 + tau)^AUTO_PATH_SLOPE
      (CPU: per AUTO_CPU_UNITS compute units);
    the path's samples: enough for path_aim, at most what AUTO_BUDGET_MS allows, or --spp
    where it is above 1 (a count the user chose is kept)."""
    o = optical_size(bricks, settings)
    big_l, n = math.log1p(o["tau"]), -math.log1p(-min(o["albedo"], 0.999))
    orders = settings.ms_orders != 0 and settings.light_cache != "off" and \
        (pixels >= AUTO_ORDERS_PIXELS or settings.light_cache == "on")
    fine = None
    if orders:
        c0, c1, c2 = AUTO_ORDERS_ERROR
        march_error = min(1.0, math.exp(c0 + c1 * big_l + c2 * n))
        if gpu and settings.light_cache_cell is None:
            from .light_cache import gpu_fine
            fine = gpu_fine(int(bricks.n_slots), o["tau"], settings.ms_orders)
            if fine is not None:
                march_error *= AUTO_FINE_ERROR[fine[0]]
    else:
        c0, c1, c2 = AUTO_MARCH_ERROR
        march_error = min(1.0, math.exp(c0) * max(big_l, 1e-6) ** c1 * math.exp(c2 * n))
    per = AUTO_PATH_MS["gpu" if gpu else "cpu"]
    if not gpu and compute_units:
        per *= AUTO_CPU_UNITS / compute_units
    sample_ms = pixels * per * (1.0 + o["tau"]) ** AUTO_PATH_SLOPE
    want = math.ceil((AUTO_PATH_NOISE / path_aim(march_error)) ** 2)
    spp = max(1, min(want, int(AUTO_BUDGET_MS / max(sample_ms, 1e-9))))
    if settings.spp > 1 and not adaptive(settings):   # --spp given: weighed at that count
        spp = settings.spp
    return {**o, "march_error": march_error, "march_orders": orders, "fine": fine,
            "path_sample_ms": sample_ms, "path_spp": spp,
            "path_error": AUTO_PATH_NOISE / math.sqrt(spp), "path_ms": spp * sample_ms,
            "device": "GPU" if gpu else "CPU", "pixels": pixels}


def auto_step(bricks, settings: VolumeSettings, gpu: bool) -> float:
    """The step of auto's march with multiple scattering: the default, or on a CPU in a thin
    medium that does not emit up to AUTO_STEP_MAX voxels, at AUTO_STEP_TAU typical optical depth a step; the
    given step where --step or --shadow-step is not the default."""
    fields = VolumeSettings.__dataclass_fields__
    default = fields["step"].default
    if gpu or bricks.emission is not None or (settings.step, settings.shadow_step) != (
            default, fields["shadow_step"].default):
        return settings.step
    sv = optical_size(bricks, settings)["sigma_voxel"]
    return min(AUTO_STEP_MAX, max(default, AUTO_STEP_TAU / max(sv, 1e-30)))


def auto_estimator(bricks, settings: VolumeSettings, pixels: int | None = None, device=None):
    """(settings, note): --estimator auto resolved for this volume, `pixels` (default
    640x480) on `device` (None: a CPU). Single scattering (the march, one band) where a
    scattered photon scatters again with probability < AUTO_MS_PROBABILITY (it adds < 25 %
    to single scattering's light); else the path estimator where auto_model predicts it
    at most AUTO_PATH_GAIN x the march's error within AUTO_BUDGET_MS (dense bright clouds,
    GPUs, small images), at the samples that reach AUTO_TARGET (or --spp if more; its --spp per pass
    with --noise-target / --time-limit); else the march with AUTO_OCTAVES octave bands
    (their gain G printed; also whenever --step or --shadow-step are not the defaults: the
    march was tuned). --ms-octaves N given: the march with N bands. Other estimators pass
    unchanged (no note)."""
    if settings.estimator != "auto":
        return settings, None
    gpu = False
    units = None
    if device is not None and hasattr(device, "device"):
        gpu, units = is_gpu(device), int(device.device.max_compute_units)
    m = auto_model(bricks, settings, pixels or 640 * 480, gpu, units)
    why = (f"albedo {m['albedo']:.3g}, typical optical depth {m['tau']:.3g}: a scattered "
           f"photon scatters again with probability {m['probability']:.2f}")
    if settings.ms_octaves is not None:
        n = settings.ms_octaves
        out = replace(settings, estimator="march", ms_octaves=n)
        what = f"{n} octave bands" if n > 1 else "single scattering"
        return out, f"estimator auto: march, {what} (--ms-octaves {n} given; {why})"
    if m["probability"] < AUTO_MS_PROBABILITY:
        return (replace(settings, estimator="march", ms_octaves=1),
                f"estimator auto: single scattering (march; {why}, below "
                f"{AUTO_MS_PROBABILITY:g}); --ms-octaves {AUTO_OCTAVES} adds multiple scattering")
    step = auto_step(bricks, settings, gpu)
    stepped = (f"; march step {step:.2g} voxels (a thin medium on a CPU: --step "
               f"{settings.step:g} for the default's)" if step != settings.step else "")
    gain = octave_gain(settings, m["tau"])
    how = ("the light cache's scattering orders where baked, else "
           if m["march_orders"] else "")
    if m["fine"] is not None:
        how = (f"the light cache's scattering orders on {m['fine'][0]}-voxel nodes (a dense "
               f"medium on a GPU: bake ~{m['fine'][1]:.0f} ms) where baked, else ")
    march = (f"march with {how}{AUTO_OCTAVES} octave bands (gain G {gain:.2f}): predicted "
             f"error {m['march_error']:.0%}")
    fields = VolumeSettings.__dataclass_fields__
    tuned = (settings.step, settings.shadow_step) != (fields["step"].default,
                                                      fields["shadow_step"].default)
    if m["path_error"] <= AUTO_PATH_GAIN * m["march_error"] and not tuned:
        spp = settings.spp if adaptive(settings) else max(settings.spp, m["path_spp"])
        return (replace(settings, estimator="path", spp=spp),
                f"estimator auto: path, {spp} spp: predicted error {m['path_error']:.0%} on "
                f"covered pixels in ~{m['path_ms'] / 1e3:.2g} s of kernel on a {m['device']} "
                f"({march}; {why})")
    return (replace(settings, estimator="march", ms_octaves=AUTO_OCTAVES, step=step),
            f"estimator auto: multiple scattering ({march} on covered pixels; the path "
            f"estimator: {m['path_error']:.0%} in ~{m['path_ms'] / 1e3:.2g} s of kernel on a "
            f"{m['device']}; {why}){stepped}; --estimator path for the unbiased image")


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


def mean_cosine(settings: VolumeSettings) -> float:
    """The phase's mean cosine: w g1 + (1 - w) g2 (clamped g)."""
    g1, g2, w = settings.clamped_phase()
    return w * g1 + (1.0 - w) * g2


def octave_gain(settings: VolumeSettings, tau: float) -> float:
    """The lights' band gain G (OCTAVE_GAIN) for a medium of typical optical depth tau
    (optical_size), or the G of --ms-octave-scales when given."""
    if settings.ms_octave_scales is not None:
        return float(settings.ms_octave_scales[1])
    g = mean_cosine(settings)
    alb = min(max(settings.albedo), 0.999)
    big_l, n = math.log1p(max(tau, 0.0)), -math.log1p(-alb)
    f = (1.0, g, g * g, big_l, big_l * g, big_l * n, big_l * g * n)
    a_inf = float(np.max(octave_decay(settings)))
    return math.exp(sum(c * x for c, x in zip(OCTAVE_GAIN, f))) / max(1.0 - a_inf, 1e-3)


def octave_scales(settings: VolumeSettings, bricks=None) -> tuple:
    """(D, G, C): --ms-octave-scales, or the defaults with G from octave_gain (the medium's
    optical size from `bricks`; without them, MS_SCALES' G)."""
    if settings.ms_octave_scales is not None:
        return tuple(settings.ms_octave_scales)
    g = MS_SCALES[1] if bricks is None else octave_gain(settings, optical_size(bricks, settings)["tau"])
    return MS_SCALES[0], g, MS_SCALES[2]


def octave_decay(settings: VolumeSettings) -> np.ndarray:
    """A_inf per channel: the closing octave band's optical-depth scale (cl/march.h),
    min(1, D sqrt(3 (1 - albedo) (1 - g_mean))): the decay rate of diffuse light deep in
    the medium relative to sigma_t (diffusion theory); 0 for albedo 1."""
    d = (settings.ms_octave_scales or MS_SCALES)[0]
    alb = np.asarray(settings.albedo, np.float64)
    one_g = max(1.0 - mean_cosine(settings), 0.0)
    return np.minimum(1.0, d * np.sqrt(3.0 * np.clip(1.0 - alb, 0.0, 1.0) * one_g))


def octave_tau_stop(settings: VolumeSettings) -> float:
    """Grey shadow optical depth past which every band's light is below MS_CUTOFF of the
    light's (exp(-A_inf s_c tau) < MS_CUTOFF in every channel c; at least the
    single-scattering 25)."""
    stop = layout.SHADOW_TAU_STOP
    if settings.octaves > 1:
        rate = octave_decay(settings) * (np.asarray(settings.sigma_t_scale, np.float64)
                                         if settings.chromatic else 1.0)
        low = float(np.min(rate))
        stop = max(stop, -math.log(MS_CUTOFF) / low) if low > 0 else math.inf
    elif settings.chromatic:
        stop /= max(min(settings.sigma_t_scale), 1e-30)
    return float(min(stop, 1e30))


def octave_log_decay(settings: VolumeSettings) -> np.ndarray:
    """ln A_inf per channel for VolumeParams.ms_decay (floored at -80: exp of it is 0 in
    float32, and 0 x it stays finite)."""
    with np.errstate(divide="ignore"):
        return np.maximum(np.log(octave_decay(settings)), -80.0)


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
        emission_color=[*emission_color(settings),
                        blackbody.INTENSITY_K if settings.blackbody_law else 0.0],
        phase=[g1, g2, w, 0], dims=[*bricks.dims, 0],
        albedo_rgb=[*settings.albedo, 0], extinction=[*settings.sigma_t_scale, 0],
        env_radiance=[*(environment.uniform if mode == 1 else (0, 0, 0)), 0],
        ms=[*octave_scales(settings, bricks)[1:], 0.0, octave_tau_stop(settings)],
        ms_decay=[*octave_log_decay(settings), 0],
        density_scale=settings.density_scale, albedo=settings.albedo[0],
        step=settings.step * vs, shadow_step=settings.shadow_step * vs,
        point_r2_min=(0.5 * vs) ** 2, env_width=env_w, env_height=env_h,
        env_visible=0.0 if settings.hide_env else 1.0, emission_scale=settings.emission_scale,
        temp_scale=settings.temperature_scale, temp_offset=settings.temperature_offset,
        bb_a=bb_a, bb_b=-bb_a / blackbody.T_MAX, bb_n=n,
        max_depth=1 if settings.estimator == "track" else settings.max_depth, rr_depth=RR_DEPTH)
    return params, w2l


ENTRIES = {"march": "render_volume", "track": "path_volume", "path": "path_volume"}


def resolved(scene, device=None):
    """The scene with --estimator auto resolved (auto_estimator, for its pixels on
    `device`), and the note saying so (None when nothing was to resolve)."""
    settings, note = auto_estimator(scene.content.bricks, scene.content.settings,
                                    scene.camera.width * scene.camera.height, device)
    if note is None:
        return scene, None
    return scene.replace(content=dataclasses.replace(scene.content, settings=settings)), note


def check_steps(bricks, settings):
    """Refuse steps that would give a ray through this volume's box more samples than the
    kernels take (layout.MAX_RAY_SAMPLES, where float32 sample indices stop resolving)."""
    if settings.estimator not in ("march", "auto"):
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
    scene, note = resolved(scene, device)
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
    inputs = [("cam", scene.camera.pack(w2l, settings.spp, settings.seed)), ("vp", params),
              ("lights", lights_mod.pack(scene.lights, w2l)),
              ("table", content.buffer(device, "table")), ("data", content.buffer(device, "data")),
              ("emission", emission), ("temperature", temperature), ("bb", blackbody.table()),
              ("env", env), ("cdf", cdf)]
    extra = []
    cache_info = {}
    if settings.estimator != "march":
        inputs.append(("majorant", track_majorants(bricks, settings)))
    else:                             # the occupied bricks, which only tiled culling reads
        occ = occupied_bricks(bricks) if features.tiled and features.skip_empty \
            else np.zeros((0, 4), np.int32)
        cache, cache_info = light_cache_of(scene, device, features, params, inputs)
        if cache is not None:
            features = dataclasses.replace(features, light_cache=cache.choice.cell,
                                           **ms_cache_fields(settings, cache.choice))
        extra = [("light_cache", cache.buffer if cache is not None else none),
                 ("occ", occ), ("n_occ", np.int32(len(occ)))]
    W, H = scene.camera.width, scene.camera.height
    # depth: (sum, weight) per pixel while samples are split across launches, then
    # (depth, weight); the layer is [..., 0]
    outputs = [("rgba", (H, W, 4)), ("depth", (H, W, 2) if settings.depth else (1,))]
    return Plan(ENTRIES[settings.estimator], features, inputs, outputs, dispatch,
                PIXELS_PER_LAUNCH, extra=extra, aovs=settings.aovs,
                info=RenderInfo(background=tuple(settings.background),
                                estimator=settings.estimator, ms_octaves=settings.octaves,
                                estimator_note=note or None, **cache_info))


def ms_cache_fields(settings, choice) -> dict:
    """The features that replace the octave bands by the cache's propagated orders
    (choice.ms_orders > 0): single scattering plus the cache's ms channels."""
    return {"ms_octaves": 1, "ms_cache": True} if choice.ms_orders else {}


def light_cache_choice(scene, device=None):
    """light_cache.Choice for a resolved volume scene on `device` (None: a CPU; its cost
    model; cell 0: none)."""
    from . import light_cache
    n_suns, n_points = counts(scene.lights)
    bricks, settings = scene.content.bricks, scene.content.settings
    o = optical_size(bricks, settings)
    return light_cache.choose(bricks, settings, scene.camera, n_suns + n_points,
                              env_mode(scene.environment) > 0, tau=o["tau"],
                              ms_orders=settings.ms_orders if settings.octaves > 1 else 0,
                              gpu=device is not None and is_gpu(device),
                              sigma_voxel=o["sigma_voxel"])


def light_cache_of(scene, device, features, params, inputs):
    """(light_cache.LightCache or None, info): the scene's cache on `device`, baked on
    first use (light_cache.get), and what Image.info records of it."""
    from . import light_cache
    choice = light_cache_choice(scene, device)
    if not choice.cell:
        return None, {"light_cache": choice.note()}
    named = dict(inputs)
    before = light_cache.builds(scene.content)
    features = dataclasses.replace(features, **ms_cache_fields(scene.content.settings, choice))
    cache = light_cache.get(scene.content, device, features, params, named["lights"],
                            scene.environment, choice, ms_medium(scene.content.settings))
    params["cache_near"] = light_cache.near_length(scene.content.bricks, choice)
    baked = light_cache.builds(scene.content) > before
    return cache, {"light_cache": choice.note(), "light_cache_baked": baked,
                   "light_cache_bake_ms": cache.bake_ms if baked else 0.0,
                   "light_cache_bytes": choice.nbytes, "light_cache_cell": choice.cell}


def ms_medium(settings) -> tuple:
    """(albedo, extinction) per channel of the medium the cache's orders 2+ scatter in
    (extinction per unit of the grey sigma_t, as VR_EXTINCTION): the medium's own, with
    an isotropic phase (docs/error_time.md: the similarity relations' sigma_t (1 - a g),
    a (1 - g) / (1 - a g) for the forward phase came out darker, WDAS x0.69 against
    x0.88 of the path estimator)."""
    a = np.asarray(settings.albedo, np.float64)
    ext = np.asarray(settings.sigma_t_scale, np.float64) if settings.chromatic else np.ones(3)
    return a, ext


# --------------------------------------------------------------------------- adaptive passes

def adaptive(settings: VolumeSettings) -> bool:
    """Whether a render runs in passes (--noise-target or --time-limit)."""
    return settings.noise_target is not None or settings.time_limit is not None


def noise_estimate(mean, m2, n_passes, n_samples, covered=None):
    """(per-pixel standard error of the mean (H, W, 3), relative noise): from the passes'
    spread, m2 = sum_b n_b (mean_b - mean)^2 (Chan's update), the per-sample variance is
    m2 / (B - 1) and the mean's variance that over N samples; relative noise = RMS of the
    standard error over the RMS of the value, both over the `covered` pixels (a boolean
    H x W; default: alpha > COVERED_ALPHA, the whole image where none is), so a sky that
    is noiseless by construction does not dilute it: it reads as the relative RMS error
    `bench error` measures against a reference."""
    var = m2[..., :3] / max(n_passes - 1, 1) / max(n_samples, 1)
    se = np.sqrt(np.maximum(var, 0.0))
    if covered is None:
        covered = mean[..., 3] > COVERED_ALPHA
    if not np.any(covered):
        covered = np.ones(mean.shape[:2], bool)
    rms = float(np.sqrt((mean[..., :3][covered] ** 2).mean()))
    return se, float(np.sqrt(var[covered].mean())) / max(rms, 1e-30)
