"""The camera (docs/camera.md): --fov zooms from a fixed place, --fill and --distance frame
the default camera, conflicting options are errors, sequences write --camera-out and print
the camera with -v, and `volrender tree` looks through the render's camera."""
import math

import numpy as np
import pytest

import volrender
from volrender import cli, generators
from volrender.camera import View

LO, HI = np.array([-1.0, -0.5, -2.0]), np.array([3.0, 1.5, 0.0])


def run(capsys, *argv):
    try:
        code = cli.main([str(a) for a in argv])
    except SystemExit as e:
        code = e.code
    out = capsys.readouterr()
    return code, out.out, out.err


def cam(**kw):
    return View(size=(32, 24), **kw).camera(LO, HI)


def dist(c):
    return float(np.linalg.norm(np.subtract(c.origin, c.target)))


def footprint(c, pts, radii=0.0):
    """The projected bounds of spheres through camera c: (larger side / the frame's smaller
    side, centre offset in pixels), by brute force per point (independent of framing.fit)."""
    f, r, u = c.basis()
    d = np.asarray(pts, np.float64) - np.asarray(c.origin)
    depth = d @ f
    assert (depth > 0).all()
    k = c.height / (2.0 * math.tan(math.radians(c.fov) / 2.0))      # pixels per tan unit
    rad = np.broadcast_to(radii, (len(d),))
    x0, x1 = k * ((d @ r - rad) / depth).min(), k * ((d @ r + rad) / depth).max()
    y0, y1 = k * ((d @ u - rad) / depth).min(), k * ((d @ u + rad) / depth).max()
    return max(x1 - x0, y1 - y0) / min(c.width, c.height), (0.5 * (x0 + x1), 0.5 * (y0 + y1))


CORNERS = np.array([[x, y, z] for x in (LO[0], HI[0]) for y in (LO[1], HI[1]) for z in (LO[2], HI[2])])


def test_fov_zooms_from_a_fixed_origin():
    base = cam()
    for fov in (15.0, 28.0, 60.0):
        c = cam(fov=fov)
        assert np.allclose(c.origin, base.origin) and np.allclose(c.target, base.target)
        # the projected size scales as the tan(fov/2) ratio
        ratio = footprint(c, CORNERS)[0] / footprint(base, CORNERS)[0]
        assert ratio == pytest.approx(math.tan(math.radians(20)) / math.tan(math.radians(fov / 2)))
    # at the default fov the box's projected bounds cover 0.9 of the smaller side, centred
    fill, (cx, cy) = footprint(base, CORNERS)
    assert fill == pytest.approx(0.9) and abs(cx) < 1e-6 and abs(cy) < 1e-6


def test_fov_zooms_in_a_render():
    """Same origin, fov 40 and 28: the cloud's rows from the image centre grow by
    tan(20)/tan(14) (1.46), within a pixel at either edge."""
    ext = {}
    far = 1.6 * dist(volrender.load_scene("blob:300", size=(48, 48)).camera)    # no cropping
    for fov in (40.0, 28.0):
        img = volrender.render(volrender.load_scene("blob:300", size=(48, 48), fov=fov,
                                                    bounces=1, distance=far))
        rows = np.nonzero((img.rgba[..., 3] > 0.5).any(axis=1))[0]
        ext[fov] = (24 - rows[0], rows[-1] + 1 - 24)        # above and below the centre
    k = math.tan(math.radians(20)) / math.tan(math.radians(14))
    for a, b in zip(ext[40.0], ext[28.0]):
        assert abs(b - k * a) <= 1.5, (ext, k)


@pytest.mark.parametrize("fill,fov,size", [(0.5, 40.0, (32, 24)), (0.9, 15.0, (24, 32)),
                                           (1.0, 70.0, (30, 30)), (2.0, 30.0, (64, 24))])
def test_fill_puts_the_contents_bounds_at_the_asked_fraction(fill, fov, size):
    """The projected bounds of the content (here a box's corners, and spheres) cover
    `fill` of the frame's smaller side, centred, whatever the fov and the aspect."""
    c = View(size=size, fill=fill, fov=fov).camera(LO, HI)
    got, (cx, cy) = footprint(c, CORNERS)
    assert got == pytest.approx(fill, rel=1e-6) and abs(cx) < 1e-6 and abs(cy) < 1e-6
    rng = np.random.default_rng(3)
    pts, radii = rng.normal(size=(500, 3)) * (3.0, 1.0, 0.5), rng.uniform(0.01, 0.3, 500)
    c = View(size=size, fill=fill, fov=fov, azimuth=40.0).camera(LO, HI, extent=(pts, radii))
    got, (cx, cy) = footprint(c, pts, radii)
    assert got == pytest.approx(fill, rel=1e-6) and abs(cx) < 1e-6 and abs(cy) < 1e-6


def test_target_alone_is_orbited_with_the_content_inside():
    """--target: looked at as given, from where the content's farther side from it covers
    half the asked fraction."""
    c = View(size=(32, 24), target=(3.0, 1.5, 0.0)).camera(LO, HI)
    assert np.allclose(c.target, (3.0, 1.5, 0.0))
    f, r, u = c.basis()
    d = CORNERS - np.asarray(c.origin)
    k = c.height / (2.0 * math.tan(math.radians(c.fov) / 2.0))
    far = k * np.abs(np.stack([(d @ r) / (d @ f), (d @ u) / (d @ f)])).max()
    assert 2.0 * far / 24 == pytest.approx(0.9)


