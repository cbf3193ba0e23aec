"""Atomic output, the one way volrender writes files (images, brick caches, tree views,
benchmark JSON).

    with atomic.replace(path) as f:      # f: a binary file object on a temporary file
        f.write(data)

The data goes to a new temporary file beside the destination, named
`.volrender-<pid>-<hex>.tmp<suffix>` (ASCII and short, whatever the destination is called); it is
flushed, fsync'ed and renamed over the destination only once complete, then the directory
is fsync'ed. The writer holds an exclusive lock (flock) on its temporary file until the
rename, which tells a live writer's file from a dead one's also across hosts sharing the
directory and when a pid has been reused. On any failure or interruption (an exception, Ctrl-C, SIGTERM, SIGHUP: the CLI
turns the last two into `process.Interrupted`) the temporary file is removed and an existing
destination is untouched. SIGINT/SIGTERM/SIGHUP are held back (process.signals_held) while the
temporary file is created and while it is renamed, so no signal can fall between creating
the file and guarding it, or between the rename and recording it in `WRITTEN`. Only SIGKILL
(or a crash, a power cut) can leave a temporary file behind: the first write of a later
process into the same directory removes those that no process holds locked and whose pid
is gone or that are older than STALE_AGE (`sweep`); nothing else is touched.

Decisions (README, "Outputs"): a destination that is a symlink is written through (its
target is replaced, the link stays); an existing destination that is read-only, or that
is not a regular file (a FIFO, a device), is refused; new files get mode 0666 minus the
umask (0644 usually), a replaced file keeps its permission bits.
"""
from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import re
import secrets
import stat
import time
from pathlib import Path

from .errors import UserError
from .process import signals_held

PREFIX = ".volrender-"
TEMP_RE = re.compile(r"^\.volrender-(\d+)-[0-9a-f]{8}\.tmp(\.[A-Za-z0-9]{1,8})?$")
STALE_AGE = 24 * 3600              # seconds after which an unlocked temporary file is stale
WRITTEN: list = []                 # destinations completed by this process, in order
_SWEPT: set = set()                # directories swept by this process (once each)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:                 # EPERM: it exists, owned by someone else
        return True
    return True


