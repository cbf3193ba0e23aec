"""The process around a command: terminating signals, the standard streams and warnings.

One home for signal handling. SIGINT raises KeyboardInterrupt and, while the CLI runs
(`handle_signals`), SIGTERM and SIGHUP raise `Interrupted`, so every one of them unwinds
(atomic.py removes its temporary files) and the command exits with 128 + the signal and one
line (`interrupted`). `signals_held` holds them back around steps that must not be cut in
two (atomic.py's create and rename, device.py's program builds). In the command-line
process they are routed (`route_signals`): blocked in every thread and taken by one watcher
thread, so no thread ever runs a handler for them. Streams: a closed pipe or a full disk on
stdout/stderr does not turn a finished render into a failure (`Stream`).
"""
from __future__ import annotations

import contextlib
import errno
import os
import signal
import sys
import threading
import time

from .errors import printable

SIGNALS = tuple(s for s in (getattr(signal, n, None) for n in ("SIGINT", "SIGTERM", "SIGHUP"))
                if s is not None)
WAKE = getattr(signal, "SIGURG", None)     # the watcher's nudge to a main thread that waits


class _Router:
    """route_signals' state: the main thread, how deep it is in signals_held blocks, a
    signal taken during one, and whether cli.main has taken over (handle_signals)."""

    def __init__(self, starting):
        self.lock = threading.RLock()     # the main thread's handler may run inside it
        self.main = threading.main_thread().ident
        self.depth = 0
        self.pending = None
        self.forward = False
        self.starting = starting


ROUTER = None


def route_signals(starting) -> bool:
    """The command line's first step: SIGINT/SIGTERM/SIGHUP blocked in the main thread, so
    in every thread started after it (numpy's OpenBLAS, PoCL's workers, OIDN's pool), and
    taken by one watcher thread (sigwait). No thread runs a handler for them: PoCL's
    in-process clang installs LLVM's handler over Python's while it compiles, and a signal
    landing in any thread then removed the compile's files ('1 error generated.'). Until
    handle_signals the watcher calls `starting(signum, None)` (it ends the process with the
    one line); after it, it raises the signal in the main thread (`_raise_in_main`), or at
    the end of a signals_held block. A signal ignored at the start (nohup) stays ignored.
    False where pthreads or sigwait are missing (nothing changed)."""
    global ROUTER
    if ROUTER is not None or not hasattr(signal, "sigwait") or WAKE is None:
        return ROUTER is not None
    try:
        signal.pthread_sigmask(signal.SIG_BLOCK, SIGNALS)
    except (AttributeError, ValueError, OSError):
        return False
    ROUTER = _Router(starting)
    threading.Thread(target=_watch, name="volrender-signals", daemon=True).start()
    return True


def _watch():
    while True:
        _deliver(signal.sigwait(SIGNALS))


def _deliver(signum):
    """A routed signal: the start-up exit before handle_signals; kept while the main thread
    is inside signals_held; else raised in the main thread."""
    with ROUTER.lock:
        if not ROUTER.forward:
            ROUTER.starting(signum, None)
        elif ROUTER.depth:
            ROUTER.pending = ROUTER.pending or signum
        else:
            _raise_in_main(signum)


def _raise_in_main(signum):
    """As if `signum` had arrived in the main thread: its Python handler runs there at the
    next bytecode, and WAKE (a no-op handler) ends a wait in a system call (a pipe read, a
    sleep, a Dask future) so that it does so at once."""
    import _thread
    _thread.interrupt_main(signum)
    try:
        signal.pthread_kill(ROUTER.main, WAKE)
    except (OSError, ValueError):
        pass


@contextlib.contextmanager
def children_unblocked():
    """The main thread's routed signals unblocked for the block, for code that starts
    processes (a Dask cluster) or long-lived threads that must get signals as usual
    (processes inherit the mask)."""
    if ROUTER is None or threading.get_ident() != ROUTER.main:
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_UNBLOCK, SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def unblock_inherited():
    """In a process started by the command (the OpenVDB reader): the routed signals'
    block, inherited with the mask, lifted."""
    try:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, SIGNALS)
    except (AttributeError, ValueError, OSError):
        pass


