"""Point-cloud input (PLY, XYZ/CSV/TXT, NPY) and seeded generators.

Every point becomes a sphere: ``centers`` (N,3) float64, optional per-point
``radii`` (N,) float64 and ``colors`` (N,3) float32 in 0..1.

Bad input is reported as :class:`~volrender.errors.UserError` naming the file,
the problem and the fix.  Non-finite coordinates are an error, never dropped
silently: a scan with NaN rows usually means the wrong columns were read.
"""
from __future__ import annotations

import io
import math
import os
import struct
import tokenize
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import UserError
from .files import check_input, check_memory, npy_header

__all__ = ["PointCloud", "load_points", "read_points", "blob", "uniform_box", "glass_gather",
           "generate", "GENERATORS"]


MAX_COORDINATE = 1e18       # |coordinate| accepted from files (glass.MAX_EXTENT: float32 squares)
MAX_PLY_HEADER = 1 << 20    # bytes of PLY header read before 'end_header' must have come
_CHUNK_LINES = 1 << 16      # text lines parsed at a time
_MEMORY_FIX = "load a smaller or decimated cloud, or free memory"


@dataclass(frozen=True)
class PointCloud:
    """Sphere centres with optional per-point radius and colour."""

    centers: np.ndarray                 # float64 (N, 3)
    radii: np.ndarray | None = None     # float64 (N,) or None (renderer picks one radius)
    colors: np.ndarray | None = None    # float32 (N, 3) in 0..1, or None
    source: str = ""

    def __post_init__(self):
        c = np.ascontiguousarray(self.centers, dtype=np.float64)
        if c.ndim != 2 or c.shape[1] != 3:
            raise ValueError(f"centers must be (N, 3), got {c.shape}")
        object.__setattr__(self, "centers", c)
        if self.radii is not None:
            r = np.ascontiguousarray(self.radii, dtype=np.float64)
            if r.shape != (len(c),):
                raise ValueError(f"radii must be ({len(c)},), got {r.shape}")
            object.__setattr__(self, "radii", r)
        if self.colors is not None:
            k = np.ascontiguousarray(self.colors, dtype=np.float32)
            if k.shape != (len(c), 3):
                raise ValueError(f"colors must be ({len(c)}, 3), got {k.shape}")
            object.__setattr__(self, "colors", k)

    def __len__(self) -> int:
        return len(self.centers)


# --------------------------------------------------------------------------- loading

