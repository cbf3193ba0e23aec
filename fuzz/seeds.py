"""Seed corpora of the fuzz targets, built at run time: small inputs made here (every PLY
format, lists, comments, VDB descriptors, brick caches, scenes, cameras, patterns,
ranges), the repository's own scenes, and, where ../shared/data is present, small cuts of
the real files there (read by path, never copied into the repository):

    python fuzz/seeds.py OUT_DIR [TARGET ...]      # OUT_DIR/TARGET/seed-NNN
"""
from __future__ import annotations

import io
import os
import struct
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("VOLRENDER_SHARED_DATA", ROOT.parent / "shared" / "data"))
MAX_SEED = 16 << 10              # bytes of a seed cut from a real file


def _string(b: bytes) -> bytes:
    return struct.pack("<I", len(b)) + b


def vdb_descriptors(names, meta=()) -> bytes:
    """A .vdb holding grid descriptors and metadata only (no voxel data)."""
    out = struct.pack("<qIII", 0x56444220, 224, 10, 0) + b"\x01" + b"0" * 36
    out += struct.pack("<I", 1) + _string(b"creator") + _string(b"string") + _string(b"fuzz")
    out += struct.pack("<i", len(names))
    for name in names:
        desc = _string(name) + _string(b"Tree_float_5_4_3") + _string(b"")
        g = len(out) + len(desc) + 24
        body = struct.pack("<I", 0) + struct.pack("<I", len(meta))
        for key, kind, raw in meta:
            body += _string(key) + _string(kind) + _string(raw)
        out += desc + struct.pack("<qqq", g, g + len(body), g + len(body)) + body
    return out


def vdb_skeleton(data: bytes) -> bytes | None:
    """A real .vdb with its voxel data cut out: the header, the descriptors and each grid's
    metadata as written, offsets rewritten (small seeds with real metadata)."""
    from volrender import vdb_header
    f = io.BytesIO(data)
    r = vdb_header._Reader(f, len(data))
    try:
        if r.unpack("q") != vdb_header.VDB_MAGIC or r.unpack("I") < 222:
            return None
        r.unpack("II")
        if r.read(1) == b"\0":
            return None
        r.read(36)
        vdb_header._read_metamap(r)
        head_end = f.tell()
        count = r.unpack("i")
        out = bytearray(data[:head_end]) + struct.pack("<i", count)
        for _ in range(count):
            d0 = f.tell()
            for _ in range(3):
                r.string()
            d1 = f.tell()
            grid_pos, _, end_pos = r.unpack("qqq")
            f.seek(grid_pos)
            r.unpack("I")
            vdb_header._read_metamap(r)
            body = data[grid_pos:f.tell()]
            g = len(out) + (d1 - d0) + 24
            out += data[d0:d1] + struct.pack("<qqq", g, g + len(body), g + len(body)) + body
            f.seek(end_pos)
        return bytes(out)
    except Exception:
        return None


def ply(fmt, rows, lists=False, comments=True, extra=()) -> bytes:
    props = "property float x\nproperty float y\nproperty float z\n"
    props += "".join(f"property {t} {n}\n" for t, n in extra)
    if lists:
        props += "property list uchar int idx\n"
    head = (f"ply\nformat {fmt} 1.0\n" + ("comment made by fuzz/seeds.py\nobj_info x\n" if comments else "")
            + "element face 2\nproperty list uchar int vertex_indices\n"
            f"element vertex {len(rows)}\n{props}end_header\n").encode()
    if fmt == "ascii":
        body = "3 0 1 2\n1 5\n"
        for r in rows:
            body += " ".join(f"{v:g}" for v in r) + "".join(" 7" for _ in extra)
            body += (" 2 7 8" if lists else "") + "\n"
        return head + body.encode()
    e = "<" if fmt == "binary_little_endian" else ">"
    codes = {"uchar": "B", "float": "f", "double": "d", "int": "i", "ushort": "H"}
    body = struct.pack(f"{e}B3i", 3, 0, 1, 2) + struct.pack(f"{e}Bi", 1, 5)
    for r in rows:
        body += struct.pack(f"{e}3f", *r)
        for t, _ in extra:
            body += struct.pack(e + codes[t], 7)
        body += struct.pack(f"{e}B2i", 2, 7, 8) if lists else b""
    return head + body


ROWS = [(0.1, 0.2, 0.3), (1.0, -2.0, 3.5), (0.0, 0.0, 0.0), (4.25, 1e-3, -7.0)]
RGB = (("uchar", "red"), ("uchar", "green"), ("uchar", "blue"))


def _ply_seeds():
    out = []
    for fmt in ("ascii", "binary_little_endian", "binary_big_endian"):
        for lists in (False, True):
            out.append(ply(fmt, ROWS, lists))
        out.append(ply(fmt, ROWS, extra=(("float", "radius"), *RGB), comments=False))
        out.append(ply(fmt, ROWS, extra=(("double", "scale"),)))
    out.append(b"ply\r\nformat ascii 1.0\r\nelement vertex 1\r\nproperty float x\r\n"
               b"property float y\r\nproperty float z\r\nend_header\r\n1 2 3\r\n")
    for name in ("bun000.ply", "bun_zipper.ply", "frag_115.ply"):
        p = SHARED / "points" / name
        if p.is_file():
            with open(p, "rb") as f:
                out.append(f.read(MAX_SEED))
    return out


def _text_seeds():
    return [b"0 0 0\n1 1 1\n", b"x,y,z,r\n0,0,0,0.1\n1,2,3,0.5\n",
            b"# comment\n0;0;0;255;0;0\n1;1;1;0;255;0\n", b"1 2 3 0.5 0.1 0.2 0.3\n",
            "\ufeffx y z\n1e3 -2.5e-3 nan\n".encode(), b"0\t0\t0\r\n1\t1\t1\r\n"]


