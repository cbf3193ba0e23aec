"""The viewer (issue 35): `volrender view` and volrender.view, on tiny scenes.

The render loop (progressive.Session) is driven here without a browser, with its clock in
the test's hands; the server is reached over HTTP and over viser's own websocket protocol
(a minimal client below: camera messages in, background images out)."""
import dataclasses
import io
import math
import os
import shlex
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

import volrender
from volrender import cli
from volrender.progressive import Session, command_line, preview_size

viser = pytest.importorskip("viser", reason="viser is not installed (pip install "
                                            "'volrender[view]'; bash run.sh test installs it)")

ROOT = Path(__file__).resolve().parents[1]
GLASS = "glass_gather:120"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    """A 16^3 ball of density (a .npz brick file: the CLI reads it back)."""
    from volrender.bricks import Bricks
    i = np.arange(16) - 7.5
    r = np.sqrt(i[:, None, None] ** 2 + i[None, :, None] ** 2 + i[None, None, :] ** 2)
    path = tmp_path_factory.mktemp("ball") / "ball.npz"
    Bricks.from_dense(np.clip(6.0 - r, 0, 1).astype(np.float32)).save_npz(path)
    return path


class Clock:
    def __init__(self):
        self.t = 1000.0

    def __call__(self):
        return self.t


def run_still(session):
    """Step a still session until it converges; its frames."""
    frames = []
    while (f := session.step()) is not None:
        frames.append(f)
    return frames


# ------------------------------------------------------------------ the camera file round trip

@pytest.mark.parametrize("kind", ["glass", "volume"])
def test_saved_camera_renders_identically_from_the_cli(kind, ball, tmp_path, monkeypatch):
    """A look found in the viewer (a new camera, a shading change) saved with the button:
    `volrender render` with the saved camera file and the saved command line writes the
    same pixels (PNG) and the same floats (.npy) as the viewer's converged frame."""
    monkeypatch.chdir(tmp_path)
    src = GLASS if kind == "glass" else str(ball)
    knob = {"ior": 1.33} if kind == "glass" else {"density_scale": 3.0}
    scene = volrender.load_scene(src, size=(24, 18), spp=4)
    v = volrender.viewer.Viewer(scene, port=0, save_dir=tmp_path)
    try:
        s = v.session
        run_still(s)
        cam = scene.camera
        origin = np.asarray(cam.target) + 1.3 * (np.asarray(cam.origin) - np.asarray(cam.target))
        s.set_camera(dataclasses.replace(cam, origin=tuple(origin), fov=33.0))
        s.set_options(**knob)
        s.changed_at = -math.inf                      # still at once
        frames = run_still(s)
        assert frames[-1].state == "converged" and frames[-1].spp == 4
        png, cam_file, cmd = v.save(tmp_path / "look")
    finally:
        v.stop()
    assert cam_file.read_text().count("[camera]") == 1
    words = shlex.split(cmd)
    assert words[:3] == ["volrender", "render", src] and "--camera" in words
    assert (tmp_path / "look.sh").read_text().strip().endswith(cmd)
    out = words.index("-o")
    for suffix in (".png", ".npy"):
        argv = words[1:out] + ["-o", str(tmp_path / f"cli{suffix}")]
        assert cli.main(argv) == 0
    from PIL import Image as PILImage
    shown = np.asarray(PILImage.open(png))
    assert np.array_equal(np.asarray(PILImage.open(tmp_path / "cli.png")), shown)
    assert np.array_equal(np.load(tmp_path / "cli.npy"), frames[-1].image.rgba)
    # the camera moved and the knob changed: the CLI's default camera gives another image
    assert cli.main(["render", src, "-o", str(tmp_path / "default.npy"), "--size", "24x18",
                     "--spp", "4"]) == 0
    assert not np.array_equal(np.load(tmp_path / "default.npy"), frames[-1].image.rgba)


