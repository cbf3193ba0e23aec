"""Denoising (issue 34): the guides are what they claim (closed forms), OIDN lowers the error
of a low-spp path-traced cloud against its converged reference and leaves a noiseless
image nearly unchanged, auto picks by the output, and a missing pyoidn degrades to one line."""
import math
import re
import warnings

import numpy as np
import pytest
from scipy.special import erf

from volrender import denoise, glass, guides, volume
from volrender.camera import Camera
from volrender.image import read_exr_channels
from volrender.lights import Sun
from volrender.cloud import PointCloud
from volrender.render import PLANNERS, render
from volrender.scene import GlassContent, Scene, VolumeContent
from helpers import centred_bricks, look_at, ray_sphere

pyoidn = pytest.importorskip("pyoidn", reason="Open Image Denoise (the `denoise` extra) is "
                                              "not installed: bash run.sh setup installs it")
SUN = (Sun((-0.6, -1.0, -0.5), 4.0),)


def guide_images(scene, dev, spp=1, edge_spp=0):
    return guides.render_guides(scene, dev, PLANNERS[scene.kind](scene, dev, None, None), spp,
                                edge_spp=edge_spp)


def test_the_albedo_guide_of_a_uniform_medium_is_its_albedo(cl_device):
    """An opaque uniform cube seen face on: every covered pixel's guide is the medium's
    albedo per channel (chromatic, so a channel mix-up shows)."""
    bricks, _ = centred_bricks(np.ones((16, 16, 16), np.float32), 0.1)
    s = volume.VolumeSettings(albedo=(0.3, 0.6, 0.9), density_scale=400.0, estimator="march")
    scene = Scene.of(look_at((0, 0, 4), fov=12, n=16), list(SUN), VolumeContent(bricks, s))
    g = guide_images(scene, cl_device, spp=4)
    face = g["albedo"][4:12, 4:12]               # well inside the 1.6-wide face
    np.testing.assert_allclose(face, np.broadcast_to([0.3, 0.6, 0.9], face.shape), atol=1e-3)
    # ... and its normal is the face's, +z towards the camera
    np.testing.assert_allclose(g["normal"][4:12, 4:12], np.broadcast_to([0, 0, 1], face.shape),
                               atol=1e-3)


def test_the_normal_guide_of_a_glass_sphere_is_its_normal(cl_device):
    """One glass sphere: the guide at each pixel centre is (p - c) / r at the ray's first
    hit p (closed form), 0 where the ray misses; the albedo is the glass colour scaled to a
    brightest channel of 1."""
    r, c = 0.7, np.array([0.2, -0.1, 0.3])
    cloud = PointCloud(c[None], np.array([r]))
    cam = Camera((0.5, 0.8, 4.0), tuple(c), (0, 1, 0), 30.0, 24, 20)
    s = glass.GlassSettings(blend=0.0, epsilon=1e-5, color=(1.0, 0.5, 0.25))
    g = guide_images(Scene.of(cam, list(SUN), GlassContent(cloud, s)), cl_device)
    d = cam.pixel_dirs()
    t = ray_sphere(np.asarray(cam.origin), d, c, r)
    hit = np.isfinite(t)
    want = (np.asarray(cam.origin) + t[..., None] * d - c) / r
    inner = hit & (np.abs(np.einsum("hwc,hwc->hw", np.where(hit[..., None], want, 0), d)) > 0.05)
    assert inner.sum() > 50
    np.testing.assert_allclose(g["normal"][inner], want[inner], atol=2e-3)
    assert np.all(g["normal"][~hit] == 0)
    np.testing.assert_allclose(g["albedo"][inner], np.broadcast_to([1, 0.5, 0.25],
                                                                   g["albedo"][inner].shape), atol=1e-6)