def test_distance_puts_the_origin_at_d_from_the_target():
    for d in (0.5, 7.0, 1e4):
        assert dist(cam(distance=d)) == pytest.approx(d)
        c = cam(distance=d, target=(1.0, 2.0, 3.0), azimuth=90.0, elevation=0.0)
        assert np.allclose(c.target, (1.0, 2.0, 3.0))
        assert np.allclose(c.origin, (1.0 + d, 2.0, 3.0))     # azimuth 90: along +x
    # a distance alone keeps the content centred
    assert np.allclose(footprint(cam(distance=9.0), CORNERS)[1], 0.0, atol=1e-6)


@pytest.mark.parametrize("args,words", [
    (["--origin", "0,0,5", "--azimuth", "30"], ["--origin", "--azimuth"]),
    (["--origin", "0,0,5", "--elevation", "30"], ["--origin", "--elevation"]),
    (["--origin", "0,0,5", "--fill", "0.5"], ["--origin", "--fill"]),
    (["--origin", "0,0,5", "--distance", "3"], ["--origin", "--distance"]),
    (["--fill", "0.5", "--distance", "3"], ["--fill", "--distance"]),
])
def test_conflicting_camera_options_are_errors(capsys, tmp_path, args, words):
    code, _, err = run(capsys, "render", "blob:50", "-o", tmp_path / "a.png", "--size", "8x8",
                       *args)
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "conflict" in err and all(w in err for w in words) and "give only one" in err
    assert not (tmp_path / "a.png").exists()


def test_camera_file_beside_azimuth_is_an_error(capsys, tmp_path):
    camf = tmp_path / "cam.toml"
    assert run(capsys, "render", "blob:50", "-o", tmp_path / "a.png", "--size", "8x8",
               "--camera-out", camf)[0] == 0
    code, _, err = run(capsys, "render", "blob:50", "-o", tmp_path / "b.png", "--size", "8x8",
                       "--camera", camf, "--azimuth", "30")
    assert code == 2 and "cam.toml: [camera].origin and --azimuth conflict" in err
    # options that replace the file's own values are not conflicts
    assert run(capsys, "render", "blob:50", "-o", tmp_path / "b.png", "--size", "8x8",
               "--camera", camf, "--fov", "20")[0] == 0


def test_conflicts_in_scene_files_and_python(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text('[points]\ngenerator = "blob"\ncount = 50\n[camera]\nfill = 0.5\n'
                     'distance = 3\n')
    with pytest.raises(volrender.UserError, match=r"s.toml: \[camera\].fill and .*"
                                                   r"\[camera\].distance conflict"):
        volrender.load_scene(scene)
    with pytest.raises(volrender.UserError, match="origin= and azimuth= conflict"):
        volrender.load_scene("blob:50", origin=(0, 0, 5), azimuth=10)
    with pytest.raises(volrender.UserError, match="fill= and distance= conflict"):
        View(fill=0.5, distance=2.0)


def test_sequence_writes_camera_out_and_prints_it(capsys, tmp_path):
    for f in (1, 2):
        np.save(tmp_path / f"p_{f:04d}.npy",
                (generators.blob(80, seed=f).centers).astype(np.float32))
    camf = tmp_path / "seq_cam.toml"
    code, _, err = run(capsys, "render", tmp_path / "p_####.npy", "-o", tmp_path / "o_####.png",
                       "--size", "12x9", "--workers", "0", "--no-progress", "--bounces", "1",
                       "--fill", "0.7", "--camera-out", camf, "-v")
    assert code == 0, err
    line = [ln for ln in err.splitlines() if "camera origin" in ln]
    assert len(line) == 1 and "size 12x9" in line[0], err
    # the file is the camera the frames used: rendering frame 1 through it gives its bytes
    assert run(capsys, "render", tmp_path / "p_0001.npy", "-o", tmp_path / "one.png",
               "--camera", camf, "--bounces", "1", "--no-progress")[0] == 0
    assert (tmp_path / "one.png").read_bytes() == (tmp_path / "o_0001.png").read_bytes()


def test_tree_looks_through_the_renders_camera(monkeypatch, tmp_path, capsys):
    pytest.importorskip("pyvista")
    from volrender import inspect
    seen = {}

    def finish(plotter, screenshot, show):
        c = plotter.camera
        seen.update(position=c.position, focal_point=c.focal_point, up=c.up,
                    view_angle=c.view_angle)
        plotter.close()
    monkeypatch.setattr(inspect, "_finish", finish)
    opts = ["--fov", "25", "--azimuth", "70", "--elevation", "10", "--fill", "0.8"]
    shot = tmp_path / "t.png"
    assert run(capsys, "tree", "blob:200", "--screenshot", shot, "--window-size", "64x48",
               *opts)[0] == 0
    c = volrender.load_scene("blob:200", size=(64, 48), fov=25.0, azimuth=70.0,
                             elevation=10.0, fill=0.8).camera
    assert np.allclose(seen["position"], c.origin) and np.allclose(seen["focal_point"], c.target)
    assert np.allclose(seen["up"], c.up) and seen["view_angle"] == pytest.approx(c.fov)
    # a camera file: the same view as the render through it
    camf = tmp_path / "cam.toml"
    assert run(capsys, "render", "blob:200", "-o", tmp_path / "r.png", "--size", "16x12",
               *opts, "--camera-out", camf)[0] == 0
    seen.clear()
    assert run(capsys, "tree", "blob:200", "--screenshot", shot, "--camera", camf)[0] == 0
    assert np.allclose(seen["position"], c.origin) and seen["view_angle"] == pytest.approx(25.0)
