"""OpenCL device choice, context/queue, and the program cache.

PoCL (the CPU OpenCL) is the default. `--device SUBSTRING` or the environment variable
VOLRENDER_DEVICE picks another device by a case-insensitive substring of
"<platform> / <device>" (e.g. "nvidia", "h200") or by "P:D" indices.
"""
from __future__ import annotations

import contextlib
import copy
import hashlib
import logging
import os
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass, field

from .errors import UserError
from .paths import cl_dir
from .process import signals_held

log = logging.getLogger("volrender")
ENV_DEVICE = "VOLRENDER_DEVICE"
ENV_OPTIONS = "VOLRENDER_CL_OPTIONS"    # extra OpenCL build options (experiments), e.g.
                                        # "-cl-nv-verbose -cl-nv-maxrregcount=64"


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


_CACHE_CHECKED = False


def _cl():
    global _CACHE_CHECKED
    if not _CACHE_CHECKED:
        _CACHE_CHECKED = True
        pocl_cache_dir()
    try:
        with signals_held():    # a KeyboardInterrupt inside its import aborts the process
            import pyopencl as cl   # (nanobind's enum_create) or half-builds its caches
    except ImportError as exc:  # pragma: no cover - set-up problem
        raise UserError(f"pyopencl does not import ({exc})", fix="run `bash run.sh setup`") from None
    return cl


def all_devices():
    """[(platform index, device index, platform, device)] for every OpenCL device found."""
    cl = _cl()
    # held: PoCL starts its worker threads here, and they inherit this thread's signal
    # mask; they compile kernels at first launch, and a signal landing in one of them
    # breaks its compiler ("1 error generated."). Held, the signals go to the main thread.
    with signals_held():
        try:
            platforms = cl.get_platforms()
        except cl.Error as exc:
            raise UserError(f"no OpenCL platform found ({exc})",
                            fix="install a runtime: `bash run.sh setup` installs PoCL") from None
        return [(i, j, p, d) for i, p in enumerate(platforms) for j, d in enumerate(p.get_devices())]


def describe(platform, device) -> str:
    return f"{platform.name.strip()} / {device.name.strip()}"


def _is_pocl(platform) -> bool:
    return "portable computing language" in platform.name.lower() or "pocl" in platform.name.lower()


def choose(spec: str | None = None):
    """Pick (platform, device): spec, else $VOLRENDER_DEVICE, else PoCL."""
    spec = spec or os.environ.get(ENV_DEVICE) or None
    found = all_devices()
    if not found:
        if pocl_cache_dir() is None:
            raise UserError("no OpenCL device found: PoCL cannot create its kernel cache "
                            "(neither ~/.cache nor the temporary directory is writable)",
                            fix="set XDG_CACHE_HOME to a writable directory")
        raise UserError("no OpenCL device found", fix="run `bash run.sh setup` to install PoCL")
    if spec is None:
        for _, _, p, d in found:
            if _is_pocl(p):
                return p, d
        warnings.warn(f"PoCL not found; using {describe(*found[0][2:])}")
        return found[0][2:]
    for i, j, p, d in found:
        if spec == f"{i}:{j}" or spec.lower() in describe(p, d).lower():
            return p, d
    listing = ", ".join(f"{i}:{j} {describe(p, d)}" for i, j, p, d in found)
    raise UserError(f"no OpenCL device matches {spec!r}", fix=f"pick one of: {listing}")


class BuildError(UserError):
    """An OpenCL program failed to build; carries the compiler log."""
    multiline = True


@contextlib.contextmanager
def _compiler_output():
    """Collect what the OpenCL compiler writes straight to file descriptor 2 (PoCL's
    clang prints e.g. "2 errors generated." there, past Python), so that a failed build
    reports one line; the text goes into the BuildError's log or, on success, the -v log."""
    out = {"text": ""}
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):
        yield out
        return
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield out
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            out["text"] = tmp.read().decode(errors="replace").strip()


