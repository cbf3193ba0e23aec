"""Running a sequence's frames (sequence.py resolves what every frame shares): the task
that renders frames in a process (render_chunk: one record per frame, --skip-existing's
claims), in this process (run_serial: as a pipeline, volrender/pipeline.py) or on Dask
(run_distributed; start_client starts a LocalCluster or reaches a scheduler, one GPU per
worker on a multi-GPU host).
"""
from __future__ import annotations

import contextlib
import fcntl
import hashlib
import logging
import os
import signal
import sys
import tempfile
import time
from pathlib import Path

from . import process
from .device import all_devices
from .errors import UserError, one_line_if_uncaught
from .frame_record import FrameRecord, FrameStatus
from .progress import Progress
from .render import render
from .scene import load_scene

CPU_CORES_PER_WORKER = 8        # default LocalCluster size on CPUs: one worker per 8 cores
KILL_HOOK = "VOLRENDER_TEST_KILL_WORKER_ONCE"   # tests: a marker file; the first task dies
GUARD_MARK = "VOLRENDER_MAIN_REIMPORTED"     # a file a worker touches when it re-ran the script
MAIN_GUARD_FIX = ("a script that starts Dask workers (render_sequence with workers) must call "
                  "it under `if __name__ == \"__main__\":` (the workers start as new Python "
                  "processes that import the script again); indent the call below that line")



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


def quiet_dask() -> dict:
    """Dask's loggers silenced while a stopped run stops its cluster (its nannies log the
    tasks cancelled on the way as errors, with tracebacks); their levels before."""
    names = ("distributed", "distributed.scheduler", "distributed.nanny", "distributed.core",
             "distributed.utils", "distributed.worker", "distributed.client")
    levels = {n: logging.getLogger(n).level for n in names}
    for n in names:
        logging.getLogger(n).setLevel(logging.CRITICAL + 1)
    return levels



def run_serial(jobs, frame_kw, save_kw, skip_existing, progress, device, records):
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


def exit_if_reimported():
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
    re-running the script (see exit_if_reimported), with the cluster's logs held back."""
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


def start_client(workers, scheduler, device):
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


def stop_client(client, cluster):
    client.close()
    if cluster is not None:
        cluster.close()


def run_distributed(client, jobs, frame_kw, save_kw, skip_existing, progress, k, records):
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
