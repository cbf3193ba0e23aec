"""Volume renderer against closed forms, brute-force references and invariants."""
import numpy as np
import pytest

import reference
from volrender import volume as volume_mod
from volrender.camera import Camera
from volrender.lights import PointLight, Sun
from volrender.volume import VolumeSettings
from volrender.bricks import Bricks
from volrender.dispatch import Launch
from helpers import VOX, render_volume, scaled, top_camera


# A slab: voxels with k in [K0, K1] hold 1, across the whole x/y extent. The trilinear
# density is 1 on [K0, K1] and ramps to 0 over one voxel on each side, so its integral
# along z is exactly (K1 - K0 + 1) voxels.
N_XY, K0, K1 = 40, 17, 22
THICK = (K1 - K0 + 1) * VOX


@pytest.fixture(scope="module")
def slab():
    v = np.zeros((N_XY, N_XY, 40), np.float32)
    v[:, :, K0:K1 + 1] = 1.0
    c = (N_XY - 1) / 2 * VOX
    return Bricks.from_dense(v, scaled(VOX, (-c, -c, -(K0 + K1) / 2 * VOX)))


def test_slab_transmittance_is_exp_of_optical_depth(cl_device, slab):
    sigma, step = 2.0, 0.25
    cam = top_camera()
    r = render_volume(slab, cam, [], VolumeSettings(density_scale=sigma, step=step), cl_device)
    cz = np.abs(cam.pixel_dirs()[..., 2])
    tau = sigma * THICK / cz
    # Midpoint-rule error at the four kinks of the piecewise-linear density: at most
    # sigma * (slope jump |dz|/VOX) * dt^2 / 8 each, dt = step * VOX along the ray.
    tol_tau = 4 * sigma * (step * VOX) ** 2 / VOX / 8 + 1e-5
    tau_k = -np.log(1.0 - r.rgba[..., 3].astype(np.float64))
    assert np.max(np.abs(tau_k - tau)) <= tol_tau
    assert np.all(r.rgba[..., :3] == 0.0)   # no lights, black background


def test_slab_single_scatter_without_shadows_is_albedo_phase_alpha(cl_device, slab):
    """With unshadowed light the in-scattered term is constant along the ray, so the
    sum telescopes: L = albedo * p(mu) * E * alpha exactly, per pixel."""
    sun = Sun((0.3, -0.2, -1.0), 2.5)
    s = VolumeSettings(density_scale=2.0, albedo=0.8, phase=(0.7, -0.4, 0.6), shadows=False)
    cam = top_camera()
    r = render_volume(slab, cam, [sun], s, cl_device)
    mu = -cam.pixel_dirs() @ np.array(sun.direction)
    want = 0.8 * reference.phase(mu, 0.7, -0.4, 0.6) * 2.5 * r.rgba[..., 3]
    np.testing.assert_allclose(r.rgba[..., 0], want, rtol=2e-5)


def test_slab_single_scatter_with_shadows_matches_closed_form(cl_device, slab):
    """Sun along the slab normal, on the viewer's side. At depth z the view path has
    optical depth tau(z)/c (c = |dir_z|) and the light path tau(z), so
    L = albedo p E (1 - exp(-tau (1 + 1/c))) / (1 + c)."""
    sigma, step, albedo, E = 2.0, 0.25, 0.9, 3.0
    sun = Sun((0.0, 0.0, -1.0), E)
    s = VolumeSettings(density_scale=sigma, albedo=albedo, phase=(0.5, 0.0, 1.0), step=step,
                       shadow_step=step, spp=4)
    cam = top_camera()
    r = render_volume(slab, cam, [sun], s, cl_device)
    dirs = cam.pixel_dirs()
    c = np.abs(dirs[..., 2])
    mu = -dirs @ np.array(sun.direction)
    tau = sigma * THICK
    want = albedo * reference.hg(mu, 0.5) * E * (1 - np.exp(-tau * (1 + 1 / c))) / (1 + c)
    # Quadrature error of both marches (see the transmittance test) moves the exponent by
    # at most ~2 * 0.0063: about 1.3 % of L.
    np.testing.assert_allclose(r.rgba[..., 1], want, rtol=0.02)