def test_the_glass_guide_takes_more_rays_exactly_on_its_edges(cl_device):
    """The CPUs' glass guide (1 ray, EDGE_SPP on guides.edges' pixels): on the edge pixels
    of the one-ray guide it is the EDGE_SPP-ray guide (the same jittered rays), elsewhere
    the one-ray guide, bit for bit; the edges hold the silhouette and little else."""
    r, c = 0.7, np.array([0.2, -0.1, 0.3])
    cloud = PointCloud(c[None], np.array([r]))
    cam = Camera((0.5, 0.8, 4.0), tuple(c), (0, 1, 0), 30.0, 32, 24)
    s = glass.GlassSettings(blend=0.0, epsilon=1e-5, color=(1.0, 0.5, 0.25))
    scene = Scene.of(cam, list(SUN), GlassContent(cloud, s))
    main = PLANNERS["glass"](scene, cl_device, None, None)
    assert guides.SPP["glass"] == 1 and guides.EDGE_SPP["glass"] == 4
    one = guide_images(scene, cl_device, spp=1)
    many = guide_images(scene, cl_device, spp=4)
    got = guides.render_guides(scene, cl_device, main, 1, edge_spp=4)
    edge = guides.edges(one["albedo"], one["normal"])
    hit = np.any(one["normal"] != 0, axis=-1)
    rim = hit & ~np.all(np.pad(hit, 1)[1:-1, 1:-1][None] == np.stack(
        [np.roll(hit, (dy, dx), (0, 1)) for dy in (-1, 0, 1) for dx in (-1, 0, 1)]), axis=0)
    assert rim.sum() > 20 and np.all(edge[rim]) and 0 < edge.mean() < 0.5
    for k in ("albedo", "normal"):
        np.testing.assert_array_equal(got[k][edge], many[k][edge])
        np.testing.assert_array_equal(got[k][~edge], one[k][~edge])
    assert np.abs(many["normal"][edge] - one["normal"][edge]).max() > 0.05


def test_guide_edges_are_where_the_neighbourhood_changes(rng):
    """guides.edges on a synthetic guide: a disc of +z normals on nothing (0) with a right
    half tilted by 45 degrees and a strip of albedo 0.5 on 0.3: edges are the pixels with a
    different neighbour in their 3 x 3 (the albedo counted between disc pixels only: what
    is behind is smooth), and only those."""
    h, w = 20, 24
    y, x = np.mgrid[0:h, 0:w]
    disc = (x - 11.5) ** 2 + (y - 9.5) ** 2 < 49
    n = np.zeros((h, w, 3), np.float32)
    n[disc] = (0, 0, 1)
    n[disc & (x >= 12)] = (0, math.sqrt(0.5), math.sqrt(0.5))
    a = np.full((h, w, 3), 0.3, np.float32)
    a[:, 6:8] = 0.5
    a[~disc] = rng.uniform(0, 1, (int((~disc).sum()), 3))      # the sky: not edges
    label = np.where(disc, np.where(x >= 12, 2, 1) * 10 + ((x >= 6) & (x < 8)), 0)
    pad = np.pad(label, 1, mode="edge")
    want = np.zeros((h, w), bool)
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            want |= pad[dy:dy + h, dx:dx + w] != label
    np.testing.assert_array_equal(guides.edges(a, n), want)


def test_the_normal_guide_of_a_gaussian_blob_is_radial_at_half_transmittance(cl_device):
    """A Gaussian blob, sigma_t = k exp(-|x - c|^2 / 2 s^2): along a ray of impact parameter
    b the optical depth to t is k e^{-b^2/2s^2} s sqrt(pi/2) (1 + erf((t - tc)/(s sqrt 2)));
    the guide is the outward radial unit vector where it reaches ln 2 (T = 1/2). The march
    finds the crossing within a step and reads a trilinear grid: 0.03 per component."""
    n, vox, sd, k = 48, 0.05, 0.35, 12.0
    i = (np.indices((n, n, n)) - (n - 1) / 2) * vox
    v = np.exp(-(i ** 2).sum(0) / (2 * sd * sd)).astype(np.float32)
    bricks, _ = centred_bricks(v, vox)
    s = volume.VolumeSettings(density_scale=k, estimator="march", step=0.25)
    cam = look_at((0.4, 0.3, 4.0), fov=24, n=24)
    g = guide_images(Scene.of(cam, list(SUN), VolumeContent(bricks, s)), cl_device)
    o, d = np.asarray(cam.origin), cam.pixel_dirs()
    tc = -(d @ o)                                   # closest approach to the centre (0)
    b2 = (o ** 2).sum() - tc ** 2
    amp = k * np.exp(-b2 / (2 * sd * sd)) * sd * math.sqrt(math.pi / 2)
    ok = 2 * amp > math.log(2) * 1.2                # rays that get well past T = 1/2
    arg = np.clip(math.log(2) / np.where(ok, amp, 1) - 1, -1 + 1e-9, 1 - 1e-9)
    from scipy.special import erfinv
    t = tc + sd * math.sqrt(2) * erfinv(arg)
    p = o + t[..., None] * d
    want = p / np.linalg.norm(p, axis=-1, keepdims=True)
    assert ok.sum() > 60
    np.testing.assert_allclose(g["normal"][ok], want[ok], atol=0.03)
    assert erf(0.0) == 0.0                          # (scipy's erf, as the docstring's)


