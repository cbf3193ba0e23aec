"""Glass: tiled dispatch and the uber-kernel give the fragment kernel's image; per-point
colours and soft shadows."""
import numpy as np
import pytest

from volrender import features, generators, glass, spheres
from volrender.camera import Camera
from volrender.errors import UserError
from volrender.lights import PointLight, Sun
from volrender.cloud import PointCloud
from helpers import render_points

# Tiled lists change only the order of the blend sums (sorted indices instead of tree
# order), so hit points move by float rounding; 2 bounces keep paths non-chaotic.
ATOL = 2e-3
LIGHTS = [Sun((-0.5, -1.0, -0.3), 3.0), PointLight((2.0, 2.0, 2.0), 5.0)]


def _render(dev, cloud, settings, size=(24, 20), cam=None, lights=LIGHTS, variant=None):
    cam = cam or glass.default_camera(cloud, *size)
    return render_points(cloud, cam, list(lights), settings, dev, variant=variant).rgba


def _agree(a, b, frac=1.0):
    assert np.isfinite(a).all() and np.isfinite(b).all()
    close = np.abs(a - b).max(axis=-1) <= ATOL
    assert close.mean() >= frac, f"{(~close).sum()} of {close.size} pixels differ"


@pytest.mark.parametrize("accel", ("grid", "tree", "none"))
@pytest.mark.parametrize("tile", [(8, 8), (16, 4), (1, 1), (5, 3)])
def test_tiled_matches_fragment(cl_device, accel, tile):
    cloud = generators.blob(300, seed=3)
    base = glass.GlassSettings(bounces=2, accel=accel, blend=0.12)
    a = _render(cl_device, cloud, base)                     # 24x20: not a multiple of 16x8
    b = _render(cl_device, cloud, glass.GlassSettings(**{**base.__dict__, "dispatch": "tiled",
                                                          "tile": tile}))
    assert a[..., 3].mean() > 0.15
    _agree(a, b)
    np.testing.assert_array_equal(a[..., 3], b[..., 3])


def test_fragment_blocks_do_not_change_the_image(cl_device):
    """Fragment work-groups of any block shape, or the driver's choice, are the same
    per-pixel computation: identical images."""
    cloud = generators.blob(300, seed=3)
    base = glass.GlassSettings(bounces=2, blend=0.12, dispatch="fragment")
    a = _render(cl_device, cloud, base)
    for kw in ({"tile": (16, 8)}, {"tile": (5, 3)}, {"dispatch": "fragment-driver"}):
        b = _render(cl_device, cloud, glass.GlassSettings(**{**base.__dict__, **kw}))
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("accel", ("grid", "tree", "none"))
def test_stats_count_the_field_work(cl_device, accel):
    """Diagnostics: brute force tests every sphere twice per evaluation (nearest, then
    the sums); the tree tests fewer spheres plus some nodes; the cells look up one cell
    per evaluation or skip, and test at most the longest list plus its core per
    evaluation; coverage is unchanged."""
    cloud = generators.blob(200, seed=3)
    base = glass.GlassSettings(bounces=2, blend=0.12, accel=accel, dispatch="fragment")
    img = _render(cl_device, cloud, base)
    st = _render(cl_device, cloud, base, variant="stats")
    np.testing.assert_array_equal(st[..., 3], img[..., 3])
    evals, nodes, tests = st[..., 0], st[..., 1], st[..., 2]
    assert evals.max() > 10
    if accel == "tree":
        assert (evals >= 1).all()
        assert nodes.sum() > 0 and tests.sum() < 2 * len(cloud.centers) * evals.sum() / 4
    elif accel == "none":
        assert (evals >= 1).all() and nodes.sum() == 0
        np.testing.assert_array_equal(tests, 2 * len(cloud.centers) * evals)
    else:
        grid = spheres.pack_scene(cloud, base, device=cl_device,          # the render's cells
                                samples=st.shape[0] * st.shape[1] * base.spp).cells
        longest = int((grid.lengths() + grid.lengths(core=True)).max())
        assert (nodes >= evals).all() and nodes.sum() > evals.sum()   # lookups, skips
        assert (tests <= longest * evals).all() and tests.sum() > 0
        assert (evals[img[..., 3] == 0] == 0).mean() > 0.5   # most misses cross only skips


def test_tiled_list_overflow_falls_back(cl_device):
    # one 16x12 tile sees all 3000 spheres: more than the list holds (GLASS_TILE_CAP)
    cloud = generators.blob(3000, seed=4)
    assert len(cloud.centers) > features.GLASS_TILE_CAP
    base = glass.GlassSettings(bounces=2)
    a = _render(cl_device, cloud, base, size=(16, 12))
    b = _render(cl_device, cloud, glass.GlassSettings(**{**base.__dict__, "dispatch": "tiled",
                                                          "tile": (16, 12)}), size=(16, 12))
    _agree(a, b)


