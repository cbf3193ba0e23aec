import time

import numpy as np
import pytest

from volrender.errors import UserError
from volrender.cloud import PointCloud
from volrender.generators import blob, generate, GENERATORS, glass_gather, uniform_box
from volrender.points import load_points

def num(v):
    """A number as text that reads back exactly: repr of the Python value (numpy 2's
    repr of a numpy scalar is `np.float64(...)`, which no point reader parses)."""
    return repr(v.item() if isinstance(v, np.generic) else v)


VERTEX = [("x", "f4"), ("y", "f4"), ("z", "f4")]


def write_ply(path, fmt, vertex_props, vertex_rows, before=(), after=(), extra_header=()):
    """Write a PLY. Elements in ``before``/``after`` are (name, header_props, rows), where
    header_props is a list of header 'property ...' tails and rows a list of
    per-row value lists (lists written flat, count first)."""
    ply_types = {"f4": "float", "f8": "double", "u1": "uchar", "i4": "int", "u2": "ushort",
                 "i2": "short"}
    endian = {"binary_little_endian": "<", "binary_big_endian": ">"}.get(fmt)
    head = ["ply", f"format {fmt} 1.0", *extra_header]
    vhead = [f"element vertex {len(vertex_rows)}"] + [
        f"property {ply_types[t]} {name}" for name, t in vertex_props]
    elems = []
    for name, props, rows in before:
        elems.append((name, props, rows))
    elems.append(("vertex", None, vertex_rows))
    elems.extend(after)
    body = b""
    for name, props, rows in elems:
        if props is None:
            head += vhead
            if endian:
                dt = np.dtype([(n, endian + t) for n, t in vertex_props])
                body += np.array([tuple(r) for r in rows], dtype=dt).tobytes()
            else:
                body += b"".join((" ".join(num(v) for v in r) + "\n").encode() for r in rows)
        else:
            head += [f"element {name} {len(rows)}"] + [f"property {p}" for p in props]
            for r in rows:   # only 'list uchar int' elements in these tests
                if endian:
                    body += np.array([len(r)], endian + "u1").tobytes()
                    body += np.array(r, endian + "i4").tobytes()
                else:
                    body += (" ".join(map(str, [len(r), *r])) + " \n").encode()
    data = ("\n".join(head) + "\nend_header\n").encode() + body
    path.write_bytes(data)
    return path


def f32(a):
    return np.asarray(a, dtype=np.float32).astype(np.float64)


@pytest.fixture
def pts(rng):
    return rng.normal(size=(23, 3)) * 10


# ---------------------------------------------------------------- round trips

@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_ply_round_trip_with_radius_and_uchar_colours(tmp_path, rng, pts, fmt):
    radius = rng.random(len(pts))
    rgb = rng.integers(0, 256, size=(len(pts), 3))
    props = [("x", "f8"), ("y", "f8"), ("z", "f8"), ("nx", "f4"), ("radius", "f8"),
             ("red", "u1"), ("green", "u1"), ("blue", "u1")]
    rows = [(*p, 0.5, r, *c) for p, r, c in zip(pts, radius, rgb)]
    faces = [[0, 1, 2], [2, 3, 4]]
    pc = load_points(write_ply(tmp_path / "a.ply", fmt, props, rows,
                               after=[("face", ["list uchar int vertex_indices"], faces)],
                               extra_header=["comment hi", "obj_info scanner 1"]))
    np.testing.assert_array_equal(pc.centers, pts)
    np.testing.assert_array_equal(pc.radii, radius)
    np.testing.assert_array_equal(pc.colors, (rgb / 255.0).astype(np.float32))
    assert pc.centers.dtype == np.float64 and pc.colors.dtype == np.float32
    assert pc.source == str(tmp_path / "a.ply")


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
@pytest.mark.parametrize("uniform", [True, False])
def test_ply_vertex_after_list_elements(tmp_path, pts, fmt, uniform):
    faces = [[0, 1, 2]] * 5 if uniform else [[0, 1, 2], [1, 2, 3, 4], [], [5]]
    grid = [[], [3], [], [7]]
    path = write_ply(tmp_path / "b.ply", fmt, VERTEX, [tuple(p) for p in f32(pts)],
                     before=[("face", ["list uchar int vertex_indices"], faces),
                             ("range_grid", ["list uchar int vertex_indices"], grid)])
    pc = load_points(path)
    np.testing.assert_array_equal(pc.centers, f32(pts))
    assert pc.radii is None and pc.colors is None


