"""Kernel launches shared by the renderers: uploads, and the two dispatch variants.

fragment: one independent work-item per pixel, no local memory; volrender launches
          work-groups of tile_w x tile_h pixels (the same blocks as tiled, so the two
          differ only in the culling). The driver's own local size (kind
          `fragment-driver`, kept for the benchmarks, not offered by the CLI) gives 1-D
          groups on the H200 that ran x1.3-1.6 slower for volumes and x1.7 for glass: a
          warp of 8x4 pixels follows more coherent paths than one of 32x1.
tiled:    one work-group per screen tile of tile_w x tile_h pixels; the kernel culls the
          scene against its tile cooperatively into local memory first. The global size is
          rounded up to whole tiles (work-items past the image edge still help the group).
auto:     the default: fragment. Against 8x8 fragment blocks tiled gains nothing
          measurable (H200 1080p: volumes x0.90-1.01, glass x0.85-1.04; PoCL x0.8-1.0);
          the gains measured before (x1.2-1.8) came from the block shape, not the lists.

Both launch in row bands and sample ranges (run_rows): each launch renders samples
s0..s1-1 of a band's pixels and continues the sums the launch before left in the output
buffer, so any split gives the bit-identical image (the RNG is keyed by pixel and sample).
Launch sizes adapt to the measured speed so that each takes about TARGET_S (CPUs) or
GPU_TARGET_S: Ctrl-C and the progress bar (both act between launches) wait no longer
than that. GPUs get whole frames (GPU_BAND_PIXELS) and split only samples, since small
launches leave most of the device idle.

A cheap launch (empty rows above a cloud, < target / CHEAP) says nothing about the rows
below, so it does not grow the next one: CPUs start at one tile row and one sample and
stay there until a launch takes long enough to measure, then grow at most x GROW per
launch from the slowest rate seen so far (docs/benchmarks.md: the launch cadence).
"""
from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field

import numpy as np

from .errors import UserError
from .process import signals_held
from .progress import Eta, Progress
from .render_info import RenderInfo

DISPATCHES = ("fragment", "tiled")
CHOICES = ("auto",) + DISPATCHES
KINDS = CHOICES + ("fragment-driver",)   # fragment with the driver's local size (bench only)
GPU_BAND_PIXELS = 1 << 22      # a 1080p frame is one launch on a GPU
TARGET_S = 0.25                # launch length aimed at on CPUs (PoCL)
GPU_TARGET_S = 0.5             # on GPUs
GROW = 4                       # a launch is at most GROW x the pixel-samples of the last
CHEAP = 16                     # a launch under target / CHEAP does not grow the next


class PastDeadline(Exception):
    """run_rows reached its deadline before the image was done (render.render_passes drops
    that pass)."""


@dataclass
class Stats:
    """What run_rows did: kernel ms (profiling events), launches, and each launch's
    (seconds, rows, samples) and its end in seconds from the first launch's start."""
    kernel_ms: float = 0.0
    kernel_ns: int = 0
    launches: int = 0
    took: list = field(default_factory=list)     # (seconds, rows, samples) per launch
    ends: list = field(default_factory=list)     # seconds from the start to each launch's end
    eta: object = None                           # progress.Eta: the cost per row measured

    @property
    def profile(self):
        """Seconds per sample per row (run_rows' profile= for the next render)."""
        return None if self.eta is None else self.eta.profile


_LAUNCHED: set = set()     # (kernel, local size) launched once in this process


def _enqueue(device, kernel, global_size, local_size):
    """One launch, waited for: (kernel ns from its profiling event, wall seconds). Tests
    replace it to fake a slow kernel. A kernel's first launch at a local size is made
    with signals held: PoCL compiles the work-group function then, and a signal inside
    its compiler breaks it ("1 error generated.") instead of ending the render after it."""
    import pyopencl as cl
    key = (kernel.int_ptr, tuple(local_size) if local_size else None)
    first = key not in _LAUNCHED
    start = time.perf_counter()
    with signals_held() if first else contextlib.nullcontext():
        ev = cl.enqueue_nd_range_kernel(device.queue, kernel, global_size, local_size)
        ev.wait()
    _LAUNCHED.add(key)
    return ev.profile.end - ev.profile.start, time.perf_counter() - start


def enqueue(device, kernel, global_size, local_size):
    """One launch, waited for (as run_rows makes them): (kernel ns, wall seconds).
    progressive.py launches its own sample ranges with it."""
    return _enqueue(device, kernel, global_size, local_size)


