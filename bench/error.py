"""Error against run time for every speed knob, against a converged reference.

    .venv/bin/python bench/error.py [--device SPEC] [--size 160x120] [--repeat 5]
        [--quick] [--out TAG] [--time kernel|cpu] [--no-glass] [--no-volume]
        [--no-ms] [--ms-size 96x72] [--ms-ref-spp N] [--fit-octaves]

Multiple scattering (issue #12; --no-ms leaves it out): on scenes/demo_cloud.vdb (the
`run.sh demo` look: a white cloud, sun and blue sky), smoke.vdb and
wdas_cloud_sixteenth.vdb, at --ms-size, against the path estimator (--estimator path,
default depth) with --ms-ref-spp x 16 samples per pixel in 16 batches (unbiased, so its
error is its noise; rmse_corrected removes it). Rows: the path estimator at 1..256 spp,
with the time it takes to reach 5%, 2% and 1% relative RMSE (interpolated log-log
between the measured points, or extrapolated as 1/sqrt(spp) past the last); the
marcher's octave approximation (--ms-octaves 1..8, default scales, 4 spp) and its error
against the path-traced image (1 octave: the error of single scattering itself). With
--fit-octaves, a grid over the octave scales (a, b, c) and counts, on all three scenes at
once (the sum of their relative mean squared errors), which chose the defaults.

Defaults (issue #22; --defaults, or --defaults-only): the five real files as `volrender
render FILE` sees them (scene.load_scene: the default sun and sky, estimator auto, fire for
the Mantaflow cache) at --defaults-size, against the path estimator with the same lights
and settings (--defaults-ref-spp x 8 batches). Rows: the default (auto), single scattering
(the march with 1 octave), the octave bands at 2, 4 and 8, the path estimator in passes
to a noise target (--noise-target 0.1 and 0.05, volume.render_adaptive) and, where pyoidn
imports, the path estimator at 4 and 16 spp denoised by OIDN (colour only). Errors:
relative RMSE per pixel and after a 2x2 box (the reference's noise removed), image-mean
ratio; time: CPU ms / cores (median of --repeat). WDAS also at 320x240 for the issue's
target (mean within 10%, 2x2 relative RMSE <= 15%, <= 3x single scattering's time).

Denoising (issue 34; --denoise, or --denoise-only): WDAS and smoke as `volrender render FILE
--estimator path` loads them, at --denoise-size, and the bunny as glass (bun_zipper.ply, at
--denoise-glass-size on CPUs), against path at --denoise-ref-spp (glass:
--denoise-glass-ref-spp) in 8 batches: the path estimator at 1..256 spp as rendered, denoised
(render(..., denoise="on"): the guides and OIDN) and denoised from the colour alone; relative
RMSE on the covered pixels (reference alpha > 0.05), the reference's noise removed; the time
to 5 % with and without the denoiser (the issue's target: x8).

Volumes (scenes/demo_cloud.vdb with the `run.sh demo` look, and smoke.vdb from
../shared/data/vdb when present): marching step (2, 1, 0.5, 0.25 voxels), shadow step
(4, 2, 1, 0.5), samples per pixel (1, 4, 16), a small grid of combinations, and the
tracking estimator (1..64 spp, and at the run time of each marching spp setting).

Reference: the tracking estimator (cl/track_volume.cl) with many samples per pixel, in
independent batches. It is unbiased, so its only error is noise, which the batches
measure: the JSON gives its per-pixel standard error, and `rmse_corrected` removes the
reference's own variance from each setting's mean squared error (the two are
independent: different seeds). Fine marching (0.05 voxel) would be biased by its step
and costs ~100x the default march per sample, where a tracking sample costs 1/10 to 1/40
of one on these scenes (PoCL).
All settings are measured against the box-filtered pixel (what many spp converge
to): a 1-spp image samples the pixel centre, so its error includes that footprint
difference, which only more samples remove.

Glass (volrender.glass): epsilon (1e-2..1e-5), max_steps (32..512), bounces (1..8), relax
swept one at a time from the defaults (1e-4, 256, 6, relax 1.6), plus presets, and (first scene)
each knob alone with the other two at the reference values, against epsilon 1e-6,
max_steps 4096, bounces 12 with brute force (use_tree=False); deterministic (one sample
at the pixel centre), so the reference has no noise. Scenes: blob:300 (seed 1) and
scenes/molten_glass.toml.

Per setting: kernel ms (median of --repeat runs after a warm-up; the runs of all
settings of a scene are interleaved, in a shuffled order per round), RMSE over the RGB
values, max |error|, bias (mean signed error), RMSE of alpha. With `--time cpu` the
time axis is the CPU time the launches consumed divided by the device's compute units
(also a median), which other processes on a shared CPU host do not inflate; the
profiling kernel ms are recorded either way. Writes
bench/results/error_<tag>.json and error_<tag>.png (log-log error vs time, Pareto front
marked: no other setting is both faster and more accurate).
"""
from __future__ import annotations

import argparse
import os
import random
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import (render_points, render_volume, result_path, device_info, find_volume, missing_data,  # noqa: E402
                          shared_data, stats, write_json)
from volrender import camera, denoise, device, generators, glass, scene as scene_mod, vdb  # noqa: E402
from volrender.lights import Sun  # noqa: E402
from volrender.volume import VolumeSettings, octave_scales  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
GLASS_SUN = Sun((-0.5, -1.0, -0.4), 3.0)
# the `run.sh demo` medium (its sky: DEMO_ENV; the single-scattering section keeps its
# own background look, which it always had)
DEMO_LOOK = dict(density_scale=6.0, albedo=0.98)
GLASS_REF = dict(epsilon=1e-6, max_steps=4096, bounces=12, relax=1.0, use_tree=False)


# --------------------------------------------------------------------------- metrics

COVERED = 0.05       # covered pixels: reference alpha above this (issue 33)


def covered(ref, emits=False):
    """The pixels with content: reference alpha > COVERED; for an emitting medium (thin
    fire has almost no alpha) also where the reference is brighter than COVERED of its
    99th-percentile luminance."""
    cov = np.asarray(ref)[..., 3] > COVERED
    if emits:
        y = np.asarray(ref)[..., :3] @ np.array([0.2126, 0.7152, 0.0722])
        cov |= y > COVERED * np.percentile(y, 99)
    return cov


def covered_errors(img, ref, var=None, emits=False) -> dict:
    """Relative RMSE (the reference's noise removed when var is given) and mean ratio on
    the covered pixels, with their fraction of the image (issue 33: error is reported
    where the content is, beside the whole image)."""
    cov = covered(ref, emits)
    if not cov.any():
        return {"covered_fraction": 0.0}
    d = img[..., :3][cov].astype(np.float64) - ref[..., :3][cov]
    mse = float((d ** 2).mean()) - (float(var[..., :3][cov].mean()) if var is not None else 0.0)
    rms = float(np.sqrt((ref[..., :3][cov] ** 2).mean()))
    return {"covered_fraction": float(cov.mean()),
            "covered_rel_rmse": max(mse, 0.0) ** 0.5 / max(rms, 1e-30),
            "covered_mean_ratio": float(img[..., :3][cov].mean() / max(ref[..., :3][cov].mean(), 1e-30))}