def test_ply_scale_as_radius_and_float_colours(tmp_path, pts):
    props = VERTEX + [("scale", "f4"), ("red", "f4"), ("green", "f4"), ("blue", "f4")]
    rows = [(*p, 0.25, 0.1, 0.5, 1.0) for p in pts]
    pc = load_points(write_ply(tmp_path / "c.ply", "binary_little_endian", props, rows))
    np.testing.assert_array_equal(pc.radii, np.full(len(pts), 0.25))
    np.testing.assert_allclose(pc.colors, np.tile([0.1, 0.5, 1.0], (len(pts), 1)), rtol=1e-7)


def test_ply_crlf_and_trailing_spaces(tmp_path):
    text = ("ply\r\nformat ascii 1.0 \r\nelement vertex 2\r\nproperty float x\r\n"
            "property float y\r\nproperty float z\r\nend_header\r\n1 2 3 \r\n\r\n4 5 6  \r\n")
    (tmp_path / "d.ply").write_bytes(text.encode())
    np.testing.assert_array_equal(load_points(tmp_path / "d.ply").centers, [[1, 2, 3], [4, 5, 6]])


@pytest.mark.parametrize("suffix,sep,header", [(".xyz", " ", None), (".csv", ",", "x,y,z"),
                                               (".txt", "\t", "# comment")])
def test_text_xyz_round_trip(tmp_path, pts, suffix, sep, header):
    lines = ([header] if header else []) + [sep.join(num(v) for v in p) for p in pts]
    path = tmp_path / ("p" + suffix)
    path.write_text("\n".join(lines) + "\n\n")
    pc = load_points(path)
    np.testing.assert_array_equal(pc.centers, pts)
    assert pc.radii is None and pc.colors is None


def test_text_with_radius_and_colours(tmp_path, rng, pts):
    r = rng.random(len(pts))
    rgb = rng.integers(0, 256, size=(len(pts), 3))
    lines = ["x y z radius r g b"] + [
        " ".join(map(num, [*p, q, *map(int, c)])) for p, q, c in zip(pts, r, rgb)]
    (tmp_path / "q.txt").write_text("\n".join(lines))
    pc = load_points(tmp_path / "q.txt")
    np.testing.assert_array_equal(pc.centers, pts)
    np.testing.assert_array_equal(pc.radii, r)
    np.testing.assert_allclose(pc.colors, rgb / 255.0, rtol=1e-6)

    (tmp_path / "r.csv").write_text("\n".join(",".join(map(num, [*p, q])) for p, q in zip(pts, r)))
    pc = load_points(tmp_path / "r.csv")
    np.testing.assert_array_equal(pc.radii, r)

    rgb01 = rng.random((len(pts), 3))
    (tmp_path / "s.xyz").write_text("\n".join(" ".join(map(num, [*p, *c]))
                                              for p, c in zip(pts, rgb01)))
    pc = load_points(tmp_path / "s.xyz")
    assert pc.radii is None
    np.testing.assert_array_equal(pc.colors, rgb01.astype(np.float32))


def test_npy_round_trip(tmp_path, rng, pts):
    np.save(tmp_path / "a.npy", pts)
    pc = load_points(tmp_path / "a.npy")
    np.testing.assert_array_equal(pc.centers, pts)
    assert pc.radii is None
    r = rng.random(len(pts))
    np.save(tmp_path / "b.npy", np.column_stack([pts, r]).astype(np.float32))
    pc = load_points(tmp_path / "b.npy")
    np.testing.assert_array_equal(pc.centers, f32(pts))
    np.testing.assert_array_equal(pc.radii, f32(r))


# ---------------------------------------------------------------- real files

