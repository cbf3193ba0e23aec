"""OpenVDB grids -> sparse brick layout (+ .npz cache).

Layout (the volume kernel depends on it):
  * local index coordinate p (float) <-> VDB index coordinate origin + p;
    voxel centres sit at integer coordinates.
  * the local box [0, dims*BRICK] is cut into bricks of BRICK^3 cells; each stored
    brick holds APRON^3 = (BRICK+1)^3 values (one extra voxel on the + side), so a
    trilinear lookup anywhere in a brick's cells reads that brick only.
  * table[(bx*dims[1] + by)*dims[2] + bz] = slot, or -1 for an all-zero brick.
  * data[slot, i, j, k] = value of local voxel (bx*8+i, by*8+j, bz*8+k).
  * majorant[slot] = data[slot].max() (bounds the interpolated density in the brick).
  * optional emission and temperature grids in the same slots; a brick is stored when
    its density or emission is non-zero (the temperature only colours the emission).
"""
from __future__ import annotations

import importlib
import math
import os
import re
import struct
import tokenize
import warnings
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import atomic
from .errors import UserError, printable
from .files import check_input, check_memory, npy_header
from .layout import APRON, BRICK  # shared with the kernels (cl/structs.h)

NPZ_FORMAT = "volrender-bricks"
# 1: density (+ emission); 2: also a temperature grid. Caches are written as version 1
# unless they hold a temperature grid, so older readers refuse only what they would
# render without its colours; this reader takes both.
NPZ_VERSION = 2
NPZ_VERSIONS = (1, 2)
MAX_BRICKS = 1 << 27          # table entries (512 MB of int32); more is refused
MAX_COND = 1e5                # largest condition number of a grid's linear transform
SCALE_RANGE = (1e-20, 1e20)   # singular values of the transform (world units per voxel)
MAX_ORIGIN = 1 << 31          # |VDB index| of a layout's origin (VDB coordinates are int32)
VDB_MAGIC = 0x56444220
_MIN_DESCRIPTOR = 3 * 4 + 3 * 8   # three empty strings and three offsets
_NODE = 128                   # edge of OpenVDB's lowest internal node (5_4_3 trees)


# --------------------------------------------------------------------------- OpenVDB

def import_openvdb():
    """Return the OpenVDB Python module (pyopenvdb, or openvdb from OpenVDB >= 12)."""
    reasons = []
    for name in ("pyopenvdb", "openvdb"):
        try:
            return importlib.import_module(name)
        except Exception as e:  # a broken binding can raise more than ImportError
            reasons.append(f"{name}: {e}".replace("\n", " "))
    raise UserError("OpenVDB's Python binding is not available (" + "; ".join(reasons) + ")",
                    fix="run `bash run.sh setup` (installs Debian's python3-openvdb), "
                        "or use a .npz brick cache converted elsewhere")


@dataclass(frozen=True)
class GridInfo:
    name: str
    value_type: str            # 'float', 'vec3s', 'int32', 'double', 'ptdataidx32', ...
    grid_class: str            # 'fog volume', 'level set', 'staggered' or 'unknown'
    active_voxels: int | None = None
    creator: str = ""          # the file's 'creator' metadata (the writing application)
    metadata_keys: tuple = ()  # names of the grid's metadata entries
    memory_bytes: int | None = None   # 'file_mem_bytes': the grid's size in memory

    def describe(self) -> str:
        return f"{self.name} ({self.value_type}, {self.grid_class})"


class _Corrupt(Exception):
    pass


class _Reader:
    def __init__(self, f, size):
        self.f, self.size = f, size

    def read(self, n):
        b = self.f.read(n)
        if len(b) != n:
            raise _Corrupt("unexpected end of file")
        return b

    def unpack(self, fmt):
        v = struct.unpack("<" + fmt, self.read(struct.calcsize("<" + fmt)))
        return v[0] if len(v) == 1 else v

    def string(self):
        n = self.unpack("I")
        if n > self.size - self.f.tell():
            raise _Corrupt(f"string of {n} bytes runs past the end of the file")
        return self.read(n).decode("utf-8", "replace")


def _read_metamap(r: _Reader) -> dict:
    """MetaMap: count, then (name, type name, uint32 size, value bytes) each."""
    meta = {}
    count = r.unpack("I")
    if count * 12 > r.size - r.f.tell():
        raise _Corrupt(f"{count} metadata entries cannot fit in the rest of the file")
    for _ in range(count):
        name, type_name = r.string(), r.string()
        n = r.unpack("I")
        if n > r.size - r.f.tell():
            raise _Corrupt(f"metadata {name!r} runs past the end of the file")
        raw = r.read(n)
        if type_name == "string":
            meta[name] = raw.decode("utf-8", "replace")
        elif (type_name, n) in (("int32", 4), ("int64", 8)):
            meta[name] = struct.unpack("<i" if n == 4 else "<q", raw)[0]
        elif (type_name, n) == ("vec3i", 12):
            meta[name] = struct.unpack("<3i", raw)
        else:
            meta[name] = None          # present, value not decoded
    return meta


def _value_type(tree_type: str) -> str:
    """'Tree_float_5_4_3' -> 'float'."""
    m = re.fullmatch(r"Tree_(.+?)((?:_\d+)+)", tree_type)
    return m.group(1) if m else tree_type


def _parse_vdb(path: Path) -> list[GridInfo] | None:
    """Grid descriptors straight from the file; None when only OpenVDB can tell."""
    with open(path, "rb") as f:
        return parse_vdb_header(f, os.fstat(f.fileno()).st_size, path)


def _int_or_none(v):
    return v if isinstance(v, int) and v >= 0 else None


def parse_vdb_header(f, size: int, path) -> list[GridInfo] | None:
    """The grid descriptors and per-grid metadata of the .vdb stream `f` (`size` bytes: a
    file or io.BytesIO; `path` names it in messages), reading no voxel data; None for
    files only OpenVDB can tell about (headers before version 222, no grid offsets)."""
    r = _Reader(f, size)
    if size < 8 or r.unpack("q") != VDB_MAGIC:
        raise UserError("not an OpenVDB file (bad magic number)", path=path,
                        fix="give a .vdb written by OpenVDB, Houdini, Blender or EmberGen")
    try:
        version = r.unpack("I")
        if version < 222:              # older headers vary; let OpenVDB read them
            return None
        r.unpack("II")                 # library major, minor
        has_offsets = r.read(1) != b"\0"
        r.read(36)                     # UUID as text
        creator = _read_metamap(r).get("creator") or ""    # file metadata
        if not has_offsets:
            return None
        count = r.unpack("i")
        if count < 0:
            raise _Corrupt("negative grid count")
        if count * _MIN_DESCRIPTOR > size - f.tell():
            raise _Corrupt(f"{count} grid descriptors cannot fit in the rest of the file")
        grids = []
        for _ in range(count):
            name = r.string().split("\x1e")[0]   # '\x1e<n>' marks duplicate names
            tree = r.string().removesuffix("_HalfFloat")
            r.string()                 # instance parent
            grid_pos, block_pos, end_pos = r.unpack("qqq")
            # each grid lies after its descriptor, in order: never trust an offset
            # that points backwards (it would make this loop read the same bytes forever)
            if not f.tell() <= grid_pos <= block_pos <= end_pos:
                raise _Corrupt(f"grid {name!r} has offsets out of order "
                               f"({grid_pos}, {block_pos}, {end_pos})")
            if end_pos > size:
                raise _Corrupt(f"grid {name!r} ends past the end of the file")
            f.seek(grid_pos)
            r.unpack("I")              # per-grid compression flags
            meta = _read_metamap(r)
            grid_class = meta.get("class")
            grids.append(GridInfo(name, _value_type(tree),
                                  grid_class if isinstance(grid_class, str) else "unknown",
                                  _int_or_none(meta.get("file_voxel_count")), str(creator),
                                  tuple(meta), _int_or_none(meta.get("file_mem_bytes"))))
            f.seek(end_pos)
        return grids
    except (_Corrupt, struct.error, UnicodeError) as e:
        raise UserError(f"truncated or corrupt OpenVDB file ({e})", path=path,
                        fix="re-export or re-download it") from None


