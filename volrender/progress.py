"""Progress bars: tqdm (tqdm.auto, so a notebook gets its widget), shown only for work
that takes more than half a second, and by default only when stderr is a terminal or in
a notebook. A render's bar (dispatch.run_rows) counts pixel-samples, with the rows
finished and the samples of the band under way as its postfix, and is updated after every
launch, i.e. several times a second (launches aim at dispatch.TARGET_S). Its time left
counts cost, not samples (rows of a cloud differ x5 and more: Eta): `ETA ?` until every
row still to render has a measured cost. A sequence's bar counts whole frames (unit
"frame", no k/M scaling)."""
from __future__ import annotations

import sys

import numpy as np

from . import process


class Eta:
    """Seconds left of a render whose rows differ in cost. Each launch (rows y0..y0+rows-1,
    `samples` samples, `seconds`) sets those rows' cost per sample; the time left is the sum
    over the rows still short of `spp` of cost x samples left, or None while a row still
    to render has no cost: measured in this render, or given by `profile` (seconds per
    sample per row, e.g. the pass before's: Eta.profile)."""

    def __init__(self, height: int, spp: int, profile=None):
        self.spp = spp
        self.cost = np.full(height, np.nan) if profile is None else \
            np.array(profile, np.float64).reshape(height)
        self.done = np.zeros(height, np.int64)

    def add(self, y0: int, rows: int, samples: int, seconds: float):
        self.cost[y0:y0 + rows] = seconds / max(rows * samples, 1)
        self.done[y0:y0 + rows] += samples

    def left(self) -> float | None:
        rem = self.spp - self.done
        todo = rem > 0
        if np.isnan(self.cost[todo]).any():
            return None
        return float((self.cost[todo] * rem[todo]).sum())

    @property
    def profile(self) -> np.ndarray:
        return self.cost.copy()


def clock(seconds: float | None) -> str:
    """'ETA 1:05' (h:mm:ss past an hour), or 'ETA ?' when not known."""
    if seconds is None or not np.isfinite(seconds):
        return "ETA ?"
    s = int(round(seconds))
    h, m = divmod(s // 60, 60)
    return f"ETA {h}:{m:02d}:{s % 60:02d}" if h else f"ETA {m}:{s % 60:02d}"


def _interactive() -> bool:
    try:
        if sys.stderr.isatty():
            return True
    except (AttributeError, ValueError):
        return False
    return "ipykernel" in sys.modules


class Progress:
    """Progress(total, label, enabled); update(n) adds n done, and `rows` (when given)
    shows as 'rows R/total_rows', `samples` as 'samples S/spp'. Counts are scaled
    (k, M) only for pixel-samples."""

    def __init__(self, total: int, label: str = "render", enabled: bool | None = None,
                 delay: float = 0.5, *, unit: str = "it", rows: int | None = None,
                 spp: int | None = None, eta: bool = False):
        self.rows, self.spp, self.bar = rows, spp, None
        self.eta = "ETA ?" if eta else None
        if not (_interactive() if enabled is None else enabled):
            return
        from tqdm.auto import tqdm
        # eta: the time left is ours (set_eta: by cost), not tqdm's (by count)
        fmt = "{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}, {rate_fmt}{postfix}]" if eta else None
        self.bar = tqdm(total=max(1, total), desc=label, unit=unit, unit_scale=unit == "sample", delay=delay,
                        file=sys.stderr, dynamic_ncols=True, mininterval=0.2, leave=True,
                        bar_format=fmt)

    def set_eta(self, seconds: float | None):
        """The time left shown by the next update (None: 'ETA ?')."""
        if self.eta is not None:
            self.eta = clock(seconds)

    def update(self, n: int = 1, rows: int | None = None, samples: int | None = None):
        if self.bar is None:
            return
        post = [] if self.eta is None else [self.eta]
        if rows is not None and self.rows:
            post.append(f"rows {rows}/{self.rows}")
        if samples is not None and self.spp:
            post.append(f"samples {samples}/{self.spp}")
        if post:
            self.bar.set_postfix_str(", ".join(post), refresh=False)
        self.bar.update(n)

    def close(self):
        if self.bar is not None:
            self.bar.close()


def say(text: str, enabled: bool | None = None):
    """One status line on stderr ('volrender: ...') where a bar would be shown: for work
    that has no bar (the glass acceleration's build)."""
    if _interactive() if enabled is None else enabled:
        process.say(f"volrender: {text}")
