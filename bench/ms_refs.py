"""Path-traced references for issue 33: the octave bands' calibration and auto's model.

    python bench/ms_refs.py prepare DIR [--size 640x480]    # here: the five real files as
        `volrender render FILE` loads them, saved as DIR/<stem>.npz + DIR/<stem>.pkl
    python bench/ms_refs.py run DIR OUT [--device SPEC] [--ref-spp N] [--synthetic-only]

`run` (any device; meant for a GPU) renders, and writes OUT/ms_refs.json (+ OUT/*.npy):
* synthetic media (volrender.media: lumpy ball, two blobs) over optical depth, albedo and
  phase, lit by a sun alone (--env 0) or by a uniform sky alone, 64x64: the path
  estimator at --synthetic-spp (the reference), and the march with 4 octave bands at the
  light gain G = 0 and G = 1 (the image is linear in G: L(G) = L0 + G (L1 - L0)), from
  which the best G per medium follows in closed form (least squares on covered pixels,
  reference alpha > 0.05);
* the real files' default scenes (from `prepare`): the path reference (--ref-spp in 8
  batches), the default march and the path estimator at 1..64 spp with their kernel
  times, and G0/G1 as above.
Errors: relative RMSE (reference noise removed) and mean ratio, on covered pixels and on
the whole image.
"""
from __future__ import annotations

import argparse
import json
import pickle
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from volrender import device, media, scene as scene_mod, volume  # noqa: E402
from volrender.camera import Camera  # noqa: E402
from volrender.lights import Sun  # noqa: E402
from volrender.render import render  # noqa: E402
from volrender.scene import Scene, VolumeContent  # noqa: E402
from volrender.volume import VolumeSettings  # noqa: E402

FILES = ("smoke", "wdas_cloud_sixteenth", "dragon_with_xform", "fluid_data_0056",
         "fluid_data_0190")
COVERED = 0.05
SUN = Sun((-0.6, -1.0, -0.5), 1.0)
SKY = (1.0, 1.0, 1.0)
CAM = Camera((0.9, 0.5, 2.2), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 32.0, 64, 64)


def covered(ref, emits=False):
    """The pixels with content: reference alpha > COVERED; for an emitting medium (thin
    fire has almost no alpha) also where the reference is brighter than COVERED of its
    99th-percentile luminance."""
    cov = ref[..., 3] > COVERED
    if emits:
        y = ref[..., :3] @ np.array([0.2126, 0.7152, 0.0722])
        cov |= y > COVERED * np.percentile(y, 99)
    return cov


def compare(img, ref, var, emits=False) -> dict:
    """Relative RMSE (reference noise removed) and mean ratio, covered pixels and all."""
    out = {}
    cov = covered(ref, emits)
    for key, m in (("covered", cov), ("image", np.ones_like(cov))):
        if not m.any():
            continue
        d = img[..., :3][m] - ref[..., :3][m]
        mse = max(float((d ** 2).mean()) - float(var[..., :3][m].mean()), 0.0)
        rms = float(np.sqrt((ref[..., :3][m] ** 2).mean()))
        out[key] = {"rel_rmse": mse ** 0.5 / max(rms, 1e-30),
                    "mean_ratio": float(img[..., :3][m].mean() / max(ref[..., :3][m].mean(), 1e-30)),
                    "fraction": float(m.mean())}
    return out


def best_gain(l0, l1, ref) -> float:
    """The G minimising |L0 + G (L1 - L0) - ref|^2 on covered pixels."""
    m = ref[..., 3] > COVERED
    a = (l1 - l0)[..., :3][m].ravel()
    b = (ref - l0)[..., :3][m].ravel()
    return float(a @ b / max(a @ a, 1e-30))


def reference(scene, spp, batches, dev):
    imgs, ms = [], 0.0
    for k in range(batches):
        r = render(scene.replace(content=VolumeContent(scene.content.bricks, replace(
            scene.content.settings, estimator="path", spp=spp, seed=50_000 + k))), dev)
        imgs.append(r.rgba.astype(np.float64))
        ms += r.kernel_ms
    imgs = np.stack(imgs)
    return imgs.mean(0), imgs.var(0, ddof=1) / batches, ms


def with_settings(scene, **kw):
    return scene.replace(content=VolumeContent(scene.content.bricks,
                                               replace(scene.content.settings, **kw)))


def gains(scene, ref, var, dev, spp):
    """G0/G1 renders (4 bands), the best gain and the errors at it and at the default."""
    st = scene.content.settings
    d, g_default, c = volume.octave_scales(st, scene.content.bricks)
    imgs = [render(with_settings(scene, estimator="march", ms_octaves=4,
                                 ms_octave_scales=(d, g, c), spp=spp, seed=9), dev).rgba
            .astype(np.float64) for g in (0.0, 1.0)]
    g = best_gain(imgs[0], imgs[1], ref)
    at = lambda gg: imgs[0] + gg * (imgs[1] - imgs[0])            # noqa: E731
    return {"best_gain": g, "gain": g_default, "at_best": compare(at(g), ref, var),
            "at_default": compare(at(g_default), ref, var),
            "single": compare(imgs[0], ref, var) if not st.env else None}


