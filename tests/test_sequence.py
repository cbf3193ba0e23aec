"""Frame sequences: patterns, one camera, Dask workers giving the serial bytes, failures
that lose nothing, a worker killed mid-run, resuming."""
import json

import numpy as np
import pytest

import volrender
from volrender import cli, image, sequence, vdb
from volrender.bricks import Bricks
from volrender.errors import UserError
from volrender.frame_record import FrameRecord, FrameStatus
from volrender.render_info import RenderInfo
from conftest import ROOT

DEMO = ROOT / "scenes" / "demo_cloud.vdb"
SIZE = (40, 30)


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """Six .npz frames of the demo cloud drifting right and up (different transforms)."""
    d = tmp_path_factory.mktemp("frames")
    b = vdb.load_volume(DEMO)
    for f in range(1, 7):
        m = b.index_to_world.copy()
        m[:3, 3] += [0.2 * f, 0.08 * f, 0.0]
        Bricks(b.origin, b.dims, b.table, b.data, b.majorant, m,
                   grid_name=b.grid_name).save_npz(d / f"cloud_{f:04d}.npz")
    return d


def _render(frames, out, **kw):
    out.mkdir(exist_ok=True)
    return volrender.render_sequence(str(frames / "cloud_####.npz"), str(out / "f_####.exr"),
                                     frames="1-6", size=SIZE, density_scale=5.0, **kw)


@pytest.fixture(scope="module")
def serial(frames, tmp_path_factory):
    out = tmp_path_factory.mktemp("serial")
    r = _render(frames, out, workers=0)
    assert [rec.status for rec in r.records] == ["ok"] * 6
    return out


def _same_files(a, b):
    for f in range(1, 7):
        assert (a / f"f_{f:04d}.exr").read_bytes() == (b / f"f_{f:04d}.exr").read_bytes(), f


def test_serial_frames_share_one_camera_framing_the_union(frames, serial):
    import OpenEXR
    heads = [OpenEXR.File(str(serial / f"f_{f:04d}.exr")).header() for f in range(1, 7)]
    for h in heads[1:]:
        for k in ("volrender:origin", "volrender:target", "volrender:fov"):
            np.testing.assert_array_equal(h[k], heads[0][k])
    # the camera fits the union of every frame's bounds: centred, 0.9 of the smaller side
    boxes = [vdb.load_volume(frames / f"cloud_{f:04d}.npz").world_bounds() for f in range(1, 7)]
    lo = np.min([b[0] for b in boxes], axis=0)
    hi = np.max([b[1] for b in boxes], axis=0)
    from volrender.camera import Camera
    cam = Camera(*(tuple(map(float, heads[0][f"volrender:{k}"])) for k in ("origin", "target", "up")),
                 float(heads[0]["volrender:fov"]), *image.read_image(serial / "f_0001.exr").shape[1::-1])
    f, r, u = cam.basis()
    d = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                  for z in (lo[2], hi[2])]) - np.asarray(cam.origin)
    k = cam.height / (2.0 * np.tan(np.radians(cam.fov) / 2.0))
    px, py = k * (d @ r) / (d @ f), k * (d @ u) / (d @ f)
    assert abs(px.min() + px.max()) < 0.05 and abs(py.min() + py.max()) < 0.05
    side = max(np.ptp(px), np.ptp(py)) / min(cam.width, cam.height)
    assert side == pytest.approx(0.9, rel=1e-3)
    # and the cloud moves in the picture: frames differ
    a, b = (image.read_image(serial / f"f_{f:04d}.exr") for f in (1, 6))
    assert np.abs(a - b).max() > 0.1
    rec = json.loads((serial / "f.sequence.json").read_text())
    assert [r["frame"] for r in rec["frames"]] == list(range(1, 7)) and rec["failed"] == []
    assert all(r["status"] == "ok" and r["seconds"] > 0 for r in rec["frames"])


def test_two_dask_workers_give_the_serial_bytes(frames, serial, client, tmp_path):
    r = _render(frames, tmp_path, client=client, chunk=2)
    assert r.workers == 2 and not r.failed
    assert {rec.worker for rec in r.records} <= {"0", "1"}
    _same_files(serial, tmp_path)