def errors(img, ref, ref_var=None) -> dict:
    """Error of an RGBA image against a reference (RGB: radiance, A: alpha), over the whole
    image and on covered pixels (covered_errors)."""
    d = img[..., :3].astype(np.float64) - ref[..., :3]
    mse = float((d ** 2).mean())
    out = {"rmse": mse ** 0.5, "max_abs": float(np.abs(d).max()), "bias": float(d.mean()),
           "alpha_rmse": float(np.sqrt(((img[..., 3].astype(np.float64) - ref[..., 3]) ** 2).mean())),
           "rel_rmse": mse ** 0.5 / max(float(np.sqrt((ref[..., :3] ** 2).mean())), 1e-30)}
    if ref_var is not None:
        # E[mse] = true mse + mean reference variance (independent noise)
        out["rmse_corrected"] = max(mse - float(ref_var[..., :3].mean()), 0.0) ** 0.5
    out.update(covered_errors(img, ref, ref_var))
    return out


def pareto(rows, key="rmse"):
    """Mark rows no other row beats in both kernel time and error."""
    pts = [(r["time_ms"], r[key]) for r in rows]
    for r, (t, e) in zip(rows, pts):
        r["pareto"] = not any((t2 <= t and e2 <= e) and (t2 < t or e2 < e) for t2, e2 in pts)


# Each render reports the CPU time of this process (all threads: PoCL's workers run in it)
# during its launches (render.Image.cpu_ms). On a shared CPU host, other processes stretch
# the kernels' wall time (the OpenCL profiling times) but not the CPU time they consume,
# so cpu_ms / cores is a contention-free stand-in for the kernel time (--time cpu).


def sweep(jobs, repeat, basis):
    """Image and timing of every (key, render) job. One pass renders each job once (the
    warm-up and program build; the image, deterministic per seed); then `repeat` rounds
    time every job, in a shuffled order per round, so that load from other processes
    spreads over all settings instead of landing on a few. `time_ms`: median kernel ms
    (basis 'kernel') or median CPU ms / compute units (basis 'cpu')."""
    out = {}
    for key, render in jobs:
        out[key] = {"rgba": render().rgba, "kernel": [], "wall": [], "cpu": []}
    order = list(jobs)
    rng = random.Random(1)
    for _ in range(repeat):
        rng.shuffle(order)
        for key, render in order:
            r = render()
            o = out[key]
            o["kernel"].append(r.kernel_ms)
            o["wall"].append(r.wall_ms)
            o["cpu"].append(r.cpu_ms)
    result = {}
    for key, o in out.items():
        t = {"kernel_ms": stats(o["kernel"]), "wall_ms": stats(o["wall"])}
        if o["cpu"]:
            t["cpu_ms"] = stats(o["cpu"])
        t["time_ms"] = (t["cpu_ms"]["median"] / basis[1] if basis[0] == "cpu" and o["cpu"]
                        else t["kernel_ms"]["median"])
        result[key] = (o["rgba"], t)
    return result


# --------------------------------------------------------------------------- volumes

def _has_openvdb() -> bool:
    """The GPU machine has no OpenVDB: there the .npz conversions in bench/data are read."""
    try:
        vdb.import_openvdb()
        return True
    except Exception:
        return False


def volume_scenes(width, height):
    """[(name, bricks, camera, lights, base settings, reference spp per batch)]; smoke
    only when present. Reference spp: enough for a standard error well below the
    smallest errors measured (smoke is ~2x costlier per sample, and less noisy)."""
    out = []
    demo = next(p for p in (ROOT / "scenes" / "demo_cloud.vdb", ROOT / "bench" / "data" / "demo_cloud.npz")
                if p.exists() and (p.suffix == ".npz" or _has_openvdb()))
    b = vdb.load_volume(demo)                                      # the `run.sh demo` look
    out.append(("demo_cloud", b, camera.frame_bounds(*b.world_bounds(), width, height, fov=28.0),
                [Sun((-0.6, -1.0, -0.5), 10.0)],
                VolumeSettings(density_scale=6.0, background=(0.32, 0.42, 0.58), estimator="march"),
                2048))
    smoke = find_volume("smoke", _has_openvdb)
    if smoke is None:
        print(f"bench/error.py: {missing_data('smoke.vdb')}; measuring the demo cloud only",
              flush=True)
    else:
        b = vdb.load_volume(smoke)                                 # bench/volume.py's settings
        out.append(("smoke", b, camera.frame_bounds(*b.world_bounds(), width, height),
                    [Sun((-0.6, -1.0, -0.5), 6.0)], VolumeSettings(density_scale=1.0, estimator="march"),
                    1024))
    return out


def volume_settings(quick):
    """[(group, label, overrides)] of the sweep (tracking at matched time comes later)."""
    rows = []
    steps, shadows, spps = ((2, 0.5), (4, 1), (1, 4)) if quick else \
        ((2, 1, 0.5, 0.25), (4, 2, 1, 0.5), (1, 4, 16))
    for h in steps:
        rows.append(("step", f"step {h}", dict(step=h)))
    for h in shadows:
        rows.append(("shadow_step", f"shadow {h}", dict(shadow_step=h)))
    for n in spps:
        rows.append(("spp", f"{n} spp", dict(spp=n)))
    if not quick:
        for h, sh, n in ((2, 4, 1), (2, 4, 4), (1, 2, 1), (1, 2, 4), (2, 2, 4), (1, 1, 4),
                         (1, 2, 16), (2, 4, 16)):
            rows.append(("combined", f"step {h}, shadow {sh}, {n} spp",
                         dict(step=h, shadow_step=sh, spp=n)))
    for n in ((1, 4) if quick else (1, 4, 16, 64)):
        rows.append(("track", f"track {n} spp", dict(estimator="track", spp=n)))
    return rows


def describe_volume(s: VolumeSettings) -> dict:
    d = {"estimator": s.estimator, "spp": s.spp, "seed": s.seed}
    if s.estimator == "march":
        d.update(step=s.step, shadow_step=s.shadow_step)
    return d


def volume_reference(dev, b, cam, lights, base, batches, spp):
    """Tracking with batches x spp samples: (mean image, per-pixel variance of the mean,
    summary)."""
    imgs, ms = [], 0.0
    for k in range(batches):
        r = render_volume(b, cam, lights, replace(base, estimator="track", spp=spp, seed=10_000 + k),
                          dev)
        imgs.append(r.rgba.astype(np.float64))
        ms += r.kernel_ms
    imgs = np.stack(imgs)
    ref = imgs.mean(0)
    var = imgs.var(0, ddof=1) / batches
    se = np.sqrt(var[..., :3])
    summary = {"estimator": "track", "spp": batches * spp, "batches": batches,
               "kernel_ms_total": ms, "se_rms": float(np.sqrt(var[..., :3].mean())),
               "se_max": float(se.max()), "alpha_se_rms": float(np.sqrt(var[..., 3].mean())),
               "value_rms": float(np.sqrt((ref[..., :3] ** 2).mean())),
               "mean_rgb": ref[..., :3].mean(axis=(0, 1)).tolist(),
               "coverage": float((ref[..., 3] > 0.01).mean())}
    return ref, var, summary


