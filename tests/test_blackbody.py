"""Blackbody colours (volrender/blackbody.py) against tabulated CIE values, the kernel's
table lookup, and the temperature grid colouring emission voxel by voxel."""
import numpy as np
import pyopencl as cl
import pytest

from volrender import blackbody as bb, vdb
from volrender.camera import Camera
from volrender.volume import VolumeSettings
from volrender.bricks import Bricks, load_npz
from helpers import render_volume

# Planckian locus (CIE 1931 x, y), as tabulated (c2 = 1.4388e-2 m K)
LOCUS = {1000: (0.6528, 0.3444), 1500: (0.5857, 0.3931), 2000: (0.5267, 0.4133),
         2500: (0.4770, 0.4137), 3000: (0.4369, 0.4041), 4000: (0.3805, 0.3768),
         5000: (0.3451, 0.3516), 6000: (0.3221, 0.3318), 6500: (0.3135, 0.3236),
         8000: (0.2952, 0.3048), 10000: (0.2807, 0.2884)}


def kim_locus(t):
    """Kim et al. (2002) cubic-spline fit of the Planckian locus, 1667-25000 K."""
    x = (-0.2661239e9 / t ** 3 - 0.2343589e6 / t ** 2 + 0.8776956e3 / t + 0.179910 if t < 4000
         else -3.0258469e9 / t ** 3 + 2.1070379e6 / t ** 2 + 0.2226347e3 / t + 0.240390)
    if t < 2222:
        y = -1.1063814 * x ** 3 - 1.34811020 * x ** 2 + 2.18555832 * x - 0.20219683
    elif t < 4000:
        y = -0.9549476 * x ** 3 - 1.37418593 * x ** 2 + 2.09137015 * x - 0.16748867
    else:
        y = 3.0817580 * x ** 3 - 5.87338670 * x ** 2 + 3.75112997 * x - 0.37001483
    return np.array([x, y])


def test_cie_table_is_the_standard_observer():
    """The three columns integrate to the CIE's 106.857 (5 nm sums), and every entry lies
    within the published analytic fit's accuracy (a typo in the table would not)."""
    cmf = bb.CIE_1931_5NM
    assert cmf.shape == (81, 4) and cmf[0, 0] == 380 and cmf[-1, 0] == 780
    np.testing.assert_allclose(cmf[:, 1:].sum(axis=0) * 5.0, 106.857, atol=2e-3)
    assert np.abs(cmf[:, 1:] - bb.cmf_fit(cmf[:, 0])).max() < 0.03
    assert cmf[np.argmax(cmf[:, 3]), 0] == 445 and cmf[np.argmax(cmf[:, 2]), 0] == 555


@pytest.mark.parametrize("kelvin", sorted(LOCUS))
def test_chromaticity_is_on_the_planckian_locus(kelvin):
    np.testing.assert_allclose(bb.chromaticity(kelvin), LOCUS[kelvin], atol=3e-4)


def test_chromaticity_follows_kims_fit_up_to_12000_k():
    for t in np.geomspace(1700, 12000, 25):
        np.testing.assert_allclose(bb.chromaticity(t), kim_locus(t), atol=1.5e-3)


def rgb_of_xy(x, y):
    """Linear Rec.709 of chromaticity (x, y), white-balanced like blackbody.rgb."""
    xyz = np.array([x / y, 1.0, (1 - x - y) / y])
    v = np.clip(bb.XYZ_TO_REC709 @ xyz / bb.linear_rec709(6500.0), 0, None)
    return v / v.max()


def test_rgb_matches_the_tabulated_locus_and_is_white_at_6500k():
    np.testing.assert_array_equal(bb.rgb(6500.0), [1.0, 1.0, 1.0])
    for t, (x, y) in LOCUS.items():
        np.testing.assert_allclose(bb.rgb(t), rgb_of_xy(x, y), atol=2e-3, err_msg=f"{t} K")
    # the numbers: 1500 K is about (1, 0.13, 0) (0.14 once white-balanced)
    np.testing.assert_allclose(bb.rgb(1500.0), [1.0, 0.141, 0.0], atol=2e-3)
    # from red through white to blue, monotonically
    t = np.geomspace(bb.T_MIN, bb.T_MAX, 200)
    c = bb.rgb(t)
    g, b = c[:, 1] / c[:, 0], c[:, 2] / c[:, 0]
    assert np.all(np.diff(g) >= 0) and np.all(np.diff(b) >= 0) and g[-1] > g[0] and b[-1] > b[0]
    assert c[0, 0] == 1.0 and c[0, 2] == 0.0 and c[-1, 2] == 1.0 and c[-1, 0] < 0.6


