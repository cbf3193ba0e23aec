"""The depth AOV against its expectation, for all three volume estimators.

The depth layer is the opacity-weighted mean distance of the medium along the primary
ray (DESIGN.md, "Outputs"; README `--aov depth`): the mean of the distance t under the
density of first collisions, sigma T dt. The three estimators estimate the same
quantity:
- march: sum_k w_k t_k / sum_k w_k, w_k = T_k a_k (a_k the step's opacity), over the
  jittered lattice of its samples (per channel: the channel mean of T_c a_c);
- track and path: the mean of the first real collision's distance over the samples
  that have one (delta tracking draws it from sigma T dt; with per-channel media the
  spectral-tracking collision has density mean_c sigma_c T_c dt, cl/track.h).
So for every pixel the expectation is

    E[t] = int t m(t) dt / int m(t) dt,   m(t) = mean_c s_c sigma(t) exp(-s_c tau(t)),

which the test integrates in numpy on the renderer's density model (trilinear between
voxel centres, tests/helpers.trilinear) with a midpoint rule of 4000 points over the
medium's extent: error O(h^2 sigma'') ~ 1e-7 here, far below every bound. Pixels are box
filtered (spp > 1 spreads the samples over the pixel), so the pixel's expectation
weights sub-pixel rays by their collision probability alpha: sum alpha E / sum alpha on a
4x4 grid of sub-pixel rays (the ball's edge pixels are left out, where that grid is
coarse against the change of E across the pixel)."""
import numpy as np
import pytest

from helpers import assert_unbiased, centred_bricks, look_at, volume_image, trilinear
from volrender.lights import Sun
from volrender.volume import VolumeSettings

VOX = 0.1
SIGMA = 5.0                 # per world unit at voxel value 1: the slab's tau is ~3.5 along z


def slab_values():
    """A layer 6 voxels thick (k = 17..22) across a 40 x 40 voxel square."""
    v = np.zeros((40, 40, 40), np.float32)
    v[:, :, 17:23] = 1.0
    return v


def ball_values(n=24, r=9.0):
    i = np.indices((n, n, n)).astype(np.float64) - (n - 1) / 2
    return np.where((i ** 2).sum(0) <= r * r, 1.0, 0.0).astype(np.float32)


def sub_rays(cam, k=3):
    """Unit directions of a k x k grid of sub-pixel rays (H, W, k*k, 3)."""
    p00, du, dv = cam.pixel_vectors()
    o = (np.arange(k) + 0.5) / k
    x = np.arange(cam.width)[:, None] + o[None, :]             # (W, k)
    y = np.arange(cam.height)[:, None] + o[None, :]            # (H, k)
    d = (p00 + x[None, :, None, :, None] * du + y[:, None, :, None, None] * dv)
    d = d.reshape(cam.height, cam.width, k * k, 3)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def medium_box(values, m):
    """World box of the nonzero voxels, padded by the one-voxel ramp to zero."""
    nz = np.argwhere(values > 0)
    lo, hi = nz.min(0) - 1.0, nz.max(0) + 1.0
    return m[:3, :3] @ lo + m[:3, 3], m[:3, :3] @ hi + m[:3, 3]   # m is a scale + shift