def load_points(path) -> PointCloud:
    """Read a point cloud; the format follows the suffix.

    ``.ply``  ASCII, binary_little_endian or binary_big_endian, elements in any
              order.  The ``vertex`` element needs x, y, z; optional radius
              (property ``radius``, else ``scale``) and colour ``red``/``green``/
              ``blue`` (integer types are divided by their maximum, e.g. uchar/255;
              float colours must already be in 0..1).  Other properties and
              elements (faces, range_grid, ...) are skipped; elements after the
              vertex element are not read at all.  ASCII rows are one per line
              (blank lines ignored); float properties are read as float64.
    ``.xyz`` / ``.csv`` / ``.txt``  one point per line, numbers separated by
              whitespace and/or commas; an optional header line (the first line,
              if it is not all numbers); blank lines and ``#`` comments skipped.
              3 columns = x y z, 4 = x y z radius, 6 = x y z r g b,
              7 = x y z radius r g b.  Colours are taken as 0..1 when none
              exceeds 1, else as 0..255.
    ``.npy``  an (N,3) array of centres or (N,4) with the radius as 4th column.

    Raises UserError on a missing file, an unsupported suffix, a malformed or
    truncated file, zero points, NaN/Inf coordinates, or negative/non-finite radii.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in _READERS and suffix != ".npy":
        raise UserError(f"unsupported suffix '{suffix or '(none)'}' for a point cloud",
                        path=path, fix="use .ply, .xyz, .csv, .txt or .npy")
    check_input(path, "point-cloud file")
    if suffix == ".npy":
        return _finish(path, *_read_npy(path))
    with open(path, "rb") as f:
        return read_points(f, suffix, path)


def read_points(f, suffix: str, label="<stream>") -> PointCloud:
    """`load_points` of the open binary stream `f` (a file, or io.BytesIO), read as a file
    of `suffix` (.ply, .xyz, .csv, .txt); `label` names it in messages. Reads headers
    first and no more of the body than the header says it needs."""
    if suffix not in _READERS:
        raise UserError(f"unsupported suffix '{suffix or '(none)'}' for a point-cloud stream",
                        path=label, fix="use .ply, .xyz, .csv or .txt")
    size = _stream_size(f)
    return _finish(label, *_READERS[suffix](f, size, label))


def _stream_size(f) -> int:
    try:
        return os.fstat(f.fileno()).st_size
    except (AttributeError, OSError, io.UnsupportedOperation):
        pos = f.tell()
        end = f.seek(0, io.SEEK_END)
        f.seek(pos)
        return end


def _finish(path, centers, radii, colors) -> PointCloud:
    n = len(centers)
    if n == 0:
        raise UserError("the file holds zero points", path=path,
                        fix="give a file with at least one point")
    bad = ~np.isfinite(centers).all(axis=1)
    if bad.any():
        raise UserError(f"{int(bad.sum())} of {n} points have NaN/Inf coordinates "
                        f"(first: point {int(np.argmax(bad))})", path=path,
                        fix="remove or repair those points")
    far = np.abs(centers).max(axis=1) > MAX_COORDINATE
    if far.any():
        i = int(np.argmax(far))
        raise UserError(f"{int(far.sum())} of {n} points lie beyond +-{MAX_COORDINATE:g}, "
                        f"where float32 rendering cannot follow (first: point {i}, "
                        f"{tuple(float(v) for v in centers[i])})", path=path,
                        fix="rescale or recentre the cloud")
    if radii is not None:
        bad = ~np.isfinite(radii) | (radii < 0) | (radii > MAX_COORDINATE)
        if bad.any():
            i = int(np.argmax(bad))
            raise UserError(f"{int(bad.sum())} radii are negative, NaN/Inf or above "
                            f"{MAX_COORDINATE:g} (first: point {i}, radius {radii[i]})",
                            path=path, fix=f"radii must be in [0, {MAX_COORDINATE:g}]")
    if colors is not None:
        if not np.isfinite(colors).all() or colors.min() < 0 or colors.max() > 1:
            raise UserError(f"colours outside 0..1 (range {np.nanmin(colors)}.."
                            f"{np.nanmax(colors)})", path=path,
                            fix="store float colours in 0..1, or as uchar 0..255")
    return PointCloud(centers=centers, radii=radii, colors=colors, source=str(path))


# ---- PLY

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_PLY_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}


@dataclass
class _Element:
    name: str
    count: int
    props: list  # (name, type) or (name, "list", count_type, item_type)

    def has_lists(self) -> bool:
        return any(len(p) == 4 for p in self.props)

    def dtype(self, endian: str) -> np.dtype:
        return np.dtype([(p[0], endian + p[1]) for p in self.props])


class _NeedMore(Exception):
    """The header read so far ends before its 'end_header' line."""


def _check_ply_magic(path, start: bytes):
    if not start:
        raise UserError("file is empty", path=path, fix="give a non-empty PLY file")
    if not (start.startswith(b"ply\n") or start.startswith(b"ply\r\n")):
        raise UserError("not a PLY file (first line is not 'ply')", path=path,
                        fix="check the file, or give it its proper suffix")


def _read_ply_header(path, f):
    """(format, elements, body offset, header line count), reading the stream `f` from its
    start only as far as the header goes: the first 5 bytes decide 'not a PLY file', and a
    header longer than MAX_PLY_HEADER is refused."""
    buf = f.read(5)
    _check_ply_magic(path, buf)
    while True:
        try:
            return _parse_ply_header(path, buf)
        except _NeedMore:
            pass
        if len(buf) >= MAX_PLY_HEADER:
            raise UserError(f"bad PLY header: no 'end_header' line in its first "
                            f"{MAX_PLY_HEADER >> 20} MiB", path=path,
                            fix="the file is truncated or not a PLY file")
        more = f.read(min(max(len(buf), 4096), MAX_PLY_HEADER - len(buf)))
        if not more:
            raise UserError("bad PLY header: no 'end_header' line", path=path,
                            fix="the file is truncated or not a PLY file")
        buf += more


def _parse_ply_header(path, data: bytes):
    """Return (format, elements, body_offset, header_line_count); _NeedMore where `data`
    ends inside the header."""
    _check_ply_magic(path, data)
    pos = 0
    fmt = None
    elements: list[_Element] = []
    lineno = 0
    while True:
        nl = data.find(b"\n", pos)
        if nl < 0:
            raise _NeedMore()
        raw = data[pos:nl]
        pos = nl + 1
        lineno += 1
        try:
            words = raw.decode("ascii").split()
        except UnicodeDecodeError:
            raise UserError(f"bad PLY header: line {lineno} is not ASCII text", path=path,
                            fix="the header must end with 'end_header'") from None
        if not words or lineno == 1:
            continue
        key = words[0]
        where = f"bad PLY header line {lineno} ('{' '.join(words)}')"
        if key == "end_header":
            break
        if key in ("comment", "obj_info"):
            continue
        if key == "format":
            if len(words) < 2 or words[1] not in _PLY_FORMATS:
                raise UserError(f"{where}: unknown format", path=path,
                                fix="use ascii, binary_little_endian or binary_big_endian")
            fmt = words[1]
        elif key == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise UserError(f"{where}: expected 'element <name> <count>'", path=path,
                                fix="repair the header")
            if len(words[2]) > 18:
                raise UserError(f"{where}: an element count of {len(words[2])} digits",
                                path=path, fix="repair the header")
            elements.append(_Element(words[1], int(words[2]), []))
        elif key == "property":
            if not elements:
                raise UserError(f"{where}: property before any element", path=path,
                                fix="repair the header")
            if len(words) == 3 and words[1] in _PLY_TYPES:
                prop = (words[2], _PLY_TYPES[words[1]])
            elif (len(words) == 5 and words[1] == "list" and words[2] in _PLY_TYPES
                  and words[3] in _PLY_TYPES):
                if _PLY_TYPES[words[2]][0] not in "iu":
                    raise UserError(f"{where}: a list's count must have an integer type",
                                    path=path, fix="use e.g. 'property list uchar int ...'")
                prop = (words[4], "list", _PLY_TYPES[words[2]], _PLY_TYPES[words[3]])
            else:
                raise UserError(f"{where}: unknown property type", path=path,
                                fix="use char/uchar/short/ushort/int/uint/float/double")
            if any(p[0] == prop[0] for p in elements[-1].props):
                raise UserError(f"{where}: duplicate property '{prop[0]}'", path=path,
                                fix="repair the header")
            elements[-1].props.append(prop)
        else:
            raise UserError(f"{where}: unknown keyword '{key}'", path=path,
                            fix="repair the header")
    if fmt is None:
        raise UserError("bad PLY header: no 'format' line", path=path,
                        fix="add 'format ascii 1.0' (or binary_little_endian)")
    return fmt, elements, pos, lineno


def _read_ply(f, size, path):
    fmt, elements, body, nheader = _read_ply_header(path, f)
    names = [e.name for e in elements]
    if "vertex" not in names:
        raise UserError("PLY file has no 'vertex' element", path=path,
                        fix="give a point cloud with 'element vertex N'")
    vi = names.index("vertex")
    vertex = elements[vi]
    pnames = [p[0] for p in vertex.props]
    for axis in "xyz":
        if axis not in pnames:
            raise UserError(f"PLY vertex element has no '{axis}' property", path=path,
                            fix="the vertex element needs float x, y, z")
        if any(p[0] == axis and len(p) == 4 for p in vertex.props):
            raise UserError(f"PLY vertex property '{axis}' is a list", path=path,
                            fix="x, y and z must be scalar properties (property float x)")
    f.seek(body)
    if fmt == "ascii":
        cols = _ply_ascii_vertices(path, f, size - body, elements[:vi], vertex, nheader)
    else:
        cols = _ply_binary_vertices(path, f, size, body, elements[:vi], vertex,
                                    _PLY_FORMATS[fmt])
    types = {p[0]: p[1] for p in vertex.props}
    centers = np.stack([np.asarray(cols[a], dtype=np.float64) for a in "xyz"], axis=1)
    radii = None
    for rname in ("radius", "scale"):
        if rname in cols and types[rname] != "list":
            radii = np.asarray(cols[rname], dtype=np.float64)
            break
    colors = None
    rgb = ("red", "green", "blue")
    if all(c in cols and types[c] != "list" for c in rgb):
        chans = []
        for c in rgb:
            v = np.asarray(cols[c], dtype=np.float64)
            if types[c][0] in "iu":
                v = v / float(np.iinfo(np.dtype(types[c])).max)
            chans.append(v)
        colors = np.stack(chans, axis=1).astype(np.float32)
    return centers, radii, colors


def _cloud_bytes(n, vertex) -> int:
    """Bytes of the arrays a cloud of n points becomes (centres, radii, colours, and the
    float64 columns they are made from)."""
    return 8 * n * (2 * 3 + 2 + 3) + 4 * n * 3


class _Projection:
    """Memory check of a reader that parses a stream in chunks: after each chunk the
    memory still to come is projected from what the chunks so far took per byte or row."""

    def __init__(self, path, total):
        self.path, self.total, self.done, self.used = path, total, 0, 0

    def add(self, done, used):
        self.done += done
        self.used += used
        if self.done and self.total > self.done:
            more = self.used * (self.total - self.done) / self.done
            # the chunks still to come, then one copy of everything (np.concatenate)
            check_memory(int(more + self.used + more), self.path, "reading this point cloud",
                         _MEMORY_FIX)


def _ply_ascii_vertices(path, f, nbytes, before, vertex, nheader):
    """The vertex rows of an ASCII body read from `f` (`nbytes` left in it), a chunk of
    lines at a time; blank lines are skipped, rows after the vertex element are not read."""
    skip = sum(e.count for e in before)
    lineno = nheader
    nprop = len(vertex.props)
    if skip:
        for line in f:
            lineno += 1
            nbytes -= len(line)
            if line.strip():
                skip -= 1
                if skip == 0:
                    break
    # each value takes at least 2 bytes (a digit and a space or a newline): more rows
    # than that cannot be there, whatever the header says
    rows_possible = min(vertex.count, max(nbytes, 0) // (2 * nprop))
    projection = _Projection(path, rows_possible)
    parts, got = [], 0
    lines, numbers = [], []
    want = vertex.count if not skip else 0
    it = iter(f) if want else iter(())
    for line in it:
        lineno += 1
        if not line.strip():
            continue
        lines.append(line)
        numbers.append(lineno)
        if len(lines) == _CHUNK_LINES or got + len(lines) == want:
            part = _ply_ascii_chunk(path, lines, numbers, vertex)
            parts.append(part)
            got += len(lines)
            projection.add(len(lines), sum(v.nbytes for v in part.values()))
            lines, numbers = [], []
            if got == want:
                break
    if got + len(lines) < vertex.count:
        raise UserError(f"truncated ASCII PLY: header says {vertex.count} vertices, "
                        f"file holds {got + len(lines)}", path=path,
                        fix="re-export the file or fix the vertex count")
    names = [p[0] for p in vertex.props if len(p) == 2]
    if len(parts) == 1:
        return parts[0]
    if not parts:
        return {name: np.zeros(0) for name in names}
    return {name: np.concatenate([part[name] for part in parts]) for name in names}


def _ply_ascii_chunk(path, vlines, linenos, vertex):
    """{scalar property: float64 column} of ASCII vertex rows."""
    names = [p[0] for p in vertex.props]

    def lineno(k):
        return linenos[k]

    if vertex.has_lists():
        return _ply_ascii_rows_with_lists(path, vlines, vertex, lineno)
    nprop = len(vertex.props)
    tokens = b" ".join(vlines).split()
    if len(tokens) != nprop * len(vlines):
        for k, line in enumerate(vlines):
            got = len(line.split())
            if got != nprop:
                raise UserError(f"line {lineno(k)}: expected {nprop} numbers, got {got}",
                                path=path, fix="each vertex line needs one value per property")
    try:
        values = np.array(tokens, dtype=np.float64).reshape(len(vlines), nprop)
    except ValueError:
        for k, line in enumerate(vlines):
            for tok in line.split():
                try:
                    float(tok)
                except ValueError:
                    raise UserError(f"line {lineno(k)}: '{tok.decode(errors='replace')}' "
                                    "is not a number", path=path,
                                    fix="repair the vertex data") from None
        raise
    return {name: values[:, j] for j, name in enumerate(names)}


def _ply_ascii_rows_with_lists(path, vlines, vertex, lineno):
    out = {p[0]: [] for p in vertex.props if len(p) == 2}
    for k, line in enumerate(vlines):
        toks = line.split()
        t = 0
        try:
            for p in vertex.props:
                if len(p) == 2:
                    out[p[0]].append(float(toks[t]))
                    t += 1
                else:
                    n = int(toks[t])
                    if n < 0:
                        raise ValueError("negative list count")
                    t += 1 + n
        except (IndexError, ValueError):
            raise UserError(f"line {lineno(k)}: malformed vertex row", path=path,
                            fix="each vertex line needs one value per property") from None
        if t != len(toks):
            raise UserError(f"line {lineno(k)}: expected {t} numbers, got {len(toks)}",
                            path=path, fix="each vertex line needs one value per property")
    return {k: np.array(v) for k, v in out.items()}


def _ply_binary_vertices(path, f, size, offset, before, vertex, endian):
    """The vertex columns of a binary body. Elements of fixed-size rows before the vertex
    element are skipped by offset and only the vertex rows are read; rows with lists
    (faces before the vertices, lists in the vertex element) need the bytes read."""
    if not vertex.has_lists() and not any(e.has_lists() for e in before):
        for elem in before:
            offset += elem.count * elem.dtype(endian).itemsize
            if offset > size:
                raise UserError(f"truncated binary PLY: the file ends inside the "
                                f"'{elem.name}' element, before the vertex data", path=path,
                                fix="re-export or re-download the file")
        dt = vertex.dtype(endian)
        need = vertex.count * dt.itemsize
        if offset + need > size:
            holds = max(0, size - offset) // dt.itemsize
            raise UserError(f"truncated binary PLY: header says {vertex.count} vertices, "
                            f"file holds {holds}", path=path,
                            fix="re-export or re-download the file")
        check_memory(need + _cloud_bytes(vertex.count, vertex), path,
                     f"a cloud of {vertex.count} points", _MEMORY_FIX)
        arr = np.empty(vertex.count, dt)
        f.seek(offset)
        got = f.readinto(arr.view(np.uint8)) if need else 0
        if got != need:                         # the file shrank since it was measured
            raise UserError(f"truncated binary PLY: header says {vertex.count} vertices, "
                            f"file holds {got // dt.itemsize}", path=path,
                            fix="re-export or re-download the file")
        return {name: arr[name] for name in dt.names}
    rest = max(0, size - offset)
    check_memory(rest * 8, path, "reading this point cloud (rows with lists)", _MEMORY_FIX)
    f.seek(offset)
    data = f.read(rest)
    pos = 0
    for elem in before:
        pos = _skip_binary_element(path, data, pos, elem, endian)
    if vertex.has_lists():
        cols, _ = _walk_binary_rows(path, data, pos, vertex, endian, keep=True)
        return cols
    dt = vertex.dtype(endian)
    need = vertex.count * dt.itemsize
    if pos + need > len(data):
        holds = max(0, len(data) - pos) // dt.itemsize
        raise UserError(f"truncated binary PLY: header says {vertex.count} vertices, "
                        f"file holds {holds}", path=path,
                        fix="re-export or re-download the file")
    arr = np.frombuffer(data, dtype=dt, count=vertex.count, offset=pos)
    return {name: arr[name] for name in dt.names}


def _skip_binary_element(path, data, offset, elem, endian):
    """Return the offset just past ``elem``'s rows."""
    if not elem.has_lists():
        end = offset + elem.count * elem.dtype(endian).itemsize
    elif elem.count == 0:
        end = offset
    else:
        end = _skip_uniform_lists(data, offset, elem, endian)
        if end is None:
            end = _walk_binary_rows(path, data, offset, elem, endian, keep=False)[1]
    if end > len(data):
        raise UserError(f"truncated binary PLY: the file ends inside the "
                        f"'{elem.name}' element, before the vertex data", path=path,
                        fix="re-export or re-download the file")
    return end


