"""A single command's overhead (issue 35; timings are in bench/latency.py, not here): the
fast PNG level stays lossless, and a render to PNG imports only what it uses."""
import json
import os
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image as PILImage

from volrender import image

ROOT = Path(__file__).resolve().parents[1]


def _idat(path) -> bytes:
    """The concatenated IDAT data (one zlib stream) of a PNG."""
    blob, pos, out = Path(path).read_bytes(), 8, b""
    while pos < len(blob):
        n = int.from_bytes(blob[pos:pos + 4], "big")
        if blob[pos + 4:pos + 8] == b"IDAT":
            out += blob[pos + 8:pos + 8 + n]
        pos += 12 + n
    return out


def test_png_at_the_fast_level_decodes_to_the_tone_mapped_codes(tmp_path):
    """Every code of a render-like image (smooth gradients, noise, highlights above 1,
    transparent corners) comes back exactly; the stream is zlib's fastest level."""
    rng = np.random.default_rng(7)
    h, w = 61, 83
    y, x = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
    rgb = np.stack([x, y, x * y], -1) * 3.0 + rng.gamma(0.5, 0.2, (h, w, 3))
    a = np.clip(1.5 - 2 * np.hypot(x - 0.5, y - 0.5), 0, 1)
    rgba = np.concatenate([rgb * a[..., None], a[..., None]], -1).astype(np.float32)
    for alpha in image.PNG_ALPHAS:
        path = image.write_image(tmp_path / f"{alpha}.png", rgba, exposure=-0.5, png_alpha=alpha)
        with PILImage.open(path) as im:
            assert im.format == "PNG" and im.mode == "RGBA"
            got = np.asarray(im)
        want = image.png_pixels(rgba, -0.5, alpha=alpha)
        assert len(np.unique(want[..., :3])) > 200          # not a flat test image
        assert np.array_equal(got, want)
        stream = _idat(path)
        assert stream[1] >> 6 == 0, "FLEVEL 0: zlib level 1 (fastest)"
        assert len(zlib.decompress(stream)) == h * (1 + 4 * w)


def _modules_after(argv, tmp_path, env=None) -> set:
    """The modules a `volrender ARGV` process holds when it exits."""
    out = tmp_path / "modules.json"
    code = ("import atexit, json, sys, runpy\n"
            f"atexit.register(lambda: open({str(out)!r}, 'w').write(json.dumps(sorted(sys.modules))))\n"
            f"sys.argv = ['volrender', *{list(argv)!r}]\n"
            "runpy.run_module('volrender', run_name='__main__', alter_sys=True)\n")
    env = {**os.environ, **(env or {}),
           "PYTHONPATH": os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr
    return set(json.loads(out.read_text()))


UNUSED = ("pyopenvdb", "openvdb", "dask", "distributed", "scipy", "matplotlib", "pyvista",
          "OpenEXR")


def test_a_vdb_render_to_png_imports_only_what_it_uses(tmp_path):
    """OpenVDB reads in its reader process, so the renderer's process does not import it
    (0.1 s); sequences' Dask, plotting and inspection libraries stay out too, and so does
    OpenEXR (40-60 ms), which only EXR files need."""
    from conftest import openvdb_missing
    if openvdb_missing():
        pytest.skip(openvdb_missing())
    mods = _modules_after(["render", str(ROOT / "scenes" / "demo_cloud.vdb"), "--size", "8x6",
                           "--spp", "1", "--no-progress", "-o", str(tmp_path / "o.png")], tmp_path)
    assert (tmp_path / "o.png").is_file() and "PIL" in mods and "pyopencl" in mods
    assert sorted(m for m in mods if m.split(".")[0] in UNUSED) == []