def run_volume(dev, width, height, args, record):
    for name, b, cam, lights, base, ref_spp in volume_scenes(width, height):
        t0 = time.perf_counter()
        ref, var, summary = volume_reference(dev, b, cam, lights, base, args.ref_batches,
                                             args.ref_spp or ref_spp)
        print(f"[{name}] reference: tracking {summary['spp']} spp in {summary['batches']} batches, "
              f"{summary['kernel_ms_total'] / 1e3:.1f} s kernel; se rms {summary['se_rms']:.2e} "
              f"(value rms {summary['value_rms']:.3g})", flush=True)
        scene = {"scene": name, "source": b.source, "dims": b.dims.tolist(),
                 "bricks_stored": int(b.n_slots), "voxel_size": b.voxel_size,
                 "density_scale": base.density_scale, "background": list(base.background),
                 "lights": [repr(l) for l in lights], "reference": summary, "rows": []}
        record["volume"].append(scene)

        def measure(settings):
            """Rows for [(group, label, VolumeSettings)], timed together."""
            done = sweep([(i, (lambda st=st: render_volume(b, cam, lights, st, dev)))
                          for i, (_, _, st) in enumerate(settings)], args.repeat, args.basis)
            rows = []
            for i, (group, label, st) in enumerate(settings):
                img, t = done[i]
                row = {"group": group, "label": label, "settings": describe_volume(st), **t,
                       **errors(img, ref, var)}
                rows.append(row)
                print(f"[{name}] {label:32s} {t['time_ms']:9.1f} ms  rmse {row['rmse']:.2e} "
                      f"(corr {row['rmse_corrected']:.2e})  max {row['max_abs']:.2e}  "
                      f"bias {row['bias']:+.1e}", flush=True)
            scene["rows"].extend(rows)
            return rows

        rows = measure([(g, lab, replace(base, **kw)) for g, lab, kw in volume_settings(args.quick)])
        # tracking at the run time of each marching spp setting
        t1 = next(r for r in rows if r["label"] == "track 1 spp")["time_ms"]
        spp_rows = [r for r in rows if r["group"] == "spp"]
        matched = [int(max(1, round(r["time_ms"] / max(t1, 1e-9)))) for r in spp_rows]
        for r, row in zip(spp_rows, measure(
                [("track@march-time", f"track {n} spp (= march {r['settings']['spp']} spp)",
                  replace(base, estimator="track", spp=n)) for r, n in zip(spp_rows, matched)])):
            row["matched_to"] = r["label"]
        rows = scene["rows"]
        pareto(rows)
        scene["bench_s"] = time.perf_counter() - t0
        scene["load_average"] = os.getloadavg()


# --------------------------------------------------------------------------- multiple scattering

MS_TARGETS = (0.05, 0.02, 0.01)          # relative RMSE for time-to-error
DEMO_ENV = (0.32, 0.42, 0.58)            # the demo's sky (run.sh)


def _find(stem):
    return find_volume(stem, _has_openvdb)


def ms_scenes(width, height):
    """[(name, bricks, camera, lights, base settings)] of the multiple-scattering section."""
    out = []
    demo = next(p for p in (ROOT / "scenes" / "demo_cloud.vdb", ROOT / "bench" / "data" / "demo_cloud.npz")
                if p.exists() and (p.suffix == ".npz" or _has_openvdb()))
    b = vdb.load_volume(demo)
    out.append(("demo_cloud", b, camera.frame_bounds(*b.world_bounds(), width, height, fov=28.0),
                [Sun((-0.6, -1.0, -0.5), 10.0)],
                VolumeSettings(**DEMO_LOOK, env=DEMO_ENV)))
    for stem, scale in (("smoke", 1.0), ("wdas_cloud_sixteenth", 0.05)):
        p = _find(stem)
        if p is None:
            print(f"bench/error.py: {stem} not found; skipping it", flush=True)
            continue
        b = vdb.load_volume(p)
        out.append((stem, b, camera.frame_bounds(*b.world_bounds(), width, height),
                    [Sun((-0.6, -1.0, -0.5), 6.0)], VolumeSettings(density_scale=scale)))
    return out


def path_reference(dev, b, cam, lights, base, batches, spp):
    """The path estimator with batches x spp samples: (mean, variance of the mean, summary)."""
    imgs, ms = [], 0.0
    for k in range(batches):
        r = render_volume(b, cam, lights, replace(base, estimator="path", spp=spp, seed=20_000 + k), dev)
        imgs.append(r.rgba.astype(np.float64))
        ms += r.kernel_ms
    imgs = np.stack(imgs)
    ref, var = imgs.mean(0), imgs.var(0, ddof=1) / batches
    summary = {"estimator": "path", "max_depth": base.max_depth, "spp": batches * spp,
               "batches": batches, "kernel_ms_total": ms,
               "se_rms": float(np.sqrt(var[..., :3].mean())),
               "value_rms": float(np.sqrt((ref[..., :3] ** 2).mean())),
               "mean_rgb": ref[..., :3].mean(axis=(0, 1)).tolist()}
    summary["se_rel"] = summary["se_rms"] / summary["value_rms"]
    return ref, var, summary


def time_to_error(points, target, key="rel_rmse"):
    """Time to reach a relative RMSE from (spp, time_ms, error) points: log-log
    interpolation between the bracketing points; at the first point, its time (an upper
    bound); past the last, err ~ 1/sqrt(spp) from the last point (flagged)."""
    pts = sorted(points, key=lambda p: p["time_ms"])
    for i, p in enumerate(pts):
        if p[key] <= target:
            if i == 0:
                return {"time_ms": p["time_ms"], "spp": p["spp"], "how": "first point: an upper bound"}
            q = pts[i - 1]
            f = (np.log(target) - np.log(q[key])) / (np.log(p[key]) - np.log(q[key]))
            t = float(np.exp(np.log(q["time_ms"]) + f * (np.log(p["time_ms"]) - np.log(q["time_ms"]))))
            sp = float(np.exp(np.log(q["spp"]) + f * (np.log(p["spp"]) - np.log(q["spp"]))))
            return {"time_ms": t, "spp": sp, "how": f"interpolated between {q['spp']} and {p['spp']} spp"}
    last = max(pts, key=lambda p: p["spp"])
    spp = last["spp"] * (last[key] / target) ** 2
    return {"time_ms": spp * last["time_ms"] / last["spp"], "spp": spp,
            "how": f"extrapolated from {last['spp']} spp as 1/sqrt(spp)"}


def octave_fit(dev, scenes, refs, args):
    """A grid over the octave count and parameters (D, G, C; cl/march.h; named a, b, c
    in the rows): (count, D, G) at C = 0.5, then C for the best (D, G) of each count. The objective sums each scene's squared relative RMSE
    against its path-traced reference (the march at 2 spp, default steps). Returns the
    rows, best first."""
    counts = (2, 4) if args.quick else (2, 4, 8)
    grid_a = (0.35, 0.5) if args.quick else (0.35, 0.5, 0.7)       # D
    grid_b = (2.0, 2.8) if args.quick else (2.0, 2.5, 2.8, 3.2)    # G
    grid_c = (0.2, 0.5) if args.quick else (0.0, 0.2, 0.5)         # C
    rows = []

    def score(n, a, bb, c):
        row = {"ms_octaves": n, "a": a, "b": bb, "c": c, "scenes": {}}
        total = 0.0
        for (name, b, cam, lights, base), (ref, var, summ) in zip(scenes, refs):
            st = replace(base, ms_octaves=n, ms_octave_scales=(a, bb, c), spp=2, seed=3)
            img = render_volume(b, cam, lights, st, dev).rgba
            e = errors(img, ref, var)
            row["scenes"][name] = {"rel_rmse": e["rmse_corrected"] / summ["value_rms"],
                                   "mean_ratio": float(img[..., :3].mean() / ref[..., :3].mean())}
            total += row["scenes"][name]["rel_rmse"] ** 2
        row["objective"] = total
        rows.append(row)
        return row

    for n in counts:
        best = min((score(n, a, bb, 0.5) for a in grid_a for bb in grid_b),
                   key=lambda r: r["objective"])
        for c in grid_c:
            r = score(n, best["a"], best["b"], c)
            best = r if r["objective"] < best["objective"] else best
        print(f"[fit] {n} octaves: best a {best['a']} b {best['b']} c {best['c']}: "
              + ", ".join(f"{k} {v['rel_rmse']:.1%} (mean x{v['mean_ratio']:.3f})"
                          for k, v in best["scenes"].items()), flush=True)
    return sorted(rows, key=lambda r: r["objective"])


