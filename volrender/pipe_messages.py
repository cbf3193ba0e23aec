"""Length-prefixed messages over a pipe between this process and a helper process of its
own (vdb.py's OpenVDB reader, frame_writer.py's writer): 8 bytes of length, then the bytes."""
from __future__ import annotations

import struct


def send(f, data: bytes, flush: bool = True):
    f.write(struct.pack("<Q", len(data)))
    f.write(data)
    if flush:
        f.flush()


def receive(f) -> bytes:
    """The next message; EOFError where the pipe ends first."""
    head = f.read(8)
    if len(head) != 8:
        raise EOFError
    n = struct.unpack("<Q", head)[0]
    data = f.read(n)
    if len(data) != n:
        raise EOFError
    return data
