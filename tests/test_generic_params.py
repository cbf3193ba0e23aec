"""Formulas checked at generic parameter values (issue 39): not at 0, 1, a single lobe, a
grey medium or a default that hides a term, and against oracles the code did not compute:
published constants, closed forms, and numpy written from the documented formula.

Each test names, in its docstring, the deliberate bug of scripts/mutants.py it was written
against (docs/testing.md lists the run)."""
import numpy as np
import pytest

import reference
from helpers import top_camera
from volrender import blackbody, glass, spheres, volume as volume_mod
from volrender.camera import Camera
from volrender.image import to_srgb
from volrender.lights import Sun
from volrender.cloud import PointCloud
from volrender.bricks import Bricks
from volrender.volume import VolumeSettings
from helpers import assert_unbiased, env_lookup, render_glass, render_volume, texel_dirs, volume_image

# ------------------------------------------------------------------ colour constants

# ITU-R BT.709 / IEC 61966-2-1 (sRGB): primaries and the D65 white point in CIE 1931 xy
PRIMARIES_XY = np.array([(0.64, 0.33), (0.30, 0.60), (0.15, 0.06)])
D65_XY = np.array([0.3127, 0.3290])


def rgb_to_xyz_from_primaries():
    """The RGB -> XYZ matrix built from the published primaries and white point: columns
    are the primaries' XYZ (Y = 1) scaled so that RGB (1, 1, 1) is D65 with Y = 1."""
    x, y = PRIMARIES_XY[:, 0], PRIMARIES_XY[:, 1]
    p = np.stack([x / y, np.ones(3), (1 - x - y) / y])          # columns: primaries
    wx, wy = D65_XY
    white = np.array([wx / wy, 1.0, (1 - wx - wy) / wy])
    return p * np.linalg.solve(p, white)


def test_xyz_to_rec709_is_the_published_matrix():
    """blackbody.XYZ_TO_REC709 is the inverse of the matrix the BT.709 primaries and D65
    give (the published xy have 4 digits: +-5e-5 moves an entry by up to 2e-4 of its size,
    6e-4 at 3.24; the matrix in use came from D65 at (0.31271, 0.32902)), D65 maps to white,
    and
    the luminance weights are its Y row (BT.709: 0.2126, 0.7152, 0.0722).
    Mutants: 'XYZ -> Rec.709: a row entry swapped with its neighbour', 'Rec.709 luminance
    weights: green and blue swapped'."""
    m = rgb_to_xyz_from_primaries()
    np.testing.assert_allclose(blackbody.XYZ_TO_REC709, np.linalg.inv(m), rtol=3e-4, atol=1e-5)
    wx, wy = D65_XY
    d65 = np.array([wx / wy, 1.0, (1 - wx - wy) / wy])
    np.testing.assert_allclose(blackbody.XYZ_TO_REC709 @ d65, 1.0, atol=5e-4)
    np.testing.assert_allclose(m[1], [0.2126, 0.7152, 0.0722], atol=1e-4)
    np.testing.assert_allclose(blackbody.REC709_Y, m[1], atol=1e-4)


def test_environment_luminance_is_rec709():
    """The environment's sampling weights are BT.709 luminance: uniform maps of each pure
    primary weigh in the ratio of the published weights (the sin(theta) factor is common).
    Mutant: 'env weights: Rec.709 green and blue weights swapped'."""
    from volrender.environment import env_weights
    got = []
    for c in range(3):
        t = np.zeros((6, 8, 3), np.float32)
        t[..., c] = 1.0
        got.append(env_weights(t).sum())
    np.testing.assert_allclose(np.array(got) / sum(got), [0.2126, 0.7152, 0.0722], rtol=1e-12)


def srgb_eotf(c):
    """IEC 61966-2-1 decoding (code value -> linear): the inverse of the encoder, with its
    own published constants (0.04045, 12.92, 0.055, 1.055, 2.4)."""
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


