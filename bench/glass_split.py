"""Error against time of the full glass model's branching (issue 32): splitting both
Fresnel branches at every surface event, or only at the first k (--split-events k: past
them one branch goes on, chosen in proportion to its weight, unbiased), crossed with the
roulette threshold of the waiting branches (--roulette).

    .venv/bin/python bench/glass_split.py [--device SPEC] [--size 96x72] [--spp 4,16]
        [--ref-spp 1024] [--repeat 3] [--scenes blob300,molten_glass] [--out TAG]

Reference per scene: every branch traced (split at every event, roulette 0) at --ref-spp
samples per pixel, in 4 batches whose spread gives its own noise (removed from each
setting's mean squared error: rmse_corrected). Every setting is unbiased, so its error is
noise: the pixel footprint (the same for all) plus the branch choices. Time: CPU ms of
the launches / compute units on CPUs (median of --repeat, shuffled rounds: a shared host's
load does not inflate it), kernel ms on GPUs. `efficiency` = 1 / (MSE x time), higher is better: the settings
compare at equal time by it. Writes bench/results/glass_split_<device>[-TAG].json.
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.common import device_info, render_points, result_path, write_json  # noqa: E402
from bench.error import errors, pareto, sweep  # noqa: E402
from volrender import device, generators, glass, scene as scene_mod  # noqa: E402
from volrender.dispatch import is_gpu  # noqa: E402
from volrender.lights import Sun  # noqa: E402

SPLITS = (64, 2, 1, 0)
ROULETTES = (0.0, 0.02, 0.1)


def scenes(width, height, names):
    out = []
    if "blob300" in names:
        cloud = generators.generate("blob", 300, seed=1)
        out.append(("blob300", cloud, glass.default_camera(cloud, width, height),
                    [Sun((-0.5, -1.0, -0.4), 3.0)], glass.GlassSettings()))
    if "molten_glass" in names:
        sc = scene_mod.load_scene(ROOT / "scenes" / "molten_glass.toml", size=(width, height))
        out.append(("molten_glass", sc.content.cloud, sc.camera, list(sc.lights), sc.settings))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("--size", default="96x72")
    ap.add_argument("--spp", default="4,16")
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--scenes", default="blob300,molten_glass")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    w, h = map(int, args.size.split("x"))
    spps = [int(s) for s in args.spp.split(",")]
    dev = device.resolve(args.device)
    cores = dev.device.max_compute_units
    record = {**device_info(dev), "size": [w, h], "ref_spp": args.ref_spp, "scenes": []}
    for name, cloud, cam, lights, base in scenes(w, h, args.scenes.split(",")):
        t0 = time.perf_counter()
        ref_s = replace(base, split_events=64, roulette=0.0)
        batches = [render_points(cloud, cam, lights, replace(ref_s, spp=args.ref_spp // 4,
                                                             seed=100 + b), dev).rgba
                   for b in range(4)]
        ref = np.mean(batches, axis=0).astype(np.float64)
        ref_var = np.var(batches, axis=0, ddof=1) / 4          # variance of the mean
        print(f"[{name}] reference {args.ref_spp} spp in {time.perf_counter() - t0:.0f} s, "
              f"noise rms {np.sqrt(ref_var[..., :3].mean()):.2e}", flush=True)
        rows = [(k, rr, spp) for k in SPLITS for rr in ROULETTES for spp in spps]
        jobs = [(j, (lambda st=replace(base, split_events=k, roulette=rr, spp=spp):
                     render_points(cloud, cam, lights, st, dev)))
                for j, (k, rr, spp) in enumerate(rows)]
        done = sweep(jobs, args.repeat, ("kernel", 1) if is_gpu(dev) else ("cpu", cores))
        out = []
        for j, (k, rr, spp) in enumerate(rows):
            img, t = done[j]
            e = errors(img, ref, ref_var)
            mse = e["rmse_corrected"] ** 2
            row = {"split_events": k, "roulette": rr, "spp": spp, **t, **e,
                   "efficiency": 1.0 / max(mse * t["time_ms"], 1e-30)}
            out.append(row)
            print(f"[{name}] split {k:2d} roulette {rr:<4g} spp {spp:3d}  {t['time_ms']:8.1f} ms"
                  f"  rmse {e['rmse_corrected']:.3e}  1/(mse t) {row['efficiency']:.3g}",
                  flush=True)
        pareto(out, "rmse_corrected")
        record["scenes"].append({"scene": name, "points": len(cloud), "rows": out,
                                 "value_rms": float(np.sqrt((ref[..., :3] ** 2).mean())),
                                 "bench_s": time.perf_counter() - t0})
        path = write_json(result_path("glass_split", dev, args.out), record)   # per scene
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