def _check_file(path) -> Path:
    return check_input(path, "volume file", fix="give a .vdb or .npz file")


def list_grids(path) -> list[GridInfo]:
    """Every grid in a .vdb file, in file order (works where readAllGridMetadata fails)."""
    p = _check_file(path)
    grids = _parse_vdb(p)
    if grids is not None:
        return grids
    vdb = import_openvdb()
    try:
        return [GridInfo(g.name, g.valueTypeName, g.gridClass, g.metadata.get("file_voxel_count"))
                for g in vdb.readAllGridMetadata(str(p))]
    except Exception as e:
        raise UserError(f"cannot list its grids ({_one_line(e)})", path=p,
                        fix="re-save it with a current OpenVDB") from None


# Grid names Blender's Mantaflow writes into its caches (gas and liquid domains): a file
# whose float grids include several of these, one of them a Mantaflow-only name, is a
# Mantaflow cache whatever its metadata says (older Blenders write no
# 'file_base_resolution', e.g. fluid_data_0190.vdb).
MANTAFLOW_GAS = frozenset({"density", "flame", "temperature", "heat", "fuel", "react", "shadow",
                           "color_r", "color_g", "color_b", "velocity", "velocity_previous", "density_inflow",
                           "heat_inflow", "temperature_inflow", "fuel_inflow", "react_inflow", "phi_obstacle",
                           "phi_inflow", "phi_out", "flags", "emission"})
MANTAFLOW_LIQUID = frozenset({"phi", "phi_previous", "phi_particles", "phi_obstacle", "phi_inflow",
                              "phi_out", "velocity", "velocity_previous", "flags", "particles"})
# names no other writer we know of uses for a density-like grid
MANTAFLOW_ONLY = frozenset({"shadow", "react", "fuel", "phi_obstacle", "phi_out", "phi_inflow",
                            "phi_particles", "density_inflow", "heat_inflow"})


def mantaflow_cache(grids) -> str:
    """Why the file is a Blender Mantaflow cache ('' when it is not): recognised by its grid
    set (at least three Mantaflow grid names, one of them Mantaflow's own, all of the file's
    grids from the gas or the liquid set), or by the 'file_base_resolution' grid metadata
    that newer Blenders add."""
    names = {g.name for g in grids}
    for kind, known in (("gas", MANTAFLOW_GAS), ("liquid", MANTAFLOW_LIQUID)):
        own = sorted(names & MANTAFLOW_ONLY)
        if len(names) >= 3 and names <= known and own:
            return (f"a Blender Mantaflow {kind} cache (grids "
                    f"{', '.join(sorted(names & {'density', 'flame', 'temperature', 'phi'} | set(own[:2])))})")
    if any("file_base_resolution" in g.metadata_keys for g in grids):
        return "a Blender (Mantaflow) cache: its grids carry 'file_base_resolution'"
    return ""


def up_axis_hint(grids) -> tuple[str | None, str]:
    """(axis, reason): 'z' for files that Blender wrote (Blender is Z-up): a 'creator'
    naming Blender, or a Mantaflow cache (mantaflow_cache: by its grid set; its caches carry
    no 'creator'); None when the file does not say."""
    creator = next((g.creator for g in grids if g.creator), "")
    if "blender" in creator.lower():
        return "z", f"written by {creator!r}"
    why = mantaflow_cache(grids)
    if why:
        return "z", why
    return None, ""


def _one_line(e: Exception) -> str:
    return f"{type(e).__name__}: {e}".replace("\n", " ").strip()


def _listing(grids) -> str:
    return "available grids: " + ", ".join(g.describe() for g in grids)


def check_transform(m, where="") -> str | None:
    """Problem with an index-to-world matrix, or None: finite, affine (last row 0 0 0 1),
    singular values in SCALE_RANGE and a condition number at most MAX_COND, so that its
    inverse in the kernels' float32 arithmetic keeps its digits."""
    m = np.asarray(m, np.float64)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        return "index_to_world is not a finite 4x4 matrix"
    if not np.array_equal(m[3], [0.0, 0.0, 0.0, 1.0]):
        return "index_to_world is not affine (its last row is not 0 0 0 1)"
    sv = np.linalg.svd(m[:3, :3], compute_uv=False)
    if sv[-1] < SCALE_RANGE[0] or sv[0] > SCALE_RANGE[1]:
        return (f"index_to_world scales voxels by {sv[-1]:.3g}..{sv[0]:.3g}, outside "
                f"[{SCALE_RANGE[0]:g}, {SCALE_RANGE[1]:g}]")
    if sv[0] > MAX_COND * sv[-1]:
        return (f"index_to_world is nearly singular (condition number {sv[0] / sv[-1]:.3g} "
                f"> {MAX_COND:g})")
    if np.abs(m[:3, 3]).max() > SCALE_RANGE[1]:
        return f"index_to_world translates by more than {SCALE_RANGE[1]:g}"
    return None


def _pick(path, grids, name, default=False) -> GridInfo:
    if name is None and default:
        names = [g.name for g in grids]
        if "density" in names:
            name = "density"
        else:
            fog = [g for g in grids if g.value_type == "float" and g.grid_class == "fog volume"]
            if len(fog) != 1:
                raise UserError(f"no grid named 'density' and {len(fog)} float fog-volume grids "
                                "to choose from", path=path,
                                fix=f"choose one by name (--grid NAME); {_listing(grids)}")
            name = fog[0].name
    same = [g for g in grids if g.name == name]
    if not same:
        raise UserError(f"no grid named {name!r}", path=path, fix=_listing(grids))
    if len(same) > 1:
        warnings.warn(f"{path}: {len(same)} grids are named {name!r}; using the first in the file",
                      stacklevel=3)
    _check_kind(path, same[0], grids)
    return same[0]


