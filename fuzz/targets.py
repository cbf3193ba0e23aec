"""Fuzz targets: one per hand-written parser of what volrender reads.

Each target takes the fuzzer's bytes and checks one property: the parser returns a valid
object or raises UserError with a one-line, printable, non-empty message, within a time
and a memory bound proportional to the input; any other exception, a hang or a blow-up is
a finding. `Finding` is raised for a broken property; every other exception propagates,
so atheris (fuzz/run.py) saves the input as a crash, and the regression tests
(tests/test_fuzz_targets.py) replay saved inputs through the same functions.

    TARGETS[name].run(data)       # -> "ok" or "error"; raises on a finding
"""
from __future__ import annotations

import io
import math
import os
import resource
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

# modules each target's coverage comes from (fuzz/run.py instruments them)
INSTRUMENT = {
    "ply": ["volrender"], "text": ["volrender"], "vdb_header": ["volrender"],
    "npy": ["volrender", "numpy.lib.format"],
    "npz": ["volrender", "zipfile", "numpy.lib.format"], "bricks": ["volrender"],
    "scene": ["volrender", "tomllib"], "camera": ["volrender", "tomllib"],
    "pattern": ["volrender"], "frames": ["volrender"], "las": ["volrender", "laspy"],
}

TIME_BOUND = (2.0, 50e-6)       # seconds: a constant plus this much per input byte
RSS_BOUND = (256 << 20, 2048)   # bytes of peak RSS growth: a constant plus this per byte


class Finding(AssertionError):
    """The property of a target does not hold for an input."""


def _check_message(exc):
    text = str(exc)
    if not text or "\n" in text or not text.isprintable():
        raise Finding(f"UserError message is not one printable line: {text!r}")


_WORK = None


def work_dir() -> Path:
    """A private directory for the targets that read real files (in RAM where possible)."""
    global _WORK
    if _WORK is None:
        import atexit
        import shutil
        base = "/dev/shm" if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK) else None
        root = Path(base or tempfile.gettempdir())
        for old in root.glob("volrender-fuzz-*-*"):     # of runs that died (a finding)
            pid = old.name.split("-")[2]
            if pid.isdigit() and not Path(f"/proc/{pid}").exists():
                shutil.rmtree(old, ignore_errors=True)
        _WORK = Path(tempfile.mkdtemp(prefix=f"volrender-fuzz-{os.getpid()}-", dir=base))
        atexit.register(shutil.rmtree, _WORK, True)
        (_WORK / "cloud.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 1\n"
                                          b"property float x\nproperty float y\n"
                                          b"property float z\nend_header\n0 0 0\n")
        (_WORK / "smoke.vdb").write_bytes(b"")
        (_WORK / "sky.exr").write_bytes(b"")
        (_WORK / "dir").mkdir()
    return _WORK


@dataclass
class Target:
    name: str
    fn: object
    doc: str

    def run(self, data: bytes) -> str:
        """Run the parser on `data`, checking the property; 'ok' or 'error' (UserError)."""
        from volrender.errors import UserError
        rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
        t0 = time.perf_counter()
        try:
            self.fn(data)
            outcome = "ok"
        except UserError as exc:
            _check_message(exc)
            outcome = "error"
        elapsed = time.perf_counter() - t0
        if elapsed > TIME_BOUND[0] + TIME_BOUND[1] * len(data):
            raise Finding(f"{self.name}: {elapsed:.2f} s for {len(data)} bytes")
        grown = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 - rss0
        if grown > RSS_BOUND[0] + RSS_BOUND[1] * len(data):
            raise Finding(f"{self.name}: peak memory grew by {grown >> 20} MiB for "
                          f"{len(data)} bytes")
        return outcome


TARGETS: dict[str, Target] = {}


def target(fn):
    TARGETS[fn.__name__] = Target(fn.__name__, fn, (fn.__doc__ or "").strip())
    return fn


# ----------------------------------------------------------------------------- checks

