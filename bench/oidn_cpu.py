"""Open Image Denoise on this machine's CPU: what a denoised render pays, split into device
creation, filter commit, first and later executions (each configuration in a fresh process,
as `volrender render` pays it), for image sizes and OIDN's qualities, interleaved.

    python bench/oidn_cpu.py [--sizes 320x240,640x480] [--qualities high,balanced,fast]
        [--repeat 2] [--tag TAG]

The colour and albedo are random (OIDN's cost does not depend on the content). Writes
bench/results/oidn_cpu[-TAG].json with the load average beside every run.
"""
import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import RESULTS, git_commit, write_json  # noqa: E402

CHILD = r"""
import json, os, sys, time
import numpy as np
t0 = time.perf_counter()
import pyoidn
from pyoidn.device import Device
from pyoidn.filter import Filter, OIDN_FORMAT_FLOAT3, OIDN_QUALITY_HIGH, OIDN_QUALITY_BALANCED, OIDN_QUALITY_FAST
q = {"high": OIDN_QUALITY_HIGH, "balanced": OIDN_QUALITY_BALANCED, "fast": OIDN_QUALITY_FAST}[sys.argv[3]]
w, h = int(sys.argv[1]), int(sys.argv[2])
rng = np.random.default_rng(0)
c = rng.random((h, w, 3), np.float32); a = rng.random((h, w, 3), np.float32); o = np.empty_like(c)
t = [time.perf_counter()]
d = Device(); d.commit(); t.append(time.perf_counter())
f = Filter(d, "RT")
for n, im in (("color", c), ("albedo", a), ("output", o)):
    f.set_image(n, im, OIDN_FORMAT_FLOAT3)
f.set_bool("hdr", True); f.set_bool("cleanAux", True); f.set_quality(q)
f.commit(); t.append(time.perf_counter())
for _ in range(3):
    f.execute(); t.append(time.perf_counter())
print(json.dumps({"import_s": t[0] - t0, "device_s": t[1] - t[0], "commit_s": t[2] - t[1],
                  "first_s": t[3] - t[2], "later_s": sorted([t[4] - t[3], t[5] - t[4]]),
                  "threads": d.get_int("numThreads")}))
"""


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="320x240,640x480")
    ap.add_argument("--qualities", default="high,balanced,fast")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--tag", default=None)
    args = ap.parse_args(argv)
    rows = []
    for _ in range(args.repeat):
        for size in args.sizes.split(","):
            w, h = size.lower().split("x")
            for q in args.qualities.split(","):
                load = os.getloadavg()[0]
                out = subprocess.run([sys.executable, "-c", CHILD, w, h, q], capture_output=True,
                                     text=True, check=True).stdout
                row = {"size": size, "quality": q, "load": load, **json.loads(out)}
                rows.append(row)
                print(f"{size:8s} {q:9s} load {load:4.1f}  device {row['device_s']:.3f}  commit "
                      f"{row['commit_s']:.3f}  first {row['first_s']:.3f}  later "
                      f"{row['later_s'][0]:.3f} s  ({row['threads']} threads)", flush=True)
    import pyoidn
    from importlib.metadata import version
    path = Path(os.environ.get("VOLRENDER_BENCH_RESULTS") or RESULTS) / \
        f"oidn_cpu{'-' + args.tag if args.tag else ''}.json"
    write_json(path, {"benchmark": "oidn_cpu", "pyoidn": version("pyoidn"), "cpus": os.cpu_count(),
                      "commit": git_commit(), "date": time.strftime("%Y-%m-%dT%H:%M:%S"),
                      "pyoidn_path": str(Path(pyoidn.__file__).parent), "rows": rows})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
