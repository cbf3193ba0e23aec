"""Frame sequences: one camera for the whole animation, frames as Dask tasks.

    volrender render 'smoke_####.vdb' -o 'out/smoke_####.exr' --frames 1-240
    volrender render 'particles_####.ply' -o 'out/glass_####.png' --frames 1-48
    volrender.render_sequence("smoke_####.vdb", "out/smoke_####.exr", frames="1-240")

Patterns: `####` or `@@@@` (any number: zero-padded to that width), `$F4` (Houdini),
`%04d` / `%d` (printf), or a glob (`smoke_*.vdb`: the frame number is the last run of
digits in each name); fileseq reads the padding. `--frames A-B[:STEP]` (also `A-BxSTEP`
and `A-BySTEP` as VFX tools write them, `N`, and comma-separated lists; fileseq expands
them) picks frames; missing input
frames are named before anything renders. The camera is resolved once, from the union
of every frame's bounds (volumes: read from the files' metadata, no voxels loaded; point
clouds: each frame read once), or from the options / `--camera`; the other options
(density scale, exposure, ...) are the same for every frame, and a point-cloud sequence
takes one radius and blend, given or chosen from its first frame.

Frames run as Dask tasks (`chunk` frames each, so a worker builds its programs once):
`workers=N` starts a LocalCluster on this machine (default: one worker per GPU, else one
per group of 8 CPU cores), `scheduler="tcp://HOST:8786"` submits to an existing cluster
(`dask scheduler` / `dask worker tcp://HOST:8786` on a shared filesystem), `workers=0`
renders in this process. Each worker uses `device`, or on a multi-GPU host one GPU per
worker. Every frame is written atomically; a frame that fails is reported with its
number and file while the others complete; a worker that dies has its tasks retried on
another. A JSON record (per frame: input, output, seconds, worker, device, status) is
written beside the outputs.

Long file: three parts that change together with the sequence command: patterns and
--frames (a fuzz target), the shared camera, and running the frames (claims, Dask, the
JSON record). Patterns are the clean seam (sequence_pattern.py) once the concurrent work
on interruption and frame records has landed.
"""
from __future__ import annotations

import contextlib
import datetime
import fcntl
import fnmatch
import glob as globmod
import hashlib
import json
import logging
import os
import re
import signal
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import points, process
from .atomic import write_bytes
from .camera import FRAMING, describe as describe_camera, write_camera_file
from .device import all_devices, resolve
from .errors import UserError, one_line_if_uncaught, option_name
from .frame_record import FrameRecord, FrameStatus
from .progress import Progress
from .render import check_image_memory, render
from .scene import load_scene, request
from .settings import in_range
from .spheres import blend_width, sphere_bounds, sphere_radii

_HASHES = re.compile(r"#+")
_PRINTF = re.compile(r"%(0?)(\d*)d")
# padding as VFX tools write it (fileseq reads its width): @@@@ (one digit each, as
# Houdini and Nuke), $F4 (Houdini); names an existing file does not count as a pattern
_VFX = re.compile(r"@+|\$F\d*")
_TOKEN = re.compile(r"#+|%0?\d*d|@+|\$F\d*")
_GLOB = re.compile(r"[*?\[]")
MAX_WIDTH = 32                  # digits a frame number is padded to, at most
CPU_CORES_PER_WORKER = 8        # default LocalCluster size on CPUs: one worker per 8 cores
KILL_HOOK = "VOLRENDER_TEST_KILL_WORKER_ONCE"   # tests: a marker file; the first task dies
GUARD_MARK = "VOLRENDER_MAIN_REIMPORTED"     # a file a worker touches when it re-ran the script
MAIN_GUARD_FIX = ("a script that starts Dask workers (render_sequence with workers) must call "
                  "it under `if __name__ == \"__main__\":` (the workers start as new Python "
                  "processes that import the script again); indent the call below that line")


# --------------------------------------------------------------------------- patterns

@dataclass(frozen=True)
class Pattern:
    """A frame-numbered path: `prefix` + frame (zero-padded to `width`) + `suffix`, or a glob."""
    text: str
    prefix: str = ""
    suffix: str = ""
    width: int = 0
    glob: bool = False

    def path(self, frame: int) -> Path:
        if self.glob:
            raise ValueError("a glob names no single frame")
        return Path(f"{self.prefix}{frame:0{self.width}d}{self.suffix}")

    def matches(self) -> dict[int, Path]:
        """{frame: path} of the files a glob matches; a file's frame is the last run of
        digits in what the wildcards matched (files without one are not frames)."""
        rx = re.compile(_glob_regex(Path(self.text).name))
        out = {}
        for name in sorted(globmod.glob(self.text)):
            m = rx.fullmatch(Path(name).name)
            digits = re.findall(r"\d+", "".join(g or "" for g in m.groups())) if m else []
            if digits:
                out.setdefault(int(digits[-1]), Path(name))
        return out


