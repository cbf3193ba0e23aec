"""Random damage to real .vdb files, read through OpenVDB (vdb.load_bricks: the brick
reader, in its reader process): every outcome must be Bricks or one UserError line; the
counts say how often OpenVDB itself died. Not coverage-guided (atheris cannot see into
OpenVDB's C++, which OSS-Fuzz fuzzes); a few inputs a second, since every error starts a
fresh reader.

    python -m fuzz.openvdb_sweep N [FILE.vdb ...]     # default: scenes/demo_cloud.vdb
"""
import random
import sys
import tempfile
import warnings
from collections import Counter
from pathlib import Path

from fuzz import targets
from fuzz.seeds import ROOT


def sweep(n, files, seed=0):
    from volrender import vdb
    from volrender.errors import UserError
    rng = random.Random(seed)
    counts, examples = Counter(), {}
    datas = [Path(f).read_bytes() for f in files]
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "m.vdb"
        for i in range(n):
            b = bytearray(rng.choice(datas))
            for _ in range(rng.randint(1, 8)):
                b[rng.randrange(len(b))] = rng.randrange(256)
            p.write_bytes(b)
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    targets._check_bricks(vdb.load_bricks(p))
                kind = "bricks"
            except UserError as exc:
                targets._check_message(exc)
                text = str(exc)
                kind = ("reader died: " + text.split("ended with ")[1].split(":")[0].split(")")[0]
                        if "reader process ended" in text else "UserError")
            counts[kind] += 1
            examples.setdefault(kind, i)
    return counts


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 100
    files = sys.argv[2:] or [ROOT / "scenes" / "demo_cloud.vdb"]
    for k, v in sorted(sweep(n, files).items()):
        print(f"{k}: {v}")