def test_command_line_writes_what_auto_resolved(ball):
    """--estimator auto is written as what it chose (and --ms-octaves for the march), the
    camera options give way to the camera file, negative values survive the shell."""
    scene = volrender.load_scene(str(ball), size=(16, 12), azimuth=30.0, sun=[(-1, -1, 0, 3)])
    s = Session(scene)
    line = command_line(s.scene(), "c.toml", "o.png", exposure=-1.5, spp=8)
    words = shlex.split(line)
    est = scene.settings.estimator
    assert f"--estimator={est}" in words and "--spp=8" in words
    if est == "march":
        assert f"--ms-octaves={scene.settings.ms_octaves}" in words
    assert not any(w.startswith("--azimuth") or w.startswith("--size") for w in words)
    assert "--sun=-1.0,-1.0,0.0,3.0" in words and "--exposure=-1.5" in words
    assert cli.build_parser().parse_args(cli.join_negative_values(words[1:])).command == "render"


# ------------------------------------------------------------------ the render loop

def test_moving_previews_then_still_accumulates_towards_the_reference(ball):
    """Moving: a reduced size at one sample. Still: the samples grow, and the mean's error
    against a 1024-spp render (another seed) falls like 1/sqrt(spp) (path estimator:
    Monte Carlo noise throughout)."""
    size, spp = (16, 12), 64
    scene = volrender.load_scene(str(ball), size=size, spp=spp, estimator="path",
                                 density_scale=2.0, denoise="off")
    clock = Clock()
    s = Session(scene, clock=clock, step_s=math.inf)   # the most a step: doubling samples
    s.set_camera(dataclasses.replace(scene.camera, fov=35.0))
    f = s.step()
    assert f.state == "preview" and f.spp == f.target == 1
    w, h = f.image.width, f.image.height
    assert w <= size[0] // 2 and h <= size[1] // 2 and (w, h) == preview_size(size, s.rate)
    assert s.step() is None                            # shown; nothing until it is still
    clock.t += s.still_after
    frames = run_still(s)
    assert [x.state for x in frames[:-1]] == ["progressive"] * (len(frames) - 1)
    assert frames[-1].state == "converged" and frames[-1].spp == spp
    assert [x.spp for x in frames] == [2 ** k for k in range(7)]
    ref = volrender.render(s.scene().replace(spp=1024, seed=99)).rgba[..., :3]
    err = {x.spp: float(np.sqrt(((x.image.rgba[..., :3] - ref) ** 2).mean())) for x in frames}
    n = np.array([k for k in err if k >= 2], float)       # the reference's own noise adds
    e = np.array([err[int(k)] for k in n])                # 1/1024 to each 1/N: negligible
    slope = np.polyfit(np.log(n), np.log(e), 1)[0]
    assert -0.7 < slope < -0.35, (slope, err)
    for k in (2, 4, 8, 16):                    # each x4 of the samples halves the error
        assert 0.3 < err[4 * k] / err[k] < 0.65, (k, err)


def test_a_change_while_still_restarts_and_a_cancelled_step_is_dropped(ball):
    scene = volrender.load_scene(str(ball), size=(16, 12), spp=8, denoise="off")
    clock = Clock()
    s = Session(scene, clock=clock, step_s=1e-9)
    first = s.step()
    assert first.state == "progressive" and first.spp == 1
    s.set_options(albedo=(0.5,))
    assert s.step().state == "preview"
    clock.t += 1.0
    again = s.step()
    assert again.state == "progressive" and again.spp == 1 and again.version == s.version
    # a value out of range: said, and the render goes on with the last options that worked
    s.set_options(albedo=(1.5,))
    assert s.step() is None and "albedo" in s.error and s.options["albedo"] == (0.5,)
    clock.t += 1.0
    assert s.step().state == "progressive" and "albedo" in s.error
    # a change between the launches of a step: the step is dropped, not shown half-done
    acc = s._accum
    assert acc.advance(cancelled=lambda: True) is None


def until(cond, timeout=10.0):
    end = time.monotonic() + timeout
    while not cond() and time.monotonic() < end:
        time.sleep(0.01)
    return cond()