def _glob_regex(pattern: str) -> str:
    """A regex for a glob with one capturing group per wildcard (*, ?, [...])."""
    out, i = [], 0
    while i < len(pattern):
        c = pattern[i]
        if c == "*":
            out.append("(.*)")
        elif c == "?":
            out.append("(.)")
        elif c == "[":
            start = i + 1 + (pattern[i + 1:i + 2] == "!")
            j = pattern.find("]", start + 1)
            if j < 0:
                out.append(re.escape(c))
            else:
                # fnmatch's own translation of the set: it escapes what a regex set would
                # read otherwise and drops reversed ranges ('[v-9]'), as glob does
                out.append("(" + fnmatch.translate(pattern[i:j + 1])[4:-3] + ")")
                i = j
        else:
            out.append(re.escape(c))
        i += 1
    return "".join(out)


def is_pattern(text: str) -> bool:
    if _VFX.search(text) and not _is_file(text):
        return True
    return bool(_HASHES.search(text) or _PRINTF.search(text) or _GLOB.search(Path(text).name))


def _is_file(text) -> bool:
    try:
        return Path(text).is_file()
    except (OSError, ValueError):
        return False


def _padding(token: str) -> int:
    """The digits a frame token pads to, as fileseq reads it (one per # or @, $F4: 4,
    %04d: 4); widths of more than 4 digits are refused before they are read."""
    import fileseq
    digits = re.sub(r"\D", "", token)
    if len(digits) > 4:
        return MAX_WIDTH + 1
    if token.startswith("%") and not digits:
        return 0                       # %d: no padding
    return fileseq.getPaddingNum(token, pad_style=fileseq.PAD_STYLE_HASH1)


def parse_pattern(text: str, *, output=False) -> Pattern:
    """A Pattern from `####`, `%04d`, `@@@@`, `$F4` (fileseq reads the padding) or (inputs
    only) a glob; one frame token only (a file's own name with @ in it is no pattern)."""
    text = str(text)
    rx = _TOKEN if not (_VFX.search(text) and _is_file(text)) else re.compile(r"#+|%0?\d*d")
    tokens = [m.group(0) for m in rx.finditer(text)]
    if len(tokens) > 1:
        raise UserError(f"the pattern {text!r} has {len(tokens)} frame numbers",
                        fix="use one #### (or one %04d, @@@@, $F4) per pattern")
    if tokens:
        m = rx.search(text)
        width = _padding(m.group(0))
        if width > MAX_WIDTH:
            raise UserError(f"the pattern {_short(text)!r} pads frame numbers to {width} digits, "
                            f"more than {MAX_WIDTH}", fix="use fewer # (or a smaller %0Nd)")
        return Pattern(text, text[:m.start()], text[m.end():], width)
    if _GLOB.search(Path(text).name):
        if output:
            raise UserError(f"the output {text!r} is a glob", fix="name output frames with #### or %04d")
        return Pattern(text, glob=True)
    raise UserError(f"{text!r} has no frame number",
                    fix="mark it with #### (any number of #), %04d, or a quoted glob")


MAX_FRAMES = 1_000_000          # frames one --frames may name, all its parts together


def parse_frames(text: str) -> list[int]:
    """`A-B[:STEP]` (also `A-BxSTEP` as VFX tools write it, and `A-BySTEP`: the frames
    that step skips), `N`, or comma-separated lists of those -> sorted frame numbers (at
    most MAX_FRAMES, each of at most 18 digits). Each part is checked here, then expanded
    by fileseq.FrameSet (volrender's `:` is fileseq's `x`)."""
    import fileseq
    frames, count = [], 0
    for part in str(text).split(","):
        m = re.fullmatch(r"\s*(-?[0-9]+)\s*(?:-\s*(-?[0-9]+)\s*(?:([:xy])\s*([0-9]+)\s*)?)?",
                         part)
        if not m:
            raise UserError(f"--frames: cannot read {_short(part.strip())!r}",
                            fix="give A-B[xSTEP], N, or a comma-separated list, e.g. 1-240x2")
        if max(len(g.lstrip("-")) for g in m.groups() if g is not None) > 18:
            raise UserError(f"--frames: {_short(part.strip())!r} has a number of more than 18 "
                            "digits", fix="give frame numbers below 10^18")
        a = int(m.group(1))
        b = int(m.group(2)) if m.group(2) is not None else a
        kind, step = m.group(3) or "x", int(m.group(4) or 1)
        if b < a or step < 1:
            raise UserError(f"--frames: {_short(part.strip())!r} is empty",
                            fix="give A-B with A <= B and STEP >= 1")
        count += (b - a) // step + 1 if kind != "y" else b - a + 1
        if count > MAX_FRAMES:
            raise UserError(f"--frames {_short(str(text).strip())!r} names more than a million "
                            "frames", fix="render at most a million frames per run")
        spec = f"{a}-{b}{'y' if kind == 'y' else 'x'}{step}" if m.group(2) is not None else str(a)
        frames.extend(int(f) for f in fileseq.FrameSet(spec))
    return sorted(set(frames))


def _short(text: str) -> str:
    return text if len(text) <= 80 else text[:40] + "..." + text[-30:]


def frame_number(path) -> int | None:
    """The frame number of a file: the last run of digits in its name's stem."""
    digits = re.findall(r"\d+", Path(path).stem)
    return int(digits[-1]) if digits else None