@pytest.mark.parametrize("bits", [8, 16])
def test_srgb_encoding_inverts_the_published_decoding(bits):
    """Every code's published linear value encodes back to that code (clamp tone map, no
    exposure), and a value a hair (1e-3 of a code) inside its neighbours' interval does
    not move. Mutants: 'sRGB: gamma 2.2', 'sRGB: linear segment to 0.003', 'sRGB: 1.05 for
    1.055'."""
    top = (1 << bits) - 1
    codes = np.arange(top + 1) if bits == 8 else np.arange(0, top + 1, 7)
    lin = srgb_eotf(codes / top)
    got = to_srgb(lin.reshape(-1, 1, 1).repeat(3, -1), tonemap="clamp", bits=bits)[..., 0].ravel()
    np.testing.assert_array_equal(got, codes)
    for off in (-0.45, 0.45):                    # within half a code of the centre
        near = srgb_eotf(np.clip((codes + off) / top, 0, 1))
        g = to_srgb(near.reshape(-1, 1, 1).repeat(3, -1), tonemap="clamp", bits=bits)[..., 0]
        np.testing.assert_array_equal(g.ravel(), codes)


# ------------------------------------------------------------------ glass: the exit's Fresnel split

def _axis_oracle(model, ior, refl, tau, bounces, front, back):
    """Radiance along the axis of one absorbing sphere (normal incidence at every event,
    chord optical depth tau per channel), written from the documentation of glass_path:
    at each event the Fresnel share F (x reflectivity) is reflected and 1 - F refracted;
    a branch that leaves reads the environment along its direction (front: towards the
    eye, back: away from it); one that meets glass with no event left returns 0. full: both branches everywhere; fast:
    the outer reflection reads the environment only, an exit's reflection is dropped."""
    f = ((ior - 1) / (ior + 1)) ** 2                 # normal incidence, either side
    att = np.exp(-np.asarray(tau, np.float64))

    def walk(inside, forward, thr, events):
        # forward: travelling away from the eye. Outside, only a forward ray meets the
        # sphere (at the entry); inside, every ray meets the far side after the chord.
        if inside:
            thr = thr * att
        hit = inside or (forward and events == 0)
        if not hit:
            return thr * (back if forward else front)
        if events >= bounces:                # meets glass with no event left: a path
            return np.zeros(3)               # tracer's depth limit (issue 32)
        events += 1
        t_thr, r_thr = thr * (1 - f), thr * f * refl
        if model == "full":
            return walk(not inside, forward, t_thr, events) + walk(inside, not forward, r_thr,
                                                                  events)
        out = r_thr * front if not inside else 0.0       # fast: outer reflection, env only
        return out + walk(not inside, forward, t_thr, events)

    return walk(False, True, np.ones(3), 0)


