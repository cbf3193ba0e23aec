"""Input files: checked before they are opened, and kept apart from the output.

`check_input` refuses what `open()` would block on or fail at (FIFOs, devices, sockets,
directories, unreadable files) with a message that says which it is; `refuse_overwrite`
refuses an output that is one of the inputs (the same inode, whether reached through a
symlink, a hard link or another spelling of the path).
"""
from __future__ import annotations

import os
import resource
import stat
from pathlib import Path

import numpy as np

from .errors import MissingFileError, UserError


def _kind(mode) -> str:
    return {stat.S_IFIFO: "a FIFO (named pipe)", stat.S_IFCHR: "a character device",
            stat.S_IFBLK: "a block device", stat.S_IFSOCK: "a socket"}.get(
        stat.S_IFMT(mode), "not a regular file")


def check_input(path, what: str = "file", fix: str = "check the path") -> Path:
    """`path` as a Path once it is an existing, readable regular file; else a UserError
    naming what it is instead (`what`: "volume file", ...; `fix`: for a wrong kind)."""
    p = Path(path)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        raise MissingFileError("no such file", path=p, fix="check the path") from None
    except NotADirectoryError:
        raise MissingFileError("no such file (a folder on its path is a file)", path=p,
                        fix="check the path") from None
    except (OSError, ValueError) as e:
        reason = "a symlink loop" if getattr(e, "errno", None) == 40 else \
            (getattr(e, "strerror", None) or str(e))
        raise UserError(f"cannot open the {what} ({reason})", path=p, fix="check the path") from None
    if stat.S_ISDIR(st.st_mode):
        raise UserError(f"is a directory, not a {what}", path=p, fix=fix)
    if not stat.S_ISREG(st.st_mode):
        raise UserError(f"is {_kind(st.st_mode)}, not a regular {what}", path=p,
                        fix="give a regular file (volrender reads its inputs more than once)")
    if not os.access(p, os.R_OK):
        raise UserError(f"cannot read the {what} (permission denied)", path=p,
                        fix="make it readable (chmod u+r) or run as its owner")
    return p


def _identity(path):
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return st.st_dev, st.st_ino


def _shown(path) -> str:
    try:
        rel = os.path.relpath(path)
    except (ValueError, OSError):
        return str(path)
    return str(path) if rel.startswith("..") else rel


def refuse_overwrite(output, inputs, command: str = "render", shown=None):
    """Refuse an output that is the same file as one of `inputs` (`shown`: the output as
    the user spelt it, for the message)."""
    out = _identity(output)
    if out is None:
        return
    for p in inputs:
        if _identity(p) == out:
            raise UserError(f"the output is the same file as the input {_shown(p)!r}; "
                            f"{command} would overwrite its own input",
                            path=shown if shown is not None else _shown(output),
                            fix="write to another file name")


MAX_TOML = 16 << 20             # bytes of a scene or camera file


def read_toml(path, what: str) -> dict:
    """The TOML document of a (small) scene or camera file: one that is larger than
    MAX_TOML is refused before it is read, not UTF-8 or not TOML is one line (tomllib's
    message), and so is nesting too deep for tomllib (its RecursionError)."""
    import tomllib
    try:
        with open(path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            if size > MAX_TOML:
                raise UserError(f"is {size} bytes long; a {what} is at most {MAX_TOML >> 20} MiB",
                                path=path, fix=f"check that this is a {what}")
            text = f.read(MAX_TOML + 1).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise UserError(f"not valid TOML ({exc})", path=path, fix="fix the syntax") from None
    except OSError as exc:
        raise UserError(f"cannot read the {what} ({exc.strerror or exc})", path=path,
                        fix="check the path") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise UserError(f"not valid TOML ({exc})", path=path, fix="fix the syntax") from None
    except RecursionError:
        raise UserError("not valid TOML for volrender (arrays or tables nested too deep)",
                        path=path, fix="fix the syntax") from None


def npy_header(f):
    """(shape, dtype, offset of the data) of the .npy stream f, read without the data."""
    fmt = np.lib.format
    version = fmt.read_magic(f)
    if version == (1, 0):
        shape, _, dtype = fmt.read_array_header_1_0(f)
    elif version in ((2, 0), (3, 0)):
        # 3.0 differs from 2.0 only by a UTF-8 header (non-Latin-1 field names, which no
        # reader here accepts); numpy has no public reader of it (its private one left
        # numpy.lib.format in numpy 2)
        shape, _, dtype = fmt.read_array_header_2_0(f)
    else:
        raise ValueError(f"unknown .npy format version {version[0]}.{version[1]}")
    return shape, dtype, f.tell()


# ---------------------------------------------------------------- memory before allocating

def _meminfo() -> dict:
    out = {}
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                key, _, rest = line.partition(":")
                words = rest.split()
                if words and words[0].isdigit():
                    out[key] = int(words[0]) * (1024 if words[1:] == ["kB"] else 1)
    except OSError:
        pass
    return out


def _vm_size() -> int:
    """This process's address space in use (VmSize), 0 where /proc does not say."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return 0


def _cgroup_room() -> int | None:
    """Bytes left under this process's cgroup (v2) memory limit, None without one."""
    try:
        with open("/proc/self/cgroup") as f:
            rel = next((line.split(":", 2)[2].strip() for line in f if line.startswith("0::")), None)
        if rel is None:
            return None
        d = Path("/sys/fs/cgroup") / rel.lstrip("/")
        limit = (d / "memory.max").read_text().strip()
        if limit == "max":
            return None
        return max(0, int(limit) - int((d / "memory.current").read_text()))
    except (OSError, ValueError, StopIteration):
        return None


def available_memory() -> tuple[int, str] | None:
    """(bytes, what limits them): the most this process can still allocate, the least of
    the host's available memory (MemAvailable + free swap), its cgroup's limit and its
    address-space limit (ulimit -v); None where none of them can be read."""
    room = []
    info = _meminfo()
    if "MemAvailable" in info:
        room.append((info["MemAvailable"] + info.get("SwapFree", 0), "available on this host"))
    cg = _cgroup_room()
    if cg is not None:
        room.append((cg, "left under this process's memory limit (cgroup)"))
    try:
        soft = resource.getrlimit(resource.RLIMIT_AS)[0]
    except (OSError, ValueError, AttributeError):
        soft = resource.RLIM_INFINITY
    if soft != resource.RLIM_INFINITY:
        room.append((max(0, soft - _vm_size()), "left under the address-space limit (ulimit -v)"))
    return min(room) if room else None


def _gib(n) -> str:
    return f"{n / 2**30:.1f} GiB" if n >= 2**30 / 10 else f"{n / 2**20:.1f} MiB"


def check_memory(need: int, path, what: str, fix: str):
    """Refuse (UserError) to allocate `need` bytes for `what` when more than that is not
    available (`available_memory`): one line before the allocation, instead of a
    MemoryError or the OOM killer part way through."""
    room = available_memory()
    if room is not None and need > room[0]:
        raise UserError(f"{what} needs about {_gib(need)} of memory, more than the "
                        f"{_gib(room[0])} {room[1]}", path=path, fix=fix)
