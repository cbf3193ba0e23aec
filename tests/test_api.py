"""The Python API (load_scene, render, Image), strict options, the camera options, help
texts and `volrender info`: the CLI and Python render the same scene to the same bytes."""
import argparse
import importlib
import sys

import numpy as np
import pytest

import volrender
from volrender import cli, image, vdb
from volrender.bricks import Bricks
from volrender.errors import UserError
from conftest import ROOT

DEMO = ROOT / "scenes" / "demo_cloud.vdb"
GLASS = ROOT / "scenes" / "molten_glass.toml"
SMALL = ["--size", "24x18", "--no-progress"]


def run(capsys, *argv):
    try:
        code = cli.main([str(a) for a in argv])
    except SystemExit as e:                  # usage errors exit from argparse
        code = e.code
    out = capsys.readouterr()
    return code, out.out, out.err


def one_line_error(code, err, *words):
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("volrender: error: "), err
    for w in words:
        assert w in lines[0], (w, err)


def test_package_exports_the_api():
    names = set(dir(volrender))
    assert {"load_scene", "render", "Scene", "Image", "Sun", "PointLight", "UserError"} <= names
    assert set(volrender.__all__) <= names


@pytest.fixture
def xyz(tmp_path):
    p = tmp_path / "pts.xyz"
    rng = np.random.default_rng(3)
    np.savetxt(p, rng.normal(size=(60, 3)) * 0.5)
    return p


@pytest.mark.parametrize("kind", ["vdb", "points", "toml"])
def test_python_reproduces_the_cli_bytes(tmp_path, capsys, xyz, kind):
    src, args, kw = {
        "vdb": (DEMO, ["--density-scale", "3", "--sun=-1,-1,0,4", "--spp", "2"],
                dict(density_scale=3.0, sun=[(-1, -1, 0, 4)], spp=2)),
        "points": (xyz, ["--radius", "0.2", "--bounces", "2"], dict(radius=0.2, bounces=2)),
        "toml": (GLASS, ["--spp", "1", "--bounces", "3"], dict(spp=1, bounces=3)),
    }[kind]
    out = tmp_path / "cli.npy"
    code, _, err = run(capsys, "render", src, "-o", out, *SMALL, *args)
    assert code == 0, err
    img = volrender.render(volrender.load_scene(src, size=(24, 18), **kw))
    assert img.rgba.shape == (18, 24, 4) and img.rgba.dtype == np.float32
    py = tmp_path / "py.npy"
    img.save(py)
    assert py.read_bytes() == out.read_bytes()


def test_bench_renders_the_cli_scene(cl_device):
    """bench error's molten_glass is the scene the CLI renders from the same TOML."""
    sys.path.insert(0, str(ROOT))
    error = importlib.import_module("bench.error")
    name, cloud, cam, lights, settings = error.glass_scenes(20, 16, quick=False)[-1]
    assert name == "molten_glass"
    scene = volrender.load_scene(GLASS, size=(20, 16))
    assert settings == scene.settings and cam == scene.camera and tuple(lights) == scene.lights
    np.testing.assert_array_equal(cloud.centers, scene.content.cloud.centers)


def test_a_volume_scene_file_equals_its_options(tmp_path):
    toml = tmp_path / "v.toml"
    toml.write_text(f'[volume]\nfile = "{DEMO}"\ndensity_scale = 2.5\nphase = [0.3]\nstep = 1.0\n'
                    '[render]\nsize = [20, 14]\nspp = 2\n[camera]\nfov = 30\n'
                    '[[lights]]\ntype = "sun"\ndirection = [0, -1, -1]\nirradiance = 5\n')
    a = volrender.render(volrender.load_scene(toml)).rgba
    b = volrender.render(volrender.load_scene(DEMO, density_scale=2.5, phase=(0.3,), step=1.0,
                                              size=(20, 14), spp=2, fov=30,
                                              sun=[(0, -1, -1, 5)])).rgba
    np.testing.assert_array_equal(a, b)
    assert volrender.load_scene(toml).inputs == (toml.resolve(), DEMO.resolve())


# ------------------------------------------------------------------ strict options

@pytest.mark.parametrize("src, args, words", [
    (DEMO, ["--bounces", "8"], ["--bounces", "molten glass", "volume"]),          # glass on a volume
    (DEMO, ["--no-tree"], ["--no-tree", "molten glass"]),
    ("blob:50", ["--emission-grid", "flame"], ["--emission-grid", "volumes only"]),  # volume on points
    ("blob:50", ["--density-scale", "2"], ["--density-scale", "volumes only"]),
    ("blob:50", ["--aov", "depth"], ["--aov", "volumes only"]),
    (DEMO, ["--step", "0"], ["--step", "must be"]),                              # ranges
    (DEMO, ["--tile", "abc"], ["--tile", "WxH"]),                                # types
    (DEMO, ["--fov", "180"], ["--fov"]),
    (DEMO, ["--up-axis", "x"], ["--up-axis"]),
])
def test_an_option_the_input_does_not_read_is_an_error(tmp_path, capsys, src, args, words):
    out = tmp_path / "o.exr"
    code, _, err = run(capsys, "render", src, "-o", out, *SMALL, *args)
    one_line_error(code, err, *words)
    assert not out.exists()


