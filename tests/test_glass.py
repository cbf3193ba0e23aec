"""Glass point clouds: smooth-union field vs the numpy oracle, support cells and tree vs
brute force, optics against closed forms, invisibility at IOR 1, and degenerate inputs."""
import math

import numpy as np
import pytest
from glass_probe import Probe, optics

import reference
from volrender import generators, glass, spheres
from volrender.camera import Camera
from volrender.errors import UserError
from volrender.lights import PointLight, Sun
from volrender.cloud import PointCloud
from helpers import render_points

# Field values are float32 sums of O(10) terms of size ~scale: relative error ~1e-6.
ATOL_FIELD = 2e-5     # blob of radius ~1
# Images: tree and brute force differ only in summation order, so hit points move by
# ~1e-6 of the path; radiance changes by far less than this.
ATOL_IMAGE = 2e-3
SIZE = 24

def field(dev, cloud, settings, x):
    """(F, grad) from the kernel at world points x, and the packed scene."""
    p = Probe(dev, cloud, settings)
    f, g = p.field(x)
    return f, g, p.scene


def _render(dev, cloud, settings, cam=None, lights=(), size=SIZE):
    cam = cam or glass.default_camera(cloud, size, size, radius=settings.radius)
    return render_points(cloud, cam, list(lights), settings, dev).rgba


def _samples(rng, cloud, n=400):
    lo, hi = cloud.centers.min(0) - 0.3, cloud.centers.max(0) + 0.3
    return rng.uniform(lo, hi, size=(n, 3))


# ------------------------------------------------------------------ field vs oracle

@pytest.mark.parametrize("accel", ("grid", "tree", "none"))
@pytest.mark.parametrize("k", [0.0, 0.05, 0.15, 2.0])
def test_field_matches_oracle(cl_device, rng, accel, k):
    """Every acceleration gives the brute-force field; cells listed everywhere (no
    skipping), so every sample point reads a list."""
    cloud = generators.blob(300, seed=3)
    s = glass.GlassSettings(blend=k, leaf_size=2, accel=accel, cell_skip=False)
    x = _samples(rng, cloud)
    f, _, _ = field(cl_device, cloud, s, x)
    ref = reference.smooth_union(x, cloud.centers, cloud.radii, k)
    atol = ATOL_FIELD * (1.0 + 0.25 * k * 10)   # large k: more (float32) terms
    np.testing.assert_allclose(f, ref, atol=atol)


@pytest.mark.parametrize("cell,k", [(0.1, 0.02), (0.3, 0.05), (0.6, 0.15)])
def test_field_with_cells_wider_than_the_blend(cl_device, rng, cell, k):
    """Cells wider than the blend k: a list's key (a sphere's distance bound over the
    whole cell) then orders spheres far from the point's own order, so a walk that
    stopped or weighted by key instead of by the point's distances would be off (a one-pass
    walk that kept spheres taken before the minimum fell was off by 0.03-0.24 here). Field
    and gradient stay brute force's."""
    cloud = generators.blob(300, seed=3)
    x = _samples(rng, cloud, 1000)
    s = glass.GlassSettings(blend=k, accel="grid", cell_skip=False, cell_size=cell)
    f, g, scene = field(cl_device, cloud, s, x)
    assert scene.accel == "grid"
    ref = reference.smooth_union(x, cloud.centers, cloud.radii, k)
    np.testing.assert_allclose(f, ref, atol=ATOL_FIELD)
    _, g_ref, _ = field(cl_device, cloud, glass.GlassSettings(blend=k, accel="none"), x)
    np.testing.assert_allclose(g, g_ref, atol=1e-4)


