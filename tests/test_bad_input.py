"""Bad input, nothing lost: the real CLI on broken files, absurd sizes and a broken
OpenCL set-up. Each case must give one line on stderr naming the problem and the fix,
exit status 2, no traceback, no output file, and leave an existing output file
byte-identical.

The same table writes docs/bad_input.md from real runs:

    .venv/bin/python tests/test_bad_input.py      # rewrites docs/bad_input.md and README's table
"""
from __future__ import annotations

import contextlib
import tempfile
import io
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from unittest import mock

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "scenes" / "demo_cloud.vdb"
SMALL = ["--size", "16x12", "--no-progress"]
PRECIOUS = b"an earlier render, not to be touched\n"


# ------------------------------------------------------------------ inputs

def _png_bytes():
    """A real 4x3 PNG (volrender's own writer)."""
    from volrender.image import write_image
    import tempfile
    with tempfile.TemporaryDirectory() as d:
        write_image(Path(d) / "p.png", np.ones((3, 4, 4), np.float32))
        return (Path(d) / "p.png").read_bytes()


def _vector_grid(path):
    from volrender.vdb import import_openvdb
    vdb = import_openvdb()
    g = vdb.Vec3SGrid()
    g.copyFromArray(np.ones((4, 4, 4, 3), np.float32))
    g.name = "velocity"
    vdb.write(str(path), grids=[g])


def _ply_header(n, fmt="ascii"):
    return (f"ply\nformat {fmt} 1.0\nelement vertex {n}\nproperty float x\nproperty float y\n"
            "property float z\nend_header\n")


def _binary_ply(path):
    rows = np.arange(30, dtype="<f4").reshape(10, 3)
    data = _ply_header(10, "binary_little_endian").encode() + rows.tobytes()
    path.write_bytes(data[:-17])                       # cut inside the 9th vertex


def _broken_cl_dir(tmp):
    """A copy of cl/ whose render_volume.cl does not compile."""
    from volrender.paths import cl_dir
    d = tmp / "broken_cl"
    if d.is_dir():                         # cl_dir() is asked for more than once per build
        return d
    shutil.copytree(cl_dir(), d)
    src = (d / "render_volume.cl").read_text()
    (d / "render_volume.cl").write_text(src + "\nthis is not OpenCL C;\n")
    return d


def _cl_error(kind, routine, status):
    import pyopencl as cl
    code = getattr(cl.status_code, status)
    return getattr(cl, kind)(cl._cl._ErrorRecord(routine, code, ""))


def _raiser(exc):
    def f(*args, **kwargs):
        raise exc
    return f


def _forbidden(what):
    def f(*args, **kwargs):
        raise AssertionError(f"{what} was called: the size check must come first")
    return f


# ------------------------------------------------------------------ the cases

@dataclass
class Case:
    id: str
    label: str                       # the 'input' column of docs/bad_input.md
    argv: list                       # run in the case's directory; {out} is the output
    words: tuple                     # must appear in the message (case-insensitive)
    files: dict = field(default_factory=dict)   # name -> bytes, str or callable(path)
    patches: object = None           # callable(tmp) -> list of context managers
    out: str = "o.png"


def _no_platform(tmp):
    import pyopencl
    return [mock.patch.object(pyopencl, "get_platforms",
                              _raiser(_cl_error("LogicError", "clGetPlatformIDs",
                                                "PLATFORM_NOT_FOUND_KHR")))]


def _no_device(tmp):
    import pyopencl
    return [mock.patch.object(pyopencl, "get_platforms", lambda: [])]


def _fresh_devices():
    from volrender import device
    return mock.patch.dict(device._DEVICES, clear=True)   # build again, in a new context


def _build_failure(tmp):
    from volrender import device
    from volrender.paths import cl_dir
    broken = _broken_cl_dir(tmp)
    assert cl_dir() != broken
    return [_fresh_devices(), mock.patch.object(device, "cl_dir", lambda: broken)]


def _buffer_oom(tmp):
    import pyopencl
    return [mock.patch.object(pyopencl, "Buffer", _raiser(
        _cl_error("MemoryError", "clCreateBuffer", "MEM_OBJECT_ALLOCATION_FAILURE")))]


def _launch_oom(tmp):
    import pyopencl
    return [mock.patch.object(pyopencl, "enqueue_nd_range_kernel", _raiser(
        _cl_error("RuntimeError", "clEnqueueNDRangeKernel", "OUT_OF_RESOURCES")))]


def _launch_fails(tmp):
    import pyopencl
    return [mock.patch.object(pyopencl, "enqueue_nd_range_kernel", _raiser(
        _cl_error("LogicError", "clEnqueueNDRangeKernel", "INVALID_COMMAND_QUEUE")))]


def _buffer_too_big(tmp):
    import pyopencl
    return [mock.patch.object(pyopencl, "Buffer", _raiser(
        _cl_error("LogicError", "clCreateBuffer", "INVALID_BUFFER_SIZE")))]


def _host_oom(tmp):
    from volrender import vdb
    return [mock.patch.object(vdb, "load_volume", _raiser(MemoryError()))]


def _nothing_allocated(tmp):
    import pyopencl
    from volrender import vdb
    return [mock.patch.object(pyopencl, "Buffer", _forbidden("pyopencl.Buffer")),
            mock.patch.object(vdb, "load_volume", _forbidden("vdb.load_volume"))]


TOML_OK = '[points]\ngenerator = "blob"\ncount = 50\n'


def _npy_cloud(path):
    np.save(path, np.random.default_rng(2).random((40, 3)))