def _check_kind(path, g: GridInfo, grids):
    vt, what = g.value_type, f"grid {g.name!r}"
    fog = [x.name for x in grids if x.value_type == "float" and x.grid_class == "fog volume"]
    fix = ("choose a float fog-volume grid: " + ", ".join(dict.fromkeys(fog))) if fog \
        else "this file has no float fog-volume grid; " + _listing(grids)
    if vt == "double":
        raise UserError(f"{what} is a double-precision grid, which OpenVDB's Python binding "
                        "cannot read", path=path,
                        fix="re-save it as a float grid (e.g. Houdini's VDB Convert SOP)")
    if vt.startswith("ptdata") or vt.startswith("ptidx"):
        raise UserError(f"{what} is a point data grid (particles), not a voxel volume",
                        path=path, fix=fix)
    if vt.startswith("vec"):
        raise UserError(f"{what} holds vectors ({vt}), not a scalar density", path=path, fix=fix)
    if vt != "float":
        raise UserError(f"{what} holds {vt} values, not float densities", path=path, fix=fix)
    if g.grid_class == "level set":
        raise UserError(f"{what} is a level set (a signed distance field to a surface), "
                        "not a density", path=path,
                        fix="convert it to a fog volume (OpenVDB's sdfToFogVolume), or " + fix)


def _index_to_world(transform) -> np.ndarray:
    t = np.array(transform.indexToWorld((0.0, 0.0, 0.0)), np.float64)
    m = np.eye(4)
    m[:3, 3] = t
    for c in range(3):
        e = [0.0, 0.0, 0.0]
        e[c] = 1.0
        m[:3, c] = np.array(transform.indexToWorld(tuple(e)), np.float64) - t
    return m


def _read_grid(vdb, path: Path, info: GridInfo):
    """One grid by name -> (grid, index_to_world, (lo, hi) active bbox or None)."""
    try:
        grid = vdb.read(str(path), info.name)
    except Exception as e:
        raise UserError(f"cannot read grid {info.name!r} ({_one_line(e)})", path=path,
                        fix="the file may be truncated or corrupt; re-export it") from None
    vt = getattr(grid, "valueTypeName", info.value_type)
    if vt != info.value_type:
        _check_kind(path, GridInfo(info.name, vt, info.grid_class), [info])
    if not grid.transform.isLinear:
        raise UserError(f"grid {info.name!r} has a non-linear (frustum) transform, which is "
                        "unsupported", path=path,
                        fix="resample it onto a linear transform (e.g. Houdini's VDB Resample)")
    bg = float(grid.background)
    if bg != 0.0:
        warnings.warn(f"{path}: grid {info.name!r} has background {bg}; space outside its "
                      "active voxels is treated as 0", stacklevel=3)
    lo, hi = (np.array(v, np.int64) for v in grid.evalActiveVoxelBoundingBox())
    box = None if np.any(lo > hi) else (lo, hi)
    m = _index_to_world(grid.transform)
    problem = check_transform(m)
    if problem:
        raise UserError(f"grid {info.name!r}: {problem}", path=path,
                        fix="resample the grid onto a well-conditioned linear transform")
    return grid, m, box