def _skip_uniform_lists(data, offset, elem, endian):
    """Fast path: every row's lists have the first row's lengths (e.g. triangles).

    Returns the end offset, or None when the rows differ (or the data is short).
    """
    fields, lengths, pos = [], {}, offset
    for p in elem.props:
        if len(p) == 2:
            fields.append((p[0], endian + p[1]))
            pos += np.dtype(p[1]).itemsize
        else:
            if pos + np.dtype(p[2]).itemsize > len(data):
                return None
            n = int(np.frombuffer(data, endian + p[2], 1, pos)[0])
            if n < 0 or n * np.dtype(p[3]).itemsize > len(data):
                return None
            lengths[p[0]] = n
            fields.append((p[0], endian + p[2]))
            fields.append((p[0] + "#items", endian + p[3], (n,)))
            pos += np.dtype(p[2]).itemsize + n * np.dtype(p[3]).itemsize
    dt = np.dtype(fields)
    end = offset + elem.count * dt.itemsize
    if end > len(data):
        return None
    rows = np.frombuffer(data, dt, elem.count, offset)
    if any((rows[name] != n).any() for name, n in lengths.items()):
        return None
    return end


_STRUCT_CODES = {"i1": "b", "u1": "B", "i2": "h", "u2": "H", "i4": "i", "u4": "I",
                 "f4": "f", "f8": "d"}


