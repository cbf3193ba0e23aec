"""The command line: demo render, convert round trip, and bad input that loses nothing."""
import os
import subprocess
import sys

import numpy as np
import pytest

from volrender import cli, image
from conftest import ROOT

DEMO = ROOT / "scenes" / "demo_cloud.vdb"
SMALL = ["--size", "24x18", "--no-progress"]


def run(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def write_grid(path, make):
    from volrender.vdb import import_openvdb
    vdb = import_openvdb()
    grid = make(vdb)
    vdb.write(str(path), grids=[grid])
    return path


def float_grid(vdb, values, name="density"):
    g = vdb.FloatGrid()
    g.copyFromArray(np.asarray(values, np.float32))
    g.name = name
    g.gridClass = vdb.GridClass.FOG_VOLUME
    return g


def assert_clean_failure(code, err, out_path, *words):
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("volrender: error: "), err
    assert "Traceback" not in err
    for w in words:
        assert w.lower() in err.lower(), (w, err)
    assert not os.path.exists(out_path)
    leftovers = [p for p in os.listdir(os.path.dirname(out_path)) if ".tmp" in p]
    assert not leftovers


def test_render_demo_to_every_format(tmp_path, capsys):
    for suffix in (".png", ".npy", ".exr"):
        out = tmp_path / f"demo{suffix}"
        code, _, err = run(capsys, "render", DEMO, "-o", out, *SMALL)
        assert code == 0, err
        assert out.is_file() and "wrote" in err
    rgba = image.read_image(tmp_path / "demo.exr")
    np.testing.assert_array_equal(rgba, np.load(tmp_path / "demo.npy"))
    assert rgba.shape == (18, 24, 4) and rgba[..., 3].max() > 0.1


def test_exr_layers_depth_and_transmittance(tmp_path, capsys):
    out = tmp_path / "aov.exr"
    # the march: its Z is the opacity-weighted distance wherever alpha > 0 (the path
    # estimator's Z comes from its first collisions, which a pixel of alpha 1e-5 may lack)
    code, _, err = run(capsys, "render", DEMO, "-o", out, *SMALL, "--aov", "depth", "--aov",
                       "transmittance", "--estimator", "march")
    assert code == 0, err
    ch = image.read_exr_channels(out)
    rgba = image.read_image(out)
    np.testing.assert_allclose(ch["T"], 1 - rgba[..., 3], atol=1e-7)
    hit = rgba[..., 3] > 0.01
    assert np.all(np.isfinite(ch["Z"][hit])) and np.all(ch["Z"][hit] > 0)
    empty = rgba[..., 3] == 0                 # nothing met: the documented far value
    assert empty.any() and np.all(ch["Z"][empty] == image.DEPTH_FAR)
    assert np.all(ch["Z"][~empty] < 1e3)
    import OpenEXR
    with OpenEXR.File(str(out)) as f:
        assert f.header()["depthFar"] == pytest.approx(image.DEPTH_FAR)


def test_convert_then_render_npz_equals_vdb(tmp_path, capsys):
    npz = tmp_path / "demo.npz"
    code, _, err = run(capsys, "convert", DEMO, npz)
    assert code == 0, err
    a, b = tmp_path / "a.npy", tmp_path / "b.npy"
    assert run(capsys, "render", DEMO, "-o", a, *SMALL)[0] == 0
    assert run(capsys, "render", npz, "-o", b, *SMALL)[0] == 0
    np.testing.assert_array_equal(np.load(a), np.load(b))


def test_negative_vector_values_parse(tmp_path, capsys):
    out = tmp_path / "o.npy"
    code, _, err = run(capsys, "render", DEMO, "-o", out, *SMALL, "--sun", "-1,-1,-0.5,4",
                       "--point-light", "-3,2,1,5", "--background", "0.1")
    assert code == 0, err


def test_info_lists_devices_and_dependencies(capsys):
    code, out, err = run(capsys, "info")
    assert code == 0, err
    assert "pyopencl" in out and "OpenVDB" in out and "*" in out


def test_info_lists_grids_of_a_vdb(capsys):
    code, out, _ = run(capsys, "info", DEMO)
    assert code == 0 and "density" in out and "fog volume" in out


def test_info_describes_each_file_given(tmp_path, capsys):
    """`volrender info *.ply demo.vdb`: every file, in order (a shell glob gives several)."""
    pts = tmp_path / "p.xyz"
    pts.write_text("0 0 0\n1 0 0\n0 1 0\n")
    code, out, err = run(capsys, "info", pts, DEMO)
    assert code == 0, err
    assert out.index(f"{pts}: 3 points") < out.index(f"{DEMO}: OpenVDB")


def test_missing_file(tmp_path, capsys):
    out = tmp_path / "o.png"
    code, _, err = run(capsys, "render", tmp_path / "nope.vdb", "-o", out, *SMALL)
    assert_clean_failure(code, err, out, "nope.vdb")


def test_not_a_vdb(tmp_path, capsys):
    bad = tmp_path / "fake.vdb"
    bad.write_text("hello, I am text\n" * 20)
    out = tmp_path / "o.png"
    code, _, err = run(capsys, "render", bad, "-o", out, *SMALL)
    assert_clean_failure(code, err, out, "fake.vdb", "openvdb")


def test_truncated_vdb(tmp_path, capsys):
    data = DEMO.read_bytes()
    bad = tmp_path / "cut.vdb"
    bad.write_bytes(data[: len(data) // 2])
    out = tmp_path / "o.png"
    code, _, err = run(capsys, "render", bad, "-o", out, *SMALL)
    assert_clean_failure(code, err, out, "cut.vdb")


def test_wrong_grid_name_lists_the_grids(tmp_path, capsys):
    out = tmp_path / "o.png"
    code, _, err = run(capsys, "render", DEMO, "-o", out, *SMALL, "--grid", "smoke")
    assert_clean_failure(code, err, out, "smoke", "density")


def test_vector_grid(tmp_path, capsys):
    def make(vdb):
        g = vdb.Vec3SGrid()
        g.copyFromArray(np.ones((4, 4, 4, 3), np.float32))
        g.name = "velocity"
        return g
    path = write_grid(tmp_path / "vel.vdb", make)
    out = tmp_path / "o.png"
    code, _, err = run(capsys, "render", path, "-o", out, *SMALL, "--grid", "velocity")
    assert_clean_failure(code, err, out, "velocity", "vec3s")


def test_empty_grid(tmp_path, capsys):
    path = write_grid(tmp_path / "empty.vdb", lambda vdb: float_grid(vdb, np.zeros((4, 4, 4))))
    out = tmp_path / "o.png"
    code, _, err = run(capsys, "render", path, "-o", out, *SMALL)
    assert_clean_failure(code, err, out, "empty.vdb", "empty", "0 active voxels")


def test_nan_voxels_render_with_a_warning(tmp_path, capsys):
    def make(vdb):
        g = float_grid(vdb, np.ones((6, 6, 6)))
        acc = g.getAccessor()         # copyFromArray would skip NaN values
        acc.setValueOn((2, 3, 1), float("nan"))
        acc.setValueOn((4, 1, 1), float("inf"))
        return g
    path = write_grid(tmp_path / "nan.vdb", make)
    out = tmp_path / "o.npy"
    proc = subprocess.run([sys.executable, "-m", "volrender", "render", str(path), "-o", str(out),
                           *SMALL], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    warn = [l for l in proc.stderr.splitlines() if l.startswith("volrender: warning:")]
    assert len(warn) == 1 and "2 NaN/Inf voxels" in warn[0]
    assert np.all(np.isfinite(np.load(out)))


@pytest.mark.parametrize("target", ["a_file/o.png", "is_a_dir", "o.tiff"])
def test_bad_output_path_fails_before_rendering(tmp_path, capsys, target):
    """(A missing folder is made at the write, issue 37; a file in its way is refused.)"""
    (tmp_path / "is_a_dir").mkdir()
    (tmp_path / "a_file").write_text("x")
    out = tmp_path / target
    code, _, err = run(capsys, "render", DEMO, "-o", out, *SMALL)
    assert code == 2 and err.startswith("volrender: error: ") and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_failed_render_leaves_existing_output_untouched(tmp_path, capsys):
    out = tmp_path / "keep.png"
    out.write_bytes(b"precious")
    code, _, err = run(capsys, "render", DEMO, "-o", out, *SMALL, "--grid", "nope")
    assert code == 2 and out.read_bytes() == b"precious"


@pytest.mark.parametrize("args, words", [
    (["--albedo", "1.5"], ["albedo"]),
    (["--fov", "0"], ["fov"]),
    (["--up", "0,0,1", "--origin", "0,0,5", "--target", "0,0,0"], ["parallel"]),
    (["--device", "no-such-device"], ["no-such-device", "pick one of"]),
])
def test_bad_settings(tmp_path, capsys, args, words):
    out = tmp_path / "o.png"
    code, _, err = run(capsys, "render", DEMO, "-o", out, *SMALL, *args)
    assert_clean_failure(code, err, out, *words)


def test_installed_entry_point_reports_errors_without_traceback(tmp_path):
    """The real process: exit status and stderr as a user sees them."""
    out = tmp_path / "o.png"
    proc = subprocess.run([sys.executable, "-m", "volrender", "render", str(tmp_path / "x.vdb"),
                           "-o", str(out)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.startswith("volrender: error: ") and "Traceback" not in proc.stderr
    assert not out.exists()


def test_render_point_inputs_and_scene(tmp_path, capsys):
    """A generator, a text file and the bundled scene render through the CLI, and
    command-line options override the scene."""
    xyz = tmp_path / "p.xyz"
    xyz.write_text("0 0 0 0.3\n0.4 0 0 0.3\n0 0.4 0 0.25\n")
    for src, extra in (("blob:300", []), (xyz, ["--blend", "0.1"]),
                       (ROOT / "scenes" / "molten_glass.toml", ["--bounces", "2", "--spp", "1"])):
        out = tmp_path / "g.npy"
        code, _, err = run(capsys, "render", src, "-o", out, *SMALL, *extra)
        assert code == 0, err
        img = np.load(out)
        assert img.shape == (18, 24, 4) and np.all(np.isfinite(img))
        assert 0.0 < img[..., 3].mean() < 1.0          # the glass covers part of the frame


def test_no_tree_matches_tree_through_the_cli(tmp_path, capsys):
    a, b = tmp_path / "a.npy", tmp_path / "b.npy"
    assert run(capsys, "render", "blob:500", "-o", a, *SMALL, "--bounces", "2", "--accel", "tree")[0] == 0
    assert run(capsys, "render", "blob:500", "-o", b, *SMALL, "--bounces", "2", "--no-tree")[0] == 0
    np.testing.assert_allclose(np.load(a), np.load(b), atol=2e-3)


@pytest.mark.parametrize("src, args, words", [
    ("blob:abc", [], ["blob:abc"]),
    ("teapot:100", [], ["unsupported", "glass_gather"]),
    ("blob:100", ["--ior", "0"], ["ior"]),
    ("blob:100", ["--aov", "depth"], ["volumes only"]),
])
def test_bad_point_inputs(tmp_path, capsys, src, args, words):
    out = tmp_path / "o.png"
    code, _, err = run(capsys, "render", src, "-o", out, *SMALL, *args)
    assert_clean_failure(code, err, out, *words)


def test_tree_command_screenshot_and_export(tmp_path, capsys):
    shot, vtm = tmp_path / "t.png", tmp_path / "t.vtm"
    code, _, err = run(capsys, "tree", "blob:400", "--screenshot", shot, "--export", vtm,
                       "--max-depth", "3", "--window-size", "320x240")
    assert code == 0, err
    assert shot.stat().st_size > 1000 and vtm.exists()
    code, _, err = run(capsys, "tree", DEMO, "--screenshot", tmp_path / "b.png", "--window-size", "320x240")
    assert code == 0, err
    code, _, err = run(capsys, "tree", "blob:400", "--depth", "99", "--screenshot", tmp_path / "x.png")
    assert code == 2 and "depth" in err and "Traceback" not in err


def test_the_cli_and_the_api_render_on_the_test_device(cl_device, capsys, tmp_path):
    """Renders given no device (cli.main, volrender.render, a subprocess) use the suite's
    device, $VOLRENDER_TEST_DEVICE (conftest points $VOLRENDER_DEVICE at it), not PoCL
    whatever the run: a GPU run of the suite is one throughout."""
    import volrender
    code, _, err = run(capsys, "render", "blob:30", "-o", tmp_path / "a.npy", *SMALL)
    assert code == 0 and err.strip().endswith(f"on {cl_device.name}"), err
    img = volrender.render(volrender.load_scene("blob:30", size=(6, 4)))
    assert img.device == cl_device.name
    proc = subprocess.run([sys.executable, "-m", "volrender", "render", "blob:30", "-o",
                           str(tmp_path / "b.npy"), *SMALL], capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stderr.strip().endswith(f"on {cl_device.name}"), proc.stderr