def _vdb_seeds():
    meta = [(b"class", b"string", b"fog volume"), (b"file_voxel_count", b"int64", struct.pack("<q", 10)),
            (b"file_mem_bytes", b"int64", struct.pack("<q", 4096)),
            (b"file_bbox_min", b"vec3i", struct.pack("<3i", 0, 0, 0)),
            (b"file_bbox_max", b"vec3i", struct.pack("<3i", 9, 9, 9))]
    out = [vdb_descriptors([b"density", b"temperature"]), vdb_descriptors([b"density"], meta),
           vdb_descriptors([b"density", b"density\x1e1"], meta[:2])]
    files = [ROOT / "scenes" / "demo_cloud.vdb"]
    if SHARED.is_dir():
        files += sorted((SHARED / "vdb").rglob("*.vdb"))
    for p in files:
        data = p.read_bytes()
        skel = vdb_skeleton(data)
        if skel is not None:
            out.append(skel)
        out.append(data[:4096])
    return out


def _npz_bytes(bricks) -> bytes:
    import tempfile
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "c.npz"
        bricks.save_npz(p)
        return p.read_bytes()


def _npz_seeds():
    import numpy as np
    from volrender.bricks import Bricks
    v = np.zeros((3, 2, 2), np.float32)
    v[1, 1, 0] = 2.0
    out = [_npz_bytes(Bricks.from_dense(v)),
           _npz_bytes(Bricks.from_dense(v, emission=v * 3, temperature=v + 1, origin=(-5, 7, 0))),
           _npz_bytes(Bricks.from_dense(np.ones((1, 1, 1), np.float32), np.diag([2.0, 2, 2, 1])))]
    return out


def _npy_bytes(a) -> bytes:
    import numpy as np
    f = io.BytesIO()
    np.save(f, a)
    return f.getvalue()


def _npy_seeds():
    import numpy as np
    rows = np.array(ROWS)
    return [_npy_bytes(rows), _npy_bytes(rows.astype(np.float32)),
            _npy_bytes(np.c_[rows, np.full(len(rows), 0.1)]), _npy_bytes(rows.astype(">i2")),
            _npy_bytes(np.asfortranarray(np.c_[rows, rows[:, :1]]))]


def _bricks_seeds():
    import numpy as np
    out = [bytes([2, 2, 2, 0, 0, 0]) + np.arange(8, dtype="<f4").tobytes(),
           bytes([8, 1, 3, 255, 1, 128, 5]) + np.array([np.nan, np.inf, -1, 3] * 6, "<f4").tobytes(),
           bytes([9, 9, 9, 0, 0, 0]) + np.ones(729 * 2, "<f4").tobytes()]
    return out


def _scene_seeds():
    out = [p.read_bytes() for p in sorted((ROOT / "scenes").glob("*.toml"))]
    out += [b'[points]\ngenerator = "blob"\ncount = 50\nseed = 3\n[render]\nsize = [16, 12]\n',
            b'[volume]\nfile = "smoke.vdb"\n[[lights]]\ntype = "sun"\ndirection = [0, -1, 0]\n'
            b'irradiance = 3\ncolor = [1, 0.9, 0.8]\n[[lights]]\ntype = "point"\n'
            b'position = [1, 2, 3]\nintensity = 10\n[camera]\nfov = 30.0\n',
            b'[points]\nfile = "cloud.ply"\n[material]\nior = 1.5\n[environment]\n',
            b'[points]\nfile = "dir"\n', b'[points]\ngenerator = "blob"\ncount = 1e3\n']
    return out


def _camera_seeds():
    return [b"# volrender camera\n[camera]\norigin = [0.0, 1.0, 5.0]\ntarget = [0.0, 0.0, 0.0]\n"
            b"up = [0.0, 1.0, 0.0]\nfov = 40.0\n\n[render]\nsize = [640, 480]\n",
            b"[camera]\nfov = 1e308\n", b"[render]\nsize = [true, 1]\n"]


def _pattern_seeds():
    texts = ["smoke_####.vdb", "out/f_%04d.exr", "x%d.npz", "frames/*.vdb", "a_[0-9]?.vdb",
             "a_[!x]*.vdb", "dir/##/f.exr", "plain.vdb", "%0d%%d.vdb", "[]].vdb"]
    return [bytes([flag]) + t.encode() for t in texts for flag in (0, 1)]


def _frames_seeds():
    return [t.encode() for t in ("1-240", "1-240:2", "7", "1,3,5-9:2", "-5--1", " 10 - 20 : 5 ",
                                 "0-9999", "1-2,2-3")]


SEEDS = {"ply": _ply_seeds, "text": _text_seeds, "npy": _npy_seeds, "vdb_header": _vdb_seeds,
         "npz": _npz_seeds,
         "bricks": _bricks_seeds, "scene": _scene_seeds, "camera": _camera_seeds,
         "pattern": _pattern_seeds, "frames": _frames_seeds}


def seeds(name) -> list[bytes]:
    return SEEDS[name]()


def build(out_dir, names=None) -> dict:
    """Write OUT/TARGET/seed-NNN for each target; returns {target: count}."""
    out = {}
    for name in names or sorted(SEEDS):
        d = Path(out_dir) / name
        d.mkdir(parents=True, exist_ok=True)
        data = seeds(name)
        for i, blob in enumerate(data):
            (d / f"seed-{i:03d}").write_bytes(blob)
        out[name] = len(data)
    return out


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    for k, v in build(sys.argv[1], sys.argv[2:]).items():
        print(f"{k}: {v} seeds")