def test_the_volume_guide_march_at_its_coarse_step_keeps_the_transmittance(cl_device):
    """The albedo guide (1 ray at the pixel centre, no sky) of a Gaussian blob, marched at
    twice the render's step (render_guides' step), is (1 - T) albedo, T = exp(-tau), tau the
    blob's closed-form optical depth along the ray, k s sqrt(2 pi) e^{-b^2 / 2 s^2} (impact
    parameter b; the grid's +-3.4 s truncation and trilinear error under 0.5 %): within
    0.01 on every pixel, transmittances from 1 down to e^-4."""
    n, vox, sd, k, alb = 48, 0.05, 0.35, 4.5, 0.8
    i = (np.indices((n, n, n)) - (n - 1) / 2) * vox
    v = np.exp(-(i ** 2).sum(0) / (2 * sd * sd)).astype(np.float32)
    bricks, _ = centred_bricks(v, vox)
    s = volume.VolumeSettings(density_scale=k, estimator="march", step=0.5, albedo=alb)
    cam = look_at((0.4, 0.3, 4.0), fov=24, n=24)
    scene = Scene.of(cam, list(SUN), VolumeContent(bricks, s))
    assert guides.SPP["volume"] == 1
    g = guides.render_guides(scene, cl_device, PLANNERS["volume"](scene, cl_device, None, None),
                             step=2.0)
    o, d = np.asarray(cam.origin), cam.pixel_dirs()
    b2 = (o ** 2).sum() - (d @ o) ** 2
    tau = k * sd * math.sqrt(2 * math.pi) * np.exp(-b2 / (2 * sd * sd))
    want = (1 - np.exp(-tau)) * alb
    assert tau.max() > 3.5 and tau.min() < 0.1
    np.testing.assert_allclose(g["albedo"], np.repeat(want[..., None], 3, -1), atol=0.01)


def small_cloud():
    rng = np.random.default_rng(1)
    i = (np.indices((24, 24, 24)) - 11.5) / 12.0
    v = sum(np.exp(-((i - c[:, None, None, None]) ** 2).sum(0) / 0.08)
            for c in rng.uniform(-0.4, 0.4, (6, 3)))
    return v.astype(np.float32)


def rel_rmse(a, ref, covered):
    return float(np.sqrt(((a[..., :3] - ref[..., :3])[covered] ** 2).mean())
                 / np.sqrt((ref[..., :3][covered] ** 2).mean()))


def test_denoising_a_low_spp_cloud_lowers_its_error(cl_device):
    """Path 4 spp of a small cloud against its 1024-spp reference (covered pixels, alpha >
    0.05): the denoised image's relative RMSE is below half the noisy one's (measured:
    0.57 -> 0.13 at 256 spp reference), and the Image keeps the noisy beauty."""
    kw = dict(size=(40, 30), density_scale=6.0, estimator="path", max_depth=8, fill=2.0)
    ref = render(small_cloud(), cl_device, spp=1024, **kw)
    img = render(small_cloud(), cl_device, spp=4, seed=7, denoise="on", **kw)
    covered = ref.rgba[..., 3] > 0.05
    assert covered.mean() > 0.2
    noisy, clean = rel_rmse(img.noisy, ref.rgba, covered), rel_rmse(img.rgba, ref.rgba, covered)
    assert img.info.denoised and noisy > 0.2
    assert clean < 0.5 * noisy, (noisy, clean)
    np.testing.assert_array_equal(img.rgba[..., 3], img.noisy[..., 3])   # alpha is the render's