@pytest.mark.parametrize("extra, words", [
    ("[render]\nbounces = 3\n", ["[render].bounces", "molten glass"]),
    ("[material]\nior = 1.4\n", ["[material]"]),
    ("[volume]\nstep = -1\n", ["[volume].step", "must be"]),
])
def test_scene_file_keys_are_named_by_file_and_key(tmp_path, extra, words):
    toml = tmp_path / "s.toml"
    body = f'[volume]\nfile = "{DEMO}"\n'
    if extra.startswith("[volume]"):
        body = f'[volume]\nfile = "{DEMO}"\n' + extra.split("\n", 1)[1]
    else:
        body += extra
    toml.write_text(body)
    with pytest.raises(UserError) as e:
        volrender.load_scene(toml)
    msg = str(e.value)
    assert str(toml) in msg and all(w in msg for w in words), msg


def test_python_overrides_are_checked_too():
    with pytest.raises(UserError, match="unknown option 'bounce'"):
        volrender.load_scene("blob:20", bounce=2)
    # (from Python the message names the keyword, issue 23; the CLI names --bounces)
    with pytest.raises(UserError, match="bounces= applies to molten glass"):
        volrender.load_scene(DEMO, bounces=2)
    # a field's own name works beside the flag's
    assert volrender.load_scene("blob:20", use_tree=False).settings.use_tree is False
    assert volrender.load_scene("blob:20", no_tree=True).settings.use_tree is False


# ------------------------------------------------------------------ camera

def test_camera_round_trip_gives_the_identical_image(tmp_path, capsys):
    cam, a, b = tmp_path / "cam.toml", tmp_path / "a.npy", tmp_path / "b.npy"
    code, _, err = run(capsys, "render", DEMO, "-o", a, *SMALL, "--azimuth", "40", "--elevation",
                       "10", "--fov", "33", "--camera-out", cam)
    assert code == 0, err
    code, _, err = run(capsys, "render", DEMO, "-o", b, "--no-progress", "--camera", cam)
    assert code == 0, err
    assert a.read_bytes() == b.read_bytes()
    # options given beside --camera win over the file
    s = volrender.load_scene(DEMO, camera=cam, fov=20)
    assert s.camera.fov == 20 and (s.camera.width, s.camera.height) == (24, 18)


def test_exr_records_the_camera(tmp_path):
    scene = volrender.load_scene(DEMO, size=(12, 9))
    out = volrender.render(scene).save(tmp_path / "c.exr")
    import OpenEXR
    h = OpenEXR.File(str(out)).header()
    np.testing.assert_allclose(h["volrender:origin"], scene.camera.origin, rtol=1e-6)
    assert h["volrender:fov"] == scene.camera.fov
    # worldToCamera maps the target onto the +z axis in front of the camera
    t = np.array([*scene.camera.target, 1.0]) @ h["worldToCamera"]
    dist = np.linalg.norm(np.subtract(scene.camera.target, scene.camera.origin))
    np.testing.assert_allclose(t[:3], [0, 0, dist], atol=1e-4 * dist)


def _blob():
    n = 20
    i = np.indices((n, 2 * n, n)).astype(np.float64)
    c = np.array([n / 2, n / 3, n / 2])                 # off-centre along the up axis
    return np.clip(1 - np.sqrt(((i - c[:, None, None, None]) ** 2).sum(0)) / 9, 0, None).astype(np.float32)


