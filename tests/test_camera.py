"""The camera (docs/camera.md): --fov zooms from a fixed place, --fill and --distance frame
the default camera, conflicting options are errors, sequences write --camera-out and print
the camera with -v, and `volrender tree` looks through the render's camera."""
import math

import numpy as np
import pytest

import volrender
from volrender import cli, generators
from volrender.camera import View, framing_distance, projected_fill

LO, HI = np.array([-1.0, -0.5, -2.0]), np.array([3.0, 1.5, 0.0])
RADIUS = 0.5 * float(np.linalg.norm(HI - LO))
CENTRE = 0.5 * (LO + HI)


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


def test_fov_zooms_from_a_fixed_origin():
    base = cam()
    for fov in (15.0, 28.0, 60.0):
        c = cam(fov=fov)
        assert np.allclose(c.origin, base.origin) and np.allclose(c.target, base.target)
        # the bounding sphere's projected size scales as the tan(fov/2) ratio
        ratio = projected_fill(RADIUS, dist(c), fov) / projected_fill(RADIUS, dist(base), 40.0)
        assert ratio == pytest.approx(math.tan(math.radians(20)) / math.tan(math.radians(fov / 2)))
    # at the default fov the sphere fills the height, as before
    assert projected_fill(RADIUS, dist(base), 40.0) == pytest.approx(1.0)


def test_fov_zooms_in_a_render():
    """Same origin, fov 40 and 28: the cloud's rows from the image centre grow by
    tan(20)/tan(14) (1.46), within a pixel at either edge."""
    ext = {}
    for fov in (40.0, 28.0):
        img = volrender.render(volrender.load_scene("blob:300", size=(48, 48), fov=fov,
                                                    bounces=1))
        rows = np.nonzero((img.rgba[..., 3] > 0.5).any(axis=1))[0]
        ext[fov] = (24 - rows[0], rows[-1] + 1 - 24)        # above and below the centre
    k = math.tan(math.radians(20)) / math.tan(math.radians(14))
    for a, b in zip(ext[40.0], ext[28.0]):
        assert abs(b - k * a) <= 1.5, (ext, k)


@pytest.mark.parametrize("fill,fov", [(0.5, 40.0), (0.9, 15.0), (1.0, 70.0), (2.0, 30.0)])
def test_fill_puts_the_bounding_sphere_at_the_asked_fraction(fill, fov):
    c = cam(fill=fill, fov=fov)
    assert np.allclose(c.target, CENTRE)
    assert projected_fill(RADIUS, dist(c), fov) == pytest.approx(fill)
    # analytic check without the helper: the silhouette's half-angle asin(r/d)
    assert math.tan(math.asin(RADIUS / dist(c))) == pytest.approx(fill * math.tan(math.radians(fov / 2)))


def test_distance_puts_the_origin_at_d_from_the_target():
    for d in (0.5, 7.0, 1e4):
        assert dist(cam(distance=d)) == pytest.approx(d)
        c = cam(distance=d, target=(1.0, 2.0, 3.0), azimuth=90.0, elevation=0.0)
        assert np.allclose(c.target, (1.0, 2.0, 3.0))
        assert np.allclose(c.origin, (1.0 + d, 2.0, 3.0))     # azimuth 90: along +x
    assert framing_distance(RADIUS, 40.0) == pytest.approx(dist(cam()))


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
