"""Input files: checked before they are opened, and kept apart from the output.

`check_input` refuses what `open()` would block on or fail at (FIFOs, devices, sockets,
directories, unreadable files) with a message that says which it is; `refuse_overwrite`
refuses an output that is one of the inputs (the same inode, whether reached through a
symlink, a hard link or another spelling of the path).
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

from .errors import UserError


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
        raise UserError("no such file", path=p, fix="check the path") from None
    except NotADirectoryError:
        raise UserError("no such file (a folder on its path is a file)", path=p,
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


def npy_header(f):
    """(shape, dtype, offset of the data) of the .npy stream f, read without the data."""
    import numpy as np
    fmt = np.lib.format
    version = fmt.read_magic(f)
    if version == (1, 0):
        shape, _, dtype = fmt.read_array_header_1_0(f)
    elif version == (2, 0):
        shape, _, dtype = fmt.read_array_header_2_0(f)
    else:
        shape, _, dtype = fmt._read_array_header(f, version)
    return shape, dtype, f.tell()
