"""Everyday use, round two (issue 37): notebook objects, peers' spellings, framing that
fills, the field's conventions. Tiny scenes made here."""

import numpy as np
import pytest

import volrender
from volrender.errors import UserError

SIZE = (12, 10)


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


# ------------------------------------------------------------------ framing that fills

def alpha_footprint(img, threshold=0.02):
    """The larger side of the box of pixels with alpha above `threshold`, over the image's
    smaller side."""
    a = img.rgba[..., 3] > threshold
    rows, cols = np.nonzero(a.any(axis=1))[0], np.nonzero(a.any(axis=0))[0]
    return max(rows[-1] - rows[0] + 1, cols[-1] - cols[0] + 1) / min(a.shape)


def ball(n=40, radius=15):
    g = np.zeros((n, n, n), np.float32)
    i = np.indices(g.shape) - (n - 1) / 2
    g[(i ** 2).sum(0) < radius ** 2] = 1.0
    return g


@pytest.mark.parametrize("source, kw", [(ball(), dict(density_scale=2.0)),
                                        ("glass_gather:300", dict(bounces=1))],
                         ids=["volume", "points"])
@pytest.mark.parametrize("size", [(80, 60), (48, 64)])
def test_fill_is_the_contents_share_of_the_smaller_side(source, kw, size):
    for fill in (0.9, 0.5):
        img = volrender.render(source, size=size, fill=fill, **kw)
        assert fill - 0.05 <= alpha_footprint(img) <= fill + 0.05, (fill, alpha_footprint(img))
    # the default framing fills 0.9 too, at 40 degrees
    assert 0.85 <= alpha_footprint(volrender.render(source, size=size, **kw)) <= 0.95


def test_real_data_fills_the_frame(shared_data):
    for path, kw in ((shared_data / "points" / "bun_zipper.ply", dict(bounces=1)),
                     (shared_data / "vdb" / "wdas_cloud_sixteenth.vdb", {})):
        img = volrender.render(path, size=(64, 48), **kw)
        assert 0.85 <= alpha_footprint(img) <= 0.95, (path.name, alpha_footprint(img))


# ------------------------------------------------------------------ LAS is Z-up

@pytest.fixture(scope="module")
def terrain(tmp_path_factory):
    """A 200 m x 100 m terrain patch with gentle hills at survey coordinates (UTM-like
    offsets), written with laspy."""
    laspy = pytest.importorskip("laspy")
    x, y = np.meshgrid(np.linspace(0, 200, 41), np.linspace(0, 100, 21))
    z = 120.0 + 3.0 * np.sin(x / 30.0) * np.cos(y / 25.0)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.offsets = [500000.0, 4100000.0, 0.0]
    header.scales = [0.01, 0.01, 0.01]
    las = laspy.LasData(header)
    las.x, las.y, las.z = (500012.5 + x).ravel(), (4100000.25 + y).ravel(), z.ravel()
    path = tmp_path_factory.mktemp("las") / "terrain.las"
    las.write(path)
    return path


def test_a_las_terrain_is_seen_from_above(terrain):
    scene = volrender.load_scene(terrain, size=(64, 48), bounces=1, blend=3.0)
    assert any("up axis z: ASPRS LAS is Z-up" in n and "--up-axis y" in n for n in scene.notes)
    cam = scene.camera
    assert tuple(cam.up) == (0.0, 0.0, 1.0)
    assert cam.origin[2] > 125.0 > cam.target[2]          # above the hills, looking down
    img = volrender.render(scene)
    sky, ground = img.rgba[:4, :, :3].mean(axis=(0, 1)), img.rgba[-4:, :, :3].mean(axis=(0, 1))
    assert sky[2] > 1.1 * sky[0] and ground[0] > ground[2]      # the sky turned with it
    a = img.rgba[..., 3] > 0.5
    rows, cols = np.nonzero(a.any(axis=1))[0], np.nonzero(a.any(axis=0))[0]
    # seen obliquely from 18.7 degrees above: 200 m wide, about 100 sin(18.7) + relief deep
    assert (rows[-1] - rows[0] + 1) / (cols[-1] - cols[0] + 1) < 0.3
    side = volrender.render(terrain, size=(64, 48), bounces=1, blend=3.0, up_axis="y")  # a wall
    a = side.rgba[..., 3] > 0.5
    rows, cols = np.nonzero(a.any(axis=1))[0], np.nonzero(a.any(axis=0))[0]
    assert (rows[-1] - rows[0] + 1) / (cols[-1] - cols[0] + 1) > 0.4


