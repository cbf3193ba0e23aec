"""Python that feels native (issue 23): each item as a user hits it, on tiny scenes made
here (a 12^3 box of density, a few dozen points)."""
import io
import subprocess
import sys
import warnings

import numpy as np
import pytest

import volrender
from volrender import cli
from volrender.errors import ImageWarning, MissingFileError, UserError

SIZE = (12, 10)


@pytest.fixture(scope="module")
def points():
    return np.random.default_rng(1).normal(size=(40, 3))


@pytest.fixture
def xyz(tmp_path, points):
    p = tmp_path / "pts.xyz"
    np.savetxt(p, points)
    return p


# ------------------------------------------------------------------ values as Python writes them

def test_a_scalar_means_grey_where_a_vector_takes_one_value(box):
    s = volrender.load_scene(box, albedo=0.9, background=0.25, env=0.5, size=SIZE)
    assert s.settings.env == (0.5, 0.5, 0.5)
    assert s.settings.albedo == volrender.load_scene(box, albedo=(0.9,), size=SIZE).settings.albedo
    assert np.allclose(s.settings.albedo, 0.9) and np.allclose(s.settings.background, 0.25)
    with pytest.raises(UserError, match="origin= "):     # a position takes no single value
        volrender.load_scene(box, origin=3.0)


def test_size_as_a_tuple_a_list_or_wxh(box):
    for size in ((20, 8), [20, 8], "20x8", np.array([20, 8])):
        cam = volrender.load_scene(box, size=size).camera
        assert (cam.width, cam.height) == (20, 8), size
    with pytest.raises(UserError, match="size"):
        volrender.load_scene(box, size="20 by 8")


def test_one_sun_as_one_tuple(box):
    one = volrender.load_scene(box, sun=(0, -1, 0, 2), size=SIZE).lights
    many = volrender.load_scene(box, sun=[(0, -1, 0, 2)], size=SIZE).lights
    assert one == many and len(one) == 1 and one[0].irradiance == 2.0
    with pytest.raises(UserError, match=r"sun= takes 4 finite numbers"):
        volrender.load_scene(box, sun=(0, -1, 0))


# ------------------------------------------------------------------ sources

def test_render_takes_a_path_and_keywords(xyz):
    img = volrender.render(xyz, size=SIZE, radius=0.3)
    ref = volrender.render(volrender.load_scene(xyz, size=SIZE, radius=0.3))
    assert img.rgba.shape == (10, 12, 4) and np.array_equal(img.rgba, ref.rgba)
    assert np.array_equal(volrender.render(str(xyz), size=SIZE, radius=0.3).rgba, ref.rgba)
    with pytest.raises(UserError, match="render\\(\\) takes a Scene"):
        volrender.render(42)


def test_numpy_arrays_are_sources(box, points):
    vol = volrender.render(box, size=SIZE, density_scale=0.5)
    assert vol.rgba[..., 3].max() > 0.5                    # the box is seen
    cloud = volrender.load_scene(points, size=SIZE)
    assert cloud.kind == "glass" and len(cloud.content.cloud.centers) == 40
    radii = volrender.load_scene(np.c_[points, np.full(40, 0.25)], size=SIZE)
    assert np.all(radii.content.cloud.radii == 0.25)
    assert volrender.render(radii).rgba[..., 3].max() > 0.5
    with pytest.raises(UserError, match=r"got shape \(3, 5\)"):
        volrender.load_scene(np.zeros((3, 5)))
    with pytest.raises(UserError, match="NaN"):
        volrender.load_scene(np.array([[0, 0, np.nan]]))


# ------------------------------------------------------------------ Scene.replace

