"""Run one fuzz target under atheris (libFuzzer): `python fuzz/run.py TARGET [libFuzzer
options and corpus directories]`, e.g.

    python fuzz/run.py ply fuzz/work/corpus/ply fuzz/work/seeds/ply -max_total_time=60

A finding (an exception other than UserError, or a broken property: fuzz/targets.py) makes
libFuzzer save the input as crash-<sha1> under -artifact_prefix and stop;
scripts/fuzz.sh runs campaigns and keeps going after a finding."""
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import atheris  # noqa: E402

from fuzz import targets  # noqa: E402


def main():
    if len(sys.argv) < 2 or sys.argv[1] not in targets.TARGETS:
        sys.exit(f"usage: {sys.argv[0]} TARGET [libFuzzer options] [corpus dirs]; targets: "
                 + ", ".join(targets.names()))
    name = sys.argv[1]
    with atheris.instrument_imports(include=targets.INSTRUMENT[name]):
        import tomllib  # noqa: F401
        import zipfile  # noqa: F401
        import numpy.lib.format  # noqa: F401
        from volrender import camera, points, scene, sequence, vdb  # noqa: F401
    one = targets.TARGETS[name].run
    targets.work_dir()

    def test_one_input(data):
        one(bytes(data))

    sys.argv = [sys.argv[0], *sys.argv[2:]]      # libFuzzer reads the options from sys.argv
    atheris.Setup(sys.argv, test_one_input)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