def _walk_binary_rows(path, data, offset, elem, endian, keep):
    """Slow general path: step row by row.  Returns (scalar columns, end offset)."""
    cols = {p[0]: [] for p in elem.props if len(p) == 2}
    pos = offset
    try:
        for _ in range(elem.count):
            for p in elem.props:
                if len(p) == 2:
                    (v,) = struct.unpack_from(endian + _STRUCT_CODES[p[1]], data, pos)
                    if keep:
                        cols[p[0]].append(v)
                    pos += np.dtype(p[1]).itemsize
                else:
                    (n,) = struct.unpack_from(endian + _STRUCT_CODES[p[2]], data, pos)
                    if n < 0:
                        raise UserError(f"corrupt binary PLY: a negative list length ({n}) in "
                                        f"the '{elem.name}' element", path=path,
                                        fix="re-export or re-download the file")
                    pos += np.dtype(p[2]).itemsize + int(n) * np.dtype(p[3]).itemsize
    except struct.error:
        pos = len(data) + 1
    if pos > len(data):
        raise UserError(f"truncated binary PLY: the file ends inside the "
                        f"'{elem.name}' element (header says {elem.count} rows)", path=path,
                        fix="re-export or re-download the file")
    return {k: np.array(v, dtype=np.float64) for k, v in cols.items()}, pos