def test_replace_takes_load_scenes_keywords_and_reuses_the_content(xyz, cl_device):
    scene = volrender.load_scene(xyz, size=SIZE, radius=0.3)
    volrender.render(scene, cl_device)
    other = scene.replace(ior=1.2, size="16x12", sun=(0, -1, 0, 3))
    assert other.settings.ior == 1.2 and scene.settings.ior != 1.2
    assert (other.camera.width, other.camera.height) == (16, 12) and len(other.lights) == 1
    assert other.content.cloud is scene.content.cloud
    volrender.render(other, cl_device)
    assert other.content.builds == 1                  # the first render's tree and cells
    fresh = volrender.load_scene(xyz, size="16x12", radius=0.3, ior=1.2, sun=(0, -1, 0, 3))
    assert np.array_equal(volrender.render(other, cl_device).rgba,
                          volrender.render(fresh, cl_device).rgba)
    with pytest.raises(UserError, match="spp= must be"):
        scene.replace(spp=0)
    assert scene.replace(camera=other.camera).camera is other.camera   # fields still work


# ------------------------------------------------------------------ Image

def test_image_has_a_png_repr(box):
    img = volrender.render(box, size=SIZE, density_scale=0.5)
    data = img._repr_png_()
    from PIL import Image as PILImage
    pic = PILImage.open(io.BytesIO(data))
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and pic.size == (12, 10)
    assert np.asarray(pic)[..., :3].max() > 0


def test_image_info_is_a_record_and_the_old_dict_reads_warn(box):
    """Image.info is a RenderInfo read by attribute; `info["spp"]` and `info.get` of the
    dict it was still answer, warning, and a field the render left empty reads as a
    missing key (KeyError, or get's default), as before."""
    img = volrender.render(box, size=SIZE, density_scale=0.5, spp=3, estimator="march")
    info = img.info
    assert info.spp == 3 and info.estimator == "march" and info.launches >= 1
    assert info.passes is None and info.denoised is None
    with pytest.warns(DeprecationWarning, match=r"Image.info.spp"):
        assert info["spp"] == 3
    with pytest.warns(DeprecationWarning):
        assert info.get("estimator") == "march" and info.get("setup_ms", -1) == info.setup_ms
    with pytest.warns(DeprecationWarning):
        assert info.get("passes", "none") == "none" and info.get("nonsense") is None
    with pytest.warns(DeprecationWarning), pytest.raises(KeyError):
        info["stopped"]
    with pytest.warns(DeprecationWarning):
        assert "spp" in info and "stopped" not in info


def test_render_warns_about_an_empty_image(box):
    with pytest.warns(ImageWarning, match="the image is empty.*density_scale="):
        volrender.render(box, size=SIZE, density_scale=1e-9)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        volrender.render(box, size=SIZE, density_scale=0.5)   # a fine image: no warning


def test_the_cli_still_prints_the_warning(tmp_path, capsys, box):
    np.save(tmp_path / "pts.npy", np.zeros((1, 3)))
    code = cli.main(["render", str(tmp_path / "pts.npy"), "-o", str(tmp_path / "o.npy"),
                     "--size", "8x8", "--no-progress", "--origin", "0,0,50", "--target",
                     "0,0,100"])
    err = capsys.readouterr().err
    assert code == 0 and "volrender: warning: the image is empty" in err and "--origin" in err


# ------------------------------------------------------------------ errors

def test_user_errors_are_value_errors_and_missing_files_file_not_found(tmp_path, box):
    with pytest.raises(ValueError):
        volrender.load_scene(box, spp=0)
    with pytest.raises(FileNotFoundError):
        volrender.load_scene(tmp_path / "nope.vdb")
    with pytest.raises(MissingFileError):
        volrender.render(tmp_path / "nope.ply")


def test_python_names_the_keyword_and_the_cli_the_flag(tmp_path, capsys, xyz):
    with pytest.raises(UserError) as exc:
        volrender.load_scene(xyz, spp=0)
    assert str(exc.value).startswith("spp= must be") and "--spp" not in str(exc.value)
    code = cli.main(["render", str(xyz), "-o", str(tmp_path / "o.png"), "--spp", "0"])
    err = capsys.readouterr().err
    assert code == 2 and "volrender: error: --spp must be" in err and "spp=" not in err