def _vdb_source(grid, box):
    """(read, is_zero) over VDB index boxes; is_zero skips regions of zero tiles.

    Inside the active box inactive voxels read as the background; outside it, as 0.
    """
    acc = grid.getConstAccessor()

    def read(lo, shape):
        a = np.zeros(tuple(int(s) for s in shape), np.float32)
        grid.copyToArray(a, ijk=tuple(int(v) for v in lo))
        for d in range(3):
            cut = [slice(None)] * 3
            cut[d] = slice(0, max(int(box[0][d] - lo[d]), 0))
            a[tuple(cut)] = 0
            cut[d] = slice(max(int(box[1][d] - lo[d] + 1), 0), None)
            a[tuple(cut)] = 0
        return a

    def is_zero(lo, hi):
        ranges = [range(int(a) // _NODE, int(b) // _NODE + 1) for a, b in zip(lo, hi)]
        for bx in ranges[0]:
            for by in ranges[1]:
                for bz in ranges[2]:
                    p = tuple(max(int(b) * _NODE, int(a)) for b, a in zip((bx, by, bz), lo))
                    # depth <= 1: the whole 128^3 node is one tile (or background)
                    if acc.getValueDepth(p) > 1 or acc.getValue(p) != 0:
                        return False
        return True

    return read, is_zero


def _dense_source(values: np.ndarray, origin: np.ndarray):
    shape = np.array(values.shape)

    def read(lo, size):
        out = np.zeros(tuple(int(s) for s in size), np.float32)
        a = np.asarray(lo) - origin
        s, e = np.maximum(a, 0), np.minimum(a + size, shape)
        if np.all(e > s):
            out[tuple(slice(i - j, k - j) for i, j, k in zip(s, a, e))] = \
                values[tuple(slice(i, k) for i, k in zip(s, e))]
        return out

    return read, (lambda lo, hi: False)


def _zero_source():
    return (lambda lo, shape: np.zeros(tuple(int(s) for s in shape), np.float32)), \
           (lambda lo, hi: True)


# --------------------------------------------------------------------------- layout

def _layout(lo, hi):
    """Brick origin and dims for an inclusive active box: one zero voxel on each side."""
    origin = np.asarray(lo, np.int64) - 1
    dims = (np.asarray(hi, np.int64) - lo + 2 + BRICK - 1) // BRICK
    return origin, dims.astype(np.int32)


def _brick_view(a, nb):
    s = np.array(a.strides)
    return np.lib.stride_tricks.as_strided(a, shape=(*nb, APRON, APRON, APRON),
                                           strides=(*(s * BRICK), *s), writeable=False)


def _sanitise(a, own, stats, negative_ok=False):
    """Non-finite and negative values -> 0, counted inside the chunk's own voxels."""
    bad = ~np.isfinite(a)
    if bad.any():
        stats[0] += int(bad[own].sum())
        a[bad] = 0
    if negative_ok:
        return
    neg = a < 0
    if neg.any():
        stats[1] += int(neg[own].sum())
        a[neg] = 0


def _build(label, sources, lo, hi, chunk=16, progress=None, passive=0):
    """Bricks from (read, is_zero) sources (density, then emission, then the `passive`
    ones: temperature) over box lo..hi. Passive sources are stored in the bricks the
    others make, and may be negative.

    Works chunk^3 bricks at a time, so memory holds one chunk plus the kept bricks.
    """
    n_active = len(sources) - passive
    origin, dims = _layout(lo, hi)
    if int(np.prod(dims.astype(np.int64))) > MAX_BRICKS:
        raise UserError(f"the active region ({hi - lo + 1} voxels) needs more than {MAX_BRICKS} "
                        "bricks", path=label, fix="crop or resample the grid")
    box_lo, box_hi = lo - origin, hi - origin + 1          # local, half-open
    stats = [[0, 0] for _ in sources]
    vmin, vmax = np.inf, -np.inf
    idx_parts, parts = [], [[] for _ in sources]
    n_chunks = -(-dims // chunk)
    total = int(np.prod(n_chunks))
    for done, c in enumerate(np.ndindex(*n_chunks.tolist())):
        if progress is not None and done:
            progress(done / total)
        b0 = np.array(c) * chunk
        nb = np.minimum(chunk, dims - b0)
        v0 = b0 * BRICK
        shape = nb * BRICK + 1
        start = origin + v0
        zero = [is_zero(start, start + shape - 1) for _, is_zero in sources]
        # the voxels this chunk owns (the + apron belongs to the next chunk) and, of
        # those, the ones inside the active box
        own = tuple(slice(0, int(n * BRICK + (b + n == d))) for n, b, d in zip(nb, b0, dims))
        sub = tuple(slice(int(max(a - v, 0)), int(max(min(b - v, o.stop), 0)))
                    for a, b, v, o in zip(box_lo, box_hi, v0, own))
        in_box = all(s.stop > s.start for s in sub)
        if all(zero[:n_active]):
            if in_box:
                vmin, vmax = min(vmin, 0.0), max(vmax, 0.0)
            continue
        arrays = [np.zeros(tuple(shape), np.float32) if z else read(start, shape)
                  for (read, _), z in zip(sources, zero)]
        mask = np.zeros(tuple(nb), bool)
        for i, (a, st) in enumerate(zip(arrays, stats)):
            _sanitise(a, own, st, negative_ok=i >= n_active)
            if i < n_active:
                mask |= _brick_view(a, nb).any(axis=(3, 4, 5))
        if in_box:
            vmin = min(vmin, float(arrays[0][sub].min()))
            vmax = max(vmax, float(arrays[0][sub].max()))
        if mask.any():
            b = b0 + np.argwhere(mask)
            idx_parts.append((b[:, 0] * dims[1] + b[:, 1]) * np.int64(dims[2]) + b[:, 2])
            for a, part in zip(arrays, parts):
                part.append(_brick_view(a, nb)[mask])
    if progress is not None:
        progress(1.0)
    idx = np.concatenate(idx_parts) if idx_parts else np.zeros(0, np.int64)
    order = np.argsort(idx, kind="stable")
    table = np.full(int(np.prod(dims.astype(np.int64))), -1, np.int32)
    table[idx[order]] = np.arange(len(idx), dtype=np.int32)
    out = []
    for p in parts:                # free each chunk's pieces before the sorted copy
        a = np.concatenate(p) if p else np.zeros((0,) + (APRON,) * 3, np.float32)
        p.clear()
        out.append(a[order])
        del a
    return origin, dims, table, out, stats, (float(vmin), float(vmax))


def _warn_sanitised(label, name, stats):
    bad, neg = stats
    if bad:
        warnings.warn(f"{label}: grid {name!r} has {bad} NaN/Inf voxels; replaced by 0",
                      stacklevel=3)
    if neg:
        warnings.warn(f"{label}: grid {name!r} has {neg} negative voxels; clamped to 0 "
                      "(a density cannot be negative)", stacklevel=3)


def _max_per_slot(data):
    return data.reshape(len(data), -1).max(axis=1) if len(data) else np.zeros(0, np.float32)


@dataclass(eq=False)
class Bricks:
    """A scalar grid (and optional emission grid) as sparse bricks; see the module doc."""
    origin: np.ndarray             # int64 (3,): VDB index of local voxel (0,0,0)
    dims: np.ndarray               # int32 (3,): bricks per axis
    table: np.ndarray              # int32 (prod(dims),): slot or -1
    data: np.ndarray               # float32 (n, 9, 9, 9)
    majorant: np.ndarray           # float32 (n,)
    index_to_world: np.ndarray     # float64 (4, 4): world = M @ [i, j, k, 1]
    emission: np.ndarray | None = None
    emission_max: np.ndarray | None = None
    grid_name: str = "density"
    emission_grid_name: str | None = None
    temperature: np.ndarray | None = None      # float32 (n, 9, 9, 9), raw grid values
    temperature_grid_name: str | None = None
    source: str = ""
    background: float = 0.0
    value_range: tuple = (0.0, 0.0)   # density min/max over the active box, sanitised
    active_voxels: int = 0
    up_axis: str | None = None        # the up axis the file suggests (vdb.up_axis_hint)
    up_axis_reason: str = ""
    index_box: tuple | None = None    # inclusive VDB index box of the active voxels (lo, hi)

    @property
    def n_slots(self) -> int:
        return len(self.data)

    @property
    def local_to_world(self) -> np.ndarray:
        t = np.eye(4)
        t[:3, 3] = self.origin
        return self.index_to_world @ t

    @property
    def voxel_size(self) -> float:
        return float(np.cbrt(abs(np.linalg.det(self.index_to_world[:3, :3]))))

    def world_bounds(self):
        ext = self.dims.astype(np.float64) * BRICK
        corners = np.array([[x, y, z, 1.0] for x in (0, ext[0])
                            for y in (0, ext[1]) for z in (0, ext[2])])
        w = (self.local_to_world @ corners.T)[:3].T
        return w.min(axis=0), w.max(axis=0)

    def sample_local(self, p, emission=False, temperature=False) -> np.ndarray:
        """Trilinear value at local index coordinates p (N, 3); 0 outside the layout."""
        vals = self.temperature if temperature else self.emission if emission else self.data
        p = np.asarray(p, np.float64).reshape(-1, 3)
        out = np.zeros(len(p))
        ext = self.dims * BRICK
        inside = np.all((p >= 0) & (p <= ext), axis=1)
        q = p[inside]
        b = np.clip(np.floor(q / BRICK).astype(np.int64), 0, self.dims - 1)
        f = q - b * BRICK
        i0 = np.clip(np.floor(f).astype(np.int64), 0, BRICK - 1)
        t = f - i0
        slot = self.table[(b[:, 0] * self.dims[1] + b[:, 1]) * self.dims[2] + b[:, 2]]
        ok = slot >= 0
        s, i0, t = slot[ok], i0[ok], t[ok]
        acc = np.zeros(len(s))
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    w = ((t[:, 0] if dx else 1 - t[:, 0]) * (t[:, 1] if dy else 1 - t[:, 1])
                         * (t[:, 2] if dz else 1 - t[:, 2]))
                    acc += w * vals[s, i0[:, 0] + dx, i0[:, 1] + dy, i0[:, 2] + dz]
        res = np.zeros(len(q))
        res[ok] = acc
        out[inside] = res
        return out

    def sample_world(self, x, emission=False, temperature=False) -> np.ndarray:
        x = np.asarray(x, np.float64).reshape(-1, 3)
        m = np.linalg.inv(self.local_to_world)
        return self.sample_local(x @ m[:3, :3].T + m[:3, 3], emission, temperature)

    @classmethod
    def from_dense(cls, values, index_to_world=None, origin=(0, 0, 0), emission=None,
                   name="density", chunk=16, temperature=None) -> "Bricks":
        """Bricks from a dense array: values[i, j, k] is VDB index origin + (i, j, k);
        emission and temperature (optional) are arrays of the same shape."""
        values = np.asarray(values, np.float32)
        if values.ndim != 3 or values.size == 0:
            raise ValueError(f"from_dense needs a non-empty 3-D array, got shape {values.shape}")
        origin = np.asarray(origin, np.int64).reshape(3)
        sources = [_dense_source(values, origin)]
        if emission is not None:
            emission = np.asarray(emission, np.float32)
            if emission.shape != values.shape:
                raise ValueError(f"emission shape {emission.shape} != density {values.shape}")
            sources.append(_dense_source(emission, origin))
        if temperature is not None:
            temperature = np.asarray(temperature, np.float32)
            if temperature.shape != values.shape:
                raise ValueError(f"temperature shape {temperature.shape} != density {values.shape}")
            sources.append(_dense_source(temperature, origin))
        hi = origin + np.array(values.shape) - 1
        lo_, dims, table, out, stats, vrange = _build("<dense>", sources, origin, hi, chunk,
                                                      passive=int(temperature is not None))
        _warn_sanitised("<dense>", name, stats[0])
        m = np.eye(4) if index_to_world is None else np.asarray(index_to_world, np.float64)
        if m.shape != (4, 4):
            raise ValueError(f"index_to_world must be 4x4, got shape {m.shape}")
        b = cls(lo_, dims, table, out[0], _max_per_slot(out[0]), m, grid_name=name,
                source="<dense>", value_range=vrange,
                active_voxels=int(np.count_nonzero(values)))
        if emission is not None:
            _warn_sanitised("<dense>", "emission", stats[1])
            b.emission, b.emission_max = out[1], _max_per_slot(out[1])
            b.emission_grid_name = "emission"
        if temperature is not None:
            _warn_sanitised("<dense>", "temperature", stats[-1])
            b.temperature, b.temperature_grid_name = out[-1], "temperature"
        return b

    def save_npz(self, path):
        """Write a brick cache atomically (volrender.atomic); version 2 only when it holds a
        temperature grid, so older readers refuse what they would render in one colour."""
        version = 2 if self.temperature is not None else 1
        arrays = dict(format=np.array(NPZ_FORMAT), version=np.array(version),
                      origin=self.origin, dims=self.dims, table=self.table, data=self.data,
                      majorant=self.majorant, index_to_world=self.index_to_world,
                      grid_name=np.array(self.grid_name), source=np.array(self.source),
                      background=np.array(self.background, np.float64),
                      value_range=np.array(self.value_range, np.float64),
                      active_voxels=np.array(self.active_voxels, np.int64),
                      up_axis=np.array(self.up_axis or ""), up_axis_reason=np.array(self.up_axis_reason))
        if self.index_box is not None:
            arrays["index_box"] = np.array(self.index_box, np.int64)
        if self.emission is not None:
            arrays.update(emission=self.emission, emission_max=self.emission_max,
                          emission_grid_name=np.array(self.emission_grid_name or ""))
        if self.temperature is not None:
            arrays.update(temperature=self.temperature,
                          temperature_grid_name=np.array(self.temperature_grid_name or ""))
        with atomic.replace(path, "brick cache") as f:
            # np.savez's layout, with the archive closed on failure too (numpy leaves it
            # to the garbage collector, which then prints a traceback of its own)
            with zipfile.ZipFile(f, mode="w", compression=zipfile.ZIP_STORED,
                                 allowZip64=True) as zf:
                for key, value in arrays.items():
                    with zf.open(f"{key}.npy", "w", force_zip64=True) as member:
                        np.lib.format.write_array(member, np.asanyarray(value),
                                                  allow_pickle=False)


# what zipfile and numpy raise on a damaged archive: a bad header or CRC, a zip version or
# compression method it does not implement, an encrypted member, a bad deflate stream
# (and numpy's .npy header parser: tokenize.TokenError from a header cut short)
_ZIP_ERRORS = (OSError, ValueError, EOFError, zipfile.BadZipFile, NotImplementedError,
               RuntimeError, zlib.error, struct.error, OverflowError, LookupError,
               tokenize.TokenError)


def _check_npz_members(z, size):
    """Every member's .npy header must agree with the member's stored size (a lying
    header would make numpy allocate what it claims before reading)."""
    for info in z.zip.infolist():
        if info.file_size > (1 << 40) or info.compress_size > size:
            return f"member {info.filename!r} claims {info.file_size} bytes"
        with z.zip.open(info) as f:
            shape, dtype, start = npy_header(f)
        need = math.prod(shape) * dtype.itemsize
        if need != info.file_size - start:
            return (f"member {info.filename!r}: its header says shape {shape} of {dtype}, "
                    f"{need} bytes, but it holds {info.file_size - start}")
    return None


def load_npz(path) -> Bricks:
    """Read a brick cache written by Bricks.save_npz, validating it fully: sizes against
    the file, dims against the table, table against the data, majorants against the
    data, a well-conditioned transform; NaN/Inf and negative voxels become 0 with a
    warning, as in a .vdb."""
    p = _check_file(path)
    with open(p, "rb") as f:
        return read_npz(f, os.fstat(f.fileno()).st_size, p)


def read_npz(f, size: int, p) -> Bricks:
    """`load_npz` of the open binary stream `f` of `size` bytes (a file or io.BytesIO);
    `p` names it in messages."""
    fix = "convert the .vdb again (volrender convert)"
    magic = f.read(4)
    f.seek(0)
    if magic not in (b"PK\x03\x04", b"PK\x05\x06"):
        # np.load would read a bare .npy whole, whatever size its header claims
        if magic == b"\x93NUM":
            raise UserError("not a volrender brick cache (a bare .npy array)", path=p, fix=fix)
        raise UserError("not a readable .npz file (no zip archive)", path=p, fix=fix)
    try:
        z = np.load(f, allow_pickle=False)
    except _ZIP_ERRORS as e:
        raise UserError(f"not a readable .npz file ({_one_line(e)})", path=p, fix=fix) from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise UserError("not a volrender brick cache (a bare .npy array)", path=p, fix=fix)
    with z:
        try:
            problem = _check_npz_members(z, size)
            if problem:
                raise UserError(f"corrupt brick cache ({problem})", path=p, fix=fix)
            # every member once as read, once as validated (cast, sanitised)
            check_memory(2 * sum(i.file_size for i in z.zip.infolist()), p,
                         "this brick cache", "convert a smaller or cropped grid, or free memory")
            if "format" not in z.files or str(z["format"]) != NPZ_FORMAT:
                raise UserError("not a volrender brick cache (no 'format' key)", path=p, fix=fix)
            if int(z["version"]) not in NPZ_VERSIONS:
                raise UserError(f"brick cache version {int(z['version'])} is not supported "
                                f"(this volrender reads {', '.join(map(str, NPZ_VERSIONS))})",
                                path=p, fix=fix)
            dims = z["dims"]
            if dims.shape != (3,) or dims.dtype.kind not in "iu":
                raise UserError(f"corrupt brick cache (dims of shape {dims.shape}, dtype "
                                f"{dims.dtype})", path=p, fix=fix)
            n_table = math.prod(int(d) for d in dims)
            if min(int(d) for d in dims) <= 0 or n_table > MAX_BRICKS:
                raise UserError(f"corrupt brick cache (dims {tuple(int(d) for d in dims)}: "
                                f"{n_table} bricks, allowed 1..{MAX_BRICKS})", path=p, fix=fix)
            b = Bricks(origin=z["origin"], dims=dims, table=z["table"], data=z["data"],
                       majorant=z["majorant"], index_to_world=z["index_to_world"],
                       grid_name=str(z["grid_name"]), source=str(z["source"]),
                       background=float(z["background"]),
                       value_range=tuple(float(v) for v in z["value_range"]),
                       active_voxels=int(z["active_voxels"]))
            if "up_axis" in z.files:                     # optional: older caches lack it
                b.up_axis = str(z["up_axis"]) or None
                b.up_axis_reason = str(z["up_axis_reason"])
            if "index_box" in z.files and z["index_box"].shape == (2, 3):
                b.index_box = tuple(tuple(int(v) for v in row) for row in z["index_box"])
            if "emission" in z.files:
                b.emission, b.emission_max = z["emission"], z["emission_max"]
                b.emission_grid_name = str(z["emission_grid_name"])
            if "temperature" in z.files:
                b.temperature = z["temperature"]
                b.temperature_grid_name = str(z["temperature_grid_name"])
            problem = _validate(b, p)
        except (KeyError, TypeError, SyntaxError, *_ZIP_ERRORS) as e:
            raise UserError(f"corrupt brick cache ({_one_line(e)})", path=p, fix=fix) from None
    if problem:
        raise UserError(f"corrupt brick cache ({problem})", path=p, fix=fix)
    return b


def _validate(b: Bricks, label="<bricks>") -> str | None:
    """Problem with a loaded cache, or None. Casts to the layout's dtypes, replaces
    NaN/Inf and negative voxels by 0 (warning, as for a .vdb) and checks the majorants."""
    checks = [(b.origin, "iu", (3,)), (b.dims, "iu", (3,)), (b.index_to_world, "f", (4, 4)),
              (b.table, "iu", None), (b.data, "f", None), (b.majorant, "f", None)]
    for a, kinds, shape in checks:
        if a.dtype.kind not in kinds or (shape and a.shape != shape):
            return f"array of dtype {a.dtype} and shape {a.shape} where {kinds!r} {shape} expected"
    n = len(b.data)
    n_table = math.prod(int(d) for d in b.dims)
    if min(int(d) for d in b.dims) <= 0 or n_table > MAX_BRICKS or b.table.shape != (n_table,):
        return "table does not match dims"
    if np.abs(b.origin.astype(np.float64)).max() > MAX_ORIGIN:
        return f"origin {tuple(int(v) for v in b.origin)} is beyond VDB's int32 index range"
    if b.data.shape != (n, APRON, APRON, APRON) or b.majorant.shape != (n,):
        return f"data shape {b.data.shape} is not (n, {APRON}, {APRON}, {APRON})"
    if len(b.table) and (b.table.min() < -1 or b.table.max() >= n):
        return "table points past the data"
    if len(b.table) and np.count_nonzero(b.table >= 0) != len(np.unique(b.table[b.table >= 0])):
        return "table points twice at the same brick"
    problem = check_transform(b.index_to_world)
    if problem:
        return problem
    if b.emission is not None and (b.emission.shape != b.data.shape
                                   or b.emission_max.shape != (n,)):
        return "emission does not match data"
    if b.temperature is not None and b.temperature.shape != b.data.shape:
        return "temperature does not match data"
    b.origin, b.dims = b.origin.astype(np.int64), b.dims.astype(np.int32)
    b.table, b.data = b.table.astype(np.int32), np.array(b.data, np.float32)
    b.majorant = b.majorant.astype(np.float32)
    arrays = [("density", b.data, b.majorant)]
    if b.emission is not None:
        b.emission = np.array(b.emission, np.float32)
        b.emission_max = b.emission_max.astype(np.float32)
        arrays.append(("emission", b.emission, b.emission_max))
    for name, data, top in arrays:
        stats = [0, 0]
        _sanitise(data, (slice(None),) * 4, stats)
        _warn_sanitised(label, b.grid_name if name == "density" else (b.emission_grid_name or name),
                        stats)
        if any(stats):                  # the stored maxima saw the bad values: recompute
            top[:] = _max_per_slot(data)
        if not np.all(np.isfinite(top)) or (len(top) and top.min() < 0):
            return f"{name} majorants are negative or not finite"
        if np.any(top < _max_per_slot(data)):
            return f"{name} majorants are below the largest value of their bricks"
    if b.temperature is not None:
        b.temperature = np.array(b.temperature, np.float32)
    return None


# --------------------------------------------------------------------------- loading

def load_bricks(path, grid=None, emission_grid=None, progress=None, *, chunk=16,
                temperature_grid=None) -> Bricks:
    """Read the wanted grid(s) of a .vdb file into bricks, chunk^3 bricks at a time.

    OpenVDB reads the file in a reader process of its own (`_Reader`), because OpenVDB
    10 dies (SIGSEGV, SIGABRT) on some corrupt files: then this raises a UserError and the
    caller lives on. `$VOLRENDER_VDB_READER=0` reads in this process instead."""
    p = _check_file(path)
    if os.environ.get(READER_ENV, "") not in ("0", "1"):
        import_openvdb()                # here too: its absence is said without a reader
        return _READER.call(p, (p, grid, emission_grid, None),
                            dict(chunk=chunk, temperature_grid=temperature_grid), progress)
    return _load_bricks(p, grid, emission_grid, progress, chunk=chunk,
                        temperature_grid=temperature_grid)


def _load_bricks(p, grid=None, emission_grid=None, progress=None, *, chunk=16,
                 temperature_grid=None) -> Bricks:
    grids = list_grids(p)
    info = _pick(p, grids, grid, default=True)
    einfo = _pick(p, grids, emission_grid) if emission_grid is not None else None
    tinfo = _pick(p, grids, temperature_grid) if temperature_grid is not None else None
    _check_load_memory(p, info, [x for x in (einfo, tinfo) if x is not None])
    vdb = import_openvdb()
    g, m, box = _read_grid(vdb, p, info)
    if box is None:
        raise UserError(f"grid {info.name!r} is empty (0 active voxels)", path=p,
                        fix="nothing to render; choose another grid or frame; " + _listing(grids))
    lo, hi = box
    sources = [_vdb_source(g, box)]
    if einfo is not None:
        eg, em, ebox = (g, m, box) if einfo.name == info.name else _read_grid(vdb, p, einfo)
        if not np.allclose(em, m, rtol=1e-6, atol=1e-6 * _cbrt_det(m)):
            raise UserError(f"emission grid {einfo.name!r} has a different transform from "
                            f"{info.name!r}, which is unsupported", path=p,
                            fix="resample it onto the density grid's transform")
        if ebox is None:
            warnings.warn(f"{p}: emission grid {einfo.name!r} is empty; it adds no light",
                          stacklevel=2)
            sources.append(_zero_source())
        else:
            lo, hi = np.minimum(lo, ebox[0]), np.maximum(hi, ebox[1])
            sources.append(_vdb_source(eg, ebox))
    if tinfo is not None:
        tg, tm, tbox = _read_grid(vdb, p, tinfo)
        if not np.allclose(tm, m, rtol=1e-6, atol=1e-6 * _cbrt_det(m)):
            raise UserError(f"temperature grid {tinfo.name!r} has a different transform from "
                            f"{info.name!r}, which is unsupported", path=p,
                            fix="resample it onto the density grid's transform")
        sources.append(_zero_source() if tbox is None else _vdb_source(tg, tbox))
    try:
        origin, dims, table, out, stats, vrange = _build(p, sources, lo, hi, chunk, progress,
                                                         passive=int(tinfo is not None))
    except (UserError, KeyboardInterrupt):
        raise
    except MemoryError:             # OpenVDB's std::bad_alloc on a size read from the file
        raise UserError(f"ran out of memory reading the voxels of grid {info.name!r}", path=p,
                        fix="the file may be truncated or corrupt, or too large for this "
                            "machine (the memory check before reading passed)") from None
    except Exception as e:          # OpenVDB decompressing voxels as they are read
        raise UserError(f"cannot read the voxels of grid {info.name!r} ({_one_line(e)})",
                        path=p, fix="the file may be truncated or corrupt; re-export it") from None
    _warn_sanitised(p, info.name, stats[0])
    if len(out[0]) == 0:
        warnings.warn(f"{p}: grid {info.name!r} holds only zeros; it renders as empty space",
                      stacklevel=2)
    axis, why = up_axis_hint(grids)
    b = Bricks(origin, dims, table, out[0], _max_per_slot(out[0]), m, grid_name=info.name,
               source=str(p), background=float(g.background), value_range=vrange,
               active_voxels=int(g.activeVoxelCount()), up_axis=axis, up_axis_reason=why,
               index_box=(tuple(int(v) for v in box[0]), tuple(int(v) for v in box[1])))
    if einfo is not None:
        _warn_sanitised(p, einfo.name, stats[1])
        b.emission, b.emission_max = out[1], _max_per_slot(out[1])
        b.emission_grid_name = einfo.name
    if tinfo is not None:
        _warn_sanitised(p, tinfo.name, stats[-1])
        b.temperature, b.temperature_grid_name = out[-1], tinfo.name
    return b


def load_memory_estimate(infos) -> int | None:
    """Bytes that loading these grids takes at the least, from their metadata (None where
    it does not say): each grid as OpenVDB holds it ('file_mem_bytes', else 4 bytes an
    active voxel), plus the bricks, at least one per 512 active voxels of the density
    grid, 9^3 float32 each per grid, twice (the bricks are sorted into a copy)."""
    density = infos[0]
    if density.active_voxels is None:
        return None
    grids = sum(g.memory_bytes if g.memory_bytes is not None else 4 * (g.active_voxels or 0)
                for g in infos)
    bricks = -(-density.active_voxels // BRICK ** 3)
    return grids + 2 * bricks * APRON ** 3 * 4 * len(infos)


def _check_load_memory(path, info, others):
    need = load_memory_estimate([info, *others])
    if need is not None:
        check_memory(need, path, f"grid {info.name!r} ({info.active_voxels} active voxels)",
                     "crop or resample the grid to fewer voxels, or free memory")


# --------------------------------------------------------------------------- reader process

READER_ENV = "VOLRENDER_VDB_READER"     # "1" in the reader process; "0": read in-process


class _ReaderProcess:
    """A Python process that runs `_load_bricks` for this one (started on first use, kept
    for the next load, started again after it died). Requests and replies are pickles on
    its stdin and stdout: progress fractions and warnings as they come, then the Bricks
    (their arrays as raw out-of-band buffers, read straight into this process's memory)
    or the exception. If it dies, the file is what killed OpenVDB."""

    def __init__(self):
        import threading
        self.proc, self.lock, self.owner = None, threading.Lock(), os.getpid()

    def _start(self):
        import subprocess
        import sys
        root = str(Path(__file__).resolve().parents[1])
        env = {**os.environ, READER_ENV: "1",
               "PYTHONPATH": os.pathsep.join([root, *filter(None, [os.environ.get("PYTHONPATH")])])}
        import tempfile
        self.err = tempfile.TemporaryFile()      # what it says as it dies (glibc, OpenVDB)
        self.proc = subprocess.Popen([sys.executable, "-c", "from volrender import vdb; vdb._serve()"],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env,
                                     stderr=self.err, close_fds=True)

    def last_words(self) -> str:
        try:
            self.err.seek(0)
            lines = [ln.strip() for ln in self.err.read()[-4000:].decode(errors="replace").splitlines()]
        except (OSError, AttributeError):
            return ""
        lines = [ln for ln in lines if ln]
        return f": {lines[-1][:200]}" if lines else ""

    def stop(self):
        proc, self.proc = self.proc, None
        if proc is not None and self.owner == os.getpid():
            with __import__("contextlib").suppress(OSError):
                proc.stdin.close()
            try:
                proc.wait(timeout=5)
            except Exception:
                proc.kill()
                proc.wait()

    def call(self, path, args, kwargs, progress):
        import pickle
        with self.lock:
            if self.proc is None or self.owner != os.getpid() or self.proc.poll() is not None:
                self._start()           # (a forked child starts its own)
                self.owner = os.getpid()
            proc = self.proc
            try:
                try:
                    cwd = os.getcwd()           # relative paths mean the same there
                except OSError:
                    cwd, args = None, (Path(os.path.abspath(args[0])), *args[1:])
                _send(proc.stdin, pickle.dumps((cwd, args, kwargs)))
                while True:
                    kind, value = pickle.loads(_receive(proc.stdout))
                    if kind == "progress":
                        if progress is not None:
                            progress(value)
                    elif kind == "warning":
                        warnings.warn(value[0], value[1], stacklevel=3)
                    elif kind == "error":       # it exits after one: OpenVDB may have
                        proc.wait()             # left its heap damaged
                        self.proc = None
                        raise value
                    else:
                        sizes = value
                        head = _receive(proc.stdout)
                        buffers = []
                        for n in sizes:
                            b = bytearray(n)
                            view, got = memoryview(b), 0
                            while got < n:
                                k = proc.stdout.readinto(view[got:])
                                if not k:
                                    raise EOFError
                                got += k
                            buffers.append(b)
                        return pickle.loads(head, buffers=buffers)
            except (EOFError, OSError, pickle.UnpicklingError):
                code = proc.wait()
                self.proc = None
                import signal
                how = (f"signal {signal.Signals(-code).name}" if code < 0 and
                       -code in signal.Signals._value2member_map_ else f"exit status {code}")
                how += self.last_words()
                raise UserError(f"OpenVDB failed reading it (its reader process ended with "
                                f"{how}): truncated or corrupt OpenVDB file", path=path,
                                fix="re-export or re-download it") from None
            except BaseException:
                if self.proc is proc and proc.poll() is None:   # interrupted: a fresh one next
                    proc.kill()
                    proc.wait()
                    self.proc = None
                raise


def _send(f, data: bytes):
    f.write(struct.pack("<Q", len(data)))
    f.write(data)
    f.flush()


def _receive(f) -> bytes:
    head = f.read(8)
    if len(head) != 8:
        raise EOFError
    n = struct.unpack("<Q", head)[0]
    data = f.read(n)
    if len(data) != n:
        raise EOFError
    return data


def _serve():
    """The reader process: one request at a time on stdin, until it closes."""
    import pickle
    import signal
    import sys
    signal.signal(signal.SIGINT, signal.SIG_IGN)       # the caller decides
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)                                      # stray prints go to stderr
    inp = sys.stdin.buffer
    while True:
        try:
            cwd, args, kwargs = pickle.loads(_receive(inp))
        except EOFError:
            return
        if cwd is not None:
            try:
                os.chdir(cwd)
            except OSError:
                args = (Path(os.path.abspath(args[0])), *args[1:])

        def progress(x):
            _send(out, pickle.dumps(("progress", x)))

        def show(message, category, filename, lineno, file=None, line=None):
            _send(out, pickle.dumps(("warning", (str(message), category))))

        try:
            with warnings.catch_warnings():
                warnings.showwarning = show
                warnings.simplefilter("default")
                result = _load_bricks(*args[:3], progress, **kwargs)
        except BaseException as exc:                     # noqa: BLE001 (sent back whole)
            try:
                blob = pickle.dumps(("error", exc))
            except Exception:
                blob = pickle.dumps(("error", RuntimeError(f"{type(exc).__name__}: {exc}")))
            _send(out, blob)
            out.close()
            return
        buffers = []
        head = pickle.dumps(result, protocol=5, buffer_callback=buffers.append)
        raws = [b.raw() for b in buffers]
        _send(out, pickle.dumps(("result", [r.nbytes for r in raws])))
        _send(out, head)
        for r in raws:
            out.write(r)
        out.flush()
        del result, buffers, raws


_READER = _ReaderProcess()
__import__("atexit").register(_READER.stop)


def _cbrt_det(m):
    return float(np.cbrt(abs(np.linalg.det(m[:3, :3]))))


def load_volume(path, grid=None, emission_grid=None, temperature_grid=None) -> Bricks:
    """A .vdb grid or a .npz brick cache, by file suffix."""
    p = _check_file(path)
    suffix = p.suffix.lower()
    if suffix == ".vdb":
        return load_bricks(p, grid, emission_grid, temperature_grid=temperature_grid)
    if suffix == ".npz":
        b = load_npz(p)
        if grid is not None and grid != b.grid_name:
            raise UserError(f"this brick cache holds grid {b.grid_name!r}, not {grid!r}",
                            path=p, fix=f"convert the .vdb again with grid {grid!r}")
        if emission_grid is not None and emission_grid != b.emission_grid_name:
            have = f"emission grid {b.emission_grid_name!r}" if b.emission is not None \
                else "no emission grid"
            raise UserError(f"this brick cache has {have}, not {emission_grid!r}", path=p,
                            fix=f"convert the .vdb again with emission grid {emission_grid!r}")
        if temperature_grid is not None and temperature_grid != b.temperature_grid_name:
            have = f"temperature grid {b.temperature_grid_name!r}" if b.temperature is not None \
                else "no temperature grid"
            raise UserError(f"this brick cache has {have}, not {temperature_grid!r}", path=p,
                            fix="convert the .vdb again with --temperature-grid "
                                f"{temperature_grid}")
        return b
    raise UserError(f"unsupported volume file type {suffix or '(no suffix)'!r}", path=p,
                    fix="give an OpenVDB .vdb file or a .npz brick cache")


# --------------------------------------------------------------------------- bounds only

def _layout_world_bounds(origin, dims, index_to_world):
    ext = np.asarray(dims, np.float64) * BRICK
    corners = np.array([[x, y, z, 1.0] for x in (0, ext[0]) for y in (0, ext[1]) for z in (0, ext[2])])
    t = np.eye(4)
    t[:3, 3] = origin
    w = (np.asarray(index_to_world, np.float64) @ t @ corners.T)[:3].T
    return w.min(axis=0), w.max(axis=0)


def world_bounds(path, grid=None, emission_grid=None):
    """(lo, hi, up-axis hint) of the brick layout a file would load into, read from grid
    metadata (a .vdb's active boxes and transforms, a .npz's small arrays) without
    loading any voxels: the same box Bricks.world_bounds() gives after loading."""
    p = _check_file(path)
    if p.suffix.lower() == ".npz":
        fix = "convert the .vdb again (volrender convert)"
        try:
            with np.load(p, allow_pickle=False) as z:
                if not isinstance(z, np.lib.npyio.NpzFile):
                    raise ValueError("a bare .npy array")
                problem = _check_npz_members(z, p.stat().st_size)
                if problem:
                    raise ValueError(problem)
                origin, dims, m = z["origin"], z["dims"], z["index_to_world"]
                axis = str(z["up_axis"]) or None if "up_axis" in z.files else None
        except (KeyError, TypeError, SyntaxError, *_ZIP_ERRORS) as e:
            raise UserError(f"not a readable brick cache ({_one_line(e)})", path=p,
                            fix=fix) from None
        problem = (check_transform(m) if origin.shape == (3,) == dims.shape
                   and origin.dtype.kind in "iu" and dims.dtype.kind in "iu"
                   and np.abs(origin.astype(np.float64)).max() <= MAX_ORIGIN
                   and 0 < dims.min() and dims.max() <= MAX_BRICKS
                   else "origin or dims is not 3 integers in range")
        if problem:
            raise UserError(f"corrupt brick cache ({problem})", path=p, fix=fix)
        lo, hi = _layout_world_bounds(origin, dims, m)
        return lo, hi, axis
    grids = list_grids(p)
    names = [_pick(p, grids, grid, default=True)]
    if emission_grid is not None:
        names.append(_pick(p, grids, emission_grid))
    ov = import_openvdb()
    box_lo, box_hi, m = None, None, None
    for info in names:
        try:
            g = ov.readGridMetadata(str(p), info.name)
        except Exception as e:
            raise UserError(f"cannot read grid {info.name!r} ({_one_line(e)})", path=p,
                            fix="the file may be truncated or corrupt; re-export it") from None
        meta = g.metadata
        if "file_bbox_min" not in meta:
            continue
        lo, hi = (np.array(meta[k], np.int64) for k in ("file_bbox_min", "file_bbox_max"))
        if np.any(lo > hi):
            continue
        m = _index_to_world(g.transform) if m is None else m
        box_lo = lo if box_lo is None else np.minimum(box_lo, lo)
        box_hi = hi if box_hi is None else np.maximum(box_hi, hi)
    if box_lo is None:
        raise UserError(f"grid {names[0].name!r} is empty (0 active voxels)", path=p,
                        fix="nothing to render; choose another grid or frame")
    origin, dims = _layout(box_lo, box_hi)
    lo, hi = _layout_world_bounds(origin, dims, m)
    return lo, hi, up_axis_hint(grids)[0]
