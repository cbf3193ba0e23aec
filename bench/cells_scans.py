"""The support cells' build with its prefix sums in numpy (host_scans, CPUs' default) against
pyopencl's device scans, each in a fresh process as `volrender render` pays it (the scans'
kernels are made once per process), alternating: the bunny as the default command loads it.

    python bench/cells_scans.py [--size 320x240] [--repeat 3] [--tag TAG]

Wall and CPU seconds of the scene's preparation (tree, cells), the build's own ms and its
kernels' ms, the load average. Writes bench/results/cells_scans_<device>[-TAG].json.
"""
import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench.common import device_info, result_path, shared_data, write_json  # noqa: E402

CHILD = r"""
import functools, json, os, sys, time
from volrender import scene as sm, device, cells
cells.build = functools.partial(cells.build, host_scans=sys.argv[1] == "host")
dev = device.resolve(None)
w, h = (int(v) for v in sys.argv[3].split("x"))
sc = sm.load_scene(sys.argv[2], size=(w, h))
w0, c0 = time.perf_counter(), time.process_time()
p = sc.content.prepare(dev, samples=w * h)
print(json.dumps({"scans": sys.argv[1], "wall_s": time.perf_counter() - w0,
                  "cpu_s": time.process_time() - c0, "build_ms": p.cells.build_ms,
                  "kernel_ms": p.cells.build_kernel_ms, "load": os.getloadavg()[0]}))
"""


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--tag", default=None)
    args = ap.parse_args(argv)
    from volrender import device
    dev = device.resolve(None)
    bunny = str(shared_data() / "points" / "bun_zipper.ply")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    rows = []
    for _ in range(args.repeat):
        for mode in ("host", "device"):
            out = subprocess.run([sys.executable, "-c", CHILD, mode, bunny, args.size], env=env,
                                 capture_output=True, text=True, check=True).stdout
            rows.append(json.loads(out.strip().splitlines()[-1]))
            print(json.dumps(rows[-1]), flush=True)
    path = write_json(result_path("cells_scans", dev, args.tag),
                      {"benchmark": "cells_scans", **device_info(dev), "size": args.size, "rows": rows})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