def test_a_killed_worker_has_its_frames_retried(frames, serial, client, tmp_path):
    marker = tmp_path / "killed-once"
    client.run(sequence.set_env, sequence.KILL_HOOK, str(marker))
    try:
        r = _render(frames, tmp_path / "out", client=client, chunk=1)
    finally:
        client.run(sequence.set_env, sequence.KILL_HOOK, None)
    assert marker.exists()                      # a worker really died on its first task
    assert not r.failed and len(r.records) == 6
    _same_files(serial, tmp_path / "out")
    assert not [p for p in (tmp_path / "out").iterdir() if ".tmp" in p.name]


def test_a_truncated_frame_fails_alone(frames, tmp_path, capsys):
    src = tmp_path / "in"
    src.mkdir()
    for f in range(1, 5):
        data = DEMO.read_bytes()
        (src / f"v_{f:04d}.vdb").write_bytes(data if f != 3 else data[: len(data) // 2])
    out = tmp_path / "out"
    out.mkdir()
    code = cli.main(["render", str(src / "v_####.vdb"), "--frames", "1-4", "-o",
                     str(out / "v_####.png"), "--size", "24x18", "--workers", "0", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2
    assert "frame 3" in err and "v_0003.vdb" in err and "frames failed: 3" in err
    assert sorted(p.name for p in out.glob("*.png")) == ["v_0001.png", "v_0002.png", "v_0004.png"]


def test_skip_existing_renders_only_the_missing_frames(frames, serial, tmp_path):
    out = tmp_path / "resume"
    out.mkdir()
    for f in (1, 2, 5):
        (out / f"f_{f:04d}.exr").write_bytes((serial / f"f_{f:04d}.exr").read_bytes())
    before = {f: (out / f"f_{f:04d}.exr").stat().st_mtime_ns for f in (1, 2, 5)}
    r = _render(frames, out, workers=0, skip_existing=True)
    status = {rec.frame: rec.status for rec in r.records}
    assert status == {1: "skipped", 2: "skipped", 3: "ok", 4: "ok", 5: "skipped", 6: "ok"}
    assert before == {f: (out / f"f_{f:04d}.exr").stat().st_mtime_ns for f in (1, 2, 5)}
    _same_files(serial, out)


@pytest.mark.parametrize("suffix", [".png", ".exr"])
def test_a_pipelined_sequence_writes_the_bytes_of_one_frame_after_another(frames, tmp_path,
                                                                         suffix, monkeypatch):
    """pipeline.run_frames (the serial path's, its frames written by the writer process,
    frame_writer.py) against render_chunk frame by frame, with a frame that fails (a
    damaged file) among them: the same files, byte for byte, and the same records but
    for the timings."""
    from volrender import frame_writer, pipeline
    monkeypatch.setenv(frame_writer.MODE_ENV, "process")
    (frames.parent / "broken").mkdir(exist_ok=True)
    broken = frames.parent / "broken" / "cloud_0004.npz"
    broken.write_bytes((frames / "cloud_0004.npz").read_bytes()[:300])
    kw = {"size": SIZE, "density_scale": 5.0}
    camera = sequence.sequence_camera({f: frames / f"cloud_{f:04d}.npz" for f in range(1, 7)}, kw)[0]
    kw.update(sequence.camera_overrides(camera))
    save = {"exposure": 0.5, "tonemap": "filmic"}
    runs = {}
    for way in ("piped", "one by one"):
        out = tmp_path / way.replace(" ", "_")
        out.mkdir()
        jobs = [(f, broken if f == 4 else frames / f"cloud_{f:04d}.npz", out / f"f_{f:04d}{suffix}")
                for f in range(1, 7)]
        if way == "piped":
            calls = []
            recs = pipeline.run_frames(jobs, kw, save, [], lambda: calls.append(1))
            assert len(calls) == 6
        else:
            recs = [r for job in jobs for r in sequence.render_chunk([job], kw, save)]
        runs[way] = (out, sorted((r.to_json() for r in recs), key=lambda r: r["frame"]))
    (a, ra), (b, rb) = runs["piped"], runs["one by one"]
    assert sorted(p.name for p in a.iterdir()) == sorted(p.name for p in b.iterdir())
    assert len(list(a.iterdir())) == 5
    for f in (1, 2, 3, 5, 6):
        assert (a / f"f_{f:04d}{suffix}").read_bytes() == (b / f"f_{f:04d}{suffix}").read_bytes(), f
    timing = {"seconds", "load_s", "build_s", "setup_s", "kernel_s", "render_s", "write_s"}
    assert [{k: v for k, v in r.items() if k not in timing | {"output"}} for r in ra] == \
        [{k: v for k, v in r.items() if k not in timing | {"output"}} for r in rb]
    assert ra[3]["status"] == "failed" and "cloud_0004.npz" in ra[3]["error"]
    if suffix == ".exr":                                  # frames that show the cloud
        assert all(image.read_image(a / f"f_{f:04d}.exr")[..., 3].max() > 0.5 for f in (1, 6))
    assert all(r["seconds"] >= r["load_s"] + r["render_s"] + r["write_s"] - 1e-6
               for r in ra if r["status"] == "ok")


def test_the_pipeline_overlaps_its_stages_and_launches_in_one_thread(monkeypatch, tmp_path):
    """Frame n's launches run only once frame n+1's load and set-up and frame n-1's write
    have begun (each waits for the other: a pipeline that ran the stages one after another
    would time out here); loads and set-ups (render.prepare, on the device's second queue)
    run in their own thread, writes in theirs, every launch in the calling one."""
    import importlib
    import threading
    import types
    from volrender import pipeline
    render_mod, scene_mod = (importlib.import_module(f"volrender.{m}") for m in ("render", "scene"))
    began = {k: {f: threading.Event() for f in range(1, 6)} for k in ("load", "write")}
    threads = {"load": set(), "prepare": set(), "render": set(), "write": set()}
    prepared = {f: threading.Event() for f in range(1, 6)}

    class Img:
        info, device, kernel_ms = RenderInfo(), "fake", 0.0

        def __init__(self, frame):
            self.frame = frame

        def save(self, out, **kw):
            threads["write"].add(threading.current_thread().name)
            began["write"][self.frame].set()
            assert began["load"][min(self.frame + 2, 5)].wait(20)   # n+1 renders meanwhile
            out = type(tmp_path)(out)
            out.write_text(str(self.frame))

    def load(src, **kw):
        frame = int(str(src)[-1])
        threads["load"].add(threading.current_thread().name)
        began["load"][frame].set()
        return types.SimpleNamespace(frame=frame)

    class Ready:
        def __init__(self, scene, builder):
            self.n, self.builder = scene.frame, builder

        def finish(self):
            threads["render"].add(threading.current_thread().name)
            n = self.n
            assert prepared[n].is_set(), f"frame {n} launched before its set-up"
            assert prepared[min(n + 1, 5)].wait(20), f"frame {n + 1} was not set up"
            if n > 1:
                assert began["write"][n - 1].wait(20), f"frame {n - 1} was not being written"
            return Img(n)

    def prepare(scene, device=None, builder=None):
        threads["prepare"].add(threading.current_thread().name)
        assert builder is not None and builder.queue is not device.queue
        assert builder.context is device.context
        prepared[scene.frame].set()
        return Ready(scene, builder)

    monkeypatch.setattr(scene_mod, "load_scene", load)
    monkeypatch.setattr(render_mod, "prepare", prepare)
    jobs = [(f, f"in_{f}", tmp_path / f"o_{f}") for f in range(1, 6)]
    recs = pipeline.run_frames(jobs, {}, {}, [])
    assert [r.status for r in recs] == ["ok"] * 5
    assert [(tmp_path / f"o_{f}").read_text() for f in range(1, 6)] == [str(f) for f in range(1, 6)]
    assert threads["render"] == {threading.current_thread().name}
    assert threads["load"] == threads["prepare"] and len(threads["write"]) == 1
    assert not (threads["load"] | threads["write"]) & threads["render"]


@pytest.mark.parametrize("text, frame, path", [
    ("a/smoke_####.vdb", 7, "a/smoke_0007.vdb"),
    ("smoke.#.vdb", 12, "smoke.12.vdb"),
    ("smoke_%04d.vdb", 7, "smoke_0007.vdb"),
    ("smoke_%d.vdb", 7, "smoke_7.vdb"),
    ("smoke_%3d.vdb", 7, "smoke_007.vdb"),
])
def test_numbered_patterns(text, frame, path):
    assert sequence.is_pattern(text)
    assert str(sequence.parse_pattern(text).path(frame)) == path


def test_globs_take_the_last_digits(tmp_path):
    for name in ("s2_0003.vdb", "s2_0010.vdb", "s2_x.vdb"):
        (tmp_path / name).write_bytes(b"")
    p = sequence.parse_pattern(str(tmp_path / "s2_*.vdb"))
    assert p.glob and sorted(p.matches()) == [3, 10]


@pytest.mark.parametrize("text, frames", [
    ("1-5", [1, 2, 3, 4, 5]), ("1-9:4", [1, 5, 9]), ("7", [7]), ("1-3,10,2", [1, 2, 3, 10]),
    ("-2-1", [-2, -1, 0, 1]),
])
def test_frame_ranges(text, frames):
    assert sequence.parse_frames(text) == frames


@pytest.mark.parametrize("call, words", [
    (lambda: sequence.parse_frames("5-1"), ["empty"]),
    (lambda: sequence.parse_frames("a-b"), ["A-B"]),
    (lambda: sequence.parse_frames("1-2:0"), ["STEP"]),
    (lambda: sequence.parse_pattern("a_##_##.vdb"), ["2 frame numbers"]),
    (lambda: sequence.parse_pattern("plain.vdb"), ["no frame number"]),
    (lambda: sequence.parse_pattern("o_*.exr", output=True), ["glob"]),
])
def test_bad_patterns_are_one_line_errors(call, words):
    with pytest.raises(UserError) as e:
        call()
    assert "\n" not in str(e.value) and all(w in str(e.value) for w in words)


def test_missing_frames_are_named_before_anything_renders(frames, tmp_path):
    with pytest.raises(UserError, match=r"2 of 8 frames are missing: 7 .*cloud_0007.npz.*, 8 "):
        volrender.render_sequence(str(frames / "cloud_####.npz"), str(tmp_path / "f_####.exr"),
                                  frames="1-8", workers=0)
    assert list(tmp_path.iterdir()) == []


def test_sequence_options_on_one_file_are_an_error(tmp_path, capsys):
    code = cli.main(["render", str(DEMO), "-o", str(tmp_path / "o.png"), "--workers", "2"])
    err = capsys.readouterr().err
    assert code == 2 and "--workers applies to sequences only" in err


def test_frame_records_are_typed_and_their_rows_on_disk_plain_json():
    """A frame's record has a FrameStatus (equal to its string); its row on disk is the
    JSON object of before (the fields that are set, the status a plain string) and reads
    back as the same record; `rec["status"]` of the dict it was still answers, warning."""
    rec = FrameRecord(3, "in_0003.npz", "out_0003.exr", worker="0", pid=7, status="ok",
                      seconds=0.5)
    assert rec.status is FrameStatus.OK and rec.status == "ok" and rec.error is None
    row = rec.to_json()
    assert row == {"frame": 3, "input": "in_0003.npz", "output": "out_0003.exr",
                   "worker": "0", "pid": 7, "status": "ok", "seconds": 0.5}
    assert type(row["status"]) is str and json.loads(json.dumps(row)) == row
    assert FrameRecord.from_json({**row, "from_a_newer_version": 1}) == rec
    with pytest.raises(ValueError):
        FrameRecord(1, "a", "b", status="done")
    with pytest.warns(DeprecationWarning, match=r"record.status"):
        assert rec["status"] == "ok"
    with pytest.warns(DeprecationWarning), pytest.raises(KeyError):
        rec["error"]
    with pytest.warns(DeprecationWarning):
        assert rec.get("error", "none") == "none"
    with pytest.warns(DeprecationWarning, match=r" in record` is deprecated: read record\."):
        assert "status" in rec and "error" not in rec and "nonsense" not in rec
