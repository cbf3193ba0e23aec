"""The sequence pipeline's writer process (volrender/frame_writer.py): it writes the bytes
Image.save writes here, its errors and warnings come back as Image.save raises them, it
outlives a Ctrl-C to its process group, and a pipeline whose writer dies still writes
every frame."""
import dataclasses
import os
import signal
import warnings

import numpy as np
import pytest

import volrender
from volrender import frame_writer, pipeline
from volrender.errors import ImageWarning, UserError
from conftest import ROOT

DEMO = ROOT / "scenes" / "demo_cloud.vdb"
SIZE = (24, 16)


@pytest.fixture(scope="module")
def img():
    return volrender.render(str(DEMO), size=SIZE, density_scale=5.0, spp=2)


@pytest.fixture
def writer():
    w = frame_writer.FrameWriter()
    yield w
    w.close()


def test_the_writer_process_writes_image_saves_bytes(img, writer, tmp_path, monkeypatch):
    """.exr (with the camera in its header) and .png with an exposure: byte for byte what
    Image.save writes in this process; then Image.save fails here, and the process still
    writes (the frames are not written here)."""
    for name, kw in (("a.exr", {}), ("b.png", {"exposure": 0.7, "tonemap": "filmic"})):
        got = writer.save(img, tmp_path / f"p_{name}", kw)
        img.save(tmp_path / f"h_{name}", **kw)
        assert got.name == f"p_{name}"
        assert (tmp_path / f"p_{name}").read_bytes() == (tmp_path / f"h_{name}").read_bytes()
    assert writer.proc.pid != os.getpid()
    monkeypatch.setattr(type(img), "save", lambda *a, **k: 1 / 0)
    writer.save(img, tmp_path / "c.exr", {})
    assert (tmp_path / "c.exr").read_bytes() == (tmp_path / "p_a.exr").read_bytes()


def test_its_errors_and_warnings_come_back_as_image_save_raises_them(img, writer, tmp_path):
    """A bad output: the UserError Image.save raises, word for word, and no file. A
    straight-alpha PNG of light without opacity: its ImageWarning raised here."""
    (tmp_path / "file").write_text("x")
    bad = tmp_path / "file" / "f.png"
    with pytest.raises(UserError) as here:
        img.save(bad)
    with pytest.raises(UserError) as there:
        writer.save(img, bad, {})
    assert str(there.value) == str(here.value)
    rgba = np.zeros((SIZE[1], SIZE[0], 4), np.float32)
    rgba[..., :3] = 1.0                                # light, alpha 0: fire-like
    ghost = dataclasses.replace(img, rgba=rgba, info=img.info.replace(transparent=True))
    with warnings.catch_warnings(record=True) as shown:
        warnings.simplefilter("always")
        writer.save(ghost, tmp_path / "g.png", {})
    assert [w.category for w in shown] == [ImageWarning]
    assert "invisible" in str(shown[0].message)
    assert (tmp_path / "g.png").stat().st_size > 0


def test_small_frames_and_frames_sent_while_it_starts_are_written_here(tmp_path, monkeypatch):
    """A sequence of frames under MIN_PIXELS starts no process (its writes cost less than
    one); a frame sent before the process has said it started is written here."""
    monkeypatch.delenv(frame_writer.MODE_ENV, raising=False)
    n = frame_writer.MIN_PIXELS
    assert not frame_writer.wanted((n // 2 - 1, 2)) and frame_writer.wanted((n // 2, 2))
    assert not frame_writer.wanted(None)
    monkeypatch.setenv(frame_writer.MODE_ENV, "thread")
    assert not frame_writer.wanted((4096, 4096))
    monkeypatch.setenv(frame_writer.MODE_ENV, "process")
    assert frame_writer.wanted((2, 2))
    w = frame_writer.FrameWriter()
    try:
        assert not w.ready()                    # its interpreter is still starting
        assert w.ready(wait=60)
    finally:
        w.close()


def test_it_outlives_ctrl_c_and_exits_when_its_input_closes(img, writer, tmp_path):
    """SIGINT, SIGTERM and SIGHUP to the writer (a terminal's Ctrl-C reaches the process
    group) leave it writing; closing its stdin ends it with status 0."""
    writer.save(img, tmp_path / "a.exr", {})           # started, its handlers set
    proc = writer.proc
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        os.kill(proc.pid, sig)
    writer.save(img, tmp_path / "b.exr", {})
    assert proc.poll() is None
    writer.close()
    assert proc.returncode == 0


def test_a_pipeline_whose_writer_dies_writes_every_frame_here(img, tmp_path, monkeypatch):
    """The writer process killed (SIGKILL) after the first frame: that frame and the next
    ones are written in this process, every record ok, the bytes those of Image.save."""
    killed = []

    class Dying(frame_writer.FrameWriter):
        def save(self, img, output, save_kw):
            if len(killed) == 1:
                self.proc.kill()
                self.proc.wait()
            killed.append(output)
            return super().save(img, output, save_kw)

    monkeypatch.setattr(frame_writer, "FrameWriter", Dying)
    monkeypatch.setenv(frame_writer.MODE_ENV, "process")     # small frames: by the process too
    src = tmp_path / "in"
    src.mkdir()
    for f in range(1, 5):
        (src / f"c_{f:04d}.vdb").symlink_to(DEMO)
    jobs = [(f, src / f"c_{f:04d}.vdb", tmp_path / f"o_{f:04d}.exr") for f in range(1, 5)]
    kw = {"size": SIZE, "density_scale": 5.0, "spp": 2}
    recs = pipeline.run_frames(jobs, kw, {}, [])
    assert [r.status for r in recs] == ["ok"] * 4 and len(killed) == 2     # then: here
    img.save(tmp_path / "here.exr")
    for f in range(1, 5):
        assert (tmp_path / f"o_{f:04d}.exr").read_bytes() == (tmp_path / "here.exr").read_bytes()
