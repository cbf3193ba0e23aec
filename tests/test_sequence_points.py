"""Point-cloud sequences: one camera framing every frame's cloud, one radius and blend
from the first frame, 2 Dask workers giving the serial bytes, a malformed frame that fails
alone with its number, and --skip-existing resuming."""
import json

import numpy as np
import pytest

import volrender
from volrender import cli, generators

SIZE = (32, 24)


@pytest.fixture(scope="module")
def cloud_frames(tmp_path_factory):
    """Four .npy frames of a scan-like cloud (no radii) moving right across the frame."""
    d = tmp_path_factory.mktemp("points")
    base = generators.blob(600, seed=4).centers
    for f in range(1, 5):
        np.save(d / f"p_{f:04d}.npy", (base + [0.8 * f, 0.0, 0.0]).astype(np.float32))
    return d


def _render(src, out, **kw):
    out.mkdir(exist_ok=True)
    return volrender.render_sequence(str(src / "p_####.npy"), str(out / "g_####.exr"),
                                     frames="1-4", size=SIZE, bounces=2, **kw)


def test_point_sequence_is_one_camera_and_one_blend(cloud_frames, tmp_path):
    notes = []
    r = _render(cloud_frames, tmp_path / "a", workers=0, say=notes.append)
    assert [rec.status for rec in r.records] == ["ok"] * 4
    assert any("blend" in n for n in notes) and any("radius" in n for n in notes)
    assert set(r.options) == {"radius", "blend"} and r.options["blend"] > 0
    rec = json.loads(r.record_path.read_text())
    assert all(f["build_s"] >= 0 and f["kernel_s"] > 0 for f in rec["frames"])
    # the camera frames the union: the cloud moves right, so its image moves right
    cols = []
    for f in range(1, 5):
        a = volrender.image.read_image(tmp_path / "a" / f"g_{f:04d}.exr")[..., 3]
        cols.append((a.sum(0) * np.arange(SIZE[0])).sum() / a.sum())
    assert np.all(np.diff(cols) > 2) and cols[0] < SIZE[0] / 2 < cols[-1]
    # every frame has the first frame's radius and blend: frame 4 rendered alone with
    # them and this camera is the same image
    c = r.camera
    one = volrender.load_scene(str(cloud_frames / "p_0004.npy"), size=SIZE, bounces=2,
                               origin=tuple(c.origin), target=tuple(c.target), up=tuple(c.up),
                               fov=c.fov, **r.options)
    np.testing.assert_array_equal(volrender.render(one).rgba,
                                  volrender.image.read_image(tmp_path / "a" / "g_0004.exr"))


def test_point_sequence_on_dask_is_the_serial_bytes(cloud_frames, tmp_path, client):
    _render(cloud_frames, tmp_path / "s", workers=0)
    r = _render(cloud_frames, tmp_path / "d", client=client)
    assert r.workers == 2 and not r.failed
    for f in range(1, 5):
        name = f"g_{f:04d}.exr"
        assert (tmp_path / "s" / name).read_bytes() == (tmp_path / "d" / name).read_bytes(), f


def test_a_malformed_frame_fails_alone_and_skip_existing_resumes(cloud_frames, tmp_path,
                                                                capsys):
    src = tmp_path / "src"
    src.mkdir()
    for f in range(1, 5):
        (src / f"p_{f:04d}.npy").write_bytes((cloud_frames / f"p_{f:04d}.npy").read_bytes())
    (src / "p_0003.npy").write_bytes(b"\x93NUMPY garbage")
    out = tmp_path / "o"
    out.mkdir()
    code = cli.main(["render", str(src / "p_####.npy"), "-o", str(out / "g_####.png"),
                     "--frames", "1-4", "--size", "32x24", "--bounces", "2", "--workers", "0"])
    err = capsys.readouterr().err
    assert code == 2 and "frame 3" in err and "Traceback" not in err
    assert sorted(p.name for p in out.iterdir() if p.suffix == ".png") == \
        ["g_0001.png", "g_0002.png", "g_0004.png"]
    before = {p.name: p.stat().st_mtime_ns for p in out.glob("*.png")}
    np.save(src / "p_0003.npy", np.load(cloud_frames / "p_0003.npy"))
    code = cli.main(["render", str(src / "p_####.npy"), "-o", str(out / "g_####.png"),
                     "--frames", "1-4", "--size", "32x24", "--bounces", "2", "--workers", "0",
                     "--skip-existing"])
    assert code == 0
    assert {p.name: p.stat().st_mtime_ns for p in out.glob("*.png") if p.name in before} == before
    assert (out / "g_0003.png").is_file()


def test_sequences_as_users_type_them(cloud_frames, tmp_path, capsys):
    """An unquoted glob (the shell's list of files), a #### pattern without --frames (the
    frames on disk), an output folder that does not exist yet, and a record that says what
    ran and keeps the first run's rows when a second one resumes."""
    files = sorted(str(p) for p in cloud_frames.glob("p_*.npy"))
    out = tmp_path / "new" / "folder"
    code = cli.main(["render", *files, "-o", str(out / "g_####.png"), "--size", "24x18",
                     "--bounces", "1", "--workers", "0"])
    assert code == 0, capsys.readouterr().err
    assert sorted(p.name for p in out.glob("*.png")) == [f"g_{f:04d}.png" for f in range(1, 5)]
    rec = json.loads((out / "g.sequence.json").read_text())
    assert rec["argv"] and rec["version"] and rec["date"] and rec["camera"]["fov"] > 0
    assert rec["settings"]["bounces"] == 1 and set(rec["options"]) == {"radius", "blend"}
    first = {r["frame"]: r["seconds"] for r in rec["frames"]}
    (out / "g_0002.png").unlink()
    code = cli.main(["render", str(cloud_frames / "p_####.npy"), "-o", str(out / "g_####.png"),
                     "--size", "24x18", "--bounces", "1", "--workers", "0", "--skip-existing"])
    assert code == 0
    rec = json.loads((out / "g.sequence.json").read_text())
    by_frame = {r["frame"]: r for r in rec["frames"]}
    assert rec["runs"] == 2 and sorted(by_frame) == [1, 2, 3, 4]
    assert by_frame[2]["status"] == "ok" and not by_frame[2].get("from_earlier_run")
    for f in (1, 3, 4):           # skipped now: the first run's rows, kept
        assert by_frame[f]["from_earlier_run"] and by_frame[f]["seconds"] == first[f]


def test_a_pipelined_point_sequence_is_the_bytes_of_one_frame_after_another(cloud_frames,
                                                                            tmp_path):
    """workers=0 builds frame n+1's acceleration on the device's second queue while frame
    n launches (pipeline.run_frames, render.prepare): every frame's file is the one a
    render of that frame alone (sequence.render_chunk) writes."""
    from volrender import sequence
    r = _render(cloud_frames, tmp_path / "p", workers=0)
    assert [rec.status for rec in r.records] == ["ok"] * 4
    c = r.camera
    kw = {"size": SIZE, "bounces": 2, **r.options, **sequence.camera_overrides(c)}
    one = tmp_path / "one"
    one.mkdir()
    for f in range(1, 5):
        rec, = sequence.render_chunk([(f, cloud_frames / f"p_{f:04d}.npy",
                                       one / f"g_{f:04d}.exr")], kw, {})
        assert rec.status == "ok"
        assert (one / f"g_{f:04d}.exr").read_bytes() == \
            (tmp_path / "p" / f"g_{f:04d}.exr").read_bytes(), f