@dataclass(frozen=True)
class Launch:
    """How a render is cut into launches (render.render(..., launch=), run_rows). The
    defaults are what renders use; tests and benchmarks pass other values instead of
    changing module constants."""
    first: int | None = None       # pixel-samples of the first launch on CPUs (None: the
                                   # integrator's Plan.band_pixels)
    target_s: float | None = None  # seconds a launch aims at (None: TARGET_S on CPUs,
                                   # GPU_TARGET_S on GPUs)
    fixed: tuple | None = None     # (rows, samples) per launch instead of adapting
    tile_cap: int | None = None    # bricks a volume tile's list holds (tiled dispatch;
                                   # None: features.VOLUME_TILE_CAP)


@dataclass(frozen=True)
class Dispatch:
    """How to launch: `kind` in DISPATCHES and, for tiled, the tile size in pixels."""
    kind: str = "fragment"
    tile: tuple = (8, 8)

    def __post_init__(self):
        if self.kind not in KINDS:
            raise UserError(f"unknown dispatch {self.kind!r}", fix=f"use one of {', '.join(CHOICES)}")
        tw, th = self.tile
        if not (isinstance(tw, (int, np.integer)) and isinstance(th, (int, np.integer))
                and 1 <= tw <= 64 and 1 <= th <= 64 and tw * th <= 1024):
            raise UserError(f"tile {tw}x{th} is out of range",
                            fix="give a tile WxH (--tile, or tile in the scene's [render]) with "
                                "1..64 each and W*H <= 1024")

    @property
    def tiled(self) -> bool:
        return self.kind == "tiled"

    @property
    def driver_local(self) -> bool:
        return self.kind == "fragment-driver"

    def resolve(self, device) -> "Dispatch":
        """`auto` made concrete (fragment on every device; see the module docstring).
        `device` stays in the signature so a future per-device choice needs no caller
        change."""
        if self.kind != "auto":
            return self
        return Dispatch("fragment", self.tile)

    def check(self, device, kernel):
        """Refuse a tile the device cannot run as one work-group."""
        if self.driver_local:
            return
        import pyopencl as cl
        limit = kernel.get_work_group_info(cl.kernel_work_group_info.WORK_GROUP_SIZE, device.device)
        n = self.tile[0] * self.tile[1]
        if n > limit:
            raise UserError(f"tile {self.tile[0]}x{self.tile[1]} ({n} work-items) exceeds this "
                            f"kernel's work-group limit {limit} on {device.name}",
                            fix="give a smaller tile (--tile, or tile in the scene's [render])")

@dataclass
class Plan:
    """What one launch needs. Kernel arguments are `inputs` (uploaded read-only; numpy
    scalars are passed by value), then one buffer per output, then `extra`, then the
    launch's first row and sample range (added by dispatch.run_rows). Inputs and extra are
    (kernel parameter name, value) pairs (tests/test_kernel_args.py checks the names
    against the kernels')."""
    entry: str                       # cl/<entry>.cl and its kernel
    features: object                 # frozen Features with .flags()
    inputs: list
    outputs: list                    # [(name, shape)]: float32 buffers the kernel writes
    dispatch: Dispatch
    band_pixels: int                 # pixel-samples of the first launch on CPUs (dispatch)
    extra: list = field(default_factory=list)
    aovs: tuple = ()                 # layers to return besides rgba
    info: RenderInfo = field(default_factory=RenderInfo)   # the integrator's fields
    build_options: tuple = ()        # compiler options for this device (e.g. register caps)

    @property
    def spp(self) -> int:
        """Samples per pixel: the camera record's (the `cam` input the kernel reads), the one
        carrier of the count; run_rows launches sample ranges up to it and Image.info.spp
        reports it."""
        return int(dict(self.inputs)["cam"]["spp"][0])

    def arg_names(self) -> list:
        """The kernel's parameter names as this plan passes them (outputs by position)."""
        return [n for n, _ in self.inputs] + [None] * len(self.outputs) + \
            [n for n, _ in self.extra] + ["y0", "s0", "s1"]


def parse_tile(text: str) -> tuple:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise UserError(f"--tile takes WxH, got {text!r}", fix="e.g. --tile 8x8") from None
    return w, h


def upload(ctx, arr, queue=None):
    """Read-only device copy of `arr`; an empty array becomes one zero element (OpenCL
    has no zero-size buffers). With `queue`: the copy is enqueued on it (not waited for:
    `arr` must live until the queue is finished), so it runs where that queue's thread
    runs, and not at a later launch on another queue (a driver may defer a COPY_HOST_PTR
    buffer's transfer to its first use)."""
    import pyopencl as cl
    arr = np.ascontiguousarray(arr)
    if arr.nbytes == 0:
        arr = np.zeros((1,) + arr.shape[1:], arr.dtype)
    if queue is None:
        return cl.Buffer(ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR, hostbuf=arr)
    buf = cl.Buffer(ctx, cl.mem_flags.READ_ONLY, arr.nbytes)
    cl.enqueue_copy(queue, buf, arr, is_blocking=False)
    return buf