# ---- text: xyz / csv / txt

_TEXT_LAYOUT = {3: "x y z", 4: "x y z radius", 6: "x y z r g b", 7: "x y z radius r g b"}


def _read_text(f, size, path):
    """x y z [radius] [r g b] rows, a chunk of lines at a time (memory: the numbers, plus
    one chunk of text)."""
    fix = "give one point per line: x y z [radius] [r g b]"
    projection = _Projection(path, size)
    parts, ncols, header_checked, nonblank = [], None, False, False
    first_row = None
    lineno = 0
    while True:
        chunk = f.readlines(_CHUNK_LINES * 32)
        if not chunk:
            break
        raw = b"".join(chunk)
        if lineno == 0:
            raw = raw.removeprefix(b"\xef\xbb\xbf")
        nonblank = nonblank or bool(raw.strip())
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            raise UserError("not a text file (invalid UTF-8)", path=path, fix=fix) from None
        lines = text.replace(",", " ").replace(";", " ").split("\n")
        if text.endswith("\n"):
            lines.pop()
        rows, numbers = [], []
        for i, line in enumerate(lines):
            toks = line.split()
            if toks and not toks[0].startswith("#"):
                rows.append(lineno + i + 1)
                numbers.append(toks)
        lineno += len(lines)
        if not header_checked and rows:
            header_checked = True
            if not _all_numbers(numbers[0]):
                rows, numbers = rows[1:], numbers[1:]      # header line
        if not rows:
            continue
        if ncols is None:
            ncols, first_row = len(numbers[0]), rows[0]
            if ncols not in _TEXT_LAYOUT:
                raise UserError(f"line {rows[0]}: expected 3, 4, 6 or 7 numbers "
                                f"(x y z [radius] [r g b]), got {ncols}", path=path,
                                fix="use one of those column layouts")
        values = _text_values(path, rows, numbers, ncols)
        parts.append(values)
        projection.add(len(raw), values.nbytes)
    if not nonblank:
        raise UserError("file is empty", path=path, fix=fix)
    if not parts:
        raise UserError("the file holds zero points", path=path, fix=fix)
    values = parts[0] if len(parts) == 1 else np.concatenate(parts)
    centers = values[:, :3].copy()
    radii = values[:, 3].copy() if ncols in (4, 7) else None
    colors = None
    if ncols >= 6:
        rgb = values[:, -3:]
        if np.isfinite(rgb).all() and rgb.max() > 1.0:
            if rgb.max() > 255.0 or rgb.min() < 0.0:
                raise UserError(f"colours outside 0..255 (range {rgb.min()}..{rgb.max()})",
                                path=path, fix="give colours as 0..1 or 0..255")
            rgb = rgb / 255.0
        colors = rgb.astype(np.float32)
    return centers, radii, colors