def _lock(fd) -> bool | None:
    """Take an exclusive lock on fd without waiting: True, False when another process
    holds it, None where the file system has no locks."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except BlockingIOError:
        return False
    except OSError as e:
        if e.errno in (errno.EAGAIN, errno.EACCES):
            return False
        return None


def sweep(directory, now=None) -> list:
    """Remove our temporary files in `directory` left by processes that no longer run
    (SIGKILL, a crash): regular files named `.volrender-<pid>-<hex>.tmp[.suffix]` that no
    process holds locked and whose pid is gone (on this host) or that were last modified
    more than STALE_AGE seconds ago (a reused pid). Returns the names removed."""
    removed = []
    try:
        names = os.listdir(directory)
    except OSError:
        return removed
    now = time.time() if now is None else now
    for name in names:
        m = TEMP_RE.match(name)
        if not m or int(m.group(1)) == os.getpid():
            continue
        path = os.path.join(directory, name)
        try:
            fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
        except OSError:                 # gone already, a symlink, unreadable
            continue
        try:
            st = os.fstat(fd)
            if not stat.S_ISREG(st.st_mode) or _lock(fd) is False:
                continue
            if _alive(int(m.group(1))) and now - st.st_mtime <= STALE_AGE:
                continue
            with contextlib.suppress(OSError):
                if os.path.samestat(os.lstat(path), st):
                    os.unlink(path)
                    removed.append(name)
        finally:
            os.close(fd)
    return removed


def destination(path, what: str = "output") -> Path:
    """The file a write to `path` replaces: absolute, symlinks followed. Refuses a symlink
    loop, a name too long, a vanished working directory, a directory, a FIFO or device,
    and a read-only existing file."""
    p = Path(os.fsdecode(path)).expanduser() if isinstance(path, bytes) else Path(path).expanduser()
    try:
        if not p.is_absolute():
            p = Path(os.getcwd()) / p
    except FileNotFoundError:
        raise UserError(f"the {what} path is relative and the working directory no longer "
                        "exists", path=path, fix="give an absolute path, or cd somewhere") from None
    name_max = 255
    with contextlib.suppress(OSError, ValueError):
        name_max = os.pathconf(p.parent if p.parent.is_dir() else "/", "PC_NAME_MAX")
    if len(os.fsencode(p.name)) > name_max:
        raise UserError(f"{what} file name is {len(os.fsencode(p.name))} bytes long, more "
                        f"than the {name_max} this file system allows", path=_short(p),
                        fix="choose a shorter name")
    try:
        real = Path(os.path.realpath(p, strict=True))
    except (FileNotFoundError, NotADirectoryError):   # not there yet, a dangling link
        real = Path(os.path.realpath(p))
    except OSError as e:
        reason = "a symlink loop" if e.errno == 40 else (e.strerror or str(e))
        raise UserError(f"cannot follow the {what} path ({reason})", path=_short(p),
                        fix="fix or remove the symlink, or choose another name") from None
    try:
        st = os.stat(real)
    except (FileNotFoundError, NotADirectoryError):
        return real
    except OSError as e:
        raise UserError(f"cannot use the {what} path ({e.strerror})", path=_short(p),
                        fix="choose another name") from None
    if stat.S_ISDIR(st.st_mode):
        raise UserError(f"{what} path is a directory", path=_short(p), fix="give a file name")
    if not stat.S_ISREG(st.st_mode):
        raise UserError(f"{what} path exists and is not a regular file ({_kind(st.st_mode)})",
                        path=_short(p), fix="remove it or choose another name")
    if not os.access(real, os.W_OK):
        raise UserError(f"{what} file exists and is read-only", path=_short(p),
                        fix="make it writable (chmod u+w) or choose another name")
    return real


def _short(p) -> str:
    s = str(p)
    return s if len(s) <= 120 else s[:60] + "..." + s[-40:]


def _kind(mode) -> str:
    return {stat.S_IFIFO: "a FIFO", stat.S_IFCHR: "a character device",
            stat.S_IFBLK: "a block device", stat.S_IFSOCK: "a socket"}.get(stat.S_IFMT(mode),
                                                                           "not a file")


def _fsync_dir(directory):
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _failed(e: OSError, dest, doing: str) -> UserError:
    fix = {errno.ENOSPC: "free some disk space", errno.EDQUOT: "free some disk space (quota)",
           errno.EACCES: "check the directory's permissions",
           errno.EROFS: "the file system is read-only; choose another directory"}.get(
        e.errno, "check free disk space and the directory's permissions")
    return UserError(f"cannot write {doing} ({e.strerror or e})", path=_short(dest), fix=fix)


@contextlib.contextmanager
def _temporary(path, what, by_name):
    dest = destination(path, what)
    directory = dest.parent
    if not directory.is_dir():
        raise UserError(f"{what} directory {_short(directory)!r} does not exist",
                        path=_short(dest), fix=f"create it first (mkdir -p {_short(directory)})")
    if directory not in _SWEPT:
        _SWEPT.add(directory)
        sweep(directory)
    keep_mode = None
    with contextlib.suppress(OSError):
        keep_mode = stat.S_IMODE(os.stat(dest).st_mode)
    suffix = dest.suffix if re.fullmatch(r"\.[A-Za-z0-9]{1,8}", dest.suffix) else ""
    tmp, created, lock_fd = None, False, None
    try:
        with signals_held():
            while True:
                tmp = directory / f"{PREFIX}{os.getpid()}-{secrets.token_hex(4)}.tmp{suffix}"
                try:
                    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC,
                                 0o666)
                    break
                except FileExistsError:
                    continue
            lock_fd = os.dup(fd)        # held until the rename: the file is in use
            _lock(lock_fd)
            f = os.fdopen(fd, "wb")
        created = True
        if by_name:
            f.close()
            yield str(tmp)
            f = open(tmp, "rb+")
        try:
            if not by_name:
                yield f
            f.flush()
            os.fsync(f.fileno())
        finally:
            f.close()
        if keep_mode is not None:
            os.chmod(tmp, keep_mode)
        with signals_held():
            os.replace(tmp, dest)
            tmp = None
            WRITTEN.append(dest)
        _fsync_dir(directory)
    except OSError as e:
        raise _failed(e, dest, "it" if created else "a new file in its directory") from None
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        if lock_fd is not None:
            os.close(lock_fd)


def replace(path, what: str = "output"):
    """Context manager: a binary file object on a new temporary file beside `path`'s
    destination (see `destination`), which replaces the destination once the block ends
    without an exception. OSErrors become UserErrors naming the file."""
    return _temporary(path, what, by_name=False)


def replace_by_name(path, what: str = "output"):
    """As `replace`, but yields the temporary file's name (for libraries that write by
    name, e.g. pyvista); the name ends in the destination's suffix, so libraries that
    pick the format by suffix still can."""
    return _temporary(path, what, by_name=True)


def write_bytes(path, data: bytes, what: str = "output") -> Path:
    """Write `data` to `path` atomically; returns the destination."""
    with replace(path, what) as f:
        f.write(data)
    return WRITTEN[-1]
