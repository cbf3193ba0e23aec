"""Support cells: the glass field's second acceleration structure (cl/cells.h reads it).

A sparse world-space grid over the clip box (render frame), cells of edge `cell` in bricks
of CELL_BRICK^3. Every cell the surface can pass through lists every sphere that can
contribute to the field anywhere inside it (built as runs of ascending sphere indices;
the renderer reads it sphere by sphere by ascending key, the walk, so that its passes stop
early: Cells.walk and Cells.entries); cells and whole bricks wholly outside the glass carry a
lower bound of the field and cells wholly inside an upper one, and rays of that side cross
them without evaluating anything. Bounds and lists are derived in cl/build_cells.cl's
banner and docs/DESIGN.md; tests/reference.py's `oracle` is the same construction in numpy
(float64, brute force over all spheres).

The build runs on the render device (cl/build_cells.cl), walking the partition tree
(volrender/tree.py) for boxes of up to 16 bricks, then classifying the octants of the boxes
left unclassified from their parent's list, down to cells; each level's lists are counted,
prefix-summed here (numpy on CPUs, pyopencl scans on GPUs) and written by a second pass.
tests/reference.py's `host_lists` is the numpy alternative (vectorised tree queries; x10
slower per cell, measured in docs/DESIGN.md).

Long file: one idea, the device builder (_Builder's named steps) with the Cells record and
the edge heuristics that size it; the numpy oracles live in tests/reference.py.
"""
from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass

import numpy as np

from . import layout
from .tree_device import padded

B = layout.CELL_BRICK
B3 = B ** 3
OUTSIDE, INSIDE = layout.CELL_OUTSIDE, layout.CELL_INSIDE
MAX_BRICKS = 1 << 21          # the brick table (8 bytes each): the cell edge grows to fit
MAX_ITEMS = 1 << 30           # list runs (8 bytes each, 8 GiB; int32 offsets), also at most
                              # the device's largest buffer; beyond: the tree walk
MAX_LIST = 1 << 16            # runs on one brick's list; beyond: the tree walk
MAX_BRICK_SPHERES = 1 << 16   # sphere centres in one brick; beyond (coincident points): the
                              # tree walk, since every cell near them would scan them all
CELL_FACTOR = 0.25            # automatic edge: CELL_FACTOR * (median radius + blend / 2)
PAD = 1e-5                    # list threshold and bound margins, relative to the extent
J = layout.CELL_BOUNDS_J      # sub-intervals of [M, U] in the bounds (cl/build_cells.cl CB_J)
# The automatic cell edge. GPUs: the base edge, grown until the bricks the surface passes
# through hold at most GPU_CELLS cells (the build is a small part of a frame there). CPUs:
# the finest of EDGE_FACTORS x the base edge whose estimated cells (estimate_cells) are at
# most CPU_CELLS_PER_SAMPLE per pixel sample of the job, else the tree walk: the rule
# bench/edge.py fits on PoCL (whole time x1.10 of the best choice, worst x1.56, over 8
# clouds and 80x60 to 1920x1080; docs/benchmarks.md).
GPU_CELLS = 1 << 24
CPU_CELLS_PER_SAMPLE = 2
EDGE_FACTORS = (1.0, 1.5, 2.0, 3.0, 4.0)
DEFAULT_SAMPLES = 640 * 480       # a job without a sample count (volrender tree --cells)


class TooLarge(Exception):
    """The lists would not fit (MAX_ITEMS): use the tree walk."""


@dataclass(frozen=True)
class CellsSummary:
    """What Image.info.cells reports of a render's support cells."""
    cell: float               # cell edge, world units
    dims: tuple               # cells per axis
    cells_listed: int         # cells that hold a list
    runs: int
    bytes: int                # device memory of the bricks, cells, lists, runs and entries
    build_ms: float
    build_kernel_ms: float    # of build_ms, in the build's kernels


