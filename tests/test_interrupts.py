"""Faults, round three (issue 38), on real processes: signals at any moment of a run and
of a sequence, nonsense numbers refused before any work, resumed sequences that check
what they find, compressed point clouds bounded like the other parsers, and errors that
name the file at fault. docs/robustness.md says what each rule is."""
from __future__ import annotations

import io
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT

PY = sys.executable
SMALL = ["--size", "16x12", "--no-progress"]
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "POCL_MAX_PTHREAD_COUNT": "1"}


def volrender(*args, cwd, timeout=300, **kw):
    return subprocess.run([PY, "-m", "volrender", *map(str, args)], cwd=cwd, env=ENV,
                          capture_output=True, text=True, timeout=timeout, **kw)


def _without_notes(err):
    """stderr without the notes said before the work (`volrender: denoise auto: ...`)."""
    lines = err.splitlines(keepends=True)
    while lines and lines[0].startswith("volrender: ") and not \
            lines[0].startswith(("volrender: error: ", "volrender: interrupted")):
        lines.pop(0)
    return "".join(lines)


def _one_error(r):
    assert r.returncode == 2, r.stderr
    err = _without_notes(r.stderr)
    assert err.startswith("volrender: error: ") and err.count("\n") == 1, r.stderr
    return err


def _frames(folder, n, shape=(12, 10, 8)):
    """n small brick caches c_0001.npz ... (random densities, one seed)."""
    from volrender import vdb
    rng = np.random.default_rng(5)
    for f in range(1, n + 1):
        v = rng.random(shape).astype(np.float32)
        vdb.Bricks.from_dense(v, np.diag([0.1, 0.1, 0.1, 1.0])).save_npz(folder / f"c_{f:04d}.npz")


CAMERA = ["--origin", "0.6,0.5,3", "--target", "0.6,0.5,0.4"]


# ------------------------------------------------------------------ resume checks what it finds