def test_up_axis_z_on_a_z_up_grid_is_the_y_up_image(cl_device):
    """The same voxels, once Y-up and once turned Z-up (y -> z, z -> -y): with --up-axis
    matching, the default camera and sun turn with the world, so the images agree."""
    values = _blob()
    m = np.diag([0.1, 0.1, 0.1, 1.0])
    turn = np.eye(4)
    turn[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
    y_up = Bricks.from_dense(values, m)
    z_up = Bricks.from_dense(values, turn @ m)
    a = volrender.render(_scene(y_up, "y", "off"), cl_device).rgba
    b = volrender.render(_scene(z_up, "z", "off"), cl_device).rgba
    assert a[..., 3].max() > 0.3
    np.testing.assert_allclose(a, b, atol=2e-5)
    c = volrender.render(_scene(z_up, "y", "off"), cl_device).rgba    # the wrong axis differs
    assert np.abs(a - c).max() > 0.05
    # the light cache's bake (the default since its CPU cost model counts shared nodes once)
    # is not bit-stable under the turn: 1.9e-4 here, the same under a black sky (so in the
    # sun's baked shadows; cause not pinned: the coarse bake march's roundoff suspected),
    # within the cache's own error and far below the wrong axis's 0.05
    a = volrender.render(_scene(y_up, "y", "on"), cl_device).rgba
    b = volrender.render(_scene(z_up, "z", "on"), cl_device).rgba
    np.testing.assert_allclose(a, b, atol=1e-3)


def _scene(bricks, axis, light_cache="auto"):
    from volrender.camera import View
    from volrender.scene import Scene, VolumeContent
    from volrender.volume import VolumeSettings
    from volrender.lights import Sun
    from volrender.camera import up_frame
    frame = up_frame(axis)
    d = np.array([-0.6, -1.0, -0.5])
    sun = Sun(tuple(d if frame is None else frame @ d), 6.0)
    cam = View(size=(32, 24), up_axis=axis).camera(*bricks.world_bounds())
    # ms_octaves: the march (deterministic; auto would pick the path estimator at 32x24)
    return Scene(cam, (sun,), VolumeContent(bricks, VolumeSettings(density_scale=8.0, ms_octaves=4,
                                                                   light_cache=light_cache)))


def test_blender_caches_default_to_z_up(shared_data):
    scene = volrender.load_scene(shared_data / "vdb" / "fluid_data_0056.vdb", size=(8, 6))
    assert scene.camera.up == (0.0, 0.0, 1.0) and any("up axis z" in n for n in scene.notes)
    assert volrender.load_scene(shared_data / "vdb" / "smoke.vdb", size=(8, 6)).camera.up == (0, 1, 0)


# ------------------------------------------------------------------ help

def _actions_without_help(parser, prog):
    out = []
    for act in parser._actions:
        if isinstance(act, argparse._SubParsersAction):
            for name, sub in act.choices.items():
                out += _actions_without_help(sub, f"{prog} {name}")
        elif not isinstance(act, argparse._HelpAction) and not act.help:
            out.append(f"{prog} {act.option_strings or act.dest}")
    return out


def test_every_option_has_help_text(monkeypatch):
    assert _actions_without_help(cli.build_parser(), "volrender") == []
    missing = []

    class Stop(Exception):
        pass

    def capture(self, *a, **k):
        missing.extend(_actions_without_help(self, self.prog))
        raise Stop
    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", capture)
    sys.path.insert(0, str(ROOT))
    for name in cli.BENCHMARKS:
        with pytest.raises(Stop):
            importlib.import_module(f"bench.{name}").main([])
    assert missing == []


def test_render_help_shows_each_default_once(capsys):
    with pytest.raises(SystemExit):
        cli.main(["render", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "(default: 640x480)" in text and "(default: None)" not in text
    assert text.count("(default: 640x480)") == 1


# ------------------------------------------------------------------ info

def test_info_suggests_a_density_scale(capsys, cl_device):
    from volrender import info
    code, out, err = run(capsys, "info", DEMO)
    assert code == 0, err
    assert "index box (-32, 10, -24)..(32, 47, 18)" in out and "31,651 active voxels" in out
    b = vdb.load_volume(DEMO)
    scale = info.suggested_density_scale(b, cl_device)
    assert f"--density-scale {scale:.3g}" in out
    # at the suggested scale the median covered pixel has optical depth TARGET_DEPTH
    scene = volrender.load_scene(DEMO, density_scale=scale, size=(64, 48), no_lights=True,
                                 estimator="march")    # deterministic alpha
    alpha = volrender.render(scene, cl_device).rgba[..., 3]
    tau = -np.log1p(-np.clip(alpha[alpha > 1e-6], 0, 1 - 1e-7))
    assert abs(np.median(tau) - info.TARGET_DEPTH) < 0.02 * info.TARGET_DEPTH


def test_an_empty_render_warns(tmp_path, capsys):
    code, _, err = run(capsys, "render", DEMO, "-o", tmp_path / "e.png", *SMALL,
                       "--density-scale", "1e-9")
    assert code == 0 and "warning: the image is empty" in err and "--density-scale" in err


def test_image_save_writes_every_format(tmp_path):
    img = volrender.render(volrender.load_scene(DEMO, size=(10, 8), aov=["depth", "transmittance"]))
    assert set(img.aovs) == {"depth", "transmittance"}
    np.testing.assert_allclose(img.aovs["transmittance"], 1 - img.rgba[..., 3])
    ch = image.read_exr_channels(img.save(tmp_path / "a.exr"))
    np.testing.assert_array_equal(ch["Z"], np.where(np.isinf(img.aovs["depth"]), image.DEPTH_FAR,
                                                    img.aovs["depth"]))