@dataclass(frozen=True, eq=False)
class Cells:
    lo: np.ndarray            # float32 (3,): min corner of cell (0, 0, 0), render frame
    cell: float               # cell edge, world units
    dims: np.ndarray          # int (3,): cells per axis
    bdims: np.ndarray         # int (3,): bricks per axis
    bricks: np.ndarray        # int32 (n_bricks, 2): code, bound bits (cl/cells.h)
    n_cell_rows: int          # rows of `cells`: n_blocks * B^3
    n_lists: int              # rows of `lists`: the listed cells
    runs_device: object       # cl.Buffer of the runs, in the builder's context: renders
                              # read it there, the host copy (runs) is made on first use
    n_runs: int
    queue: object             # the builder's queue
    tau: float                # skippable cells have |F| > tau
    pad: float                # lists hold lo_i <= U + k + pad
    build_ms: float
    build_kernel_ms: float = 0.0    # of build_ms, in the build's kernels (profiling events)
    build_launches: int = 0
    buffers: tuple = ()       # device bricks, cells, lists (the builder's context): renders
                              # there read them; the host cells and lists are copied on use
    walk_device: tuple = ()   # device walk lists and entries, what renders read (walk)
    n_entries: int = 0

    def _host(self, key, buffer, rows, cols):
        host = self.__dict__.get(key)
        if host is None:
            import pyopencl as cl
            host = np.empty((max(rows, 1), cols), np.int32)
            cl.enqueue_copy(self.queue, host, buffer)
            host = host[:rows]
            object.__setattr__(self, key, host)
        return host

    @property
    def cells(self) -> np.ndarray:
        """int32 (n_blocks * B^3, 2): code, bound bits of every cell of the mixed bricks."""
        return self._host("_cells", self.buffers[1], self.n_cell_rows, 2)

    @property
    def lists(self) -> np.ndarray:
        """int32 (n_lists, 4): list start, count, core start, count in runs (core: the
        spheres that can be the nearest)."""
        return self._host("_lists", self.buffers[2], self.n_lists, 4)

    @property
    def runs(self) -> np.ndarray:
        """int32 (n_runs, 2): first sphere, count of consecutive sphere indices (tree
        order), ascending within a list."""
        return self._host("_runs", self.runs_device, self.n_runs, 2)

    @property
    def walk(self) -> np.ndarray:
        """int32 (n_lists, 4): the render's lists, start, count, start, core count in
        entries (cl/build_cells.cl, build_walk_fill)."""
        return self._host("_walk", self.walk_device[0], self.n_lists, 4)

    @property
    def entries(self) -> np.ndarray:
        """int32 (n_entries, 2): sphere, key bits (float32 lo_i - pad: at most the sphere's
        distance from any point of its cell), each list by ascending key."""
        return self._host("_entries", self.walk_device[1], self.n_entries, 2)

    @property
    def nbytes(self) -> int:
        return (self.bricks.nbytes + 8 * self.n_cell_rows + 32 * self.n_lists
                + 8 * self.n_runs + 8 * self.n_entries)

    def lengths(self, core=False):
        """Spheres on each list (or core)."""
        start, count = (self.lists[:, 2], self.lists[:, 3]) if core else \
            (self.lists[:, 0], self.lists[:, 1])
        c = np.concatenate([[0], np.cumsum(self.runs[:, 1], dtype=np.int64)])
        return c[start + count] - c[start]

    def summary(self) -> "CellsSummary":
        """What a render reports (cheap: the runs stay on the device)."""
        return CellsSummary(float(self.cell), tuple(int(v) for v in self.dims),
                            int(self.n_lists), int(self.n_runs), int(self.nbytes),
                            self.build_ms, self.build_kernel_ms)

    def stats(self) -> dict:
        """Counts for reports and benchmarks (reads the runs back from the device)."""
        codes = self.cells[:, 0]
        bcodes = self.bricks[:, 0]
        n = self.lengths()
        nc = self.lengths(core=True)
        return {"cell": float(self.cell), "dims": [int(v) for v in self.dims],
                "bricks": int(len(bcodes)), "mixed_bricks": int((bcodes >= 0).sum()),
                "bricks_outside": int((bcodes == OUTSIDE).sum()),
                "bricks_inside": int((bcodes == INSIDE).sum()),
                "cells_listed": int(len(self.lists)),
                "cells_outside": int((codes == OUTSIDE).sum()),
                "cells_inside": int((codes == INSIDE).sum()),
                "list_mean": float(n.mean()) if len(n) else 0.0,
                "list_max": int(n.max()) if len(n) else 0,
                "core_mean": float(nc.mean()) if len(nc) else 0.0,
                "entries": int(n.sum() + nc.sum()), "runs": int(len(self.runs)),
                "walk_entries": int(self.n_entries),
                "bytes": int(self.nbytes), "build_ms": self.build_ms,
                "build_kernel_ms": self.build_kernel_ms, "build_launches": self.build_launches}

    def box(self, q):
        """(lo, hi) float64 of the cells with integer coordinates q (..., 3)."""
        q = np.asarray(q, np.float64)
        lo = self.lo.astype(np.float64)
        return lo + q * self.cell, lo + (q + 1) * self.cell

    def locate(self, x):
        """Integer cell coordinates of render-frame points x (M, 3), clamped (cl/cells.h)."""
        g = np.floor((np.asarray(x, np.float32) - self.lo) * np.float32(1.0 / self.cell))
        return np.clip(g, 0, self.dims - 1).astype(np.int64)

    def lookup(self, q):
        """For cell coordinates q (M, 3): (code, bound, list of sphere indices or None); the
        cores are `core(code)`."""
        q = np.asarray(q, np.int64).reshape(-1, 3)
        b = q // B
        bi = (b[:, 2] * self.bdims[1] + b[:, 1]) * self.bdims[0] + b[:, 0]
        e = self.bricks[bi]
        code = e[:, 0].copy()
        bound = e[:, 1].view(np.float32).astype(np.float64)
        mixed = code >= 0
        l = q[mixed] - b[mixed] * B
        v = self.cells[e[mixed, 0] * B3 + (l[:, 2] * B + l[:, 1]) * B + l[:, 0]]
        code[mixed] = v[:, 0]
        bound[mixed] = v[:, 1].view(np.float32)
        lists = [None] * len(q)
        for j in np.nonzero(code >= 0)[0]:
            s, n = self.lists[code[j], :2]
            lists[j] = _expand(self.runs[s:s + n])
        return code, bound, lists

    def core(self, code):
        """The core list (the spheres that can be nearest) of listed cell `code`."""
        s, n = self.lists[code, 2:]
        return _expand(self.runs[s:s + n])


