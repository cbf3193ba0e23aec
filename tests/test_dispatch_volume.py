"""Tiled dispatch of the volume renderer (issue #4): same image as the fragment dispatch.

Why the two agree to (far below) float tolerance: both march the same lattice
t = t0 + (k + u) dt from the box entry t0, with the same expressions in the same order.
The tiled kernel only starts at a later k and stops earlier; the samples it leaves out
lie in empty bricks (outside every listed, padded occupied brick), and an empty brick
reads exactly 0 -- it is stored as empty only when its 9^3 values, apron included, are
all zero. The only sample that can differ is one within rounding (delta, a few ulps of
the local coordinate) of a face between an empty and an occupied brick, which the
empty-brick jump may take in one variant and skip in the other. There the trilinear
density is 0 on the face and at most vmax * delta away from it, so such a sample changes
the opacity by at most a = sigma * vmax * delta * dt and the radiance by at most
a * (peak radiance + in-scatter) -- see `tolerance`, which is still far below what one
sample more or less would change (test_tolerance_is_tight_enough...). On PoCL the
images are in fact bit-identical, here and in bench/volume.py (max |diff| = 0).
"""
from dataclasses import replace

import numpy as np
import pyopencl as cl
import pytest

from volrender import camera as camera_mod, features, layout, vdb
from volrender.camera import Camera
from volrender.errors import UserError
from volrender.lights import PointLight, Sun
from volrender.volume import VolumeSettings
from volrender.bricks import Bricks
from volrender.dispatch import Launch
from bench.common import tile_lists
from helpers import VOX, render_volume, scaled

LIGHTS = [Sun((-1.0, -0.5, -0.3), 2.0), PointLight((0.3, 4.0, 0.2), 40.0)]


def local_origin(b, cam):
    m = np.linalg.inv(np.asarray(b.local_to_world, np.float64))
    return m[:3, :3] @ np.asarray(cam.origin) + m[:3, 3]


def tolerance(b, cam, s, lights, peak):
    """Bound on |tiled - fragment| (module doc): a few boundary samples per ray, each
    changing the opacity by at most a = sigma * vmax * delta * dt and so the radiance by
    at most a * (albedo * in-scatter + what lies behind: background, image peak). The
    in-scatter is bounded by the phase function's maximum times each light's largest
    irradiance over the grid's box (a point light's at its distance from the box)."""
    eps = float(np.finfo(np.float32).eps)
    extent = max(float(np.abs(local_origin(b, cam)).max()), float(b.dims.max() * layout.BRICK))
    delta = 8 * eps * extent                               # voxels
    dt = s.step * b.voxel_size                             # world units
    vmax = float(b.majorant.max()) if b.n_slots else 0.0
    a = s.density_scale * vmax * delta * dt
    g1, g2, w = s.clamped_phase()
    hg_max = lambda g: (1 + abs(g)) / (4 * np.pi * (1 - abs(g)) ** 2)
    p_max = w * hg_max(g1) + (1 - w) * hg_max(g2)
    lo, hi = b.world_bounds()
    irradiance = 0.0
    for l in lights:
        if isinstance(l, Sun):
            irradiance += max(l.color) * l.irradiance
        else:
            r = np.linalg.norm(np.maximum(0.0, np.maximum(lo - l.position, l.position - hi)))
            irradiance += max(l.color) * l.intensity / max(r, 0.5 * b.voxel_size) ** 2
    scale = max(s.albedo) * p_max * irradiance + max(1.0, peak, max(s.background))
    return 4 * a * scale + 1e-7 * max(1.0, peak)


def tiled(s, tile=(8, 8)):
    return VolumeSettings(**{**s.__dict__, "dispatch": "tiled", "tile": tile})


def compare(dev, b, cam, s, lights=LIGHTS, tiles=((8, 8),), launch=None):
    """Render fragment and tiled (each tile size); assert they agree; return the images."""
    ref = render_volume(b, cam, lights, s, dev, launch=launch).rgba
    assert np.all(np.isfinite(ref))
    tol = tolerance(b, cam, s, lights, float(ref.max()))
    out = {}
    for tile in tiles:
        t = render_volume(b, cam, lights, tiled(s, tile), dev, launch=launch)
        assert t.flags["VR_TILED"] == 1 and t.flags["VR_TILE_W"] == tile[0]
        diff = float(np.abs(t.rgba - ref).max())
        assert diff <= tol, f"tile {tile}: max |diff| {diff:.3g} > {tol:.3g}"
        out[tile] = t.rgba
    return ref, out


