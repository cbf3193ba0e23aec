"""The whole command a user waits for: `volrender render ...` run as a process (start-up,
load, build, render, write), default against alternatives, interleaved runs.

    .venv/bin/python bench/whole.py [--repeat 2] [--tag TAG] [--case NAME ...]

Wall time and the process's CPU time (user + sys of the child: on a shared machine it
moves far less with the load than wall time). Writes bench/results/whole_<device>.json.
"""
from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench.common import device_info, result_path, shared_data, write_json  # noqa: E402

BUNNY = str(shared_data() / "points" / "bun_zipper.ply")
CASES = {
    # the glass issue's targets on PoCL (issue 20)
    "bunny-look-good-320x240": [BUNNY, "--radius", "0.002", "--blend", "0.004", "--size", "320x240"],
    "blob100k-preview-160x120": ["blob:100000", "--size", "160x120"],
    # issue 32: the first render a point-cloud user makes, <= 6 s on 2 cores
    "bunny-default-320x240": [BUNNY, "--size", "320x240"],
    # the volumes' default command (issue 33: <= 5 s each, smoke <= 3 s, at 640x480)
    **{f"{short}-default-640x480": [str(shared_data() / "vdb" / f"{stem}.vdb")]
       for short, stem in (("smoke", "smoke"), ("wdas", "wdas_cloud_sixteenth"),
                           ("dragon", "dragon_with_xform"), ("fire0056", "fluid_data_0056"),
                           ("0190", "fluid_data_0190"))},
}
VARIANTS = {"default": [], "tree": ["--accel", "tree"], "grid": ["--accel", "grid"],
            "fast": ["--glass-model", "fast"], "fast-tree": ["--glass-model", "fast", "--accel", "tree"]}


def timed(argv, device, code=None):
    exe = Path(sys.executable).parent / "volrender"
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    env = {**os.environ, **({"VOLRENDER_DEVICE": device} if device else {})}
    if code:
        env["PYTHONPATH"] = os.pathsep.join([code, *filter(None, [os.environ.get("PYTHONPATH")])])
    proc = subprocess.run([str(exe), "render", *argv], capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if proc.returncode:
        raise SystemExit(f"{' '.join(argv)}: {proc.stderr.strip()}")
    lines = proc.stderr.strip().splitlines()
    parts = {}
    for line in lines:                     # -v's "volrender: time: load 0.1 s, cells 2.8 s, ..."
        if line.startswith("volrender: time: "):
            for item in line[len("volrender: time: "):].split(", "):
                name, _, value = item.rpartition(" ")[0].rpartition(" ")
                parts[name] = float(value)
    return wall, cpu, lines[-1], parts


def main(argv=None):
    ap = argparse.ArgumentParser(prog="volrender bench whole", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=2, help="runs of each command (default: 2; the fastest counts)")
    ap.add_argument("--case", action="append", default=None, choices=list(CASES),
                    help="a case to run (repeatable; default: all)")
    ap.add_argument("--variants", default="default,tree,fast,fast-tree",
                    help=f"comma-separated, from {', '.join(VARIANTS)}")
    ap.add_argument("--device", default=None, help="OpenCL device (default: PoCL)")
    ap.add_argument("--tag", default=None, help="added to the results' name: whole_<device>-<tag>.json")
    ap.add_argument("--code", action="append", default=None, metavar="NAME=DIR",
                    help="run the commands with DIR first on PYTHONPATH (a checkout of other "
                         "code: old=/tmp/old), interleaved with the others (repeatable; default: "
                         "this checkout)")
    ap.add_argument("-v", "--verbose", action="store_true",
                    help="run with -v and record its time line (the seconds of each part)")
    args = ap.parse_args(argv)
    from volrender import device
    dev = device.get(args.device)
    rows = []
    out = Path(tempfile.mkdtemp()) / "o.png"
    codes = dict(c.split("=", 1) for c in args.code) if args.code else {"": None}
    verbose = ["-v"] if args.verbose else []
    for case in args.case or list(CASES):
        runs = {(c, v): [] for c in codes for v in args.variants.split(",")}
        for _ in range(args.repeat):
            for c, v in runs:
                runs[c, v].append(timed([*CASES[case], *VARIANTS[v], *verbose, "-o", str(out)],
                                        args.device, codes[c]) + (os.getloadavg()[0],))
        for (c, v), rs in runs.items():
            best = min(rs, key=lambda r: r[0])
            row = {"case": case, "variant": v, "argv": [*CASES[case], *VARIANTS[v]],
                   "wall_s": best[0], "cpu_s": min(r[1] for r in rs),
                   "status": rs[-1][2], "walls_s": [r[0] for r in rs],
                   "loads": [r[4] for r in rs]}
            if c:
                row["code"] = c
            if best[3]:
                row["parts_s"] = best[3]
            rows.append(row)
            print(f"{case:26s} {c:6s} {v:10s} wall {row['wall_s']:6.2f} s  "
                  f"cpu {row['cpu_s']:6.2f} s  "
                  f"{row['status'][:90]}", flush=True)
    path = write_json(result_path("whole", dev, args.tag), {"benchmark": "whole", **device_info(dev),
                                                             "repeat": args.repeat, "codes": codes,
                                                             "rows": rows})
    print(f"wrote {path}")


if __name__ == "__main__":
    sys.exit(main())