def _text_values(path, rows, numbers, ncols):
    lens = np.fromiter(map(len, numbers), dtype=np.int64, count=len(numbers))
    bad = np.flatnonzero(lens != ncols)
    if bad.size:
        k = int(bad[0])
        raise UserError(f"line {rows[k]}: expected {ncols} numbers, got {int(lens[k])}",
                        path=path, fix=f"every line needs {ncols} numbers "
                                       f"({_TEXT_LAYOUT[ncols]}), like the first")
    try:
        values = np.array([t for toks in numbers for t in toks], dtype=np.float64)
    except ValueError:
        for k, toks in enumerate(numbers):
            if not _all_numbers(toks):
                raise UserError(f"line {rows[k]}: not all numbers: '{' '.join(toks)}'",
                                path=path, fix="only the first line may be a header") from None
        raise
    return values.reshape(-1, ncols)


def _all_numbers(tokens) -> bool:
    try:
        for t in tokens:
            float(t)
    except ValueError:
        return False
    return True


# ---- npy

def load_npy_checked(path, fix: str):
    """np.load of a .npy file once its header agrees with the file's size (a header that
    claims more than the file holds would otherwise ask for that much memory first)."""
    try:
        with open(path, "rb") as f:
            shape, dtype, start = npy_header(f)
        size = Path(path).stat().st_size
        if dtype.hasobject:
            raise UserError("the array holds Python objects, which volrender does not unpickle",
                            path=path, fix=fix)
        need = math.prod(shape) * dtype.itemsize
        if need != size - start:
            raise UserError(f"the .npy header says shape {shape} of {dtype} ({need} bytes), "
                            f"but the file holds {size - start} bytes of data", path=path,
                            fix=fix)
        # the array, its float64 copy and the columns taken from it
        check_memory(need + 3 * 8 * math.prod(shape), path, f"an array of shape {shape}",
                     "load a smaller array, or free memory")
        return np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError, TypeError, SyntaxError, tokenize.TokenError) as exc:
        raise UserError(f"not a readable .npy array ({exc})", path=path, fix=fix) from None


