"""OpenVDB grids -> sparse brick layout (volrender/bricks.py, with the .npz cache); the
file's header and metadata are parsed by hand in volrender/vdb_header.py.

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

Long file: one idea, reading OpenVDB, including the reader subprocess (_ReaderProcess,
_serve) that keeps a crash inside OpenVDB out of the renderer's process; the header and
the brick layout already live in vdb_header.py and bricks.py.
"""
from __future__ import annotations

import importlib
import importlib.util
import os
import pickle
import signal
import sys
import tempfile
import threading
import warnings
from pathlib import Path

import numpy as np

from .bricks import (MAX_BRICKS, MAX_ORIGIN, ZIP_ERRORS, Bricks, brick_box, build_bricks,
                     check_npz_members, check_transform, check_volume_file, load_npz,
                     max_per_slot, one_line, warn_sanitised, zero_source)
from .errors import UserError
from .files import check_memory
from .layout import APRON, BRICK  # shared with the kernels (cl/structs.h)
from .pipe_messages import receive, send
from .vdb_header import GridInfo, parse_vdb, up_axis_hint

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


def list_grids(path) -> list[GridInfo]:
    """Every grid in a .vdb file, in file order (works where readAllGridMetadata fails)."""
    p = check_volume_file(path)
    grids = parse_vdb(p)
    if grids is not None:
        return grids
    vdb = import_openvdb()
    try:
        return [GridInfo(g.name, g.valueTypeName, g.gridClass, g.metadata.get("file_voxel_count"))
                for g in vdb.readAllGridMetadata(str(p))]
    except Exception as e:
        raise UserError(f"cannot list its grids ({one_line(e)})", path=p,
                        fix="re-save it with a current OpenVDB") from None