def test_tiled_camera_inside_glass(cl_device):
    cloud = generators.blob(150, seed=10)
    cam = Camera((0.0, 0.0, 0.0), (0.0, 0.0, -1.0), fov=90, width=16, height=16)
    s = glass.GlassSettings(blend=0.15, bounces=2)
    a = _render(cl_device, cloud, s, cam=cam)
    b = _render(cl_device, cloud, glass.GlassSettings(**{**s.__dict__, "dispatch": "tiled"}), cam=cam)
    _agree(a, b)
    assert (b[..., 3] == 1).all()


@pytest.mark.parametrize("opts", [{}, {"refraction": False}, {"shadows": False},
                                  {"glow": 0.0, "absorption": (0, 0, 0)}])
def test_uber_kernel_gives_the_specialised_image(cl_device, opts):
    cloud = generators.blob(200, seed=6)
    s = glass.GlassSettings(bounces=2, **opts)
    a = _render(cl_device, cloud, s)
    r = render_points(cloud, glass.default_camera(cloud, 24, 20), LIGHTS, s, cl_device,
                            variant="uber")
    np.testing.assert_allclose(a, r.rgba, atol=1e-5)
    # and it really is one program with every feature in
    flags = r.flags
    assert flags["VR_UBER"] == 1 and flags["VR_REFRACTION"] == 1 and flags["VR_N_SUNS"] == 0


def test_unlit_uber_matches_unlit(cl_device):
    cloud = generators.blob(120, seed=2)
    s = glass.GlassSettings(bounces=2)
    a = _render(cl_device, cloud, s, lights=[])
    b = _render(cl_device, cloud, s, lights=[], variant="uber")
    np.testing.assert_allclose(a, b, atol=1e-5)


# ------------------------------------------------------------------ per-point colours

def _two_spheres(colors):
    return PointCloud(centers=np.array([[-0.6, 0, 0], [0.6, 0, 0]], float),
                      radii=np.array([0.5, 0.5]), colors=np.array(colors, np.float32))


def test_point_colours_tint_each_sphere(cl_device):
    cloud = _two_spheres([[1, 0, 0], [0, 0, 1]])
    cam = Camera((0, 0, 4), (0, 0, 0), fov=40, width=32, height=16)
    s = glass.GlassSettings(refraction=False, blend=0.2, reflectivity=0.0)
    img = _render(cl_device, cloud, s, cam=cam, lights=[])
    left, right = img[8, 10, :3], img[8, 21, :3]          # sphere centres' pixels
    assert left[0] > 0 and left[2] == 0 and left[1] == 0
    assert right[2] > 0 and right[0] == 0 and right[1] == 0
    neck = img[8, 16, :3]                                  # the blend mixes both colours
    assert neck[0] > 0 and neck[2] > 0
    # --no-point-colors: the material colour everywhere
    plain = _render(cl_device, cloud, glass.GlassSettings(**{**s.__dict__, "point_colors": False}),
                    cam=cam, lights=[])
    uncoloured = _render(cl_device, PointCloud(centers=cloud.centers, radii=cloud.radii), s,
                         cam=cam, lights=[])
    np.testing.assert_array_equal(plain, uncoloured)


def test_point_colours_set_the_glow(cl_device):
    cloud = _two_spheres([[0, 1, 0], [0, 1, 0]])
    cam = Camera((0, 0, 4), (0, 0, 0), fov=40, width=16, height=8)
    s = glass.GlassSettings(ior=1.0, absorption=(0, 0, 0), reflectivity=0.0, glow=1.0,
                            color=(1.0, 0.0, 0.0))
    with_cols = _render(cl_device, cloud, s, cam=cam, lights=[])
    without = _render(cl_device, cloud, glass.GlassSettings(**{**s.__dict__, "point_colors": False}),
                      cam=cam, lights=[])
    sky = _render(cl_device, PointCloud(centers=np.zeros((0, 3)), radii=np.zeros(0)), s,
                  cam=cam, lights=[])
    glow_c, glow_m = with_cols - sky, without - sky
    assert glow_c[..., 1].max() > 0.1 and np.abs(glow_c[..., [0, 2]]).max() < 1e-5
    assert glow_m[..., 0].max() > 0.1 and np.abs(glow_m[..., [1, 2]]).max() < 1e-5


# ------------------------------------------------------------------ soft shadows

def _shadow_scene():
    # an opaque ground sphere, a small occluder above it, the sun straight down
    cloud = PointCloud(centers=np.array([[0, -10.0, 0], [0, 0.6, 0]]), radii=np.array([10.0, 0.25]))
    cam = Camera((0, 3.0, 2.5), (0, 0, 0), fov=50, width=32, height=32)
    return cloud, cam, [Sun((0, -1.0, 0), 3.0)]


