"""Shared helpers for benchmarks: device description, timing statistics, JSON output."""
from __future__ import annotations

import datetime
import json
import os
import platform
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"     # $VOLRENDER_BENCH_RESULTS instead (tests)
CONVERTED = ROOT / "bench" / "data"          # .npz conversions (git-ignored), e.g. for the GPU


def shared_data() -> Path:
    """The real third-party files: $VOLRENDER_SHARED_DATA, else ../shared/data beside the
    checkout (a user's clone has none; data/README.md there says where they come from)."""
    env = os.environ.get("VOLRENDER_SHARED_DATA")
    return Path(env) if env else ROOT.parent / "shared" / "data"


def find_volume(name: str, need_openvdb=None) -> Path | None:
    """shared_data()/vdb/NAME.vdb, else bench/data/NAME.npz (its `volrender convert`);
    a .vdb only where OpenVDB imports (need_openvdb: a callable saying so)."""
    vdb = shared_data() / "vdb" / f"{name}.vdb"
    if vdb.is_file() and (need_openvdb is None or need_openvdb()):
        return vdb
    npz = CONVERTED / f"{name}.npz"
    return npz if npz.is_file() else None


def missing_data(what: str) -> str:
    """The message for a benchmark whose real input is absent (it exits non-zero)."""
    return (f"{what} not found: put the real files in {shared_data() / 'vdb'} (or set "
            f"VOLRENDER_SHARED_DATA to a folder holding vdb/), or convert them into "
            f"{CONVERTED} with `volrender convert FILE.vdb {CONVERTED}/NAME.npz`")


def git_commit() -> str:
    """The checkout's commit (+ "-dirty" with uncommitted changes), or "unknown";
    $VOLRENDER_COMMIT when set (bench/gpu.sh: the GPU machine gets a copy of the working
    tree whose git metadata is not the checkout's)."""
    if os.environ.get("VOLRENDER_COMMIT"):
        return os.environ["VOLRENDER_COMMIT"]
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True,
                             text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return (sha or "unknown") + ("-dirty" if dirty else "")


def device_info(dev) -> dict:
    """What a result was measured on and with: device, driver, commit, version, argv.
    Timings are warm (each benchmark renders once untimed first, building the program)
    unless a field says cold."""
    import volrender
    d = dev.device
    return {"device": dev.name, "version": d.version.strip(), "driver": d.driver_version.strip(),
            "compute_units": int(d.max_compute_units), "host": platform.node(),
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "commit": git_commit(), "volrender": volrender.__version__, "argv": sys.argv,
            "timing": "warm"}


def result_path(name: str, dev, tag: str | None = None, suffix=".json") -> Path:
    """bench/results/NAME_<device>[-TAG].json ($VOLRENDER_BENCH_RESULTS instead of
    bench/results): --tag adds to the device, never replaces it."""
    folder = Path(os.environ.get("VOLRENDER_BENCH_RESULTS") or RESULTS)
    return folder / f"{name}_{device_tag(dev)}{'-' + tag if tag else ''}{suffix}"


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


def render_points(cloud, camera, lights, settings, device, variant=None) -> dict:
    """A PointCloud rendered through the public path (Scene.of, render): Image.as_dict()."""
    from volrender.render import render
    from volrender.scene import GlassContent, Scene
    scene = Scene.of(camera, lights, GlassContent(cloud, settings))
    return render(scene, device, variant=variant).as_dict()


def render_volume(bricks, camera, lights, settings, device) -> dict:
    """Bricks rendered through the public path (Scene.of, render): Image.as_dict()."""
    from volrender.render import render
    from volrender.scene import Scene, VolumeContent
    return render(Scene.of(camera, lights, VolumeContent(bricks, settings)), device).as_dict()
