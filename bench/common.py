"""Shared helpers for benchmarks: device description, timing statistics, JSON output."""
from __future__ import annotations

import datetime
import json
import platform
import statistics
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def device_info(dev) -> dict:
    d = dev.device
    return {"device": dev.name, "version": d.version.strip(), "driver": d.driver_version.strip(),
            "compute_units": int(d.max_compute_units), "host": platform.node(),
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}


def stats(values) -> dict:
    values = sorted(values)
    return {"median": statistics.median(values), "min": values[0], "max": values[-1],
            "runs": values}


def write_json(path: Path, payload: dict) -> Path:
    """Write results atomically (volrender.atomic: an interrupted benchmark leaves the
    previous results whole and no temporary file)."""
    from volrender import atomic
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic.write_bytes(path, json.dumps(payload, indent=1).encode(), "results")
    return path


def device_tag(dev) -> str:
    name = dev.device.name.lower()
    return "gpu-" + "".join(c for c in name if c.isalnum())[:16] if "nvidia" in dev.name.lower() \
        else "pocl"