def test_skip_existing_renders_again_a_frame_that_is_cut_short_or_the_wrong_size(tmp_path):
    """A PNG cut short (a copy or a full disk), one of another size and an empty file are
    rendered again and named; a good frame is kept untouched."""
    _frames(tmp_path, 4)
    args = ["render", "c_####.npz", "-o", "f_####.png", "--frames", "1-4", "--workers", "0",
            "--size", "24x18", "--no-progress", *CAMERA]
    r = volrender(*args, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    first = {f: (tmp_path / f"f_{f:04d}.png").read_bytes() for f in range(1, 5)}
    kept = (tmp_path / "f_0001.png").stat().st_mtime_ns
    (tmp_path / "f_0002.png").write_bytes(first[2][:len(first[2]) // 2])
    from PIL import Image
    Image.new("RGB", (8, 6)).save(tmp_path / "f_0003.png")
    (tmp_path / "f_0004.png").write_bytes(b"")
    r = volrender(*args, "--skip-existing", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    for f in (2, 3, 4):
        assert (tmp_path / f"f_{f:04d}.png").read_bytes() == first[f], f
    assert (tmp_path / "f_0001.png").stat().st_mtime_ns == kept
    notes = [line for line in r.stderr.splitlines() if "rendered it again" in line]
    assert len(notes) == 3, r.stderr
    assert "f_0002.png" in notes[0] and "cut short" in notes[0]
    assert "f_0003.png" in notes[1] and "8x6, not 24x18" in notes[1]
    assert "f_0004.png" in notes[2]
    assert "wrote 3 frames (1 skipped" in r.stderr, r.stderr
    rec = json.loads((tmp_path / "f.sequence.json").read_text())
    assert [fr.get("redone") is not None for fr in rec["frames"]] == [False, True, True, True]


def test_an_existing_output_is_checked_whole_for_each_format(tmp_path):
    """sequence.unusable: each format read whole, and its size (the rule --skip-existing uses)."""
    from volrender.image import write_image
    from volrender.sequence import unusable
    rgba = np.random.default_rng(1).random((6, 8, 4)).astype(np.float32)
    for suffix in (".png", ".exr", ".npy"):
        p = write_image(tmp_path / f"a{suffix}", rgba)
        assert unusable(p, (8, 6)) is None, suffix
        assert unusable(p, (8, 7)) == "it is 8x6, not 8x7", suffix
        whole = p.read_bytes()
        for cut in (len(whole) - 1, len(whole) // 2, 10):
            p.write_bytes(whole[:cut])
            assert unusable(p, (8, 6)) is not None, (suffix, cut)


# ------------------------------------------------------------------ the file at fault, limits first

def _huge_maps(folder):
    """An .exr whose header's data window is 200000x100000 (its pixels: 8x4) and an .hdr
    whose resolution line says the same: the header lies, the file is small."""
    import struct
    from volrender.image import write_image
    write_image(folder / "small.exr", np.ones((4, 8, 4), np.float32))
    b = bytearray((folder / "small.exr").read_bytes())
    i = b.index(b"dataWindow\x00box2i\x00") + len(b"dataWindow\x00box2i\x00") + 4
    assert struct.unpack("<4i", b[i:i + 16]) == (0, 0, 7, 3)
    b[i:i + 16] = struct.pack("<4i", 0, 0, 199_999, 99_999)
    (folder / "huge.exr").write_bytes(bytes(b))
    (folder / "huge.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n"
                                      b"-Y 100000 +X 200000\n" + b"\x02\x02" * 64)


def test_an_environment_map_with_absurd_header_dimensions_is_named(tmp_path):
    """Refused from its header, naming the map (not the scene input) and its size."""
    pytest.importorskip("OpenImageIO")
    _huge_maps(tmp_path)
    for name in ("huge.exr", "huge.hdr"):
        err = _one_error(volrender("render", "blob:200", "--env", name, "-o", "o.png", *SMALL,
                                   cwd=tmp_path))
        assert err.startswith(f"volrender: error: {name}: the 200000x100000 environment map "
                              "needs about"), err
        assert "of memory" in err and "blob:200" not in err
    assert not (tmp_path / "o.png").exists()


def test_a_sequence_too_large_for_memory_is_refused_once_before_any_frame_is_read(tmp_path):
    """An image size no frame can have: one line, before the first frame's load (the
    frames here are not even readable: the size is what is said)."""
    for f in (1, 2, 3):
        (tmp_path / f"c_{f:04d}.npz").write_bytes(os.urandom(3000))
    host = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") // 3
    for workers in ("0", "1") if host < 16 << 30 else ("0",):    # Dask: host memory only
        err = _one_error(volrender("render", "c_####.npz", "-o", "f_####.png", "--frames", "1-3",
                                   "--workers", workers, "--size", "32768x32768",
                                   "--no-progress", cwd=tmp_path))
        assert "a 32768x32768 image needs 16.0 GiB of buffers" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"c_{f:04d}.npz" for f in (1, 2, 3)]


# ------------------------------------------------------------------ numbers checked before any work

def test_nonsense_worker_and_chunk_counts_are_refused_before_any_work(tmp_path):
    """`--workers -1` waited forever for a LocalCluster of -1 workers; every count is now
    range-checked first: one line, status 2, no output folder made, no cluster started;
    so are `volrender tree`'s own numbers (checked after the tree was built, before)."""
    _frames(tmp_path, 2)
    for opt, value in (("--workers", "-1"), ("--workers", "100000"), ("--chunk", "0"),
                       ("--chunk", "-3")):
        t0 = time.perf_counter()
        err = _one_error(volrender("render", "c_####.npz", "-o", "out/f_####.png", opt, value,
                                   *SMALL, cwd=tmp_path, timeout=120))
        assert f"{opt} must be an integer in [" in err and f"got {value}" in err, err
        assert time.perf_counter() - t0 < 60
        assert not (tmp_path / "out").exists()
    for opt, value in (("--blend", "-5"), ("--max-depth", "-1"), ("--depth", "-2")):
        # tree: checked before its input is read (it is not even there)
        err = _one_error(volrender("tree", "missing.ply", opt, value, "--screenshot", "t.png",
                                   cwd=tmp_path))
        assert f"{opt} must be a" in err and f"got {value}" in err, err
    from volrender import render_sequence
    with pytest.raises(ValueError, match=r"workers= must be an integer in \[0, 1024\], got -1"):
        render_sequence(str(tmp_path / "c_####.npz"), str(tmp_path / "o_####.png"), workers=-1)


# ------------------------------------------------------------------ compressed point clouds

def _las_file(folder, name, n=2000, compress=True):
    laspy = pytest.importorskip("laspy", reason="laspy is not installed (pip install 'volrender[las]')")
    rng = np.random.default_rng(0)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [0.01] * 3, [0.0] * 3
    las = laspy.LasData(header)
    las.x, las.y, las.z = rng.random(n) * 10, rng.random(n) * 10, rng.random(n) * 10
    las.write(folder / name, do_compress=compress)
    return (folder / name).read_bytes()


def test_damaged_las_and_laz_files_are_one_line_naming_the_file_within_bounds(tmp_path):
    """A LAZ cut short (lazrs raised), a header claiming 788 million variable-length records
    (laspy read them on, growing without end), a LAZ claiming 50 million points in 13 KB,
    an uncompressed file shorter than its point count: one line each, status 2, in
    seconds, under a 2 GB address-space cap."""
    import resource
    import struct
    laz = _las_file(tmp_path, "ok.laz")
    las = _las_file(tmp_path, "ok.las", compress=False)
    (tmp_path / "cut.laz").write_bytes(laz[:len(laz) // 2])
    bomb = bytearray(laz)
    bomb[100:104] = struct.pack("<I", 788_529_153)
    (tmp_path / "vlrs.laz").write_bytes(bytes(bomb))
    (tmp_path / "short.las").write_bytes(las[:-100])
    many = bytearray(laz)
    many[107:111] = struct.pack("<I", 50_000_000)
    (tmp_path / "count.laz").write_bytes(bytes(many))
    expect = {"cut.laz": "not a readable LAZ file (LazrsError",
              "count.laz": "the header says 50000000 points of 34 bytes, more than 4096 times",
              "vlrs.laz": "788529153 variable-length records, more than the",
              "short.las": "the header says 2000 points of 34 bytes, but the file holds"}

    def cap():
        resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))
    for name, words in expect.items():
        t0 = time.perf_counter()
        r = subprocess.run([PY, "-m", "volrender", "render", name, "-o", "o.png", *SMALL],
                           cwd=tmp_path, env=ENV, capture_output=True, text=True, timeout=120,
                           preexec_fn=cap)
        err = _one_error(r)
        assert err.startswith(f"volrender: error: {name}: ") and words in err, err
        assert time.perf_counter() - t0 < 60
    assert not (tmp_path / "o.png").exists()
    r = volrender("render", "ok.laz", "-o", "o.png", *SMALL, cwd=tmp_path)
    assert r.returncode == 0, r.stderr


def test_random_damage_to_a_laz_file_never_escapes_as_a_traceback(tmp_path):
    """1-8 random bytes changed (mostly in the header and VLRs), 40 times, in-process: each
    load gives the cloud or one UserError line (lazrs raised LazrsError on most)."""
    import random
    from volrender.errors import UserError
    from volrender.points import load_points
    laz = _las_file(tmp_path, "ok.laz", n=500)
    rnd = random.Random(2)
    outcomes = []
    for i in range(40):
        b = bytearray(laz)
        for _ in range(rnd.randint(1, 8)):
            j = rnd.randrange(0, 700) if rnd.random() < 0.7 else rnd.randrange(len(b))
            b[j] = rnd.randrange(256)
        p = tmp_path / f"m{i}.laz"
        p.write_bytes(bytes(b))
        try:
            load_points(p)
            outcomes.append("ok")
        except UserError as exc:
            assert str(exc).startswith(f"{p}: ") and "\n" not in str(exc), exc
            outcomes.append("error")
    assert outcomes.count("error") > 20, outcomes


# ------------------------------------------------------------------ interrupted sequences

# the script pip writes for the `volrender` command ([project.scripts])
CONSOLE_SCRIPT = """import re
import sys
from volrender.cli import main
if __name__ == '__main__':
    sys.argv[0] = re.sub(r'(-script\\.pyw|\\.exe)?$', '', sys.argv[0])
    sys.exit(main())
"""


def _stopped_sequence(tmp_path, workers, signum, group):
    """A sequence of 8 frames, stopped by `signum` once its first frame is on disk: sent
    to its process group as a terminal's Ctrl-C is (its Dask workers get it too), through
    the `volrender` command; or to the main process alone as `kill` sends SIGTERM, through
    `python -m volrender`. workers "0 writer": in this process, its frames written by the
    pipeline's writer process (frame_writer.py, which gets the group's Ctrl-C too)."""
    env = ENV
    if workers == "0 writer":
        workers, env = "0", {**ENV, "VOLRENDER_FRAME_WRITER": "process"}
    out = tmp_path / f"out{workers}{signum}{len(env)}"
    out.mkdir()
    (tmp_path / "volrender").write_text(CONSOLE_SCRIPT)
    entry = [str(tmp_path / "volrender")] if group else ["-m", "volrender"]
    p = subprocess.Popen([PY, *entry, "render", "c_####.npz", "-o",
                          f"{out.name}/f_####.png", "--frames", "1-8", "--workers", workers,
                          "--size", "200x150", "--spp", "16", "--no-progress", *CAMERA],
                         cwd=tmp_path, env=env, stderr=subprocess.PIPE, text=True,
                         start_new_session=True)
    t0 = time.time()
    while not list(out.glob("f_*.png")) and p.poll() is None and time.time() - t0 < 240:
        time.sleep(0.02)
    (os.killpg if group else os.kill)(p.pid, signum)
    err = p.communicate(timeout=120)[1]
    return p.returncode, err, out


@pytest.mark.parametrize("workers", ["0", "0 writer", "1"])
def test_a_stopped_sequence_says_which_frames_were_written_and_records_them(tmp_path, workers):
    """Ctrl-C (SIGINT to the group) and SIGTERM (to the main process), serial and on Dask:
    one line naming the frames written and those not, as the files on disk are; status
    128 + signal; the record written, its rows saying the same; no temporary file. (Dask
    workers of the `volrender` command took the start-up handler with the command's argv,
    and each printed 'interrupted ... while starting' as well; workers that got the Ctrl-C
    logged tracebacks of their own.)"""
    pytest.importorskip("distributed")
    _frames(tmp_path, 8)
    for signum, group in ((signal.SIGINT, True), (signal.SIGTERM, False)):
        code, err, out = _stopped_sequence(tmp_path, workers, signum, group)
        assert code == 128 + signum, err
        notes, last = err.splitlines()[:-1], err.splitlines()[-1]   # the notes said first
        assert all(n.startswith("volrender: ") and "interrupted" not in n for n in notes), err
        assert "Traceback" not in err and "ERROR" not in err, err
        err = last + "\n"
        on_disk = sorted(int(p.stem[2:]) for p in out.glob("f_*.png"))
        assert on_disk and on_disk[-1] < 8, on_disk
        from volrender.sequence import _ranges
        rest = [f for f in range(1, 9) if f not in on_disk]
        words = (f"{'frame' if len(on_disk) == 1 else 'frames'} {_ranges(on_disk)} written, "
                 f"{'frame' if len(rest) == 1 else 'frames'} {_ranges(rest)} not; record ")
        assert err.startswith(f"volrender: interrupted ({signal.Signals(signum).name}); {words}"), err
        rec = json.loads((out / "f.sequence.json").read_text())
        assert {r["frame"]: r["status"] for r in rec["frames"]} == \
            {f: "ok" if f in on_disk else "interrupted" for f in range(1, 9)}
        assert [p.name for p in out.iterdir() if ".tmp" in p.name] == []


# ------------------------------------------------------------------ a signal at any moment

def _classify(code, err, signum, wrote):
    """What one interrupted run did: 'line' (volrender's one line and 128 + signal, true
    about the output), 'done' (it had finished: status 0, the status line), or 'python'
    (the interpreter's own start, before volrender's first line: killed by the signal
    before Python took it over, or Python's KeyboardInterrupt with no volrender frame)."""
    name = signal.Signals(signum).name
    # Python's start reported a KeyboardInterrupt and went on (site.py past a .pth line,
    # importlib's lock callback): before volrender's first line, so no volrender frame
    # (Python 3.11 ends the ignored one 'KeyboardInterrupt: ', with an empty message)
    for start, end in (("Error processing line ", r"Remainder of file ignored\n"),
                       ("Exception ignored in", r"KeyboardInterrupt(: )?\n")):
        m = re.search(end, err) if err.startswith(start) else None
        if m:
            head, err = err[:m.start()], err[m.end():]
            assert "volrender/" not in head, head
    err = _without_notes(err)
    if code == 0 and err.startswith("wrote ") and err.count("\n") == 1 and wrote:
        return "done"
    if code == 128 + signum and err.startswith("wrote ") and err.count("\n") == 2:
        err = err.split("\n", 1)[1]         # a signal Python swallowed, said after the command
    if code == 128 + signum and err.count("\n") == 1 and \
            err.startswith(f"volrender: interrupted ({name})"):
        said = "o.png was written before that" in err
        assert said == wrote, (err, wrote)
        return "line"
    if "Fatal Python error: init_" in err:  # the interpreter's own start (init_sys_streams)
        assert "volrender:" not in err and not wrote and code in (1, -signal.SIGABRT), (code, err)
        return "python"
    # Python's default handler tripped before volrender's start-up handler replaced it:
    # the KeyboardInterrupt comes out of that stanza's first lines (__init__'s _start)
    frames = re.findall(r'File "([^"]+)", line \d+, in (\S+)', err)
    ours = [(f, fn) for f, fn in frames if "volrender/" in f]
    starting = bool(ours) and all(f.endswith("volrender/__init__.py") and fn in ("<module>", "_start")
                                  for f, fn in ours)
    assert ("volrender/" not in err or starting) and "volrender:" not in err and not wrote, \
        (code, err)
    assert code in (-signum, 1) and (err == "" or err.rstrip().endswith("KeyboardInterrupt")), \
        (code, err)
    return "python"


def _until_volrender_catches(p, signum, timeout=60.0):
    """perf_counter() when volrender's start-up handler first catches `signum`
    (/proc/PID/status SigCgt), polled every millisecond."""
    end = time.monotonic() + timeout
    while time.monotonic() < end and p.poll() is None:
        try:          # (before the exec, the child shows the parent's handlers)
            status = Path(f"/proc/{p.pid}/status").read_text()
            execed = b"volrender" in Path(f"/proc/{p.pid}/cmdline").read_bytes()
        except OSError:
            break
        caught = next((int(ln.split()[1], 16) for ln in status.splitlines()
                       if ln.startswith("SigCgt:")), 0)
        if execed and caught >> (signum - 1) & 1:
            return time.perf_counter()
        time.sleep(0.001)
    raise AssertionError("volrender's start-up handler never appeared")


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_at_any_moment_is_one_line_and_its_status(tmp_path, signum):
    """Signals at 2.5 ms steps from the exec (interpreter start, the entry point's imports,
    option parsing, the load, the render, the write, the exit): from volrender's first
    line on, the one interrupted line and 128 + signal, saying what was written; before it,
    only Python's own start (docs/robustness.md). It printed KeyboardInterrupt tracebacks
    from volrender's imports (atomic, errors) and, after the command, 'while starting; no
    output written' though the image was there."""
    seen = {"line": 0, "done": 0, "python": 0}
    t0 = time.perf_counter()
    p = subprocess.Popen([PY, "-m", "volrender", "render", "blob:50", "-o", "o.png", *SMALL],
                         cwd=tmp_path, env=ENV, stderr=subprocess.DEVNULL)
    started = _until_volrender_catches(p, signal.SIGTERM) - t0   # its first line ran
    assert p.wait(timeout=300) == 0
    run = time.perf_counter() - t0
    # 2.5 ms steps through Python's start and through volrender's first 150 ms (however
    # long a loaded machine makes the start), then through the load, render and write
    delays = [i * 0.0025 for i in range(40)]
    delays += [max(0.0, started + i * 0.0025) for i in range(-10, 60)]
    delays += [run * f for f in (0.3, 0.5, 0.7, 0.8, 0.9, 0.95, 1.0, 1.05, 1.1)]
    for d in delays:
        (tmp_path / "o.png").unlink(missing_ok=True)
        p = subprocess.Popen([PY, "-m", "volrender", "render", "blob:50", "-o", "o.png", *SMALL],
                             cwd=tmp_path, env=ENV, stderr=subprocess.PIPE, text=True)
        time.sleep(d)
        p.send_signal(signum)
        err = p.communicate(timeout=300)[1]
        try:
            seen[_classify(p.returncode, err, signum, (tmp_path / "o.png").exists())] += 1
        except AssertionError as exc:    # the whole stderr: _classify strips what it knows
            raise AssertionError(f"signal after {d:.4f} s: status {p.returncode}, "
                                 f"stderr {err!r}") from exc
        assert [n for n in os.listdir(tmp_path) if ".tmp" in n] == []
    assert seen["line"] > 50, seen         # most of the steps fell in volrender's part


def test_a_stopped_sequence_from_python_raises_with_the_summary_after_the_record(tmp_path):
    """render_sequence under a script's Ctrl-C: the record written, then
    sequence.Interrupted (a KeyboardInterrupt) whose message names the frames."""
    _frames(tmp_path, 8)
    script = ("import volrender\nvolrender.render_sequence('c_####.npz', 'o/f_####.png', "
              "workers=0, size=(200, 150), spp=16, origin=(0.6, 0.5, 3), "
              "target=(0.6, 0.5, 0.4))\n")
    (tmp_path / "o").mkdir()
    p = subprocess.Popen([PY, "-c", script], cwd=tmp_path, env=ENV, stderr=subprocess.PIPE,
                         text=True)
    t0 = time.time()
    while not list((tmp_path / "o").glob("f_*.png")) and p.poll() is None and time.time() - t0 < 240:
        time.sleep(0.02)
    p.send_signal(signal.SIGINT)
    err = p.communicate(timeout=120)[1]
    last = err.strip().splitlines()[-1]
    assert last.startswith("volrender.sequence.Interrupted: frame"), err
    assert last.endswith("/o/f.sequence.json") and "; record " in last, last
    rec = json.loads((tmp_path / "o" / "f.sequence.json").read_text())
    assert "interrupted" in {r["status"] for r in rec["frames"]}


@pytest.mark.skipif(not Path("/proc/self/status").is_file(), reason="needs Linux's /proc")
def test_dask_workers_keep_sigint_blocked_and_take_sigterm():
    """A terminal's Ctrl-C reaches the whole process group: the command's Dask workers must
    have SIGINT blocked (the command stops them; they printed KeyboardInterrupt tracebacks
    of their own), and SIGTERM open (a nanny stops its worker with it). multiprocessing's
    resource tracker, started by the first worker's spawn, unblocks SIGINT and SIGTERM in
    the thread that starts it (CPython 3.11), so workers came up with nothing blocked.
    The calling thread's own mask is left as it was."""
    pytest.importorskip("distributed")
    script = (
        "import signal\n"
        "from volrender.sequence_frames import start_client, stop_client\n"
        "def blocked():\n"
        "    s = open('/proc/self/status').read()\n"
        "    return int(s.split('SigBlk:')[1].split()[0], 16)\n"
        "before = signal.pthread_sigmask(signal.SIG_BLOCK, [])\n"
        "client, cluster = start_client(2, None, None)\n"
        "try:\n"
        "    masks = list(client.run(blocked).values())\n"
        "finally:\n"
        "    stop_client(client, cluster)\n"
        "after = signal.pthread_sigmask(signal.SIG_BLOCK, [])\n"
        "print(len(masks), all(m >> 1 & 1 for m in masks), any(m >> 14 & 1 for m in masks),"
        " before == after)\n")
    out = subprocess.run([PY, "-c", script], env=ENV, capture_output=True, text=True,
                         timeout=240)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["2", "True", "False", "True"], out.stdout


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux's /proc")
def test_the_runtime_threads_never_receive_the_terminating_signals():
    """PoCL compiles a kernel's work-group function in its worker threads at the first
    launch; a SIGTERM landing in one of them broke that compile ('1 error generated.'
    beside the interrupted line, 1 run in 3 on a cold kernel cache). The threads the
    runtime starts while the device and context are made must have SIGINT, SIGTERM and
    SIGHUP blocked, so that the kernel delivers those signals to the main thread."""
    script = (
        "import os, signal\n"
        "from volrender.device import Device, choose\n"
        "before = set(os.listdir('/proc/self/task'))\n"
        "dev = Device(*choose())\n"
        "new = sorted(set(os.listdir('/proc/self/task')) - before)\n"
        "masks = []\n"
        "for tid in new:\n"
        "    status = open(f'/proc/self/task/{tid}/status').read().split('\\n')\n"
        "    masks.append(int([s for s in status if s.startswith('SigBlk')][0].split()[1], 16))\n"
        "main = signal.pthread_sigmask(signal.SIG_BLOCK, [])\n"
        "print(len(new), all(m >> (s - 1) & 1 for m in masks for s in (1, 2, 15)),"
        " any(s in main for s in (1, 2, 15)))\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([PY, "-c", script], env=env, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    started, all_blocked, main_blocked = out.stdout.split()
    if started == "0":
        pytest.skip("this OpenCL runtime starts no threads with the device")
    assert all_blocked == "True", f"{started} runtime threads can receive the signals"
    assert main_blocked == "False", "the main thread was left with the signals blocked"


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux's /proc")
def test_in_a_command_no_thread_runs_a_handler_for_the_terminating_signals(tmp_path):
    """The command routes SIGINT/SIGTERM/SIGHUP (process.route_signals): every thread of a
    rendering process, the main one, OpenBLAS's and PoCL's workers, has them blocked
    (LLVM's handler, installed over Python's while PoCL compiles, cannot run anywhere) but
    the watcher, which takes them in sigwait (the kernel opens its mask only while it
    waits there), and a SIGTERM still ends the render with the one line and 143."""
    p = subprocess.Popen([PY, "-m", "volrender", "render", "blob:3000", "--size", "160x120",
                          "--spp", "1024", "--no-progress", "-o", "o.png"], cwd=tmp_path,
                         env=ENV, stderr=subprocess.PIPE, text=True)
    end = time.monotonic() + 120
    masks = {}
    while time.monotonic() < end and p.poll() is None and len(masks) < 4:
        masks = {}          # main, the watcher, OpenBLAS's and PoCL's worker (one: ENV)
        for tid in os.listdir(f"/proc/{p.pid}/task"):
            try:
                status = Path(f"/proc/{p.pid}/task/{tid}/status").read_text().splitlines()
            except OSError:
                continue
            waits = Path(f"/proc/{p.pid}/task/{tid}/wchan").read_text()
            masks[tid] = (int(next(s for s in status if s.startswith("SigBlk")).split()[1], 16),
                          "sigtimedwait" in waits)
        time.sleep(0.05)
        if len(masks) == 3 and time.monotonic() > end - 110:   # OpenBLAS may start none
            break
    open_to = [t for t, (m, waiting) in masks.items()
               if not all(m >> (s - 1) & 1 for s in (1, 2, 15)) and not waiting]
    watchers = [t for t, (_, waiting) in masks.items() if waiting]
    p.send_signal(signal.SIGTERM)
    err = p.communicate(timeout=60)[1]
    assert len(masks) >= 3, f"only {len(masks)} threads seen before it ended: {err}"
    assert open_to == [], f"threads {open_to} of {len(masks)} can receive the signals"
    assert len(watchers) == 1, f"{len(watchers)} threads wait in sigwait"
    assert p.returncode == 143, err
    assert _without_notes(err).strip() in ("volrender: interrupted (SIGTERM); no output written",
                                           "volrender: interrupted (SIGTERM) while starting; "
                                           "no output written")
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("before, gap", [("volrender: a note cut before its newline", "\n"),
                                         ("volrender: a whole note\n", "")])
def test_the_interrupted_line_is_a_line_of_its_own(monkeypatch, before, gap):
    """A signal between a note's text and its newline (print writes them apart) left the
    interrupted line on the note's line (seen under load: 'rendered' + 'volrender:
    interrupted' on one line); the line starts a new one then, and only then."""
    from volrender import process
    saved = {s: signal.getsignal(s) for s in process.SIGNALS}
    out = io.StringIO()
    monkeypatch.setattr(sys, "stderr", process.Stream(out))
    try:
        sys.stderr.write(before)
        assert process.interrupted(KeyboardInterrupt()) == 130
    finally:
        for s, handler in saved.items():
            signal.signal(s, handler)
    assert out.getvalue() == f"{before}{gap}volrender: interrupted (SIGINT); no output written\n"