def test_point_light_follows_inverse_square(cl_device, slab):
    """A far point light on the sun's line looks like a sun of E = I / D^2; doubling D
    quarters the light (to the slab's relative depth, THICK / D)."""
    d = np.array([0.2, 0.1, -1.0]) / np.linalg.norm([0.2, 0.1, -1.0])
    s = VolumeSettings(density_scale=2.0, shadows=False)
    cam = top_camera(8)
    sun = render_volume(slab, cam, [Sun(tuple(d), 1.0)], s, cl_device).rgba[..., 0]
    near = render_volume(slab, cam, [PointLight(tuple(-40 * d), 1600.0)], s, cl_device).rgba[..., 0]
    far = render_volume(slab, cam, [PointLight(tuple(-80 * d), 1600.0)], s, cl_device).rgba[..., 0]
    np.testing.assert_allclose(near, sun, rtol=0.03)
    np.testing.assert_allclose(near / far, 4.0, rtol=0.03)


def ball(n, radius, value=1.0):
    i = np.indices((n, n, n)).astype(np.float64) - (n - 1) / 2
    return np.where((i ** 2).sum(0) <= radius ** 2, value, 0.0).astype(np.float32)


def test_sphere_transmittance_matches_chord(cl_device):
    """Homogeneous voxel ball of radius R voxels. Its trilinear density blurs the
    boundary: the effective radius is R + 1/2 voxel, give or take the staircase of
    voxel centres (< 0.9 voxel along the normal). Along a ray entering at incidence
    cos(theta) that moves the optical depth by at most sigma * 0.9 * VOX / cos(theta)
    per crossing. Pixels whose impact parameter is below 0.8 R have cos(theta) >= 0.6."""
    n, R, sigma = 48, 18, 1.5
    c = (n - 1) / 2 * VOX
    b = Bricks.from_dense(ball(n, R), scaled(VOX, (-c, -c, -c)))
    cam = Camera((0.3, -0.2, 8.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 30.0, 48, 40)
    r = render_volume(b, cam, [], VolumeSettings(density_scale=sigma, step=0.25), cl_device)
    dirs = cam.pixel_dirs().reshape(-1, 3)
    o = np.array(cam.origin)
    reff = (R + 0.5) * VOX
    chord = reference.sphere_chord(o, dirs, np.zeros(3), reff)
    impact = np.linalg.norm(np.cross(dirs, -o), axis=1)
    core = impact < 0.8 * reff
    tau_k = -np.log(1 - r.rgba[..., 3].reshape(-1).astype(np.float64))
    tol = 2 * sigma * 0.9 * VOX / 0.6
    assert core.sum() > 100
    assert np.max(np.abs(tau_k[core] - sigma * chord[core])) <= tol
    outside = impact > reff + 1.5 * VOX
    assert np.all(r.rgba[..., 3].reshape(-1)[outside] == 0.0)


def sparse_blobs():
    """Two soft blobs 100 voxels apart: mostly empty bricks."""
    n = 120
    i = np.indices((n, 24, 24)).astype(np.float64)
    v = np.zeros((n, 24, 24))
    for cx in (12, 108):
        r2 = (i[0] - cx) ** 2 + (i[1] - 12) ** 2 + (i[2] - 12) ** 2
        v += np.clip(1 - r2 / 81.0, 0, None)
    return Bricks.from_dense(v.astype(np.float32), scaled(VOX, (-6.0, -1.2, -1.2)))


def test_empty_space_skipping_matches_plain_marching(cl_device):
    b = sparse_blobs()
    assert b.n_slots < 0.5 * np.prod(b.dims)
    cam = Camera((0.0, 2.0, 14.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 55.0, 48, 24)
    lights = [Sun((-1.0, -0.5, -0.3), 2.0), PointLight((0.0, 1.5, 0.0), 3.0)]
    base = VolumeSettings(density_scale=4.0, spp=2, seed=7)
    a = render_volume(b, cam, lights, base, cl_device).rgba
    p = render_volume(b, cam, lights, VolumeSettings(**{**base.__dict__, "skip_empty": False}),
                      cl_device).rgba
    assert a[..., 3].max() > 0.5
    np.testing.assert_allclose(a, p, atol=1e-5 * max(1.0, float(p.max())))


@pytest.mark.parametrize("behind", [True, False])
def test_forward_scattering_brightens_the_silver_lining(cl_device, behind):
    """Sun behind the cloud (propagating towards the camera): g > 0 makes the thin rim
    brighter than g < 0. With the sun behind the camera it is the other way round."""
    n = 40
    i = np.indices((n, n, n)).astype(np.float64) - (n - 1) / 2
    soft = np.clip(1.0 - np.sqrt((i ** 2).sum(0)) / 16.0, 0.0, 1.0).astype(np.float32)
    c = (n - 1) / 2 * VOX
    b = Bricks.from_dense(soft, scaled(VOX, (-c, -c, -c)))
    cam = Camera((0.0, 0.0, 6.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 45.0, 32, 32)
    sun = Sun((0.05, 0.1, 1.0 if behind else -1.0), 3.0)
    out = {}
    for g in (0.7, -0.7):
        r = render_volume(b, cam, [sun], VolumeSettings(density_scale=6.0, phase=(g, 0.0, 1.0)),
                          cl_device).rgba
        rim = (r[..., 3] > 0.05) & (r[..., 3] < 0.6)
        out[g] = r[..., 0][rim].mean()
    assert rim.sum() > 20
    if behind:
        assert out[0.7] > 2.0 * out[-0.7]
    else:
        assert out[-0.7] > 2.0 * out[0.7]


def alpha_moments(a):
    y, x = np.indices(a.shape) + 0.5
    w = a.sum()
    cx, cy = (a * x).sum() / w, (a * y).sum() / w
    return cx, cy, w, (a * (x - cx) ** 2).sum() / w, (a * (y - cy) ** 2).sum() / w


def project(cam, x):
    f, r, u = cam.basis()
    v = np.asarray(x) - np.array(cam.origin)
    half_h = np.tan(np.radians(cam.fov) / 2)
    half_w = half_h * cam.width / cam.height
    px = (v @ r / (v @ f) / half_w + 1) / 2 * cam.width
    py = (1 - v @ u / (v @ f) / half_h) / 2 * cam.height
    return px, py


def test_grid_transform_places_and_sizes_the_volume(cl_device):
    """The same voxels with voxel size 0.1 at one offset and 0.05 at another (centres at
    the same depth) land where the transform says, at half the size; a 90-degree rotation turns an x-elongated
    blob into a y-elongated one."""
    i = np.indices((32, 16, 16)).astype(np.float64)
    blob = np.clip(1 - ((i[0] - 15.5) / 12) ** 2 - ((i[1] - 7.5) / 6) ** 2 - ((i[2] - 7.5) / 6) ** 2,
                   0, None).astype(np.float32)
    cam = Camera((0.0, 0.0, 12.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 35.0, 96, 96)
    s = VolumeSettings(density_scale=1e4)      # opaque: alpha is the silhouette
    results = []
    for vox, offset in ((0.1, (-2.0, -1.0, 0.0)), (0.05, (0.5, 0.6, 0.375))):
        b = Bricks.from_dense(blob, scaled(vox, offset))
        a = render_volume(b, cam, [], s, cl_device).rgba[..., 3]
        centre = np.array(offset) + vox * np.array([15.5, 7.5, 7.5])
        cx, cy, area, vx, vy = alpha_moments(a)
        px, py = project(cam, centre)
        assert abs(cx - px) < 0.5 and abs(cy - py) < 0.5
        assert vx > 2.5 * vy
        results.append((area, vx))
    assert results[1][0] / results[0][0] == pytest.approx(0.25, rel=0.1)
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])   # x -> y
    b = Bricks.from_dense(blob, scaled(0.1, (0.0, 0.0, 0.0), rot))
    a = render_volume(b, cam, [], s, cl_device).rgba[..., 3]
    cx, cy, area, vx, vy = alpha_moments(a)
    assert vy > 2.5 * vx
    px, py = project(cam, rot @ (0.1 * np.array([15.5, 7.5, 7.5])))
    assert abs(cx - px) < 0.5 and abs(cy - py) < 0.5


def test_emission_is_integrated_along_the_chord(cl_device):
    """Emission e with absorption sigma: L = e (1 - exp(-sigma l)) / sigma; without
    absorption, L = e l (l = chord length)."""
    n, R = 40, 15
    c = (n - 1) / 2 * VOX
    b = Bricks.from_dense(ball(n, R), scaled(VOX, (-c, -c, -c)), emission=ball(n, R))
    cam = Camera((0.0, 0.0, 6.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 8.0, 8, 8)
    colour = volume_mod.emission_color(VolumeSettings())
    for sigma in (0.0, 2.0):
        r = render_volume(b, cam, [], VolumeSettings(density_scale=sigma, emission_scale=2.0, step=0.25),
                          cl_device).rgba
        tau = -np.log(1 - r[..., 3]) if sigma else None
        chord = reference.sphere_chord(np.array(cam.origin), cam.pixel_dirs().reshape(-1, 3),
                                       np.zeros(3), (R + 0.5) * VOX).reshape(8, 8)
        for ch in range(3):
            if sigma:
                want = 2.0 * colour[ch] * (1 - np.exp(-tau)) / sigma
                np.testing.assert_allclose(r[..., ch], want, rtol=0.02)
            else:
                # effective radius R + 1/2 voxel, +-0.9 voxel per crossing (see the
                # sphere test); these rays meet the surface at cos(theta) > 0.9
                tol = 2.0 * colour[ch] * 2 * 0.9 * VOX / 0.9
                assert np.max(np.abs(r[..., ch] - 2.0 * colour[ch] * chord)) <= tol
    assert colour[0] == 1.0 and colour[0] > colour[1] > colour[2]


def test_same_seed_same_image_whatever_the_launch_split(cl_device):
    b = sparse_blobs()
    cam = Camera((0.0, 2.0, 14.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 55.0, 40, 30)
    s = VolumeSettings(density_scale=4.0, spp=3, seed=11)
    one = render_volume(b, cam, [Sun((0, -1, -1), 2.0)], s, cl_device).rgba
    split = render_volume(b, cam, [Sun((0, -1, -1), 2.0)], s, cl_device,
                          launch=Launch(first=40 * 7)).rgba
    assert np.array_equal(one, split)
    other = render_volume(b, cam, [Sun((0, -1, -1), 2.0)], VolumeSettings(density_scale=4.0, spp=3, seed=12),
                          cl_device).rgba
    assert not np.array_equal(one, other)


@pytest.mark.parametrize("feature", ["emission", "depth", "sun", "point", "shadows", "mixed"])
def test_a_feature_without_effect_matches_it_switched_off(cl_device, feature):
    """Each compile-time feature, switched on where it cannot matter, gives the same
    image as the program built without it."""
    n = 24
    v = ball(n, 9)
    c = (n - 1) / 2 * VOX
    cam = Camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 35.0, 16, 16)
    base = Bricks.from_dense(v, scaled(VOX, (-c, -c, -c)))
    lights = [Sun((0, -1, -1), 2.0)]
    s = VolumeSettings(density_scale=3.0, phase=(0.5, 0.0, 1.0))
    off = render_volume(base, cam, lights, s, cl_device).rgba
    if feature == "emission":
        on = render_volume(Bricks.from_dense(v, scaled(VOX, (-c, -c, -c)), emission=np.zeros_like(v)),
                           cam, lights, s, cl_device)
    elif feature == "depth":
        on = render_volume(base, cam, lights, VolumeSettings(**{**s.__dict__, "aovs": ("depth",)}), cl_device)
        assert np.all(np.isfinite(on.aovs["depth"][on.rgba[..., 3] > 0]))
    elif feature == "sun":
        on = render_volume(base, cam, lights + [Sun((1, 0, 0), 0.0)], s, cl_device)
    elif feature == "point":
        on = render_volume(base, cam, lights + [PointLight((0, 3, 0), 0.0)], s, cl_device)
    elif feature == "shadows":
        # shadow rays toward a light of irradiance 0 cannot matter; the medium, lit by a
        # uniform environment (which --no-shadows leaves attenuated), is not black
        dark = [Sun((0, -1, -1), 0.0)]
        lit = {**s.__dict__, "env": (0.3, 0.4, 0.5)}
        off = render_volume(base, cam, dark, VolumeSettings(**lit), cl_device)
        on = render_volume(base, cam, dark, VolumeSettings(**{**lit, "shadows": False}), cl_device)
        assert off.flags["VR_SHADOWS"] == 1 and on.flags["VR_SHADOWS"] == 0
        off = off.rgba
        assert off[..., 3].max() > 0.5 and off[..., :3].max() > 0.05
    else:
        on = render_volume(base, cam, lights, VolumeSettings(**{**s.__dict__, "phase": (0.5, 0.9, 0.99999)}),
                           cl_device)
        assert on.flags["VR_PHASE_MIXED"] == 1
        np.testing.assert_allclose(on.rgba, off, rtol=1e-4, atol=1e-6)
        return
    np.testing.assert_array_equal(on.rgba, off)


def test_stiff_inputs_stay_finite(cl_device):
    """Optical depth per step >> 1, |g| at the clamp, huge point-light intensity close
    by: finite, opaque where it should be."""
    n = 24
    c = (n - 1) / 2 * VOX
    b = Bricks.from_dense(ball(n, 9), scaled(VOX, (-c, -c, -c)))
    cam = Camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 35.0, 16, 16)
    with pytest.warns(UserWarning, match="clamped"):
        s = VolumeSettings(density_scale=1e6, phase=(1.0, -1.0, 0.5))
        r = render_volume(b, cam, [Sun((0, 0, 1), 1e3), PointLight((0, 0, 0), 1e9)], s, cl_device)
    assert np.all(np.isfinite(r.rgba))
    assert r.rgba[8, 8, 3] == 1.0