@pytest.mark.parametrize("kind", ["glass", "volume"])
def test_controls_set_the_options_they_name(kind, ball):
    """Each control reaches the session as the option it names (the sun as the CLI's --sun:
    its propagation direction, from the angles of the direction towards it)."""
    from volrender.viewer import Viewer, sun_angles, sun_direction
    src = GLASS if kind == "glass" else str(ball)
    scene = volrender.load_scene(src, size=(16, 12), spp=2)
    v = Viewer(scene, port=0)
    try:
        c = v.controls
        want = ({"IOR": (1.7, "ior", 1.7), "glass model": ("fast", "glass_model", "fast"),
                 "blend": (0.02, "blend", 0.02)} if kind == "glass" else
                {"density scale": (3.5, "density_scale", 3.5), "albedo": (0.4, "albedo", (0.4,)),
                 "estimator": ("path", "estimator", "path")})
        want.update({"samples": (16, "spp", 16), "denoise": (False, "denoise", "off")})
        for label, (value, key, option) in want.items():
            c[label].value = value
            assert until(lambda: v.session.options.get(key) == option), (label, v.session.options)
        c["sun azimuth"].value, c["sun elevation"].value = 30.0, 60.0
        d = sun_direction(30.0, 60.0, None)
        assert until(lambda: np.allclose(v.session.options.get("sun", [(0,) * 4])[0][:3], d))
        from volrender.lights import Sun
        assert sun_angles(Sun(d), None) == pytest.approx((30.0, 60.0))
        assert d[1] < 0                                 # high in the sky: shining down
        version = v.session.version
        c["exposure"].value = 2.0                       # display only: no new render
        assert until(lambda: v.exposure == 2.0) and v.session.version == version
    finally:
        v.stop()


# ------------------------------------------------------------------ scene reuse

def test_camera_and_shading_changes_reuse_the_acceleration():
    scene = volrender.load_scene(GLASS, size=(16, 12), spp=2, denoise="off")
    clock = Clock()
    s = Session(scene, clock=clock, step_s=1e-9)
    run_still(s)
    content = s.scene().content
    assert content.builds == 1
    changes = [dict(ior=1.2), dict(glass_model="fast"), dict(sun=[(0.3, -1.0, 0.2, 4.0)]),
               dict(spp=4), None]
    for change in changes:
        if change is None:
            s.set_camera(dataclasses.replace(s.camera, fov=25.0))
        else:
            s.set_options(**change)
        s.step()                                       # a preview
        clock.t += 1.0
        run_still(s)
        assert s.scene().content.store is content.store
        assert content.builds == 1, change
    s.set_options(blend=0.05)                          # the smooth union's width: rebuilt
    clock.t += 1.0
    run_still(s)
    assert content.builds == 2


def test_volume_changes_reuse_the_uploaded_bricks(ball):
    scene = volrender.load_scene(str(ball), size=(16, 12), spp=2, denoise="off")
    clock = Clock()
    s = Session(scene, clock=clock, step_s=1e-9)
    run_still(s)
    store = s.scene().content.store
    buffers = {k: v for k, v in store.items()          # VolumeContent.buffer's uploads
               if isinstance(k, tuple) and len(k) == 2 and k[1] in ("table", "data")}
    assert len(buffers) == 2
    for change in (dict(density_scale=4.0), dict(albedo=(0.3,)), dict(estimator="march")):
        s.set_options(**change)
        clock.t += 1.0
        run_still(s)
        now = s.scene().content.store
        assert now is store and all(now[k] is b for k, b in buffers.items())


# ------------------------------------------------------------------ the server

def decode_frames(raw: bytes):
    """viser's server-to-client frame (infra._message_producer): [8: inner size][8: zstd
    size][zstd msgpack {messages, binaryBufferLengths}][buffers, 8-byte aligned]. Yields
    (message dict, [buffers])."""
    import msgspec
    import zstandard
    n = int.from_bytes(raw[8:16], "little")
    inner = msgspec.msgpack.decode(zstandard.ZstdDecompressor().decompress(raw[16:16 + n]))
    off, bufs = 16 + n, []
    for length in inner["binaryBufferLengths"]:
        off += (8 - off % 8) % 8
        bufs.append(raw[off:off + length])
        off += length
    for m in inner["messages"]:
        yield m, bufs