_READERS = {".ply": _read_ply, ".xyz": _read_text, ".csv": _read_text, ".txt": _read_text}


def _read_npy(path):
    arr = load_npy_checked(path, "save with numpy.save(path, array) of shape (N,3) or (N,4)")
    if not isinstance(arr, np.ndarray) or arr.dtype.kind not in "fiu" \
            or arr.ndim != 2 or arr.shape[1] not in (3, 4):
        desc = f"shape {getattr(arr, 'shape', '?')}, dtype {getattr(arr, 'dtype', '?')}"
        raise UserError(f"expected a numeric (N,3) or (N,4) array, got {desc}", path=path,
                        fix="columns are x y z [radius]")
    arr = arr.astype(np.float64)
    radii = arr[:, 3].copy() if arr.shape[1] == 4 else None
    return arr[:, :3].copy(), radii, None


# --------------------------------------------------------------------------- generators
#
# Each generator fills a fixed region of about unit size with n points and gives
# every point a radius proportional to the local mean spacing (V/n)^(1/3), so the
# number of overlapping neighbours per sphere stays about the same as n grows.

def _check_n(n, seed):
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise UserError(f"point count must be a positive integer, got {n!r}",
                        fix="pass n >= 1")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise UserError(f"seed must be an integer, got {seed!r}", fix="pass an int seed")
    # numpy refuses negative seeds; --seed -1 is accepted for volumes, so fold it into
    # 64 bits here too (non-negative seeds are unchanged)
    return int(n), np.random.default_rng(int(seed) % (1 << 64) if seed < 0 else int(seed))


def _in_ball(rng, n):
    d = rng.normal(size=(n, 3))
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    return d * rng.random(n)[:, None] ** (1.0 / 3.0)


def _jittered(rng, n, base):
    return base * rng.uniform(0.8, 1.2, n)


def blob(n: int, seed: int = 0) -> PointCloud:
    """Dense, slightly squashed ball of radius ~1; spheres overlap ~10 neighbours."""
    n, rng = _check_n(n, seed)
    p = _in_ball(rng, n) * np.array([1.0, 0.85, 0.95])
    spacing = (4.0 / 3.0 * math.pi * 0.85 * 0.95 / n) ** (1.0 / 3.0)
    return PointCloud(p, _jittered(rng, n, 0.7 * spacing), None,
                      f"blob(n={n}, seed={seed})")


def uniform_box(n: int, seed: int = 0) -> PointCloud:
    """Uniform points in the cube [-1, 1]^3; sparser overlap (~4 neighbours)."""
    n, rng = _check_n(n, seed)
    p = rng.uniform(-1.0, 1.0, size=(n, 3))
    spacing = (8.0 / n) ** (1.0 / 3.0)
    return PointCloud(p, np.full(n, 0.5 * spacing), None,
                      f"uniform_box(n={n}, seed={seed})")


