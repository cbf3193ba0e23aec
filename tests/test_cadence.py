"""Launch cadence (issue 23): launches stay short where the cost changes down the image,
so the bar moves and a signal is answered within a few launches. The kernel's time is
faked (dispatch._enqueue) from a cost per pixel-sample by row: no timing asserts."""
import signal
import threading

import numpy as np
import pytest

from volrender import dispatch
from volrender.render import render

from helpers import CADENCE_H as H, cadence_scene as scene, fake_cost

SPP = 8


def cheap_then_dense(y):
    return 1e-8 if y < 40 else 2e-4       # empty rows above, then 0.05 s per row-sample


def test_cheap_band_does_not_make_one_launch_cover_the_image(cl_device, monkeypatch, log):
    """Rows 0..39 cost nothing, the rest 0.05 s per row-sample: no launch covers more
    than a few tile rows or runs past twice the target, and the image is still all
    there (every pixel-sample once)."""
    if dispatch.is_gpu(cl_device):
        pytest.skip("GPUs launch whole frames")
    fake_cost(monkeypatch, cheap_then_dense, log)
    img = render(scene(), cl_device)
    launches = log["launches"]
    assert sum(r * s for _, r, s, _ in launches) == H * SPP
    longest = max(t for *_, t in launches)
    assert longest <= 2 * dispatch.TARGET_S, launches
    assert max(r for _, r, _, _ in launches) <= H // 4, launches
    assert img.info.launches == len(launches)


def test_progress_moves_at_least_every_target(cl_device, monkeypatch, log):
    """The bar is updated after every launch; on the fake clock the gaps between its
    updates stay under 2 x TARGET_S (the bar moves several times a second)."""
    if dispatch.is_gpu(cl_device):
        pytest.skip("GPUs launch whole frames")
    fake_cost(monkeypatch, cheap_then_dense, log)
    stamps = []
    real = dispatch.Progress.update

    def update(self, n=1, rows=None, samples=None):
        stamps.append(log["clock"])
        return real(self, n, rows, samples)
    monkeypatch.setattr(dispatch.Progress, "update", update)
    render(scene(), cl_device)
    gaps = np.diff([0.0] + stamps)
    assert len(stamps) == len(log["launches"]) and gaps.max() <= 2 * dispatch.TARGET_S


def test_sigint_ends_a_render_within_one_launch(cl_device, monkeypatch, log):
    """A SIGINT raised during the third launch (from the fake kernel) ends the render
    with KeyboardInterrupt before the fourth: signals are answered between launches."""
    fake_cost(monkeypatch, cheap_then_dense, log)
    inner = dispatch._enqueue

    def enqueue(*a):
        out = inner(*a)
        if len(log["launches"]) == 3:
            signal.raise_signal(signal.SIGINT)
        return out
    monkeypatch.setattr(dispatch, "_enqueue", enqueue)
    assert threading.current_thread() is threading.main_thread()
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            render(scene(), cl_device)
    finally:
        signal.signal(signal.SIGINT, old)
    assert len(log["launches"]) == 3


def test_next_work_rules():
    """A cheap launch keeps the first size; a measured one aims at the target at the
    slowest rate seen, growing at most x GROW and shrinking at most x8."""
    t = dispatch.TARGET_S
    assert dispatch.next_work(1000, 1e-6, t, 0.0, 256) == 256
    assert dispatch.next_work(1000, t, t, 0.0, 256) == 1000
    assert dispatch.next_work(1000, t / 10, t, 0.0, 256) == 1000 * dispatch.GROW
    assert dispatch.next_work(1000, t * 100, t, 0.0, 256) == 125
    assert dispatch.next_work(1000, t / 2, t, 1e-3, 256) == 250      # the slowest rate wins
    assert dispatch.next_work(1000, 1e-6, t, 0.0, None) == 1000 * dispatch.GROW   # GPUs