def run_ms(dev, args, record):
    mw, mh = args.ms_size
    scenes = ms_scenes(mw, mh)
    refs = []
    for name, b, cam, lights, base in scenes:
        t0 = time.perf_counter()
        ref, var, summ = path_reference(dev, b, cam, lights, base, args.ref_batches, args.ms_ref_spp)
        refs.append((ref, var, summ))
        single = render_volume(b, cam, lights, replace(base, estimator="path", max_depth=1,
                                                       spp=args.ms_ref_spp, seed=7), dev).rgba
        summ["single_over_multiple"] = float(single[..., :3].mean() / max(ref[..., :3].mean(), 1e-30))
        print(f"[{name}] MS reference: path {summ['spp']} spp, depth {summ['max_depth']}, "
              f"{summ['kernel_ms_total'] / 1e3:.1f} s kernel; se {summ['se_rel']:.2%} of the value rms; "
              f"single scattering is x{summ['single_over_multiple']:.2f} of it", flush=True)
        sc = {"scene": name, "size": [mw, mh], "source": b.source, "reference": summ,
              "settings": {"density_scale": base.density_scale, "albedo": list(base.albedo),
                           "env": base.env}, "rows": []}
        record["multiple_scattering"].append(sc)
        spps = (1, 4, 16) if args.quick else (1, 2, 4, 8, 16, 32, 64, 128, 256)
        octs = (1, 2, 4) if args.quick else (1, 2, 3, 4, 5, 6, 8)
        settings = [("path", f"path {n} spp", replace(base, estimator="path", spp=n, seed=n)) for n in spps]
        settings += [("octaves", f"march {n} octaves, 4 spp", replace(base, ms_octaves=n, spp=4, seed=5))
                     for n in octs]
        settings += [("octaves", f"march {n} octaves, 1 spp", replace(base, ms_octaves=n, seed=5))
                     for n in (1, 4)]
        done = sweep([(i, (lambda st=st: render_volume(b, cam, lights, st, dev)))
                      for i, (_, _, st) in enumerate(settings)], args.repeat, args.basis)
        for i, (group, label, st) in enumerate(settings):
            img, t = done[i]
            e = errors(img, ref, var)
            row = {"group": group, "label": label, "settings": {**describe_volume(st),
                   "ms_octaves": st.ms_octaves, "ms_octave_scales": list(octave_scales(st, b)),
                   "max_depth": st.max_depth}, **t, **e,
                   "rel_rmse": e["rmse_corrected"] / summ["value_rms"],
                   "mean_ratio": float(img[..., :3].mean() / max(ref[..., :3].mean(), 1e-30)),
                   "spp": st.spp}
            sc["rows"].append(row)
            print(f"[{name}] {label:28s} {t['time_ms']:9.1f} ms  rel rmse {row['rel_rmse']:.2%}  "
                  f"mean x{row['mean_ratio']:.3f}; covered pixels "
                  f"({e.get('covered_fraction', 0):.0%}) {e.get('covered_rel_rmse', 0):.2%} "
                  f"x{e.get('covered_mean_ratio', 0):.3f}", flush=True)
        pts = [r for r in sc["rows"] if r["group"] == "path"]
        sc["path_time_to_error"] = {f"{tg:g}": time_to_error(pts, tg) for tg in MS_TARGETS}
        print(f"[{name}] path time to " + ", ".join(
            f"{float(k):.0%}: {v['time_ms']:.0f} ms ({v['spp']:.0f} spp{'?' if 'extra' in v['how'] else ''})"
            for k, v in sc["path_time_to_error"].items()), flush=True)
        pareto(sc["rows"], key="rmse_corrected")
        sc["bench_s"] = time.perf_counter() - t0
    if args.fit_octaves and scenes:
        record["octave_fit"] = octave_fit(dev, scenes, refs, args)[:40]


# --------------------------------------------------------------------------- defaults (issue #22)

DEFAULT_FILES = ("wdas_cloud_sixteenth", "smoke", "dragon_with_xform", "fluid_data_0056",
                 "fluid_data_0190")


def box2(a):
    """2x2 box average (odd edges dropped)."""
    h, w = a.shape[0] // 2 * 2, a.shape[1] // 2 * 2
    a = a[:h, :w]
    return 0.25 * (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2])


def default_errors(img, ref, var) -> dict:
    """Relative RMSE per pixel and after a 2x2 box, each with the reference's noise
    removed, and the image-mean ratio."""
    out = {}
    rms = float(np.sqrt((ref[..., :3] ** 2).mean()))
    for key, f in (("rel_rmse", lambda a: a), ("rel_rmse_box2", box2)):
        d = f(img[..., :3].astype(np.float64)) - f(ref[..., :3])
        v = f(var[..., :3]) / (4.0 if f is box2 else 1.0)
        r = float(np.sqrt((f(ref[..., :3]) ** 2).mean()))
        out[key] = max(float((d ** 2).mean()) - float(v.mean()), 0.0) ** 0.5 / max(r, 1e-30)
    out["mean_ratio"] = float(img[..., :3].mean() / max(ref[..., :3].mean(), 1e-30))
    out["value_rms"] = rms
    out.update(covered_errors(img, ref, var))
    return out


def oidn_denoise(rgba):
    """Colour-only OIDN (pyoidn.denoise, HDR, the `denoise` extra) of an RGBA render, or
    None where pyoidn is absent."""
    try:
        import pyoidn
    except Exception:
        return None
    res = np.array(rgba, np.float32)
    res[..., :3] = pyoidn.denoise(np.ascontiguousarray(np.maximum(res[..., :3], 0.0)), hdr=True)
    return res