def explicit_inputs(paths, frames=None) -> dict[int, Path]:
    """{frame: path} of several input files (an unquoted glob the shell expanded), each
    numbered by the last run of digits in its name."""
    out = {}
    for p in paths:
        f = frame_number(p)
        if f is None:
            raise UserError("an input of the sequence has no frame number in its name",
                            path=p, fix="name the frames with their numbers (smoke_0001.vdb)")
        if f in out:
            raise UserError(f"frame {f} is given twice: {out[f]} and {p}", path=p,
                            fix="give each frame once")
        out[f] = Path(p)
    if frames is not None:
        missing = [f for f in frames if f not in out]
        if missing:
            raise UserError(f"--frames asks for frames the inputs do not have: "
                            f"{', '.join(map(str, missing[:8]))}", fix="give those files too")
        out = {f: out[f] for f in frames}
    return dict(sorted(out.items()))


def _on_disk(pattern: Pattern) -> dict[int, Path]:
    """{frame: path} of the files a #### / %04d pattern names that exist (any number of
    digits where the width is 0, at least the width's otherwise)."""
    folder = Path(pattern.prefix).parent
    head, tail = Path(pattern.prefix).name, pattern.suffix
    rx = re.compile(re.escape(head) + r"(\d{%d,})" % max(pattern.width, 1) + re.escape(tail))
    found = {}
    try:
        names = sorted(p.name for p in folder.iterdir()) if folder.is_dir() else []
    except OSError:
        names = []
    for name in names:
        m = rx.fullmatch(name)
        if m and (pattern.width == 0 or len(m.group(1)) == pattern.width or
                  m.group(1)[0] != "0"):
            found.setdefault(int(m.group(1)), folder / name)
    return found


def frame_inputs(pattern: Pattern, frames=None) -> dict[int, Path]:
    """{frame: input path} for the frames asked for (every one must exist); without
    --frames, the frames found on disk."""
    if pattern.glob:
        found = pattern.matches()
        if not found:
            raise UserError(f"no file matches {pattern.text!r}", fix="check the pattern (quote it)")
        wanted = frames if frames is not None else sorted(found)
        missing = [f for f in wanted if f not in found]
        paths = {f: found[f] for f in wanted if f in found}
    else:
        if frames is None:
            found = _on_disk(pattern)
            if not found:
                raise UserError(f"no file matches {pattern.text!r}",
                                fix="check the pattern, or give --frames A-B")
            return found
        paths = {f: pattern.path(f) for f in frames}
        missing = [f for f, p in paths.items() if not p.is_file()]
    if missing:
        shown = ", ".join(f"{f} ({paths.get(f, pattern.text)})" if not pattern.glob else str(f)
                          for f in missing[:8])
        more = f" and {len(missing) - 8} more" if len(missing) > 8 else ""
        raise UserError(f"{len(missing)} of {len(frames or paths)} frames are missing: {shown}{more}",
                        path=pattern.text, fix="provide them, or pick the frames that exist with --frames")
    return paths


# --------------------------------------------------------------------------- one camera

def sequence_camera(paths, overrides, device=None):
    """(camera, {frame: error}, options for every frame, notes): the options' camera
    framed on the union of every frame's bounds, so nothing jumps from frame to frame.
    Volumes: bounds from the files' metadata; the middle frame is loaded once for the
    options every frame shares (_frame_defaults: the fire's exposure, auto's estimator).
    `device`: a device.Device auto weighs (else a CPU's model). Point clouds: each frame
    is read once for its bounds, and the radius and blend are one for the whole sequence,
    given or chosen from the first frame (said in the notes). Frames whose bounds cannot
    be read are left out of the union and returned as failed."""
    from . import vdb
    first = next(iter(paths.values()))
    req = request(first, **overrides)
    if req.origin not in ("volume", "points"):
        raise UserError("sequences render volumes (.vdb, .npz) or point clouds (.ply, .npy, "
                        ".xyz, .csv, .txt)", path=first, fix="give a pattern of such files")
    extra, notes = {}, []
    if req.kind == "glass":
        scene0 = req.load()
        settings = scene0.content.settings
        notes = [f"frame {next(iter(paths))}: {n}" for n in scene0.notes]
        if settings.radius is not None:
            extra["radius"] = settings.radius
        k = blend_width(sphere_radii(scene0.content.cloud, settings), settings)
        extra["blend"] = k
        if settings.blend is None:
            notes.append(f"blend {k:.4g} for every frame (from the first frame's radii); "
                         "set --blend")

        def bounds(path):
            cloud = scene0.content.cloud if path == first else points.load_points(path)
            return (*sphere_bounds(cloud, sphere_radii(cloud, settings)), cloud.up_axis)
    else:
        def bounds(path):
            return vdb.world_bounds(path, req.settings.grid, req.settings.emission_grid)
        extra, notes = _frame_defaults(paths, overrides, device)
    lo, hi, hint, bad = np.full(3, np.inf), np.full(3, -np.inf), None, {}
    for frame, path in paths.items():
        try:
            a, b, h = bounds(path)
        except UserError as exc:
            bad[frame] = str(exc)
            continue
        lo, hi = np.minimum(lo, a), np.maximum(hi, b)
        hint = hint or h
    if not bad.keys() < paths.keys():
        raise UserError(f"no frame of the sequence can be read (frame {min(bad)}: {bad[min(bad)]})")
    return req.view.camera(lo, hi, hint), bad, extra, notes