# The gather: a drop of glass hanging from the tip of a blowpipe, stretched
# downwards and a little forward; neck at the tip, bulb near the bottom.
_PIPE_START = np.array([-1.9, 0.75, 0.0])
_PIPE_TIP = np.array([-0.15, 0.55, 0.0])
_PIPE_RADIUS = 0.05
_DROP_AXIS_END = np.array([0.1, -0.95, 0.05])
_DROP_BULB = 0.55   # bulb radius
_DROP_NECK = 0.08   # radius where the drop meets the pipe


def _drop_profile(t):
    """Radius of the drop at t in [0,1] along its axis (0 = pipe tip)."""
    a, b = 1.3, 0.5
    peak = (a / (a + b)) ** a * (b / (a + b)) ** b
    return np.maximum(_DROP_NECK * (1 - t) ** 0.5, _DROP_BULB * t ** a * (1 - t) ** b / peak)


def glass_gather(n: int, seed: int = 0) -> PointCloud:
    """A gather of molten glass on a blowpipe: a drop hanging from a line of points.

    The pipe is a straight line of up to 40 evenly spaced spheres of fixed radius
    0.05 (fewer for tiny n); the rest fill a drop-shaped volume (narrow neck at
    the pipe tip, bulb near the bottom) that sags under gravity (-y).
    """
    n, rng = _check_n(n, seed)
    n_pipe = min(40, n // 5)
    n_drop = n - n_pipe
    axis = _DROP_AXIS_END - _PIPE_TIP
    length = float(np.linalg.norm(axis))
    axis /= length
    u = np.cross(axis, [0.0, 0.0, 1.0])
    u /= np.linalg.norm(u)
    w = np.cross(axis, u)
    pts = np.empty((0, 3))
    while len(pts) < n_drop:           # rejection sampling in the bounding cylinder
        m = 2 * (n_drop - len(pts)) + 16
        t = rng.random(m)
        q = rng.uniform(-1.0, 1.0, size=(m, 2)) * _DROP_BULB
        ok = np.hypot(q[:, 0], q[:, 1]) <= _drop_profile(t)
        t, q = t[ok], q[ok]
        new = _PIPE_TIP + (t * length)[:, None] * axis + q[:, :1] * u + q[:, 1:] * w
        pts = np.concatenate([pts, new])
    pts = pts[:n_drop]
    tt = np.linspace(0.0, 1.0, 2001)
    trapezoid = getattr(np, "trapezoid", None) or np.trapz       # numpy 2 renamed it
    volume = float(trapezoid(math.pi * _drop_profile(tt) ** 2, tt * length))
    radii = _jittered(rng, n_drop, 0.7 * (volume / max(n_drop, 1)) ** (1.0 / 3.0))
    if n_pipe:
        s = np.linspace(0.0, 1.0, n_pipe)[:, None]
        pipe = _PIPE_START + s * (_PIPE_TIP - _PIPE_START)
        pts = np.concatenate([pipe, pts])
        radii = np.concatenate([np.full(n_pipe, _PIPE_RADIUS), radii])
    return PointCloud(pts, radii, None, f"glass_gather(n={n}, seed={seed})")


GENERATORS = {"blob": blob, "uniform_box": uniform_box, "glass_gather": glass_gather}


def generate(name: str, n: int, seed: int = 0) -> PointCloud:
    """Run the generator called ``name`` (see GENERATORS)."""
    if name not in GENERATORS:
        raise UserError(f"unknown point generator '{name}'",
                        fix=f"choose one of: {', '.join(GENERATORS)}")
    return GENERATORS[name](n, seed)


def nn_distances(centers) -> np.ndarray:
    """Distance from each point to its nearest neighbour (exact: a k-d tree,
    scipy.spatial.cKDTree). Points that coincide with another say nothing of the spacing
    and are left out."""
    from scipy.spatial import cKDTree
    centers = np.asarray(centers, np.float64)
    if len(centers) < 2:
        return np.zeros(0)
    d, _ = cKDTree(centers).query(centers, k=2, workers=-1)
    nn = d[:, 1]
    return nn[np.isfinite(nn) & (nn > 0)]


def nn_spacing(centers, percentile=50) -> float:
    """A percentile (default: the median) of nn_distances, 0 when no two points differ."""
    nn = nn_distances(centers)
    return float(np.percentile(nn, percentile)) if nn.size else 0.0


def default_radius(centers, fallback: float = 0.5) -> float:
    """Half the median nearest-neighbour spacing of the points (nn_spacing), or
    ``fallback`` when no spacing can be measured (a single point, or all points
    coincident)."""
    med = nn_spacing(centers)
    return 0.5 * med if med > 0 else float(fallback)
