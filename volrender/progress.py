"""A small progress bar on stderr, shown only for renders that take more than a moment."""
from __future__ import annotations

import sys
import time


class Progress:
    def __init__(self, total: int, label: str = "render", enabled: bool | None = None,
                 delay: float = 0.5, stream=None):
        self.total, self.label, self.done = max(1, total), label, 0
        self.stream = stream or sys.stderr
        self.enabled = self.stream.isatty() if enabled is None else enabled
        self.delay, self.start, self.shown = delay, time.perf_counter(), False

    def update(self, n: int = 1):
        self.done = min(self.total, self.done + n)
        elapsed = time.perf_counter() - self.start
        if not self.enabled or (elapsed < self.delay and not self.shown):
            return
        self.shown = True
        frac = self.done / self.total
        eta = elapsed * (1 - frac) / frac if frac > 0 else 0.0
        bar = "#" * int(30 * frac)
        self.stream.write(f"\r{self.label} {100 * frac:5.1f}% [{bar:<30}] "
                          f"{elapsed:6.1f} s, eta {eta:5.1f} s")
        self.stream.flush()

    def close(self):
        if self.shown:
            self.stream.write("\n")
            self.stream.flush()
