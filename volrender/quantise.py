"""8-bit codes of float32 images through a table on their bit patterns: fast, and equal to
the float64 definition for every float32 value (volrender/image.py, `to_srgb`).

A view transform that acts on each value alone, followed by rounding to 8 bits, is a
non-decreasing step function `code(v)`; so is the rounding of OpenColorIO's output. Its
255 thresholds (the smallest float32 whose code is at least c) are found by bisection
over the bit patterns, whose order is that of the non-negative float32 values, calling
the definition itself. A value's code is then the number of thresholds at or below it:
read from a table indexed by the top 19 bits of its pattern (sign, exponent and 10
mantissa bits: each bin spans a relative width of 2^-10), plus one compare where a
threshold falls inside its bin. No bin holds two thresholds for the curves used (checked
when the table is made; where one would, `table` returns None and the caller computes
the definition). Negative values, -Inf and NaN get 0, +Inf the code of the largest value.
The table is 2.5 MB; a 1080p frame is coded in row blocks, on a few threads.
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

SHIFT = 13                          # a bin: the patterns sharing their top 32 - SHIFT bits
INF = 0x7F800000                    # +Inf's pattern: the last non-NaN positive one
_NEVER = 0xFFFFFFFF                 # the cut of a bin no threshold splits
_BLOCK = 1 << 16                    # values a thread codes at a time
_POOL = []


def thresholds(code_of, top: int = 255) -> np.ndarray:
    """(top,) uint32: for c = 1..top the smallest pattern p in 0..INF (a non-negative
    float32 or +Inf) with code_of(p as float32) >= c, or _NEVER where none has. `code_of`
    maps a float32 array to integer codes and must not decrease with the value."""
    c = np.arange(1, top + 1)
    lo = np.full(top, -1, np.int64)               # code(lo) < c (lo = -1: below every value)
    hi = np.full(top, INF, np.int64)              # code(hi) >= c, when any value's is
    reached = np.asarray(code_of(hi.astype(np.uint32).view(np.float32))) >= c
    while np.any(hi - lo > 1):
        mid = (lo + hi) // 2
        ok = np.asarray(code_of(mid.astype(np.uint32).view(np.float32))) >= c
        hi, lo = np.where(ok, mid, hi), np.where(ok, lo, mid)
    return np.where(reached, hi, _NEVER).astype(np.uint32)


def table(cuts: np.ndarray):
    """(codes, cut) of thresholds `cuts`: per bin, the code of its first pattern (uint8) and
    the pattern from which the code is one more (uint32; _NEVER where it stays). None when a
    bin holds two thresholds or more."""
    n = 1 << (32 - SHIFT)
    first = np.arange(INF >> SHIFT, dtype=np.int64) << SHIFT    # the bins below +Inf's
    lo = np.searchsorted(cuts, first, side='right')
    hi = np.searchsorted(cuts, first + (1 << SHIFT) - 1, side='right')
    if np.any(hi - lo > 1):
        return None
    codes = np.zeros(n, np.uint8)
    codes[:len(first)] = lo
    codes[INF >> SHIFT] = np.searchsorted(cuts, INF, side='right')   # +Inf (and NaNs: fixed)
    cut = np.full(n, _NEVER, np.uint32)
    split = np.nonzero(hi > lo)[0]
    cut[split] = cuts[lo[split]]
    return codes, cut


def _pool():
    """The threads (made once per process: a forked child gets its own)."""
    if _POOL and _POOL[0][0] != os.getpid():
        _POOL.clear()
    if not _POOL:
        try:
            n = len(os.sched_getaffinity(0))
        except AttributeError:
            n = os.cpu_count() or 1
        from .process import hold_in_this_thread
        _POOL.append((os.getpid(), ThreadPoolExecutor(
            max(1, min(4, n)), thread_name_prefix="volrender-codes", initializer=hold_in_this_thread)))
    return _POOL[0][1]


def in_blocks(run, rows: int, per_row: int) -> None:
    """run(r0, r1) over rows 0..rows in blocks of about _BLOCK values, on the pool's threads
    (numpy and OpenColorIO let go of the GIL while they work)."""
    step = max(1, _BLOCK // max(1, per_row))
    spans = [(r, min(r + step, rows)) for r in range(0, rows, step)]
    if len(spans) == 1:
        run(*spans[0])
        return
    for f in [_pool().submit(run, *s) for s in spans]:
        f.result()


def apply(x: np.ndarray, codes: np.ndarray, cut: np.ndarray, out: np.ndarray | None = None,
          nan: bool = True):
    """uint8 codes of float32 `x` (any shape and strides) through a `table`, written into
    `out` (same shape; a new array when None); NaN gets 0 (nan=False: `x` has none, and
    is not searched for them)."""
    x = np.asarray(x)
    if x.dtype != np.float32:
        raise TypeError(f"quantise.apply needs float32 values, got {x.dtype}")
    shape = x.shape
    x = x.reshape(1) if x.ndim == 0 else x
    res = np.empty(x.shape, np.uint8) if out is None else out.reshape(x.shape)
    bits = x.view(np.uint32)

    def run(r0, r1):
        b = bits[r0:r1]
        i = b >> SHIFT
        c = codes.take(i)
        c += b >= cut.take(i)
        res[r0:r1] = c

    in_blocks(run, len(x), x[0].size)
    if nan:
        res[np.isnan(x)] = 0
    return res.reshape(shape) if out is None else out
