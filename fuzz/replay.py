"""Replay inputs through a fuzz target without atheris, showing each one's outcome and, for
a finding, its traceback: python -m fuzz.replay TARGET FILE_OR_DIR ..."""
import sys
import traceback
from pathlib import Path

from fuzz import targets


def main(argv):
    if len(argv) < 2 or argv[0] not in targets.TARGETS:
        sys.exit(f"usage: python -m fuzz.replay TARGET FILE_OR_DIR ...; targets: "
                 + ", ".join(targets.names()))
    t, bad = targets.TARGETS[argv[0]], 0
    files = [f for a in argv[1:] for f in (sorted(Path(a).iterdir()) if Path(a).is_dir() else [Path(a)])]
    for f in files:
        data = f.read_bytes()
        try:
            print(f"{f}: {t.run(data)}")
        except Exception:
            bad += 1
            print(f"{f}: FINDING ({data[:120]!r})")
            traceback.print_exc()
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