def smooth_noise(shape, seed, lo=0.0):
    """Positive, smooth random density (sums of a few sines), floored at lo."""
    rng = np.random.default_rng(seed)
    i = np.indices(shape).astype(np.float64)
    v = np.zeros(shape)
    for _ in range(4):
        f = rng.uniform(0.1, 0.4, 3)
        v += np.sin(sum(f[a] * i[a] for a in range(3)) + rng.uniform(0, 6.3))
    return np.clip(0.25 * v + 0.5, lo, None).astype(np.float32)


def blob(n, radius):
    i = np.indices((n, n, n)).astype(np.float64) - (n - 1) / 2
    return np.clip(1.0 - np.sqrt((i ** 2).sum(0)) / radius, 0.0, None).astype(np.float32)


@pytest.fixture(scope="module")
def dense():
    """Every brick occupied: culling keeps everything the tile sees."""
    b = Bricks.from_dense(smooth_noise((32, 24, 28), 1, lo=0.05), scaled(VOX, (-1.6, -1.2, -1.4)))
    assert b.n_slots == np.prod(b.dims)
    return b


@pytest.fixture(scope="module")
def sparse():
    """Two objects 160 voxels apart (bench/volume.py's sparse_pair, smaller): a soft blob
    and a hard-edged block whose density reaches 0.8 within two voxels of the face of
    its first brick, so a sample lost at the entry into an occupied brick shows."""
    n = 16
    v = np.zeros((176, n, n), np.float32)
    v[:n] = blob(n, 7.5)
    v[161:175, 1:15, 1:15] = 0.8
    b = Bricks.from_dense(v, scaled(VOX, (-8.8, -0.8, -0.8)))
    assert b.n_slots <= 0.1 * np.prod(b.dims)
    return b


