"""The path estimator (cl/path_volume.cl): the white furnace, depth 1 against the
march's single scattering, more depth never darker, per-channel media channel by
channel, and the launch independence of its random numbers.

Statistics as in test_tracking.py: standard errors from independent batches (seeds),
bounds at 5 of them (the seeds are fixed: a pass or a failure is reproducible)."""
import numpy as np
import pytest

from volrender import cli
from volrender.camera import Camera
from volrender.lights import PointLight, Sun
from volrender.volume import VolumeSettings
from conftest import ROOT
from helpers import ENV, lumpy_ball, render_volume

Z = 5.0


def batches(b, cam, lights, n, **kw):
    imgs = np.stack([render_volume(b, cam, lights, VolumeSettings(**kw, seed=1000 + k),
                                   DEV[0]).rgba for k in range(n)])
    imgs = imgs.astype(np.float64)
    return imgs.mean(0), imgs.std(0, ddof=1) / np.sqrt(n)


DEV = []


@pytest.fixture(autouse=True)
def _device(cl_device):
    DEV[:] = [cl_device]


@pytest.mark.parametrize("density", [1.0, 12.0])
def test_white_furnace(density):
    """Albedo 1, no lights, inside a uniform environment of radiance L: every pixel is L
    (optical depth across the ball ~0.7 and ~8). With albedo 0.6 no pixel exceeds L."""
    b = lumpy_ball()
    cam = Camera((0.3, 0.2, 3.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 45.0, 16, 16)
    mean, se = batches(b, cam, [], 16, density_scale=density, albedo=1.0, env=ENV,
                       estimator="path", max_depth=100000, spp=16, phase=(0.5, -0.3, 0.7))
    alpha = mean[..., 3]
    assert alpha.max() > (0.9 if density > 5 else 0.3)
    rgb, se_rgb = mean[..., :3], se[..., :3]
    miss = alpha == 0
    assert miss.any() and np.allclose(rgb[miss], ENV, rtol=1e-6)      # no medium: L exactly
    z = (rgb - np.float32(ENV)) / np.maximum(se_rgb, 1e-9)
    assert np.all(np.abs(z[~miss]) < 6), np.abs(z).max()
    hit = ~miss
    for ch in range(3):
        d = (rgb[..., ch] - ENV[ch])[hit]
        assert abs(d.mean()) < Z * np.sqrt((se_rgb[..., ch][hit] ** 2).sum()) / hit.sum()
    grey, se_g = batches(b, cam, [], 6, density_scale=density, albedo=0.6, env=ENV,
                         estimator="path", max_depth=100000, spp=8)
    assert np.all(grey[..., :3] <= np.float32(ENV) + Z * se_g[..., :3] + 1e-6)
    lost = (np.float32(ENV) - grey[..., :3])[hit].mean(axis=0)      # absorbed: clearly darker
    assert np.all(lost > Z * np.sqrt((se_g[..., :3][hit] ** 2).sum(axis=0)) / hit.sum())


def test_more_depth_never_darkens():
    """Without an environment the first k vertices of a path draw the same random numbers
    whatever max_depth is, so each extra depth only adds light: per pixel, exactly."""
    b = lumpy_ball()
    cam = Camera((0.3, 0.2, 3.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 45.0, 16, 16)
    lights = [Sun((-0.5, -1.0, -0.3), 3.0), PointLight((0.8, 0.9, 0.5), 1.0)]
    prev = None
    for depth in (1, 2, 3, 5, 8, 64):
        img = render_volume(b, cam, lights, VolumeSettings(density_scale=8.0, albedo=0.95, spp=4,
                                                           estimator="path", max_depth=depth),
                            DEV[0]).rgba.astype(np.float64)
        if prev is not None:
            assert np.all(img[..., :3] >= prev[..., :3] * (1 - 1e-6)), depth
            np.testing.assert_array_equal(img[..., 3], prev[..., 3])
        prev = img
    assert prev[..., 0].mean() > 1.5 * render_volume(
        b, cam, lights, VolumeSettings(density_scale=8.0, albedo=0.95, spp=4, estimator="path",
                                       max_depth=1), DEV[0]).rgba[..., 0].mean()


def test_depth_one_is_the_marchs_single_scattering():
    """max_depth 1 with a sun and a uniform environment against the fine march (its
    environment light is one phase-sampled direction per step, so it is averaged over
    spp too): per pixel within 6 path standard errors plus the march's own step error
    and noise (the difference between two march steps bounds both)."""
    b = lumpy_ball(seed=7)
    cam = Camera((1.4, 0.8, 2.6), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 30.0, 12, 12)
    sun = [Sun((0.7, -0.5, 0.45), 2.0)]
    base = dict(density_scale=3.0, albedo=0.8, phase=(0.6, -0.3, 0.8), env=(0.2, 0.25, 0.4),
                background=(0.05, 0.0, 0.0))
    mean, se = batches(b, cam, sun, 16, **base, estimator="path", max_depth=1, spp=64)
    fine, coarse = (render_volume(b, cam, sun, VolumeSettings(**base, spp=32, seed=s, step=h,
                                                              shadow_step=h), DEV[0]).rgba
                    .astype(np.float64) for s, h in ((3, 0.1), (4, 0.2)))
    assert fine[..., 3].max() > 0.5
    allow = 6 * se + np.abs(coarse - fine) + 1e-6
    bad = np.abs(mean - fine) > allow
    assert not bad.any(), (np.abs(mean - fine) / allow)[bad]
    for ch in range(3):
        d = (mean - fine)[..., ch]
        assert abs(d.sum()) <= Z * np.sqrt((se[..., ch] ** 2).sum()) + np.abs(coarse - fine)[..., ch].sum()


def test_coloured_media_are_grey_media_channel_by_channel():
    """sigma_t scale s and albedo a per channel: channel c renders as a grey medium of
    density s_c and albedo a_c. The march: the same numbers, to rounding. The path
    estimator (spectral tracking, depth 6): within noise of the grey path renders."""
    b = lumpy_ball(seed=9)
    cam = Camera((0.3, 0.2, 3.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 45.0, 12, 12)
    sun = [Sun((-0.5, -1.0, -0.3), 3.0)]
    s_c, a_c = (0.5, 1.0, 2.0), (0.95, 0.8, 0.6)
    col = VolumeSettings(density_scale=4.0, sigma_t_scale=s_c, albedo=a_c, spp=2, seed=5,
                         env=(0.1, 0.1, 0.1))
    assert col.chromatic
    img = render_volume(b, cam, sun, col, DEV[0]).rgba
    for ch in range(3):
        grey = render_volume(b, cam, sun, VolumeSettings(density_scale=4.0 * s_c[ch], albedo=a_c[ch],
                                                         spp=2, seed=5, env=(0.1, 0.1, 0.1)),
                             DEV[0]).rgba
        np.testing.assert_allclose(img[..., ch], grey[..., ch], rtol=1e-4, atol=1e-6)
    path = dict(estimator="path", max_depth=6, spp=16, env=(0.1, 0.1, 0.1))
    mean, se = batches(b, cam, sun, 12, density_scale=4.0, sigma_t_scale=s_c, albedo=a_c, **path)
    for ch in range(3):
        g, gse = batches(b, cam, sun, 12, density_scale=4.0 * s_c[ch], albedo=a_c[ch], **path)
        d, e = mean[..., ch] - g[..., ch], np.sqrt(se[..., ch] ** 2 + gse[..., ch] ** 2)
        assert np.all(np.abs(d) < 6 * e + 1e-6), (ch, (np.abs(d) / (e + 1e-9)).max())
        assert abs(d.sum()) < Z * np.sqrt((e ** 2).sum())
    # alpha comes from the mean transmittance over the channels; GPU rounding dips a few 1e-8 below 0
    assert np.all(mean[..., 3] >= -1e-6) and mean[..., 3].max() > 0.5


def test_path_image_does_not_depend_on_the_launch():
    b = lumpy_ball()
    cam = Camera((0.3, 0.2, 3.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 45.0, 13, 7)
    base = dict(density_scale=6.0, spp=3, seed=2, estimator="path", max_depth=8,
                env=(0.2, 0.3, 0.4), aovs=("depth",))
    lights = [Sun((0.3, -1.0, 0.2), 2.0)]
    frag = render_volume(b, cam, lights, VolumeSettings(**base, dispatch="fragment"), DEV[0])
    tiled = render_volume(b, cam, lights, VolumeSettings(**base, dispatch="tiled", tile=(4, 4)),
                          DEV[0])
    np.testing.assert_array_equal(frag.rgba, tiled.rgba)
    np.testing.assert_array_equal(frag.aovs["depth"], tiled.aovs["depth"])


def test_cli_renders_a_sky_lit_cloud(tmp_path, capsys):
    out = tmp_path / "p.npy"
    code = cli.main(["render", str(ROOT / "scenes" / "demo_cloud.vdb"), "-o", str(out),
                     "--size", "24x18", "--no-progress", "--estimator", "path", "--spp", "2",
                     "--max-depth", "16", "--env", "0.3,0.4,0.7", "--albedo", "0.95,0.95,0.9"])
    assert code == 0, capsys.readouterr().err
    rgba = np.load(out)
    assert np.isfinite(rgba).all() and rgba[..., 3].max() > 0.1
    assert np.allclose(rgba[0, 0, :3], (0.3, 0.4, 0.7), rtol=1e-5)     # the sky behind