SRC = """
#include "common.h"
#include "structs.h"
#include "volume.h"
__kernel void probe(__constant VolumeParams* vp, __global const float4* bb,
                    __global const float* kelvin, __global float4* out)
{
    int i = get_global_id(0);
    out[i] = (float4)(vr_blackbody(bb, vp, kelvin[i]), 0.0f);
}
"""


def test_kernel_lookup_equals_the_table_oracle(cl_device):
    from volrender.dispatch import upload
    from volrender.volume import volume_params
    b = Bricks.from_dense(np.ones((2, 2, 2), np.float32))
    params, _ = volume_params(b)
    t = np.concatenate([[1.0, 300.0, 799.0, 800.0, 6500.0, 12000.0, 5e4],
                        np.geomspace(800, 12000, 500)]).astype(np.float32)
    tab = bb.table()
    prg = cl_device.build(SRC, {}, "blackbody probe")
    out = np.empty((len(t), 4), np.float32)
    d_out = cl.Buffer(cl_device.context, cl.mem_flags.WRITE_ONLY, out.nbytes)
    cl.Kernel(prg, "probe")(cl_device.queue, (len(t),), None, upload(cl_device.context, params),
                            upload(cl_device.context, tab), upload(cl_device.context, t), d_out)
    cl.enqueue_copy(cl_device.queue, out, d_out)
    np.testing.assert_allclose(out[:, :3], bb.lookup(t.astype(np.float64), tab), atol=2e-5)
    assert np.abs(bb.lookup(np.geomspace(800, 12000, 5000)) - bb.rgb(np.geomspace(800, 12000, 5000))).max() < 3e-3


def two_temperatures():
    """Emission 1 in a slab; its left half at 1200 K, its right half at 4000 K (as grid
    values 0.12 and 0.4 with scale 1e4: a mapping the renderer must apply)."""
    v = np.zeros((24, 24, 24), np.float32)
    v[2:22, 2:22, 10:14] = 1.0
    temp = np.where(np.arange(24)[:, None, None] < 12, 0.12, 0.4) * np.ones_like(v)
    m = np.eye(4)
    m[:3, :3] *= 0.1
    m[:3, 3] = -1.15
    return Bricks.from_dense(v, m, emission=v, temperature=temp.astype(np.float32))


@pytest.mark.parametrize("estimator", ["march", "path"])
def test_temperature_grid_colours_each_voxel(cl_device, estimator):
    """Pure emission (density 0): every pixel's colour is the blackbody colour of the
    voxels it sees, times emission_scale x the chord: left 1200 K, right 4000 K."""
    b = two_temperatures()
    cam = Camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 12.0, 16, 16)
    s = VolumeSettings(density_scale=0.0, emission_grid="emission", temperature_grid="temperature",
                       temperature_scale=1e4, emission_scale=2.0, estimator=estimator,
                       spp=1 if estimator == "march" else 256, emission_law="colour")
    img = render_volume(b, cam, [], s, cl_device).rgba[..., :3].astype(np.float64)
    left, right = img[6:10, 2:6].reshape(-1, 3), img[6:10, 10:14].reshape(-1, 3)
    for block, kelvin in ((left, 1200.0), (right, 4000.0)):
        colour = block / block.max(axis=1, keepdims=True)
        np.testing.assert_allclose(colour, np.broadcast_to(bb.lookup(kelvin), colour.shape),
                                   atol=0.02 if estimator == "path" else 2e-4)
        # intensity: emission_scale x chord (0.4 world units through the slab, ~normal);
        # the path estimator counts emitting points (noise ~3% per pixel at 256 spp)
        peak = block.max(axis=1)
        np.testing.assert_allclose(peak, 2.0 * 0.4, rtol=0.03 if estimator == "march" else 0.2)
        assert abs(peak.mean() / 0.8 - 1) < 0.03


def test_temperature_grid_round_trips_through_npz(tmp_path):
    b = two_temperatures()
    b.save_npz(tmp_path / "fire.npz")
    c = load_npz(tmp_path / "fire.npz")
    np.testing.assert_array_equal(c.temperature, b.temperature)
    assert c.temperature_grid_name == "temperature"
    with np.load(tmp_path / "fire.npz") as z:
        assert int(z["version"]) == 2             # older readers refuse it, not ignore it
    plain = Bricks.from_dense(np.ones((3, 3, 3), np.float32))
    plain.save_npz(tmp_path / "plain.npz")
    with np.load(tmp_path / "plain.npz") as z:
        assert int(z["version"]) == 1             # unchanged for everything else


