"""PLY point clouds (ASCII and binary, both endians, list properties, comments), parsed by
hand: x/y/z, an optional radius and colours; the header is read first and checked, then
only the vertex rows. Kept over plyfile, which measured 7-40x slower; a fuzz target."""
from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from .cloud import CHUNK_LINES, MEMORY_FIX, Projection
from .errors import UserError
from .files import check_memory

MAX_PLY_HEADER = 1 << 20    # bytes of PLY header read before 'end_header' must have come

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


def read_ply(f, size, path):
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
    projection = Projection(path, rows_possible)
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
        if len(lines) == CHUNK_LINES or got + len(lines) == want:
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
                     f"a cloud of {vertex.count} points", MEMORY_FIX)
        arr = np.empty(vertex.count, dt)
        f.seek(offset)
        got = f.readinto(arr.view(np.uint8)) if need else 0
        if got != need:                         # the file shrank since it was measured
            raise UserError(f"truncated binary PLY: header says {vertex.count} vertices, "
                            f"file holds {got // dt.itemsize}", path=path,
                            fix="re-export or re-download the file")
        return {name: arr[name] for name in dt.names}
    rest = max(0, size - offset)
    check_memory(rest * 8, path, "reading this point cloud (rows with lists)", MEMORY_FIX)
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
