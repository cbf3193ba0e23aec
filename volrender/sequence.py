"""Frame sequences: one camera for the whole animation, frames as Dask tasks.

    volrender render 'smoke_####.vdb' -o 'out/smoke_####.exr' --frames 1-240
    volrender render 'particles_####.ply' -o 'out/glass_####.png' --frames 1-48
    volrender.render_sequence("smoke_####.vdb", "out/smoke_####.exr", frames="1-240")

Patterns (`####`, `@@@@`, `$F4`, `%04d`, globs) and `--frames` are read in
sequence_pattern.py; missing input frames are named before anything renders. The camera
is resolved once, from the union of every frame's bounds (volumes: read from the files'
metadata, no voxels loaded; point clouds: each frame read once), or from the options /
`--camera`; the other options (density scale, exposure, ...) are the same for every
frame, and a point-cloud sequence takes one radius and blend, given or chosen from its
first frame.

Frames run (sequence_frames.py) as Dask tasks (`chunk` frames each, so a worker builds
its programs once): `workers=N` starts a LocalCluster on this machine (default: one
worker per GPU, else one per group of 8 CPU cores), `scheduler="tcp://HOST:8786"`
submits to an existing cluster (`dask scheduler` / `dask worker tcp://HOST:8786` on a
shared filesystem), `workers=0` renders in this process. Each worker uses `device`, or
on a multi-GPU host one GPU per worker. Every frame is written atomically; a frame that
fails is reported with its number and file while the others complete; a worker that
dies has its tasks retried on another. A JSON record (per frame: input, output, seconds,
worker, device, status) is written beside the outputs.
"""
from __future__ import annotations

import datetime
import json
import logging
import os
import signal
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import points, process
from .atomic import write_bytes
from .camera import FRAMING, describe as describe_camera, write_camera_file
from .device import resolve
from .errors import UserError, option_name
from .frame_record import FrameRecord, FrameStatus
from .render import check_image_memory
from .scene import request
from .sequence_frames import (KILL_HOOK, default_workers, device_per_worker,  # noqa: F401
                              exit_if_reimported, gpu_specs, quiet_dask, render_chunk,
                              run_distributed, run_serial, set_env, start_client, stop_client,
                              unusable)
from .sequence_pattern import (MAX_FRAMES, MAX_WIDTH, Pattern, explicit_inputs,  # noqa: F401
                               frame_inputs, frame_number, is_pattern, parse_frames,
                               parse_pattern)
from .settings import in_range
from .spheres import blend_width, sphere_bounds, sphere_radii


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
    exit_if_reimported()
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
            run_serial(jobs, frame_kw, save_kw, skip_existing, progress, device, records)
        else:
            if client is None:
                own = start_client(workers, scheduler, device)
                client = own[0]
            n_workers = len(client.scheduler_info().get("workers", {})) or 1
            k = chunk or max(1, min(8, len(jobs) // (2 * n_workers) or 1))
            run_distributed(client, jobs, frame_kw, save_kw, skip_existing, progress, k, records)
    except KeyboardInterrupt as exc:      # Ctrl-C, SIGTERM, SIGHUP: stop, say what is done
        stopped, handlers, levels = exc, process.ignore_signals(), quiet_dask()
    finally:
        if own is not None:
            stop_client(*own)
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