def _link(target):
    def make(path):
        path.symlink_to(target)
    return make


def _hard_link(target):
    def make(path):
        os.link(path.parent / target, path)
    return make


def _fifo(path):
    os.mkfifo(path)


def _env_exr(path):
    from volrender.image import write_image
    write_image(path, np.full((4, 8, 4), 0.5, np.float32))


def vdb_header(grids, count=None, backwards=False):
    """A .vdb holding only grid descriptors (each grid's data: compression flags and an
    empty metadata map). `backwards`: every descriptor's offsets point into the header,
    before the descriptor (a parser that follows them reads the same bytes forever)."""
    import struct
    def string(b):
        return struct.pack("<I", len(b)) + b
    head = struct.pack("<qIII", 0x56444220, 224, 10, 0) + b"\x01" + b"0" * 36 + struct.pack("<I", 0)
    out = head + struct.pack("<i", len(grids) if count is None else count)
    for name in grids:
        desc = string(name) + string(b"Tree_float_5_4_3") + string(b"")
        start = len(out)
        if backwards:
            out += desc + struct.pack("<qqq", 17, 17, start)        # into the UUID's bytes
        else:
            g = start + len(desc) + 24
            out += desc + struct.pack("<qqq", g, g + 8, g + 8) + struct.pack("<II", 0, 0)
    return out


def _ply_lists(kind):
    head = "ply\nformat {fmt} 1.0\nelement vertex 2\n{props}end_header\n"
    if kind == "list_x":
        return (head.format(fmt="ascii", props="property list uchar float x\nproperty float y\n"
                            "property float z\n") + "1 0 0 0\n1 1 1 1\n").encode()
    if kind == "nan_count":
        return (head.format(fmt="ascii", props="property float x\nproperty float y\nproperty float z\n"
                            "property list uchar float w\n") + "0 0 0 nan\n1 1 1 0\n").encode()
    import struct                                         # binary, a count of -1 (signed char)
    body = struct.pack("<fffb", 0, 0, 0, -1) + struct.pack("<fffb", 1, 1, 1, 0)
    return head.format(fmt="binary_little_endian", props="property float x\nproperty float y\n"
                       "property float z\nproperty list char float w\n").encode() + body


def _bricks_npz(kind):
    def make(path):
        from volrender.bricks import Bricks
        b = Bricks.from_dense(np.ones((9, 9, 9), np.float32))
        b.save_npz(path)
        z = dict(np.load(path))
        if kind == "dims":
            z["dims"] = np.array([1 << 30, 1 << 30, 1 << 30], np.int64)
        elif kind == "majorant":
            z["majorant"] = -np.abs(z["majorant"])
        elif kind == "singular":
            z["index_to_world"] = np.diag([1.0, 1.0, 1e-9, 1.0])
        elif kind == "long":                  # valid, but 8 M voxels long
            z["dims"] = np.array([1 << 20, 1, 1], np.int32)
            z["table"] = np.full(1 << 20, -1, np.int32)
            z["table"][0] = 0
            z["data"], z["majorant"] = z["data"][:1], z["majorant"][:1]
        np.savez(path, **z)
    return make


def _lying_npy(path):
    """A .npy whose header claims 10^12 points; the file holds 3."""
    with open(path, "wb") as f:
        np.lib.format.write_array_header_1_0(
            f, {"descr": "<f8", "fortran_order": False, "shape": (10 ** 12, 3)})
        f.write(np.zeros((3, 3)).tobytes())


def _unreadable(name):
    """What mode 000 gives a user that is not root (root reads anything): os.access
    says no for that file."""
    def patches(tmp):
        real = os.access

        def access(path, mode, *a, **kw):
            if Path(path).name == name and mode & os.R_OK:
                return False
            return real(path, mode, *a, **kw)
        return [mock.patch.object(os, "access", access)]
    return patches


def _read_only_output(tmp):
    real = os.access

    def access(path, mode, *a, **kw):
        if Path(path).name == "o.png" and mode & os.W_OK:
            return False
        return real(path, mode, *a, **kw)
    return [mock.patch.object(os, "access", access)]


def _full_disk(tmp):
    from volrender import atomic
    real = os.fdopen

    def full(fd, mode="r", *a, **kw):
        os.close(fd)
        return real(os.open("/dev/full", os.O_WRONLY), mode, *a, **kw)
    return [mock.patch.object(atomic.os, "fdopen", full)]