def background(ws, shape, timeout=60.0):
    """The next background image of `shape` the server sends, as an array."""
    from PIL import Image as PILImage
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        raw = ws.recv(timeout=end - time.monotonic())
        for m, bufs in decode_frames(raw):
            if m.get("type") == "BackgroundImageMessage" and m.get("rgb_data") is not None:
                data = m["rgb_data"]
                data = bufs[data["__binary_index"]] if isinstance(data, dict) else data
                img = np.asarray(PILImage.open(io.BytesIO(bytes(data))).convert("RGB"))
                if img.shape == shape:
                    return img
    raise AssertionError("no background image")


def camera_message(origin, target, up, fov_deg, w, h):
    import msgspec
    from viser import _messages
    m = _messages.ViewerCameraMessage(wxyz=(1.0, 0.0, 0.0, 0.0), position=tuple(origin),
                                      fov=math.radians(fov_deg), near=0.01, far=1000.0,
                                      image_height=h, image_width=w, look_at=tuple(target),
                                      up_direction=tuple(up))
    return msgspec.msgpack.encode(m.as_serializable_dict())


def test_the_server_serves_the_page_and_streams_frames():
    """GET on the URL returns viser's page; a websocket client speaking viser's protocol
    sends a camera and receives a non-blank frame of the canvas's size; another camera
    gives another frame."""
    from websockets.sync.client import connect
    scene = volrender.load_scene(GLASS, size=(20, 16), spp=2, denoise="off")
    v = volrender.view(scene, port=0, size="canvas")       # 0: a free port, the URL says which
    port = v.port
    try:
        assert v.url == f"http://localhost:{port}/" and port > 0
        with urllib.request.urlopen(v.url, timeout=30) as r:
            assert r.status == 200 and b"viser" in r.read().lower()
        cam = scene.camera
        with connect(f"ws://127.0.0.1:{port}", subprotocols=[f"viser-v{viser.__version__}"],
                     max_size=None) as ws:
            ws.send(camera_message(cam.origin, cam.target, cam.up, cam.fov, 30, 20))
            first = background(ws, (20, 30, 3))          # the still size: the canvas's
            assert first.std() > 1.0
            other = np.asarray(cam.target) + np.array([0.0, 0.0, 1.0]) * np.linalg.norm(
                np.subtract(cam.origin, cam.target))
            ws.send(camera_message(other, cam.target, cam.up, cam.fov, 30, 20))
            frame = background(ws, first.shape)
            while np.abs(frame.astype(int) - first).mean() < 1.0:    # one in flight before
                frame = background(ws, first.shape)
    finally:
        v.stop()
    with pytest.raises(OSError):
        urllib.request.urlopen(v.url, timeout=5)


# ------------------------------------------------------------------ bad input, Ctrl-C

