"""The denoiser's guides at 4, 2 and 1 camera rays a pixel (denoise.GUIDE_SPP is 4): the bunny
as `volrender render bun_zipper.ply` loads it (full model, defaults), 160x120, 1 spp beauty
denoised by OIDN with each, relative RMSE on the covered pixels against 64 spp in 8 batches
(the reference's noise removed), and the guides' seconds. Issue 32: whether a lighter
guide pass on CPUs is worth its error.

    python bench/guides_spp.py [--device SPEC] [--out FILE]
"""
import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import device_info, result_path, shared_data, write_json  # noqa: E402
from volrender import denoise, device, guides, scene as scene_mod  # noqa: E402
from volrender.render import PLANNERS, render  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None, help="OpenCL device (default: PoCL)")
    ap.add_argument("--out", default=None, help="JSON path (default: bench/results/guides_spp_<device>.json)")
    args = ap.parse_args(argv)
    dev = device.resolve(args.device)
    sc = scene_mod.load_scene(shared_data() / "points" / "bun_zipper.ply", size=(160, 120))
    imgs = np.stack([render(sc.replace(spp=8, seed=40_000 + k), dev).rgba.astype(np.float64)
                     for k in range(8)])
    ref, var = imgs.mean(0), imgs.var(0, ddof=1) / 8
    cov = ref[..., 3] > 0.05
    scale = np.sqrt((ref[..., :3][cov] ** 2).mean())

    def rel(p):
        d = (p[..., :3] - ref[..., :3])[cov]
        return float(np.sqrt(max((d ** 2).mean() - var[..., :3][cov].mean(), 0.0)) / scale)

    record = {**device_info(dev), "size": [160, 120], "reference_spp": 64,
              "reference_noise": float(np.sqrt(var[..., :3][cov].mean()) / scale), "rows": []}
    plan = PLANNERS[sc.kind](sc, dev, None, None)
    for seed in (1, 2, 3):
        img = render(sc.replace(spp=1, seed=seed), dev)
        row = {"seed": seed, "noisy": rel(img.rgba), "guides": {}}
        for gs in (4, 2, 1):
            t = time.perf_counter()
            g = guides.render_guides(sc, dev, plan, spp=gs)
            row["guides"][gs] = {"seconds": time.perf_counter() - t,
                                 "denoised": rel(denoise.denoise(img.rgba, g["albedo"], g["normal"]))}
        record["rows"].append(row)
        print(json.dumps(row), flush=True)
    out = Path(args.out) if args.out else result_path("guides_spp", dev)
    write_json(out, record)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