def test_bun_zipper(shared_data):
    pc = load_points(shared_data / "points" / "bun_zipper.ply")
    assert len(pc) == 35947 and pc.radii is None and pc.colors is None
    np.testing.assert_allclose(pc.centers.min(0), [-0.094690, 0.032987, -0.061874], atol=1e-6)
    np.testing.assert_allclose(pc.centers.max(0), [0.061009, 0.187321, 0.058800], atol=1e-6)


def test_bun000_with_range_grid(shared_data):
    pc = load_points(shared_data / "points" / "bun000.ply")
    assert len(pc) == 40256
    np.testing.assert_allclose(pc.centers.min(0), [-0.09475, 0.035736, -0.058698], atol=1e-6)
    np.testing.assert_allclose(pc.centers.max(0), [0.061, 0.18794, 0.058723], atol=1e-6)


def test_frag_115_binary_colours(shared_data):
    pc = load_points(shared_data / "points" / "frag_115.ply")
    assert len(pc) == 64365 and pc.radii is None
    np.testing.assert_allclose(pc.centers.min(0), [0.8398, 0.9180, 0.5664], atol=1e-4)
    np.testing.assert_allclose(pc.centers.max(0), [2.5724, 2.8135, 1.6089], atol=1e-4)
    c = pc.colors
    assert c.dtype == np.float32 and c.shape == (64365, 3)
    assert 0.0 <= c.min() and c.max() <= 1.0
    np.testing.assert_allclose(c.min(0) * 255, [73, 82, 10], atol=1e-3)
    np.testing.assert_allclose(c.max(0) * 255, [228, 207, 210], atol=1e-3)
    np.testing.assert_allclose(c.mean(0) * 255, [164, 150, 152], atol=1.0)


# ---------------------------------------------------------------- errors

def err(path, *fragments):
    with pytest.raises(UserError) as info:
        load_points(path)
    msg = str(info.value)
    assert str(path) in msg and "\n" not in msg
    for f in fragments:
        assert f in msg, msg
    return msg


def test_missing_file_and_unsupported_suffix(tmp_path):
    err(tmp_path / "nope.ply", "no such file")
    (tmp_path / "a.obj").write_text("v 1 2 3\n")
    err(tmp_path / "a.obj", "unsupported suffix '.obj'", ".ply")
    (tmp_path / "noext").write_text("1 2 3\n")
    err(tmp_path / "noext", "unsupported suffix")
    (tmp_path / "dir.ply").mkdir()
    err(tmp_path / "dir.ply", "is a directory")


@pytest.mark.parametrize("suffix", [".ply", ".xyz", ".csv", ".npy"])
def test_empty_file(tmp_path, suffix):
    (tmp_path / ("e" + suffix)).write_bytes(b"")
    err(tmp_path / ("e" + suffix))


@pytest.mark.parametrize("text,fragment", [
    ("plx\nformat ascii 1.0\nend_header\n", "not a PLY file"),
    ("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n", "no 'end_header'"),
    ("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
     "property float z\nbogus 1\nend_header\n1 2 3\n", "unknown keyword 'bogus'"),
    ("ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\nend_header\n", "unknown property type"),
    ("ply\nformat binary_middle_endian 1.0\nend_header\n", "unknown format"),
    ("ply\nelement vertex 1\nproperty float x\nend_header\n1\n", "no 'format' line"),
    ("ply\nformat ascii 1.0\nproperty float x\nend_header\n", "property before any element"),
    ("ply\nformat ascii 1.0\nelement vertex many\nend_header\n", "element <name> <count>"),
    ("ply\nformat ascii 1.0\nelement face 0\nproperty list uchar int v\nend_header\n", "no 'vertex' element"),
    ("ply\nformat ascii 1.0\nelement vertex 2\nproperty float y\nproperty float z\n"
     "end_header\n1 2\n3 4\n", "PLY vertex element has no 'x' property"),
    ("ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
     "property float z\nend_header\n", "zero points"),
    ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
     "property float z\nend_header\n1 2 3\n4 5\n6 7 8\n", "line 9: expected 3 numbers, got 2"),
    ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
     "property float z\nend_header\n1 2 3\n4 5 6\n", "truncated ASCII PLY: header says 3 vertices, file holds 2"),
    ("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
     "property float z\nend_header\n1 2 3\n4 five 6\n", "line 9: 'five' is not a number"),
    ("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
     "property float z\nend_header\n1 2 3\n4 nan 6\n", "NaN/Inf coordinates (first: point 1)"),
    ("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
     "property float z\nproperty float radius\nend_header\n1 2 3 -1\n", "radii are negative"),
    ("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
     "property float z\nproperty float red\nproperty float green\nproperty float blue\n"
     "end_header\n1 2 3 255 0 0\n", "colours outside 0..1"),
])
def test_bad_ply(tmp_path, text, fragment):
    (tmp_path / "bad.ply").write_text(text)
    err(tmp_path / "bad.ply", fragment)