@pytest.mark.parametrize("model", ["full", "fast"])
def test_axis_of_an_absorbing_sphere_is_the_fresnel_branch_sum(cl_device, model):
    """The centre pixel of one sphere under a structured environment, IOR 1.7, reflectivity
    0.8, chromatic absorption, 5 events, no roulette: the sum over the branch tree of
    F^k (1 - F)^m reflectivity^k exp(-j tau) env(+-z), the exit-side internal reflections
    included (full) or dropped (fast). Bound: hit points lie within eps (base + t) ~ 1e-4
    x 3 of the surface, moving the chord by ~1e-3 of its length at most: exp(-tau) by
    tau x 1e-3 (2e-3 relative at tau 2), and float32 sums (1e-6); measured 4e-4.
    Mutants: 'full model: the exit's internal reflection dropped (checked directly)',
    'full model: an internal reflection not weighted by reflectivity', 'full model:
    reflections not weighted by reflectivity', 'full model: the refracted share 1 - F
    reflectivity', 'fast model: the exit reflection kept', 'fast model: the outer
    reflection not weighted by reflectivity'."""
    h = w = 9
    cam = Camera((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 20.0, w, h)
    r = 0.7
    a = np.array([0.1, 0.25, 0.5])                  # per world unit (material unit 1)
    s = glass.GlassSettings(ior=1.7, reflectivity=0.8, absorption=tuple(a), glow=0.0,
                            blend=0.0, material_unit=1.0, bounces=5, roulette=0.0,
                            glass_model=model, spp=1, split_events=64)   # every branch
    hh, ww = 16, 32
    v, u = np.meshgrid((np.arange(hh) + 0.5) / hh, (np.arange(ww) + 0.5) / ww, indexing="ij")
    tex = np.stack([0.5 + 0.4 * np.cos(2 * np.pi * u), 0.4 + 0.5 * v,
                    0.7 + 0.2 * np.sin(2 * np.pi * (u + v))], -1).astype(np.float32)
    img = render_glass(PointCloud(np.zeros((1, 3)), np.array([r])), cam, [], s, cl_device,
                       environment=tex).rgba
    front, back = env_lookup(tex, np.array([0.0, 0.0, 1.0])), env_lookup(tex, np.array([0.0, 0.0, -1.0]))
    want = _axis_oracle(model, 1.7, 0.8, a * 2 * r, 5, front, back)
    np.testing.assert_allclose(img[h // 2, w // 2, :3], want, rtol=3e-3)
    # the oracle's terms matter: the exit's first internal reflection alone is this much
    f = (0.7 / 2.7) ** 2
    exit_refl = (1 - f) ** 2 * f * 0.8 * np.exp(-4 * a * r) * front
    assert np.all(exit_refl > 3 * 3e-3 * want) or model == "fast"


# ------------------------------------------------------------------ volumes: a slab

VOX = 0.1
N_XY, K0, K1 = 24, 12, 17                 # voxels k in [K0, K1] hold 1 (trilinear ramps beside)
THICK = (K1 - K0 + 1) * VOX               # the density's integral along z


def slab(emission=False):
    v = np.zeros((N_XY, N_XY, 30), np.float32)
    v[:, :, K0:K1 + 1] = 1.0
    m = np.eye(4)
    m[:3, :3] *= VOX
    c = (N_XY - 1) / 2 * VOX
    m[:3, 3] = (-c, -c, -(K0 + K1) / 2 * VOX)
    return Bricks.from_dense(v, m, emission=v.copy() if emission else None)


def octave_oracle(mu, c, tau, albedo, phase, scales, n, s, at=0.5):
    """The march's band sum for a sun shining up through the slab's bottom face (|cos| s
    to its normal), written from cl/march.h's banner and DESIGN.md: band 0 p(mu; g)
    exp(-tau_s); band k (k = 1..N-1) G albedo p_k(mu) [exp(-A_k tau_s) - exp(-A_{k-1}
    tau_s)], A_k = A_inf^(k/(N-1)), p_k with both g scaled by C^((u_{k-1} + u_k)/2) (`at`
    0.5: the band's middle), A_inf = min(1, D sqrt(3 (1 - albedo) (1 - g_mean))), g_mean =
    w g1 + (1 - w) g2; all of it scattered with albedo. A sample at depth z below the top
    (view optical depth sigma z / c) sees tau_s = sigma (T - z) / s, so each exp(-A tau_s)
    integrates over the slab (optical thickness tau) to exp(-A tau / s) (1 - exp(-x tau))
    / (c x), x = 1/c - A/s."""
    g1, g2, w = phase
    d, gain, contraction = scales
    alb = np.asarray(albedo, np.float64)
    g_mean = w * g1 + (1 - w) * g2
    a_inf = np.minimum(1.0, d * np.sqrt(3 * (1 - alb) * (1 - g_mean)))

    def J(a):
        x = 1 / c - a / s
        return np.exp(-a * tau / s) * -np.expm1(-x * tau) / (c * x)

    total = reference.phase(mu, g1, g2, w)[..., None] * J(1.0)
    prev = J(1.0)
    for k in range(1, n):
        u, du = k / (n - 1), 1 / (n - 1)
        ck = contraction ** (u - at * du)
        cur = J(a_inf ** u)
        total = total + gain * alb * reference.phase(mu, g1 * ck, g2 * ck, w)[..., None] * (cur - prev)
        prev = cur
    return alb * total


@pytest.mark.parametrize("albedo", [(0.8,), (0.9, 0.75, 0.5)])
def test_octave_bands_at_an_intermediate_contraction(cl_device, albedo):
    """--ms-octaves 4 at scales (D, G, C) = (0.9, 1.6, 0.3), the default mixed phase, a
    sun shining up through the slab at 26 degrees (mu ~ 0.9: forward scattering, where
    the bands' broadened phases differ from the phase) and albedos that put A_inf inside
    (0, 1) (0.45-0.9): every band's depth scale, gain and broadened phase against
    octave_oracle, per pixel. Bound: the march's quadrature error at the slab's four kinks
    (test_render_volume.py: sigma (dt)^2 / (8 VOX) each) moves the exponents by <= 3e-4
    at step 0.05: 0.1 % of L, doubled for the shadow march, plus float32 (1e-5): 3e-3
    (measured: 6e-4; 1.7e-3 at step 0.1). One sample per pixel, at its centre: mu moves
    by 5e-3 across a pixel, and HG's slope at mu 0.9 turns that into 1.5 % of noise.
    Mutants: 'octaves: a band's phase at its end, not its middle', 'octaves: a band's phase
    at its start', 'octaves: A_k with (k + 1) / (N - 1)', 'octaves: band spacing 1 / N',
    'octaves: light bands without the albedo', 'octaves: every band against band 0',
    'octaves: chromatic decay of the red channel for all', 'octave decay: mean cosine of
    the first lobe only', 'octave decay: sqrt(1 - albedo) without the 3', 'octave decay:
    D read from G's slot', 'octave params: G and C swapped'."""
    sigma, step, E = 2.0, 0.05, 3.0
    scales = (0.9, 1.6, 0.3)
    phase = (0.6, -0.3, 0.8)
    prop = np.array([np.sqrt(1 - 0.9 ** 2), 0.0, 0.9])        # upwards, |cos| 0.9
    s = VolumeSettings(density_scale=sigma, albedo=albedo, phase=phase, step=step,
                       shadow_step=step, spp=1, ms_octaves=4, ms_octave_scales=scales,
                       estimator="march")
    a_inf = volume_mod.octave_decay(s)
    assert np.all((a_inf > 0.3) & (a_inf < 0.95)), a_inf        # generic, not a limit
    cam = top_camera(8)
    img = render_volume(slab(), cam, [Sun(tuple(prop), E)], s, cl_device).rgba
    dirs = cam.pixel_dirs()
    c = np.abs(dirs[..., 2])[..., None]
    mu = -dirs @ prop
    want = E * octave_oracle(mu, c, sigma * THICK, albedo, phase, scales, 4, 0.9)
    want = np.broadcast_to(want, img[..., :3].shape)
    np.testing.assert_allclose(img[..., :3], want, rtol=3e-3)
    # the geometry sees the broadened phases: at the band's end or start instead of its
    # middle the light moves by more than twice the bound in some channel
    for at in (0.0, 1.0):
        moved = E * octave_oracle(mu, c, sigma * THICK, albedo, phase, scales, 4, 0.9, at)
        assert np.all(np.abs(moved / want - 1).max(axis=-1) > 6e-3), at


def test_alpha_is_one_minus_the_mean_channel_transmittance(cl_device):
    """A chromatic slab (sigma_t scales 0.4, 1, 2.3): alpha = 1 - mean_c exp(-tau s_c / cz)
    (DESIGN.md: alpha = 1 - transmittance, the channels' mean), for the march and the
    tracker. Bound: the march's quadrature error (see above) at step 0.1, ~1e-3 in tau;
    the tracker: 5 standard errors of its per-pixel estimates.
    Mutants: 'march alpha from the green channel's transmittance', 'path alpha from the
    largest channel's transmittance'."""
    sigma, scale = 1.5, (0.4, 1.0, 2.3)
    cam = top_camera(12)
    cz = np.abs(cam.pixel_dirs()[..., 2])
    want = 1 - np.mean([np.exp(-sigma * THICK * sc / cz) for sc in scale], axis=0)
    s = VolumeSettings(density_scale=sigma, sigma_t_scale=scale, step=0.1, estimator="march")
    a = render_volume(slab(), cam, [], s, cl_device).rgba[..., 3]
    np.testing.assert_allclose(a, want, atol=2e-3)
    t = VolumeSettings(density_scale=sigma, sigma_t_scale=scale, estimator="track", spp=64)
    a = render_volume(slab(), cam, [], t, cl_device).rgba[..., 3]
    assert_unbiased(a.ravel(), want.ravel(), "tracked alpha")


@pytest.mark.filterwarnings("ignore:the image is empty")
def test_march_samples_are_uniformly_jittered_within_a_step(cl_device):
    """An emitting slab 0.6 thick marched at steps of 0.37 (3.7 voxels): each sample lies
    uniformly within its step (t = t0 + (k + u) dt), so the mean over pixels and samples
    of the emission is its integral e THICK / cz exactly (optically thin: density 1e-4).
    A fixed offset (u = 1/2: the midpoint rule on this coarse step) misses it by ~10 %,
    u in [0, 1/2) by more. Bound: 5 standard errors across pixels.
    Mutants: 'march jitter: every sample at its step's middle', 'march jitter over half
    a step'."""
    cam = top_camera(12, fov=4.0)
    s = VolumeSettings(density_scale=1e-4, step=3.7, spp=8, estimator="march",
                       emission_scale=2.0, seed=3)
    img = render_volume(slab(emission=True), cam, [], s, cl_device).rgba[..., :3]
    col = volume_mod.emission_color(s)
    cz = np.abs(cam.pixel_dirs()[..., 2])
    want = col[1] * THICK / cz * np.exp(-1e-4 * THICK / cz)
    assert_unbiased(img[..., 1].ravel(), want.ravel(), "jittered emission")


def test_march_environment_sampling_with_the_default_mixed_phase(cl_device):
    """A thin slab (tau 0.012) under a smooth map that is bright ahead of the camera ray,
    brighter still in a lobe to the side (where the phase is small: the map's and the
    phase's densities differ) and dim behind, with the default two-lobe phase (0.6, -0.3,
    0.8): the march's
    one-sample MIS (the phase's lobes, or the map) gives albedo alpha int p(w . d) L(w) dw
    to first order in tau, per pixel; the integral is a quadrature of the same bilinear
    map. Bound: 5 standard errors of the pixels' ratios, plus the slab's self-shadowing
    (-tau/2: 0.6 %).
    Mutants: 'march env: phase samples pick the lobe from u0 unscaled (always lobe 1)',
    'march env: the mixture density with the first lobe only', 'march env: a quarter of
    the samples from the phase'."""
    h, w = 16, 32
    d = texel_dirs(h, w)
    tex = (0.1 + 0.8 * np.maximum(-d[..., 2], 0.0) ** 2 + 3.0 * np.maximum(d[..., 0], 0.0) ** 8
           )[..., None] * np.array([1.0, 0.8, 0.6])
    tex = tex.astype(np.float32)
    v = np.zeros((N_XY, N_XY, 30), np.float32)
    v[:, :, K0:K0 + 2] = 1.0
    m = np.eye(4)
    m[:3, :3] *= VOX
    m[:3, 3] = (-(N_XY - 1) / 2 * VOX, -(N_XY - 1) / 2 * VOX, -K0 * VOX)
    b = Bricks.from_dense(v, m)
    cam = top_camera(10, fov=4.0)
    phase = (0.6, -0.3, 0.8)
    s = VolumeSettings(density_scale=0.06, albedo=0.8, phase=phase, spp=128, seed=7, step=0.5,
                       shadow_step=0.5, hide_env=True, estimator="march")
    rgba = volume_image(b, cam, [], s, cl_device, environment=tex).rgba.astype(np.float64)
    th = (np.arange(192) + 0.5) / 192 * np.pi
    ph = (np.arange(384) + 0.5) / 384 * 2 * np.pi
    T, P = np.meshgrid(th, ph, indexing="ij")
    dirs = np.stack([np.sin(T) * np.sin(P), np.cos(T), -np.sin(T) * np.cos(P)], -1).reshape(-1, 3)
    lum = env_lookup(tex, dirs)
    dA = (np.sin(T) * (np.pi / 192) * (2 * np.pi / 384)).ravel()
    pix = cam.pixel_dirs().reshape(-1, 3)
    alpha = rgba[..., 3].ravel()
    want = 0.8 * alpha[:, None] * ((reference.phase(pix @ dirs.T, *phase) * dA) @ lum)
    ratio = rgba.reshape(-1, 4)[:, :3] / want
    tau = 0.06 * 2 * VOX
    for ch in range(3):
        r = ratio[:, ch]
        m_, se = r.mean(), r.std(ddof=1) / np.sqrt(len(r))
        assert abs(m_ - (1 - tau / 2)) < 5 * se + 0.002, (ch, m_, se)


# ------------------------------------------------------------------ support cells at their thresholds

def _threshold_cloud(dev, k, cell):
    """Spheres placed against the support-cell grid of 8 anchor spheres (which fix the clip
    box, so the grid does not move when the placed spheres join): in target cell Q (render
    frame box [lo, hi]) a sphere A whose hi_A is U; B with lo_B = (U + k)(1 - 1e-4) (on the
    list); B' with lo = (U + k)(1 + 1e-4) + 2 pad (off it, rounding pad included); C with
    lo_C = U - 1e-4 |U| (on the core); D centred 1e-4 cells past Q's +y face (in the
    neighbour: both cells list it). Returns (cloud, settings, Q, U)."""
    anchors = np.array([(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    s = glass.GlassSettings(blend=k, cell_size=cell, accel="grid", cell_skip=False)
    # as many spheres as the final cloud: the clip box grows with the blend's bulge ~ ln N
    base = PointCloud(np.vstack([anchors, np.zeros((5, 3))]), np.full(13, 0.12))
    p = spheres.pack_scene(base, s, device=dev)
    g = p.cells
    q = g.locate((np.array([[0.031, -0.047, 0.052]]) - p.centre))[0]
    lo, hi = (v[0] for v in g.box(q[None]))
    mid = 0.5 * (lo + hi)
    a_c, a_r = mid + np.array([0.13, -0.07, 0.04]) * cell, 0.3 * cell
    u = np.max(np.linalg.norm(np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                                        for z in (lo[2], hi[2])]) - a_c, axis=1)) - a_r
    thr = u + k
    face = lambda axis, sign, dist, r, off: (        # noqa: E731: a centre `dist` + r off a face
        mid + off * cell + np.eye(3)[axis] * (sign * (0.5 * cell + dist + r)))
    pad = g.pad
    placed = [(a_c, a_r),
              (face(0, +1, thr * (1 - 1e-4), 0.4 * cell, np.array([0, 0.2, -0.1])), 0.4 * cell),
              (face(1, -1, thr * (1 + 1e-4) + 2 * pad, 0.35 * cell, np.array([0.1, 0, 0.2])),
               0.35 * cell),
              (face(2, -1, u - 1e-4 * abs(u), 0.2 * cell, np.array([-0.15, 0.1, 0])), 0.2 * cell),
              (face(1, +1, 1e-4 * cell, 0.25 * cell, np.array([0.3, 0, -0.2])), 0.25 * cell)]
    c = np.array([pc for pc, _ in placed]) + p.centre
    r = np.array([pr for _, pr in placed])
    cloud = PointCloud(np.vstack([anchors, c]), np.concatenate([np.full(8, 0.12), r]))
    check = spheres.pack_scene(cloud, s, device=dev)
    np.testing.assert_array_equal(check.cells.lo, g.lo)            # the grid did not move
    np.testing.assert_allclose(check.centre, p.centre)
    return cloud, s, q, u


@pytest.mark.parametrize("k", [0.03, 0.11])
def test_support_cells_at_their_inclusion_thresholds(cl_device, k):
    """Spheres within a relative 1e-4 of the list threshold U + k, of the core threshold U
    and of a cell face (_threshold_cloud), against the brute-force float64 lists of the
    cell and its 26 neighbours: every sphere with lo_i <= U + k is listed, every one with
    lo_i <= U is on the core, nothing beyond U + k + 2 pad is; and the field with the
    cells equals brute force on points 1e-4 cells either side of the cell's faces.
    Mutants: 'cells: list threshold U + k/2', 'cells: core threshold M (the nearest lo)',
    'cells: U from lo_i (the nearest distance, not the farthest)'."""
    from glass_probe import Probe
    cell = 0.1
    cloud, s, q, u = _threshold_cloud(cl_device, k, cell)
    pr = Probe(cl_device, cloud, s)
    g, sp = pr.scene.cells, pr.scene.spheres.astype(np.float64)
    qs = (q[None] + np.array([(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1)
                              for c in (-1, 0, 1)])).reshape(-1, 3)
    lo, hi = g.box(qs)
    member, _, _ = reference.oracle(sp[:, :3], sp[:, 3], k, lo, hi)
    wide, _, _ = reference.oracle(sp[:, :3], sp[:, 3], k + 2 * g.pad, lo, hi)
    dlo, dhi = reference.box_distances(sp[:, :3], sp[:, 3], lo, hi)
    core_need = dlo <= dhi.min(axis=1, keepdims=True)
    code, _, lists = g.lookup(qs)
    assert (code >= 0).all()
    for j in range(len(qs)):
        got = np.zeros(len(sp), bool)
        got[lists[j]] = True
        core = np.zeros(len(sp), bool)
        core[g.core(code[j])] = True
        assert (got | ~member[j]).all(), f"cell {qs[j]} misses a sphere at its threshold"
        assert (~got | wide[j]).all(), f"cell {qs[j]} lists a sphere past U + k + 2 pad"
        assert (core | ~core_need[j]).all(), f"cell {qs[j]}: core misses a sphere"
    # the target cell is adversarial: its list has a sphere within 1e-4 of U + k and one
    # just past it, and its core one within 1e-4 of U
    j0 = 13
    gap = dlo[j0] - (dhi[j0].min() + k)
    assert np.sum(np.abs(gap) < 2e-4 * (abs(dhi[j0].min()) + k) + 3 * g.pad) >= 2
    # the field on both sides of every face of the target cell, brute force
    rng = np.random.default_rng(5)
    lo0, hi0 = lo[j0], hi[j0]
    x = []
    for axis in range(3):
        for side in (lo0[axis], hi0[axis]):
            for e in (-1e-4, 1e-4):
                p = lo0 + rng.random((20, 3)) * (hi0 - lo0)
                p[:, axis] = side + e * cell
                x.append(p)
    x = np.vstack(x) + pr.scene.centre
    f, _ = pr.field(x)
    want = reference.smooth_union(x, cloud.centers, cloud.radii, k)
    np.testing.assert_allclose(f, want, atol=2e-5)


def test_a_point_reads_its_own_cells_list(cl_device):
    """A point three quarters into its cell, next to the neighbour whose list cannot hold
    a sphere that matters at the point: a large sphere A holds the point 0.01 inside its
    surface and extends past the +x face (so the +x neighbour's U is ~0.03 below the
    point's m), and a small sphere B on the -x side sits 0.03 inside the support (d_B =
    m + k - 0.03): B is on the point's cell's list and off the neighbour's (lo_B there =
    d_B + a quarter cell > U + k). The field with the cells is brute force's (B's term
    moves F by ~4e-3). Mutant: 'cells: the cell of a point rounded, not floored' (it reads
    the neighbour's list)."""
    from glass_probe import Probe
    k, cell = 0.11, 0.1
    anchors = np.array([(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    s = glass.GlassSettings(blend=k, cell_size=cell, accel="grid", cell_skip=False)
    probe_base = spheres.pack_scene(PointCloud(np.vstack([anchors, np.zeros((2, 3))]),
                                             np.full(10, 0.12)), s, device=cl_device)
    g = probe_base.cells
    q = g.locate(np.array([[-0.75, 0.02, -0.04]]) - probe_base.centre)[0]
    lo, hi = (v[0] for v in g.box(q[None]))
    x = lo + np.array([0.75, 0.3, 0.4]) * cell                    # render frame
    c_a, r_a = x + [0.79, 0.0, 0.0], 0.8                           # d_A(x) = -0.01
    c_b, r_b = x - [0.12, 0.0, 0.0], 0.05                          # d_B(x) = 0.07 = m + k - 0.03
    cloud = PointCloud(np.vstack([anchors, [c_a, c_b] + probe_base.centre]),
                       np.concatenate([np.full(8, 0.12), [r_a, r_b]]))
    pr = Probe(cl_device, cloud, s)
    assert np.array_equal(pr.scene.cells.lo, g.lo)                 # the grid did not move
    gq = pr.scene.cells
    sp = pr.scene.spheres.astype(np.float64)
    b_index = int(np.argmin(np.linalg.norm(sp[:, :3] - c_b, axis=1)))
    code, _, lists = gq.lookup(np.array([q, q + [1, 0, 0]]))
    assert b_index in lists[0] and b_index not in lists[1]
    xw = (x + probe_base.centre)[None]
    f, _ = pr.field(xw)
    want = reference.smooth_union(xw, cloud.centers, cloud.radii, k)
    without_b = reference.smooth_union(xw, np.delete(cloud.centers, 9, 0),
                                       np.delete(cloud.radii, 9), k)
    assert abs(want - without_b)[0] > 1e-3                          # B's term is visible
    np.testing.assert_allclose(f, want, atol=2e-5)


def test_tracking_under_a_map_with_the_default_mixed_phase(cl_device):
    """The tracker's map sampling (power-heuristic MIS of a map sample and a phase-sampled
    walk, cl/path_volume.cl) with the default two-lobe phase, against the march (checked
    above against a quadrature with the same phase) on the same map, single scattering
    (max depth 1), slab optical depth 0.4. The pixels are independent: the mean over
    pixels of track - march lies within 5 standard errors of it (their spread) plus the
    march's step error (first order: the difference between steps 0.5 and 0.25).
    Mutant: 'path env map: the map sample's phase with lobe 1 only' ('the walk's MIS
    weight with lobe 1's density' biases this image by ~1 %, within the noise: a
    survivor, explained in scripts/mutants.py)."""
    h, w = 16, 32
    d = texel_dirs(h, w)
    # bright behind the camera (+z), where only the backward lobe (weight 0.2) scatters
    # towards it: HG(-1; 0.6) is a quarter of the mixture there
    tex = (0.1 + 0.6 * np.maximum(-d[..., 2], 0.0) ** 2 + 2.5 * np.maximum(d[..., 2], 0.0) ** 4
           + 3.0 * np.maximum(d[..., 0], 0.0) ** 8)[..., None] * np.array([1.0, 0.8, 0.6])
    tex = tex.astype(np.float32)
    v = np.zeros((N_XY, N_XY, 30), np.float32)
    v[:, :, K0:K0 + 2] = 1.0
    m = np.eye(4)
    m[:3, :3] *= VOX
    m[:3, 3] = (-(N_XY - 1) / 2 * VOX, -(N_XY - 1) / 2 * VOX, -K0 * VOX)
    b = Bricks.from_dense(v, m)
    cam = top_camera(10, fov=4.0)
    base = dict(density_scale=2.0, albedo=0.8, phase=(0.6, -0.3, 0.8), hide_env=True, seed=11)

    def img(**kw):
        return volume_image(b, cam, [], VolumeSettings(**base, **kw), cl_device,
                            environment=tex).rgba[..., :3].astype(np.float64)

    track = img(estimator="track", max_depth=1, spp=256)
    fine = img(estimator="march", spp=32, step=0.25, shadow_step=0.25)
    coarse = img(estimator="march", spp=32, step=0.5, shadow_step=0.5)
    assert fine.mean() > 0.01
    for ch in range(3):
        dd = (track - fine)[..., ch].ravel()
        se = dd.std(ddof=1) / np.sqrt(dd.size)
        step = abs((coarse - fine)[..., ch].mean()) + 5 * (coarse - fine)[..., ch].std(ddof=1) / np.sqrt(dd.size)
        assert abs(dd.mean()) <= 5 * se + step, (ch, dd.mean(), se, step, fine[..., ch].mean())