def test_the_denoiser_leaves_a_noiseless_image_nearly_unchanged(rng):
    """A smooth HDR image (no noise at all) with its own albedo and a flat normal: OIDN
    changes it by under 2% RMS."""
    h, w = 48, 64
    y, x = np.mgrid[0:h, 0:w] / 40.0
    rgb = np.stack([1.5 + np.sin(x), 1.0 + 0.5 * np.cos(y + x), 0.5 + 0.3 * y], -1)
    rgba = np.concatenate([rgb, np.ones((h, w, 1))], -1).astype(np.float32)
    alb = np.clip(rgb / rgb.max(), 0, 1).astype(np.float32)
    nrm = np.broadcast_to(np.float32([0, 0, 1]), (h, w, 3))
    out = denoise.denoise(rgba, alb, nrm)
    change = np.sqrt(((out - rgba)[..., :3] ** 2).mean()) / np.sqrt((rgba[..., :3] ** 2).mean())
    assert change < 0.02, change
    np.testing.assert_array_equal(out[..., 3], rgba[..., 3])


def test_auto_denoises_png_and_leaves_exr_as_rendered():
    assert denoise.decide("auto", ".png")[0] is True
    on, note = denoise.decide("auto", ".exr")
    assert not on and "EXR written as rendered" in note and "--denoise on" in note
    assert denoise.decide("auto", None) == (False, None)          # Python: off
    assert denoise.decide("on", ".exr") == (True, None)
    assert denoise.decide("off", ".png") == (False, None)


def test_an_exr_denoised_keeps_the_noisy_image_and_the_guides_as_blender_names(cl_device, tmp_path):
    img = render(small_cloud(), cl_device, size=(16, 12), spp=2, estimator="path",
                 density_scale=6.0, denoise="on")
    img.save(tmp_path / "a.exr")
    ch = read_exr_channels(tmp_path / "a.exr")
    for layer, parts in (("Denoising Albedo", "RGB"), ("Denoising Normal", "XYZ"),
                         ("Noisy Image", "RGBA")):
        assert all(f"{layer}.{c}" in ch for c in parts), sorted(ch)
    np.testing.assert_array_equal(ch["Noisy Image.R"], img.noisy[..., 0])
    np.testing.assert_array_equal(ch["Denoising Normal.Y"], img.aovs["normal"][..., 1])
    img.save(tmp_path / "a.png")                 # guides are EXR layers only: no refusal


def test_without_pyoidn_a_render_is_written_as_rendered_with_one_line(cl_device, monkeypatch,
                                                                     tmp_path, capsys):
    monkeypatch.setattr(denoise, "_missing", "Open Image Denoise is not available (test)")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        img = render(small_cloud(), cl_device, size=(8, 6), denoise="on")
    assert img.noisy is None and img.info.denoised is False
    assert len(caught) == 1 and "not denoised" in str(caught[0].message)
    from volrender.cli import main
    capsys.readouterr()
    assert main(["render", "glass_gather:40", "-o", str(tmp_path / "o.png"),
                 "--size", "8x6"]) == 0
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if "denoise" in ln.lower()]
    assert len(lines) == 1 and "not available" in lines[0], err
    assert (tmp_path / "o.png").is_file()


def test_the_time_line_names_the_guides_and_the_denoiser(cl_device, tmp_path, capsys):
    """-v's time line carries the guides' and OIDN's seconds when the PNG is denoised (they
    were missing: 7 s of a 26 s bunny command on PoCL), and neither when it is not."""
    from volrender.cli import main
    for flag, denoised in (("on", True), ("off", False)):
        capsys.readouterr()
        assert main(["render", "glass_gather:40", "-o", str(tmp_path / "o.png"), "-v",
                     "--size", "8x6", "--denoise", flag]) == 0
        err = capsys.readouterr().err
        line = next(ln for ln in err.splitlines() if "time: " in ln)
        parts = dict((k.strip(), float(v)) for k, v in
                     re.findall(r"([a-z ]+?) ([0-9.]+) s", line.split("time:")[1]))
        assert ("guides" in parts and "denoise" in parts) == denoised, line
        if denoised:
            assert parts["guides"] > 0 and parts["denoise"] > 0, line
