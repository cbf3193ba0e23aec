"""The tracking estimator (cl/path_volume.cl at max depth 1): unbiased against closed forms and against
fine ray marching, with tolerances derived from the estimator's own sample variance.

Every pixel is an independent estimate (the RNG is keyed by pixel), so where all pixels
share (nearly) one expected value the spread of the residuals across pixels estimates
the per-pixel standard deviation; elsewhere independent batches (seeds) do. Bounds are
5 standard errors: a false alarm has probability ~6e-7 per check for a normal mean, and
the seeds are fixed, so a pass or a failure is reproducible.
"""
import numpy as np
import pytest

import reference
from volrender import cli
from volrender.camera import Camera
from volrender.errors import UserError
from volrender.lights import Sun
from volrender.volume import (ESTIMATORS, VolumeSettings, emission_color, track_majorants)
from volrender.bricks import Bricks
from conftest import ROOT
from helpers import VOX, render_volume, scaled, top_camera

Z = 5.0                         # standard errors allowed
N_XY, K0, K1 = 40, 17, 22       # slab of tests/test_render_volume.py
THICK = (K1 - K0 + 1) * VOX     # its integral along z, exactly


def make_slab(emission):
    """Voxels with k in [K0, K1] hold 1 across the whole x/y extent: the trilinear
    density along z integrates to exactly THICK. With emission, the emission grid too."""
    v = np.zeros((N_XY, N_XY, 40), np.float32)
    v[:, :, K0:K1 + 1] = 1.0
    c = (N_XY - 1) / 2 * VOX
    return Bricks.from_dense(v, scaled(VOX, (-c, -c, -(K0 + K1) / 2 * VOX)),
                             emission=v if emission else None)


@pytest.fixture(scope="module")
def slab():
    return make_slab(False)


def assert_unbiased(est, want, what):
    """est, want: per-pixel estimates and expected values of i.i.d.-noise pixels."""
    r = (np.asarray(est, np.float64) - want).ravel()
    sd = r.std(ddof=1)
    se = sd / np.sqrt(r.size)
    assert abs(r.mean()) <= Z * se + 1e-6, f"{what}: mean residual {r.mean():.2e}, se {se:.2e}"
    # no pixel far outside the spread (NaN, a lost sample, a stuck pixel)
    assert np.all(np.abs(r - r.mean()) <= 6 * sd + 1e-6), f"{what}: outlier pixel"
    return sd


def test_slab_alpha_is_one_minus_exp_optical_depth(cl_device, slab):
    sigma, spp = 2.0, 512
    cam = top_camera()
    r = render_volume(slab, cam, [], VolumeSettings(density_scale=sigma, spp=spp, seed=3,
                                                    estimator="track"), cl_device)
    cz = np.abs(cam.pixel_dirs()[..., 2])
    want = 1.0 - np.exp(-sigma * THICK / cz)
    sd = assert_unbiased(r.rgba[..., 3], want, "alpha")
    # a per-sample alpha lies in [0, 1], so its variance is at most 1/4
    assert 0 < sd <= 0.5 / np.sqrt(spp)
    assert np.all(r.rgba[..., :3] == 0.0)


def test_slab_single_scatter_with_shadows_matches_closed_form(cl_device, slab):
    """Sun along the slab normal on the viewer's side: view optical depth tau(z)/c,
    light tau(z), so L = albedo p E (1 - exp(-tau (1 + 1/c))) / (1 + c) for any profile."""
    sigma, albedo, E = 2.0, 0.9, 3.0
    sun = Sun((0.0, 0.0, -1.0), E)
    s = VolumeSettings(density_scale=sigma, albedo=albedo, phase=(0.5, 0.0, 1.0), spp=512,
                       seed=5, estimator="track")
    cam = top_camera()
    r = render_volume(slab, cam, [sun], s, cl_device)
    dirs = cam.pixel_dirs()
    c = np.abs(dirs[..., 2])
    mu = -dirs @ np.array(sun.direction)
    want = albedo * reference.hg(mu, 0.5) * E * (1 - np.exp(-sigma * THICK * (1 + 1 / c))) / (1 + c)
    assert_unbiased(r.rgba[..., 1], want, "radiance")


