"""Faults, round three (issue 38), on real processes: signals at any moment of a run and
of a sequence, nonsense numbers refused before any work, resumed sequences that check
what they find, compressed point clouds bounded like the other parsers, and errors that
name the file at fault. docs/robustness.md says what each rule is."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT

PY = sys.executable
SMALL = ["--size", "16x12", "--no-progress"]
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "POCL_MAX_PTHREAD_COUNT": "1"}


def volrender(*args, cwd, timeout=300, **kw):
    return subprocess.run([PY, "-m", "volrender", *map(str, args)], cwd=cwd, env=ENV,
                          capture_output=True, text=True, timeout=timeout, **kw)


def _one_error(r):
    assert r.returncode == 2, r.stderr
    assert r.stderr.startswith("volrender: error: ") and r.stderr.count("\n") == 1, r.stderr
    return r.stderr


def _frames(folder, n, shape=(12, 10, 8)):
    """n small brick caches c_0001.npz ... (random densities, one seed)."""
    from volrender import vdb
    rng = np.random.default_rng(5)
    for f in range(1, n + 1):
        v = rng.random(shape).astype(np.float32)
        vdb.Bricks.from_dense(v, np.diag([0.1, 0.1, 0.1, 1.0])).save_npz(folder / f"c_{f:04d}.npz")


CAMERA = ["--origin", "0.6,0.5,3", "--target", "0.6,0.5,0.4"]


# ------------------------------------------------------------------ resume checks what it finds

def test_skip_existing_renders_again_a_frame_that_is_cut_short_or_the_wrong_size(tmp_path):
    """A PNG cut short (a copy or a full disk), one of another size and an empty file are
    rendered again and named; a good frame is kept untouched."""
    _frames(tmp_path, 4)
    args = ["render", "c_####.npz", "-o", "f_####.png", "--frames", "1-4", "--workers", "0",
            "--size", "24x18", "--no-progress", *CAMERA]
    r = volrender(*args, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    first = {f: (tmp_path / f"f_{f:04d}.png").read_bytes() for f in range(1, 5)}
    kept = (tmp_path / "f_0001.png").stat().st_mtime_ns
    (tmp_path / "f_0002.png").write_bytes(first[2][:len(first[2]) // 2])
    from PIL import Image
    Image.new("RGB", (8, 6)).save(tmp_path / "f_0003.png")
    (tmp_path / "f_0004.png").write_bytes(b"")
    r = volrender(*args, "--skip-existing", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    for f in (2, 3, 4):
        assert (tmp_path / f"f_{f:04d}.png").read_bytes() == first[f], f
    assert (tmp_path / "f_0001.png").stat().st_mtime_ns == kept
    notes = [line for line in r.stderr.splitlines() if "rendered it again" in line]
    assert len(notes) == 3, r.stderr
    assert "f_0002.png" in notes[0] and "cut short" in notes[0]
    assert "f_0003.png" in notes[1] and "8x6, not 24x18" in notes[1]
    assert "f_0004.png" in notes[2]
    assert "wrote 3 frames (1 skipped" in r.stderr, r.stderr
    rec = json.loads((tmp_path / "f.sequence.json").read_text())
    assert [fr.get("redone") is not None for fr in rec["frames"]] == [False, True, True, True]


def test_an_existing_output_is_checked_whole_for_each_format(tmp_path):
    """image.unusable: each format read whole, and its size (the rule --skip-existing uses)."""
    from volrender.image import unusable, write_image
    rgba = np.random.default_rng(1).random((6, 8, 4)).astype(np.float32)
    for suffix in (".png", ".exr", ".npy"):
        p = write_image(tmp_path / f"a{suffix}", rgba)
        assert unusable(p, (8, 6)) is None, suffix
        assert unusable(p, (8, 7)) == "it is 8x6, not 8x7", suffix
        whole = p.read_bytes()
        for cut in (len(whole) - 1, len(whole) // 2, 10):
            p.write_bytes(whole[:cut])
            assert unusable(p, (8, 6)) is not None, (suffix, cut)