def test_two_sphere_blend_is_c1_and_compact():
    """Two spheres: F equals the plain union where |a - b| >= k, lies below it inside,
    by (k/2) ln 2 on the seam, and its slope along a-b is 1/2 from both sides there."""
    k = 0.4
    c = np.array([[0.0, 0, 0], [0.9, 0, 0]])
    x = np.random.default_rng(1).uniform(-1, 2, size=(400, 3))
    a = np.linalg.norm(x - c[0], axis=1) - 0.5
    b = np.linalg.norm(x - c[1], axis=1) - 0.5
    f = reference.smooth_union(x, c, 0.5, k)
    far = np.abs(a - b) >= k
    np.testing.assert_allclose(f[far], np.minimum(a, b)[far], atol=1e-12)
    assert np.all(f[~far] < np.minimum(a, b)[~far])
    seam = np.array([[0.45, 0.3, 0.0]])
    assert reference.smooth_union(seam, c, 0.5, k)[0] == pytest.approx(
        np.linalg.norm(seam - c[0]) - 0.5 - 0.5 * k * np.log(2.0))
    e = 1e-6                       # along x, d_a grows and d_b shrinks at the same rate
    fx = [reference.smooth_union(seam + [[s, 0, 0]], c, 0.5, k)[0] for s in (-e, 0.0, e)]
    assert (fx[1] - fx[0]) / e == pytest.approx((fx[2] - fx[1]) / e, abs=1e-4)


def test_gradient_matches_finite_difference(cl_device, rng):
    cloud = generators.blob(100, seed=4)
    s = glass.GlassSettings(blend=0.2, leaf_size=4, cell_skip=False)
    x = _samples(rng, cloud, 50)
    _, g, _ = field(cl_device, cloud, s, x)
    h = 1e-5
    fd = np.stack([(reference.smooth_union(x + h * e, cloud.centers, cloud.radii, 0.2)
                    - reference.smooth_union(x - h * e, cloud.centers, cloud.radii, 0.2)) / (2 * h)
                   for e in np.eye(3)], axis=1)
    assert np.median(np.linalg.norm(g - fd, axis=1)) < 1e-3


@pytest.mark.parametrize("k", [0.05, 0.2, 0.6])
def test_gradient_bound_holds(cl_device, rng, k):
    """lip = max(1, 2 s1o/S - 1) bounds |grad F| at the point: the kernel's analytic
    gradient and the oracle's central differences both stay below it."""
    cloud = generators.blob(200, seed=6)
    s = glass.GlassSettings(blend=k, leaf_size=4, cell_skip=False)
    x = _samples(rng, cloud, 300)
    gnorm, lip, _ = Probe(cl_device, cloud, s).lip(x)
    assert (lip >= 1.0).all()
    assert (gnorm <= lip * (1 + 1e-4) + 1e-5).all()
    h = 1e-6
    fd = np.stack([(reference.smooth_union(x + h * e, cloud.centers, cloud.radii, k)
                    - reference.smooth_union(x - h * e, cloud.centers, cloud.radii, k)) / (2 * h)
                   for e in np.eye(3)], axis=1)
    assert (np.linalg.norm(fd, axis=1) <= lip + 1e-3).all()


def _first_crossing(o, d, cloud, k, side, t_max=6.0, h=2e-3):
    """Oracle: the first t where side * F changes sign along o + t d (dense scan, then
    bisection), or nan."""
    t = np.arange(0.0, t_max, h)
    f = side * reference.smooth_union(o + t[:, None] * d, cloud.centers, cloud.radii, k)
    below = np.nonzero(f <= 0)[0]
    if len(below) == 0:
        return np.nan
    j = below[0]
    if j == 0:
        return 0.0
    a, b = t[j - 1], t[j]
    for _ in range(40):
        c = 0.5 * (a + b)
        fc = side * reference.smooth_union(o + c * d, cloud.centers, cloud.radii, k)[0]
        a, b = (a, c) if fc <= 0 else (c, b)
    return 0.5 * (a + b)


