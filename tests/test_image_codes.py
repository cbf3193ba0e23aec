"""8-bit PNG codes through quantise tables (issue 35): equal to image._codes, the float64
definition of to_srgb, for every float32 value, and on real renders."""
import os
import warnings

import numpy as np
import pytest

from volrender import image, quantise

VIEWS = ("filmic", "clamp", "standard", "aces")


def _all_kinds_of_float32(n, seed=3):
    """n float32 values from uniform random bit patterns (every sign, exponent, subnormal,
    NaN and Inf turns up) plus the special values."""
    bits = np.random.default_rng(seed).integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32)
    x = bits.view(np.float32)
    x[:8] = [0.0, -0.0, np.inf, -np.inf, np.nan, 1.0, 0.5, np.finfo(np.float32).max]
    return x


@pytest.mark.parametrize("view", VIEWS)
def test_fast_codes_equal_the_definition_for_any_float32(view):
    x = _all_kinds_of_float32(300_000).reshape(-1, 3)
    for exposure in (0.0, -7.25, 1.3, 20.0, 120.0):
        assert image._table8(view if view in ("filmic", "clamp") else None, exposure) is not None
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            want = image._codes(x, exposure, view, 8)
            got = image.to_srgb(x, exposure, view)
        assert got.dtype == np.uint8 and got.shape == x.shape
        assert np.array_equal(got, want), (exposure, np.count_nonzero(got != want))


@pytest.mark.parametrize("view", ["filmic", "clamp", None])
def test_codes_step_exactly_at_each_threshold(view):
    """The float32 just below each threshold has the lower code, the threshold itself the
    higher one, in the table and in the definition (255 steps of one code each)."""
    exposure = -0.5
    define = (image._round8 if view is None else
              lambda v: image._codes(v, exposure, view, 8))
    cuts = quantise.thresholds(define)
    assert len(cuts) == 255 and np.all(np.diff(cuts.astype(np.int64)) > 0)
    tab = image._table8(view, exposure if view else 0.0)
    at = cuts.view(np.float32)
    below = (cuts - 1).view(np.float32)
    for x, want in ((below, np.arange(255)), (at, np.arange(1, 256))):
        assert np.array_equal(define(x), want)
        assert np.array_equal(quantise.apply(x, *tab), want)


def test_a_bin_with_two_thresholds_has_no_table():
    """Steps closer than a bin's width: no table (the caller computes the definition)."""
    cuts = np.array([0x3F800001, 0x3F800002], np.uint32)   # two float32 just above 1.0
    assert quantise.table(cuts) is None
    assert quantise.table(cuts[:1]) is not None


@pytest.fixture
def renders(shared_data):
    """A real volume (smoke.vdb) and a real point cloud (the Stanford bunny as glass), small."""
    import volrender
    from conftest import openvdb_missing
    out = {}
    if not openvdb_missing():
        out["smoke"] = volrender.render(str(shared_data / "vdb" / "smoke.vdb"), size=(72, 48),
                                        spp=2).rgba
    out["bunny"] = volrender.render(str(shared_data / "points" / "bun_zipper.ply"),
                                    size=(48, 36), spp=1).rgba
    return out


def test_real_renders_code_as_the_definition_and_exr_keeps_them(renders, tmp_path):
    """Opaque PNG pixels equal the float64 definition's; straight alpha (colour rounded to
    float32) is within one code; EXR and NPY store the render's floats untouched."""
    for name, rgba in renders.items():
        assert rgba.dtype == np.float32
        for view in VIEWS:
            for exposure in (0.0, 2.0, -1.5):
                got = image.png_pixels(rgba, exposure, view, alpha="opaque")
                assert np.array_equal(got[..., :3], image._codes(rgba[..., :3], exposure, view, 8))
                assert (got[..., 3] == 255).all()
                straight = image.png_pixels(rgba, exposure, view, alpha="straight")
                slow = image.png_pixels(rgba.astype(np.float64), exposure, view, alpha="straight")
                assert np.abs(straight.astype(int) - slow).max() <= 1
                assert np.mean(straight != slow) < 1e-3
        assert len(np.unique(image.png_pixels(rgba, 0.0, alpha="opaque"))) > 30   # not flat
        for suffix in (".exr", ".npy"):
            back = image.read_image(image.write_image(tmp_path / f"{name}{suffix}", rgba))
            assert np.array_equal(back.view(np.uint32), rgba.view(np.uint32))


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork")
def test_a_forked_child_codes_with_threads_of_its_own():
    """The row-block threads belong to the process that made them: a child forked after a
    first PNG (multiprocessing's fork start) hung on the parent's pool, which it lacks."""
    import signal
    x = np.random.default_rng(0).random((300, 400, 3)).astype(np.float32)
    want = image.to_srgb(x)
    pid = os.fork()
    if pid == 0:                                         # the child: 10 s, then SIGALRM
        code = 3
        try:
            signal.alarm(10)
            code = 0 if np.array_equal(image.to_srgb(x), want) else 3
        finally:
            os._exit(code)
    status = os.waitpid(pid, 0)[1]
    assert os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0, status
