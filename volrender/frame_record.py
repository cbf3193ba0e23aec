"""One frame of a sequence as it went (SequenceResult.records, the rows of the JSON record):
a typed record with a status enum. On disk it is the JSON object it always was
(`to_json`: the fields that are set, the status as its string); `rec["status"]` and
`rec.get(...)`, from when records were dicts, still work and warn (DeprecationWarning,
dict_reads.py).
"""
from __future__ import annotations

import dataclasses
import enum
from dataclasses import dataclass

from .dict_reads import DictReads


class FrameStatus(str, enum.Enum):
    """How a frame ended; compares equal to its string ("ok" == FrameStatus.OK)."""
    OK = "ok"                       # rendered and written (or found written as a run stopped)
    SKIPPED = "skipped"             # --skip-existing found it written
    FAILED = "failed"               # its error is in `error`; the other frames went on
    INTERRUPTED = "interrupted"     # the run stopped before it was written

    def __str__(self) -> str:
        return self.value


@dataclass
class FrameRecord(DictReads):
    frame: int
    input: str
    output: str
    worker: str | None = None               # the worker that rendered it
    pid: int | None = None
    redone: str | None = None               # --skip-existing: why the file there was redone
    status: FrameStatus | None = None
    error: str | None = None                # failed: the one-line reason
    device: str | None = None               # ok: the render's device and where time went
    load_s: float | None = None
    build_s: float | None = None
    setup_s: float | None = None
    kernel_s: float | None = None
    render_s: float | None = None
    write_s: float | None = None
    seconds: float | None = None            # the frame's whole time
    from_earlier_run: bool | None = None    # a resumed run's row kept from the run before

    def __post_init__(self):
        if self.status is not None:
            self.status = FrameStatus(self.status)

    def set(self, **fields) -> "FrameRecord":
        """Set fields by name (an unknown name raises TypeError); returns the record."""
        for k, v in fields.items():
            if k not in FIELDS:
                raise TypeError(f"FrameRecord has no field {k!r}")
            setattr(self, k, FrameStatus(v) if k == "status" and v is not None else v)
        return self

    def to_json(self) -> dict:
        """The record's row on disk: the fields that are set, in this order."""
        out = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if v is not None:
                out[f.name] = v.value if isinstance(v, FrameStatus) else v
        return out

    @classmethod
    def from_json(cls, row: dict) -> "FrameRecord":
        """A row of a record on disk (unknown keys are left out)."""
        return cls(**{k: v for k, v in row.items() if k in FIELDS})


FIELDS = frozenset(f.name for f in dataclasses.fields(FrameRecord))
