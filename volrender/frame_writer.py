"""A process that writes a sequence's frames (volrender/pipeline.py), so that encoding a
frame (OpenEXR's compression, PNG's tone mapping and zlib) does not hold this process's
GIL while the next frame builds and the current one launches. Measured on the H200 (10^5
spheres at 1080p, EXR, docs/benchmarks.md): the write stage 182 -> 142 ms, frames/s
x1.02-1.05 (the loading thread's build, not the write, is the slowest stage there).

The frame goes over a pipe as the Image itself (pickle protocol 5: its arrays as raw
out-of-band buffers) and the process calls Image.save on it: the same code as writing
here, so the same bytes, written atomically (volrender/atomic.py) under the same path
from the same working directory. Warnings and errors come back and are raised here.
The process ignores SIGINT, SIGTERM and SIGHUP (a terminal's Ctrl-C reaches the whole
process group): this process decides, and it exits when its stdin closes, after the
frame it is writing (also when this process is killed). Where it cannot start or dies,
the frames are written in this process (`WriterDied`); so are frames sent before it has
started (its Python's start-up: a fraction of a second) and frames under MIN_PIXELS
(`wanted`: their write costs less than the process). VOLRENDER_FRAME_WRITER=thread writes
in this process, =process in the process whatever the size.
"""
from __future__ import annotations

import fcntl
import os
import pickle
import select
import signal
import sys
import tempfile
import warnings
from pathlib import Path

from . import atomic, process
from .pipe_messages import receive, send

MODE_ENV = "VOLRENDER_FRAME_WRITER"       # "thread": write in this process; "process": always
PIPE_BYTES = 1 << 20                       # the pipe's buffer (Linux: at most pipe-max-size)
MIN_PIXELS = 1 << 18                       # smaller frames are written in this process
READY = b"volrender frame writer"          # its first words, once it has started


class WriterDied(Exception):
    """The writer process could not start, or ended: write the frame here."""


class NotSent(Exception):
    """A frame that does not pickle (an Image of the caller's own class): write it here."""


def wanted(size=None) -> bool:
    """Whether a sequence of frames of `size` (width, height; None: not known) is written
    by the process."""
    mode = os.environ.get(MODE_ENV, "")
    if mode in ("thread", "process"):
        return mode == "process"
    return size is not None and size[0] * size[1] >= MIN_PIXELS


