"""Launches split by rows and by samples (volrender/dispatch.py): any split gives the
bit-identical image, for every kernel and its accumulators (rgba, depth, glass stats),
and the progress bar counts every pixel-sample."""
import numpy as np
import pytest

from helpers import glowing_ball
from volrender import dispatch, generators, glass
from volrender.dispatch import Launch
from volrender.camera import Camera
from volrender.lights import PointLight, Sun
from volrender.render import render
from volrender.scene import GlassContent, Scene, VolumeContent
from volrender.volume import VolumeSettings

# (rows, samples) per launch: every tile row and every sample its own launch; uneven
SPLITS = [(1, 1), (9, 2), (40, 3)]


def renders(cl_device, scene, variant=None):
    whole = render(scene, cl_device, variant=variant)
    out = []
    for split in SPLITS:
        out.append((split, render(scene, cl_device, variant=variant, launch=Launch(fixed=split))))
    return whole, out


@pytest.mark.parametrize("estimator", ["march", "track"])
@pytest.mark.parametrize("dispatch_kind", ["fragment", "tiled"])
def test_volume_splits_are_bit_identical(cl_device, estimator, dispatch_kind):
    if estimator == "track" and dispatch_kind == "tiled":
        pytest.skip("the tracker has one dispatch")
    cam = Camera((0.3, 0.4, 3.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, 21, 19)
    s = VolumeSettings(density_scale=3.0, spp=5, seed=4, estimator=estimator, emission_grid="emission",
                       aovs=("depth",), dispatch=dispatch_kind, tile=(4, 4), background=(0.1, 0.2, 0.3))
    scene = Scene(cam, (Sun((0.2, -1.0, -0.4), 2.0), PointLight((0.5, 0.5, 0.5), 1.0)),
                  VolumeContent(glowing_ball(), s))
    whole, split = renders(cl_device, scene)
    assert whole.rgba[..., 3].max() > 0.3
    for how, img in split:
        assert np.array_equal(img.rgba, whole.rgba), how
        assert np.array_equal(img.aovs["depth"], whole.aovs["depth"], equal_nan=True), how


@pytest.mark.parametrize("variant", [None, "uber", "stats"])
def test_glass_splits_are_bit_identical(cl_device, variant):
    cloud = generators.blob(120, seed=3)
    cam = glass.default_camera(cloud, 19, 17)
    s = glass.GlassSettings(spp=4, bounces=3)
    scene = Scene(cam, (Sun((0.3, -1.0, -0.2), 3.0),), GlassContent(cloud, s))
    whole, split = renders(cl_device, scene, variant)
    assert whole.rgba[..., 3].mean() > 0.1
    for how, img in split:
        assert np.array_equal(img.rgba, whole.rgba), (how, variant)


def test_progress_counts_every_sample(cl_device, monkeypatch, capsys):
    """The bar (forced on) ends at width x height x spp samples and all rows."""
    cam = Camera((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, 16, 24)
    scene = Scene(cam, (), VolumeContent(glowing_ball(), VolumeSettings(spp=3)))
    bars = []
    real = dispatch.Progress

    class Spy(real):
        def __init__(self, *a, **kw):
            super().__init__(*a, **kw, delay=0.0)
            bars.append(self)
    monkeypatch.setattr(dispatch, "Progress", Spy)
    render(scene, cl_device, progress=True, launch=Launch(fixed=(8, 2)))
    (bar,) = bars
    assert bar.bar.n == bar.bar.total == 16 * 24 * 3
    assert "rows 24/24" in capsys.readouterr().err


def test_launches_adapt_to_the_target(cl_device, monkeypatch):
    """With a tiny target every launch stays one tile row and one sample; with launches
    that take long enough to measure (a faked 0.1 s each) they grow, at most x GROW per
    launch, towards whole bands of every sample."""
    sizes = []
    real = dispatch.Progress.update

    def spy(self, samples, rows=None, s1=None):
        sizes.append(samples)
        return real(self, samples, rows, s1)
    monkeypatch.setattr(dispatch.Progress, "update", spy)
    cam = Camera((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, 16, 64)
    scene = Scene(cam, (), VolumeContent(glowing_ball(), VolumeSettings(spp=4)))
    gpu = dispatch.is_gpu(cl_device)          # GPUs launch whole frames, splitting samples
    render(scene, cl_device, launch=Launch(first=16 * 8, target_s=1e-9))
    assert sizes == ([16 * 64] * 4 if gpu else [16 * 8] * (8 * 4))
    sizes.clear()
    enqueue = dispatch._enqueue
    monkeypatch.setattr(dispatch, "_enqueue", lambda *a: (enqueue(*a)[0], 0.1))
    render(scene, cl_device, launch=Launch(first=16 * 8, target_s=1.0))
    assert sum(sizes) == 16 * 64 * 4 and (gpu or sizes[1] > sizes[0])
    assert all(b <= dispatch.GROW * a for a, b in zip(sizes, sizes[1:]))
