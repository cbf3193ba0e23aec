"""Importance sampling of an environment map (cl/env.h) against probabilities built here,
from the definition (DESIGN.md, cl/env.h), not from volume.env_weights: a texel is drawn
with probability proportional to the largest luminance (Rec.709: 0.2126 R + 0.7152 G +
0.0722 B) among it and its 8 neighbours (wrapping in u, clamped in v) times the solid
angle it covers, 2 pi / W (cos theta_top - cos theta_bottom); then uniformly in (u, v)
within it. And the path estimator's use of it (multiple importance sampling with the
phase) against the march's (a one-sample mixture), two independent estimators of the
same single scattering under a map."""
import numpy as np
import pyopencl as cl
import pytest

from helpers import Z, centred_bricks, chi2_sf, look_at, sky, volume_image
from volrender.dispatch import upload
from volrender.volume import VolumeSettings, env_distribution

SRC = """
#include "common.h"
#include "env.h"
__kernel void sample(__global const float* cdf, int w, int h, uint seed, __global float4* out)
{
    int i = get_global_id(0);
    float pdf;
    float3 d = vr_env_sample(cdf, w, h, vr_rand(seed, i, 0, 0), vr_rand(seed, i, 0, 1), &pdf);
    out[i] = (float4)(d, pdf);
}
"""
LUMA = (0.2126, 0.7152, 0.0722)


def coloured_map(h=16, w=32):
    """sky() (a bright spot, a blue sky, a dark ground) plus texels of equal red and
    different green, and a pure-blue band, so that luminance, not one channel, decides."""
    t = sky(h, w).astype(np.float64)
    t[5, 4:12] = (1.0, 0.0, 0.0)
    t[5, 12:20] = (1.0, 2.0, 0.0)
    t[10, :] = (0.0, 0.0, 3.0)
    return t.astype(np.float32)


def built_probabilities(t):
    """P(texel) from the definition: neighbourhood-max luminance x exact solid angle."""
    t = np.asarray(t, np.float64)
    h, w = t.shape[:2]
    lum = np.zeros((h, w))
    for c in range(3):
        lum += LUMA[c] * t[..., c]
    lum = np.maximum(lum, 0.0)
    best = np.zeros((h, w))
    for i in range(h):
        for j in range(w):
            best[i, j] = max(lum[ii, jj % w] for ii in range(max(i - 1, 0), min(i + 2, h))
                             for jj in (j - 1, j, j + 1))
    theta = np.pi * np.arange(h + 1) / h
    omega = 2 * np.pi / w * (np.cos(theta[:-1]) - np.cos(theta[1:]))
    p = best * omega[:, None]
    return p / p.sum()


def draw(dev, t, n, seed=7):
    h, w = t.shape[:2]
    cdf = env_distribution(t)
    prg = dev.build(SRC, {}, "env sampling probe")
    out = np.empty((n, 4), np.float32)
    d_out = cl.Buffer(dev.context, cl.mem_flags.WRITE_ONLY, out.nbytes)
    cl.Kernel(prg, "sample")(dev.queue, (n,), None, upload(dev.context, cdf), np.int32(w),
                             np.int32(h), np.uint32(seed), d_out)
    cl.enqueue_copy(dev.queue, out, d_out)
    return out.astype(np.float64)


def uv(d):
    u = 0.5 + np.arctan2(d[:, 0], -d[:, 2]) / (2 * np.pi)
    v = np.arccos(np.clip(d[:, 1], -1, 1)) / np.pi
    return u, v


N = 400_000


@pytest.fixture(scope="module")
def samples(cl_device):
    t = coloured_map()
    return t, draw(cl_device, t, N)


def test_texels_are_drawn_by_luminance_times_solid_angle(samples):
    """Chi-square of the texel counts against the built probabilities (512 cells,
    400k samples; a false alarm at p < 1e-3), with a power check: the same counts judged
    against probabilities without the solid angle, or with the red channel for the
    luminance, would give chi-square values far past that level (their expected excess
    n sum (p' - p)^2 / p is computed and required to be > 50 standard deviations)."""
    t, out = samples
    h, w = t.shape[:2]
    u, v = uv(out[:, :3])
    i, j = np.clip((v * h).astype(int), 0, h - 1), np.clip((u * w).astype(int), 0, w - 1)
    counts = np.bincount(i * w + j, minlength=h * w).reshape(h, w)
    p = built_probabilities(t)
    assert (p > 0).all()
    expected = N * p
    chi2 = ((counts - expected) ** 2 / expected).sum()
    assert chi2_sf(chi2, h * w - 1) > 1e-3, chi2
    # power: the alternatives are far outside what this chi-square accepts
    sd = np.sqrt(2 * (h * w - 1))
    no_sin = built_probabilities(t) / (2 * np.pi / w * (np.cos(np.pi * np.arange(h) / h)
                                                          - np.cos(np.pi * np.arange(1, h + 1) / h)))[:, None]
    red = t.copy()
    red[..., 1:] = 0
    for alt in (no_sin / no_sin.sum(), built_probabilities(red)):
        assert N * ((alt - p) ** 2 / p).sum() > 50 * sd