def test_survey_coordinates_keep_their_digits(terrain, tmp_path, capsys):
    from volrender import cli
    assert cli.main(["info", str(terrain)]) == 0
    out = capsys.readouterr().out
    assert "(500012.5, 4100000.25, " in out and "offset 500000, 4100000, 0" in out, out
    assert cli.main(["render", str(terrain), "-o", str(tmp_path / "t.png"), "--size", "16x12",
                     "--bounces", "1", "--no-progress", "-v"]) == 0
    err = capsys.readouterr().err
    line = next(ln for ln in err.splitlines() if "camera origin" in ln)
    target = line.split(" target ")[1].split(" ")[0].split(",")
    assert float(target[0]) == pytest.approx(500112.5, abs=10)
    assert len(target[0].replace(".", "")) > 6             # more than %g's 6 digits
    assert "volrender: up axis z: ASPRS LAS is Z-up" in err


@pytest.mark.filterwarnings("ignore::volrender.errors.ImageWarning")
def test_the_turned_glass_sky_is_the_kernels_sky(cl_device):
    """lights.glass_sky_texels in the y-up frame against cl/glass.h's procedural sky, seen
    past a tiny cloud: the same radiance within the map's bilinear error (the checker's
    edges excepted: the median)."""
    from volrender.environment import Environment
    from volrender.lights import glass_sky_texels
    scene = volrender.load_scene("blob:20", size=(48, 36), bounces=1, fov=90.0,
                                 elevation=-10.0, distance=1e3)
    procedural = volrender.render(scene, cl_device).rgba
    mapped = volrender.render(scene.replace(environment=Environment(glass_sky_texels(np.eye(3)))),
                              cl_device).rgba
    clear = (procedural[..., 3] == 0)
    diff = np.abs(procedural - mapped)[..., :3][clear]
    assert clear.sum() > 1000 and np.median(diff) < 2e-3 and diff.mean() < 0.02, \
        (np.median(diff), diff.mean())


# ------------------------------------------------------------------ view transforms

def srgb_encode(v):
    """IEC 61966-2-1's encoding, written out (the oracle for 'standard')."""
    v = np.asarray(v, np.float64)
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.abs(v) ** (1 / 2.4) - 0.055)


RAMP = np.array([0.0, 0.001, 0.0031308, 0.01, 0.05, 0.18, 0.5, 0.9, 1.0, 2.0, 16.0])


def test_standard_is_the_srgb_encoding_clipped():
    from volrender.image import to_srgb
    rgb = np.stack([RAMP, RAMP * 0.5, RAMP * 0.25], axis=-1)
    want = np.floor(srgb_encode(np.minimum(rgb, 1.0)) * 65535 + 0.5)
    got = to_srgb(rgb, tonemap="standard", bits=16).astype(float)
    assert np.abs(got - want).max() <= 2, np.abs(got - want).max()    # 3e-5 of the range
    # published code values (8 bits): 0.18 -> 118, 0.5 -> 188, 0.0031308 -> 10
    assert to_srgb(np.array([[0.18] * 3, [0.5] * 3, [0.0031308] * 3]), tonemap="standard")[:, 0] \
        .tolist() == [118, 188, 10]


def test_aces_meets_the_documented_curve_at_its_anchors():
    """ACES 1.0 SDR video (RRT + sRGB ODT, dim surround) on greys: the RRT's spline puts
    0.18 at 4.8 nits and the ODT's 48-nit spline maps 0.18 * 2^-6.5 .. 0.18 * 2^6.5 onto
    0.02 .. 48 nits (aces-dev's SegmentedSplineParams); code values are linear
    (Y - 0.02) / (48 - 0.02), raised to the dim-surround 0.9811, sRGB-encoded."""
    from volrender.image import to_srgb
    mid = srgb_encode(((4.8 - 0.02) / (48.0 - 0.02)) ** 0.9811)        # 0.35597
    grey = np.array([[v] * 3 for v in (0.18 * 2 ** -6.5, 0.18, 0.18 * 2 ** 6.5)])
    got = to_srgb(grey, tonemap="aces", bits=16)[:, 0] / 65535.0
    assert got[1] == pytest.approx(float(mid), abs=1e-3)
    assert got[0] == pytest.approx(0.0, abs=1e-3) and got[2] == pytest.approx(1.0, abs=1e-3)
    ramp = to_srgb(np.repeat(RAMP[:, None], 3, axis=1), tonemap="aces", bits=16)[:, 0]
    assert np.all(np.diff(ramp.astype(int)) >= 0) and ramp[-1] > 65000