class FrameWriter:
    """The writer process (started at once; it imports volrender while the first frame
    renders). save() is called from one thread at a time."""

    def __init__(self):
        import subprocess
        root = str(Path(__file__).resolve().parents[1])
        env = {**os.environ,
               "PYTHONPATH": os.pathsep.join([root, *filter(None, [os.environ.get("PYTHONPATH")])])}
        if not sys.executable:                  # an embedded interpreter: no Python to start
            raise WriterDied("no Python executable to start the frame writer with")
        self.err = tempfile.TemporaryFile()      # what it says as it dies
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-c", "from volrender import frame_writer; frame_writer.serve()"],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.err, env=env,
                close_fds=True)
        except (OSError, ValueError) as exc:
            raise WriterDied(f"the frame writer process did not start ({exc})") from None
        _grow_pipe(self.proc.stdin)
        self.started = False

    def ready(self, wait: float = 0.0) -> bool:
        """Whether it has started (said READY), waiting up to `wait` seconds; False once
        it has ended."""
        if self.started or self.proc is None:
            return self.started and self.proc is not None
        try:
            if select.select([self.proc.stdout], [], [], wait)[0]:
                self.started = receive(self.proc.stdout) == READY
                if not self.started:
                    self.proc = None
        except (EOFError, OSError, ValueError):
            self.proc = None
        return self.started

    def save(self, img, output, save_kw) -> Path:
        """img.save(output, **save_kw) in the process: the file written; its warnings
        raised here; UserError / MemoryError as Image.save raises them."""
        if not self.ready(wait=60.0):
            raise WriterDied(f"the frame writer process has ended{self.last_words()}")
        proc = self.proc
        buffers = []
        try:
            head = pickle.dumps(img, protocol=5, buffer_callback=buffers.append)
        except (pickle.PicklingError, TypeError, AttributeError) as exc:
            raise NotSent(str(exc)) from None
        raws = [b.raw() for b in buffers]
        try:
            cwd = os.getcwd()
        except OSError:
            cwd, output = None, os.path.abspath(output)
        try:
            send(proc.stdin, pickle.dumps((cwd, str(output), save_kw,
                                           [r.nbytes for r in raws])), flush=False)
            send(proc.stdin, head, flush=False)
            for r in raws:
                proc.stdin.write(r)
            proc.stdin.flush()
            kind, value, shown = pickle.loads(receive(proc.stdout))
        except (EOFError, OSError, pickle.UnpicklingError) as exc:
            self.proc = None
            code = proc.poll()
            raise WriterDied(f"the frame writer process ended ({code if code is not None else exc})"
                             f"{self.last_words()}") from None
        for message, category in shown:
            warnings.warn(message, category, stacklevel=2)
        if kind == "ok":
            atomic.WRITTEN.append(Path(value))
            return Path(value)
        raise value

    def last_words(self) -> str:
        try:
            self.err.seek(0)
            lines = [ln.strip() for ln in self.err.read()[-4000:].decode(errors="replace").splitlines()]
        except (OSError, ValueError):
            return ""
        lines = [ln for ln in lines if ln]
        return f": {lines[-1][:200]}" if lines else ""

    def close(self, timeout: float = 60.0):
        """Its stdin closed; it exits after the frame it writes (waited for up to
        `timeout` seconds, then killed)."""
        proc, self.proc = self.proc, None
        if proc is not None:
            try:
                proc.stdin.close()
            except OSError:
                pass
            try:
                proc.wait(timeout=timeout)
            except Exception:                      # noqa: BLE001 - a stop goes on regardless
                proc.kill()
                proc.wait()
        self.err.close()


def _grow_pipe(f):
    """A 1 MiB pipe buffer, where Linux gives one: fewer switches for a 33 MB frame."""
    try:
        fcntl.fcntl(f.fileno(), getattr(fcntl, "F_SETPIPE_SZ", 1031), PIPE_BYTES)
    except (OSError, ValueError):
        pass


def _read_into(f, n: int) -> bytearray:
    b = bytearray(n)
    view, got = memoryview(b), 0
    while got < n:
        k = f.readinto(view[got:])
        if not k:
            raise EOFError
        got += k
    return b


def serve():
    """The writer process: one frame at a time from stdin, until it closes."""
    for sig in (signal.SIGINT, signal.SIGTERM, getattr(signal, "SIGHUP", None)):
        if sig is not None:
            signal.signal(sig, signal.SIG_IGN)       # the caller decides
    process.unblock_inherited()
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)                                    # stray prints go to stderr
    inp = sys.stdin.buffer
    _grow_pipe(out)
    send(out, READY)
    while True:
        try:
            cwd, output, save_kw, sizes = pickle.loads(receive(inp))
            head = receive(inp)
            buffers = [_read_into(inp, n) for n in sizes]
        except EOFError:
            return
        if cwd is not None and cwd != os.getcwd():
            try:
                os.chdir(cwd)
            except OSError:
                pass
        with warnings.catch_warnings(record=True) as shown:
            warnings.simplefilter("always")        # the caller's filters decide there
            try:
                reply = ("ok", str(pickle.loads(head, buffers=buffers).save(output, **save_kw)))
            except MemoryError:
                reply = ("error", MemoryError())
            except Exception as exc:                 # noqa: BLE001 (sent back whole)
                reply = ("error", exc)
        del buffers, head
        shown = [(str(w.message), w.category) for w in shown]
        try:
            blob = pickle.dumps((*reply, shown))
        except Exception:                            # noqa: BLE001
            blob = pickle.dumps(("error", RuntimeError(f"{type(reply[1]).__name__}: "
                                                       f"{reply[1]}"), shown))
        send(out, blob)