def test_soft_shadows(cl_device):
    cloud, cam, sun = _shadow_scene()
    base = glass.GlassSettings(refraction=False, blend=0.0)
    hard = _render(cl_device, cloud, base, cam=cam, lights=sun)
    zero = _render(cl_device, cloud, glass.GlassSettings(**{**base.__dict__, "shadow_angle": 0.0}),
                   cam=cam, lights=sun)
    np.testing.assert_array_equal(hard, zero)
    soft = _render(cl_device, cloud, glass.GlassSettings(**{**base.__dict__, "shadow_angle": 5.0}),
                   cam=cam, lights=sun)
    unlit = _render(cl_device, cloud, base, cam=cam, lights=[])
    assert np.isfinite(soft).all()
    lum = lambda a: a[..., :3].sum(-1)                    # noqa: E731
    lit = lum(hard) - lum(unlit)                           # the sun's share: 0 in shadow
    share = (lum(soft) - lum(unlit)) / np.where(lit > 0, lit, 1)
    ground = lum(unlit) > 0
    # hard: each ground pixel either fully lit or fully shadowed
    assert ((lit > 1e-4) | (np.abs(lum(hard) - lum(unlit)) < 1e-5)).all()
    assert (lit[ground] <= 1e-4).sum() > 4                   # there is a shadow
    # soft: the penumbra estimate only ever removes light (the umbra stays the hard one),
    # and a band of partly lit pixels appears around the shadow
    assert (lum(soft) <= lum(hard) + 1e-5).all()
    partial = (share > 0.05) & (share < 0.95) & (lit > 1e-4)
    assert partial.sum() > 4


def test_soft_shadow_angle_is_validated():
    with pytest.raises(UserError, match="shadow_angle="):
        glass.GlassSettings(shadow_angle=90.0)
    with pytest.raises(UserError, match="tile"):
        glass.GlassSettings(dispatch="tiled", tile=(64, 64))
    with pytest.raises(UserError, match="dispatch"):
        glass.GlassSettings(dispatch="warp")


# ------------------------------------------------------------------ over-relaxation

def test_over_relaxation_misses_nothing(cl_device):
    """Over-relaxed steps fall back whenever the safe balls stop overlapping, so the same
    rays hit (identical coverage) and hit points move only within the threshold."""
    cloud = generators.blob(200, seed=8)
    base = glass.GlassSettings(bounces=1, max_steps=4096, epsilon=1e-5)
    a = _render(cl_device, cloud, base, size=(32, 24))
    for w in (1.5, 1.9):
        b = _render(cl_device, cloud, glass.GlassSettings(**{**base.__dict__, "relax": w}),
                    size=(32, 24))
        np.testing.assert_array_equal(a[..., 3], b[..., 3])
        _agree(a, b, frac=0.97)
    with pytest.raises(UserError, match="relax"):
        glass.GlassSettings(relax=2.0)


class _Stub:
    def __init__(self, extensions):
        self.extensions = extensions

    def has_extension(self, name):
        return name in self.extensions.split()


def test_register_cap_only_where_the_compiler_takes_it(cl_device, monkeypatch):
    cap = (f"-cl-nv-maxrregcount={glass.NV_MAX_REGISTERS}",)
    nv = _Stub("cl_khr_fp64 cl_nv_compiler_options")
    glassy = features.GlassFeatures(n_suns=1)
    opaque_unlit = features.GlassFeatures(refraction=False)
    assert glass.build_options(glassy, nv) == cap
    assert glass.build_options(features.GlassFeatures(refraction=False, n_points=1), nv) == cap
    assert glass.build_options(opaque_unlit, nv) == ()
    assert glass.build_options(features.GlassFeatures(n_suns=1, colors=True), nv) == ()
    assert glass.build_options(glassy, _Stub("cl_khr_fp64")) == ()
    monkeypatch.setenv("VOLRENDER_NV_MAX_REGISTERS", "0")
    assert glass.build_options(glassy, nv) == ()
    monkeypatch.setenv("VOLRENDER_NV_MAX_REGISTERS", "64")
    assert glass.build_options(glassy, nv) == ("-cl-nv-maxrregcount=64",)
    monkeypatch.setenv("VOLRENDER_NV_MAX_REGISTERS", "many")
    with pytest.raises(UserError, match="VOLRENDER_NV_MAX_REGISTERS"):
        glass.build_options(glassy, nv)
    monkeypatch.delenv("VOLRENDER_NV_MAX_REGISTERS")
    # the default device (PoCL here) takes no NVIDIA option, and renders
    assert glass.build_options(glassy, cl_device) == () or \
        cl_device.has_extension("cl_nv_compiler_options")
    img = _render(cl_device, generators.blob(40, seed=2), glass.GlassSettings())
    assert np.isfinite(img).all() and img[..., 3].max() > 0.5
