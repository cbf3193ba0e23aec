"""Volumes: settings, the VolumeParams record and the render orchestration of the marcher and
the tracker. Each work-item owns its pixel (no float atomics), so an image depends only on
the scene, the settings and the seed."""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass

import numpy as np

from . import layout, lights as lights_mod
from .errors import UserError
from .features import VolumeFeatures
from .dispatch import Dispatch, run_rows, upload

G_MAX = 0.999          # |g| is clamped here: HG at |g| = 1 is a delta
PIXELS_PER_LAUNCH = 1 << 16
# march: jittered ray marching (biased by the step, low noise); track: delta/ratio
# tracking on per-brick majorants (unbiased; step and shadow_step are unused).
ESTIMATORS = ("march", "track")


@dataclass(frozen=True)
class VolumeSettings:
    density_scale: float = 1.0      # sigma_t = density_scale * grid value (per world unit)
    albedo: float = 0.9             # sigma_s / sigma_t
    phase: tuple = (0.6, -0.3, 0.8) # g1, g2, w: p = w HG(g1) + (1-w) HG(g2)
    background: tuple = (0.0, 0.0, 0.0)
    step: float = 0.5               # primary step, voxels
    shadow_step: float = 1.0        # shadow step, voxels
    spp: int = 1
    seed: int = 0
    shadows: bool = True
    skip_empty: bool = True
    emission_scale: float = 1.0     # radiance per unit length per emission-grid value
    emission_temperature: float = 1500.0  # K, colour of the emission
    depth: bool = False             # also return the opacity-weighted mean depth
    estimator: str = "march"        # "march" (cl/render_volume.cl) or "track" (cl/track_volume.cl)
    dispatch: str = "auto"          # volrender.dispatch: "auto", "fragment" or "tiled"
    tile: tuple = (8, 8)            # tiled: work-group tile, pixels (w, h)

    def __post_init__(self):
        def check(ok, msg):
            if not ok:
                raise UserError(msg)
        check(math.isfinite(self.density_scale) and 0 <= self.density_scale <= 1e30,
              f"--density-scale must be in [0, 1e30], got {self.density_scale}")
        check(0.0 <= self.albedo <= 1.0, f"--albedo must be in [0, 1], got {self.albedo}")
        check(len(self.phase) == 3 and all(map(math.isfinite, self.phase)),
              f"--phase takes g1,g2,w, got {self.phase}")
        check(0.0 <= self.phase[2] <= 1.0, f"--phase weight w must be in [0, 1], got {self.phase[2]}")
        check(all(math.isfinite(c) and c >= 0 for c in self.background) and len(self.background) == 3,
              f"--background takes three finite values >= 0, got {self.background}")
        check(math.isfinite(self.step) and self.step > 0, f"--step must be > 0 voxels, got {self.step}")
        check(math.isfinite(self.shadow_step) and self.shadow_step > 0,
              f"--shadow-step must be > 0 voxels, got {self.shadow_step}")
        check(1 <= self.spp <= 1 << 16, f"--spp must be in [1, 65536], got {self.spp}")
        check(math.isfinite(self.emission_scale) and self.emission_scale >= 0,
              f"--emission-scale must be finite and >= 0, got {self.emission_scale}")
        check(100.0 <= self.emission_temperature <= 1e5,
              f"--emission-temperature must be in [100, 1e5] K, got {self.emission_temperature}")
        check(self.estimator in ESTIMATORS,
              f"--estimator must be one of {', '.join(ESTIMATORS)}, got {self.estimator!r}")
        Dispatch(self.dispatch, tuple(self.tile))     # raises UserError when invalid

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


def render_volume(bricks, camera, lights, settings: VolumeSettings, device, progress=None):
    """Render a Bricks volume. Returns a dict with 'rgba' (H, W, 4 float32), optionally
    'depth' (H, W), plus 'kernel_ms', 'wall_ms', 'flags'."""
    import pyopencl as cl

    n_suns, n_points = lights_mod.counts(lights)
    dispatch = Dispatch(settings.dispatch, tuple(settings.tile)).resolve(device)
    features = VolumeFeatures(n_suns=n_suns, n_points=n_points, shadows=settings.shadows,
                              phase_mixed=settings.phase[2] < 1.0, skip_empty=settings.skip_empty,
                              emission=bricks.emission is not None, depth=settings.depth,
                              **VolumeFeatures.dispatch_fields(dispatch))
    entry = "track_volume" if settings.estimator == "track" else "render_volume"
    kernel = device.kernel(entry, features.flags())

    params, w2l = volume_params(bricks, settings)
    cam = camera.pack(w2l, settings.spp, settings.seed)
    light_rec = lights_mod.pack(lights, w2l)

    ctx = device.context
    W, H = camera.width, camera.height
    emission = bricks.emission if bricks.emission is not None else np.zeros(1, np.float32)
    bufs = [upload(ctx, a) for a in (cam, params, light_rec, np.asarray(bricks.table, np.int32),
                                      np.asarray(bricks.data, np.float32),
                                      np.asarray(emission, np.float32))]
    if settings.estimator == "track":
        bufs.append(upload(ctx, track_majorants(bricks, settings)))
    out = np.empty((H, W, 4), np.float32)
    depth = np.empty((H, W), np.float32) if settings.depth else np.empty(1, np.float32)
    d_out = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, out.nbytes)
    d_depth = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, depth.nbytes)
    tail = [d_out, d_depth]
    if entry == "render_volume":      # + the occupied bricks, which only tiled culling reads
        culls = features.tiled and features.skip_empty
        occ = occupied_bricks(bricks) if culls else np.zeros((0, 4), np.int32)
        tail += [upload(ctx, occ), np.int32(len(occ))]
    t_start = time.perf_counter()
    kernel_ms = run_rows(device, kernel, [*bufs, *tail], W, H, PIXELS_PER_LAUNCH, progress,
                         dispatch=dispatch)
    cl.enqueue_copy(device.queue, out, d_out)
    if settings.depth:
        cl.enqueue_copy(device.queue, depth, d_depth)
    device.queue.finish()
    result = {"rgba": out, "kernel_ms": kernel_ms,
              "wall_ms": 1e3 * (time.perf_counter() - t_start), "flags": features.flags()}
    if settings.depth:
        result["depth"] = depth
    return result
