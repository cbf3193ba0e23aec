"""The fuzz targets (fuzz/targets.py) in the suite: every seed and every saved finding
(tests/data/fuzz/TARGET/) replayed in-process with a memory bound (tracemalloc, which
numpy's buffers count in), and a short coverage-guided run of every target under atheris
(a few seconds each; skipped where atheris is not importable). Longer campaigns:
scripts/fuzz.sh TARGET SECONDS (docs/fuzzing.md)."""
import importlib.util
import os
import re
import resource
import subprocess
import sys
import tracemalloc

import pytest

from conftest import ROOT

sys.path.insert(0, str(ROOT))
from fuzz import seeds, targets  # noqa: E402

FINDINGS = ROOT / "tests" / "data" / "fuzz"
SHORT_RUN_S = int(os.environ.get("VOLRENDER_FUZZ_SECONDS", "4"))


def _replay(name, data):
    """One input through the target: 'ok' or 'error'; a finding raises. Memory: the
    Python and numpy allocations may peak at 64 MiB plus 64 bytes per input byte."""
    tracemalloc.start()
    try:
        outcome = targets.TARGETS[name].run(data)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < (64 << 20) + 64 * len(data), f"{name}: {peak >> 20} MiB for {len(data)} bytes"
    return outcome


def test_every_target_has_seeds_and_a_seed_that_parses():
    assert set(targets.TARGETS) == set(seeds.SEEDS) == set(targets.INSTRUMENT)
    for name in targets.names():
        outcomes = [_replay(name, s) for s in seeds.seeds(name)]
        assert "ok" in outcomes, name


def _saved():
    if not FINDINGS.is_dir():
        return []
    return [(d.name, f) for d in sorted(FINDINGS.iterdir()) if d.is_dir()
            for f in sorted(d.iterdir())]


@pytest.mark.parametrize("name, path", _saved(), ids=lambda v: v if isinstance(v, str) else v.name)
def test_saved_findings_are_fixed(name, path):
    """Inputs a campaign found (fixed since): each gives a value or one UserError line."""
    assert _replay(name, path.read_bytes()) in ("ok", "error")


# a few findings written out, with what the user sees now
def test_glob_sets_that_are_not_regex_sets():
    from volrender import sequence, sequence_pattern
    for text in ("a[v-9_]z.vdb", "0[]-9].vdb", "x[[a&&b].vdb", "f[!x]?.vdb"):
        p = sequence.parse_pattern(text)
        assert p.glob
        re.compile(sequence_pattern._glob_regex(p.text))


def test_frame_lists_are_bounded_in_total():
    from volrender import sequence
    from volrender.errors import UserError
    with pytest.raises(UserError, match="more than a million"):
        sequence.parse_frames(",".join(f"{k * 10**6}-{k * 10**6 + 999_999}" for k in range(3)))
    with pytest.raises(UserError, match="18 digits"):
        sequence.parse_frames("1" * 5000)                # int() refuses > 4300 digits
    assert sequence.parse_frames("3, 1-2") == [1, 2, 3]


def test_a_bare_npy_is_no_brick_cache_and_is_not_read():
    """np.load reads a bare .npy whole, whatever its header claims (1.2 GiB of RSS for a
    few bytes); a header cut inside raised tokenize.TokenError."""
    head = b"\x93NUMPY\x01\x00v\x00{'descr': '<f8', 'fortran_order': False, 'shape': (100000000000,), }"
    assert _replay("npz", head.ljust(128, b" ") + b"\n") == "error"
    assert _replay("npy", head[:40]) == "error"


def test_ply_element_count_of_thousands_of_digits():
    assert _replay("ply", b"ply\nformat ascii 1.0\nelement vertex " + b"9" * 5000 + b"\n") == "error"


HAVE_ATHERIS = importlib.util.find_spec("atheris") is not None


@pytest.mark.skipif(not HAVE_ATHERIS, reason="atheris is not installed (pip install "
                    "'volrender[test]'); the seeds and saved findings still run above")
@pytest.mark.parametrize("name", targets.names())
def test_a_short_fuzz_run_finds_nothing(name, tmp_path):
    """A few seconds of coverage-guided fuzzing from the seeds (fuzz/run.py): no finding,
    and libFuzzer reports coverage."""
    seed_dir = tmp_path / "seeds"
    seeds.build(seed_dir, [name])
    corpus = tmp_path / "corpus"
    corpus.mkdir()
    # libFuzzer's RSS check reads the peak RSS, and Linux keeps a process's peak across
    # fork and exec: the fuzzer starts at this (pytest) process's peak, so the 4 GB a
    # target may use is counted above it (a CI run whose pytest had reached 4.1 GB saw
    # every target 'oom' at its first input)
    limit = 4096 + resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024
    r = subprocess.run([sys.executable, str(ROOT / "fuzz" / "run.py"), name, str(corpus),
                        str(seed_dir / name), f"-max_total_time={SHORT_RUN_S}", "-timeout=30",
                        f"-rss_limit_mb={limit}", "-max_len=4096",
                        f"-artifact_prefix={tmp_path}/", "-print_final_stats=1"],
                       capture_output=True, text=True, timeout=SHORT_RUN_S + 120, cwd=ROOT)
    found = [p.name for p in tmp_path.iterdir() if p.name.startswith(("crash-", "timeout-", "oom-"))]
    assert r.returncode == 0 and not found, (found, r.stderr[-3000:])
    assert re.search(r"cov: \d+ ft: \d+", r.stderr), r.stderr[-2000:]


def test_toml_nested_too_deep_for_tomllib():
    """tomllib recurses once per '[' or '{': 1000 of them raised RecursionError."""
    for text in (b"a = " + b"[" * 2000, b"a = " + b"{b=" * 1000 + b"1" + b"}" * 1000):
        assert _replay("scene", text) == "error"
        assert _replay("camera", b"[camera]\norigin = " + text[4:]) == "error"


def test_a_huge_scene_file_is_refused_before_it_is_read(tmp_path):
    from volrender import files, scene_file
    from volrender.errors import UserError
    p = tmp_path / "big.toml"
    with open(p, "wb") as f:
        f.truncate(files.MAX_TOML + 1)
    with pytest.raises(UserError, match="a scene file is at most 16 MiB"):
        scene_file.read(p)


def test_npy_format_versions_read_without_numpys_private_header_reader(tmp_path):
    """Versions 1.0, 2.0 and 3.0 load; any other is one error line. The reader once called
    numpy.lib.format._read_array_header for versions other than 1.0 and 2.0, which numpy 2
    removed: a .npy of version 0.1 (a fuzz finding, tests/data/fuzz/npy/) raised
    AttributeError there."""
    import numpy as np
    from volrender.errors import UserError
    from volrender.points import load_points
    a = np.arange(12, dtype=np.float64).reshape(4, 3)
    for v in ((1, 0), (2, 0), (3, 0)):
        p = tmp_path / f"v{v[0]}.npy"
        with open(p, "wb") as f:
            np.lib.format.write_array(f, a, version=v)
        np.testing.assert_array_equal(load_points(p).centers, a)
    bad = tmp_path / "v0.npy"
    bad.write_bytes((tmp_path / "v1.npy").read_bytes().replace(b"NUMPY\x01\x00", b"NUMPY\x00\x01", 1))
    with pytest.raises(UserError, match=r"v0\.npy: not a readable \.npy array \(unknown \.npy format version 0\.1\)"):
        load_points(bad)