def test_a_busy_port_is_one_line_naming_it_and_the_fix(capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        assert cli.main(["view", GLASS, "--port", str(port)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"port {port}" in err[0] and "--port" in err[0], err


def test_without_viser_the_error_names_the_install(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "viser", None)       # import viser raises ImportError
    assert cli.main(["view", GLASS, "--port", str(free_port())]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install 'volrender[view]'" in err[0] \
        and "bash run.sh setup" in err[0], err


def test_ctrl_c_stops_the_viewer_with_one_line():
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    p = subprocess.Popen([sys.executable, "-m", "volrender", "view", GLASS, "--size", "16x12",
                          "--spp", "2", "--port", "0"], cwd=ROOT, env=env,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        url = p.stdout.readline().strip()
        assert url.startswith("http://localhost:") and url.endswith("/"), p.stderr.read()
        with urllib.request.urlopen(url, timeout=30) as r:
            assert r.status == 200
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 128 + signal.SIGINT, (out, err)
    lines = [l for l in err.splitlines() if l.strip()]
    assert lines[-1] == "volrender: interrupted (SIGINT); no output written", (out, err)
    assert "Traceback" not in err and "viser" not in out, (out, err)


# ------------------------------------------------------------------ a real browser

@pytest.fixture
def browser():
    """Headless Chromium through Selenium (Debian's chromium and chromium-driver; `bash
    run.sh test` installs them where apt works), real time: WebGL in software."""
    import shutil
    webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is not installed")
    from selenium.webdriver.chrome.service import Service
    exe, driver = shutil.which("chromium") or shutil.which("chromium-browser"), \
        shutil.which("chromedriver")
    if not exe or not driver:
        pytest.skip("no chromium and chromedriver here (Debian: apt-get install chromium "
                    "chromium-driver)")
    opts = webdriver.ChromeOptions()
    opts.binary_location = exe
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader",
              "--window-size=800,600", "--force-device-scale-factor=1"):
        opts.add_argument(a)
    try:
        d = webdriver.Chrome(options=opts, service=Service(driver))
    except Exception as exc:                     # a browser that does not start here
        pytest.skip(f"chromium does not start: {str(exc).splitlines()[0]}")
    yield d
    d.quit()


def shown_in(browser, v, camera, timeout=120.0):
    """Wait until the viewer has converged on `camera` (origin, target) sent by the
    browser and the page says so; the frame and a screenshot of the page."""
    from PIL import Image as PILImage
    end = time.monotonic() + timeout
    s = v.session
    while time.monotonic() < end:
        f = s.frame
        if f is not None and f.state == "converged" and f.version == s.version \
                and np.allclose(s.camera.origin, camera[0], atol=1e-6) \
                and np.allclose(s.camera.target, camera[1], atol=1e-6) \
                and "converged:" in browser.page_source:
            shot = np.asarray(PILImage.open(io.BytesIO(browser.get_screenshot_as_png()))
                              .convert("RGB"))
            if f.image.rgba.shape[:2] == shot.shape[:2]:   # (not a frame from before the
                return f, shot                            # browser said its canvas size)
        time.sleep(0.2)
    raise AssertionError(f"not converged on {camera}: {s.frame and s.frame.state}, "
                         f"camera {s.camera.origin}")


def test_in_a_real_browser(browser, tmp_path):
    """Chromium opens the page, sends its camera (the viewer's start, then one from the
    URL), and shows the frames: the converged frame is on screen where no panel covers it
    (8-bit, PNG), it is not blank, another camera gives another frame, and the saved
    camera file reproduces it through the CLI bit for bit."""
    scene = volrender.load_scene(GLASS, size=(64, 48), spp=1, denoise="off",
                                 glass_model="fast")     # the canvas is 800 pixels wide
    v = volrender.view(scene, port=0, size="canvas", save_dir=tmp_path)
    try:
        cam = scene.camera
        browser.get(v.url)
        first, shot = shown_in(browser, v, (cam.origin, cam.target))
        rgb = v.pixels(first)
        assert rgb.shape == shot.shape                   # the canvas: the whole window
        region = (slice(200, 440), slice(20, 450))       # below the notice, left of the panel
        diff = np.abs(shot[region].astype(int) - rgb[region]).max(axis=-1)
        assert np.median(diff) <= 2 and (diff <= 6).mean() > 0.8, np.median(diff)
        assert rgb[region].std() > 5.0
        other = np.asarray(cam.target) + np.array([0.0, 0.3, 1.0]) * np.linalg.norm(
            np.subtract(cam.origin, cam.target))
        q = ",".join
        browser.get(v.url + f"?initialCameraPosition={q(map(repr, other))}"
                            f"&initialCameraLookAt={q(map(repr, cam.target))}")
        second, shot = shown_in(browser, v, (other, cam.target))
        rgb2 = v.pixels(second)
        assert np.abs(rgb2.astype(int) - rgb).mean() > 2.0
        diff = np.abs(shot[region].astype(int) - rgb2[region]).max(axis=-1)
        assert np.median(diff) <= 2 and (diff <= 6).mean() > 0.8
        png, _, cmd = v.save(tmp_path / "browser")
    finally:
        v.stop()
    words = shlex.split(cmd)
    words[words.index("-o") + 1] = str(tmp_path / "cli.npy")
    assert cli.main(words[1:]) == 0
    assert np.array_equal(np.load(tmp_path / "cli.npy"), second.image.rgba)