def test_truncated_binary_ply(tmp_path, rng):
    p = rng.random((100, 3))
    path = write_ply(tmp_path / "t.ply", "binary_little_endian", VERTEX, [tuple(r) for r in p])
    data = path.read_bytes()
    path.write_bytes(data[:len(data) - 63 * 12 - 5])
    err(path, "truncated binary PLY: header says 100 vertices, file holds 36")
    # truncated inside a list element that precedes the vertices
    path = write_ply(tmp_path / "u.ply", "binary_big_endian", VERTEX, [tuple(r) for r in p],
                     before=[("face", ["list uchar int vertex_indices"], [[1, 2, 3], [4]])])
    head = path.read_bytes().split(b"end_header\n")[0] + b"end_header\n"
    path.write_bytes(head + bytes([3, 0, 0, 0, 1]))
    err(path, "truncated binary PLY", "'face'")


@pytest.mark.parametrize("text,fragment", [
    ("1 2 3\n4 5 6\n7 8\n", "line 3: expected 3 numbers, got 2"),
    ("x y z\n1 2 3\n\n4 5 6 7\n", "line 4: expected 3 numbers, got 4"),
    ("1 2 3 4 5\n", "line 1: expected 3, 4, 6, 7 or 9 numbers"),
    ("x y z\n", "zero points"),
    ("1 2 3\n4 b 6\n", "line 2: not all numbers"),
    ("1 2 3\nnan 2 3\n", "NaN/Inf"),
    ("1 2 3 300 0 0\n", "colours outside 0..255"),
])
def test_bad_text(tmp_path, text, fragment):
    (tmp_path / "bad.csv").write_text(text)
    err(tmp_path / "bad.csv", fragment)


def test_bad_npy(tmp_path):
    np.save(tmp_path / "a.npy", np.zeros((4, 5)))
    err(tmp_path / "a.npy", "(N,3) or (N,4)")
    np.save(tmp_path / "b.npy", np.zeros((0, 3)))
    err(tmp_path / "b.npy", "zero points")
    (tmp_path / "c.npy").write_bytes(b"garbage")
    err(tmp_path / "c.npy", "not a readable .npy")
    np.save(tmp_path / "d.npy", np.array([[1, 2, np.inf]]))
    err(tmp_path / "d.npy", "NaN/Inf")


def test_binary_garbage_as_text(tmp_path):
    (tmp_path / "g.xyz").write_bytes(b"\xff\xfe\x00\x01garbage")
    err(tmp_path / "g.xyz", "not a text file")


# ---------------------------------------------------------------- generators

def neighbour_counts(pc):
    """Per sphere: how many other spheres it overlaps (brute force, chunked)."""
    c, r = pc.centers, pc.radii
    out = np.empty(len(c), dtype=np.int64)
    for i in range(0, len(c), 512):
        d = np.linalg.norm(c[i:i + 512, None] - c[None], axis=2)
        out[i:i + 512] = (d < r[i:i + 512, None] + r[None]).sum(1) - 1
    return out


