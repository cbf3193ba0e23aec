"""Progress bars: tqdm (tqdm.auto, so a notebook gets its widget), shown only for work
that takes more than half a second, and by default only when stderr is a terminal or in
a notebook. A render's bar (dispatch.run_rows) counts pixel-samples, with the rows
finished and the samples of the band under way as its postfix, and is updated after every
launch, i.e. several times a second (launches aim at dispatch.TARGET_S). A sequence's bar
counts whole frames (unit "frame", no k/M scaling)."""
from __future__ import annotations

import sys


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
                 spp: int | None = None):
        self.rows, self.spp, self.bar = rows, spp, None
        if not (_interactive() if enabled is None else enabled):
            return
        from tqdm.auto import tqdm
        self.bar = tqdm(total=max(1, total), desc=label, unit=unit, unit_scale=unit == "sample", delay=delay,
                        file=sys.stderr, dynamic_ncols=True, mininterval=0.2, leave=True)

    def update(self, n: int = 1, rows: int | None = None, samples: int | None = None):
        if self.bar is None:
            return
        post = []
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
        print(f"volrender: {text}", file=sys.stderr, flush=True)