def _check_cloud(cloud):
    import numpy as np
    from volrender.cloud import MAX_COORDINATE, PointCloud
    if not isinstance(cloud, PointCloud) or len(cloud) < 1:
        raise Finding(f"not a non-empty PointCloud: {cloud!r}")
    c = cloud.centers
    if c.dtype != np.float64 or c.ndim != 2 or c.shape[1] != 3:
        raise Finding(f"centres of dtype {c.dtype}, shape {c.shape}")
    if not np.isfinite(c).all() or np.abs(c).max() > MAX_COORDINATE:
        raise Finding("centres not finite or beyond MAX_COORDINATE")
    if cloud.radii is not None and (not np.isfinite(cloud.radii).all() or cloud.radii.min() < 0):
        raise Finding("radii not finite or negative")
    if cloud.colors is not None and not (np.isfinite(cloud.colors).all()
                                         and cloud.colors.min() >= 0 and cloud.colors.max() <= 1):
        raise Finding("colours outside 0..1")


def _check_bricks(b):
    import numpy as np
    from volrender.bricks import Bricks, check_transform
    from volrender.layout import APRON
    if not isinstance(b, Bricks):
        raise Finding(f"not Bricks: {b!r}")
    n = len(b.data)
    if b.data.dtype != np.float32 or b.data.shape != (n, APRON, APRON, APRON):
        raise Finding(f"data {b.data.dtype} {b.data.shape}")
    if b.table.dtype != np.int32 or b.table.shape != (int(np.prod(b.dims.astype(np.int64))),):
        raise Finding(f"table {b.table.dtype} {b.table.shape} for dims {b.dims}")
    if len(b.table) and (b.table.min() < -1 or b.table.max() >= n):
        raise Finding("table points past the data")
    if not np.isfinite(b.data).all() or (n and b.data.min() < 0):
        raise Finding("voxels not finite or negative")
    if b.majorant.shape != (n,) or (n and np.any(b.majorant < b.data.reshape(n, -1).max(axis=1))):
        raise Finding("majorants below their bricks' values")
    if check_transform(b.index_to_world) is not None:
        raise Finding("a transform check_transform refuses")


# ----------------------------------------------------------------------------- targets

@target
def ply(data):
    """PLY, ASCII and binary of both endians, lists, comments (points.read_points)."""
    from volrender.points import read_points
    _check_cloud(read_points(io.BytesIO(data), ".ply", "<fuzz>.ply"))


@target
def text(data):
    """XYZ/CSV/TXT point rows (points.read_points)."""
    from volrender.points import read_points
    _check_cloud(read_points(io.BytesIO(data), ".xyz", "<fuzz>.xyz"))


@target
def npy(data):
    """.npy point arrays (points.load_points: the header checked against the file's size
    before numpy reads it)."""
    from volrender.points import load_points
    _check_cloud(_in_file(data, "cloud.npy", load_points))


@target
def vdb_header(data):
    """The VDB header, grid descriptors and grid metadata (parse_vdb_header)."""
    from volrender import vdb_header as header
    grids = header.parse_vdb_header(io.BytesIO(data), len(data), "<fuzz>.vdb")
    if grids is None:
        return
    if not isinstance(grids, list) or len(grids) * header._MIN_DESCRIPTOR > len(data):
        raise Finding(f"{len(grids)} grids from {len(data)} bytes")
    for g in grids:
        if not (isinstance(g, header.GridInfo) and isinstance(g.name, str)
                and isinstance(g.value_type, str) and isinstance(g.grid_class, str)
                and isinstance(g.creator, str)
                and all(isinstance(k, str) for k in g.metadata_keys)
                and (g.active_voxels is None or isinstance(g.active_voxels, int))
                and (g.memory_bytes is None or isinstance(g.memory_bytes, int))):
            raise Finding(f"malformed GridInfo {g!r}")
        g.describe()


@target
def npz(data):
    """The .npz brick cache validator (read_npz)."""
    from volrender.bricks import read_npz
    _check_bricks(read_npz(io.BytesIO(data), len(data), "<fuzz>.npz"))


def _dense_from(data):
    """A small dense grid, origin, transform and emission flag from the bytes."""
    import numpy as np
    if len(data) < 6:
        return None
    nx, ny, nz = (1 + data[0] % 10, 1 + data[1] % 10, 1 + data[2] % 10)
    origin = tuple(int.from_bytes(data[3 + i:4 + i], "little", signed=True) * (1 << (data[5] % 28))
                   for i in range(3))
    body = data[6:]
    count = nx * ny * nz
    values = np.frombuffer(body[:4 * count].ljust(4 * count, b"\0"), "<f4").reshape(nx, ny, nz)
    emission = None
    if len(body) > 4 * count:
        emission = np.frombuffer(body[4 * count:8 * count].ljust(4 * count, b"\0"),
                                 "<f4").reshape(nx, ny, nz)
    return values, origin, emission


