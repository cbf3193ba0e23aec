"""Fire that glows (issue 33): the exposure chosen from the emission's statistics
(volrender/fire.py), a hot core brighter and yellower than its edges, an all-zero flame
grid rendered as smoke, and grids named on the command line given the automatic path's
units. Synthetic fires (volrender.media.fire_ball) run everywhere; the Mantaflow files
where ../shared/data is."""
import dataclasses

import numpy as np
import pytest

from volrender import blackbody, fire, image, media, scene as scene_mod
from volrender.camera import Camera
from volrender.render import render
from volrender.scene import Scene, VolumeContent
from volrender.volume import VolumeSettings

FIRE = VolumeSettings(emission_grid="flame", temperature_grid="temperature",
                      temperature_scale=1000.0, env=(0.0,))
CAM = Camera((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 25.0, 24, 24)
REC709 = np.array([0.2126, 0.7152, 0.0722])


def dense_columns(n, hot, cold, axis):
    """The brute-force column luminance of media.fire_ball: the dense grids summed."""
    i = (np.indices((n, n, n)) + 0.5) / n - 0.5
    r = np.sqrt((i ** 2).sum(0)) / 0.4
    flame = (r < 1.0).astype(np.float32)
    t = np.where(r < 1.0, hot + (cold - hot) * r, 0.0).astype(np.float32)
    y = flame * blackbody.INTENSITY_K * (1000.0 * t.astype(np.float64)) ** 4
    return y.sum(axis) / n


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_column_luminance_is_the_dense_sum(axis):
    """fire.column_luminance over the bricks equals the dense grids' sum along the axis
    times the voxel size, column by column (the brick layout starts at b.origin and pads
    with zeros)."""
    b = media.fire_ball(20)
    col = fire.column_luminance(b, FIRE, axis)
    i, j = (-int(b.origin[a]) for a in range(3) if a != axis)
    full = np.zeros_like(col)
    full[i:i + 20, j:j + 20] = dense_columns(20, 3.0, 1.2, axis)
    np.testing.assert_allclose(col, full, rtol=1e-5, atol=1e-9)
    assert col.max() > 0


def test_exposure_follows_the_emission_not_a_fixed_scale():
    """The exposure brings the 99th-percentile column to EXPOSURE_TARGET: a flame grid 7x
    brighter gets 1/7 the scale (the exposed emission is the same), a hotter fire a smaller
    one, and the note says what was chosen."""
    b = media.fire_ball(20)
    scale, note = fire.exposure(b, FIRE)
    stat = min(np.percentile(c[c > 0], fire.EXPOSURE_PERCENTILE)
               for c in (dense_columns(20, 3.0, 1.2, a) for a in range(3)))
    assert scale == pytest.approx(fire.EXPOSURE_TARGET / stat, rel=1e-5)
    assert f"x{scale:.3g}" in note and "stops" in note
    bright = dataclasses.replace(b, emission=b.emission * 7.0, emission_max=b.emission_max * 7.0)
    assert fire.exposure(bright, FIRE)[0] == pytest.approx(scale / 7.0, rel=1e-5)
    hotter = media.fire_ball(20, hot=4.0)
    assert fire.exposure(hotter, FIRE)[0] < scale


def test_all_zero_emission_is_empty():
    b = media.fire_ball(20)
    assert not fire.is_empty(b)
    zero = dataclasses.replace(b, emission=b.emission * 0.0, emission_max=b.emission_max * 0.0)
    assert fire.is_empty(zero) and fire.exposure(zero, FIRE) == (None, None)


def test_synthetic_fire_core_is_brighter_and_yellower(cl_device):
    """The fire ball exposed by fire.exposure, no lights: the centre (3000 K) is brighter
    than the rim (1200-2000 K) and yellower (green over red), and the hottest pixels sit
    at the chosen exposure (luminance of order EXPOSURE_TARGET, not the raw 0.x)."""
    b = media.fire_ball(20)
    scale, _ = fire.exposure(b, FIRE)
    img = render(Scene.of(CAM, [], VolumeContent(b, dataclasses.replace(
        FIRE, emission_scale=scale))), cl_device).rgba[..., :3].astype(np.float64)
    lum = img @ REC709
    y, x = np.indices(lum.shape) + 0.5 - 12.0
    r = np.hypot(x, y) / 12.0
    core, rim = r < 0.25, (r > 0.55) & (lum > 0.01 * lum.max())
    assert rim.sum() >= 8
    assert lum[core].mean() > 3.0 * lum[rim].mean()
    gr = img[..., 1] / np.maximum(img[..., 0], 1e-12)
    assert gr[core].mean() > gr[rim].mean() + 0.1, (gr[core].mean(), gr[rim].mean())
    assert 0.5 * fire.EXPOSURE_TARGET < lum.max() < 4.0 * fire.EXPOSURE_TARGET


def test_0190_renders_as_smoke(shared_data):
    """fluid_data_0190's flame grid is all zeros: no emission, the normal sun and sky (not
    the fire's dusk), and a note saying so."""
    sc = scene_mod.load_scene(shared_data / "vdb" / "fluid_data_0190.vdb", size=(16, 12))
    assert sc.settings.emission_grid is None and sc.content.bricks.emission is None
    assert sc.lights[0].irradiance == pytest.approx(6.0)
    assert any("holds only zeros: rendered as smoke under the normal sky" in n for n in sc.notes)
    assert not any(n.startswith("fire: a Blender") for n in sc.notes)
    off = scene_mod.load_scene(shared_data / "vdb" / "fluid_data_0056.vdb", size=(16, 12),
                               emission_grid="none")      # a z-up cache, not a fire
    np.testing.assert_array_equal(sc.environment.texels, off.environment.texels)


def test_0056_core_is_brighter_and_yellower(shared_data, cl_device):
    """fluid_data_0056 at defaults (exposed, its own light only): the brightest tenth of
    the emitting pixels is far brighter than the dimmest quarter and yellower; the core
    reaches the tone curve's shoulder (luminance > 1), where the raw blackbody left the
    image at 0.4."""
    sc = scene_mod.load_scene(shared_data / "vdb" / "fluid_data_0056.vdb", size=(64, 48))
    assert any(n.startswith("fire exposure: emission x") for n in sc.notes)
    img = render(sc.replace(lights=(), environment=None), cl_device).rgba[..., :3]
    img = img.astype(np.float64)
    lum = img @ REC709
    lit = lum > 0.01 * lum.max()
    order = np.argsort(lum[lit])
    n = len(order)
    hot, dim = order[-n // 10:], order[: n // 4]
    assert lum[lit][hot].mean() > 5.0 * lum[lit][dim].mean()
    gr = img[..., 1][lit] / np.maximum(img[..., 0][lit], 1e-12)
    assert gr[hot].mean() > gr[dim].mean() + 0.05, (gr[hot].mean(), gr[dim].mean())
    assert np.percentile(lum[lit], 99) > 1.0
    # as displayed (the PNG's tone curve): a white-yellow core (green near red, blue well
    # above zero), orange-red edges
    disp = image.to_srgb(img).astype(np.float64)
    dgr = disp[..., 1][lit] / np.maximum(disp[..., 0][lit], 1e-12)
    dbr = disp[..., 2][lit] / np.maximum(disp[..., 0][lit], 1e-12)
    assert dgr[hot].mean() > 0.9 and dbr[hot].mean() > 0.5, (dgr[hot].mean(), dbr[hot].mean())
    assert dgr[dim].mean() < dgr[hot].mean() - 0.2


def test_named_grids_equal_the_automatic_path(shared_data, cl_device):
    """--emission-grid flame --temperature-grid temperature on the Mantaflow cache: the
    same settings (1000 K units, the exposure), lights and image as the automatic path."""
    path = shared_data / "vdb" / "fluid_data_0056.vdb"
    auto = scene_mod.load_scene(path, size=(16, 12))
    named = scene_mod.load_scene(path, size=(16, 12), emission_grid="flame",
                                 temperature_grid="temperature")
    assert named.settings == auto.settings and named.lights == auto.lights
    a, b = (render(s, cl_device).rgba for s in (auto, named))
    np.testing.assert_array_equal(a, b)
    kelvin = scene_mod.load_scene(path, size=(16, 12), emission_grid="flame",
                                  temperature_grid="temperature", temperature_scale=1.0)
    assert kelvin.settings.temperature_scale == 1.0          # given: kept


def test_a_fire_sequence_gets_one_exposure(shared_data, tmp_path):
    """A sequence of Mantaflow fire frames: the middle frame's exposure for every frame (no
    pumping brightness), said in a note; --emission-scale given: none chosen."""
    from volrender import sequence
    src = shared_data / "vdb" / "fluid_data_0056.vdb"
    paths = {}
    for k in (1, 2, 3):
        (tmp_path / f"fire_{k:04d}.vdb").symlink_to(src)
        paths[k] = str(tmp_path / f"fire_{k:04d}.vdb")
    _, bad, extra, notes = sequence.sequence_camera(paths, {"size": (16, 12)})
    want = scene_mod.load_scene(src, size=(16, 12)).settings.emission_scale
    assert not bad and extra["emission_scale"] == pytest.approx(want)
    assert any("for every frame (from frame 2" in n for n in notes)
    _, _, extra, notes = sequence.sequence_camera(paths, {"size": (16, 12), "emission_scale": 3.0})
    assert "emission_scale" not in extra and not any("fire exposure" in n for n in notes)


def test_a_sequence_gets_one_estimator(shared_data, tmp_path):
    """auto's choice from the middle frame for every frame (it could flip between the march
    and the path estimator as the medium changes), said; --estimator given: kept."""
    from volrender import sequence
    src = shared_data / "vdb" / "wdas_cloud_sixteenth.vdb"
    paths = {}
    for k in (1, 2):
        (tmp_path / f"c_{k:04d}.vdb").symlink_to(src)
        paths[k] = str(tmp_path / f"c_{k:04d}.vdb")
    for size, want in (((640, 480), ("march", "ms_octaves")), ((32, 24), ("path", "spp"))):
        _, _, extra, notes = sequence.sequence_camera(paths, {"size": size})
        assert extra["estimator"] == want[0] and want[1] in extra, extra
        assert any(n.startswith(f"estimator auto for every frame: {want[0]}") for n in notes)
    _, _, extra, notes = sequence.sequence_camera(paths, {"size": (32, 24), "estimator": "march"})
    assert "estimator" not in extra and not notes
