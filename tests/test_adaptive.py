"""Adaptive passes on the content (issue 34): the noise estimate behind --noise-target covers
the pixels the volume covers, so a small object in a large sky is rendered until it is
clean; the samples reported are the samples taken; --time-limit holds from the first pass;
an unreachable target stops at --max-spp and says so."""
import numpy as np

from volrender import volume
from volrender.render import render


def small_blob(n=16):
    i = (np.indices((n, n, n)) - (n - 1) / 2) / (n / 2)
    return np.exp(-(i ** 2).sum(0) / 0.15).astype(np.float32)


SKY = dict(env=(0.6, 0.7, 0.9), estimator="path", max_depth=4, density_scale=4.0,
           size=(48, 40), fill=0.5)


def test_a_small_object_in_a_large_sky_is_rendered_until_it_is_clean(cl_device):
    """The blob covers ~5% of the image; the sky is noiseless. The whole-image estimate
    (the sky diluting it) met the target passes before the covered pixels' did, and the
    render went on to the covered target; the reported spp are the samples the launches
    took; the estimate reads as the true relative error (against a 2048-spp reference,
    within 1.5x the target and at least a third of it)."""
    target = 0.08
    img = render(small_blob(), cl_device, spp=2, noise_target=target, **SKY)
    info = img.info
    covered = img.rgba[..., 3] > volume.COVERED_ALPHA
    assert 0.01 < covered.mean() < 0.15
    assert info.stopped.startswith("noise") and info.noise <= target
    whole_met = [n for n, _, whole in info.history[volume.ADAPTIVE_MIN_PASSES - 2:]
                 if whole <= target]
    assert whole_met and whole_met[0] < info.spp / 2, info.history
    assert info.spp == info.samples_taken == info.history[-1][0]
    ref = render(small_blob(), cl_device, spp=2048, seed=99, **SKY)
    m = ref.rgba[..., 3] > volume.COVERED_ALPHA
    true = np.sqrt(((img.rgba - ref.rgba)[..., :3][m] ** 2).mean()) / np.sqrt(
        (ref.rgba[..., :3][m] ** 2).mean())
    assert target / 3 < true < 1.5 * target, (true, info.noise)


def test_the_time_limit_holds_when_one_pass_of_spp_would_overrun_it(cl_device):
    """--spp 1024 takes longer than the 0.6 s limit on PoCL (about 3 s); the passes start
    at one sample per pixel and fit the rest, so the render stops within the limit (plus a
    launch's length)."""
    kw = dict(SKY, size=(64, 48), fill=1.0)
    img = render(small_blob(), cl_device, spp=1024, time_limit=0.6, **kw)
    assert img.info.stopped.startswith("time limit"), img.info.stopped
    assert img.wall_ms < 600 + 400, img.wall_ms
    assert img.info.spp >= 1 and img.info.spp == img.info.samples_taken


def test_an_unreachable_target_stops_at_the_cap_and_says_what_it_reached(cl_device):
    img = render(small_blob(), cl_device, spp=2, noise_target=1e-4, max_spp=16, **SKY)
    assert img.info.spp == img.info.samples_taken == 16
    assert "the cap of 16 spp (--max-spp) before the target" in img.info.stopped
    assert f"{img.info.noise:.3g}" in img.info.adaptive


def test_the_status_line_reports_the_samples_taken(cl_device):
    from volrender.commands import describe
    from volrender.scene import load_scene
    scene = load_scene(small_blob(), spp=2, noise_target=1e-4, max_spp=12, **SKY)
    img = render(scene, cl_device)
    assert describe(scene, img) == "12 spp"