def synthetic(dev, args, out):
    rows = []
    shapes = {"lumpy_ball": media.lumpy_ball(24), "two_blobs": media.two_blobs(32)}
    phases = {"iso": (0.0,), "default": VolumeSettings().phase, "forward": (0.8,)}
    for shape, b in shapes.items():
        for light in ("sun", "sky"):
            for tau in args.taus:
                for alb in args.albedos:
                    for pname, ph in phases.items():
                        t0 = time.perf_counter()
                        st = VolumeSettings(density_scale=tau, albedo=(alb,), phase=ph,
                                            env=(0.0,) if light == "sun" else SKY)
                        scene = Scene.of(CAM, [SUN] if light == "sun" else [],
                                         VolumeContent(b, st))
                        ref, var, ms = reference(scene, args.synthetic_spp, 4, dev)
                        o = volume.optical_size(b, st)
                        row = {"shape": shape, "light": light, "density_scale": tau,
                               "tau": o["tau"], "albedo": alb, "phase": list(ph),
                               "g_mean": volume.mean_cosine(st), "ref_kernel_ms": ms,
                               "ref_mean_covered": float(ref[..., :3][ref[..., 3] > COVERED].mean()),
                               **gains(scene, ref, var, dev, 16)}
                        row["s"] = time.perf_counter() - t0
                        rows.append(row)
                        print(f"{shape} {light} tau {o['tau']:.3g} a {alb} {pname}: G* "
                              f"{row['best_gain']:.3f}, default {row['at_default']['covered']}",
                              flush=True)
    out["synthetic"] = rows


def files(dev, args, out, spec):
    out["files"] = []
    for stem in FILES:
        pk = spec / f"{stem}.pkl"
        if not pk.exists():
            continue
        with open(pk, "rb") as f:
            d = pickle.load(f)
        from volrender import vdb
        b = vdb.load_npz(spec / f"{stem}.npz")
        scene = Scene.of(d["camera"], d["lights"], VolumeContent(b, d["settings"]),
                         d["environment"])
        t0 = time.perf_counter()
        ref, var, ms = reference(scene, args.ref_spp, 8, dev)
        np.save(Path(args.out) / f"ref_{stem}.npy", ref.astype(np.float32))
        np.save(Path(args.out) / f"var_{stem}.npy", var.astype(np.float32))
        row = {"file": stem, "size": [scene.camera.width, scene.camera.height],
               "ref_spp": args.ref_spp * 8, "ref_kernel_ms": ms,
               "settings": {"estimator": d["settings"].estimator,
                            "ms_octaves": d["settings"].octaves},
               "covered_fraction": float(covered(ref, b.emission is not None).mean()),
               "rows": []}
        jobs = [("default", with_settings(scene))]
        jobs += [(f"path {n} spp", with_settings(scene, estimator="path", spp=n, seed=7 + n))
                 for n in (1, 4, 16, 64)]
        jobs += [("single", with_settings(scene, estimator="march", ms_octaves=1))]
        for label, sc in jobs:
            render(sc, dev)                                # warm-up / build
            ts, img = [], None
            for _ in range(3):
                r = render(sc, dev)
                ts.append(r.kernel_ms)
                img = r.rgba.astype(np.float64)
            row["rows"].append({"label": label, "kernel_ms": float(np.median(ts)),
                                **compare(img, ref, var, b.emission is not None)})
            print(f"[{stem}] {label}: {np.median(ts):.1f} ms {row['rows'][-1]}", flush=True)
        if d["settings"].estimator == "march" and d["settings"].octaves > 1:
            row["gain"] = gains(scene, ref, var, dev, 1)
        row["s"] = time.perf_counter() - t0
        out["files"].append(row)


def prepare(spec: Path, size):
    spec.mkdir(parents=True, exist_ok=True)
    from bench.common import find_volume
    for stem in FILES:
        p = find_volume(stem)
        if p is None:
            print(f"{stem}: not found, skipped")
            continue
        sc = scene_mod.load_scene(p, size=size)
        sc.content.bricks.save_npz(spec / f"{stem}.npz")
        with open(spec / f"{stem}.pkl", "wb") as f:
            pickle.dump({"camera": sc.camera, "lights": sc.lights, "settings": sc.settings,
                         "environment": sc.environment, "notes": sc.notes}, f)
        print(stem, sc.settings.estimator, sc.settings.octaves, sc.notes)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("mode", choices=["prepare", "run"])
    ap.add_argument("spec")
    ap.add_argument("out", nargs="?")
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--device", default=None)
    ap.add_argument("--ref-spp", type=int, default=128, help="per batch, 8 batches")
    ap.add_argument("--synthetic-spp", type=int, default=256, help="per batch, 4 batches")
    ap.add_argument("--synthetic-only", action="store_true")
    ap.add_argument("--files-only", action="store_true")
    ap.add_argument("--taus", default="0.5,2,8,32")
    ap.add_argument("--albedos", default="0.5,0.8,0.95,0.99")
    args = ap.parse_args(argv)
    args.taus = [float(v) for v in args.taus.split(",")]
    args.albedos = [float(v) for v in args.albedos.split(",")]
    if args.mode == "prepare":
        prepare(Path(args.spec), tuple(int(v) for v in args.size.split("x")))
        return 0
    dev = device.get(args.device)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    out = {"device": dev.device.name.strip(), "platform": dev.device.platform.name.strip()}
    t0 = time.perf_counter()
    if not args.files_only:
        synthetic(dev, args, out)
        Path(args.out, "ms_refs.json").write_text(json.dumps(out, indent=1))
    if not args.synthetic_only:
        files(dev, args, out, Path(args.spec))
    out["s"] = time.perf_counter() - t0
    Path(args.out, "ms_refs.json").write_text(json.dumps(out, indent=1))
    print(f"done in {out['s']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