def _frame_defaults(paths, overrides, device=None):
    """(options for every frame, notes) from the sequence's middle frame, loaded once: the
    fire's exposure (volrender/fire.py) unless --emission-scale is given, and auto's
    estimator (with its octave bands or samples) unless --estimator is given, so that
    neither the brightness nor the estimator changes from frame to frame; ({}, [])
    when neither applies or the frame cannot be read."""
    fire = "emission_scale" not in overrides
    auto = overrides.get("estimator", "auto") == "auto"
    if not (fire or auto):
        return {}, []
    frames = list(paths.items())
    frame, mid = frames[len(frames) // 2]
    try:          # a device spec is not opened here (workers open their own): a CPU's model
        scene = request(mid, **overrides).load(
            device=device if hasattr(device, "device") else None)
    except UserError:
        return {}, []
    st, extra, notes = scene.content.settings, {}, []
    where = f"(from frame {frame}, the middle one)"
    if fire and any(n.startswith("fire exposure:") for n in scene.notes):
        extra["emission_scale"] = st.emission_scale
        notes.append(f"fire exposure x{st.emission_scale:.3g} for every frame {where}; set "
                     "--emission-scale")
    if auto:
        extra["estimator"] = st.estimator
        what = st.estimator
        if st.estimator == "path":
            extra["spp"] = st.spp
            what += f", {st.spp} spp"
        else:
            extra["ms_octaves"] = st.octaves
            what += f", {st.octaves} octave band{'s' if st.octaves > 1 else ''}"
        notes.append(f"estimator auto for every frame: {what} {where}; set --estimator")
    return extra, notes


def camera_overrides(camera) -> dict:
    return {"origin": tuple(camera.origin), "target": tuple(camera.target),
            "up": tuple(camera.up), "fov": camera.fov, "size": (camera.width, camera.height)}


# --------------------------------------------------------------------------- the tasks

def render_chunk(jobs, overrides, save_kw, skip_existing=False):
    """Render [(frame, input, output)] in this process: one record per frame. A frame
    that fails is recorded, not raised, so the others of the chunk still render. With
    `skip_existing`, a frame another run is rendering (`_claim`) is left to the end and
    then waited for, so two runs over one output folder render each frame once."""
    hook = os.environ.get(KILL_HOOK)
    if hook:
        try:
            os.close(os.open(hook, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
            os.kill(os.getpid(), signal.SIGKILL)          # tests: this worker dies once
        except FileExistsError:
            pass
    worker = _worker_name()
    records = []
    deferred = []
    for job in jobs:
        rec = _render_frame(job, overrides, save_kw, skip_existing, worker, wait=False)
        if rec is None:                 # another run renders it now: come back to it last
            deferred.append(job)
        else:
            records.append(rec)
    for job in deferred:
        records.append(_render_frame(job, overrides, save_kw, skip_existing, worker, wait=True))
    return sorted(records, key=lambda r: r.frame)


_PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"      # a PNG's last chunk: empty, fixed CRC


def unusable(path, size) -> str | None:
    """Why an existing output cannot stand for a render of `size` (width, height), or None
    when it can (--skip-existing): it reads whole in its suffix's format (a PNG ends with
    its IEND chunk, an EXR or .npy decodes) and has that size."""
    path = Path(path)
    try:
        if path.suffix.lower() == ".png":
            with open(path, "rb") as f:
                f.seek(max(os.fstat(f.fileno()).st_size - len(_PNG_END), 0))
                if f.read() != _PNG_END:
                    return "it is cut short (no IEND chunk at its end)"
        from .image import read_image
        arr = read_image(path)
    except UserError as exc:
        return str(exc).removeprefix(f"{path}: ")
    except (OSError, MemoryError) as exc:
        return f"it cannot be read ({getattr(exc, 'strerror', None) or type(exc).__name__})"
    w, h = size or arr.shape[1::-1]
    if arr.shape[:2] != (h, w):
        return f"it is {arr.shape[1]}x{arr.shape[0]}, not {w}x{h}"
    return None


def _found(out):
    """The identity of an existing output file (None when there is none), to tell whether
    another run replaced it."""
    try:
        st = os.stat(out)
    except OSError:
        return None
    return (st.st_ino, st.st_mtime_ns, st.st_size)


_LOCK_NAME = ".volrender-frames.lock"
_LOCK_FDS: dict = {}


def _claim(out, wait: bool):
    """With --skip-existing, the right to render `out`: an exclusive record lock (fcntl) on
    one byte of the lock file in its directory, at an offset hashed from its path, so two
    runs over one output folder (on one host or over NFS) render each frame once. Returns a
    release function, or None where another process holds it and `wait` is false. Where the
    directory takes no lock file or no locks, every claim is granted."""
    d = Path(out).resolve().parent
    fd = _LOCK_FDS.get(d)
    if fd is None:
        try:
            fd = os.open(d / _LOCK_NAME, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        except OSError:
            return lambda: None
        _LOCK_FDS[d] = fd          # kept open: closing any descriptor drops the locks
    key = os.fsencode(str(Path(out).resolve()))
    offset = int.from_bytes(hashlib.blake2b(key, digest_size=7).digest(), "little")
    try:
        fcntl.lockf(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB), 1, offset)
    except (BlockingIOError, PermissionError):
        return None
    except OSError:
        return lambda: None
    return lambda: fcntl.lockf(fd, fcntl.LOCK_UN, 1, offset)


def _render_frame(job, overrides, save_kw, skip_existing, worker, wait):
    """One frame's record; None when --skip-existing finds another run rendering it and
    `wait` is false."""
    from .pipeline import frame_times      # (concurrent.futures: off the start-up path)
    frame, src, out = job
    rec = FrameRecord(frame, str(src), str(out), worker=worker, pid=os.getpid())
    t0 = time.perf_counter()
    release = lambda: None  # noqa: E731
    if skip_existing:
        found = _found(out)
        if found is not None:
            why = unusable(out, overrides.get("size"))
            if why is None:
                rec.status, rec.seconds = FrameStatus.SKIPPED, 0.0
                return rec
            rec.redone = why                # rendered again, and said so
        release = _claim(out, wait)
        if release is None:
            return None
        now = _found(out)
        if now is not None and now != found and unusable(out, overrides.get("size")) is None:
            release()                   # the run that held it has written it
            rec.redone = None
            rec.status, rec.seconds = FrameStatus.SKIPPED, time.perf_counter() - t0
            return rec
    try:
        try:
            scene = load_scene(src, **overrides)
            t1 = time.perf_counter()
            img = render(scene, os.environ.get("VOLRENDER_DEVICE") or None)
            t2 = time.perf_counter()
            img.save(out, **save_kw)
            t3 = time.perf_counter()
            rec.set(**frame_times(img, t1 - t0, t2 - t1, t3 - t2))
        except UserError as exc:
            rec.status, rec.error = FrameStatus.FAILED, str(exc)
        except MemoryError:
            rec.status, rec.error = FrameStatus.FAILED, "out of host memory"
    finally:
        release()
    rec.seconds = time.perf_counter() - t0
    return rec


def set_env(name: str, value: str | None):
    """Set (None: remove) an environment variable in this process: `client.run(set_env,
    ...)` does it on every worker (an os.environ method would be pickled with a copy)."""
    if value is None:
        os.environ.pop(name, None)
    else:
        os.environ[name] = value


def _worker_name() -> str:
    try:
        from distributed import get_worker
        return str(get_worker().name)
    except (ImportError, ValueError):
        return "local"


def device_per_worker(specs):
    """A Dask worker plugin: worker `name` (an int in a LocalCluster) renders on GPU
    `name % len(specs)`, by setting $VOLRENDER_DEVICE before any task runs."""
    from distributed.diagnostics.plugin import WorkerPlugin

    class DevicePerWorker(WorkerPlugin):
        name = "volrender-device"

        def __init__(self, specs):
            self.specs = list(specs)

        def setup(self, worker):
            try:
                i = int(worker.name)
            except (TypeError, ValueError):
                i = sum(map(ord, str(worker.name)))
            os.environ["VOLRENDER_DEVICE"] = self.specs[i % len(self.specs)]
    return DevicePerWorker(specs)


def gpu_specs() -> list[str]:
    """'P:D' of every GPU OpenCL lists (empty without one)."""
    import pyopencl as cl
    return [f"{i}:{j}" for i, j, _, d in all_devices() if d.type & cl.device_type.GPU]


def default_workers(device=None) -> int:
    if device is None:
        n = len(gpu_specs())
        if n:
            return n
    return max(1, (os.cpu_count() or 1) // CPU_CORES_PER_WORKER)


# --------------------------------------------------------------------------- the sequence

@dataclass
class SequenceResult:
    records: list = field(default_factory=list)   # FrameRecord per frame, in frame order
    wall_s: float = 0.0
    workers: int = 0
    record_path: Path | None = None
    notes: list = field(default_factory=list)     # choices made for every frame
    camera: object = None                         # the one camera of every frame
    options: dict = field(default_factory=dict)   # options chosen for every frame (radius, blend)

    @property
    def failed(self) -> list:
        return [r for r in self.records if r.status == FrameStatus.FAILED]

    @property
    def fps(self) -> float:
        done = sum(r.status == FrameStatus.OK for r in self.records)
        return done / self.wall_s if self.wall_s > 0 else 0.0


def record_path(output: Pattern) -> Path:
    """Where the JSON record goes: beside the outputs, named after the pattern."""
    stem = Path(output.prefix).name.rstrip("._-") or "frames"
    return Path(output.prefix).parent / f"{stem}.sequence.json"


def render_sequence(pattern, output, frames=None, client=None, *, workers=None, scheduler=None,
                    chunk=None, skip_existing=False, device=None, progress=None, exposure=0.0,
                    tonemap="filmic", say=None, camera_out=None, verbose=False,
                    **overrides) -> SequenceResult:
    """Render every frame of `pattern` to `output` (see the module docstring). `client`: a
    dask.distributed.Client to use (else one is created from `scheduler` or `workers`).
    Raises UserError before rendering for bad patterns and missing frames; failed frames
    are in the result's `failed` (the others are written). `say`: called with each note
    (choices made for every frame) before the frames render; with `verbose` also the
    camera. `camera_out`: write the one camera there (a --camera file)."""
    _exit_if_reimported()
    _check_counts(workers=workers, chunk=chunk)
    from . import image
    dst = parse_pattern(output, output=True)
    frame_list = parse_frames(frames) if isinstance(frames, str) else (
        sorted(set(int(f) for f in frames)) if frames is not None else None)
    if isinstance(pattern, (list, tuple)):        # several files: an expanded glob
        paths = explicit_inputs(pattern, frame_list)
    else:
        paths = frame_inputs(parse_pattern(pattern), frame_list)
    folder = Path(dst.prefix).parent
    if not folder.exists():
        try:
            folder.mkdir(parents=True)
        except OSError as exc:
            raise UserError(f"cannot create the output folder ({exc.strerror or exc})",
                            path=folder, fix="give an output pattern in a folder you can write") from None
    outs = {f: dst.path(f) for f in paths}
    for f, out in outs.items():
        image.check_output(out, overrides.get("aov", ()))
    clash = {Path(p).resolve() for p in paths.values()} & {o.resolve() for o in outs.values()}
    if clash:
        raise UserError(f"an output frame is also an input: {sorted(clash)[0]}",
                        fix="write the frames somewhere else")
    _check_every_frame(next(iter(paths.values())), overrides, device,
                       serial=client is None and workers == 0 and scheduler is None)
    camera, bad, extra, notes = sequence_camera(paths, overrides, device)
    for note in notes if say else ():
        say(note)
    if verbose and say:
        say(describe_camera(camera))
    if camera_out is not None:
        write_camera_file(camera, camera_out)
    frame_kw = {**overrides, **extra, **camera_overrides(camera)}
    for key in ("camera", *FRAMING):          # the camera is resolved: frames get it whole
        frame_kw.pop(key, None)
    save_kw = {"exposure": exposure, "tonemap": tonemap}
    jobs = [(f, paths[f], outs[f]) for f in sorted(paths) if f not in bad]
    failed = [FrameRecord(f, str(paths[f]), str(outs[f]), status=FrameStatus.FAILED, error=err,
                          seconds=0.0) for f, err in bad.items()]
    t0, started = time.perf_counter(), time.time_ns()
    own, records, n_workers, stopped, handlers, levels = None, [], 0, None, {}, {}
    try:
        if client is None and (workers == 0 and scheduler is None):
            _serial(jobs, frame_kw, save_kw, skip_existing, progress, device, records)
        else:
            if client is None:
                own = _start_client(workers, scheduler, device)
                client = own[0]
            n_workers = len(client.scheduler_info().get("workers", {})) or 1
            k = chunk or max(1, min(8, len(jobs) // (2 * n_workers) or 1))
            _distributed(client, jobs, frame_kw, save_kw, skip_existing, progress, k, records)
    except KeyboardInterrupt as exc:      # Ctrl-C, SIGTERM, SIGHUP: stop, say what is done
        stopped, handlers, levels = exc, process.ignore_signals(), _quiet_dask()
    finally:
        if own is not None:
            _stop_client(*own)
    if stopped is not None:
        records = _rows_when_stopped(records, jobs, started)
    result = SequenceResult(sorted(records + failed, key=lambda r: r.frame),
                            time.perf_counter() - t0, n_workers, notes=notes, camera=camera,
                            options=extra)
    for rec in result.records if say else ():
        if rec.redone:
            say(f"frame {rec.frame}: {rec.output} was there but {rec.redone}; "
                "rendered it again")
    settings = {k: (list(v) if isinstance(v, tuple) else v) for k, v in overrides.items()
                if isinstance(v, (int, float, str, bool, tuple, list)) or v is None}
    result.record_path = _write_record(dst, result, pattern, output, settings, skip_existing)
    if stopped is not None:
        process.restore_signals(handlers)
        for name, level in levels.items():
            logging.getLogger(name).setLevel(level)
        signum = getattr(stopped, "signum", signal.SIGINT)
        raise Interrupted(signum, _stopped_summary(result)) from None
    return result


class Interrupted(process.Interrupted):
    """A sequence stopped by a signal, after its record was written: `summary` names the
    frames written and those not; `signum` the signal."""

    def __init__(self, signum: int, summary: str):
        super().__init__(signum)
        self.summary, self.args = summary, (summary,)     # what a traceback shows


def _quiet_dask() -> dict:
    """Dask's loggers silenced while a stopped run stops its cluster (its nannies log the
    tasks cancelled on the way as errors, with tracebacks); their levels before."""
    names = ("distributed", "distributed.scheduler", "distributed.nanny", "distributed.core",
             "distributed.utils", "distributed.worker", "distributed.client")
    levels = {n: logging.getLogger(n).level for n in names}
    for n in names:
        logging.getLogger(n).setLevel(logging.CRITICAL + 1)
    return levels


def _rows_when_stopped(records, jobs, started_ns):
    """The records of a stopped run, one per job: a frame without a record was written
    if its output is there, complete and newer than the run's start (a worker finished it
    as the run stopped), and is 'interrupted' otherwise."""
    have = {r.frame for r in records}
    out = list(records)
    for frame, src, dst in jobs:
        if frame in have:
            continue
        try:
            fresh = os.stat(dst).st_mtime_ns >= started_ns
        except OSError:
            fresh = False
        out.append(FrameRecord(frame, str(src), str(dst), seconds=0.0,
                               status=FrameStatus.OK if fresh else FrameStatus.INTERRUPTED))
    return out


def _ranges(frames) -> str:
    """1,2,3,5,7,8 -> '1-3, 5, 7-8'."""
    out, frames = [], sorted(frames)
    i = 0
    while i < len(frames):
        j = i
        while j + 1 < len(frames) and frames[j + 1] == frames[j] + 1:
            j += 1
        out.append(str(frames[i]) if i == j else f"{frames[i]}-{frames[j]}")
        i = j + 1
    return ", ".join(out)


def _stopped_summary(result) -> str:
    """'frames 1-3 written, 4-8 not (record out/f.sequence.json)' and the like."""
    by = {}
    for r in result.records:
        by.setdefault(r.status.value, []).append(r.frame)
    ok, left = by.get("ok", []), by.get("interrupted", [])
    parts = [f"{'frame' if len(ok) == 1 else 'frames'} {_ranges(ok)} written" if ok
             else "no frame written"]
    parts.append(f"{'frame' if len(left) == 1 else 'frames'} {_ranges(left)} not" if left
                 else "none left")
    for status, words in (("skipped", "kept (there already)"), ("failed", "failed")):
        if by.get(status):
            parts.append(f"{_ranges(by[status])} {words}")
    record = f"record {result.record_path}" if result.record_path else "no record written"
    return f"{', '.join(parts)}; {record}"


MAX_WORKERS = 1024              # Dask workers one LocalCluster may start
MAX_CHUNK = MAX_FRAMES


def _check_counts(**counts):
    """workers in 0..MAX_WORKERS and chunk in 1..MAX_CHUNK (None: the default), before
    any work: a LocalCluster asked for -1 workers waits for them forever."""
    checks = {"workers": in_range(0, MAX_WORKERS, integer=True, allow_none=True),
              "chunk": in_range(1, MAX_CHUNK, integer=True, allow_none=True)}
    for key, value in counts.items():
        problem = checks[key](value)
        if problem:
            raise UserError(f"{option_name(key)} {problem}, got {value!r}")


def _check_every_frame(first, overrides, device, serial):
    """The limits every frame shares, once, before any frame is read: the options, and
    the image's buffers against memory (the device's too when frames render here)."""
    req = request(first, **overrides)             # every option checked, nothing loaded
    dev = None
    if serial:
        dev = resolve(device)
    check_image_memory(*req.view.size, dev, len(req.settings.aovs) if req.kind == "volume" else 0)


def _serial(jobs, frame_kw, save_kw, skip_existing, progress, device, records):
    """Render the jobs here, appending each frame's record to `records` as it is done: as
    a pipeline (volrender/pipeline.py), or one frame after another with --skip-existing
    (whose claims and deferrals render_chunk makes)."""
    if device is not None:
        os.environ["VOLRENDER_DEVICE"] = device
    bar = Progress(len(jobs), "frames", progress, unit="frame")
    try:
        if skip_existing or len(jobs) < 2:
            for job in jobs:
                records += render_chunk([job], frame_kw, save_kw, skip_existing)
                bar.update()
        else:
            from .pipeline import run_frames
            run_frames(jobs, frame_kw, save_kw, records, bar.update, worker=_worker_name())
    finally:
        bar.close()
    return records


def _exit_if_reimported():
    """In a worker process that is importing the user's script again (multiprocessing's
    spawn start: the script called render_sequence without a `__main__` guard): mark it for
    the parent (GUARD_MARK) and leave quietly, instead of starting workers of its own."""
    import multiprocessing
    if not getattr(multiprocessing.current_process(), "_inheriting", False):
        return
    mark = os.environ.get(GUARD_MARK)
    if mark:
        try:
            Path(mark).touch()
        except OSError:
            pass
    raise SystemExit(3)


def _local_cluster(**kw):
    """A LocalCluster; a UserError naming the `__main__` guard when its workers died
    re-running the script (see _exit_if_reimported), with the cluster's logs held back."""
    from distributed import LocalCluster
    names = ("distributed.nanny", "distributed.deploy.spec", "distributed.core",
             "distributed.process", "distributed.worker")
    levels = {n: logging.getLogger(n).level for n in names}
    with tempfile.TemporaryDirectory(prefix="volrender-guard-") as tmp:
        mark = Path(tmp) / "reimported"
        old = os.environ.get(GUARD_MARK)
        os.environ[GUARD_MARK] = str(mark)      # spawned workers inherit the environment
        for n in names:
            logging.getLogger(n).setLevel(logging.CRITICAL + 1)
        try:
            return LocalCluster(**kw)
        except Exception:
            if mark.exists():     # one line even uncaught: the cluster's traceback is noise
                raise one_line_if_uncaught(UserError(
                    "the Dask workers re-ran this script and stopped",
                    path=getattr(sys.modules.get("__main__"), "__file__", None),
                    fix=MAIN_GUARD_FIX)) from None
            raise
        finally:
            for n, level in levels.items():
                logging.getLogger(n).setLevel(level)
            if old is None:
                os.environ.pop(GUARD_MARK, None)
            else:
                os.environ[GUARD_MARK] = old


def _start_client(workers, scheduler, device):
    from distributed import Client
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise UserError(f"cannot reach the Dask scheduler {scheduler} ({exc})",
                            fix="start it with `dask scheduler` and its workers with "
                                f"`dask worker {scheduler}`") from None
        if device is not None:
            client.run(set_env, "VOLRENDER_DEVICE", device)
        return client, None
    for name in ("distributed", "distributed.scheduler", "distributed.nanny", "distributed.core"):
        logging.getLogger(name).setLevel(logging.ERROR)    # the cluster's chatter
    n = workers or default_workers(device)
    env = {}
    gpus = [] if device is not None else gpu_specs()
    if device is not None:
        env["VOLRENDER_DEVICE"] = device
    elif not gpus:                                # PoCL: share the cores between workers
        env["POCL_MAX_PTHREAD_COUNT"] = str(max(1, (os.cpu_count() or 1) // n))
    if os.environ.get(KILL_HOOK):
        env[KILL_HOOK] = os.environ[KILL_HOOK]
    # SIGINT is held back while the workers start, so they start with it blocked and keep
    # it so: a terminal's Ctrl-C reaches the whole process group, and this process stops
    # them (they printed tracebacks of their own); here it is delivered right after.
    # SIGTERM and SIGHUP reach them as usual (not the command line's routed block).
    cluster = None
    try:
        with process.children_unblocked(), _sigint_held():
            _start_resource_tracker()
            cluster = _local_cluster(n_workers=n, threads_per_worker=1, processes=True,
                                     dashboard_address=":0", env=env,
                                     silence_logs=logging.CRITICAL)
        # (workers log only what is critical: a stopped sequence's shutdown logged ERROR
        # tracebacks of a close on a closed comm; a frame's failure comes back in its record)
        client = Client(cluster)
    except KeyboardInterrupt:
        if cluster is not None:
            cluster.close()
        raise
    if gpus:
        client.register_plugin(device_per_worker(gpus))
    return client, cluster


def _start_resource_tracker():
    """multiprocessing's resource tracker started here, this thread's signal mask put
    back. The thread that starts it leaves SIGINT and SIGTERM unblocked (CPython 3.11
    unblocks them instead of restoring the mask): started from Dask's spawner thread, it
    made that thread start workers that took the terminal's Ctrl-C."""
    from multiprocessing import resource_tracker
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, ())
    except (AttributeError, ValueError, OSError):
        return
    try:
        resource_tracker.ensure_running()
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


@contextlib.contextmanager
def _sigint_held():
    """SIGINT blocked in this thread for the block (threads and processes started in it
    keep it blocked); delivered after it."""
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    except (AttributeError, ValueError, OSError):
        yield
        return
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _stop_client(client, cluster):
    client.close()
    if cluster is not None:
        cluster.close()


def _distributed(client, jobs, frame_kw, save_kw, skip_existing, progress, k, records):
    """Render the jobs as Dask tasks of k frames, appending the records as they come."""
    from distributed import as_completed
    chunks = [jobs[i:i + k] for i in range(0, len(jobs), k)]
    futures = [client.submit(render_chunk, c, frame_kw, save_kw, skip_existing, pure=False,
                             retries=2, key=f"volrender-frames-{c[0][0]}-{c[-1][0]}-{os.getpid()}")
               for c in chunks]
    bar = Progress(len(jobs), "frames", progress, unit="frame")
    try:
        for fut in as_completed(futures):
            try:
                recs = fut.result()
            except Exception as exc:                 # the task itself failed, not a frame
                c = chunks[futures.index(fut)]
                why = f"the worker failed ({type(exc).__name__}: {exc})".replace("\n", " ")
                recs = [FrameRecord(f, str(s), str(o), status=FrameStatus.FAILED, error=why,
                                    seconds=0.0) for f, s, o in c]
            records += recs
            bar.update(len(recs))
    finally:
        bar.close()
    return records


def _write_record(dst, result, pattern, output, settings=None, resume=False):
    """The JSON record beside the outputs: the command, settings, camera, version and date,
    and one row per frame; a resumed run (--skip-existing) keeps the earlier run's rows of
    the frames it skipped."""
    from . import __version__     # the package (its __init__ imports this module)
    path = record_path(dst)
    frames = [r.to_json() for r in result.records]
    runs = 1
    if resume and path.is_file():
        try:
            old = json.loads(path.read_text())
            earlier = {r["frame"]: r for r in old.get("frames", []) if r.get("status") == "ok"}
            frames = [{**earlier[r["frame"]], "from_earlier_run": True}
                      if r["status"] == FrameStatus.SKIPPED.value and r["frame"] in earlier else r
                      for r in frames]
            runs = int(old.get("runs", 1)) + 1
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            pass                      # an unreadable old record is replaced
    cam = result.camera
    payload = {"input": pattern if isinstance(pattern, str) else [str(p) for p in pattern],
               "output": str(output), "argv": sys.argv, "version": __version__,
               "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
               "runs": runs, "settings": settings or {}, "options": result.options,
               "camera": camera_overrides(cam) if cam is not None else None,
               "wall_s": result.wall_s, "workers": result.workers, "fps": result.fps,
               "failed": [r.frame for r in result.failed], "frames": frames}
    try:
        return write_bytes(path, json.dumps(payload, indent=1, default=str).encode(),
                           "sequence record")
    except UserError as exc:
        process.say(f"volrender: warning: {exc}")
        return None