@dataclass
class Device:
    """A context and an in-order, profiling queue on one OpenCL device."""

    platform: object
    device: object
    context: object = None
    queue: object = None
    _programs: dict = field(default_factory=dict)

    def __post_init__(self):
        cl = _cl()
        with signals_held():                  # threads started here inherit the mask too
            self.context = cl.Context([self.device])
            self.queue = cl.CommandQueue(
                self.context, properties=cl.command_queue_properties.PROFILING_ENABLE)

    def side(self) -> "Device":
        """This device with a second in-order queue: the same context, programs and
        kernels, so buffers made on either queue serve both. A thread that builds and
        uploads on it overlaps launches on this one (a sequence's next frame,
        volrender/pipeline.py); finish its queue before the other uses its buffers."""
        cl = _cl()
        other = copy.copy(self)             # shares _programs: one program cache
        with signals_held():
            other.queue = cl.CommandQueue(
                self.context, properties=cl.command_queue_properties.PROFILING_ENABLE)
        return other

    @property
    def name(self) -> str:
        return describe(self.platform, self.device)

    @property
    def version_string(self) -> str:
        d = self.device
        return f"{self.name} ({d.version.strip()}, driver {d.driver_version.strip()})"

    def program(self, entry: str, flags: dict[str, int], options=()):
        """Build cl/<entry>.cl with -D flags; cached per (sources, flags, options, device)."""
        return self.build((cl_dir() / f"{entry}.cl").read_text(), flags, f"cl/{entry}.cl",
                          options)

    def kernel(self, entry: str, flags: dict[str, int], name: str | None = None, options=()):
        """A kernel object of cl/<entry>.cl, kept for repeated launches."""
        key = ("kernel", entry, tuple(sorted(flags.items())), name, tuple(options),
               os.environ.get(ENV_OPTIONS, ""))     # as build() reads it
        if key not in self._programs:
            self._programs[key] = _cl().Kernel(self.program(entry, flags, options),
                                               name or entry)
        return self._programs[key]

    def has_extension(self, name: str) -> bool:
        return name in self.device.extensions.split()

    def build(self, source: str, flags: dict[str, int] | None = None, what: str = "program",
              options=()):
        """Build OpenCL source with cl/ on the include path, -D flags and compiler
        `options`, cached per (source and headers, flags, options, device)."""
        cl = _cl()
        src_dir = cl_dir()
        digest = hashlib.sha256(source.encode())
        for path in sorted(src_dir.glob("*.h")):
            digest.update(path.name.encode())
            digest.update(path.read_bytes())
        defines = [f"-D{k}={int(v)}" for k, v in sorted((flags or {}).items())]
        defines += [*options, *os.environ.get(ENV_OPTIONS, "").split()]
        key = (digest.hexdigest(), tuple(defines))
        if key in self._programs:
            return self._programs[key]
        start = time.perf_counter()
        failure = None
        # held: a signal inside the compiler (PoCL's in-process clang) breaks the build
        # ("1 error generated.") instead of ending the render cleanly after it
        with signals_held(), _compiler_output() as noise:
            try:
                prg = cl.Program(self.context, source).build(options=["-I", str(src_dir), *defines])
            except cl.RuntimeError as exc:
                failure = exc
        if failure is not None:
            extra = f"\n{noise['text']}" if noise["text"] else ""
            raise BuildError(
                f"OpenCL build of {what} failed on {self.name} with {' '.join(defines) or 'no flags'}:"
                f"\n{failure}{extra}", fix="this is a volrender bug; please report it with this log")
        if noise["text"]:
            log.info("compiler output for %s: %s", what, noise["text"])
        if os.environ.get(ENV_OPTIONS):
            log.info("build log of %s: %s", what,
                     prg.get_build_info(self.device, cl.program_build_info.LOG).strip())
        log.info("built %s %s in %.0f ms", what, " ".join(defines),
                 1e3 * (time.perf_counter() - start))
        self._programs[key] = prg
        return prg


_DEVICES: dict = {}


def get(spec: str | None = None) -> Device:
    """The Device for spec (see choose), created once per process."""
    platform, device = choose(spec)
    key = device.int_ptr
    if key not in _DEVICES:
        _DEVICES[key] = Device(platform, device)
    return _DEVICES[key]


def resolve(device=None) -> Device:
    """A Device from None (PoCL or $VOLRENDER_DEVICE), a spec string, or a Device."""
    if device is None or isinstance(device, str):
        return get(device)
    return device