def _expand(runs):
    """Sphere indices of runs (first, count)."""
    if len(runs) == 0:
        return np.zeros(0, np.int64)
    return np.concatenate([np.arange(a, a + c) for a, c in runs])


def auto_cell_size(radii, blend) -> float:
    """The cell edge chosen from the spheres: CELL_FACTOR * (median radius + blend / 2)."""
    r = float(np.median(radii)) if len(radii) else 0.0
    return CELL_FACTOR * (r + 0.5 * float(blend))


def choose_edge(spheres, blend, box_lo, base, samples) -> float | None:
    """The CPU rule (see EDGE_FACTORS): the finest factor x base whose estimated cells are
    at most CPU_CELLS_PER_SAMPLE x samples, or None (the tree walk: support cells would
    not repay their build on a job this small)."""
    samples = DEFAULT_SAMPLES if samples is None else samples
    centres = np.asarray(spheres[:, :3], np.float64) - np.asarray(box_lo, np.float64)
    for m in EDGE_FACTORS:
        if estimate_cells(spheres, blend, None, m * base, centres) <= CPU_CELLS_PER_SAMPLE * samples:
            return m * base
    return None


def grid_shape(box_lo, box_hi, cell):
    """(cell, dims, bdims) covering [box_lo, box_hi]; the edge grows until the brick
    table fits MAX_BRICKS (and is never 0)."""
    ext = np.maximum(np.asarray(box_hi, np.float64) - np.asarray(box_lo, np.float64), 0.0)
    size = float(ext.max())
    if not cell > 0 or not math.isfinite(cell):
        cell = size / 64 if size > 0 else 1.0
    cell = max(cell, size * 2.0 ** -20, 1e-30)
    while True:
        dims = np.maximum(np.ceil(ext / cell).astype(np.int64), 1)
        bdims = -(-dims // B)
        if int(bdims.prod()) <= MAX_BRICKS:
            return float(cell), dims, bdims
        cell *= 1.25


def hit_length(scale, box_lo, box_hi, bounces) -> float:
    """The longest base + t whose hit threshold eps (base + t) grows (the kernels clamp it
    here, GlassParams.hit_len): the hit floor, a camera up to four box diagonals from the
    box, one diagonal per segment and one for the shadow ray. Independent of the camera, so
    the cells serve every view; a camera farther away gets a tighter threshold, not a
    missed skip."""
    diag = float(np.linalg.norm(np.asarray(box_hi, np.float64) - np.asarray(box_lo, np.float64)))
    return 1e-2 * scale + 4.0 * diag + (bounces + 2) * diag


def threshold(epsilon, bounces, scale, box_lo, box_hi, blend=0.0, n=1) -> float:
    """tau: above every hit threshold eps * min(base + t, hit_length) a render can test
    (cl/sdf.h), and above float32 rounding of the field."""
    lo, hi = np.asarray(box_lo, np.float64), np.asarray(box_hi, np.float64)
    t_max = hit_length(scale, lo, hi, bounces)
    extent = float(np.abs(np.concatenate([lo, hi])).max())
    rounding = PAD * (extent + blend * (1.0 + math.log(max(n, 1))))
    return 2.0 * epsilon * t_max + rounding


def _round_up(n, m=64):
    return max(m, -(-n // m) * m)


def build(spheres, nodes, first_leaf, blend, box_lo, box_hi, cell, tau, device,
          classify=True, max_cells=None, max_runs=None, host_scans=None) -> Cells:
    """Support cells over [box_lo, box_hi] (render frame) for float32 `spheres` (N, 4, tree
    order) and their TreeNode records, on `device` (a volrender.device.Device).
    classify=False lists every cell (tests). max_runs: most list runs (default MAX_ITEMS,
    and what the device's largest buffer holds); beyond, TooLarge.
    max_cells: when the bricks the surface passes through hold more cells than this, the
    cell edge grows by (cells / max_cells)^0.5, the brick pass redone, until they fit.
    Everything between the levels stays on the device (_Builder): a level reads back its
    count of unclassified boxes and its total of list runs, nothing else. host_scans: the
    prefix sums and compactions in numpy (default: on CPUs, where the device's memory is
    the host's and pyopencl's scan kernels cost ~0.4 s to make in every process)."""
    t0 = time.perf_counter()
    lo = np.asarray(box_lo, np.float32)
    extent = float(np.abs(np.concatenate([np.asarray(box_lo, np.float64),
                                          np.asarray(box_hi, np.float64)])).max())
    pad = PAD * (extent + blend)
    max_runs = min(MAX_ITEMS if max_runs is None else int(max_runs),
                   int(device.device.max_mem_alloc_size) // 8)
    cell = grid_shape(box_lo, box_hi, cell)[0]
    crowd = int(_occupancy(np.asarray(spheres[:, :3]) - lo, B * cell).max())
    if crowd > MAX_BRICK_SPHERES:
        raise TooLarge(f"{crowd} sphere centres in one brick")
    if host_scans is None:
        from .dispatch import is_gpu
        host_scans = not is_gpu(device)
    b = _Builder(device, spheres, nodes, first_leaf, max_runs, host_scans)
    while True:
        cell, dims, bdims = grid_shape(box_lo, box_hi, cell)
        params = layout.record("CellBuild", grid_lo=[*lo, cell], blend=blend, pad=pad,
                               tau=float(tau) if classify else 3e38, n_spheres=len(spheres),
                               first_leaf=first_leaf, box_cells=B)
        b.start(params, bdims)
        level = b.bricks()
        if max_cells is None or level.kept * B3 <= max_cells or level.kept <= 1:
            break
        cell *= max(1.1, (level.kept * B3 / max_cells) ** 0.5)
    level = b.cells(level)
    walk, entries, n_entries = b.walk(level)
    bricks, n_cell_rows = b.tables()
    kernel_ms = b.kernel_ms()
    return Cells(lo, cell, dims, bdims, bricks, n_cell_rows, level.kept, level.runs,
                 level.total, device.queue, float(tau), pad, 1e3 * (time.perf_counter() - t0),
                 kernel_ms, b.launches,
                 buffers=(b.table.data, b.cells_table.data, level.lists.data),
                 walk_device=(walk.data, entries), n_entries=n_entries)


TOP_BOXES = 1 << 15           # boxes of the first (tree-walking) level, at most


@dataclass
class _Level:
    """One level of boxes on the device: their origins (cells), blocks, classification,
    and the kept (unclassified) ones with their lists and runs."""
    size: int                 # box edge, cells
    origins: object           # int4 (n,) device array
    blk: object               # int (n,): the brick's block (cell levels)
    n: int
    out: object = None        # int4 (n,): class, runs, core runs or bound bits, U bits
    sel: object = None        # int (kept,): the kept boxes' indices
    kept: int = 0
    lists: object = None      # int4 (kept,): list start, count, core start, count
    runs: object = None       # cl.Buffer of int2 runs
    total: int = 0


class _Builder:
    """The device side of build: the kernels of cl/build_cells.cl and pyopencl scans for
    the prefix sums (list offsets) and compaction (the unclassified boxes)."""

    def __init__(self, device, spheres, nodes, first_leaf, max_runs, host_scans=False):
        import pyopencl as cl
        import pyopencl.array as cla
        self.cl, self.cla, self.padded = cl, cla, padded
        self.device, self.q = device, device.queue
        self.max_runs = max_runs
        flags = {"VR_TREE_STACK": layout.tree_stack(first_leaf)}
        self.k = {n: device.kernel("build_cells", flags, n) for n in (
            "build_classify", "build_classify_sub", "build_fill", "build_expand",
            "build_paint_bricks", "build_mark_mixed", "build_paint_cells",
            "build_mark_listed", "build_walk_count", "build_walk_fill")}
        self.host = host_scans
        self.scans = None if host_scans else _scans(device.context)
        mf = cl.mem_flags
        self.sp = cl.Buffer(device.context, mf.READ_ONLY | mf.COPY_HOST_PTR,
                            hostbuf=np.ascontiguousarray(spheres if len(spheres) else
                                                         np.zeros((1, 4), np.float32)))
        self.nodes = cl.Buffer(device.context, mf.READ_ONLY | mf.COPY_HOST_PTR,
                               hostbuf=np.ascontiguousarray(nodes))
        self.none = cla.zeros(self.q, 1, cl.cltypes.int4)
        self.events, self.launches = [], 0

    def _run(self, name, n, *args):
        if n > 0:
            self.events.append(self.k[name](self.q, (_round_up(n),), None, *args))
            self.launches += 1

    def start(self, params, bdims):
        cla, cl = self.cla, self.cl
        self.bdims = np.asarray(bdims, np.int64)
        self.bd4 = cl.cltypes.make_int4(*[int(v) for v in bdims], 0)
        self.prm = {}
        for size in (B << t for t in range(5)):
            p = params.copy()
            p["box_cells"] = size
            self.prm[size] = cl.Buffer(self.device.context,
                                       cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                                       hostbuf=p)
        for size in (1, 2, 4):
            p = params.copy()
            p["box_cells"] = size
            self.prm[size] = cl.Buffer(self.device.context,
                                       cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                                       hostbuf=p)
        self.table = cla.empty(self.q, int(np.prod(bdims)), cl.cltypes.int2)
        self.table.fill(cl.cltypes.make_int2(-99, 0))

    def _classify(self, lv, parent=None):
        cla, cl = self.cla, self.cl
        lv.out = cla.empty(self.q, max(lv.n, 1), cl.cltypes.int4)
        if parent is None:
            self._run("build_classify", lv.n, self.prm[lv.size], self.sp, self.nodes,
                      lv.origins.data, lv.out.data, np.int32(lv.n))
        else:
            self._run("build_classify_sub", lv.n, self.prm[lv.size], self.sp, parent.runs,
                      parent.lists.data, lv.origins.data, lv.out.data, np.int32(lv.n))

    def _keep(self, lv, inside):
        """Compact the unclassified boxes (inside the grid, at brick levels)."""
        cla = self.cla
        if self.host:
            out = lv.out.get()[:lv.n]
            keep = out["s0"] == 0
            if inside and lv.n:
                org = lv.origins.get()[:lv.n]
                for f, v in zip(("s0", "s1", "s2"), self.bdims):
                    keep &= org[f] // B < v
            sel = np.flatnonzero(keep).astype(np.int32)
            lv.kept = len(sel)
            lv.sel = cla.to_device(self.q, sel if len(sel) else np.zeros(1, np.int32))
            return
        lv.sel = cla.empty(self.q, max(lv.n, 1), np.int32)
        count = cla.zeros(self.q, 1, np.int32)
        if lv.n:
            bd = [int(v) for v in self.bdims]
            self.scans["keep"](lv.out, lv.origins, np.int32(lv.n), *map(np.int32, bd),
                               np.int32(inside), lv.sel, count, size=self.padded(lv.n, self.device),
                               queue=self.q)
        lv.kept = int(count.get()[0])

    def _fill(self, lv, parent=None):
        cla, cl = self.cla, self.cl
        if self.host:
            o = lv.out.get()[lv.sel.get()[:lv.kept]] if lv.kept else np.zeros(0, cl.cltypes.int4)
            n, nc = o["s1"].astype(np.int64), o["s2"].astype(np.int64)
            ends = np.cumsum(n + nc)
            lv.total = int(ends[-1]) if len(ends) else 0
            if lv.total > self.max_runs:
                raise TooLarge(f"over {self.max_runs} list runs")
            start = ends - n - nc
            lists = np.zeros(max(lv.kept, 1), cl.cltypes.int4)
            lists["s0"][:lv.kept], lists["s1"][:lv.kept] = start, n
            lists["s2"][:lv.kept], lists["s3"][:lv.kept] = start + n, nc
            lv.lists = cla.to_device(self.q, lists)
            longest = int(n.max()) if lv.size == B and lv.kept else 0
        else:
            lv.lists = cla.empty(self.q, max(lv.kept, 1), cl.cltypes.int4)
            total = cla.zeros(self.q, 1, np.int64)
            if lv.kept:
                self.scans["lists"](lv.out, lv.sel, np.int32(lv.kept), lv.lists, total,
                                    size=self.padded(lv.kept, self.device), queue=self.q)
            lv.total = int(total.get()[0])
            if lv.total > self.max_runs:
                raise TooLarge(f"over {self.max_runs} list runs")
            longest = int(self.scans["longest"](lv.out, lv.sel, range=slice(lv.kept),
                                                queue=self.q).get()) \
                if lv.size == B and lv.kept else 0
        if longest > MAX_LIST:
            raise TooLarge(f"a brick's list holds {longest} runs")
        lv.runs = cl.Buffer(self.device.context, cl.mem_flags.READ_WRITE, 8 * max(lv.total, 1))
        if parent is None:
            self._run("build_fill", lv.kept, self.prm[lv.size], self.sp, self.nodes,
                      self.none.data, self.none.data, lv.sel.data, lv.origins.data, lv.out.data,
                      lv.lists.data, lv.runs, np.int32(lv.kept), np.int32(1))
        else:
            self._run("build_fill", lv.kept, self.prm[lv.size], self.sp, self.nodes,
                      parent.runs, parent.lists.data, lv.sel.data, lv.origins.data,
                      lv.out.data, lv.lists.data, lv.runs, np.int32(lv.kept), np.int32(0))

    def _expand(self, lv):
        cla, cl = self.cla, self.cl
        n = 8 * lv.kept
        nxt = _Level(lv.size // 2, cla.empty(self.q, max(n, 1), cl.cltypes.int4),
                     cla.empty(self.q, max(n, 1), np.int32), n)
        self._run("build_expand", n, lv.origins.data, lv.blk.data, lv.sel.data,
                  np.int32(lv.kept), np.int32(lv.size // 2), nxt.origins.data, nxt.blk.data)
        return nxt

    def bricks(self):
        """Classify every brick: boxes of 2^t bricks from the tree first (t: the smallest
        with at most TOP_BOXES of them), then the octants of the unclassified ones from
        their parents' lists, down to bricks. Returns the brick level (kept: the mixed
        bricks, each given its block)."""
        cla, cl = self.cla, self.cl
        bdims = self.bdims
        t = 0
        while t < 4 and int(np.prod(-(-bdims // (1 << t)))) > TOP_BOXES:
            t += 1
        size = B << t
        tdims = -(-bdims // (1 << t))
        tz, ty, tx = np.meshgrid(*(np.arange(v) for v in tdims[::-1]), indexing="ij")
        org = np.zeros((tx.size, 4), np.int32)
        org[:, 0], org[:, 1], org[:, 2] = tx.ravel() * size, ty.ravel() * size, tz.ravel() * size
        lv = _Level(size, cla.to_device(self.q, org.view(cl.cltypes.int4).ravel()),
                    cla.zeros(self.q, len(org), np.int32), len(org))
        parent = None
        while True:
            self._classify(lv, parent)
            self._run("build_paint_bricks", lv.n, lv.origins.data, lv.out.data, np.int32(lv.n),
                      np.int32(lv.size), self.bd4, self.table.data)
            self._keep(lv, inside=True)
            self._fill(lv, parent)
            if lv.size == B:
                self._run("build_mark_mixed", lv.kept, lv.origins.data, lv.sel.data,
                          np.int32(lv.kept), self.bd4, self.table.data, lv.blk.data)
                return lv
            parent, lv = lv, self._expand(lv)

    def cells(self, bricks):
        """The octants of the mixed bricks, each from its parent's list, down to cells;
        returns the last level (kept: the listed cells, in the order of their lists)."""
        cla, cl = self.cla, self.cl
        self.cells_table = cla.empty(self.q, max(bricks.kept * B3, 1), cl.cltypes.int2)
        parent, lv = bricks, self._expand(bricks)
        while True:
            self._classify(lv, parent)
            self._run("build_paint_cells", lv.n, lv.origins.data, lv.blk.data, lv.out.data,
                      np.int32(lv.n), np.int32(lv.size), self.cells_table.data)
            self._keep(lv, inside=False)
            self._fill(lv, parent)
            if lv.size == 1:
                self._run("build_mark_listed", lv.kept, lv.origins.data, lv.blk.data,
                          lv.sel.data, np.int32(lv.kept), self.cells_table.data)
                return lv
            parent, lv = lv, self._expand(lv)

    def walk(self, lv):
        """The render's lists (cl/cells.h): each listed cell's spheres one by one with their
        keys, sorted on the device. Returns (walk lists, entries buffer, entries)."""
        cla, cl = self.cla, self.cl
        n = lv.kept
        counts = cla.empty(self.q, max(n, 1), cl.cltypes.int2)
        self._run("build_walk_count", n, lv.lists.data, lv.runs, np.int32(n), counts.data)
        if self.host:
            c = counts.get()[:n]
            ends = np.cumsum(c["s0"].astype(np.int64))
            n_entries = int(ends[-1]) if n else 0
            start = ends - c["s0"]
            w = np.zeros(max(n, 1), cl.cltypes.int4)
            w["s0"][:n], w["s1"][:n], w["s2"][:n], w["s3"][:n] = start, c["s0"], start, c["s1"]
            walk = cla.to_device(self.q, w)
        else:
            walk = cla.empty(self.q, max(n, 1), cl.cltypes.int4)
            total = cla.zeros(self.q, 1, np.int64)
            if n:
                self.scans["walk"](counts, np.int32(n), walk, total,
                                   size=self.padded(n, self.device), queue=self.q)
            n_entries = int(total.get()[0])
        if n_entries > self.max_runs:
            raise TooLarge(f"over {self.max_runs} list entries (the list runs' budget)")
        entries = cl.Buffer(self.device.context, cl.mem_flags.READ_WRITE, 8 * max(n_entries, 1))
        self._run("build_walk_fill", n, self.prm[1], self.sp, lv.sel.data, lv.origins.data,
                  lv.out.data, lv.lists.data, lv.runs, walk.data, entries, np.int32(n))
        return walk, entries, n_entries

    def tables(self):
        """The host copy of the brick table (small) and the cell table's rows; the cells
        and lists stay on the device until read (Cells.cells, Cells.lists)."""
        bricks = self.table.get().view(np.int32).reshape(-1, 2)
        assert (bricks[:, 0] != -99).all(), "a brick was left unclassified"
        return bricks, int(np.count_nonzero(bricks[:, 0] >= 0)) * B3

    def kernel_ms(self):
        self.q.finish()
        return 1e-6 * sum(e.profile.end - e.profile.start for e in self.events)


@functools.lru_cache(maxsize=None)
def _scans(context):
    """The build's pyopencl scans and reduction, built once per context: the compaction of
    unclassified boxes (sel), the list offsets (lists, and the total of runs in int64),
    the walk's offsets (walk, the total of entries) and the longest brick list."""
    from pyopencl.reduction import ReductionKernel
    from pyopencl.scan import GenericScanKernel
    keep = GenericScanKernel(
        context, np.int32,
        arguments="__global const int4 *out, __global const int4 *org, int n, int bx, int by, "
                  "int bz, int inside, __global int *sel, __global int *count",
        input_expr=f"(i < n && out[i].x == 0 && (!inside || (org[i].x / {B} < bx && "
                   f"org[i].y / {B} < by && org[i].z / {B} < bz))) ? 1 : 0",
        scan_expr="a + b", neutral="0",
        output_statement="if (prev_item != item) sel[prev_item] = i; "
                         "if (i == n - 1) count[0] = item;")
    lists = GenericScanKernel(
        context, np.int64,
        arguments="__global const int4 *out, __global const int *sel, int n, "
                  "__global int4 *lists, __global long *total",
        input_expr="i < n ? (long)out[sel[i]].y + (long)out[sel[i]].z : 0",
        scan_expr="a + b", neutral="0",
        output_statement="if (i < n) { int4 o = out[sel[i]]; lists[i] = (int4)((int)prev_item, "
                         "o.y, (int)(prev_item + o.y), o.z); } if (i == n - 1) total[0] = item;")
    walk = GenericScanKernel(
        context, np.int64,
        arguments="__global const int2 *counts, int n, __global int4 *walk, "
                  "__global long *total",
        input_expr="i < n ? (long)counts[i].x : 0",
        scan_expr="a + b", neutral="0",
        output_statement="if (i < n) { int2 c = counts[i]; walk[i] = (int4)((int)prev_item, "
                         "c.x, (int)prev_item, c.y); } if (i == n - 1) total[0] = item;")
    longest = ReductionKernel(context, np.int32, neutral="0", reduce_expr="max(a, b)",
                              map_expr="out[sel[i]].y",
                              arguments="__global const int4 *out, __global const int *sel")
    return {"keep": keep, "lists": lists, "walk": walk, "longest": longest}


def _occupancy(c, edge):
    """Sphere centres per occupied box of edge `edge` (c relative to the grid's corner);
    one box per centre when the boxes are too small to count in int64."""
    if len(c) == 0:
        return np.zeros(0, np.int64)
    qf = np.floor(np.ascontiguousarray(np.asarray(c, np.float64).T) / edge)    # (3, n)
    if not np.abs(qf).max() < 2.0 ** 40:
        return np.ones(len(c), np.int64)
    q = qf.astype(np.int64)
    q -= q.min(axis=1, keepdims=True)
    span = q.max(axis=1) + 1
    boxes = float(np.prod(span.astype(np.float64)))
    if boxes >= 2.0 ** 62:
        return np.unique(q.T, axis=0, return_counts=True)[1]
    key = (q[2] * span[1] + q[1]) * span[0] + q[0]
    if boxes <= max(4 * len(c), 1 << 22):          # a count per box: no sort
        counts = np.bincount(key)
        return counts[counts > 0]
    return np.unique(key, return_counts=True)[1]


def estimate_cells(spheres, blend, box_lo, cell, centres=None) -> int:
    """Cells in the bricks the surface passes through at edge `cell`, estimated before
    anything is classified: the bricks holding a sphere centre, with their neighbours
    within the blend and the largest radius (bench/edge.py measures its error). centres:
    float64 sphere centres relative to box_lo, when the caller has them."""
    c = centres if centres is not None else \
        np.asarray(spheres[:, :3], np.float64) - np.asarray(box_lo, np.float64)
    r = float(np.max(spheres[:, 3])) if len(spheres) else 0.0
    edge = B * max(cell, 1e-30)
    grow = 1.0 + 2.0 * (blend + r) / edge                      # neighbours, per axis
    return int(len(_occupancy(c, edge)) * min(grow, 3.0) ** 2 * B3)


def _block_cell(q, block_of, bdims):
    """Index in the cell table of cells q (M, 3) of mixed bricks."""
    b = q // B
    local = q - b * B
    return block_of[_brick_index(b, bdims)] * B3 + (local[:, 2] * B + local[:, 1]) * B + local[:, 0]


def _brick_index(b, bdims):
    return (b[:, 2] * bdims[1] + b[:, 1]) * bdims[0] + b[:, 0]