@target
def bricks(data):
    """The brick builder the VDB reader feeds (Bricks.from_dense, build_bricks): any
    float32 values (NaN, Inf, negative), shapes up to 10^3 and origins up to 2^34; the
    bricks must hold the sanitised values at every voxel."""
    import warnings
    import numpy as np
    from volrender.bricks import Bricks
    got = _dense_from(data)
    if got is None:
        return
    values, origin, emission = got
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        b = Bricks.from_dense(values, origin=origin, emission=emission, chunk=2)
    _check_bricks(b)
    want = np.nan_to_num(values, nan=0.0, posinf=0.0, neginf=0.0).clip(0, None)
    idx = np.argwhere(np.ones(values.shape, bool)).astype(np.float64)
    local = idx + np.asarray(origin, np.float64) - b.origin
    got = b.sample_local(local)
    if not np.array_equal(got.reshape(values.shape).astype(np.float32), want):
        raise Finding("bricks do not hold the grid's values at its voxels")


def _in_file(data, name, fn):
    p = work_dir() / name
    p.write_bytes(data)
    return fn(p)


@target
def las(data):
    """LAS and LAZ point records (points.load_points: the header checked by las.py, then
    laspy, with lazrs decoding LAZ; the compression bit, not the suffix, decides)."""
    from volrender.points import load_points
    _check_cloud(_in_file(data, "cloud.laz", load_points))


@target
def scene(data):
    """Scene TOML files (scene_file.read: tomllib, then the schema: sections, keys, types,
    lights, paths relative to the file)."""
    from volrender import scene_file
    out = _in_file(data, "scene.toml", scene_file.read)
    if not isinstance(out, dict) or not (("points" in out) ^ ("volume" in out)):
        raise Finding(f"scene without exactly one of [points], [volume]: {out!r}")


@target
def camera(data):
    """Camera TOML files (camera.read_camera_file)."""
    from volrender.camera import read_camera_file
    out = _in_file(data, "camera.toml", read_camera_file)
    if not isinstance(out, dict) or not set(out) <= {"origin", "target", "up", "fov", "size"}:
        raise Finding(f"camera file read as {out!r}")


def _text(data) -> str:
    return data.decode("utf-8", "surrogateescape")


@target
def pattern(data):
    """Sequence patterns: ####, %04d, @@@@, $F4, globs (sequence.parse_pattern: volrender
    finds the token and splits the path, fileseq reads its padding; Pattern.path, the glob
    regex): a frame's path holds its number, padded; a glob's regex compiles."""
    import re
    from volrender import sequence, sequence_pattern
    if not data:
        return
    output, text = bool(data[0] & 1), _text(data[1:])
    sequence.is_pattern(text)
    p = sequence.parse_pattern(text, output=output)
    if p.glob:
        if output:
            raise Finding("a glob accepted as an output pattern")
        re.compile(sequence_pattern._glob_regex(Path(p.text).name))
    else:
        for frame in (0, 1, -7, 10 ** 6):
            path = p.path(frame)
            if f"{frame:0{p.width}d}" not in str(path):
                raise Finding(f"path {path} of frame {frame} does not hold its number")


@target
def frames(data):
    """--frames ranges: A-B[:STEP], A-BxSTEP, A-BySTEP, N, comma-separated lists
    (sequence.parse_frames: volrender checks each part and its size, fileseq expands it)."""
    from volrender import sequence
    out = sequence.parse_frames(_text(data))
    if out != sorted(set(out)) or not all(isinstance(f, int) for f in out):
        raise Finding("frames not sorted unique integers")
    if len(out) > sequence.MAX_FRAMES:
        raise Finding(f"{len(out)} frames from {len(data)} bytes")


def names():
    return sorted(TARGETS)


if __name__ == "__main__":
    print("\n".join(f"{t.name:11s} {t.doc.splitlines()[0]}" for t in TARGETS.values()))
    _ = math  # noqa