def test_slab_emission_and_background(cl_device):
    """Emission e = E0 v with sigma = s0 v: int T e dt = (E0/s0)(1 - T), plus T * background.
    With density scale 0 the emission is seen unattenuated: E0 * THICK / c, sampled at the
    emission-only rate (one point per voxel) that track_majorants adds."""
    slab = make_slab(True)
    cam = top_camera(12)
    cz = np.abs(cam.pixel_dirs()[..., 2])
    bg = (0.2, 0.3, 0.4)
    for sigma in (2.0, 0.0):
        s = VolumeSettings(density_scale=sigma, spp=256, seed=11, background=bg,
                           emission_scale=0.5, estimator="track")
        assert np.all(track_majorants(slab, s) > 0)
        col = emission_color(s)
        r = render_volume(slab, cam, [], s, cl_device).rgba
        T = np.exp(-sigma * THICK / cz)
        emitted = THICK / cz if sigma == 0 else (1 - T) / sigma
        for ch in range(3):
            assert_unbiased(r[..., ch], col[ch] * emitted + T * bg[ch], f"sigma {sigma} ch {ch}")


@pytest.mark.parametrize("sigma", [1e5, 1e9])
def test_stiff_slab_reaches_the_half_space_limit(cl_device, slab, sigma):
    """Optical depth 6e4 and 6e8 across the slab: mean free paths far below what a float
    ray parameter resolves (1e9) switch the walk to whole intervals with a linear density
    (cl/track.h, VR_BULK_*), exact on the slab's linear ramp. The closed form
    tends to albedo p E / (1 + c), independent of sigma."""
    sun = Sun((0.0, 0.0, -1.0), 3.0)
    cam = top_camera(8)
    s = VolumeSettings(density_scale=sigma, albedo=0.9, phase=(0.5, 0.0, 1.0), spp=256, seed=5,
                       estimator="track")
    r = render_volume(slab, cam, [sun], s, cl_device).rgba
    dirs = cam.pixel_dirs()
    c = np.abs(dirs[..., 2])
    want = 0.9 * reference.hg(-dirs @ np.array(sun.direction), 0.5) * 3.0 / (1 + c)
    assert np.all(r[..., 3] == 1.0)
    assert_unbiased(r[..., 1], want, f"sigma {sigma}")


def test_overflowing_density_stays_finite(cl_device, slab):
    """sigma beyond float range: opaque, finite, no hang."""
    s = VolumeSettings(density_scale=1e30, spp=4, estimator="track", background=(0.2, 0.2, 0.2))
    r = render_volume(slab, top_camera(6), [Sun((0.2, -0.3, -1.0), 2.0)], s, cl_device).rgba
    assert np.isfinite(r).all() and np.all(r[..., 3] == 1.0)


def smooth_noise(n, seed):
    """Positive, smooth random field on n^3 voxels, zero on the border."""
    rng = np.random.default_rng(seed)
    v = rng.random((n, n, n))
    for ax in range(3):          # three box blurs per axis ~ a smooth bump field
        for _ in range(3):
            v = (np.roll(v, 1, ax) + v + np.roll(v, -1, ax)) / 3
    v = np.clip((v - v.mean()) / v.std() * 0.5 + 0.6, 0.0, None)
    v[[0, -1]], v[:, [0, -1]], v[:, :, [0, -1]] = 0, 0, 0
    return v.astype(np.float32)


def test_tracking_agrees_with_fine_marching_on_a_heterogeneous_grid(cl_device):
    """A 20^3 random smooth cloud over 3^3 bricks (per-brick majorants differ), an oblique
    camera and sun (the brick DDA steps both ways on every axis). The field of view is
    narrow (a pixel spans ~0.2 voxel), so marching's few jittered samples per pixel
    average the pixel's footprint well: both then estimate the same pixel value.
    Per pixel: |track - march(0.1)| <= 6 se_track + |march(0.2) - march(0.1)|, se_track
    from 16 independent batches (a t statistic with 15 degrees of freedom exceeds 6 with
    probability 2.4e-5), the march term bounding marching's own error (O(step^2):
    Richardson puts it near a third of that difference) and jitter noise. Then all
    pixels at once: the summed residual within Z of its standard error."""
    b = Bricks.from_dense(smooth_noise(20, 1), scaled(VOX, (-1.0, -1.0, -1.0)))
    assert b.n_slots == 27 and len(set(np.round(b.majorant, 4))) > 3
    cam = Camera((1.6, 1.1, 4.5), (0.13, 0.07, 0.05), (0.0, 1.0, 0.0), 3.0, 12, 12)
    sun = [Sun((0.7, -0.5, 0.45), 2.0)]
    base = dict(density_scale=1.2, albedo=0.8, phase=(0.6, -0.3, 0.8), background=(0.1, 0.1, 0.1))
    batches = np.stack([render_volume(b, cam, sun, VolumeSettings(**base, spp=128, seed=100 + k,
                                                                  estimator="track"),
                                      cl_device).rgba for k in range(16)]).astype(np.float64)
    mean, se = batches.mean(0), batches.std(0, ddof=1) / np.sqrt(len(batches))
    fine, coarse = (render_volume(b, cam, sun, VolumeSettings(**base, spp=4, step=h, shadow_step=h),
                                  cl_device).rgba.astype(np.float64) for h in (0.1, 0.2))
    assert 0.5 < fine[..., 3].min() and fine[..., 3].max() < 0.95 and fine[..., 0].min() > 0.05
    march_err = np.abs(coarse - fine)
    allow = 6 * se + march_err + 1e-6
    bad = np.abs(mean - fine) > allow
    assert not bad.any(), (np.abs(mean - fine) / allow)[bad]
    for ch in range(4):
        d = (mean - fine)[..., ch]
        assert abs(d.sum()) <= Z * np.sqrt((se[..., ch] ** 2).sum()) + march_err[..., ch].sum()