def test_dense_grid(cl_device, dense):
    cam = Camera((1.5, 1.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, 40, 32)
    ref, _ = compare(cl_device, dense, cam, VolumeSettings(density_scale=3.0))
    assert ref[..., 3].max() > 0.5


@pytest.mark.parametrize("view", ["end-on", "side"])
def test_sparse_grid(cl_device, sparse, view):
    if view == "end-on":    # down the long axis: rays cross ~20 empty bricks between blobs
        cam = Camera((-11.0, 0.1, 0.15), (8.0, 0.0, 0.0), (0.0, 1.0, 0.0), 12.0, 32, 24)
    else:
        cam = Camera((0.0, 2.0, 12.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 80.0, 48, 24)
    ref, _ = compare(cl_device, sparse, cam, VolumeSettings(density_scale=6.0))
    assert ref[..., 3].max() > 0.5


def test_camera_inside_the_grid(cl_device, dense, sparse):
    """The camera sits inside the box (and inside an occupied brick for the dense grid;
    in an empty stretch between the blobs for the sparse one), looking along an axis
    and obliquely: bricks around and behind the camera must not break culling."""
    s = VolumeSettings(density_scale=1.5)
    for target in ((1.0, 0.0, 0.0), (1.0, 0.7, 0.4)):
        ref, _ = compare(cl_device, dense, Camera((0.05, -0.02, 0.03), target, (0.0, 1.0, 0.0), 90.0, 24, 24),
                         s, tiles=((8, 8), (16, 4)))
        assert ref[..., 3].min() > 0.05
    ref, _ = compare(cl_device, sparse, Camera((0.0, 0.0, 0.0), (-8.0, 0.1, 0.0), (0.0, 1.0, 0.0), 60.0, 24, 24),
                     VolumeSettings(density_scale=6.0))
    assert ref[..., 3].max() > 0.5


@pytest.mark.parametrize("tile", [(1, 1), (8, 8), (16, 4)])
def test_tile_sizes_and_ragged_image(cl_device, sparse, tile):
    """37 x 23 is a multiple of no tile here but 1x1: edge work-items only help cull.
    Launched in bands of 8 rows, so the tiles of later bands start at y0 > 0."""
    cam = Camera((0.0, 1.5, 11.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 75.0, 37, 23)
    ref, _ = compare(cl_device, sparse, cam, VolumeSettings(density_scale=6.0), tiles=(tile,),
                     launch=Launch(first=37 * 8))
    assert ref[..., 3].max() > 0.3


def test_several_samples_per_pixel_and_depth(cl_device, sparse):
    """spp > 1 jitters inside the pixel, inside the tile's footprint; and the depth AOV."""
    cam = Camera((0.0, 1.5, 11.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 75.0, 24, 16)
    s = VolumeSettings(density_scale=6.0, spp=3, seed=5, aovs=("depth",))
    compare(cl_device, sparse, cam, s, tiles=((8, 8), (16, 4)))
    f = render_volume(sparse, cam, LIGHTS, s, cl_device).aovs["depth"]
    t = render_volume(sparse, cam, LIGHTS, tiled(s), cl_device).aovs["depth"]
    np.testing.assert_allclose(t, f, rtol=1e-6)


def test_list_overflow_falls_back_to_the_full_march(cl_device, sparse):
    """With a local list of 5 bricks, some tiles of this view overflow (they march the
    whole box) and some do not: the image is the same."""
    cam = Camera((0.0, 1.5, 11.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 75.0, 40, 24)
    counts = tile_lists(cl_device, sparse, cam, (8, 8), cap=1024)[0]
    assert (counts > 5).sum() >= 2 and ((counts > 0) & (counts <= 5)).sum() >= 1
    ref, _ = compare(cl_device, sparse, cam, VolumeSettings(density_scale=6.0),
                     launch=Launch(tile_cap=5))
    r = render_volume(sparse, cam, [], tiled(VolumeSettings()), cl_device,
                      launch=Launch(tile_cap=5))
    assert r.flags["VR_TILE_CAP"] == 5


def test_plain_marching_with_tiled_launch(cl_device, sparse):
    """--no-skip is the reference: tiled launches it unculled, same image."""
    cam = Camera((0.0, 1.5, 11.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 75.0, 24, 16)
    compare(cl_device, sparse, cam, VolumeSettings(density_scale=6.0, skip_empty=False))


def test_real_file(cl_device, shared_data):
    """dragon_with_xform.vdb: a rotated, scaled grid (culling works in its local space)."""
    b = vdb.load_volume(shared_data / "vdb" / "dragon_with_xform.vdb")
    cam = camera_mod.frame_bounds(*b.world_bounds(), 48, 36)
    ref, _ = compare(cl_device, b, cam, VolumeSettings(), lights=[Sun((-0.6, -1.0, -0.5), 6.0)],
                     tiles=((8, 8), (16, 4)))
    assert ref[..., 3].max() > 0.5


def test_settings_validate_the_dispatch():
    with pytest.raises(UserError, match="dispatch= must be one of"):
        VolumeSettings(dispatch="compute")
    with pytest.raises(UserError, match="out of range"):
        VolumeSettings(dispatch="tiled", tile=(0, 8))
    with pytest.raises(UserError, match="out of range"):
        VolumeSettings(dispatch="tiled", tile=(64, 32))
    assert VolumeSettings().dispatch == "auto"


def test_auto_dispatch_is_fragment(cl_device):
    """auto: fragment (in 8x8 blocks), the measured winner on PoCL and the H200; explicit
    kinds pass through."""
    from volrender.dispatch import Dispatch
    assert Dispatch("auto", (4, 2)).resolve(cl_device) == Dispatch("fragment", (4, 2))
    assert Dispatch("tiled").resolve(cl_device).kind == "tiled"
    assert Dispatch("fragment").resolve(cl_device).kind == "fragment"


def test_fragment_compiles_no_local_memory(cl_device, dense):
    """The fragment program has no __local list; the tiled one has it, sized by the cap."""
    cam = Camera((1.5, 1.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, 8, 8)
    info = cl.kernel_work_group_info.LOCAL_MEM_SIZE
    mem = {}
    for kind in ("fragment", "tiled"):
        flags = render_volume(dense, cam, [], VolumeSettings(dispatch=kind), cl_device).flags
        mem[kind] = cl_device.kernel("render_volume", flags).get_work_group_info(info, cl_device.device)
    assert mem["fragment"] < 64           # NVIDIA's driver reports a byte or so for none
    assert mem["tiled"] >= 16 * features.VOLUME_TILE_CAP


# ----------------------------------------------------------------- the culling itself

def crossed_bricks(b, cam, x0, x1, y0, y1, n=6, samples=4000):
    """Occupied bricks that rays through the pixel rectangle [x0, x1] x [y0, y1] cross
    (an n x n grid of rays incl. the edges, each sampled densely), local coordinates."""
    w2l = np.linalg.inv(np.asarray(b.local_to_world, np.float64))
    p00, du, dv = cam.pixel_vectors()
    xs, ys = np.meshgrid(np.linspace(x0, x1, n), np.linspace(y0, y1, n))
    d = p00 + xs.reshape(-1, 1) * du + ys.reshape(-1, 1) * dv
    d = d @ w2l[:3, :3].T
    o = local_origin(b, cam)
    t = np.linspace(0.0, 2.0 * np.linalg.norm(b.dims * 8.0) + np.linalg.norm(o), samples)
    p = o + t[None, :, None] * (d / np.linalg.norm(d, axis=1, keepdims=True))[:, None, :]
    c = np.floor(p.reshape(-1, 3) / 8).astype(np.int64)
    ok = np.all((c >= 0) & (c < b.dims), axis=1)
    c = np.unique(c[ok], axis=0)
    slot = b.table[(c[:, 0] * b.dims[1] + c[:, 1]) * b.dims[2] + c[:, 2]]
    return {tuple(v) for v in c[slot >= 0]}


@pytest.mark.parametrize("case", ["sparse", "inside", "dragon"])
def test_culling_is_conservative_and_culls(cl_device, sparse, shared_data, case):
    """Every occupied brick the tile's rays cross is in the tile's list (pad 0: the
    frustum test alone), and the lists are much shorter than the occupied set."""
    if case == "dragon":
        b = vdb.load_volume(shared_data / "vdb" / "dragon_with_xform.vdb")
        cam = camera_mod.frame_bounds(*b.world_bounds(), 48, 40)
    else:
        b = sparse
        cam = (Camera((0.0, 2.0, 12.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 80.0, 48, 24)
               if case == "sparse" else
               Camera((-8.3, 0.0, 0.0), (8.0, 0.3, 0.1), (0.0, 1.0, 0.0), 50.0, 32, 32))
    tile = (16, 8)
    counts, lists, n_occ = tile_lists(cl_device, b, cam, tile, cap=1024)
    assert counts.max() <= 1024
    assert counts.mean() < 0.5 * n_occ
    for ty in range(counts.shape[0]):
        for tx in range(counts.shape[1]):
            x0, y0 = tx * tile[0], ty * tile[1]
            x1, y1 = min(x0 + tile[0], cam.width), min(y0 + tile[1], cam.height)
            kept = {tuple((v[:3] / 8).round().astype(int)) for v in lists[ty, tx, :counts[ty, tx]]}
            missing = crossed_bricks(b, cam, x0, x1, y0, y1) - kept
            assert not missing, f"tile {(tx, ty)} lost bricks {sorted(missing)[:5]}"


def test_tolerance_is_tight_enough_to_see_one_lost_sample(cl_device, sparse):
    """One sample lost in the hard-edged block changes alpha by far more than
    `tolerance`: the comparisons above would see it (they do, for a kernel that starts
    its march two samples late)."""
    cam = Camera((-11.0, 0.1, 0.15), (8.0, 0.0, 0.0), (0.0, 1.0, 0.0), 12.0, 32, 24)
    s = VolumeSettings(density_scale=6.0)
    ref = render_volume(sparse, cam, LIGHTS, s, cl_device).rgba
    tol = tolerance(sparse, cam, s, LIGHTS, float(ref.max()))
    # opacity of one sample on the block's plateau (density 0.8)
    one_sample = 1.0 - np.exp(-s.density_scale * 0.8 * s.step * sparse.voxel_size)
    assert tol < 0.01 * one_sample


def test_skipping_runs_or_single_bricks_gives_the_plain_image(cl_device, sparse):
    """Skipping crosses empty bricks one by one (GPUs) or a whole run at once (CPUs): the
    samples it leaves out read exactly zero, so both equal plain marching, bit for bit,
    in the primary march and the shadow rays (the sun crosses the gap between the objects)."""
    cam = camera_mod.frame_bounds(*sparse.world_bounds(), 40, 24)
    lights = [Sun((1.0, -0.2, 0.1), 4.0)]
    base = VolumeSettings(density_scale=6.0, spp=2, seed=3)
    plain = render_volume(sparse, cam, lights, replace(base, skip_empty=False), cl_device)
    for runs in (True, False):
        r = render_volume(sparse, cam, lights, replace(base, skip_runs=runs), cl_device)
        assert r.flags["VR_SKIP_RUNS"] == int(runs)
        np.testing.assert_array_equal(r.rgba, plain.rgba)
    assert plain.rgba[..., 3].max() > 0.5