def expected_depth(values, m, origin, dirs, scales, n=1000):
    """(E[t], alpha) per ray: the collision-weighted mean distance and the channel mean
    of 1 - T, by the midpoint rule over the ray's chord through medium_box."""
    lo, hi = medium_box(values, m)
    with np.errstate(divide="ignore"):
        ta, tb = (lo - origin) / dirs, (hi - origin) / dirs
    t0 = np.maximum(np.minimum(ta, tb).max(-1), 0.0)
    t1 = np.maximum(np.maximum(ta, tb).min(-1), t0)
    h = (t1 - t0) / n                                          # (...)
    t = t0[..., None] + (np.arange(n) + 0.5) * h[..., None]    # (..., n)
    x = np.asarray(origin) + dirs[..., None, :] * t[..., None]
    sig = SIGMA * trilinear(values, m, x)                      # (..., n)
    num = den = alpha = 0.0
    for s in scales:
        tau = (np.cumsum(s * sig, axis=-1) - 0.5 * s * sig) * h[..., None]   # tau at t
        dens = s * sig * np.exp(-tau)
        num = num + (dens * t).sum(-1) * h
        den = den + dens.sum(-1) * h
        alpha = alpha + (1.0 - np.exp(-(s * sig).sum(-1) * h))
    with np.errstate(invalid="ignore"):
        return num / den, alpha / len(scales)


def pixel_expectation(values, m, cam, scales):
    """(E[t], alpha, the smallest sub-ray alpha) per pixel."""
    e, a = expected_depth(values, m, np.asarray(cam.origin), sub_rays(cam), scales)
    with np.errstate(invalid="ignore"):
        return (a * e).sum(-1) / a.sum(-1), a.mean(-1), a.min(-1)


def march_model(values, m, bricks, cam, scales, step, us):
    """The march's own sums in numpy (render_volume.cl): samples t0 + (k + u) dt from the
    layout box's entry, a = 1 - exp(-s sigma dt), w = mean_c T_c a_c, at the pixel centres,
    for each jitter u. Returns per pixel and u the depth sum_k w t / sum_k w (H, W, U)."""
    l2w = bricks.local_to_world
    w2l = np.linalg.inv(l2w)
    box = bricks.dims * 8.0
    o = np.asarray(cam.origin, np.float64)
    dirs = cam.pixel_dirs()
    ol = w2l[:3, :3] @ o + w2l[:3, 3]
    dl = dirs @ w2l[:3, :3].T
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (0.0 - ol) / dl, (box - ol) / dl
    t_in = np.maximum(np.nanmax(np.minimum(ta, tb), -1), 0.0)
    t_out = np.nanmin(np.maximum(ta, tb), -1)
    dt = step * VOX
    out = np.zeros(dirs.shape[:2] + (len(us),))
    kmax = int(np.ceil((t_out - t_in).max() / dt)) + 1
    k = np.arange(kmax)
    for j, u in enumerate(us):
        t = t_in[..., None] + (k + u) * dt                        # (H, W, K)
        inside = t < t_out[..., None]
        sig = SIGMA * trilinear(values, m, o + dirs[..., None, :] * t[..., None]) * inside
        num = den = 0.0
        for s in scales:
            a = 1.0 - np.exp(-s * sig * dt)
            T = np.cumprod(np.concatenate([np.ones(a.shape[:-1] + (1,)), 1.0 - a[..., :-1]],
                                          -1), -1)
            num = num + (T * a * t).sum(-1)
            den = den + (T * a).sum(-1)
        with np.errstate(invalid="ignore"):
            out[..., j] = num / den
    return out


CASES = {
    # name: (values, camera origin, fov, sigma_t scales, albedo)
    "slab": (slab_values, (0.3, -0.2, 5.0), 8.0, (1.0, 1.0, 1.0), 0.8),
    "ball": (ball_values, (0.4, 0.6, 4.0), 30.0, (1.0, 1.0, 1.0), 0.8),
    "chromatic_ball": (ball_values, (0.4, 0.6, 4.0), 30.0, (0.3, 1.0, 2.5), (0.9, 0.5, 0.2)),
}


@pytest.fixture(scope="module", params=list(CASES))
def case(request):
    make, origin, fov, scales, albedo = CASES[request.param]
    values = make()
    bricks, m = centred_bricks(values, VOX)
    cam = look_at(origin, fov=fov, n=14)
    want, alpha, alpha_min = pixel_expectation(values, m, cam, scales)
    return dict(name=request.param, values=values, m=m, bricks=bricks, cam=cam, scales=scales,
                albedo=albedo, want=want, alpha=alpha, alpha_min=alpha_min)