def test_temperature_grid_needs_an_emission_grid():
    from volrender.errors import UserError
    with pytest.raises(UserError, match="emission_grid="):
        VolumeSettings(temperature_grid="temperature")


def test_blender_fire_shows_more_than_one_hue(cl_device, shared_data):
    """The Blender fire file, coloured by its own temperature grid (Blender's 0..1 =
    0..1000 K: --temperature-scale 1000; the flame sits at 400..3000 K): its hues span
    red to orange-yellow, where one --emission-temperature gives one hue."""
    path = shared_data / "vdb" / "fluid_data_0056.vdb"
    b = vdb.load_volume(path, emission_grid="flame", temperature_grid="temperature")
    from volrender.camera import frame_bounds
    cam = frame_bounds(*b.world_bounds(), 40, 30)
    s = VolumeSettings(density_scale=200.0, emission_grid="flame", temperature_grid="temperature",
                       temperature_scale=1000.0, emission_scale=20.0)
    img = render_volume(b, cam, [], s, cl_device).rgba[..., :3].astype(np.float64)
    lit = img.max(axis=2) > 0.05 * img.max()
    g_over_r = (img[..., 1] / np.maximum(img[..., 0], 1e-12))[lit]
    assert lit.sum() > 30
    lo, hi = np.percentile(g_over_r, [5, 95])
    assert hi - lo > 0.1, (lo, hi)            # e.g. 1700 K (0.21) to 2500 K (0.39)
    one = render_volume(b, cam, [], VolumeSettings(density_scale=200.0, emission_grid="flame",
                                                   emission_scale=20.0), cl_device).rgba
    hue = (one[..., 1] / np.maximum(one[..., 0], 1e-12))[lit]
    assert np.ptp(hue) < 1e-3                       # one blackbody colour without it


@pytest.mark.parametrize("estimator", ["march", "path"])
def test_blackbody_law_brightness_rises_as_t4(cl_device, estimator):
    """The intensity law (the default with a temperature grid): each pixel is
    emission_scale x chord x INTENSITY_K T^4 x the colour of luminance 1 (its numpy
    oracle, blackbody.lookup_radiance), so 4000 K is (4000/1200)^4 x brighter in
    luminance than 1200 K."""
    b = two_temperatures()
    cam = Camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 12.0, 16, 16)
    s = VolumeSettings(density_scale=0.0, emission_grid="emission", temperature_grid="temperature",
                       temperature_scale=1e4, emission_scale=2.0, estimator=estimator,
                       spp=1 if estimator == "march" else 256)
    assert s.blackbody_law
    img = render_volume(b, cam, [], s, cl_device).rgba[..., :3].astype(np.float64)
    lum = {}
    for (rows, cols), kelvin in (((slice(6, 10), slice(2, 6)), 1200.0),
                                 ((slice(6, 10), slice(10, 14)), 4000.0)):
        block = img[rows, cols].reshape(-1, 3)
        want = 2.0 * 0.4 * bb.lookup_radiance(kelvin)
        np.testing.assert_allclose(block.mean(axis=0), want,
                                   rtol=0.03 if estimator == "march" else 0.1)
        lum[kelvin] = float((block @ bb.REC709_Y).mean())
        np.testing.assert_allclose(want @ bb.REC709_Y, 0.8 * bb.INTENSITY_K * kelvin ** 4,
                                   rtol=1e-3)
    assert lum[4000.0] / lum[1200.0] == pytest.approx((4000 / 1200) ** 4,
                                                      rel=0.04 if estimator == "march" else 0.15)


def test_blackbody_law_oracle():
    """blackbody.radiance: luminance INTENSITY_K T^4 (Blender's 1500 K -> 0.091, 3000 K ->
    1.46), hue from the colour table; the kernel's table oracle agrees within 0.3%; cold
    voxels fade as T^4 below the table."""
    for kelvin, y in ((1500.0, 0.0913), (3000.0, 1.461)):
        assert bb.radiance(kelvin) @ bb.REC709_Y == pytest.approx(y, rel=2e-3)
    t = np.array([500.0, 900.0, 1800.0, 2700.0, 6000.0, 11000.0])
    np.testing.assert_allclose(bb.lookup_radiance(t), bb.radiance(t), rtol=3e-3, atol=1e-12)
    assert bb.radiance(400.0) @ bb.REC709_Y == pytest.approx(bb.INTENSITY_K * 400.0 ** 4, rel=1e-6)
