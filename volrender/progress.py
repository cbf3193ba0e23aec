"""The progress bar of a render: tqdm (tqdm.auto, so a notebook gets its widget), counting
pixel-samples, with the rows finished as its postfix. Shown only for renders that take
more than half a second, and by default only when stderr is a terminal or in a notebook;
dispatch.run_rows updates it after every launch, i.e. at least every second (its launches
aim at TARGET_S)."""
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
    def __init__(self, total: int, rows: int, label: str = "render", enabled: bool | None = None,
                 delay: float = 0.5):
        self.rows = rows
        self.bar = None
        if not (_interactive() if enabled is None else enabled):
            return
        from tqdm.auto import tqdm
        self.bar = tqdm(total=total, desc=label, unit="sample", unit_scale=True, delay=delay,
                        file=sys.stderr, dynamic_ncols=True, mininterval=0.2, leave=True)

    def update(self, samples: int, rows_done: int):
        if self.bar is not None:
            self.bar.set_postfix_str(f"rows {rows_done}/{self.rows}", refresh=False)
            self.bar.update(samples)

    def close(self):
        if self.bar is not None:
            self.bar.close()