def test_positions_within_texels_are_uniform(samples):
    """Within its texel a sample is uniform in (u, v): the fractional positions, pooled
    over the texels, fill a 6 x 6 grid evenly (chi-square)."""
    t, out = samples
    h, w = t.shape[:2]
    u, v = uv(out[:, :3])
    fu, fv = (u * w) % 1.0, (v * h) % 1.0
    counts, _, _ = np.histogram2d(fu, fv, bins=6, range=((0, 1), (0, 1)))
    expected = N / 36
    assert chi2_sf(((counts - expected) ** 2 / expected).sum(), 35) > 1e-3


def test_each_sample_carries_its_density_per_solid_angle(samples):
    """The density per solid angle of uniform (u, v) in a texel of probability P is
    P W H / (2 pi^2 sin theta) (dw = 2 pi^2 sin theta du dv), with P the built one."""
    t, out = samples
    h, w = t.shape[:2]
    d, pdf = out[:, :3], out[:, 3]
    u, v = uv(d)
    i, j = np.clip((v * h).astype(int), 0, h - 1), np.clip((u * w).astype(int), 0, w - 1)
    st = np.sqrt(1 - d[:, 1] ** 2)
    ok = st > 1e-3                       # float32 directions next to the poles
    assert ok.mean() > 0.999
    want = built_probabilities(t)[i[ok], j[ok]] * w * h / (2 * np.pi ** 2 * st[ok])
    # float32: the CDFs carry ~1e-7 relative per entry, the direction ~1e-7 in sin theta
    np.testing.assert_allclose(pdf[ok], want, rtol=2e-3)


def test_track_under_a_map_is_the_marchs_single_scattering(cl_device, tmp_path):
    """A slab (optical depth ~0.4 across) lit by the map alone, seen from above: the
    tracker (max depth 1: at each collision one map sample with a ratio-tracked shadow
    ray, and one phase sample whose walk gathers the map, combined by the power
    heuristic) against the fine march (one direction per step from a half-half mixture of
    phase and map, balance heuristic). Bounds from the noise: independent seeds give
    per-pixel standard errors; the sum over all pixels must agree within Z standard errors
    of the difference plus the march's step error, which is first order in the step, so
    that the difference between steps 0.5 and 0.25 voxel bounds it (itself measured
    within Z of its standard errors)."""
    from volrender.image import write_image
    t = coloured_map()
    write_image(tmp_path / "map.exr", np.concatenate([t, np.ones_like(t[..., :1])], -1))
    v = np.zeros((24, 24, 24), np.float32)
    v[:, :, 9:15] = 1.0
    bricks, _ = centred_bricks(v, 0.1)
    cam = look_at((0.2, 1.5, 4.0), fov=12.0, n=10)
    base = dict(density_scale=1.0, albedo=0.8, phase=(0.4, 0.0, 1.0), env=str(tmp_path / "map.exr"),
                hide_env=True)

    def mean_se(n, **kw):
        imgs = np.stack([volume_image(bricks, cam, [], VolumeSettings(**base, **kw, seed=100 + k),
                                       cl_device).rgba[..., :3] for k in range(n)]).astype(np.float64)
        return imgs.mean(0), imgs.std(0, ddof=1) / np.sqrt(n)

    track, tse = mean_se(16, estimator="track", spp=128)
    fine, fse = mean_se(8, estimator="march", spp=64, step=0.25, shadow_step=0.25)
    coarse, cse = mean_se(8, estimator="march", spp=64, step=0.5, shadow_step=0.5)
    assert fine.mean() > 0.02
    for ch in range(3):
        d = (track - fine)[..., ch].sum()
        se = np.sqrt((tse[..., ch] ** 2 + fse[..., ch] ** 2).sum())
        step = abs((coarse - fine)[..., ch].sum()) + Z * np.sqrt((cse[..., ch] ** 2 + fse[..., ch] ** 2).sum())
        assert abs(d) <= Z * se + step, (ch, d, se, step)