@pytest.mark.parametrize("accel", ["grid", "tree"])
@pytest.mark.parametrize("relax", [1.0, 1.6, 1.9])
@pytest.mark.parametrize("side,spread", [(1.0, 0.1), (1.0, 0.4), (-1.0, 0.0)])
def test_trace_finds_the_first_crossing(cl_device, rng, relax, side, spread, accel):
    """Sphere tracing with the gradient bound and over-relaxation never steps over a
    surface, and neither does crossing support cells without evaluations: from outside
    (rays aimed into the blob, and with the wider spread many that graze its bumps, where
    the adaptive factor climbs to its cap) and from inside (rays from sphere centres), the
    hit is the oracle's first crossing."""
    cloud = generators.blob(120, seed=7)
    k = 0.25
    probe = Probe(cl_device, cloud, glass.GlassSettings(blend=k, leaf_size=4, accel=accel,
                                                         epsilon=1e-5))
    n = 64
    if side > 0:
        aim = cloud.centers[rng.integers(0, len(cloud.centers), n)] + rng.normal(0, spread, (n, 3))
        o = rng.normal(0, 1, (n, 3))
        o = 3.0 * o / np.linalg.norm(o, axis=1, keepdims=True)
        d = aim - o
    else:
        o = cloud.centers[rng.integers(0, len(cloud.centers), n)]
        d = rng.normal(0, 1, (n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t, _ = probe.trace(o, d, side, relax)
    ref = np.array([_first_crossing(o[i], d[i], cloud, k, side) for i in range(n)])
    assert np.isfinite(ref).mean() > (0.9 if spread < 0.2 else 0.3)
    hit = t >= 0
    np.testing.assert_array_equal(hit, np.isfinite(ref))
    np.testing.assert_allclose(t[hit], ref[hit], atol=2e-3)


@pytest.mark.parametrize("accel", ("grid", "tree", "none"))
@pytest.mark.parametrize("margin", [1e-3, 0.1, 0.5])
def test_relaxed_step_past_the_march_end_is_retried(cl_device, accel, margin):
    """From a sphere's centre outwards the first relaxed step (1.6 r) ends past a march end
    just beyond the wall (the clip box's exit, t1 = r (1 + margin)): the plain step must be
    taken instead, so the wall is hit at r (a lost ray was a miss). The shadow rays' march
    (a penumbra cone) is the same loop."""
    r = 0.5
    cloud = PointCloud(np.zeros((1, 3)), np.array([r]))
    probe = Probe(cl_device, cloud, glass.GlassSettings(blend=0.0, accel=accel, epsilon=1e-5))
    d = np.random.default_rng(2).normal(0, 1, (32, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.zeros((32, 3))
    for cone in (0.0, 0.05):
        t, _ = probe.trace(o, d, side=-1.0, relax=1.6, t1=r * (1 + margin), cone=cone)
        np.testing.assert_allclose(t, r, atol=1e-4)
    # and from outside: rays that graze past the sphere to a box exit just beyond it see
    # no surface, and rays through it hit at the closed form
    o = np.tile([0.0, 0.0, 3.0 * r], (32, 1))
    aim = np.random.default_rng(3).uniform(-0.8 * r, 0.8 * r, (32, 3)) * [1, 1, 0]
    d = (aim - o) / np.linalg.norm(aim - o, axis=1, keepdims=True)
    b = np.einsum("ij,ij->i", d, o)
    t_ref = -b - np.sqrt(b * b - (np.einsum("ij,ij->i", o, o) - r * r))
    t, _ = probe.trace(o, d, relax=1.6, t1=t_ref.max() * (1 + margin))
    np.testing.assert_allclose(t, t_ref, atol=1e-4)


@pytest.mark.parametrize("accel", ("grid", "tree", "none"))
@pytest.mark.parametrize("blend", [0.0, 0.05])
def test_relaxed_tracing_gives_the_plain_image(cl_device, accel, blend):
    """One glass sphere at blend 0 (and 0.05 r): over-relaxed tracing renders what plain
    tracing does, up to the float noise that moving hit points within the hit band makes
    (the plain image against itself at half the epsilon). Lost rays (a relaxed step past
    the far wall and the box exit) left 26-31% of the sphere's pixels off."""
    cloud = PointCloud(np.zeros((1, 3)), np.ones(1))
    cam = glass.default_camera(cloud, 48, 48)

    def img(**kw):
        s = glass.GlassSettings(blend=blend, accel=accel, absorption=(0, 0, 0), glow=0.0, **kw)
        return _render(cl_device, cloud, s, cam)

    plain, relaxed = img(relax=1.0), img(relax=1.6)
    noise = _differ(plain, img(relax=1.0, epsilon=5e-5))
    cover = plain[..., 3] > 0
    assert cover.mean() > 0.2
    assert _differ(plain, relaxed) <= max(noise, 0.01)
    assert relaxed[cover, :3].mean() == pytest.approx(plain[cover, :3].mean(), rel=2e-3)


# ------------------------------------------------------------------ cells, tree, brute force

def _differ(a, b):
    return (np.abs(a - b).max(axis=-1) > ATOL_IMAGE).mean()


# Paths through many refractions are chaotic: in brute force alone, moving the camera by
# 3e-6 changes ~3% of 48x48 pixels at 6 bounces. So: all pixels agree at 2 bounces, and
# nearly all at 6 (the differences are float noise amplified, not missed spheres).
# Support cells listed everywhere evaluate the same field at the same points as the tree,
# summed in another order (the walk's key order, cl/cells.h): the tree's image as brute
# force gives it (all pixels at 2 bounces, nearly all at 6), the same coverage. Cells that rays
# cross without evaluating move where marching resumes, so hit points move within the hit
# band eps (base + t): the image then differs from brute force on fewer pixels than brute
# force with half the epsilon differs from itself (measured: 2.4% against 6.4% at 2
# bounces, 6.4% against 11.3% at 6), with the same coverage.
@pytest.mark.parametrize("leaf_size,bounces,min_frac", [(1, 2, 1.0), (3, 2, 1.0), (2, 6, 0.97)])
def test_accelerations_give_the_brute_force_image(cl_device, leaf_size, bounces, min_frac):
    cloud = generators.blob(250, seed=5)
    spacing = (4.0 / 250) ** (1 / 3)          # blend ~ spacing: many spheres straddle leaves
    base = glass.GlassSettings(blend=spacing, leaf_size=leaf_size, bounces=bounces)
    lights = [Sun((-0.5, -1.0, -0.3), 3.0), PointLight((2.0, 2.0, 2.0), 5.0)]

    def render(**kw):
        return _render(cl_device, cloud, glass.GlassSettings(**{**base.__dict__, **kw}),
                       lights=lights)

    tree, none = render(accel="tree"), render(accel="none")
    assert np.isfinite(tree).all()
    assert tree[..., 3].mean() > 0.2
    assert 1 - _differ(tree, none) >= min_frac, f"{_differ(tree, none):.3f} of the pixels differ"
    np.testing.assert_array_equal(tree[..., 3], none[..., 3])     # same coverage
    listed = render(accel="grid", cell_skip=False)
    np.testing.assert_array_equal(listed[..., 3], tree[..., 3])
    assert 1 - _differ(listed, tree) >= min_frac, f"{_differ(listed, tree):.3f} differ"
    grid = render(accel="grid")
    np.testing.assert_array_equal(grid[..., 3], none[..., 3])
    assert _differ(grid, none) <= _differ(none, render(accel="none", epsilon=base.epsilon / 2))


@pytest.mark.parametrize("colors", [False, True])
def test_list_prefetch_gives_the_plain_walk_image(cl_device, monkeypatch, colors):
    """Walking a cell's list with its loads issued ahead (VR_LIST_PREFETCH 1 and 2,
    cl/sdf.h SDF_WALK_LIST) tests the same spheres in the same order as the plain walk:
    the image is the plain walk's bit for bit, per-point colours included (cells smaller
    than the spheres, so rays read many lists, some short)."""
    cloud = generators.blob(250, seed=5)
    if colors:
        rgb = np.random.default_rng(1).uniform(0, 1, (250, 3)).astype(np.float32)
        cloud = PointCloud(cloud.centers, cloud.radii, rgb)
    s = glass.GlassSettings(blend=0.15, accel="grid", bounces=3, cell_size=0.03)
    lights = [Sun((-0.5, -1.0, -0.3), 3.0)]
    images = []
    for level in ("0", "1", "2"):
        monkeypatch.setenv("VOLRENDER_CL_OPTIONS", f"-DVR_LIST_PREFETCH={level}")
        images.append(_render(cl_device, cloud, s, lights=lights))
    assert images[0][..., 3].mean() > 0.2
    np.testing.assert_array_equal(images[0], images[1])
    np.testing.assert_array_equal(images[0], images[2])
    # and the options do reach the kernel (the device's kernel cache keys them): a
    # smaller relaxation margin moves hit points within the hit band
    monkeypatch.setenv("VOLRENDER_CL_OPTIONS", "-DVR_RELAX_MARGIN=0.5f")
    assert not np.array_equal(images[0], _render(cl_device, cloud, s, lights=lights))


# ------------------------------------------------------------------ single sphere, optics

def test_single_sphere_hit_and_normal(cl_device, rng):
    r, c = 0.7, np.array([0.3, -0.2, 0.1])
    cloud = PointCloud(c[None], np.array([r]))
    o = np.tile([0.0, 0.0, 5.0], (64, 1)) + rng.uniform(-0.1, 0.1, (64, 3))
    aim = c + rng.uniform(-0.4, 0.4, (64, 3))
    d = (aim - o) / np.linalg.norm(aim - o, axis=1, keepdims=True)
    oc = o - c
    b = np.einsum("ij,ij->i", d, oc)
    t_ref = -b - np.sqrt(b * b - (np.einsum("ij,ij->i", oc, oc) - r * r))
    n_ref = (o + t_ref[:, None] * d - c) / r
    for accel in ("grid", "tree", "none"):
        t, n = Probe(cl_device, cloud, glass.GlassSettings(blend=0.0, epsilon=1e-5,
                                                            accel=accel)).trace(o, d)
        np.testing.assert_allclose(t, t_ref, atol=1e-4)
        np.testing.assert_allclose(n, n_ref, atol=1e-4)


_optics = optics


def test_refraction_follows_snell(cl_device):
    theta = np.radians(np.linspace(0, 89, 30))
    d = np.stack([np.sin(theta), 0 * theta, -np.cos(theta)], axis=1)
    for eta in (1 / 1.5, 1 / 1.33, 1.2):
        out = _optics(cl_device, d, eta)
        ok = eta * np.sin(theta) < 1
        sin_t = out[ok, 0]
        np.testing.assert_allclose(sin_t, eta * np.sin(theta[ok]), atol=2e-6)
        np.testing.assert_allclose(np.linalg.norm(out[ok, :3], axis=1), 1, atol=1e-6)
        assert (out[ok, 2] < 0).all()                      # continues through the surface


def test_fresnel_normal_incidence_and_tir(cl_device):
    for n in (1.0, 1.33, 1.5, 2.4):
        out = _optics(cl_device, np.array([[0.0, 0, -1]]), 1 / n)
        assert out[0, 3] == pytest.approx(((n - 1) / (n + 1)) ** 2, abs=1e-6)
    crit = math.asin(1 / 1.5)
    theta = np.array([crit - 0.02, crit + 0.02, 1.5])
    d = np.stack([np.sin(theta), 0 * theta, -np.cos(theta)], axis=1)
    out = _optics(cl_device, d, 1.5)                         # from inside glass
    assert out[0, 3] < 1 and np.linalg.norm(out[0, :3]) > 0.99
    assert (out[1:, 3] == 1).all() and (out[1:, :3] == 0).all()


# ------------------------------------------------------------------ invisibility

def test_ior_one_is_invisible(cl_device):
    cloud = generators.blob(120, seed=6)
    s = glass.GlassSettings(ior=1.0, absorption=(0, 0, 0), reflectivity=0.0, glow=0.0)
    cam = glass.default_camera(cloud, SIZE, SIZE)
    lights = [Sun((0.3, -1.0, -0.2), 4.0)]
    img = _render(cl_device, cloud, s, cam, lights)
    empty = _render(cl_device, PointCloud(np.zeros((0, 3))), s, cam, lights)
    assert img[..., 3].mean() > 0.2 and (empty[..., 3] == 0).all()
    np.testing.assert_array_equal(img[..., :3], empty[..., :3])
    tinted = _render(cl_device, cloud, glass.GlassSettings(), cam, lights)
    assert np.abs(tinted[..., :3] - empty[..., :3]).max() > 0.1


# ------------------------------------------------------------------ degenerate and extreme

def test_tiny_blend_is_plain_union(cl_device, rng):
    cloud = generators.blob(80, seed=7)
    x = _samples(rng, cloud, 200)
    f, _, _ = field(cl_device, cloud, glass.GlassSettings(blend=1e-30, cell_skip=False), x)
    d = np.linalg.norm(x[:, None] - cloud.centers[None], axis=2) - cloud.radii
    np.testing.assert_allclose(f, d.min(1), atol=ATOL_FIELD)


@pytest.mark.parametrize("case", ["huge_blend", "zero_radius", "one_point", "coincident"])
def test_degenerate_clouds_render_finite(cl_device, case):
    c = generators.blob(60, seed=8)
    cloud, s = {
        "huge_blend": (c, glass.GlassSettings(blend=50.0, bounces=2)),
        "zero_radius": (PointCloud(c.centers, np.zeros(60)), glass.GlassSettings(blend=0.3)),
        "one_point": (PointCloud(np.array([[1.0, 2.0, 3.0]]), np.array([0.5])),
                      glass.GlassSettings()),
        "coincident": (PointCloud(np.zeros((20, 3)), np.full(20, 0.5)),
                       glass.GlassSettings(blend=0.2)),
    }[case]
    img = _render(cl_device, cloud, s, lights=[Sun((0, -1, 0))])
    assert np.isfinite(img).all() and (img >= 0).all()
    if case != "zero_radius":
        assert img[..., 3].mean() > 0.05


def test_far_from_origin_renders_the_same(cl_device):
    cloud = generators.blob(150, seed=9)
    offset = np.array([1e5, -2e5, 1e5])
    far = PointCloud(cloud.centers + offset, cloud.radii)
    s = glass.GlassSettings(blend=0.1)
    cam = glass.default_camera(cloud, SIZE, SIZE)
    cam_far = Camera(tuple(np.add(cam.origin, offset)), tuple(np.add(cam.target, offset)),
                     cam.up, cam.fov, SIZE, SIZE)
    lights = [Sun((0.3, -1, -0.2), 3.0), PointLight((1.5, 2.0, 1.0), 4.0)]
    lights_far = [lights[0], PointLight(tuple(np.add((1.5, 2.0, 1.0), offset)), 4.0)]
    a = _render(cl_device, cloud, s, cam, lights)
    b = _render(cl_device, far, s, cam_far, lights_far)
    np.testing.assert_allclose(a, b, atol=ATOL_IMAGE)


def test_camera_inside_glass_is_finite(cl_device):
    cloud = generators.blob(100, seed=10)
    cam = Camera((0.0, 0.0, 0.0), (0.0, 0.0, -1.0), fov=90, width=SIZE, height=SIZE)
    img = _render(cl_device, cloud, glass.GlassSettings(blend=0.15), cam, [Sun((0, -1, 0))])
    assert np.isfinite(img).all()
    assert (img[..., 3] == 1).all()          # every primary ray starts in glass


def test_opaque_mode_and_env_map(cl_device, tmp_path):
    from volrender.image import write_image
    env = np.zeros((8, 16, 4), np.float32)
    env[:4, :, 0] = 2.0                     # red sky, blue ground
    env[4:, :, 2] = 1.0
    write_image(tmp_path / "env.exr", env)
    cloud = generators.blob(60, seed=11)
    s = glass.GlassSettings(env=str(tmp_path / "env.exr"), refraction=False)
    img = _render(cl_device, cloud, s, lights=[Sun((0, -1, 0))])
    assert np.isfinite(img).all()
    top = img[0, :, :3].mean(0)
    assert top[0] > 1.0 and top[1] == 0.0


def test_settings_are_validated():
    for bad in ({"ior": 0.0}, {"blend": -1.0}, {"bounces": 0}, {"absorption": (1, 2)},
                {"epsilon": 0.0}, {"radius": float("nan")}, {"spp": 0}):
        with pytest.raises(UserError):
            glass.GlassSettings(**bad)
    with pytest.raises(UserError, match="radius"):
        spheres.pack_scene(PointCloud(np.zeros((2, 3))), glass.GlassSettings())
    # |x - c|^2 would overflow float32 (the field uses sqrt(dot), not length())
    with pytest.raises(UserError, match="float32"):
        spheres.pack_scene(PointCloud(np.array([[0.0, 0, 0], [1e19, 0, 0]])),
                         glass.GlassSettings(radius=1.0))
    spheres.pack_scene(PointCloud(np.array([[0.0, 0, 0], [1e17, 0, 0]])), glass.GlassSettings(radius=1.0))


# ------------------------------------------------------------------ defaults of scans

def test_default_radius_is_half_the_exact_median_spacing(rng):
    """Brute-force nearest neighbours: half their median; points that coincide with another
    say nothing of the spacing and are left out."""
    c = rng.uniform(0, 1, (400, 3)) * [1.0, 0.3, 2.0]
    c = np.concatenate([c, c[:50]])
    d = np.linalg.norm(c[:, None] - c[None], axis=2)
    np.fill_diagonal(d, np.inf)
    nn = d.min(axis=1)
    assert spheres.default_radius(c) == pytest.approx(0.5 * np.median(nn[nn > 0]), rel=1e-12)
    assert spheres.default_radius(np.zeros((5, 3))) == 0.5       # no spacing: the fallback


def test_scans_get_melting_defaults(shared_data):
    """A scan without radii: radius half the median spacing, blend three times the 90th
    percentile (frag_115's spacing is uneven: the old in-leaf estimate was 42% high);
    absorption and glow follow the cloud's size."""
    from scipy.spatial import cKDTree
    from volrender import load_scene
    path = shared_data / "points" / "frag_115.ply"
    sc = load_scene(path, size=(8, 6))
    c = sc.content.cloud.centers
    nn = cKDTree(c).query(c, k=2)[0][:, 1]
    nn = nn[nn > 0]
    assert sc.settings.radius == pytest.approx(0.5 * np.median(nn))
    assert sc.settings.blend == pytest.approx(spheres.SCAN_BLEND * np.percentile(nn, 90))
    assert any("without radii" in n for n in sc.notes)
    scene = spheres.pack_scene(sc.content.cloud, glass.GlassSettings(radius=sc.settings.radius,
                                                                   accel="none"))
    assert spheres.material_unit(scene, sc.settings) == pytest.approx(scene.scale)
    assert spheres.material_unit(scene, glass.GlassSettings(material_unit=1.0)) == 1.0
    given = load_scene(path, size=(8, 6), radius=0.01, blend=0.02)
    assert (given.settings.radius, given.settings.blend) == (0.01, 0.02)