def test_filmic_is_its_documented_shoulder():
    """volrender's filmic: identity to 0.5, then 0.5 + 0.5 (1 - exp(-(x - 0.5) / 0.5))."""
    from volrender.image import to_srgb
    x = RAMP
    curve = np.where(x <= 0.5, x, 0.5 + 0.5 * (1.0 - np.exp(-(x - 0.5) / 0.5)))
    got = to_srgb(x, tonemap="filmic", bits=16).astype(float)
    assert np.abs(got - np.floor(srgb_encode(curve) * 65535 + 0.5)).max() <= 1


def test_agx_says_where_to_find_it(monkeypatch):
    from volrender.image import _PROCESSORS, to_srgb
    monkeypatch.delenv("OCIO", raising=False)
    _PROCESSORS.pop("agx", None)
    with pytest.raises(UserError, match=r"'agx' is in none of OpenColorIO's built-in configs; "
                                        r"point \$OCIO at"):
        to_srgb(np.zeros((1, 3)), tonemap="agx")


# ------------------------------------------------------------------ a quiet terminal

def test_tree_prints_no_vtk_warnings_nor_colour_codes(tmp_path):
    """`volrender tree` off-screen: VTK's logger at errors only, no ANSI codes into a pipe
    (without a display VTK warned 'bad X server connection' in colour on every call)."""
    import os
    import subprocess
    import sys
    pytest.importorskip("pyvista")
    env = {k: v for k, v in os.environ.items() if k != "DISPLAY"}
    env["TERM"] = "xterm-256color"
    run = subprocess.run([sys.executable, "-m", "volrender", "tree", "blob:50", "--screenshot",
                          str(tmp_path / "t.png"), "--window-size", "48x36"],
                         capture_output=True, text=True, env=env, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "\x1b[" not in run.stderr and "WARN" not in run.stderr, run.stderr
    assert run.stderr.strip().splitlines() == [f"wrote {tmp_path / 't.png'} (tree)"]


# ------------------------------------------------------------------ VFX frame syntax

@pytest.mark.parametrize("text, frame, path", [
    ("a/smoke_@@@@.vdb", 7, "a/smoke_0007.vdb"), ("smoke.@.vdb", 12, "smoke.12.vdb"),
    ("smoke_$F4.vdb", 7, "smoke_0007.vdb"), ("smoke_$F.vdb", 7, "smoke_7.vdb"),
    ("smoke_$F3.vdb", 1234, "smoke_1234.vdb")])
def test_houdini_and_nuke_padding(text, frame, path):
    from volrender import sequence
    assert sequence.is_pattern(text)
    assert str(sequence.parse_pattern(text).path(frame)) == path


def test_a_file_with_at_in_its_name_is_one_file(tmp_path):
    from volrender import sequence
    f = tmp_path / "scan@2x.xyz"
    f.write_text("0 0 0\n")
    assert not sequence.is_pattern(str(f)) and sequence.is_pattern(str(tmp_path / "s_@@.xyz"))
    with pytest.raises(UserError, match="2 frame numbers"):
        sequence.parse_pattern("s_@@_$F4.vdb")


@pytest.mark.parametrize("text, frames", [
    ("1-240x2", list(range(1, 241, 2))), ("1-10x3", [1, 4, 7, 10]), ("1-10:3", [1, 4, 7, 10]),
    ("1-10y3", [2, 3, 5, 6, 8, 9]), ("1-3,20-24x2", [1, 2, 3, 20, 22, 24])])
def test_vfx_frame_ranges(text, frames):
    from volrender import sequence
    assert sequence.parse_frames(text) == frames


def test_a_vfx_pattern_renders_a_sequence(tmp_path, capsys):
    from volrender import cli
    for f in (1, 3, 5):
        np.savetxt(tmp_path / f"p_{f:03d}.xyz", np.random.default_rng(f).normal(size=(20, 3)))
    code = cli.main(["render", str(tmp_path / "p_$F3.xyz"), "-o", str(tmp_path / "o_@@@.npy"),
                     "--frames", "1-5x2", "--size", "8x6", "--workers", "0", "--bounces", "1",
                     "--no-progress"])
    assert code == 0, capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.glob("o_*.npy")) == ["o_001.npy", "o_003.npy", "o_005.npy"]


# ------------------------------------------------------------------ peers' spellings

@pytest.mark.parametrize("word, want", [
    ("res", "size= (vdb_render's -res)"), ("samples", "spp= (vdb_render's -samples)"),
    ("lookat", "target= (vdb_render's -lookat)"), ("translate", "origin= (vdb_render's -translate)"),
    ("pixelsamples", "spp= (pbrt's pixelsamples)"), ("sample_count", "spp= (Mitsuba's sample_count)")])
def test_peers_spellings_in_python(word, want):
    with pytest.raises(UserError, match=f"unknown option '{word}'; did you mean "
                                        + want.replace("(", r"\(").replace(")", r"\)") + r"\?"):
        volrender.load_scene("blob:20", **{word: 1})


