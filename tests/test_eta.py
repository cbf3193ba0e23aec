"""The progress bar's time left counts cost (issue 34): the rows of a cloud differ x5 and
more in cost, so a time left from the samples done is wrong by as much; volrender shows
'ETA ?' until every row still to render has a measured cost. The kernel's time is faked
(helpers.fake_cost): no timing asserts."""
import dataclasses

import numpy as np
import pytest

from volrender import dispatch
from volrender.progress import Eta, clock
from volrender.render import render
from volrender.volume import VolumeSettings
from helpers import CADENCE_H as H, cadence_scene as scene, fake_cost


def five_then_one(y):
    return 5e-5 if y < H // 2 else 1e-5      # the top half costs 5x the bottom's


def test_eta_is_unknown_until_every_row_left_has_a_cost_then_counts_cost():
    e = Eta(4, spp=2)
    e.add(0, 2, 2, seconds=2 * 2 * 5.0)      # rows 0-1 done at 5 s a sample
    assert e.left() is None                  # rows 2-3 unmeasured: no guess
    e.add(2, 2, 1, seconds=2 * 1 * 1.0)      # rows 2-3: one sample of two, 1 s each
    assert e.left() == pytest.approx(2.0)    # one sample left on 2 rows at 1 s
    p = Eta(4, spp=2, profile=[5.0, 5.0, 1.0, 1.0])
    assert p.left() == pytest.approx(2 * (5 + 5 + 1 + 1))
    assert clock(None) == "ETA ?" and clock(65.2) == "ETA 1:05" and clock(3725) == "ETA 1:02:05"


def test_the_bar_time_left_is_the_cost_left_not_the_samples_left(cl_device, monkeypatch, log):
    """Two passes (the second reads the first's row costs): in the first, the bar says
    'ETA ?' until the last rows are under way; in the second, from its first launch on,
    the time left is within 25% of the fake clock's (a boundary launch averages two costs),
    while a time left from the samples done is off by more than x2 at half the samples."""
    if dispatch.is_gpu(cl_device):
        pytest.skip("GPUs launch whole frames: every launch measures every row")
    fake_cost(monkeypatch, five_then_one, log)
    seen = []
    real = dispatch.Progress.set_eta

    def set_eta(self, seconds):
        seen.append((len(log["launches"]), seconds))
        return real(self, seconds)
    monkeypatch.setattr(dispatch.Progress, "set_eta", set_eta)
    s = scene()
    s = dataclasses.replace(s, content=dataclasses.replace(
        s.content, settings=VolumeSettings(spp=8, noise_target=1e-4, max_spp=16)))
    render(s, cl_device)
    launches = log["launches"]
    cut = next(i for i, (y0, *_rest) in enumerate(launches) if i and y0 == 0 and launches[i - 1][0] > 0)
    first, second = seen[:cut], seen[cut:]
    assert first[0][1] is None and sum(v is None for _, v in first) > len(first) / 2
    costs = np.array([t for *_, t in launches[cut:]])
    samples = np.array([r * k for _, r, k, _ in launches[cut:]], float)
    assert len(second) == len(costs) > 4
    half = None
    for i, (_, eta) in enumerate(second):
        truth = costs[i + 1:].sum()
        assert eta is not None
        assert eta == pytest.approx(truth, rel=0.25, abs=1e-6), (i, eta, truth)
        if half is None and samples[:i + 1].sum() >= samples.sum() / 2:
            half = i
    by_count = costs[:half + 1].sum() * (samples[half + 1:].sum() / samples[:half + 1].sum())
    assert by_count > 2 * costs[half + 1:].sum()
