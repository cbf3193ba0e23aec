"""Multiple-scattering octaves in the marcher (cl/march.h): one octave is the single
scattering of commit b93f561 bit for bit (tests/refs, rendered there), more octaves
only add light, and the octave scales mean what they say."""
import json

import numpy as np
import pytest

from volrender import volume as volume_mod
from volrender.camera import frame_bounds
from volrender.errors import UserError
from volrender.lights import Sun
from volrender.volume import VolumeSettings
from conftest import ROOT
from helpers import render_volume

REFS = ROOT / "tests" / "refs"


def b93f561_blackbody(kelvin):
    """The emission colour b93f561 used (Planck at three wavelengths), so its emitting
    reference scenes stay comparable after the CIE colours replaced it."""
    lam = np.array([610e-9, 550e-9, 465e-9])
    h, c, k = 6.62607015e-34, 2.99792458e8, 1.380649e-23
    spectral = 1.0 / (lam ** 5 * np.expm1(h * c / (lam * k * kelvin)))
    return spectral / spectral.max()


def test_one_octave_is_single_scattering_bit_for_bit(cl_device, monkeypatch):
    import sys
    sys.path.insert(0, str(REFS))
    import march_scenes
    meta = json.loads((REFS / "march_refs.json").read_text())
    monkeypatch.setattr(volume_mod, "emission_color",
                        lambda s: s.emission_scale * b93f561_blackbody(s.emission_temperature))
    same_device = cl_device.name == meta["device"]
    missing = []
    for name, b, cam, lights, kw in march_scenes.scenes():
        if b is None:
            missing.append(name)
            continue
        got = march_scenes.render(cl_device, name, b, cam, lights, kw, ms_octaves=1)
        for key, a in got.items():
            ref = np.load(REFS / f"march_{name}_{key}.npy")
            if same_device:
                np.testing.assert_array_equal(a, ref, err_msg=f"{name} {key}")
            else:        # another CPU or GPU: its own float rounding, nothing more
                np.testing.assert_allclose(a, ref, rtol=1e-4, atol=1e-6, err_msg=f"{name} {key}")
    if missing:          # the others were checked above
        pytest.skip(f"scene {', '.join(missing)} needs OpenVDB's Python binding (a .vdb file)")


@pytest.fixture(scope="module")
def demo():
    from volrender import vdb
    b = vdb.load_volume(ROOT / "scenes" / "demo_cloud.vdb")
    return b, frame_bounds(*b.world_bounds(), 32, 24, fov=28.0), [Sun((-0.6, -1.0, -0.5), 10.0)]


def test_more_octaves_never_darken(cl_device, demo):
    """A light's bands weigh G >= 1 and A_k <= A_k-1, so each adds light: any octave
    count is at least single scattering, pixel by pixel; alpha is unchanged."""
    b, cam, sun = demo
    one = render_volume(b, cam, sun, VolumeSettings(density_scale=6.0, ms_octaves=1, spp=2,
                                                    env=(0.1, 0.15, 0.3)), cl_device).rgba
    for n in (2, 3, 5):
        img = render_volume(b, cam, sun, VolumeSettings(density_scale=6.0, ms_octaves=n, spp=2,
                                                        env=(0.1, 0.15, 0.3)), cl_device).rgba
        assert np.all(img[..., :3] >= one[..., :3] * (1 - 1e-5) - 1e-7), n
        np.testing.assert_array_equal(img[..., 3], one[..., 3])
        assert img[..., :3].mean() > 1.05 * one[..., :3].mean()


def test_octave_scales_mean_what_they_say(cl_device, demo):
    """G = 0 without an environment: the bands add nothing (single scattering); D large
    enough that A_inf = 1, or albedo 0 (the bands' light scatters once more): no band
    either; C = 0: the bands share one phase, so the sum
    telescopes and every count gives the same image."""
    b, cam, sun = demo
    one = render_volume(b, cam, sun, VolumeSettings(density_scale=6.0, ms_octaves=1),
                        cl_device).rgba
    for scales in ((0.5, 0.0, 0.5), (100.0, 2.5, 0.2)):
        off = render_volume(b, cam, sun, VolumeSettings(density_scale=6.0, ms_octaves=4,
                                                        ms_octave_scales=scales),
                            cl_device).rgba
        np.testing.assert_allclose(off, one, rtol=1e-5, atol=1e-7, err_msg=str(scales))
    black = [render_volume(b, cam, sun, VolumeSettings(density_scale=6.0, ms_octaves=n, albedo=0.0,
                                                       env=(0.1, 0.15, 0.3)), cl_device).rgba
             for n in (1, 4)]
    np.testing.assert_allclose(black[1], black[0], rtol=1e-5, atol=1e-7)
    imgs = [render_volume(b, cam, sun, VolumeSettings(density_scale=6.0, ms_octaves=n,
                                                      ms_octave_scales=(0.5, 2.0, 0.0)),
                          cl_device).rgba for n in (2, 3, 7)]
    for img in imgs[1:]:
        np.testing.assert_allclose(img, imgs[0], rtol=2e-4, atol=1e-6)
    assert imgs[0][..., :3].mean() > 1.2 * one[..., :3].mean()


def test_octave_settings_are_checked():
    with pytest.raises(UserError, match="ms_octaves="):
        VolumeSettings(ms_octaves=0)
    with pytest.raises(UserError, match="ms_octave_scales="):
        VolumeSettings(ms_octave_scales=(0.5, 150.0, 0.5))
    assert volume_mod.octave_tau_stop(VolumeSettings()) == 25.0
    # every band's light is below 1e-4 of the light's past the stop: exp(-A_inf tau) < 1e-4
    s = VolumeSettings(ms_octaves=4, ms_octave_scales=(0.5, 2.0, 0.5), albedo=0.8)
    stop = volume_mod.octave_tau_stop(s)
    a_inf = float(volume_mod.octave_decay(s).min())
    assert 0 < a_inf < 1 and np.exp(-a_inf * stop) <= 1.0001e-4
    # A_inf: diffusion theory's decay, 0 at albedo 1, 1 (no bands) where absorption dominates
    g = volume_mod.mean_cosine(s)
    assert a_inf == pytest.approx(0.5 * np.sqrt(3 * 0.2 * (1 - g)))
    assert volume_mod.octave_decay(VolumeSettings(albedo=1.0)).max() == 0.0
    assert volume_mod.octave_tau_stop(VolumeSettings(albedo=1.0, ms_octaves=2)) == 1e30
    assert volume_mod.octave_decay(VolumeSettings(albedo=0.1, ms_octave_scales=(1, 1, 1))).min() == 1.0