def _listing(grids) -> str:
    return "available grids: " + ", ".join(g.describe() for g in grids)


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
        raise UserError(f"cannot read grid {info.name!r} ({one_line(e)})", path=path,
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


# --------------------------------------------------------------------------- loading

def load_bricks(path, grid=None, emission_grid=None, progress=None, *, chunk=16,
                temperature_grid=None) -> Bricks:
    """Read the wanted grid(s) of a .vdb file into bricks, chunk^3 bricks at a time.

    OpenVDB reads the file in a reader process of its own (`_Reader`), because OpenVDB
    10 dies (SIGSEGV, SIGABRT) on some corrupt files: then this raises a UserError and the
    caller lives on. `$VOLRENDER_VDB_READER=0` reads in this process instead."""
    p = check_volume_file(path)
    if os.environ.get(READER_ENV, "") not in ("0", "1"):
        if not any(importlib.util.find_spec(n) for n in ("pyopenvdb", "openvdb")):
            import_openvdb()            # its absence is said without a reader; its import
                                        # (0.1 s) is the reader's alone
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
            sources.append(zero_source())
        else:
            lo, hi = np.minimum(lo, ebox[0]), np.maximum(hi, ebox[1])
            sources.append(_vdb_source(eg, ebox))
    if tinfo is not None:
        tg, tm, tbox = _read_grid(vdb, p, tinfo)
        if not np.allclose(tm, m, rtol=1e-6, atol=1e-6 * _cbrt_det(m)):
            raise UserError(f"temperature grid {tinfo.name!r} has a different transform from "
                            f"{info.name!r}, which is unsupported", path=p,
                            fix="resample it onto the density grid's transform")
        sources.append(zero_source() if tbox is None else _vdb_source(tg, tbox))
    try:
        origin, dims, table, out, stats, vrange = build_bricks(p, sources, lo, hi, chunk, progress,
                                                         passive=int(tinfo is not None))
    except (UserError, KeyboardInterrupt):
        raise
    except MemoryError:             # OpenVDB's std::bad_alloc on a size read from the file
        raise UserError(f"ran out of memory reading the voxels of grid {info.name!r}", path=p,
                        fix="the file may be truncated or corrupt, or too large for this "
                            "machine (the memory check before reading passed)") from None
    except Exception as e:          # OpenVDB decompressing voxels as they are read
        raise UserError(f"cannot read the voxels of grid {info.name!r} ({one_line(e)})",
                        path=p, fix="the file may be truncated or corrupt; re-export it") from None
    warn_sanitised(p, info.name, stats[0])
    if len(out[0]) == 0:
        warnings.warn(f"{p}: grid {info.name!r} holds only zeros; it renders as empty space",
                      stacklevel=2)
    axis, why = up_axis_hint(grids)
    b = Bricks(origin, dims, table, out[0], max_per_slot(out[0]), m, grid_name=info.name,
               source=str(p), background=float(g.background), value_range=vrange,
               active_voxels=int(g.activeVoxelCount()), up_axis=axis, up_axis_reason=why,
               index_box=(tuple(int(v) for v in box[0]), tuple(int(v) for v in box[1])))
    if einfo is not None:
        warn_sanitised(p, einfo.name, stats[1])
        b.emission, b.emission_max = out[1], max_per_slot(out[1])
        b.emission_grid_name = einfo.name
    if tinfo is not None:
        warn_sanitised(p, tinfo.name, stats[-1])
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
        self.proc, self.lock, self.owner = None, threading.Lock(), os.getpid()

    def _start(self):
        import subprocess
        root = str(Path(__file__).resolve().parents[1])
        env = {**os.environ, READER_ENV: "1",
               "PYTHONPATH": os.pathsep.join([root, *filter(None, [os.environ.get("PYTHONPATH")])])}
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
                send(proc.stdin, pickle.dumps((cwd, args, kwargs)))
                while True:
                    kind, value = pickle.loads(receive(proc.stdout))
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
                        head = receive(proc.stdout)
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


def _serve():
    """The reader process: one request at a time on stdin, until it closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)       # the caller decides
    from .process import unblock_inherited
    unblock_inherited()                                # SIGTERM/SIGHUP end it as usual
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)                                      # stray prints go to stderr
    try:                                               # before the first request (it may
        import_openvdb()                               # have been started early: start_reader)
    except UserError:
        pass                                           # said again at the request
    inp = sys.stdin.buffer
    while True:
        try:
            cwd, args, kwargs = pickle.loads(receive(inp))
        except EOFError:
            return
        if cwd is not None:
            try:
                os.chdir(cwd)
            except OSError:
                args = (Path(os.path.abspath(args[0])), *args[1:])

        def progress(x):
            send(out, pickle.dumps(("progress", x)))

        def show(message, category, filename, lineno, file=None, line=None):
            send(out, pickle.dumps(("warning", (str(message), category))))

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
            send(out, blob)
            out.close()
            return
        buffers = []
        head = pickle.dumps(result, protocol=5, buffer_callback=buffers.append)
        raws = [b.raw() for b in buffers]
        send(out, pickle.dumps(("result", [r.nbytes for r in raws])))
        send(out, head)
        for r in raws:
            out.write(r)
        out.flush()
        del result, buffers, raws


_READER = _ReaderProcess()
__import__("atexit").register(_READER.stop)


def start_reader() -> bool:
    """Start the OpenVDB reader process now, if it will be used (OpenVDB installed, no
    $VOLRENDER_VDB_READER) and is not running: its start-up (Python, numpy, OpenVDB: ~0.75
    of smoke.vdb's 1.16 s cold load on the 2-core PoCL machine; the bricks' build is
    0.09 s, OpenVDB's read 0.04 s; docs/error_time.md) then overlaps the caller's own, e.g.
    its device's. True where it started one."""
    if os.environ.get(READER_ENV, "") in ("0", "1") or \
            not any(importlib.util.find_spec(n) for n in ("pyopenvdb", "openvdb")):
        return False
    with _READER.lock:
        if _READER.proc is not None and _READER.owner == os.getpid() and \
                _READER.proc.poll() is None:
            return False
        _READER._start()
        _READER.owner = os.getpid()
        return True


def _cbrt_det(m):
    return float(np.cbrt(abs(np.linalg.det(m[:3, :3]))))


def load_volume(path, grid=None, emission_grid=None, temperature_grid=None) -> Bricks:
    """A .vdb grid or a .npz brick cache, by file suffix."""
    p = check_volume_file(path)
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
    p = check_volume_file(path)
    if p.suffix.lower() == ".npz":
        fix = "convert the .vdb again (volrender convert)"
        try:
            with np.load(p, allow_pickle=False) as z:
                if not isinstance(z, np.lib.npyio.NpzFile):
                    raise ValueError("a bare .npy array")
                problem = check_npz_members(z, p.stat().st_size)
                if problem:
                    raise ValueError(problem)
                origin, dims, m = z["origin"], z["dims"], z["index_to_world"]
                axis = str(z["up_axis"]) or None if "up_axis" in z.files else None
        except (KeyError, TypeError, SyntaxError, *ZIP_ERRORS) as e:
            raise UserError(f"not a readable brick cache ({one_line(e)})", path=p,
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
            raise UserError(f"cannot read grid {info.name!r} ({one_line(e)})", path=p,
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
    origin, dims = brick_box(box_lo, box_hi)
    lo, hi = _layout_world_bounds(origin, dims, m)
    return lo, hi, up_axis_hint(grids)[0]