def is_gpu(device) -> bool:
    import pyopencl as cl
    return bool(device.device.type & cl.device_type.GPU)


def row_bands(width: int, height: int, pixels: int, unit: int = 1):
    """(first row, rows) bands of about `pixels` pixels each; rows a multiple of `unit`
    except possibly the last."""
    rows = max(1, min(height, pixels // max(1, width)))
    rows = max(unit, rows - rows % unit)
    return [(y, min(rows, height - y)) for y in range(0, height, rows)]


def run_rows(device, kernel, args, width, height, pixels, progress=None,
             dispatch: Dispatch | None = None, spp: int = 1, launch: Launch | None = None,
             deadline: float | None = None, profile=None) -> Stats:
    """Launch `kernel(*args, y0, s0, s1)` over the image, band by band and sample range by
    sample range (see the module docstring); returns Stats. `pixels`: pixel-samples of the
    first launch on CPUs (unless launch.first), at most one tile row of one sample; later
    launches grow (at most x GROW, and only after one that was not cheap) or shrink
    towards the target (launch.target_s, else TARGET_S or GPU_TARGET_S) at the slowest
    rate seen; launch.fixed: (rows, samples) per launch. deadline: a time.perf_counter()
    after which no launch starts (PastDeadline is raised instead). The bar's time left
    counts cost (progress.Eta; profile: seconds per sample per row from an earlier render
    of the same scene, Stats.profile)."""
    launch = launch or Launch()
    fixed = launch.fixed
    if launch.first is not None:
        pixels = launch.first
    dispatch = (dispatch or Dispatch()).resolve(device)
    dispatch.check(device, kernel)
    driver = dispatch.driver_local
    tw, th = (1, 1) if driver else dispatch.tile
    spp = max(1, int(spp))
    gpu = is_gpu(device)
    target = launch.target_s or (GPU_TARGET_S if gpu else TARGET_S)
    gpu_rows = row_bands(width, height, GPU_BAND_PIXELS, th)[0][1]
    first = gpu_rows * width if gpu else max(1, min(int(pixels), width * th))
    work = first                                         # pixel-samples of the next launch
    rate = 0.0                                           # slowest seconds per pixel-sample
    bar = Progress(width * height * spp, "render", progress, unit="sample", rows=height, spp=spp,
                   eta=True)
    eta = Eta(height, spp, profile)
    stats = Stats(eta=eta)
    gx = -(-width // tw) * tw
    y0 = 0
    t_start = time.perf_counter()
    try:
        while y0 < height:
            if fixed is not None:
                rows = min(height - y0, max(th, fixed[0] // th * th))
                work = width * rows * fixed[1]
            elif gpu:
                rows = min(height - y0, gpu_rows)
            elif work >= width * spp * th:                   # whole samples, several rows
                rows = min(height - y0, max(th, work // (width * spp) // th * th))
            else:
                rows = min(height - y0, th)
            s0 = 0
            while s0 < spp:
                chunk = max(1, work // (width * rows))
                chunk = -(-(spp - s0) // -(-(spp - s0) // chunk))    # even chunks, no stub
                s1 = min(spp, s0 + chunk)
                if deadline is not None and time.perf_counter() >= deadline:
                    raise PastDeadline()
                kernel.set_args(*args, np.int32(y0), np.int32(s0), np.int32(s1))
                if driver:
                    ns, took = _enqueue(device, kernel, (width, rows), None)
                else:
                    ns, took = _enqueue(device, kernel, (gx, -(-rows // th) * th), (tw, th))
                stats.kernel_ns += ns
                stats.launches += 1
                stats.took.append((took, rows, s1 - s0))
                stats.ends.append(time.perf_counter() - t_start)
                done = width * rows * (s1 - s0)
                if fixed is None:
                    # GPUs always launch the whole frame: every timing is representative
                    work = next_work(done, took, target, rate, None if gpu else first)
                    if gpu or took >= target / CHEAP:
                        rate = max(rate, took / done)
                eta.add(y0, rows, s1 - s0, took)
                bar.set_eta(eta.left())
                bar.update(done, y0 + rows if s1 == spp else y0, s1)
                s0 = s1
            y0 += rows
    finally:
        bar.close()
    stats.kernel_ms = stats.kernel_ns * 1e-6
    return stats


def next_work(done: int, took: float, target: float, rate: float, first) -> int:
    """Pixel-samples of the next launch after one of `done` that took `took` seconds:
    a cheap one (< target / CHEAP) keeps the size (not above `first`; first None: no
    such rule); otherwise the
    target at the slowest rate seen (`rate`, this launch's included), between done / 8
    and done x GROW."""
    if first is not None and took < target / CHEAP:
        return max(1, min(done, first))
    slowest = max(rate, took / max(done, 1))
    return int(max(1, min(max(target / slowest, done / 8), done * GROW)))
