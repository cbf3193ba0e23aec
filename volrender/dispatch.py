"""Kernel launches shared by the renderers: uploads, and one-work-item-per-pixel
launches split into row bands (for progress) that each write their own pixels."""
from __future__ import annotations

import numpy as np

from .progress import Progress


def upload(ctx, arr):
    """Read-only device copy of `arr`; an empty array becomes one zero element (OpenCL
    has no zero-size buffers)."""
    import pyopencl as cl
    arr = np.ascontiguousarray(arr)
    if arr.nbytes == 0:
        arr = np.zeros((1,) + arr.shape[1:], arr.dtype)
    return cl.Buffer(ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR, hostbuf=arr)


def row_bands(width: int, height: int, pixels: int):
    """(first row, rows) bands of about `pixels` pixels each."""
    rows = max(1, min(height, pixels // max(1, width)))
    return [(y, min(rows, height - y)) for y in range(0, height, rows)]


def run_rows(device, kernel, args, width, height, pixels, progress=None) -> float:
    """Launch `kernel(*args, y0)` over a width x rows range for each band; returns the
    kernel time in ms (OpenCL profiling events)."""
    import pyopencl as cl
    bands = row_bands(width, height, pixels)
    bar = Progress(len(bands), "render", progress)
    kernel_ns = 0
    try:
        for y0, rows in bands:
            kernel.set_args(*args, np.int32(y0))
            ev = cl.enqueue_nd_range_kernel(device.queue, kernel, (width, rows), None)
            ev.wait()
            kernel_ns += ev.profile.end - ev.profile.start
            bar.update()
    finally:
        bar.close()
    return kernel_ns * 1e-6
