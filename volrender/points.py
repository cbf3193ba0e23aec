"""Point-cloud input: the readers by suffix (PLY in volrender/ply.py, XYZ/CSV/TXT and NPY
here), the seeded generators (volrender/generators.py) and nearest-neighbour spacing.

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
import tokenize
from pathlib import Path

import numpy as np

from .cloud import CHUNK_LINES, PointCloud, Projection, finish_cloud
from .errors import UserError
from .files import check_input, check_memory, npy_header
from .ply import read_ply

__all__ = ["load_points", "read_points"]






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
              A header line naming the columns (x y z, radius, red green blue or
              r g b, nx ny nz; CloudCompare's //X,Y,Z,...) is read by name; columns
              it does not know, and normals, are ignored and said in a note.
              Without one, 6 columns whose last three are unit vectors are
              normals, and 9 are x y z with colours and normals in either order.
    ``.npy``  an (N,3) array of centres or (N,4) with the radius as 4th column.
    ``.las`` / ``.laz``  LiDAR point records through laspy (the `las` extra): the
              scaled x, y, z and, where the format has them, 16-bit colours. Z-up
              (ASPRS LAS defines z as elevation): the cloud's up_axis is "z".

    Raises UserError on a missing file, an unsupported suffix, a malformed or
    truncated file, zero points, NaN/Inf coordinates, or negative/non-finite radii.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in _READERS and suffix not in (".npy", ".las", ".laz"):
        raise UserError(f"unsupported suffix '{suffix or '(none)'}' for a point cloud",
                        path=path, fix="use .ply, .xyz, .csv, .txt, .npy, .las or .laz")
    check_input(path, "point-cloud file")
    if suffix == ".npy":
        return finish_cloud(path, *_read_npy(path))
    if suffix in (".las", ".laz"):
        return finish_cloud(path, *_read_las(path))
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
    return finish_cloud(label, *_READERS[suffix](f, size, label))


def _stream_size(f) -> int:
    try:
        return os.fstat(f.fileno()).st_size
    except (AttributeError, OSError, io.UnsupportedOperation):
        pos = f.tell()
        end = f.seek(0, io.SEEK_END)
        f.seek(pos)
        return end




# ---- text: xyz / csv / txt

_TEXT_LAYOUT = {3: "x y z", 4: "x y z radius", 6: "x y z r g b (or nx ny nz)",
                7: "x y z radius r g b", 9: "x y z r g b nx ny nz (either order)"}
# header names (lower case, leading '/' and '#' dropped: CloudCompare writes //X,Y,Z,...)
_NAMES = {"x": "x", "y": "y", "z": "z", "radius": "radius", "rad": "radius",
          "red": "r", "green": "g", "blue": "b", "r": "r", "g": "g", "b": "b",
          "rf": "r", "gf": "g", "bf": "b", "nx": "nx", "ny": "ny", "nz": "nz",
          "normal_x": "nx", "normal_y": "ny", "normal_z": "nz"}


def _is_unit(v) -> bool:
    """Whether the (N, 3) columns look like unit normals: within [-1, 1], |n| ~ 1 on 99%
    of the rows and some component negative (colours are never negative)."""
    if not len(v) or not np.isfinite(v).all() or np.abs(v).max() > 1.0 + 1e-6:
        return False
    norm = np.linalg.norm(v, axis=1)
    return bool((np.abs(norm - 1.0) < 1e-2).mean() >= 0.99 and (v < 0).any())


def _columns(path, header, values):
    """{role: column} for x, y, z and the optional radius and r, g, b, from the header's
    names when it has any, else from the count (6 and 9 columns: a triple of unit vectors
    with a negative component is the normals); and what was left out (said in a note)."""
    ncols = values.shape[1]
    if header:
        roles = [_NAMES.get(t.lower().lstrip("/#")) for t in header]
        if len(roles) != ncols:
            raise UserError(f"the header names {len(roles)} columns, the rows have {ncols}",
                            path=path, fix="make the header match the rows")
        cols = {r: i for i, r in reversed(list(enumerate(roles))) if r}
        if not {"x", "y", "z"} <= set(cols):
            raise UserError(f"the header ({' '.join(header)}) names no x, y and z columns",
                            path=path, fix="name the coordinate columns x, y, z")
        if any(c in cols for c in "rgb") and not all(c in cols for c in "rgb"):
            cols = {k: v for k, v in cols.items() if k not in "rgb"}
        left = [h for h, r in zip(header, roles) if r is None or r in ("nx", "ny", "nz")]
        return cols, left
    cols = {"x": 0, "y": 1, "z": 2}
    if ncols in (4, 7):
        cols["radius"] = 3
    if ncols in (6, 7):
        if ncols == 6 and _is_unit(values[:, 3:6]):
            return cols, ["nx", "ny", "nz"]
        cols.update(r=ncols - 3, g=ncols - 2, b=ncols - 1)
    if ncols == 9:
        rgb, normals = (6, 3) if _is_unit(values[:, 3:6]) else (3, 6)
        cols.update(r=rgb, g=rgb + 1, b=rgb + 2)
        return cols, [f"columns {normals + 1}-{normals + 3} (normals)"]
    return cols, []


def _read_text(f, size, path):
    """Text rows, a chunk of lines at a time (memory: the numbers, plus one chunk of
    text); the columns from a header's names (x, y, z, radius, red/green/blue or r/g/b,
    nx/ny/nz) or the count (_TEXT_LAYOUT). Returns centres, radii, colours and notes."""
    fix = "give one point per line: x y z [radius] [r g b], or a header naming the columns"
    projection = Projection(path, size)
    parts, ncols, header_checked, nonblank, header = [], None, False, False, None
    lineno = 0
    while True:
        chunk = f.readlines(CHUNK_LINES * 32)
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
            if toks and toks[0].startswith("//") and not header_checked:
                toks = [toks[0][2:] or "x", *toks[1:]] if len(toks[0]) > 2 else toks[1:]
            elif toks and toks[0].startswith("#"):
                continue
            if toks:
                rows.append(lineno + i + 1)
                numbers.append(toks)
        lineno += len(lines)
        if not header_checked and rows:
            header_checked = True
            if not _all_numbers(numbers[0]):
                header = numbers[0]
                rows, numbers = rows[1:], numbers[1:]      # header line
        if not rows:
            continue
        if ncols is None:
            ncols = len(numbers[0])
            if header is None and ncols not in _TEXT_LAYOUT:
                raise UserError(f"line {rows[0]}: expected 3, 4, 6, 7 or 9 numbers "
                                f"(x y z [radius] [r g b] [nx ny nz]), got {ncols}", path=path,
                                fix="use one of those column layouts, or a header line "
                                    "naming the columns (x y z ...)")
        values = _text_values(path, rows, numbers, ncols)
        parts.append(values)
        projection.add(len(raw), values.nbytes)
    if not nonblank:
        raise UserError("file is empty", path=path, fix=fix)
    if not parts:
        raise UserError("the file holds zero points", path=path, fix=fix)
    values = parts[0] if len(parts) == 1 else np.concatenate(parts)
    cols, left = _columns(path, header, values)
    centers = values[:, [cols["x"], cols["y"], cols["z"]]].copy()
    radii = values[:, cols["radius"]].copy() if "radius" in cols else None
    colors = None
    if "r" in cols:
        rgb = values[:, [cols["r"], cols["g"], cols["b"]]]
        if np.isfinite(rgb).all() and rgb.max() > 1.0:
            if rgb.max() > 255.0 or rgb.min() < 0.0:
                raise UserError(f"colours outside 0..255 (range {rgb.min()}..{rgb.max()})",
                                path=path, fix="give colours as 0..1 or 0..255")
            rgb = rgb / 255.0
        colors = rgb.astype(np.float32)
    notes = (f"{path}: read x y z{' radius' if radii is not None else ''}"
             f"{' r g b' if colors is not None else ''}; ignored: {', '.join(left)} (the "
             f"glass takes its normals from the field)",) if left else ()
    return centers, radii, colors, notes


def _text_values(path, rows, numbers, ncols):
    lens = np.fromiter(map(len, numbers), dtype=np.int64, count=len(numbers))
    bad = np.flatnonzero(lens != ncols)
    if bad.size:
        k = int(bad[0])
        raise UserError(f"line {rows[k]}: expected {ncols} numbers, got {int(lens[k])}",
                        path=path, fix=f"every line needs {ncols} numbers "
                                       f"({_TEXT_LAYOUT.get(ncols, 'as the header names')}), "
                                       "like the first")
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


_READERS = {".ply": read_ply, ".xyz": _read_text, ".csv": _read_text, ".txt": _read_text}


def _read_las(path):
    """(centres, radii, colours, notes, up axis, why) of a LAS/LAZ file (volrender/las.py)."""
    from .las import read_las
    return read_las(path)


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
