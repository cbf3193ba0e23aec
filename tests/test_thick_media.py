"""Media past the point where light gets through, against closed forms: the march's deep
shadows (light crossing an optical depth of 12 must arrive as exp(-12), so neither the
transmittance clamp VR_TAU_MAX nor the shadow march's early stop may show), and the
emission of stiff media (per-voxel optical depths up to 1e8, where the tracker takes
whole intervals, cl/track.h VR_BULK_*), which is e / sigma whatever sigma is."""
import numpy as np
import pytest

from helpers import assert_unbiased, centred_bricks, look_at, volume_image, trilinear
import reference
from volrender.lights import Sun
from volrender.volume import VolumeSettings, emission_color

VOX = 0.1
K0, K1 = 17, 22                       # the slab: voxels k = 17..22 across 40 x 40


def slab(emission=False):
    v = np.zeros((40, 40, 40), np.float32)
    v[:, :, K0:K1 + 1] = 1.0
    return centred_bricks(v, VOX, emission=v if emission else None), v


def deep_shadow(values, m, cam, sigma, g, E, albedo, n=6000):
    """Single scattering of a sun shining straight up (+z) through the slab, seen from
    above: L = albedo p(mu) E int sigma(z) exp(-tau_above(z) / c - tau_below(z)) dz / c,
    c = |d_z|, mu = c (the light's propagation against the direction to the camera); the
    vertical profile from the renderer's density model, midpoint rule (error ~1e-8
    relative)."""
    lo, hi = -3.0 * VOX - 0.3, 3.0 * VOX + 0.3
    h = (hi - lo) / n
    z = lo + (np.arange(n) + 0.5) * h
    s = sigma * trilinear(values, m, np.stack([0 * z, 0 * z, z], -1))
    above = (np.cumsum(s[::-1]) - 0.5 * s[::-1])[::-1] * h
    below = s.sum() * h - above
    c = np.abs(cam.pixel_dirs()[..., 2])
    integrand = s[None, None, :] * np.exp(-above / c[..., None] - below)
    return albedo * reference.hg(c, g) * E * integrand.sum(-1) * h / c


def test_light_through_optical_depth_12_is_exp_minus_12(cl_device):
    """The sun under a slab of vertical optical depth 12, the camera above: what reaches
    the camera went through the slab once, so L ~ albedo p E exp(-12) 12: the shadow
    rays of the upper layers cross optical depths near 12, so a transmittance clamped
    at exp(-8) or a shadow march that stops at tau 2.5 is off by x4 or x1e4. Bound: the
    march's own error, first order in its steps, so no more than the difference between
    steps 0.25 and 0.5 voxel (up to 17% here) plus its jitter noise (12 seeds); and, as a
    guard that is not derived, within 5% (measured: 1.8%)."""
    (bricks, m), values = slab()
    sigma = 20.0                      # THICK = 0.6: tau = 12 along z
    cam = look_at((0.1, 0.2, 5.0), fov=6.0, n=8)
    sun = Sun((0.0, 0.0, 1.0), 1.0)
    want = deep_shadow(values, m, cam, sigma, 0.3, 1.0, 0.8)
    assert 1e-6 < want.mean() < 1e-4

    def march(step, seeds=12):
        imgs = [volume_image(bricks, cam, [sun], VolumeSettings(
            density_scale=sigma, albedo=0.8, phase=(0.3, 0.0, 1.0), step=step, shadow_step=step,
            spp=4, seed=k), cl_device).rgba[..., 1] for k in range(seeds)]
        imgs = np.asarray(imgs, np.float64)
        return imgs.mean(0), imgs.std(0, ddof=1) / np.sqrt(seeds)
    fine, fse = march(0.25)
    coarse, cse = march(0.5)
    step_err = np.abs(coarse - fine) + 5 * np.sqrt(fse ** 2 + cse ** 2)
    rel = np.abs(fine - want) / want
    assert np.all(np.abs(fine - want) <= step_err + 5 * fse), rel.max()
    assert rel.max() < 0.05


@pytest.mark.parametrize("sigma", [1e3, 1e9])
@pytest.mark.parametrize("estimator", ["march", "track"])
def test_stiff_emission_is_e_over_sigma(cl_device, sigma, estimator):
    """Emission e = k sigma_0 v with sigma = sigma_0 v: int T e C dt = k C (1 - T) for any
    profile, and T = exp(-0.6 sigma_0 / c) = 0 here, so every pixel is k C, plus T
    times the background. At sigma_0 = 1e9 (optical depth 1e8 per voxel) the tracker
    crosses the slab's edge in bulk intervals, whose emission estimate is (1 - exp(-tau))
    / tau of their length times the interval's mean emission: a wrong tau there scales
    the pixel, and the emission read at the interval's start alone (~0 at the edge, where
    the first interval holds all the optical depth) blacks it out. The march integrates T
    over each step exactly ((1 - exp(-tau)) / sigma): exact to float32 rounding (1e-4 of
    sums of ~10 terms) and the T < 1e-5 it leaves. The tracker at 1e3 is the ordinary
    unbiased walk (bound: Z standard errors over the pixels); in bulk deterministic up to
    rounding."""
    (bricks, m), _ = slab(emission=True)
    cam = look_at((0.1, 0.2, 5.0), fov=6.0, n=10)
    k = 0.5
    s = VolumeSettings(density_scale=sigma, emission_scale=k * sigma, estimator=estimator,
                       spp=32 if estimator == "track" else 2, seed=3, background=(0.2, 0.3, 0.4))
    img = volume_image(bricks, cam, [], s, cl_device).rgba.astype(np.float64)
    col = emission_color(s) / (k * sigma)               # the blackbody colour C
    for ch in range(3):
        want = np.full(img.shape[:2], k * col[ch])
        if estimator == "track" and sigma < 1e6:
            assert_unbiased(img[..., ch], want, f"channel {ch}")
        else:
            # the march stops once T < 1e-5 (VR_T_CUTOFF): T (bg - k C) < 5e-6 is left
            np.testing.assert_allclose(img[..., ch], want, rtol=1e-4, atol=5e-6)
    np.testing.assert_allclose(img[..., 3], 1.0, atol=1e-5)      # T < VR_T_CUTOFF
