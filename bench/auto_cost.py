"""Cost of the march and of a path sample on this device (issue 33, auto's cost model).

    python bench/auto_cost.py [--device SPEC] [--size 160x120] [--repeat 3]

The five real files as `volrender render FILE` loads them (the march as auto resolved it,
multiple scattering or not) and the path estimator at 4 spp: time per pixel (CPU ms of the
launches / compute units on a CPU device, kernel ms on a GPU; median of --repeat), with the
medium's optical size. Writes bench/results/auto_cost_<device>.json; docs/error_time.md
fits volume.AUTO_COST from it and bench/ms_refs.py's GPU run.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import device_info, find_volume, result_path, write_json  # noqa: E402
from volrender import device, scene as scene_mod, volume  # noqa: E402
from volrender.dispatch import is_gpu  # noqa: E402
from volrender.render import render  # noqa: E402
from volrender.scene import VolumeContent  # noqa: E402

FILES = ("smoke", "wdas_cloud_sixteenth", "dragon_with_xform", "fluid_data_0056",
         "fluid_data_0190")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default=None)
    ap.add_argument("--size", default="160x120")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.size.split("x"))
    dev = device.get(args.device)
    gpu = is_gpu(dev)
    cores = int(dev.device.max_compute_units)
    rows = []
    for stem in FILES:
        p = find_volume(stem)
        if p is None:
            continue
        sc = scene_mod.load_scene(p, size=(w, h))
        st = sc.settings

        def timed(s):
            s2 = sc.replace(content=VolumeContent(sc.content.bricks, s, sc.content.store))
            render(s2, dev)
            ts = []
            for _ in range(args.repeat):
                r = render(s2, dev)
                ts.append(r.kernel_ms if gpu else r.cpu_ms / cores)
            return float(np.median(ts)), r.rgba

        t_march, img = timed(st)
        t_path, _ = timed(replace(st, estimator="path", spp=4, seed=3))
        o = volume.optical_size(sc.content.bricks, st)
        row = {"file": stem, "size": [w, h], "estimator": st.estimator, "ms_octaves": st.octaves,
               "tau": o["tau"], "albedo": o["albedo"], "march_ms": t_march,
               "path_ms_per_spp": t_path / 4, "coverage": float((img[..., 3] > 0.05).mean()),
               "lights": len(sc.lights), "env": sc.environment is not None}
        rows.append(row)
        print(row, flush=True)
    out = {"benchmark": "auto_cost", **device_info(dev),
           "time_basis": "kernel ms" if gpu else f"CPU ms / {cores} cores", "rows": rows}
    path = result_path("auto_cost", dev)
    write_json(path, out)
    print("wrote", path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