CASES = [
    Case("missing", "missing file", ["render", "nope.vdb", "-o", "{out}"], ("nope.vdb", "no such file")),
    Case("random_vdb", "corrupt VDB (4 KiB of random bytes)", ["render", "random.vdb", "-o", "{out}"],
         ("random.vdb", "not an OpenVDB file"),
         files={"random.vdb": np.random.default_rng(1).bytes(4096)}),
    Case("cut_vdb", "truncated VDB (first half of demo_cloud.vdb)", ["render", "cut.vdb", "-o", "{out}"],
         ("cut.vdb", "truncated"),
         files={"cut.vdb": lambda p: p.write_bytes(DEMO.read_bytes()[:DEMO.stat().st_size // 2])}),
    Case("cut_vdb_head", "truncated VDB (first 100 bytes)", ["render", "head.vdb", "-o", "{out}"],
         ("head.vdb", "truncated"),
         files={"head.vdb": lambda p: p.write_bytes(DEMO.read_bytes()[:100])}),
    Case("png_as_vdb", "foreign file (a PNG renamed .vdb)", ["render", "picture.vdb", "-o", "{out}"],
         ("picture.vdb", "not an OpenVDB file"), files={"picture.vdb": lambda p: p.write_bytes(_png_bytes())}),
    Case("grid_name", "wrong grid name (`--grid smoke`)",
         ["render", "demo.vdb", "-o", "{out}", "--grid", "smoke"], ("smoke", "density"),
         files={"demo.vdb": lambda p: shutil.copy(DEMO, p)}),
    Case("vector_grid", "wrong grid type (a vec3s grid)",
         ["render", "velocity.vdb", "-o", "{out}", "--grid", "velocity"], ("velocity", "vec3s"),
         files={"velocity.vdb": _vector_grid}),
    Case("vector_grid_default", "no density grid (only a vec3s grid, no `--grid`)",
         ["render", "velocity.vdb", "-o", "{out}"], ("velocity.vdb", "velocity"),
         files={"velocity.vdb": _vector_grid}),
    Case("ply_count", "PLY whose header says 10 vertices, holding 3",
         ["render", "lies.ply", "-o", "{out}"], ("lies.ply", "10 vertices"),
         files={"lies.ply": _ply_header(10) + "0 0 0\n1 0 0\n0 1 0\n"}),
    Case("ply_binary", "binary PLY cut inside its vertex data",
         ["render", "cut.ply", "-o", "{out}"], ("cut.ply", "truncated binary PLY"),
         files={"cut.ply": _binary_ply}),
    Case("csv_text", "CSV with a non-numeric value", ["render", "points.csv", "-o", "{out}"],
         ("points.csv", "line 3"), files={"points.csv": "x,y,z\n0,0,0\n1,two,0\n"}),
    Case("xyz_binary", "XYZ that is binary garbage", ["render", "points.xyz", "-o", "{out}"],
         ("points.xyz",), files={"points.xyz": bytes(range(256)) * 4}),
    Case("toml_syntax", "TOML syntax error", ["render", "scene.toml", "-o", "{out}"],
         ("scene.toml", "TOML"), files={"scene.toml": "[points\ngenerator = 'blob'\n"}),
    Case("toml_key", "TOML unknown key (`[material] iro = 1.5`)", ["render", "scene.toml", "-o", "{out}"],
         ("scene.toml", "[material].iro", "ior"), files={"scene.toml": TOML_OK + "[material]\niro = 1.5\n"}),
    Case("toml_type", "TOML wrong type (`count = \"many\"`)", ["render", "scene.toml", "-o", "{out}"],
         ("scene.toml", "[points].count", "integer"),
         files={"scene.toml": '[points]\ngenerator = "blob"\ncount = "many"\n'}),
    Case("toml_count", "TOML absurd point count (`count = 100000000000`)",
         ["render", "scene.toml", "-o", "{out}"], ("[points].count", "5e7"),
         files={"scene.toml": '[points]\ngenerator = "blob"\ncount = 100000000000\n'}),
    Case("toml_path", "TOML path that names a directory (`file = \".\"`)",
         ["render", "scene.toml", "-o", "{out}"], ("[points].file", "directory"),
         files={"scene.toml": '[points]\nfile = "."\n'}),
    Case("toml_size", "TOML size of booleans (`size = [true, true]`)",
         ["render", "scene.toml", "-o", "{out}"], ("[render].size", "integers"),
         files={"scene.toml": TOML_OK + "[render]\nsize = [true, true]\n"}),
    Case("size_zero", "`--size 0x0`", ["render", "blob:50", "-o", "{out}", "--size", "0x0"],
         ("--size", "0x0")),
    Case("size_huge", "`--size 1000000x1000000`",
         ["render", "blob:50", "-o", "{out}", "--size", "1000000x1000000"], ("--size", "32768")),
    Case("size_memory", "`--size 32768x32768` (within the per-side limit, too big for the device)",
         ["render", "demo.vdb", "-o", "{out}", "--size", "32768x32768"], ("32768x32768", "smaller size (--size"),
         files={"demo.vdb": lambda p: shutil.copy(DEMO, p)}, patches=_nothing_allocated),
    Case("no_platform", "no OpenCL platform (`clGetPlatformIDs` fails)",
         ["render", "blob:50", "-o", "{out}"], ("OpenCL", "PoCL"), patches=_no_platform),
    Case("no_device", "no OpenCL device (no platforms listed)",
         ["render", "demo.vdb", "-o", "{out}"], ("no OpenCL device", "PoCL"),
         files={"demo.vdb": lambda p: shutil.copy(DEMO, p)}, patches=_no_device),
    Case("build", "kernel build failure (a broken cl/render_volume.cl, the march's kernel)",
         ["render", "demo.vdb", "-o", "{out}", "--estimator", "march"],
         ("build", "render_volume.cl", "--debug"),
         files={"demo.vdb": lambda p: shutil.copy(DEMO, p)}, patches=_build_failure),
    Case("oom_buffer", "device out of memory (`clCreateBuffer`: MEM_OBJECT_ALLOCATION_FAILURE)",
         ["render", "demo.vdb", "-o", "{out}"], ("out of memory", "--size"),
         files={"demo.vdb": lambda p: shutil.copy(DEMO, p)}, patches=_buffer_oom),
    Case("oom_launch", "device out of resources at launch (glass, OUT_OF_RESOURCES)",
         ["render", "blob:50", "-o", "{out}"], ("out of memory", "fewer points"), patches=_launch_oom),
    Case("buffer_size", "buffer larger than the device allows (INVALID_BUFFER_SIZE)",
         ["render", "blob:50", "-o", "{out}"], ("out of memory", "--size"), patches=_buffer_too_big),
    Case("cl_other", "any other OpenCL failure (INVALID_COMMAND_QUEUE at launch)",
         ["render", "demo.vdb", "-o", "{out}"], ("OpenCL failed", "INVALID_COMMAND_QUEUE", "--device"),
         files={"demo.vdb": lambda p: shutil.copy(DEMO, p)}, patches=_launch_fails),
    Case("host_oom", "host out of memory while loading", ["render", "demo.vdb", "-o", "{out}"],
         ("demo.vdb", "out of host memory", "smaller"),
         files={"demo.vdb": lambda p: shutil.copy(DEMO, p)}, patches=_host_oom),
    # 1. data loss: the output is one of the inputs
    Case("out_is_input", "output is the input", ["render", "cloud.npy", "-o", "cloud.npy"],
         ("cloud.npy", "same file as the input"), files={"cloud.npy": _npy_cloud}, out="cloud.npy"),
    Case("out_is_env", "output is the environment map",
         ["render", "blob:50", "--env", "sky.exr", "-o", "sky.exr"], ("sky.exr", "same file"),
         files={"sky.exr": _env_exr}, out="sky.exr"),
    Case("out_is_scene_file", "output is a file the scene reads (`[points] file`)",
         ["render", "scene.toml", "-o", "pts.npy"], ("pts.npy", "same file"),
         files={"pts.npy": _npy_cloud, "scene.toml": '[points]\nfile = "pts.npy"\n'}, out="pts.npy"),
    Case("out_is_hard_link", "output is a hard link of the input",
         ["render", "cloud.npy", "-o", "again.npy"], ("again.npy", "same file"),
         files={"cloud.npy": _npy_cloud, "again.npy": _hard_link("cloud.npy")}, out="again.npy"),
    Case("convert_onto_input", "`convert` onto its input through a symlink",
         ["convert", "demo.vdb", "link.npz"], ("link.npz", "same file"),
         files={"demo.vdb": lambda p: shutil.copy(DEMO, p), "link.npz": _link("demo.vdb")},
         out="demo.vdb"),
    # 2. hangs
    Case("step_tiny", "`--step 1e-9`", ["render", "demo.vdb", "-o", "{out}", "--step", "1e-9"],
         ("--step", "0.01"), files={"demo.vdb": lambda p: shutil.copy(DEMO, p)}),
    Case("step_samples", "a step that gives a ray more than 2^24 samples (a cache 8 M voxels long)",
         ["render", "long.npz", "-o", "{out}", "--step", "0.1"], ("16777216", "step"),
         files={"long.npz": _bricks_npz("long")}),
    Case("fifo_vdb", "a FIFO named .vdb", ["render", "pipe.vdb", "-o", "{out}"],
         ("pipe.vdb", "FIFO"), files={"pipe.vdb": _fifo}),
    Case("fifo_toml", "a FIFO named .toml", ["render", "pipe.toml", "-o", "{out}"],
         ("pipe.toml", "FIFO"), files={"pipe.toml": _fifo}),
    Case("fifo_env", "a FIFO as `--env`", ["render", "blob:50", "--env", "pipe.exr", "-o", "{out}"],
         ("pipe.exr", "FIFO", "--env"), files={"pipe.exr": _fifo}),
    Case("vdb_backwards", "crafted VDB whose grid descriptors point backwards (`info`)",
         ["info", "loop.vdb"], ("loop.vdb", "out of order"),
         files={"loop.vdb": vdb_header([b"density", b"density"], backwards=True)}),
    Case("vdb_count", "VDB header claiming 2^31-1 grids", ["render", "many.vdb", "-o", "{out}"],
         ("many.vdb", "cannot fit"), files={"many.vdb": vdb_header([b"density"], count=2 ** 31 - 1)}),
    # 3. tracebacks
    Case("tile_text", "`--tile abc`", ["render", "blob:50", "-o", "{out}", "--tile", "abc"],
         ("--tile", "abc")),
    Case("exposure_nan", "`--exposure nan`", ["render", "blob:50", "-o", "{out}", "--exposure", "nan"],
         ("--exposure", "finite")),
    Case("exposure_huge", "`--exposure 1e4`", ["render", "blob:50", "-o", "{out}", "--exposure", "1e4"],
         ("--exposure", "64")),
    Case("count_inf", "`blob:inf`", ["render", "blob:inf", "-o", "{out}"], ("blob:inf", "5e7")),
    Case("out_loop", "output is a symlink loop", ["render", "blob:50", "-o", "{out}"],
         ("o.png", "symlink loop"), files={"o.png": _link("p.png"), "p.png": _link("o.png")}),
    Case("out_long", "output name of 300 bytes", ["render", "blob:50", "-o", "x" * 296 + ".png"],
         ("bytes long", "shorter name"), out="x" * 296 + ".png"),
    Case("out_dir", "output is a directory", ["render", "blob:50", "-o", "{out}"],
         ("o.png", "directory"), files={"o.png": lambda p: p.mkdir()}),
    Case("convert_dir", "`convert` onto a directory", ["convert", "demo.vdb", "out.npz"],
         ("out.npz", "directory"),
         files={"demo.vdb": lambda p: shutil.copy(DEMO, p), "out.npz": lambda p: p.mkdir()},
         out="out.npz"),
    Case("convert_full", "`convert` onto a full disk (writes fail with ENOSPC)",
         ["convert", "demo.vdb", "out.npz"], ("out.npz", "No space left", "free some disk space"),
         files={"demo.vdb": lambda p: shutil.copy(DEMO, p)}, patches=_full_disk, out="out.npz"),
    Case("render_full", "render onto a full disk", ["render", "blob:50", "-o", "{out}"],
         ("o.png", "No space left"), patches=_full_disk),
    Case("ply_list_x", "PLY whose `x` is a list property", ["render", "l.ply", "-o", "{out}"],
         ("l.ply", "'x' is a list"), files={"l.ply": _ply_lists("list_x")}),
    Case("ply_nan_count", "ASCII PLY with a list count `nan`", ["render", "n.ply", "-o", "{out}"],
         ("n.ply", "malformed vertex row"), files={"n.ply": _ply_lists("nan_count")}),
    Case("ply_negative_count", "binary PLY with a list count of -1", ["render", "m.ply", "-o", "{out}"],
         ("m.ply", "negative list length"), files={"m.ply": _ply_lists("negative")}),
    Case("unreadable_vdb", "unreadable .vdb (mode 000, as a user)", ["render", "demo.vdb", "-o", "{out}"],
         ("demo.vdb", "permission denied"), files={"demo.vdb": lambda p: shutil.copy(DEMO, p)},
         patches=_unreadable("demo.vdb")),
    Case("unreadable_ply", "unreadable .ply", ["render", "p.ply", "-o", "{out}"],
         ("p.ply", "permission denied"), files={"p.ply": _ply_header(1) + "0 0 0\n"},
         patches=_unreadable("p.ply")),
    Case("unreadable_toml", "unreadable scene file", ["render", "s.toml", "-o", "{out}"],
         ("s.toml", "permission denied"), files={"s.toml": TOML_OK}, patches=_unreadable("s.toml")),
    # 4. non-finite images from finite input: every knob has a range
    Case("sun_huge", "`--sun 0,-1,0,1e300`", ["render", "blob:50", "-o", "{out}", "--sun", "0,-1,0,1e300"],
         ("--sun", "irradiance", "1e+30")),
    Case("point_huge", "`--point-light 0,3,0,1e300`",
         ["render", "blob:50", "-o", "{out}", "--point-light", "0,3,0,1e300"], ("--point-light", "1e+30")),
    Case("background_huge", "`--background 1e39`",
         ["render", "demo.vdb", "-o", "{out}", "--background", "1e39"], ("--background", "1e+30"),
         files={"demo.vdb": lambda p: shutil.copy(DEMO, p)}),
    Case("emission_huge", "`--emission-scale 1e300`",
         ["render", "demo.vdb", "-o", "{out}", "--emission-scale", "1e300"], ("--emission-scale", "1e+30"),
         files={"demo.vdb": lambda p: shutil.copy(DEMO, p)}),
    Case("glow_huge", "`--glow 1e300`", ["render", "blob:50", "-o", "{out}", "--glow", "1e300"],
         ("--glow", "1e+30")),
    Case("light_color_toml", "scene light whose colour x irradiance overflows",
         ["render", "s.toml", "-o", "{out}"], ("s.toml", "[[lights]] #1", "color x irradiance"),
         files={"s.toml": TOML_OK + '[[lights]]\ntype = "sun"\ndirection = [0, -1, 0]\n'
                'irradiance = 1e20\ncolor = [1e20, 1, 1]\n'}),
    # 5. corrupt brick caches
    Case("npz_dims", "brick cache whose dims' product overflows", ["render", "c.npz", "-o", "{out}"],
         ("c.npz", "corrupt brick cache", "dims"), files={"c.npz": _bricks_npz("dims")}),
    Case("npz_majorant", "brick cache with negative majorants", ["render", "c.npz", "-o", "{out}"],
         ("c.npz", "majorants"), files={"c.npz": _bricks_npz("majorant")}),
    Case("npz_singular", "brick cache with a near-singular transform", ["render", "c.npz", "-o", "{out}"],
         ("c.npz", "index_to_world"), files={"c.npz": _bricks_npz("singular")}),
    # 7. wrong or unclear messages
    Case("npy_lying", ".npy whose header claims 10^12 points", ["render", "big.npy", "-o", "{out}"],
         ("big.npy", "header says shape"), files={"big.npy": _lying_npy}),
    Case("float32_coords", "points beyond float32's reach", ["render", "far.xyz", "-o", "{out}"],
         ("far.xyz", "beyond"), files={"far.xyz": "0 0 0\n1e30 0 0\n"}),
    Case("toml_tile", "scene file tile out of range (`tile = [64, 64]`)",
         ["render", "s.toml", "-o", "{out}"], ("s.toml", "[render].tile"),
         files={"s.toml": TOML_OK + "[render]\ntile = [64, 64]\n"}),
    Case("dir_input", "a directory named .ply", ["render", "d.ply", "-o", "{out}"],
         ("d.ply", "is a directory"), files={"d.ply": lambda p: p.mkdir()}),
    # 8. terminal escapes in what is quoted from files
    Case("escape_ply", "PLY header line with terminal escapes", ["render", "e.ply", "-o", "{out}"],
         ("e.ply", "\\x1b]0;"), files={"e.ply": "ply\nformat ascii 1.0\nelement vertex 1\n"
                                      "title\x1b]0;owned\x07\nend_header\n0\n"}),
    Case("escape_csv", "CSV token with terminal escapes", ["render", "e.csv", "-o", "{out}"],
         ("e.csv", "\\x1b[2J"), files={"e.csv": "0,0,0\n1,\x1b[2J,0\n"}),
    Case("escape_vdb", "VDB grid name with terminal escapes", ["render", "e.vdb", "-o", "{out}"],
         ("e.vdb", "\\x1b]0;"), files={"e.vdb": vdb_header([b"\x1b]0;owned\x07"])}),
    # decided: a read-only or FIFO output is refused
    Case("out_read_only", "existing output is read-only", ["render", "blob:50", "-o", "{out}"],
         ("o.png", "read-only"), files={"o.png": PRECIOUS}, patches=_read_only_output),
    Case("out_fifo", "output is a FIFO", ["render", "blob:50", "-o", "{out}"], ("o.png", "FIFO"),
         files={"o.png": _fifo}),
]


def run_case(case: Case, workdir: Path, existing: bytes | None = None):
    """Run the CLI in-process in workdir (relative paths, so messages are portable).
    Returns (exit code, stderr, output bytes or None)."""
    from volrender import cli
    workdir.mkdir(parents=True, exist_ok=True)
    for name, content in case.files.items():
        p = workdir / name
        if callable(content):
            content(p)
        elif isinstance(content, bytes):
            p.write_bytes(content)
        else:
            p.write_text(content)
    out = workdir / case.out
    if existing is not None and case.out not in case.files:
        out.write_bytes(existing)
    argv = [a.replace("{out}", case.out) for a in case.argv]
    if argv[0] == "render":
        if "--size" not in argv:
            argv += SMALL[:2]
        argv += SMALL[2:]
    err = io.StringIO()
    cwd = os.getcwd()
    with contextlib.ExitStack() as stack:
        for p in (case.patches(workdir) if case.patches else []):
            stack.enter_context(p)
        stack.enter_context(contextlib.redirect_stderr(err))
        stack.enter_context(contextlib.redirect_stdout(io.StringIO()))
        os.chdir(workdir)
        try:
            code = cli.main(argv)
        except SystemExit as exc:             # argparse
            code = exc.code
        finally:
            os.chdir(cwd)
    return code, err.getvalue(), _contents(out)


def _contents(path):
    """The output's bytes (None when absent; a directory, FIFO or loop reads as itself)."""
    if not os.path.lexists(path) or not os.path.isfile(path):
        return "not a file" if os.path.lexists(path) else None
    return path.read_bytes()


NOTES = ("volrender: estimator auto:", "volrender: lights:", "volrender: fire:",
         "volrender: up axis", "volrender: denoise auto:")


def error_lines(err):
    """stderr's lines but the scene's notes (issue #22: the estimator auto picked, the
    default lights; issue 34: what --denoise auto does with the output), which come before
    a failure in the render itself."""
    return [ln for ln in err.strip().splitlines() if not ln.startswith(NOTES)]


def check(case, code, err, out_bytes, existing, workdir, before=None):
    assert "Traceback" not in err, err
    # the scene's notes (issue #22: the estimator auto picked, the default lights) come
    # before a failure in the render itself
    lines = error_lines(err)
    assert len(lines) == 1, err
    assert lines[0].startswith("volrender: error: "), err
    assert code == 2, (code, err)
    assert "\x1b" not in err and "\x07" not in err, "a raw terminal escape was printed"
    for w in case.words:
        assert w.lower() in err.lower(), (w, err)
    assert out_bytes == (before if case.out in case.files else existing), \
        "the output file was created or changed"
    assert not [p for p in os.listdir(workdir) if ".tmp" in p], "a temporary file was left"


def _case_params():
    """Every case without an output, and with an existing one where that can be (not when
    the output is one of the case's own files, or a name too long to exist)."""
    for c in CASES:
        yield pytest.param(c, None, id=f"{c.id}-no_output")
        if not (c.out in c.files or len(c.out) > 255):
            yield pytest.param(c, PRECIOUS, id=f"{c.id}-existing_output")


@pytest.mark.parametrize("case, existing", list(_case_params()))
def test_bad_input_fails_cleanly(tmp_path, case, existing):
    before = None
    if case.out in case.files:                  # the output is an input: it must survive
        setup = Case(case.id, case.label, ["info"], (), case.files, None, "none")
        run_case(setup, tmp_path / "probe")
        before = _contents(tmp_path / "probe" / case.out)
    code, err, out_bytes = run_case(case, tmp_path / "run", existing)
    check(case, code, err, out_bytes, existing, tmp_path / "run", before)


def test_size_check_runs_before_loading_or_allocating(tmp_path):
    """--size 32768x32768 passes argparse; the memory check refuses it before the volume
    is read or any buffer exists (the case patches both to fail loudly)."""
    case = next(c for c in CASES if c.id == "size_memory")
    code, err, _ = run_case(case, tmp_path)
    assert code == 2 and "was called" not in err


def test_a_failed_build_writes_nothing_past_python(tmp_path, capfd):
    """PoCL's compiler prints "N errors generated." straight to file descriptor 2; the
    user must still see one line only (device.build collects it into the log)."""
    case = next(c for c in CASES if c.id == "build")
    code, err, _ = run_case(case, tmp_path)
    assert code == 2 and len(error_lines(err)) == 1
    fd = capfd.readouterr()
    assert fd.err == "" and fd.out == "", fd


def test_debug_shows_the_traceback_and_the_build_log(tmp_path):
    case = next(c for c in CASES if c.id == "build")
    from volrender.device import BuildError
    debug = Case(case.id, case.label, case.argv + ["--debug"], (), case.files, case.patches)
    with pytest.raises(BuildError) as exc:
        run_case(debug, tmp_path)
    assert "\n" in str(exc.value) and "error" in str(exc.value).lower()   # the log is kept


def test_negative_seed_with_a_generator_renders(tmp_path, capsys):
    """--seed -1 works for volumes; generators used to crash in numpy (ValueError)."""
    from volrender import cli
    out = tmp_path / "o.npy"
    code = cli.main(["render", "blob:30", "-o", str(out), *SMALL, "--seed", "-1"])
    assert code == 0, capsys.readouterr().err
    assert np.isfinite(np.load(out)).all()


def volrender_exe():
    exe = Path(sys.executable).parent / "volrender"
    return [str(exe)] if exe.is_file() else [sys.executable, "-m", "volrender"]


@pytest.mark.parametrize("case_id", ["missing", "toml_syntax", "size_zero"])
def test_installed_command_gives_the_same_line(tmp_path, case_id):
    """The real process agrees with the in-process run, and leaves the output alone."""
    case = next(c for c in CASES if c.id == case_id)
    code, err, _ = run_case(case, tmp_path / "a")
    work = tmp_path / "b"
    work.mkdir()
    for name, content in case.files.items():       # these cases use text files only
        (work / name).write_text(content)
    (work / case.out).write_bytes(PRECIOUS)
    argv = [a.replace("{out}", case.out) for a in case.argv]
    if "--size" not in argv:
        argv += SMALL[:2]
    proc = subprocess.run([*volrender_exe(), *argv, *SMALL[2:]], cwd=work, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == code == 2
    assert proc.stderr == err and "Traceback" not in proc.stderr
    assert (work / case.out).read_bytes() == PRECIOUS


# ------------------------------------------------------------------ docs/bad_input.md

def _shown(arg):
    return arg if len(arg) <= 40 else f"{arg[:6]}...{arg[-8:]}"


def write_doc(path=ROOT / "docs" / "bad_input.md"):
    import tempfile
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for case in CASES:
            work = Path(d) / case.id
            code, err, _ = run_case(case, work)
            line = err.strip().replace(f"{os.path.realpath(work)}/", "").replace("|", "\\|")
            args = " ".join(_shown(a.replace("{out}", case.out)) for a in case.argv)
            rows.append(f"| {case.label} <br> `volrender {args}` | `` {line} `` | {code} |")
    from volrender import device
    text = (
        "# Bad input: what the user sees\n\n"
        "Generated from real runs by `tests/test_bad_input.py` (run it as a script to refresh:\n"
        "`.venv/bin/python tests/test_bad_input.py`); each row is also a test. Paths are\n"
        "relative to the directory the command ran in; images are 16x12 unless the size is\n"
        "the point. In every case stderr is that one line (no traceback), no output file is\n"
        "written and an existing one is left byte-identical. `--debug` shows the traceback\n"
        "(and a build failure's compiler log). Where the output is one of the inputs, that\n"
        "input is left byte-identical. Conditions that cannot be produced on demand (no\n"
        "OpenCL platform, a kernel that does not compile, memory exhaustion, a full disk, an\n"
        "unreadable file when the tests run as root) are simulated: pyopencl's\n"
        "`get_platforms`, `Buffer` or `enqueue_nd_range_kernel` raise the error a real runtime\n"
        "raises, the kernel source is replaced by a broken copy, the temporary file's writes\n"
        "go to `/dev/full`, or `os.access` says no. Signals, a read-only `$HOME`, a vanished\n"
        "working directory and mode-000 files (run as `nobody`) are tested on real processes\n"
        "by the tests after the table.\n\n"
        f"Device: {device.get().name}.\n\n"
        + TABLE_HEAD + "\n".join(rows) + "\n")
    path.write_text(text)
    readme = ROOT / "README.md"
    doc = readme.read_text()
    start = doc.index(TABLE_HEAD, doc.index("## Bad input"))
    end = doc.index("\n\n", start)
    readme.write_text(doc[:start] + TABLE_HEAD + "\n".join(rows) + doc[end:])
    return text


TABLE_HEAD = "| input | what the user sees (stderr) | exit code |\n|---|---|---|\n"


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    print(write_doc())


# ------------------------------------------------------------------ signals

LONG = ["render", "blob:3000", "--size", "320x240", "--spp", "256", "--no-progress"]


def _spawn(argv, cwd):
    """A real volrender process with SIGINT at its default (a job started in the
    background with & would ignore it), in its own process group."""
    import signal
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.Popen([sys.executable, "-m", "volrender", *argv], cwd=cwd, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: (signal.signal(signal.SIGINT, signal.SIG_DFL),
                                                os.setpgrp()))


def _wait_for_volrender_handlers(p, timeout=30.0):
    """Until volrender's start-up handler catches SIGTERM (/proc/PID/status SigCgt): the
    interpreter's own start is over, however loaded the machine is."""
    import signal
    import time
    bit = 1 << (signal.SIGTERM - 1)
    end = time.monotonic() + timeout
    while time.monotonic() < end and p.poll() is None:
        try:
            status = Path(f"/proc/{p.pid}/status").read_text()
        except OSError:
            break
        caught = next((int(line.split()[1], 16) for line in status.splitlines()
                       if line.startswith("SigCgt:")), 0)
        if caught & bit:
            return
        time.sleep(0.005)


def _finish(p, timeout):
    """(exit status, stderr, seconds until it exited); kills it when it will not stop."""
    import time
    t = time.perf_counter()
    try:
        err = p.communicate(timeout=timeout)[1]
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, 9)
        p.communicate()
        raise AssertionError(f"still running {timeout} s after the signal")
    return p.returncode, err, time.perf_counter() - t


@pytest.mark.parametrize("name,status", [("SIGINT", 130), ("SIGTERM", 143), ("SIGHUP", 129)])
def test_a_signal_stops_a_long_render_cleanly(tmp_path, name, status):
    """A render that would take minutes, signalled after 1.5 s: it exits within a few
    seconds (launches take about dispatch.TARGET_S) with 128 + the signal and one line,
    leaves no temporary file and the earlier output byte-identical."""
    import signal
    import time
    (tmp_path / "o.png").write_bytes(PRECIOUS)
    p = _spawn([*LONG, "-o", "o.png"], tmp_path)
    _wait_for_volrender_handlers(p)
    time.sleep(1.5)
    p.send_signal(getattr(signal, name))
    code, err, took = _finish(p, 30)
    assert code == status, err
    assert "Traceback" not in err and len(error_lines(err)) == 1, err
    assert f"interrupted ({name})" in err and "no output written" in err
    assert took < 5.0, f"{took:.1f} s to stop"
    assert sorted(os.listdir(tmp_path)) == ["o.png"]
    assert (tmp_path / "o.png").read_bytes() == PRECIOUS


@pytest.mark.parametrize("name,status", [("SIGINT", 130), ("SIGTERM", 143)])
def test_a_signal_during_start_up_is_one_line(tmp_path, name, status):
    """While the modules import (volrender/__init__.py exits at once) or while cli.main
    parses and loads: one line, 128 + the signal. (The interpreter's own start, the first
    ~50 ms before volrender is imported, is not covered.)"""
    import signal
    p = _spawn([*LONG, "-o", "o.png"], tmp_path)
    _wait_for_volrender_handlers(p)
    p.send_signal(getattr(signal, name))
    code, err, _ = _finish(p, 30)
    assert code == status, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert os.listdir(tmp_path) == []


def test_an_interrupt_after_the_rename_says_the_output_was_written(tmp_path, monkeypatch):
    from volrender import cli
    from volrender.render import Image
    real = Image.save

    def save_then_interrupt(self, *a, **kw):
        real(self, *a, **kw)
        raise KeyboardInterrupt
    monkeypatch.setattr(Image, "save", save_then_interrupt)
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = cli.main(["render", "blob:30", "-o", str(tmp_path / "o.png"), *SMALL])
    assert code == 130
    assert "o.png was written" in err.getvalue() and "no output" not in err.getvalue()


def test_no_signal_falls_between_creating_and_guarding_the_temporary_file(tmp_path, monkeypatch):
    """Ctrl-C right after the temporary file is created: held back until the file is
    guarded, then raised; the file is removed."""
    import signal
    from volrender import atomic
    real_open = os.open

    def open_then_ctrl_c(path, flags, *a):
        fd = real_open(path, flags, *a)
        if flags & os.O_EXCL:
            os.kill(os.getpid(), signal.SIGINT)       # pending: signals are held here
        return fd
    monkeypatch.setattr(atomic.os, "open", open_then_ctrl_c)
    with pytest.raises(KeyboardInterrupt):
        atomic.write_bytes(tmp_path / "x.npy", b"data")
    assert os.listdir(tmp_path) == []


def test_unreadable_files_as_a_user(tmp_path):
    """Mode 000 for real: as root, the command runs as nobody (root reads anything)."""
    if os.geteuid() != 0:
        uid = None
    else:
        import pwd
        try:
            uid = pwd.getpwnam("nobody").pw_uid
        except KeyError:
            pytest.skip("no user 'nobody'")
    work = Path(tempfile.mkdtemp(dir="/tmp"))
    try:
        work.chmod(0o777)
        (work / "p.xyz").write_text("0 0 0\n1 1 1\n")
        (work / "p.xyz").chmod(0)
        env = dict(os.environ, PYTHONPATH=str(ROOT), HOME=str(work))
        proc = subprocess.run([sys.executable, "-m", "volrender", "render", "p.xyz", "-o", "o.png",
                               *SMALL], cwd=work, env=env, capture_output=True, text=True,
                              timeout=120, user=uid)
        assert proc.returncode == 2, proc.stderr
        assert "p.xyz: cannot read the point-cloud file (permission denied)" in proc.stderr
        assert "Traceback" not in proc.stderr and not (work / "o.png").exists()
    finally:
        shutil.rmtree(work, ignore_errors=True)


def test_relative_output_after_the_working_directory_is_gone(tmp_path):
    gone = tmp_path / "gone"
    gone.mkdir()
    script = ("import os, sys; os.chdir(sys.argv[1]); os.rmdir(sys.argv[1]); "
              "from volrender import cli; sys.exit(cli.main(['render', 'blob:30', '-o', 'o.png', "
              "'--size', '8x8', '--no-progress']))")
    proc = subprocess.run([sys.executable, "-c", script, str(gone)], capture_output=True, text=True,
                          env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert "working directory no longer exists" in proc.stderr and "Traceback" not in proc.stderr


def test_a_read_only_home_still_finds_the_device(tmp_path):
    """PoCL and pyopencl cache under ~/.cache; with a HOME where nothing can be created
    volrender points them at a private folder under the temporary directory."""
    env = {k: v for k, v in os.environ.items() if k not in ("XDG_CACHE_HOME", "POCL_CACHE_DIR")}
    env.update(PYTHONPATH=str(ROOT), HOME="/proc/self/no-such-home")
    proc = subprocess.run([sys.executable, "-m", "volrender", "render", "blob:30", "-o", "o.png",
                           "--size", "8x8", "--no-progress"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "o.png").is_file()