def run_defaults(dev, args, record):
    from volrender.render import render
    sizes = [(stem, args.defaults_size) for stem in DEFAULT_FILES]
    if not args.quick:
        sizes.append(("wdas_cloud_sixteenth", (320, 240)))
    for stem, (w, h) in sizes:
        p = _find(stem)
        if p is None:
            print(f"bench/error.py: {stem} not found; skipping it", flush=True)
            continue
        t0 = time.perf_counter()
        scene = scene_mod.load_scene(p, size=(w, h))
        st = scene.settings

        def with_(**kw):
            c = scene_mod.VolumeContent(scene.content.bricks, replace(st, **kw), scene.content.store)
            return scene.replace(content=c)
        imgs = []
        ms = 0.0
        for k in range(args.ref_batches_defaults):
            r = render(with_(estimator="path", spp=args.defaults_ref_spp, seed=30_000 + k), dev)
            imgs.append(r.rgba.astype(np.float64))
            ms += r.kernel_ms
        imgs = np.stack(imgs)
        ref, var = imgs.mean(0), imgs.var(0, ddof=1) / len(imgs)
        summ = {"estimator": "path", "spp": args.defaults_ref_spp * len(imgs), "batches": len(imgs),
                "kernel_ms_total": ms, "se_rel": float(np.sqrt(var[..., :3].mean()) /
                                                       max(np.sqrt((ref[..., :3] ** 2).mean()), 1e-30))}
        sc = {"scene": stem, "size": [w, h], "source": str(p), "notes": list(scene.notes),
              "settings": {"estimator": st.estimator, "ms_octaves": st.octaves,
                           "density_scale": st.density_scale, "albedo": list(st.albedo),
                           "emission_grid": st.emission_grid,
                           "temperature_grid": st.temperature_grid},
              "lights": [repr(l) for l in scene.lights],
              "environment": scene.environment.source if scene.environment else None,
              "reference": summ, "rows": []}
        record["defaults"].append(sc)
        print(f"[{stem} {w}x{h}] defaults: {st.estimator}, {st.octaves} octaves; reference path "
              f"{summ['spp']} spp, se {summ['se_rel']:.2%}", flush=True)
        jobs = [("default", f"default (auto: {st.estimator}, {st.octaves} octaves)", with_()),
                ("single", "single scattering (march, 1 octave)", with_(ms_octaves=1)),
                *[("octaves", f"march {n} octaves", with_(ms_octaves=n)) for n in (2, 4, 8)],
                *[("path", f"path {n} spp", with_(estimator="path", spp=n, seed=7 + n))
                  for n in (1, 4, 16)]]
        done = sweep([(i, (lambda sc_=sc_: render(sc_, dev)))
                      for i, (_, _, sc_) in enumerate(jobs)], args.repeat, args.basis)
        for i, (group, label, _) in enumerate(jobs):
            img, t = done[i]
            row = {"group": group, "label": label, **t, **default_errors(img, ref, var)}
            sc["rows"].append(row)
        for n in (4, 16):
            path = next(r for r in zip(jobs, range(len(jobs))) if r[0][1] == f"path {n} spp")
            img, t = done[path[1]]
            t1 = time.perf_counter()
            den = oidn_denoise(img)
            if den is None:
                break
            row = {"group": "oidn", "label": f"path {n} spp + OIDN (colour)",
                   "time_ms": t["time_ms"] + 1e3 * (time.perf_counter() - t1),
                   "denoise_ms": 1e3 * (time.perf_counter() - t1), **default_errors(den, ref, var)}
            sc["rows"].append(row)
        for target in (0.1, 0.05):
            t1, c1 = time.perf_counter(), time.process_time()
            r = render(with_(estimator="path", spp=2, noise_target=target, seed=11), dev)
            row = {"group": "adaptive", "label": f"path to noise {target:g}",
                   "time_ms": 1e3 * (time.process_time() - c1) / args.basis[1]
                   if args.basis[0] == "cpu" else r.kernel_ms,
                   "wall_ms": 1e3 * (time.perf_counter() - t1), "spp": r.info.spp,
                   "passes": r.info.passes, "noise_estimate": r.info.noise,
                   **default_errors(r.rgba, ref, var)}
            sc["rows"].append(row)
        single = next(r for r in sc["rows"] if r["group"] == "single")
        for row in sc["rows"]:
            row["time_vs_single"] = row["time_ms"] / max(single["time_ms"], 1e-9)
            print(f"[{stem} {w}x{h}] {row['label']:40s} {row['time_ms']:9.1f} ms "
                  f"(x{row['time_vs_single']:.2f})  rel rmse {row['rel_rmse']:.1%}  2x2 "
                  f"{row['rel_rmse_box2']:.1%}  mean x{row['mean_ratio']:.3f}; covered "
                  f"{row.get('covered_rel_rmse', 0):.1%} x{row.get('covered_mean_ratio', 0):.3f}",
                  flush=True)
        d = sc["rows"][0]
        sc["target"] = {"mean_within_10pct": abs(d["mean_ratio"] - 1) <= 0.10,
                        "box2_rel_rmse_le_15pct": d["rel_rmse_box2"] <= 0.15,
                        "time_le_3x_single": d["time_vs_single"] <= 3.0}
        pareto(sc["rows"], key="rel_rmse_box2")
        sc["bench_s"] = time.perf_counter() - t0


# --------------------------------------------------------------------------- denoising (issue 34)

DENOISE_SPPS = (1, 2, 4, 8, 16, 32, 64, 128, 256)
DENOISE_TARGET = 0.05          # the issue's: within 5 % of path 1024 spp, covered pixels
COVERED = 0.05                 # covered pixels: reference alpha above this


def masked_errors(img, ref, var, covered) -> dict:
    """Relative RMSE over the covered pixels (RGB), the reference's noise removed (its
    variance of the mean, independent of the image's), and the covered mean's ratio."""
    d = img[..., :3].astype(np.float64)[covered] - ref[..., :3][covered]
    mse = max(float((d ** 2).mean()) - float(var[..., :3][covered].mean()), 0.0)
    rms = float(np.sqrt((ref[..., :3][covered] ** 2).mean()))
    return {"rel_rmse": mse ** 0.5 / max(rms, 1e-30),
            "mean_ratio": float(img[..., :3][covered].mean() / max(ref[..., :3][covered].mean(), 1e-30))}


def denoise_scenes(args, gpu):
    """[(name, Scene)]: WDAS and smoke as `volrender render FILE --estimator path` loads them
    (default sun and sky), the bunny as glass (the full model, defaults)."""
    out = []
    w, h = args.denoise_size
    for stem in ("wdas_cloud_sixteenth", "smoke"):
        if stem.split("_")[0] not in args.denoise_scenes:
            continue
        p = _find(stem)
        if p is None:
            print(f"bench/error.py: {stem} not found; skipping it", flush=True)
            continue
        out.append((stem, scene_mod.load_scene(p, size=(w, h), estimator="path")))
    bunny = shared_data() / "points" / "bun_zipper.ply"
    if "bunny" not in args.denoise_scenes:
        pass
    elif bunny.is_file():
        gw, gh = (w, h) if gpu else args.denoise_glass_size
        out.append(("bunny (glass)", scene_mod.load_scene(bunny, size=(gw, gh))))
    else:
        print(f"bench/error.py: {bunny} not found; skipping the bunny", flush=True)
    return out


