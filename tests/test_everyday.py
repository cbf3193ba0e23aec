"""Everyday use, round two (issue 37): notebook objects, peers' spellings, framing that
fills, the field's conventions. Tiny scenes made here."""
import io

import numpy as np
import pytest

import volrender
from volrender.errors import UserError

SIZE = (12, 10)


@pytest.fixture(scope="module")
def box():
    g = np.zeros((12, 12, 12), np.float32)
    g[3:9, 3:9, 3:9] = 1.0
    return g


@pytest.fixture(scope="module")
def box_image(box):
    return volrender.render(box, size=SIZE, density_scale=0.5, spp=2)


# ------------------------------------------------------------------ Image in a notebook

def test_image_repr_is_one_line_with_size_spp_device_and_time(box_image):
    text = repr(box_image)
    assert "\n" not in text and len(text) < 200, text
    assert "12x10" in text and "2 spp" in text and box_image.device in text
    assert f"{box_image.seconds:.2f} s" in text and box_image.seconds > 0


def test_image_is_an_array(box_image):
    a = np.asarray(box_image)
    assert a.shape == (10, 12, 4) and a.dtype == np.float32
    assert np.array_equal(a, box_image.rgba)
    assert np.asarray(box_image, dtype=np.float64).dtype == np.float64
    assert float(np.mean(box_image)) == pytest.approx(float(box_image.rgba.mean()), rel=1e-6)


def test_image_to_pil_is_the_png_it_saves(box_image, tmp_path):
    pic = box_image.to_pil()
    assert pic.size == (12, 10) and pic.mode == "RGBA"
    from volrender.image import read_image
    saved = read_image(box_image.save(tmp_path / "b.png"))
    assert np.array_equal(np.asarray(pic), saved)
    assert np.asarray(pic)[..., :3].max() > 0


def test_image_html_shows_the_picture_and_the_timing_line(box_image):
    import base64
    import html
    import re
    text = box_image._repr_html_()
    data = re.search(r'src="data:image/png;base64,([^"]+)"', text).group(1)
    assert base64.b64decode(data) == box_image._repr_png_()
    assert html.escape(repr(box_image)) in text


@pytest.mark.parametrize("kw, field, want", [
    (dict(spp=2.0), "spp", 2), (dict(bounces=np.float64(3.0)), "bounces", 3),
    (dict(size=(16.0, 8.0)), "size", (16, 8))])
def test_integral_floats_are_integers(kw, field, want):
    scene = volrender.load_scene("blob:20", **kw)
    value = (scene.camera.width, scene.camera.height) if field == "size" else \
        getattr(scene.settings, field)
    assert value == want and all(type(v) is int for v in np.atleast_1d(value).tolist())


@pytest.mark.parametrize("kw, words", [(dict(spp=2.5), "spp= must be an integer"),
                                       (dict(size=(16.5, 8)), "size= must be WxH")])
def test_fractional_values_are_still_refused(kw, words):
    with pytest.raises(UserError, match=words):
        volrender.load_scene("blob:20", **kw)


def test_a_scene_file_takes_integral_floats(tmp_path):
    toml = tmp_path / "s.toml"
    toml.write_text('[points]\ngenerator = "blob"\ncount = 20\n[render]\nspp = 3.0\n'
                    'size = [16.0, 8]\n')
    scene = volrender.load_scene(toml)
    assert scene.settings.spp == 3 and (scene.camera.width, scene.camera.height) == (16, 8)
