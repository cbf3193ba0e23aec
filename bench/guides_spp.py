"""The denoiser's guides against their cost: the scene as `volrender render FILE` loads it
(defaults), a 1 spp beauty denoised by OIDN (as render.denoised: albedo and normal for glass,
the albedo alone for volumes) with guides of each variant (rays a pixel, and for volumes the
march's step factor and transmittance stop, cl/guide_volume.cl), relative RMSE on the
covered pixels (alpha > 0.05) against 64 spp in 8 batches (the reference's noise removed),
and the guides' and OIDN's seconds. Issues 32 and 33: how light the guides can be.

    python bench/guides_spp.py [--scene bunny|smoke|wdas] [--size 160x120]
        [--variants 4,2,1] [--device SPEC] [--tag TAG]

A variant is SPP[/STEP[/T_STOP]][+EDGE_SPP][:QUALITY]: rays a pixel, the volume march's step
factor and stop, rays again on the glass guide's edge pixels (guides.edges), OIDN's quality
(default high): 4, 1/2, 1/4/0.01:fast, 1+4. Writes bench/results/guides_spp_<device>[-TAG].json.
"""
import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import device_info, result_path, shared_data, write_json  # noqa: E402
from volrender import denoise, device, guides, scene as scene_mod  # noqa: E402
from volrender.render import PLANNERS, render  # noqa: E402

SCENES = {"bunny": "points/bun_zipper.ply", "smoke": "vdb/smoke.vdb",
          "wdas": "vdb/wdas_cloud_sixteenth.vdb"}


def variant(text):
    text, _, quality = text.partition(":")
    text, _, edge = text.partition("+")
    v = [float(x) for x in text.split("/")]
    spp, step, t_stop = (v + [1.0, 1e-4][len(v) - 1:])[:3]
    return {"spp": int(spp), "step": step, "t_stop": t_stop, "edge_spp": int(edge or 0),
            "quality": quality or "high"}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="bunny", choices=list(SCENES))
    ap.add_argument("--size", default="160x120", help="WxH (default 160x120)")
    ap.add_argument("--variants", default="4,2,1",
                    help="comma-separated SPP[/STEP[/T_STOP]][+EDGE_SPP][:QUALITY]")
    ap.add_argument("--seeds", type=int, default=3, help="noisy beauties (default 3)")
    ap.add_argument("--device", default=None, help="OpenCL device (default: PoCL)")
    ap.add_argument("--tag", default=None, help="added to the results' name")
    ap.add_argument("--reference", default=None, metavar="NPZ",
                    help="the 64-spp batches: read from NPZ when it exists, else written there")
    args = ap.parse_args(argv)
    dev = device.resolve(args.device)
    w, h = (int(v) for v in args.size.lower().split("x"))
    sc = scene_mod.load_scene(shared_data() / SCENES[args.scene], size=(w, h))
    t = time.perf_counter()
    if args.reference and Path(args.reference).exists():
        imgs = np.load(args.reference)["batches"]
    else:
        imgs = np.stack([render(sc.replace(spp=8, seed=40_000 + k), dev).rgba.astype(np.float64)
                         for k in range(8)])
        if args.reference:
            np.savez_compressed(args.reference, batches=imgs)
    ref_s = time.perf_counter() - t
    ref, var = imgs.mean(0), imgs.var(0, ddof=1) / 8
    cov = ref[..., 3] > 0.05
    scale = np.sqrt((ref[..., :3][cov] ** 2).mean())

    def rel(p):
        d = (p[..., :3] - ref[..., :3])[cov]
        return float(np.sqrt(max((d ** 2).mean() - var[..., :3][cov].mean(), 0.0)) / scale)

    variants = [variant(v) for v in args.variants.split(",")]
    record = {**device_info(dev), "scene": args.scene, "size": [w, h], "reference_spp": 64,
              "reference_s": ref_s, "covered": float(cov.mean()),
              "reference_noise": float(np.sqrt(var[..., :3][cov].mean()) / scale),
              "load": os.getloadavg()[0], "variants": variants, "rows": []}
    plan = PLANNERS[sc.kind](sc, dev, None, None)
    for seed in range(1, args.seeds + 1):
        img = render(sc.replace(spp=1, seed=seed), dev)
        row = {"seed": seed, "noisy": rel(img.rgba), "variants": []}
        for v in variants:
            if seed == 1:
                guides.render_guides(sc, dev, plan, v["spp"], v["step"], v["t_stop"], v["edge_spp"])
            t0 = time.perf_counter()
            g = guides.render_guides(sc, dev, plan, v["spp"], v["step"], v["t_stop"], v["edge_spp"])
            t1 = time.perf_counter()
            normal = g["normal"] if sc.kind == "glass" else None
            out = denoise.denoise(img.rgba, g["albedo"], normal, v["quality"])
            t2 = time.perf_counter()
            row["variants"].append({**v, "guides_s": t1 - t0, "denoise_s": t2 - t1,
                                    "denoised": rel(out),
                                    "edge_share": float(guides.edges(g["albedo"],
                                                                     g["normal"]).mean())})
        record["rows"].append(row)
        print(json.dumps(row), flush=True)
    summary = []
    for i, v in enumerate(variants):
        e = [r["variants"][i]["denoised"] for r in record["rows"]]
        s = [r["variants"][i]["guides_s"] for r in record["rows"]]
        summary.append({**v, "denoised_mean": float(np.mean(e)),
                        "guides_s_median": float(np.median(s))})
        print(f"{v}: denoised {np.mean(e):.4f}  guides {np.median(s):.3f} s")
    record["summary"] = summary
    record["load_end"] = os.getloadavg()[0]
    out = result_path("guides_spp", dev, args.tag)
    write_json(out, record)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