def run_denoise(dev, args, record):
    """Error against time with and without the denoiser (render(..., denoise="on"): the
    guides and OIDN), on the covered pixels, against path (glass: the full model) at
    --denoise-ref-spp in 8 batches. Time: the render's launches (kernel ms, or CPU ms /
    cores with --time cpu) plus, denoised, the guides' and OIDN's time on the same basis."""
    from volrender.dispatch import is_gpu
    from volrender.render import render
    cores = args.basis[1]
    cpu = args.basis[0] == "cpu"
    batches = 8
    for name, scene in denoise_scenes(args, is_gpu(dev)):
        t0 = time.perf_counter()
        top = args.denoise_max_spp if scene.kind == "volume" else args.denoise_glass_max_spp
        spps = [n for n in DENOISE_SPPS if n <= top]
        ref_spp = args.denoise_ref_spp if scene.kind == "volume" else args.denoise_glass_ref_spp
        imgs, ref_ms = [], 0.0
        for k in range(batches):
            r = render(scene.replace(spp=max(1, ref_spp // batches), seed=40_000 + k), dev)
            imgs.append(r.rgba.astype(np.float64))
            ref_ms += r.kernel_ms
        imgs = np.stack(imgs)
        ref, var = imgs.mean(0), imgs.var(0, ddof=1) / batches
        covered = ref[..., 3] > COVERED
        w, h = scene.camera.width, scene.camera.height
        sc = {"scene": name, "size": [w, h], "covered": float(covered.mean()),
              "reference": {"spp": batches * max(1, ref_spp // batches), "batches": batches,
                            "kernel_ms_total": ref_ms,
                            "se_rel": float(np.sqrt(var[..., :3][covered].mean()) /
                                            np.sqrt((ref[..., :3][covered] ** 2).mean()))},
              "rows": []}
        record["denoise"].append(sc)
        print(f"[{name} {w}x{h}] reference {sc['reference']['spp']} spp, covered "
              f"{sc['covered']:.0%}, its noise {sc['reference']['se_rel']:.2%}", flush=True)
        render(scene.replace(spp=1, denoise="on"), dev)          # builds, OIDN's first call
        for n in spps:
            img = render(scene.replace(spp=n, seed=n, denoise="on"), dev)
            base = img.cpu_ms / cores if cpu else img.kernel_ms
            extra = ((img.info.guides_cpu_ms + img.info.denoise_cpu_ms) / cores if cpu
                     else img.info.guides_ms + img.info.denoise_ms)
            c1, t1 = time.process_time(), time.perf_counter()
            plain = denoise.denoise(img.noisy)            # OIDN on the colour alone
            alone = 1e3 * ((time.process_time() - c1) / cores if cpu else time.perf_counter() - t1)
            for group, pic, t in (("path", img.noisy, base), ("path + OIDN", img.rgba, base + extra),
                                  ("path + OIDN colour only", plain, base + alone)):
                row = {"group": group, "label": f"{group} {n} spp", "spp": n, "time_ms": t,
                       **masked_errors(pic, ref, var, covered)}
                if group == "path + OIDN":
                    row.update(guides_ms=img.info.guides_ms, denoise_ms=img.info.denoise_ms)
                sc["rows"].append(row)
                print(f"[{name}] {row['label']:34s} {t:9.1f} ms  rel rmse (covered) "
                      f"{row['rel_rmse']:.2%}  mean x{row['mean_ratio']:.3f}", flush=True)
        out = {}
        for group in ("path", "path + OIDN", "path + OIDN colour only"):
            pts = [r for r in sc["rows"] if r["group"] == group]
            out[group] = time_to_error(pts, DENOISE_TARGET)
        sc["time_to_5pct"] = out
        sc["speedup_at_5pct"] = out["path"]["time_ms"] / out["path + OIDN"]["time_ms"]
        sc["target_met"] = sc["speedup_at_5pct"] >= 8.0
        print(f"[{name}] to {DENOISE_TARGET:.0%} (covered): path {out['path']['time_ms']:.0f} ms "
              f"({out['path']['how']}), + OIDN {out['path + OIDN']['time_ms']:.0f} ms "
              f"({out['path + OIDN']['how']}): x{sc['speedup_at_5pct']:.1f} "
              f"(target x8: {'met' if sc['target_met'] else 'missed'})", flush=True)
        pareto(sc["rows"], key="rel_rmse")
        sc["bench_s"] = time.perf_counter() - t0


# --------------------------------------------------------------------------- the command (issue 33)

def run_command(dev, args, record):
    """`volrender render FILE -o OUT.npy --size WxH` for the five real files, as a user runs
    it (a fresh process each: load, auto's choice, program from the cache, render, write;
    wall time of the whole command, median of --repeat), against the path-traced reference
    of the same scene in --command-refs (ref_<stem>.npy, var_<stem>.npy where present: from
    `bench/ms_refs.py run`, which renders the scenes `prepare` saved): relative RMSE (the
    reference's noise removed) and mean ratio on covered pixels and over the whole image."""
    import subprocess
    import tempfile
    refs = Path(args.command_refs)
    w, h = args.command_size
    for stem in DEFAULT_FILES:
        p, ref_path = _find(stem), refs / f"ref_{stem}.npy"
        if p is None or not ref_path.exists():
            print(f"bench/error.py: {stem} or its reference not found; skipping it", flush=True)
            continue
        ref = np.load(ref_path).astype(np.float64)
        var_path = refs / f"var_{stem}.npy"
        var = np.load(var_path).astype(np.float64) if var_path.exists() else None
        walls, notes = [], ""
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "out.npy"
            for _ in range(args.repeat):
                out.unlink(missing_ok=True)
                t0 = time.perf_counter()
                r = subprocess.run([sys.executable, "-m", "volrender", "render", str(p), "-o",
                                    str(out), "--size", f"{w}x{h}"]
                                   + (["--device", args.device] if args.device else []),
                                   capture_output=True, text=True, cwd=ROOT,
                                   env={**os.environ, "PYTHONPATH": str(ROOT)})
                walls.append(time.perf_counter() - t0)
                if r.returncode:
                    raise SystemExit(f"bench/error.py: {stem}: {r.stderr.strip()}")
                notes = r.stderr
            img = np.load(out).astype(np.float64)
        if img.shape != ref.shape:
            raise SystemExit(f"bench/error.py: {stem}: image {img.shape} != reference {ref.shape}")
        emits = stem == "fluid_data_0056"
        d = img[..., :3] - ref[..., :3]
        mse = float((d ** 2).mean()) - (float(var[..., :3].mean()) if var is not None else 0.0)
        row = {"file": stem, "size": [w, h], "wall_s": float(np.median(walls)), "wall_runs_s": walls,
               "notes": [n for n in notes.splitlines() if n.startswith("volrender:")],
               "reference": {"file": str(ref_path), "noise_removed": var is not None},
               "rel_rmse": max(mse, 0.0) ** 0.5 / max(float(np.sqrt((ref[..., :3] ** 2).mean())), 1e-30),
               "mean_ratio": float(img[..., :3].mean() / max(ref[..., :3].mean(), 1e-30)),
               **covered_errors(img, ref, var, emits)}
        record["command"].append(row)
        print(f"[{stem} {w}x{h}] the command: {row['wall_s']:.2f} s wall; covered pixels "
              f"({row['covered_fraction']:.0%}): rel RMSE {row.get('covered_rel_rmse', 0):.1%}, "
              f"mean x{row.get('covered_mean_ratio', 0):.3f}; whole image {row['rel_rmse']:.1%}, "
              f"x{row['mean_ratio']:.3f}", flush=True)


# --------------------------------------------------------------------------- glass

def glass_scenes(width, height, quick):
    """[(name, cloud, camera, lights, base settings)]."""
    out = []
    cloud = generators.generate("blob", 300, seed=1)
    out.append(("blob300", cloud, glass.default_camera(cloud, width, height), [GLASS_SUN],
                glass.GlassSettings()))
    if not quick:
        # the scene the CLI renders (scene.load_scene), at this benchmark's size
        sc = scene_mod.load_scene(ROOT / "scenes" / "molten_glass.toml", size=(width, height))
        out.append(("molten_glass", sc.content.cloud, sc.camera, list(sc.lights), sc.settings))
    return out


def glass_settings(quick, isolated):
    """[(group, label, overrides)]: each knob from the defaults (1e-4, 256, 6); with
    `isolated`, each knob alone with the others at the reference values."""
    eps = (1e-2, 1e-4) if quick else (1e-2, 1e-3, 1e-4, 1e-5)
    steps = (32, 256) if quick else (32, 64, 128, 256, 512)
    bounces = (1, 6) if quick else (1, 2, 4, 6, 8)
    rows = [("epsilon", f"epsilon {e:g}", dict(epsilon=e)) for e in eps]
    rows += [("max_steps", f"max_steps {n}", dict(max_steps=n)) for n in steps]
    rows += [("bounces", f"bounces {n}", dict(bounces=n)) for n in bounces]
    rows += [("relax", f"relax {w:g}", dict(relax=w)) for w in ((1.0,) if quick else (1.0, 1.3, 1.9))]
    if not quick:
        rows += [("preset", "preview: eps 1e-3, 64 steps, 2 bounces",
                  dict(epsilon=1e-3, max_steps=64, bounces=2)),
                 ("preset", "draft: eps 1e-3, 128 steps, 4 bounces",
                  dict(epsilon=1e-3, max_steps=128, bounces=4)),
                 ("preset", "final: eps 1e-5, 512 steps, 8 bounces",
                  dict(epsilon=1e-5, max_steps=512, bounces=8)),
                 ("preset", "fine: eps 1e-5, 1024 steps, 8 bounces",
                  dict(epsilon=1e-5, max_steps=1024, bounces=8)),
                 ("preset", "final, plain steps: eps 1e-5, 512 steps, 8 bounces, relax 1",
                  dict(epsilon=1e-5, max_steps=512, bounces=8, relax=1.0)),
                 ("tree vs brute", "defaults, brute force", dict(use_tree=False)),
                 ("tree vs brute", "defaults, tree walk", dict(accel="tree"))]
    if isolated:
        ref = {k: v for k, v in GLASS_REF.items() if k != "use_tree"}
        rows += [("alone: epsilon", f"epsilon {e:g} alone", {**ref, "epsilon": e}) for e in eps]
        rows += [("alone: max_steps", f"max_steps {n} alone", {**ref, "max_steps": n})
                 for n in (*steps, 1024)]
        rows += [("alone: bounces", f"bounces {n} alone", {**ref, "bounces": n}) for n in bounces]
        rows += [("alone: relax", f"relax {w:g} alone", {**ref, "relax": w}) for w in (1.3, 1.6, 1.9)]
        rows += [("tree vs brute", "reference knobs, tree", dict(ref, accel="tree")),
                 ("tree vs brute", "reference knobs, cells", dict(ref, accel="grid"))]
    return rows


def describe_glass(s: glass.GlassSettings) -> dict:
    return {"epsilon": s.epsilon, "max_steps": s.max_steps, "bounces": s.bounces,
            "relax": s.relax, "accel": s.accel, "spp": s.spp}


def run_glass(dev, width, height, args, record):
    for i, (name, cloud, cam, lights, base) in enumerate(glass_scenes(width, height, args.quick)):
        t0 = time.perf_counter()
        r = render_points(cloud, cam, lights, replace(base, **GLASS_REF), dev)
        ref = r.rgba.astype(np.float64)
        summary = {**describe_glass(replace(base, **GLASS_REF)), "kernel_ms": r.kernel_ms,
                   "value_rms": float(np.sqrt((ref[..., :3] ** 2).mean())),
                   "coverage": float((ref[..., 3] > 0.5).mean())}
        print(f"[{name}] reference: eps 1e-6, 4096 steps, 12 bounces, brute force, "
              f"{r.kernel_ms / 1e3:.1f} s kernel (value rms {summary['value_rms']:.3g})", flush=True)
        scene = {"scene": name, "points": len(cloud), "reference": summary, "rows": []}
        record["glass"].append(scene)
        settings = [(g, lab, replace(base, **kw))
                    for g, lab, kw in glass_settings(args.quick, isolated=i == 0)]
        done = sweep([(j, (lambda st=st: render_points(cloud, cam, lights, st, dev)))
                      for j, (_, _, st) in enumerate(settings)], args.repeat, args.basis)
        for j, (group, label, st) in enumerate(settings):
            img, t = done[j]
            row = {"group": group, "label": label, "settings": describe_glass(st), **t,
                   **errors(img, ref)}
            scene["rows"].append(row)
            print(f"[{name}] {label:40s} {t['time_ms']:9.1f} ms  rmse {row['rmse']:.2e}  "
                  f"max {row['max_abs']:.2e}  bias {row['bias']:+.1e}", flush=True)
        pareto(scene["rows"])
        scene["bench_s"] = time.perf_counter() - t0
        scene["load_average"] = os.getloadavg()


# --------------------------------------------------------------------------- output

def plot(record, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker
    panels = [("volume", s) for s in record["volume"]] + [("glass", s) for s in record["glass"]]
    panels += [("ms", s) for s in record.get("multiple_scattering", [])]
    panels += [("defaults", s) for s in record.get("defaults", [])]
    panels += [("denoise", s) for s in record.get("denoise", [])]
    if not panels and record.get("command"):
        return plot_command(record, path)
    if not panels:
        return
    cols = min(2, len(panels))
    nrows = -(-len(panels) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(6.2 * cols, 4.6 * nrows), squeeze=False)
    markers = "osD^v<>pPX*h"
    for ax, (kind, sc) in zip(axes.flat, panels):
        groups = list(dict.fromkeys(r["group"] for r in sc["rows"]))
        key = {"ms": "rel_rmse", "defaults": "rel_rmse_box2", "denoise": "rel_rmse"}.get(kind, "rmse")
        for i, g in enumerate(groups):
            rows = [r for r in sc["rows"] if r["group"] == g]
            ax.loglog([r["time_ms"] for r in rows], [max(r[key], 1e-12) for r in rows],
                      markers[i % len(markers)], ls="" if g in ("combined", "preset", "tree vs brute", "octaves") else "--" if g.startswith("alone") else "-",
                      label=g, alpha=0.8)
            if g == "octaves" and kind == "ms":    # label each point with its octave count (and spp)
                for r in rows:
                    ax.annotate(f"{r['settings']['ms_octaves']}" + ("" if r["spp"] == 4 else f"/{r['spp']}spp"),
                                (r["time_ms"], max(r[key], 1e-12)), fontsize=6, xytext=(3, 2),
                                textcoords="offset points")
        front = sorted((r for r in sc["rows"] if r["pareto"]), key=lambda r: r["time_ms"])
        ax.step([r["time_ms"] for r in front], [max(r[key], 1e-12) for r in front],
                where="post", color="k", lw=1.2, alpha=0.6, label="Pareto front")
        ax.scatter([r["time_ms"] for r in front], [max(r[key], 1e-12) for r in front],
                   s=110, facecolors="none", edgecolors="k", lw=1.2)
        if kind == "denoise":
            w, h = sc["size"]
            title = (f"denoising: {sc['scene']} {w}x{h}, covered pixels (ref {sc['reference']['spp']} "
                     f"spp); to 5%: x{sc['speedup_at_5pct']:.1f}")
            ax.axhline(DENOISE_TARGET, color="C3", ls="--", lw=0.6, alpha=0.5)
            ax.axhline(sc["reference"]["se_rel"], color="grey", ls=":", lw=1,
                       label="reference noise")
        elif kind == "defaults":
            w, h = sc["size"]
            title = (f"defaults: {sc['scene']} {w}x{h} (ref: path {sc['reference']['spp']} spp, "
                     "same lights)")
            ax.axhline(0.15, color="C3", ls="--", lw=0.6, alpha=0.5)
        elif kind == "ms":
            ax.axhline(sc["reference"]["se_rel"], color="grey", ls=":", lw=1,
                       label="reference noise (se / value rms)")
            for tg in MS_TARGETS:
                ax.axhline(tg, color="C3", ls="--", lw=0.6, alpha=0.5)
            w, h = sc["size"]
            title = (f"multiple scattering: {sc['scene']} {w}x{h} (ref: path {sc['reference']['spp']} spp, "
                     f"depth {sc['reference']['max_depth']})")
        elif kind == "volume":
            ax.axhline(sc["reference"]["se_rms"], color="grey", ls=":", lw=1,
                       label="reference noise (se rms)")
            title = f"volume: {sc['scene']} (ref: tracking {sc['reference']['spp']} spp)"
        else:
            title = f"glass: {sc['scene']} ({sc['points']} points; ref eps 1e-6, 4096 steps, 12 bounces)"
        ax.set_title(title, fontsize=9)
        ax.set_xlabel(record["time_label"])
        fmt = matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}")
        for axis in (ax.xaxis, ax.yaxis):
            axis.set_major_formatter(fmt)
            axis.set_minor_locator(matplotlib.ticker.LogLocator(subs=(2.0, 5.0)))
            axis.set_minor_formatter(fmt)
        ax.set_ylabel("relative RMSE vs path-traced reference" if kind in ("ms", "denoise") else
                      "relative RMSE (2x2 box) vs path reference" if kind == "defaults" else
                      "RMSE (RGB) vs reference")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    w, h = record["size"]
    fig.suptitle(f"error against run time, {w}x{h} — {record['device']}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_command(record, path):
    """The command section: relative RMSE on covered pixels and over the whole image, and
    the wall time, per file."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rows = record["command"]
    names = [r["file"].replace("_", " ") for r in rows]
    x = np.arange(len(rows))
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    a.bar(x - 0.2, [100 * r.get("covered_rel_rmse", 0) for r in rows], 0.4, label="covered pixels")
    a.bar(x + 0.2, [100 * r["rel_rmse"] for r in rows], 0.4, label="whole image")
    a.axhline(10, color="C3", ls="--", lw=0.8, label="issue target 10 %")
    a.set_ylabel("relative RMSE vs path reference, %")
    b.bar(x, [r["wall_s"] for r in rows], 0.5, color="C2")
    b.set_ylabel("wall s (the whole command)")
    for ax in (a, b):
        ax.set_xticks(x, names, rotation=20, fontsize=7)
        ax.grid(True, axis="y", alpha=0.3)
    a.legend(fontsize=7)
    w, h = rows[0]["size"]
    fig.suptitle(f"volrender render FILE at {w}x{h} — {record['device']} (load "
                 f"{record['load_average_start'][0]:.0f})", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default=None, help="OpenCL device (default: PoCL)")
    ap.add_argument("--size", default="160x120", help="image size WxH")
    ap.add_argument("--repeat", type=int, default=None,
                    help="timed rounds over all settings (default 5; quick 1)")
    ap.add_argument("--quick", action="store_true", help="a fast smoke run: tiny image, few settings")
    ap.add_argument("--ref-spp", type=int, default=None,
                    help="reference spp per batch (default: demo_cloud 2048, smoke 1024; quick 64)")
    ap.add_argument("--ref-batches", type=int, default=None, help="reference batches (default 16; quick 4)")
    ap.add_argument("--time", choices=["kernel", "cpu"], default="kernel",
                    help="time axis: kernel = OpenCL profiling ms (median); cpu = CPU ms of the "
                         "launches / compute units (median), for a CPU device on a shared host")
    ap.add_argument("--no-volume", action="store_true", help="skip the volume scenes")
    ap.add_argument("--no-glass", action="store_true", help="skip the glass scenes")
    ap.add_argument("--no-ms", action="store_true", help="skip the multiple-scattering section")
    ap.add_argument("--ms-size", default=None, help="multiple-scattering image size (96x72; quick 32x24)")
    ap.add_argument("--ms-ref-spp", type=int, default=None,
                    help="path reference spp per batch (default 1024; quick 64)")
    ap.add_argument("--fit-octaves", action="store_true",
                    help="grid over the octave scales and counts against the path reference")
    ap.add_argument("--defaults", action="store_true",
                    help="also measure the defaults on the five real files (issue #22)")
    ap.add_argument("--defaults-only", action="store_true", help="only the defaults section")
    ap.add_argument("--defaults-size", default="160x120", help="defaults section image size")
    ap.add_argument("--defaults-ref-spp", type=int, default=None,
                    help="defaults section: path reference spp per batch (default 128; quick 16)")
    ap.add_argument("--denoise", action="store_true",
                    help="also measure error against time with and without the denoiser (issue 34)")
    ap.add_argument("--denoise-only", action="store_true", help="only the denoising section")
    ap.add_argument("--denoise-size", default="128x96", help="denoising section: volume image size")
    ap.add_argument("--denoise-glass-size", default="48x36",
                    help="denoising section: the bunny's size on CPUs (GPUs: --denoise-size)")
    ap.add_argument("--denoise-ref-spp", type=int, default=1024,
                    help="denoising section: the volumes' path reference spp (8 batches)")
    ap.add_argument("--denoise-glass-ref-spp", type=int, default=128,
                    help="denoising section: the bunny's reference spp (8 batches)")
    ap.add_argument("--denoise-max-spp", type=int, default=256,
                    help="denoising section: the curve's largest spp (powers of two from 1)")
    ap.add_argument("--denoise-glass-max-spp", type=int, default=32,
                    help="denoising section: the bunny's largest spp")
    ap.add_argument("--denoise-scenes", default="wdas,smoke,bunny",
                    help="denoising section: which of wdas, smoke, bunny")
    ap.add_argument("--command-refs", default=None,
                    help="only the command section (issue 33): `volrender render FILE` for the "
                         "five files against the references in this folder (bench/ms_refs.py)")
    ap.add_argument("--command-size", default="640x480", help="the command section's image size")
    ap.add_argument("--tag", default=None, help="added to the results' name: error_<device>-<tag>.json")
    args = ap.parse_args(argv)
    if args.quick and args.size == ap.get_default("size"):
        args.size = "48x36"
    args.repeat = args.repeat or (1 if args.quick else 5)
    args.ref_spp = args.ref_spp or (64 if args.quick else None)
    args.ref_batches = args.ref_batches or (4 if args.quick else 16)
    args.ms_ref_spp = args.ms_ref_spp or (64 if args.quick else 1024)
    args.defaults_ref_spp = args.defaults_ref_spp or (16 if args.quick else 128)
    args.ref_batches_defaults = 4 if args.quick else 8
    args.defaults_size = tuple(int(v) for v in args.defaults_size.lower().split("x"))
    if args.defaults_only or args.command_refs:
        args.defaults = not args.command_refs
        args.no_volume = args.no_ms = args.no_glass = True
    if args.denoise_only:
        args.denoise = args.no_volume = args.no_ms = args.no_glass = True
    args.command_size = tuple(int(v) for v in args.command_size.lower().split("x"))
    for name in ("denoise_size", "denoise_glass_size"):
        try:
            setattr(args, name, tuple(int(v) for v in getattr(args, name).lower().split("x")))
        except ValueError:
            ap.error(f"--{name.replace('_', '-')} takes WxH, got {getattr(args, name)!r}")
    try:
        args.ms_size = tuple(int(v) for v in (args.ms_size or ("32x24" if args.quick else "96x72"))
                             .lower().split("x"))
    except ValueError:
        ap.error(f"--ms-size takes WxH, got {args.ms_size!r}")
    try:
        width, height = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        ap.error(f"--size takes WxH, got {args.size!r}")
    dev = device.get(args.device)
    cores = int(dev.device.max_compute_units)
    args.basis = (args.time, cores)
    path = result_path("error", dev, "-".join(t for t in (args.tag, "quick" if args.quick else None) if t))
    record = {"benchmark": "error", "size": [width, height], "repeat": args.repeat,
              "quick": args.quick, **device_info(dev),
              "reference_volume": f"tracking, {args.ref_batches} batches (spp per scene below)",
              "reference_glass": GLASS_REF, "time_basis": args.time,
              "time_label": ("kernel ms per frame (median of runs)" if args.time == "kernel" else
                             f"kernel-equivalent ms: CPU ms of the launches / {cores} cores (median)"),
              "load_average_start": os.getloadavg(), "volume": [], "glass": [],
              "multiple_scattering": [], "defaults": [], "command": [], "denoise": []}
    t0 = time.perf_counter()
    if args.command_refs:
        run_command(dev, args, record)
        write_json(path, record)
    if args.defaults:
        run_defaults(dev, args, record)
        write_json(path, record)
    if args.denoise:
        run_denoise(dev, args, record)
        write_json(path, record)
    if not args.no_volume:
        run_volume(dev, width, height, args, record)
        write_json(path, record)
    if not args.no_ms:
        run_ms(dev, args, record)
        write_json(path, record)
    if not args.no_glass:
        run_glass(dev, width, height, args, record)
    record["bench_s"] = time.perf_counter() - t0
    record["load_average_end"] = os.getloadavg()
    write_json(path, record)
    plot(record, path.with_suffix(".png"))
    print(f"wrote {path} and {path.with_suffix('.png').name} in {record['bench_s']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
