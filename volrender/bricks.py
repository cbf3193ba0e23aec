"""The sparse brick layout the volume kernels read, and volrender's .npz brick cache
(written by `volrender convert`, validated member by member on reading: a fuzz target).
Layout: see volrender/vdb.py.

Long file: two sides of one format, the Bricks record with its builder and the .npz cache
reader that validates it; the reader (check_npz_members, load_npz, read_npz, _validate:
about 140 lines) is the seam if either grows."""
from __future__ import annotations

import math
import os
import struct
import tokenize
import warnings
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import atomic
from .errors import UserError
from .files import check_input, check_memory, npy_header
from .framing import box_corners, column_extremes
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


def check_volume_file(path) -> Path:
    return check_input(path, "volume file", fix="give a .vdb or .npz file")


def one_line(e: Exception) -> str:
    return f"{type(e).__name__}: {e}".replace("\n", " ").strip()


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


def zero_source():
    return (lambda lo, shape: np.zeros(tuple(int(s) for s in shape), np.float32)), \
           (lambda lo, hi: True)



def brick_box(lo, hi):
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


def build_bricks(label, sources, lo, hi, chunk=16, progress=None, passive=0):
    """Bricks from (read, is_zero) sources (density, then emission, then the `passive`
    ones: temperature) over box lo..hi. Passive sources are stored in the bricks the
    others make, and may be negative.

    Works chunk^3 bricks at a time, so memory holds one chunk plus the kept bricks.
    """
    n_active = len(sources) - passive
    origin, dims = brick_box(lo, hi)
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


def warn_sanitised(label, name, stats):
    bad, neg = stats
    if bad:
        warnings.warn(f"{label}: grid {name!r} has {bad} NaN/Inf voxels; replaced by 0",
                      stacklevel=3)
    if neg:
        warnings.warn(f"{label}: grid {name!r} has {neg} negative voxels; clamped to 0 "
                      "(a density cannot be negative)", stacklevel=3)


def max_per_slot(data):
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
    up_axis: str | None = None        # the up axis the file suggests (vdb_header.up_axis_hint)
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

    def occupied_corners(self, sub: int = 2) -> np.ndarray:
        """World corners of the content's boxes, for the default camera's fit: in each
        brick on the outside of the occupied ones (framing.column_extremes), the box of the
        non-zero voxels (density or emission; a voxel spans its centre +- 0.5) of each
        `sub`^3 block. The layout's corners when no voxel is non-zero."""
        core = self.data[:, :BRICK, :BRICK, :BRICK] != 0
        if self.emission is not None:
            core = core | (self.emission[:, :BRICK, :BRICK, :BRICK] != 0)
        slots = np.nonzero(core.reshape(len(core), -1).any(axis=1))[0]
        if len(slots) == 0:
            return box_corners(*self.world_bounds())
        where = np.nonzero(self.table >= 0)[0]
        brick_of = np.empty(len(self.data), np.int64)
        brick_of[self.table[where]] = where
        flat = brick_of[slots]
        b = np.stack([flat // (self.dims[1] * self.dims[2]), flat // self.dims[2] % self.dims[1],
                      flat % self.dims[2]], axis=1)
        occ = np.zeros(tuple(self.dims), bool)
        occ[b[:, 0], b[:, 1], b[:, 2]] = True
        outer = column_extremes(occ)[b[:, 0], b[:, 1], b[:, 2]]
        b, q = b[outer], BRICK // sub
        blocks = core[slots[outer]].reshape(-1, q, sub, q, sub, q, sub)
        lo = np.empty(blocks.shape[:1] + (q, q, q, 3))
        hi = np.empty_like(lo)
        full = None
        for axis, (keep, others) in enumerate(((2, (4, 6)), (4, (2, 6)), (6, (2, 4)))):
            has = np.moveaxis(blocks.any(axis=others), keep - len([o for o in others if o < keep]), -1)
            full = has.any(axis=-1) if full is None else full
            step = np.arange(q).reshape([q if i == axis else 1 for i in range(3)]) * sub
            lo[..., axis] = step + has.argmax(axis=-1) - 0.5
            hi[..., axis] = step + sub - 1 - has[..., ::-1].argmax(axis=-1) + 0.5
        n, i, j, k = np.nonzero(full)
        base = (b[n] * BRICK)[:, None, :]
        pick = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], bool)
        local = (base + np.where(pick[None], hi[n, i, j, k][:, None], lo[n, i, j, k][:, None])
                 ).reshape(-1, 3)
        m = self.local_to_world
        return local @ m[:3, :3].T + m[:3, 3]

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
        lo_, dims, table, out, stats, vrange = build_bricks("<dense>", sources, origin, hi, chunk,
                                                      passive=int(temperature is not None))
        warn_sanitised("<dense>", name, stats[0])
        m = np.eye(4) if index_to_world is None else np.asarray(index_to_world, np.float64)
        if m.shape != (4, 4):
            raise ValueError(f"index_to_world must be 4x4, got shape {m.shape}")
        b = cls(lo_, dims, table, out[0], max_per_slot(out[0]), m, grid_name=name,
                source="<dense>", value_range=vrange,
                active_voxels=int(np.count_nonzero(values)))
        if emission is not None:
            warn_sanitised("<dense>", "emission", stats[1])
            b.emission, b.emission_max = out[1], max_per_slot(out[1])
            b.emission_grid_name = "emission"
        if temperature is not None:
            warn_sanitised("<dense>", "temperature", stats[-1])
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
ZIP_ERRORS = (OSError, ValueError, EOFError, zipfile.BadZipFile, NotImplementedError,
               RuntimeError, zlib.error, struct.error, OverflowError, LookupError,
               tokenize.TokenError)


def check_npz_members(z, size):
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
    p = check_volume_file(path)
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
    except ZIP_ERRORS as e:
        raise UserError(f"not a readable .npz file ({one_line(e)})", path=p, fix=fix) from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise UserError("not a volrender brick cache (a bare .npy array)", path=p, fix=fix)
    with z:
        try:
            problem = check_npz_members(z, size)
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
        except (KeyError, TypeError, SyntaxError, *ZIP_ERRORS) as e:
            raise UserError(f"corrupt brick cache ({one_line(e)})", path=p, fix=fix) from None
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
        warn_sanitised(label, b.grid_name if name == "density" else (b.emission_grid_name or name),
                        stats)
        if any(stats):                  # the stored maxima saw the bad values: recompute
            top[:] = max_per_slot(data)
        if not np.all(np.isfinite(top)) or (len(top) and top.min() < 0):
            return f"{name} majorants are negative or not finite"
        if np.any(top < max_per_slot(data)):
            return f"{name} majorants are below the largest value of their bricks"
    if b.temperature is not None:
        b.temperature = np.array(b.temperature, np.float32)
    return None