@pytest.mark.parametrize("name", sorted(GENERATORS))
def test_generators_deterministic(name):
    a, b = generate(name, 500, seed=3), generate(name, 500, seed=3)
    c = generate(name, 500, seed=4)
    assert isinstance(a, PointCloud) and len(a) == 500 and a.radii.shape == (500,)
    np.testing.assert_array_equal(a.centers, b.centers)
    np.testing.assert_array_equal(a.radii, b.radii)
    assert not np.array_equal(a.centers, c.centers)
    assert np.isfinite(a.centers).all() and (a.radii > 0).all()
    for n in (1, 2, 7):
        assert len(generate(name, n, seed=0)) == n


@pytest.mark.parametrize("gen", [blob, uniform_box, glass_gather])
def test_generator_overlap_stable_in_n(gen):
    small = np.median(neighbour_counts(gen(600, seed=1)))
    large = np.median(neighbour_counts(gen(4800, seed=1)))
    assert 2 <= small and 2 <= large
    assert 0.5 <= large / small <= 2.0, (small, large)


def test_glass_gather_shape():
    pc = glass_gather(4000, seed=0)
    pipe, drop = pc.centers[:40], pc.centers[40:]
    # the pipe is a straight line of points
    d = pipe - pipe[0]
    assert np.linalg.matrix_rank(d, tol=1e-9) == 1
    # the drop hangs below the pipe tip
    assert drop[:, 1].min() < pipe[:, 1].min() - 1.0
    assert drop[:, 1].max() <= pipe[-1, 1] + 0.1     # the neck is ~0.08 thick


def test_generate_errors():
    with pytest.raises(UserError, match="blob, uniform_box, glass_gather"):
        generate("teapot", 10, 0)
    for n in (0, -5, 2.5, True):
        with pytest.raises(UserError, match="positive integer"):
            generate("blob", n, 0)


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_ply_vertex_with_list_property(tmp_path, fmt):
    """Rare but legal: a list inside the vertex element (slow row-by-row path)."""
    endian = {"binary_little_endian": "<", "binary_big_endian": ">"}.get(fmt)
    rows = [((1.5, 2.0, 3.0), [7, 8]), ((4.0, 5.0, 6.25), []), ((-1.0, 0.0, 1.0), [9])]
    head = (f"ply\nformat {fmt} 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            "property list uchar int idx\nproperty float z\nproperty uchar red\n"
            "property uchar green\nproperty uchar blue\nend_header\n").encode()
    body = b""
    for (x, y, z), lst in rows:
        if endian:
            body += np.array([x, y], endian + "f4").tobytes() + bytes([len(lst)])
            body += np.array(lst, endian + "i4").tobytes() + np.array([z], endian + "f4").tobytes()
            body += bytes([255, 0, 51])
        else:
            body += f"{x} {y} {len(lst)} {' '.join(map(str, lst))} {z} 255 0 51\n".encode()
    (tmp_path / "v.ply").write_bytes(head + body)
    pc = load_points(tmp_path / "v.ply")
    np.testing.assert_array_equal(pc.centers, [r[0] for r in rows])
    np.testing.assert_allclose(pc.colors, [[1, 0, 0.2]] * 3, rtol=1e-6)
    (tmp_path / "w.ply").write_bytes(head + body[:-3])
    err(tmp_path / "w.ply")


def test_large_files_load_fast(tmp_path, rng):
    """200k lines of .xyz read exactly and within 8x numpy's own text reader on the same
    file (np.loadtxt, a C parser; measured 2.4-3x on the 2-core machine), the best of two
    runs each: a bound relative to the machine's speed and load, which a reader that
    falls back to Python per value or grows faster than linearly would break."""
    p = rng.random((200_000, 3))
    path = tmp_path / "big.xyz"
    np.savetxt(path, p, fmt="%.17g")

    def best(f):
        out = []
        for _ in range(2):
            t0 = time.perf_counter()
            f(path)
            out.append(time.perf_counter() - t0)
        return min(out)
    pc = load_points(path)
    np.testing.assert_array_equal(pc.centers, p)
    mine, numpy_s = best(load_points), best(np.loadtxt)
    assert mine <= 8 * numpy_s + 0.2, f"{mine:.2f} s against np.loadtxt's {numpy_s:.2f} s"
