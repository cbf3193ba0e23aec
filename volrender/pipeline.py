"""A sequence's frames in one process as a pipeline (issue 35): frame n+1 is read and set
up (render.prepare: the acceleration's build, the program, the uploads, on a second queue
of the device, Device.side()) in one thread and frame n-1 written in another while frame
n's launches and read-back run in the calling thread, on the device's own queue. Each
frame goes through the same steps as one after another (sequence_frames._render_frame:
load_scene, render, Image.save), so it writes the same bytes; its record's load, build,
set-up, render (the launches and read-back) and write seconds are its own stages', and
`seconds` runs from its load's start to its write's end (they overlap other frames').

The writes of frames of a quarter of a megapixel and more go to a process of their own
(volrender/frame_writer.py): encoding a frame in this interpreter holds the GIL the other
two stages need. The write thread sends the frame and waits; while the process starts,
and where it cannot start or dies, the frames are written in that thread.

Stopped by a signal (KeyboardInterrupt in the calling thread): the frame being written is
finished and recorded, the next frame's load is dropped, and the exception goes on.
"""
from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor

from . import device as device_mod, frame_writer
from .errors import UserError
from .frame_record import FrameRecord, FrameStatus
from .process import hold_in_this_thread


def _failure(exc) -> str:
    return "out of host memory" if isinstance(exc, MemoryError) else str(exc)


def frame_times(img, load_s, render_s, write_s) -> dict:
    """A written frame's record fields (FrameRecord.set): status, device and its stages'
    seconds."""
    build_s = (img.info.tree_ms + img.info.cells_ms) / 1e3
    return dict(status=FrameStatus.OK, device=img.device, load_s=load_s, build_s=build_s,
                setup_s=img.info.setup_ms / 1e3, kernel_s=img.kernel_ms / 1e3,
                render_s=render_s, write_s=write_s)


def run_frames(jobs, overrides, save_kw, records, done=lambda: None, worker="local") -> list:
    """Render [(frame, input, output)] here, appending each frame's record to `records`
    when its file is written (or it failed) and calling `done()` then; `worker` names
    this process in them (sequence.render_chunk's name)."""
    from .render import prepare       # looked up per call: tests put fakes in their place
    from .scene import load_scene
    dev = device_mod.resolve(os.environ.get("VOLRENDER_DEVICE") or None)
    builder = dev.side()

    def load(job):
        t0 = time.perf_counter()
        t1, ready, error = None, None, None
        try:
            scene = load_scene(job[1], **overrides)
            t1 = time.perf_counter()
            ready = prepare(scene, dev, builder=builder)
        except (UserError, MemoryError) as exc:
            error = _failure(exc)
        return t0, t1 or time.perf_counter(), ready, error

    def write(rec, img, t0, load_s, render_s):
        t = time.perf_counter()
        try:
            save(img, rec.output)
            rec.set(**frame_times(img, load_s, render_s, time.perf_counter() - t))
        except (UserError, MemoryError) as exc:
            rec.set(status=FrameStatus.FAILED, error=_failure(exc))
        rec.seconds = time.perf_counter() - t0
        return rec

    proc = None
    if frame_writer.wanted(overrides.get("size")):
        try:
            proc = frame_writer.FrameWriter()
        except frame_writer.WriterDied:
            proc = None
    always = os.environ.get(frame_writer.MODE_ENV) == "process"

    def save(img, output):
        nonlocal proc
        if proc is not None and (always or proc.ready()):      # here while it starts
            try:
                return proc.save(img, output, save_kw)
            except frame_writer.NotSent:
                pass                            # this frame: here
            except frame_writer.WriterDied:
                proc = None                     # this frame and the next ones: here
        return img.save(output, **save_kw)

    # the loader keeps the signals: the OpenVDB reader process it may start takes them
    loader = ThreadPoolExecutor(1, "volrender-load")
    writer = ThreadPoolExecutor(1, "volrender-write", initializer=hold_in_this_thread)
    writing = None

    def written():
        nonlocal writing
        if writing is not None:
            rec = writing.result()              # a signal here: the finally waits for it
            writing = None
            records.append(rec)
            done()

    try:
        loading = loader.submit(load, jobs[0])
        for i, (frame, src, out) in enumerate(jobs):
            rec = FrameRecord(frame, str(src), str(out), worker=worker, pid=os.getpid())
            t0, t1, ready, error = loading.result()
            loading = loader.submit(load, jobs[i + 1]) if i + 1 < len(jobs) else None
            t2 = time.perf_counter()
            if error is None:
                try:
                    img = ready.finish()
                except (UserError, MemoryError) as exc:
                    error = _failure(exc)
            ready = None
            t3 = time.perf_counter()
            written()                           # frame n-1: written while frame n rendered
            if error is not None:
                rec.set(status=FrameStatus.FAILED, error=error, seconds=t3 - t0)
                records.append(rec)
                done()
                continue
            writing = writer.submit(write, rec, img, t0, t1 - t0, t3 - t2)
            img = None
        written()
    finally:
        loader.shutdown(wait=False, cancel_futures=True)
        if writing is not None:                 # stopped: the frame being written counts
            try:
                records.append(writing.result())
            except BaseException:               # noqa: BLE001 - the stop goes on regardless
                pass
        writer.shutdown(wait=True)
        if proc is not None:
            proc.close()
    return records
