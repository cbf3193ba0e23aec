"""Property-based fuzz of the readers of untrusted files: the VDB header parser, PLY and
CSV/XYZ. Random truncations, byte flips and lying counts on valid files: the result is
always a valid value or one UserError line, within a time bound (hypothesis' deadline)
and a memory bound (tracemalloc's peak, which numpy's buffers count in)."""
import struct
import tempfile
import tracemalloc
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings, strategies as st

from volrender.vdb_header import GridInfo, parse_vdb
from volrender.errors import UserError
from volrender.cloud import PointCloud
from volrender.points import load_points

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "scenes" / "demo_cloud.vdb"
MEMORY = 64 << 20                       # bytes a reader of a file of a few KiB may use
FUZZ = settings(max_examples=150, deadline=2000, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def mutate(data: bytes, draw_ops):
    """Apply (kind, position, value) edits: flip a byte, truncate, or overwrite 4 or 8
    bytes with a lying little-endian count."""
    out = bytearray(data)
    for kind, pos, value in draw_ops:
        if not out:
            break
        pos %= len(out)
        if kind == "flip":
            out[pos] ^= 1 + value % 255
        elif kind == "cut":
            del out[pos:]
        elif kind == "count32":
            out[pos:pos + 4] = struct.pack("<I", value % (1 << 32))
        else:
            out[pos:pos + 8] = struct.pack("<q", value % (1 << 63))
    return bytes(out)


OPS = st.lists(st.tuples(st.sampled_from(["flip", "cut", "count32", "count64"]),
                         st.integers(0, 1 << 20), st.integers(0, 1 << 64)), min_size=1, max_size=4)


def bounded(call):
    """call() -> ('ok', value) or ('error', message); asserts the memory bound."""
    tracemalloc.start()
    try:
        try:
            result = ("ok", call())
        except UserError as exc:
            result = ("error", str(exc))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < MEMORY, f"{peak / 2**20:.0f} MiB"
    if result[0] == "error":
        assert "\n" not in result[1] and result[1], result[1]
        assert all(c.isprintable() for c in result[1]), result[1]
    return result


def in_file(data: bytes, suffix: str, fn):
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / f"f{suffix}"
        p.write_bytes(data)
        return bounded(lambda: fn(p))


def vdb_descriptors(names):
    """A .vdb holding grid descriptors only, each grid's data an empty metadata map."""
    def string(b):
        return struct.pack("<I", len(b)) + b
    out = struct.pack("<qIII", 0x56444220, 224, 10, 0) + b"\x01" + b"0" * 36
    out += struct.pack("<I", 1) + string(b"creator") + string(b"string") + string(b"fuzz")
    out += struct.pack("<i", len(names))
    for name in names:
        desc = string(name) + string(b"Tree_float_5_4_3") + string(b"")
        g = len(out) + len(desc) + 24
        out += desc + struct.pack("<qqq", g, g + 8, g + 8) + struct.pack("<II", 0, 0)
    return out


VDB_SEEDS = [vdb_descriptors([b"density", b"temperature"]), DEMO.read_bytes()[:4096]]


@FUZZ
@given(seed=st.sampled_from(range(len(VDB_SEEDS))), ops=OPS)
def test_vdb_header_parser(seed, ops):
    data = mutate(VDB_SEEDS[seed], ops)
    kind, value = in_file(data, ".vdb", parse_vdb)
    if kind == "ok" and value is not None:
        assert all(isinstance(g, GridInfo) for g in value)
        assert len(value) * 36 <= len(data)


def test_vdb_seeds_are_valid():
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "g.vdb"
        p.write_bytes(VDB_SEEDS[0])
        assert [g.name for g in parse_vdb(p)] == ["density", "temperature"]
    assert [g.name for g in parse_vdb(DEMO)] == ["density"]


def ply(fmt, rows, lists=False):
    props = "property float x\nproperty float y\nproperty float z\n"
    if lists:
        props += "property list uchar int idx\n"
    head = (f"ply\nformat {fmt} 1.0\nelement face 2\nproperty list uchar int vertex_indices\n"
            f"element vertex {len(rows)}\n{props}end_header\n").encode()
    if fmt == "ascii":
        body = "3 0 1 2\n1 5\n" + "".join(" ".join(f"{v:g}" for v in r) + (" 2 7 8" if lists else "")
                                         + "\n" for r in rows)
        return head + body.encode()
    e = "<" if fmt == "binary_little_endian" else ">"
    body = struct.pack(f"{e}B3i", 3, 0, 1, 2) + struct.pack(f"{e}Bi", 1, 5)
    for r in rows:
        body += struct.pack(f"{e}3f", *r) + (struct.pack(f"{e}B2i", 2, 7, 8) if lists else b"")
    return head + body


ROWS = np.random.default_rng(7).random((12, 3)).round(3).tolist()
PLY_SEEDS = [ply(f, ROWS, lists) for f in ("ascii", "binary_little_endian", "binary_big_endian")
             for lists in (False, True)]


def check_cloud(value):
    assert isinstance(value, PointCloud) and len(value) >= 1
    assert np.isfinite(value.centers).all()


@FUZZ
@given(seed=st.sampled_from(range(len(PLY_SEEDS))), ops=OPS)
def test_ply_reader(seed, ops):
    kind, value = in_file(mutate(PLY_SEEDS[seed], ops), ".ply", load_points)
    if kind == "ok":
        check_cloud(value)


@FUZZ
@given(seed=st.sampled_from(range(len(PLY_SEEDS))), count=st.integers(0, 1 << 62),
       which=st.sampled_from([b"element face ", b"element vertex "]))
def test_ply_lying_counts(seed, count, which):
    data = PLY_SEEDS[seed]
    start = data.index(which) + len(which)
    end = data.index(b"\n", start)
    kind, value = in_file(data[:start] + str(count).encode() + data[end:], ".ply", load_points)
    if kind == "ok":
        check_cloud(value)


def test_ply_seeds_are_valid():
    for data in PLY_SEEDS:
        kind, value = in_file(data, ".ply", load_points)
        assert kind == "ok", value
        np.testing.assert_allclose(value.centers, ROWS, rtol=1e-6)


CSV_TOKENS = st.sampled_from(["0", "1.5", "-2e3", "nan", "inf", "x", ",", ";", "#", " ", "\t",
                              "\n", "\r\n", "1e400", "\x1b[2J", "\xff", "255", "", "0,0,0"])


@FUZZ
@given(tokens=st.lists(CSV_TOKENS, max_size=60), suffix=st.sampled_from([".csv", ".xyz", ".txt"]))
def test_csv_reader(tokens, suffix):
    kind, value = in_file("".join(tokens).encode("utf-8", "surrogateescape"), suffix, load_points)
    if kind == "ok":
        check_cloud(value)


@FUZZ
@given(ops=OPS)
def test_csv_reader_mutations(ops):
    seed = ("x,y,z,r\n" + "".join(f"{a},{b},{c},0.1\n" for a, b, c in ROWS)).encode()
    kind, value = in_file(mutate(seed, ops), ".csv", load_points)
    if kind == "ok":
        check_cloud(value)