def settings(case, **kw):
    return VolumeSettings(density_scale=SIGMA, sigma_t_scale=case["scales"], albedo=case["albedo"],
                          aovs=("depth",), **kw)


@pytest.mark.parametrize("estimator", ["track", "path"])
def test_tracked_depth_is_the_mean_collision_distance(cl_device, case, estimator):
    """Delta tracking's first collision is distributed as sigma T dt (per channel: its
    channel mean), so the pixel's depth, the mean over the samples that collide, has
    expectation E[t] exactly; its per-pixel noise is what the spread across pixels shows
    (bound: Z standard errors of the mean residual). A depth scaled by 2, a local
    (voxel) distance or an offset from the box entry are off by far more."""
    spp = 256
    extra = dict(max_depth=4, seed=21) if estimator == "path" else dict(seed=20)
    img = volume_image(case["bricks"], case["cam"], [Sun((0.0, -1.0, -0.3), 2.0)],
                        settings(case, estimator=estimator, spp=spp, **extra), cl_device)
    depth, alpha = img.aovs["depth"], img.rgba[..., 3]
    use = case["alpha_min"] > 0.3           # P(no collision in 256 samples) < 1e-39
    assert use.sum() >= 60, use.sum()
    assert np.all(np.isinf(depth[case["alpha"] < 1e-9]))      # no medium: no depth
    sd = assert_unbiased(depth[use], case["want"][use], f"{case['name']} {estimator} depth")
    # the spread is the collision distance's own: below the medium's extent / sqrt(spp)
    assert sd < 2.0 / np.sqrt(spp)
    # alpha (1 - the camera segment's ratio-tracked T) agrees with the same integral
    assert_unbiased(alpha[use], case["alpha"][use], f"{case['name']} {estimator} alpha")


def test_marched_depth_is_the_same_expectation(cl_device, case):
    """The march's depth against (a) a numpy model of its own sums at the same step
    (pixel centres, 32 jitters; spp 1 puts the kernel's one ray through the centre with
    one random jitter u), within Z times the model's spread over u plus float32
    accumulation (~1e-4: sums of ~1e3 products of size ~5 with relative error 6e-8 each);
    and (b) that model, averaged over u, against E[t] within its discretisation error: the
    jittered lattice is unbiased to first order in sigma dt, and the second-order term
    measured on this model is below 2e-4 world units at step 0.25 voxel (allowed: 5e-4).
    Weights without T, a depth scaled by 2 or taken at the step's start are off by more."""
    step = 0.25
    img = volume_image(case["bricks"], case["cam"], [],
                        settings(case, estimator="march", step=step, spp=1, seed=4), cl_device)
    depth = img.aovs["depth"].astype(np.float64)
    us = (np.arange(32) + 0.5) / 32
    model = march_model(case["values"], case["m"], case["bricks"], case["cam"], case["scales"],
                        step, us)
    use = case["alpha_min"] > 0.3
    assert use.sum() >= 60
    spread = model.max(-1) - model.min(-1)
    lo, hi = model.min(-1) - 1e-4, model.max(-1) + 1e-4          # any u lies in between
    assert np.all((depth[use] >= lo[use]) & (depth[use] <= hi[use])), \
        np.abs(depth - model.mean(-1))[use].max()
    assert spread[use].max() < 0.02
    # the pixel centre's E[t] (one sub-ray per pixel)
    e, _ = expected_depth(case["values"], case["m"], np.asarray(case["cam"].origin),
                          case["cam"].pixel_dirs(), case["scales"])
    np.testing.assert_allclose(model.mean(-1)[use], e[use], atol=5e-4)
    # and the kernel's pixels against E[t] directly: discretisation plus jitter spread
    assert np.abs(depth[use] - e[use]).max() < 5e-4 + spread[use].max()