def test_tracking_image_does_not_depend_on_the_launch(cl_device):
    """Random numbers are keyed by (seed, pixel, sample, dimension): fragment and tiled
    launches (tiles overhanging the image edge) give the same image, bit for bit."""
    b = Bricks.from_dense(smooth_noise(20, 2), scaled(VOX, (-1.0, -1.0, -1.0)))
    cam = Camera((1.2, 0.8, 4.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 30.0, 13, 7)
    base = dict(density_scale=3.0, spp=3, seed=9, estimator="track", aovs=("depth",))
    lights = [Sun((0.3, -1.0, 0.2), 2.0)]
    frag = render_volume(b, cam, lights, VolumeSettings(**base, dispatch="fragment"), cl_device)
    tiled = render_volume(b, cam, lights, VolumeSettings(**base, dispatch="tiled", tile=(4, 4)),
                          cl_device)
    assert frag.rgba[..., 3].max() > 0.3 and np.isfinite(frag.aovs["depth"]).any()
    np.testing.assert_array_equal(frag.rgba, tiled.rgba)
    np.testing.assert_array_equal(frag.aovs["depth"], tiled.aovs["depth"])


def test_estimator_is_validated(tmp_path, capsys):
    assert ESTIMATORS == ("auto", "march", "track", "path")
    with pytest.raises(UserError, match="estimator"):
        VolumeSettings(estimator="monte-carlo")
    out = tmp_path / "o.png"
    with pytest.raises(SystemExit) as exc:
        cli.main(["render", str(ROOT / "scenes" / "demo_cloud.vdb"), "-o", str(out),
                  "--estimator", "exact"])
    assert exc.value.code == 2 and "estimator" in capsys.readouterr().err
    assert not out.exists()


def test_cli_renders_with_tracking(tmp_path, capsys):
    out = tmp_path / "t.npy"
    code = cli.main(["render", str(ROOT / "scenes" / "demo_cloud.vdb"), "-o", str(out),
                     "--size", "24x18", "--no-progress", "--estimator", "track", "--spp", "4"])
    assert code == 0, capsys.readouterr().err
    rgba = np.load(out)
    assert rgba.shape == (18, 24, 4) and np.isfinite(rgba).all() and rgba[..., 3].max() > 0.1


def test_error_bench_quick_run(tmp_path, monkeypatch):
    """bench/error.py --quick end to end (volumes only), writing into tmp_path."""
    import json
    from bench import error
    monkeypatch.setenv("VOLRENDER_BENCH_RESULTS", str(tmp_path))
    assert error.main(["--quick", "--no-glass", "--size", "24x18", "--ref-spp", "16",
                       "--tag", "t"]) == 0
    (path,) = tmp_path.glob("error_*-t-quick.json")     # the device's tag, then ours
    rec = json.loads(path.read_text())
    assert path.with_suffix(".png").stat().st_size > 0
    assert rec["commit"] and rec["argv"] and rec["timing"] == "warm"
    demo = rec["volume"][0]
    assert demo["scene"] == "demo_cloud" and demo["reference"]["spp"] == 64
    rows = demo["rows"]
    assert {"step", "shadow_step", "spp", "track", "track@march-time"} <= {r["group"] for r in rows}
    assert any(r["pareto"] for r in rows)
    for r in rows:
        assert r["time_ms"] > 0 and np.isfinite(r["rmse"]) and r["max_abs"] >= r["rmse"] * 0.99
    ms = rec["multiple_scattering"][0]            # path reference, path and octave rows
    assert ms["scene"] == "demo_cloud" and ms["reference"]["estimator"] == "path"
    assert {"path", "octaves"} <= {r["group"] for r in ms["rows"]}
    assert set(ms["path_time_to_error"]) == {"0.05", "0.02", "0.01"}
    # single scattering is darker than the multiply scattered reference
    one = next(r for r in ms["rows"] if r["label"] == "march 1 octaves, 4 spp")
    assert one["mean_ratio"] < 0.9 and ms["reference"]["single_over_multiple"] < 0.9
