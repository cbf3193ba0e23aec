"""Glass kernel time and the field's work counters for issue 32's targets: sphere counts
and the bunny (its look-good settings: radius 0.002, blend 0.004), at each bounce count,
for glass models full, fast and full:K (--split-events K), one sun, support cells,
fragment dispatch. Uses only bench/spheres.py's measure() and the public settings, so the
same file runs against an older checkout (a model full:K is skipped where the settings
have no split_events) for a before/after in one run.

    python3 bench/glass_speed.py --device nvidia --size 1920x1080 --bounces 2,6 \\
        --cases 3000,1000000,bunny --models full,fast,full:1 [--relax 1.3,1.6] [--repeat 3] \\
        [--out FILE]

Writes FILE (default bench/results/glass_speed_<device>.json) with the device and commit.
"""
from __future__ import annotations

import argparse
import dataclasses
import itertools
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import device_info, result_path, write_json  # noqa: E402
from bench.spheres import SCAN_SUN, SUN, measure, scan_path  # noqa: E402
from volrender import device, glass, points  # noqa: E402
try:                                   # the layout after issue 36
    from volrender.generators import generate  # noqa: E402
except ImportError:                    # an older checkout
    generate = points.generate

BUNNY = ("bun_zipper.ply", {"radius": 0.002, "blend": 0.004})


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--bounces", default="2,6")
    ap.add_argument("--cases", default="3000,1000000,bunny")
    ap.add_argument("--models", default="full,fast")
    ap.add_argument("--relax", default="",
                    help="over-relaxation factors to sweep, comma-separated (default: the "
                         "settings' default only)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--label", default="")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    w, h = map(int, args.size.split("x"))
    dev = device.resolve(args.device)
    fields = {f.name for f in dataclasses.fields(glass.GlassSettings)}
    record = {**device_info(dev), "label": args.label, "size": [w, h], "rows": []}
    out = Path(args.out) if args.out else result_path("glass_speed", dev)
    relaxes = [float(x) for x in args.relax.split(",")] if args.relax else [None]
    for case in args.cases.split(","):
        if case == "bunny":
            src = scan_path(BUNNY[0])
            if src is None:
                print("bunny: bun_zipper.ply not found; skipped")
                continue
            cloud, opts, lights = points.load_points(src), dict(BUNNY[1]), [SCAN_SUN]
        else:
            cloud, opts, lights = generate("blob", int(case), seed=1), {}, [SUN]
        cam = glass.default_camera(cloud, w, h, radius=opts.get("radius"))
        for bounces in map(int, args.bounces.split(",")):
            for model, relax in itertools.product(args.models.split(","), relaxes):
                name, _, k = model.partition(":")
                kw = dict(opts, bounces=bounces, accel="grid", dispatch="fragment",
                          glass_model=name)
                if k:
                    if "split_events" not in fields:
                        continue
                    kw["split_events"] = int(k)
                if relax is not None:
                    kw["relax"] = relax
                t0 = time.perf_counter()
                settings = glass.GlassSettings(**kw)
                _, t = measure(cloud, cam, settings, dev, args.repeat, lights)
                row = {"case": case, "bounces": bounces, "model": model,
                       "relax": settings.relax, **t, "bench_s": time.perf_counter() - t0}
                record["rows"].append(row)
                wk = row["work"]
                print(f"{args.label:>6} {case:>8} b{bounces} {model:7s} w{settings.relax:g} kernel "
                      f"{t['kernel_ms']['median']:9.2f} ms  evals {wk['evals_mean']:.1f} "
                      f"(p99 {wk['evals_p99']:.0f})  tests/eval {wk['nodes_per_eval']:.1f}+"
                      f"{wk['spheres_per_eval']:.0f}  simd {wk['simd_efficiency']:.2f}",
                      flush=True)
                write_json(out, record)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