def test_peers_spellings_in_scene_files(tmp_path):
    toml = tmp_path / "s.toml"
    toml.write_text('[points]\ngenerator = "blob"\ncount = 20\n[render]\nsamples = 4\n')
    with pytest.raises(UserError, match=r"did you mean \[render\]\.spp \(vdb_render's -samples\)\?"):
        volrender.load_scene(toml)


# ------------------------------------------------------------------ outputs

def test_a_single_image_creates_its_folder(tmp_path, box_image):
    out = box_image.save(tmp_path / "new" / "deeper" / "b.png")
    assert out.is_file() and out.parent.name == "deeper"
    (tmp_path / "file").write_text("x")
    with pytest.raises(UserError, match="does not exist"):       # a file in the way
        box_image.save(tmp_path / "file" / "b.png")


def test_a_nearly_invisible_transparent_png_warns(tmp_path):
    from volrender.errors import ImageWarning
    from volrender.image import write_image
    rgba = np.zeros((4, 4, 4), np.float32)
    rgba[1:3, 1:3] = (2.0, 0.8, 0.1, 0.003)             # fire: light, almost no opacity
    with pytest.warns(ImageWarning, match=r"alpha is at most 0.003 .*drop --transparent"):
        write_image(tmp_path / "f.png", rgba, png_alpha="straight")
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        write_image(tmp_path / "o.png", rgba)                           # opaque: fine
        rgba[1, 1, 3] = 0.5                                              # some opacity
        write_image(tmp_path / "s.png", rgba, png_alpha="straight")


@pytest.mark.parametrize("argv, words", [
    (["rendr", "x.vdb"], "unknown command 'rendr'; did you mean render?"),
    (["render", "blob:20", "-o", "o.png", "-res", "32x24"], "unknown option -res; did you mean --size (vdb_render's -res)?"),
    (["render", "blob:20", "-o", "o.png", "--res", "32x24"], "unknown option --res; did you mean --size (vdb_render's -res)?"),
    (["render", "blob:20", "-o", "o.png", "-samples", "4"], "did you mean --spp (vdb_render's -samples)?"),
    (["render", "blob:20", "-o", "o.png", "-lookat", "0,0,0"], "did you mean --target (vdb_render's -lookat)?"),
    (["render", "blob:20", "-o", "o.png", "-translate", "0,0,5"], "did you mean --origin (vdb_render's -translate)?"),
    (["render", "blob:20", "-o", "o.png", "--pixelsamples", "4"], "did you mean --spp (pbrt's pixelsamples)?"),
    (["render", "blob:20", "-o", "o.png", "--dispatch", "fragmnt"], "did you mean fragment?")])
def test_peers_spellings_on_the_command_line(capsys, tmp_path, argv, words):
    from volrender import cli
    with pytest.raises(SystemExit) as exc:
        cli.main([str(tmp_path / a) if a == "o.png" else a for a in argv])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and words in err and len(err.splitlines()) == 1, err


def test_view_on_the_command_line(tmp_path, capsys):
    from volrender import cli
    from volrender.image import read_image
    base = ["render", "blob:30", "--size", "16x12", "--bounces", "1", "--no-progress"]
    for view in ("filmic", "standard", "aces"):
        assert cli.main([*base, "-o", str(tmp_path / f"{view}.png"), "--view", view]) == 0
    assert cli.main([*base, "-o", str(tmp_path / "old.png"), "--tonemap", "clamp"]) == 0
    px = {v: read_image(tmp_path / f"{v}.png")[..., :3].astype(int) for v in
          ("filmic", "standard", "aces", "old")}
    assert np.abs(px["standard"] - px["old"]).max() <= 1          # clamp: standard's old name
    assert px["aces"].mean() < px["standard"].mean() - 5            # ACES darkens mid-tones
    capsys.readouterr()
    assert cli.main([*base, "-o", str(tmp_path / "new" / "sub" / "one.png")]) == 0   # folders made
    assert (tmp_path / "new" / "sub" / "one.png").is_file()


def test_fire_with_transparent_warns_on_the_command_line(shared_data, tmp_path, capsys):
    from volrender import cli
    code = cli.main(["render", str(shared_data / "vdb" / "fluid_data_0190.vdb"), "-o",
                     str(tmp_path / "f.png"), "--size", "16x12", "--no-progress", "--transparent",
                     "--emission-grid", "density", "--density-scale", "1e-4",
                     "--emission-scale", "50"])
    err = capsys.readouterr().err
    assert code == 0 and "volrender: warning: the transparent PNG's alpha is at most" in err, err