def test_close_matches_for_keywords_flags_and_scene_keys(tmp_path, capsys, xyz):
    with pytest.raises(UserError, match=r"unknown option 'spps'; did you mean spp=\?"):
        volrender.load_scene(xyz, spps=2)
    with pytest.raises(SystemExit):
        cli.main(["render", str(xyz), "-o", str(tmp_path / "o.png"), "--spps", "2"])
    err = capsys.readouterr().err
    assert "unknown option --spps; did you mean --spp?" in err and len(err.splitlines()) == 1
    toml = tmp_path / "s.toml"
    toml.write_text(f'[points]\nfile = "{xyz}"\n[material]\niro = 1.3\n')
    with pytest.raises(UserError, match=r"unknown key \[material\]\.iro; did you mean "
                                        r"\[material\]\.ior\?"):
        volrender.load_scene(toml)
    toml.write_text(f'[points]\nfile = "{xyz}"\n[materials]\nior = 1.3\n')
    with pytest.raises(UserError, match=r"did you mean \[material\]\?"):
        volrender.load_scene(toml)


def test_workers_from_a_script_without_the_main_guard(tmp_path, points):
    for i in (1, 2):
        np.savetxt(tmp_path / f"f_{i:04d}.xyz", points + i)
    script = tmp_path / "noguard.py"
    script.write_text("import volrender\n"
                      f"volrender.render_sequence({str(tmp_path / 'f_####.xyz')!r}, "
                      f"{str(tmp_path / 'out' / 'o_####.npy')!r}, workers=1, size=(8, 8))\n")
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    lines = r.stderr.strip().splitlines()
    assert r.returncode != 0 and len(lines) == 1, r.stderr
    assert lines[0].startswith("volrender: error: ") and 'if __name__ == "__main__":' in lines[0]


def test_image_warnings_of_a_large_image_read_a_grid_but_empty_reads_every_pixel():
    """image_problems reads the shares of an image over render.SAMPLED_PIXELS on a regular
    grid over the whole frame (1080p: 40-140 ms -> 4-13 ms a render), but 'empty' on every
    pixel: one covered pixel off the grid is not an empty image."""
    import importlib
    import types
    render_mod = importlib.import_module("volrender.render")
    h, w = 768, 1024                                     # 12x SAMPLED_PIXELS: step 3
    assert h * w > 4 * render_mod.SAMPLED_PIXELS
    rgba = np.zeros((h, w, 4), np.float32)
    rgba[h - 1, w - 2] = (0.5, 0.5, 0.5, 1.0)            # off the grid (row h-1 = 767 % 3 != 0)
    img = types.SimpleNamespace(rgba=rgba)
    assert render_mod.image_problems(img, "glass") == []
    rgba[h - 1, w - 2] = 0.0
    assert "empty" in render_mod.image_problems(img, "glass")[0]
    # the lower 60% of the rows covered and overexposed, the top 40% covered and dim:
    # half the covered pixels above 4 only when the grid reaches the bottom rows
    rgba[:, :, 3] = 1.0
    rgba[: int(0.4 * h), :, :3] = 0.5
    rgba[int(0.4 * h):, :, :3] = 8.0
    assert any("overexposed" in p for p in render_mod.image_problems(img, "glass"))
    rgba[int(0.4 * h):, :, :3] = 2.0
    assert not any("overexposed" in p for p in render_mod.image_problems(img, "glass"))
    # opaque everywhere but a transparent band on the right: the volume warning sees it
    rgba[..., 3] = 1.0
    assert any("silhouette" in p for p in render_mod.image_problems(img, "volume"))
    rgba[:, int(0.9 * w):, 3] = 0.5
    assert not any("silhouette" in p for p in render_mod.image_problems(img, "volume"))
