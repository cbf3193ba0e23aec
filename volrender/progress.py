"""Progress bars: tqdm (tqdm.auto, so a notebook gets its widget), shown only for work
that takes more than half a second, and by default only when stderr is a terminal or in
a notebook. A render's bar (dispatch.run_rows) counts pixel-samples, with the rows
finished as its postfix, and is updated after every launch, i.e. at least every second
(launches aim at dispatch.TARGET_S)."""
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
    shows as 'rows R/total_rows'."""

    def __init__(self, total: int, label: str = "render", enabled: bool | None = None,
                 delay: float = 0.5, *, unit: str = "it", rows: int | None = None):
        self.rows, self.bar = rows, None
        if not (_interactive() if enabled is None else enabled):
            return
        from tqdm.auto import tqdm
        self.bar = tqdm(total=max(1, total), desc=label, unit=unit, unit_scale=True, delay=delay,
                        file=sys.stderr, dynamic_ncols=True, mininterval=0.2, leave=True)

    def update(self, n: int = 1, rows: int | None = None):
        if self.bar is None:
            return
        if rows is not None and self.rows:
            self.bar.set_postfix_str(f"rows {rows}/{self.rows}", refresh=False)
        self.bar.update(n)

    def close(self):
        if self.bar is not None:
            self.bar.close()
