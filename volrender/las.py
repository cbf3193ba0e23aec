"""LAS and LAZ point clouds through laspy (lazrs decodes LAZ), with the guarantees of the
hand-written parsers: the public header block is read and checked here before laspy sees
the file (the signature, the version, the header and record sizes, the VLR and EVLR
counts against the bytes that could hold them, and an uncompressed file's point count
against its size, exactly), the memory the points need is checked against what this
process can still get before anything is decoded, and whatever the decoder raises on a
damaged file is one line naming it.

A LAZ file's point count can only be bounded by its size: the records it promises may be
at most MAX_LAZ_RATIO times its compressed bytes (identical points, the most a LAZ
compresses, come to about 2800 times; real scans 5 to 15); the memory check bounds the
rest, and decoding stops where the compressed bytes end.
"""
from __future__ import annotations

import logging
import os
import struct

import numpy as np

from .cloud import MEMORY_FIX
from .errors import UserError
from .files import check_memory

FIX = "check the file, or convert it again (LAZ needs laspy's lazrs backend)"
# the smallest record of each point data format (LAS 1.4, table 7 and on)
RECORD_SIZE = {0: 20, 1: 28, 2: 26, 3: 34, 4: 57, 5: 63, 6: 30, 7: 36, 8: 38, 9: 59, 10: 67}
VLR_HEADER, EVLR_HEADER = 54, 60
BYTES_PER_POINT = 3 * (3 * 8 + 3 * 4)    # the float64 copies and colours held per point
MAX_LAZ_RATIO = 4096                     # records' bytes per compressed byte, at most


def check_header(path, head: bytes, size: int) -> tuple[int, bool, int]:
    """(point count, compressed, record size) of a LAS/LAZ file from its first 375 bytes `head` and its
    size; UserError (naming the file) when the header cannot describe the file."""
    def bad(problem):
        return UserError(problem, path=path, fix=FIX)
    if len(head) < 227 or head[:4] != b"LASF":
        raise bad("not a LAS/LAZ file (no 'LASF' signature)" if head[:4] != b"LASF"
                  else f"not a readable LAS/LAZ file (its header is 227 bytes at least, the file "
                       f"holds {size})")
    major, minor = head[24], head[25]
    if major != 1 or minor > 4:
        raise bad(f"LAS version {major}.{minor} is not one laspy reads (1.0 to 1.4)")
    header_size, offset, n_vlrs = struct.unpack_from("<HII", head, 94)
    fmt_byte, record = struct.unpack_from("<BH", head, 104)
    count = struct.unpack_from("<I", head, 107)[0]
    least = 375 if minor >= 4 else 227
    if not least <= header_size <= offset <= size:
        raise bad(f"the header says it is {header_size} bytes and the points start at byte "
                  f"{offset}, in a file of {size} bytes (the header is {least} bytes at least)")
    if n_vlrs * VLR_HEADER > offset - header_size:
        raise bad(f"the header says {n_vlrs} variable-length records, more than the "
                  f"{offset - header_size} bytes before the points can hold")
    fmt, compressed = fmt_byte & 0x3F, bool(fmt_byte & 0xC0)
    if fmt not in RECORD_SIZE or record < RECORD_SIZE[fmt]:
        raise bad(f"point format {fmt} with {record}-byte records is not a LAS point format"
                  if fmt not in RECORD_SIZE else
                  f"point format {fmt} takes records of {RECORD_SIZE[fmt]} bytes at least, the "
                  f"header says {record}")
    end = size
    if minor >= 4 and len(head) >= 375:
        evlr_start, n_evlrs, count14 = struct.unpack_from("<QIQ", head, 235)
        count = count14 or count
        if n_evlrs:
            if not offset <= evlr_start <= size or n_evlrs * EVLR_HEADER > size - evlr_start:
                raise bad(f"the header says {n_evlrs} extended records from byte {evlr_start}, "
                          f"more than the {size}-byte file holds")
            end = evlr_start
    if count == 0:
        raise bad("the file holds no points")
    if not compressed and count * record > end - offset:
        raise bad(f"the header says {count} points of {record} bytes, but the file holds "
                  f"{end - offset} bytes of points (it is cut short)")
    if compressed and count * record > (end - offset) * MAX_LAZ_RATIO:
        raise bad(f"the header says {count} points of {record} bytes, more than "
                  f"{MAX_LAZ_RATIO} times the {end - offset} compressed bytes could hold "
                  "(the header is damaged)")
    return count, compressed, record


def read_las(path):
    """(centres, radii, colours, notes, up axis, why) of a LAS/LAZ file: the header checked (check_header)
    and the memory checked before laspy decodes it."""
    try:
        import laspy
    except ImportError:
        raise UserError("reading .las/.laz needs laspy", path=path,
                        fix="pip install 'volrender[las]' (laspy with its LAZ backend)") from None
    try:
        with open(path, "rb") as f:
            head = f.read(375)
            size = os.fstat(f.fileno()).st_size
    except OSError as exc:
        raise UserError(f"cannot read it ({exc.strerror or exc})", path=path, fix=FIX) from None
    n, compressed, record = check_header(path, head, size)
    check_memory(n * (record + BYTES_PER_POINT), path, f"reading {n} LAS points", MEMORY_FIX)
    quiet = logging.getLogger("laspy")          # it logs each decoding error as well
    level, quiet.level = quiet.level, logging.CRITICAL + 1
    try:
        with laspy.open(path) as reader:
            las = reader.read()
            offset = ", ".join(f"{v:.10g}" for v in reader.header.offsets)
        xyz = [np.asarray(las.x, np.float64), np.asarray(las.y, np.float64),
               np.asarray(las.z, np.float64)]
        names = set(las.point_format.dimension_names)
        rgb = (np.column_stack([las.red, las.green, las.blue]).astype(np.float64)
               if {"red", "green", "blue"} <= names else None)
        fmt = las.point_format.id
    except MemoryError:
        raise UserError("out of host memory while decoding it", path=path, fix=MEMORY_FIX) from None
    except Exception as exc:      # noqa: BLE001 (laspy and lazrs raise many kinds on damage)
        first = (str(exc).splitlines() or [type(exc).__name__])[0][:160]
        raise UserError(f"not a readable {'LAZ' if compressed else 'LAS'} file "
                        f"({type(exc).__name__}: {first})", path=path, fix=FIX) from None
    finally:
        quiet.setLevel(level)
    if len(xyz[0]) != n:
        raise UserError(f"the header says {n} points, {len(xyz[0])} were decoded", path=path,
                        fix=FIX)
    colors = None
    if rgb is not None and rgb.max() > 0:
        colors = (rgb / (65535.0 if rgb.max() > 255 else 255.0)).astype(np.float32)
    notes = (f"{path}: {n} LAS points (format {fmt}, offset {offset})",)
    return np.column_stack(xyz), None, colors, notes, "z", "ASPRS LAS is Z-up"
