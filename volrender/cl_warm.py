"""The OpenCL platform list read in a thread while a render command imports (issue 35).

Listing the platforms the first time loads and starts every vendor's driver (H200: 0.24 s,
NVIDIA's and PoCL's), and pyopencl holds the GIL through it, so nothing else runs. Called
through ctypes the same calls release the GIL: `start()`, at the command's first line,
lists the platforms and their devices in a thread of pyopencl's own OpenCL loader (the
same library instance), while the command imports numpy and volrender; device.py waits
for it (`wait()`) before its own first OpenCL call, so the two never run OpenCL at once,
and then finds the drivers started. Nothing is kept from the thread's calls but the
started drivers; a failure there only means the list is read later, as before. The
OpenCL stack's cache folder is made sure of first (pocl_cache_dir: PoCL lists no device
without one). VOLRENDER_CL_WARM=0 turns it off.
"""
from __future__ import annotations

import atexit
import glob
import importlib.util
import logging
import os
import tempfile
import threading

log = logging.getLogger("volrender")
_THREAD = None
CL_DEVICE_TYPE_ALL = 0xFFFFFFFF


def _writable_dir(path) -> bool:
    try:
        os.makedirs(path, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            return True
    except OSError:
        return False


def pocl_cache_dir() -> str | None:
    """Make sure the OpenCL stack has a writable cache before it starts: PoCL fails to
    list its device at all when it cannot create its kernel cache, and pyopencl (through
    pytools) raises when it cannot create its own. Both live under $XDG_CACHE_HOME (else
    ~/.cache); when that is not writable (a read-only or missing $HOME), point
    $XDG_CACHE_HOME at a private folder under the temporary directory. Returns the cache
    root in use, or None when none is writable."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    if _writable_dir(base):
        return base
    fallback = os.path.join(tempfile.gettempdir(), f"volrender-cache-{os.getuid()}")
    if _writable_dir(fallback):
        os.environ["XDG_CACHE_HOME"] = fallback
        log.info("the cache folder %s is not writable; using %s", base, fallback)
        return fallback
    return None


def loader_path() -> str | None:
    """pyopencl's OpenCL loader (a wheel bundles its own under pyopencl/.libs), found
    without importing pyopencl; else the system's."""
    try:
        spec = importlib.util.find_spec("pyopencl")
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.origin:
        return None
    home = os.path.dirname(spec.origin)
    own = sorted(glob.glob(os.path.join(home, ".libs", "libOpenCL*.so*")))
    if not own:
        return "libOpenCL.so.1"
    # the wheel's loader finds its drivers from PYOPENCL_HOME, which pyopencl's import sets
    # to its folder (unset, the loader crashes): set here as that import will
    os.environ.setdefault("PYOPENCL_HOME", home)
    return own[0]


def _list_platforms(path):
    import ctypes                     # (its import costs start-up time: here, in the thread)
    try:
        lib = ctypes.CDLL(path)
        n = ctypes.c_uint(0)
        if lib.clGetPlatformIDs(0, None, ctypes.byref(n)) != 0 or not n.value:
            return
        ids = (ctypes.c_void_p * n.value)()
        if lib.clGetPlatformIDs(n.value, ids, None) != 0:
            return
        for p in ids:
            m = ctypes.c_uint(0)
            lib.clGetDeviceIDs(ctypes.c_void_p(p), ctypes.c_uint64(CL_DEVICE_TYPE_ALL), 0, None,
                               ctypes.byref(m))
    except (OSError, AttributeError):
        return


def start() -> bool:
    """Start the thread (once); False where there is no loader to call."""
    global _THREAD
    if _THREAD is not None:
        return True
    if os.environ.get("VOLRENDER_CL_WARM") == "0":
        return False
    path = loader_path()
    if path is None:
        return False
    pocl_cache_dir()                   # before PoCL starts: it needs a writable cache
    _THREAD = threading.Thread(target=_list_platforms, args=(path,), name="volrender-cl-warm",
                               daemon=True)
    _THREAD.start()
    atexit.register(wait, 10.0)        # a command that ends at once: not inside a driver's start
    return True


def wait(timeout: float = 120.0):
    """Return once the thread's calls are done (at once where none was started)."""
    if _THREAD is not None:
        _THREAD.join(timeout)