class Interrupted(KeyboardInterrupt):
    """A terminating signal other than SIGINT (SIGTERM, SIGHUP), raised like Ctrl-C."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


@contextlib.contextmanager
def signals_held():
    """Hold SIGINT/SIGTERM/SIGHUP back for the block (they are delivered after it)."""
    routed = ROUTER is not None and threading.get_ident() == ROUTER.main
    if routed:
        with ROUTER.lock:
            ROUTER.depth += 1
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, SIGNALS)
    except (AttributeError, ValueError, OSError):      # no pthreads, or not the main thread
        old = None
    try:
        yield
    finally:
        if old is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)
        if routed:
            with ROUTER.lock:
                ROUTER.depth -= 1
                pending = ROUTER.pending if not ROUTER.depth else None
                if pending:
                    ROUTER.pending = None
                    _raise_in_main(pending)


def handle_signals():
    """SIGTERM and SIGHUP raise Interrupted, as SIGINT raises KeyboardInterrupt, so
    every one of them unwinds (temporary files removed) and exits with 128 + the signal.
    A signal ignored when the process started (nohup, a background job's SIGINT) stays
    ignored, and so does a call from a thread other than the main one. Returns the
    previous handlers (for restore_signals)."""
    global RECEIVED
    if threading.current_thread() is not threading.main_thread():
        return {}
    RECEIVED = None

    def interrupted(signum, frame):
        global RECEIVED
        RECEIVED = signum                  # in case Python swallows the raise (lost_signal)
        if ROUTER is not None and ROUTER.depth:   # tripped just before a signals_held block
            with ROUTER.lock:
                ROUTER.pending = ROUTER.pending or signum
            return
        if _not_here(frame):               # inside an import or a finalizer: a moment later
            threading.Thread(target=_again, args=(signum,), daemon=True).start()
            return
        raise KeyboardInterrupt if signum == signal.SIGINT else Interrupted(signum)
    old = {}
    for name, handler in (("SIGINT", interrupted), ("SIGTERM", interrupted),
                          ("SIGHUP", interrupted)):
        sig = getattr(signal, name, None)
        if sig is not None and signal.getsignal(sig) is not signal.SIG_IGN:
            old[sig] = signal.signal(sig, handler)
    if ROUTER is not None:
        old[WAKE] = signal.signal(WAKE, _woken)
        with ROUTER.lock:
            ROUTER.forward = True
    return old


def _woken(signum, frame):
    """WAKE's handler: nothing; its arrival ended a wait so the main thread runs the
    routed signal's handler now."""


RECEIVED = None         # the last signal handle_signals' handlers took, until it is reported


def _again(signum):
    """The signal raised in the main thread again, a moment later (see _not_here)."""
    import _thread
    time.sleep(0.02)
    if ROUTER is not None:
        _deliver(signum)
    else:
        _thread.interrupt_main(signum)


def _not_here(frame) -> bool:
    """Whether `frame` runs inside a module's import or a `__del__`, where a raise does harm:
    in an import it half-builds module state (pyopencl.invoker's cache then fails in its
    own __del__) or aborts the process (nanobind's enum_create: "Critical nanobind error",
    status -6); in a finalizer Python prints "Exception ignored" and drops it."""
    while frame is not None:
        code = frame.f_code
        if code.co_name == "__del__" or code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


def lost_signal():
    """A signal whose KeyboardInterrupt Python swallowed (raised inside a weakref callback,
    such as importlib's module-lock one, it is printed as 'Exception ignored' and the
    command goes on): as Interrupted, to report once the command is done; else None."""
    return Interrupted(RECEIVED) if RECEIVED is not None else None


def restore_signals(old):
    for sig, handler in old.items():
        signal.signal(sig, handler if handler is not None else signal.SIG_DFL)


def ignore_signals() -> dict:
    """SIGINT/SIGTERM/SIGHUP ignored from now on (a command that is done or winding up:
    a second signal cannot cut that short); the previous handlers (for restore_signals).
    Nothing from a thread other than the main one."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    return {sig: signal.signal(sig, signal.SIG_IGN) for sig in SIGNALS}


def interrupted(exc, written=()) -> int:
    """One line saying what really happened (after the rename, the output was written):
    `written`, the outputs this command completed (atomic.WRITTEN's new entries), or the
    exception's `summary` (a stopped sequence's frames). Returns the exit status, 128 +
    the signal."""
    global RECEIVED
    ignore_signals()                                   # a second signal: no traceback
    RECEIVED = None
    signum = getattr(exc, "signum", signal.SIGINT)
    done = ", ".join(printable(p) for p in dict.fromkeys(map(str, written)))
    what = f"{done} was written before that" if done else "no output written"
    what = getattr(exc, "summary", None) or what       # a sequence says which frames
    # on a line of its own: the signal may have come between a note's text and its newline
    fresh = "" if getattr(sys.stderr, "line_ended", True) else "\n"
    say(f"{fresh}volrender: interrupted ({signal.Signals(signum).name}); {what}")
    return 128 + signum


def interrupt_within(exc):
    """The KeyboardInterrupt (or Interrupted) that `exc` was raised from, if any: a signal
    while a C extension initialises (pybind11's OpenEXR importing numpy) comes out as
    `ImportError: initialization failed` caused by it."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def say(line: str):
    """`line` and its newline to stderr in one write: print() writes them in two, and a
    signal raised between them left the interrupted line on the same line."""
    sys.stderr.write(line + "\n")
    sys.stderr.flush()


def warn_one_line(message, category, filename, lineno, file=None, line=None):
    """warnings.showwarning for the CLI: one line, no source excerpt."""
    say(f"volrender: warning: {printable(message)}")


class Stream:
    """stdout or stderr whose write errors (a closed pipe, a full disk or a closed file:
    EPIPE, ENOSPC, EIO, EBADF) are recorded and drop every later write, instead of turning
    a finished render into a failure (docs/robustness.md, "Streams"). After the first
    error the descriptor is pointed at /dev/null, so that what the stream still buffers
    cannot fail again at exit."""

    def __init__(self, stream):
        self._stream, self.error = stream, None
        self.line_ended = True          # the last text written ended its line

    def write(self, text):
        if text:
            self.line_ended = text.endswith("\n")
        if self.error is None:
            try:
                return self._stream.write(text)
            except (OSError, ValueError) as exc:
                self._failed(exc)
        return len(text)

    def flush(self):
        if self.error is None:
            try:
                self._stream.flush()
            except (OSError, ValueError) as exc:
                self._failed(exc)

    def _failed(self, exc):
        self.error = exc
        try:
            fd = self._stream.fileno()
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, fd)
            os.close(null)
        except (OSError, ValueError, AttributeError):
            pass

    def __getattr__(self, name):
        return getattr(self._stream, name)


def guard_streams():
    """Descriptors 0-2 that are closed are opened on /dev/null (else the first file opened
    would become 'stderr', and a library's message would land in an image), and stdout and
    stderr are wrapped in Stream. Returns the streams to restore."""
    closed = []
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            os.open(os.devnull, os.O_RDWR)          # the lowest free descriptor: fd
            closed.append(fd)
    old = sys.stdout, sys.stderr
    sys.stdout = Stream(sys.stdout if sys.stdout is not None else open(os.devnull, "w"))
    sys.stderr = Stream(sys.stderr if sys.stderr is not None else open(os.devnull, "w"))
    if 1 in closed:
        sys.stdout.error = OSError(9, "it is closed")
    return old


def stdout_failed(command) -> int | None:
    """The exit status when stdout, the product of `volrender info`, could not be written:
    2 for a full disk or an I/O error; none when the reader went away (EPIPE, `| head -1`:
    it read what it wanted), nor for the other commands, whose product is a file."""
    sys.stdout.flush()
    exc = sys.stdout.error
    if command != "info" or exc is None or getattr(exc, "errno", None) == errno.EPIPE:
        return None
    print(f"volrender: error: cannot write to standard output ({getattr(exc, 'strerror', None) or exc})",
          file=sys.stderr)
    return 2


def hold_in_this_thread():
    """SIGINT/SIGTERM/SIGHUP blocked in the calling thread for good: the initializer of a
    helper thread (sequence.py's loader and writer, quantise.py's pool), so that the kernel
    delivers those signals to the main thread, whose handlers raise."""
    try:
        signal.pthread_sigmask(signal.SIG_BLOCK, SIGNALS)
    except (AttributeError, ValueError, OSError):      # no pthreads
        pass
