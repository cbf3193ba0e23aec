"""Comparison with peers: OpenVDB's `vdb_render` and Mitsuba 3 against volrender's own
converged reference, on the same VDB file, image size, camera, sun and medium.

    .venv/bin/python bench/peers.py [--size 320x240] [--file smoke.vdb] [--quick]
        [--device SPEC] [--mitsuba-variant auto|llvm_ad_rgb|scalar_rgb]
        [--no-vdb-render] [--no-mitsuba] [--tag pocl]

`bash run.sh peers` installs the optional peers (Debian's libopenvdb-tools and libllvm16,
mitsuba 3.5.x into .venv) and runs this. Two scenes, each matched to one peer's model:

* vdb scene (peer: vdb_render): isotropic phase, because vdb_render has no phase function;
  vdb_render shoots one ray through each pixel centre, so the reference is volrender at
  one sample per pixel (which goes through the pixel centre, DESIGN.md) at a fine step,
  averaged over seeds (only the step jitter differs between seeds).
* Mitsuba scene (peer: Mitsuba 3 `volpath`, max_depth=2 = single scattering):
  volrender's default two-lobe phase (0.6, -0.3, 0.8) as a `blendphase` of two `hg`; box
  pixel filter on both sides; the reference is volrender at a fine step rendered at 3x3
  the resolution (one ray through each sub-pixel centre) and box-downsampled.

Errors are relative RMSE over all pixels and RGB channels:
sqrt(mean((img - ref)^2) / mean(ref^2)). Times are wall-clock seconds on this machine:
in-process render calls for volrender and Mitsuba (after a warm-up that builds the
programs), and for vdb_render both its own "ray-tracing ... completed in" time and the
process wall time (median of 3). Writes bench/results/peers_<tag>.json and .png.
docs/peers.md explains every convention mapping.
"""
from __future__ import annotations

import argparse
import importlib.metadata
import math
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import (render_volume, result_path, device_info, missing_data,  # noqa: E402
                          shared_data, stats, write_json)
from volrender import camera as camera_mod, device, layout, vdb  # noqa: E402
from volrender.lights import Sun  # noqa: E402
from volrender.volume import VolumeSettings  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_FILE = shared_data() / "vdb" / "smoke.vdb"
LIBLLVM16 = "/usr/lib/x86_64-linux-gnu/libLLVM-16.so.1"
# per-file scene: density scale (sigma_t per world unit per grid value), vertical fov,
# sun irradiance. smoke: as bench/volume.py; demo_cloud: as `bash run.sh demo`.
SCENES = {"smoke": dict(density_scale=1.0, fov=40.0, irradiance=6.0),
          "demo_cloud": dict(density_scale=6.0, fov=28.0, irradiance=10.0)}
SUN_DIR = (-0.6, -1.0, -0.5)           # propagation direction (the volrender default)
ALBEDO = 0.9
MIXED_PHASE = (0.6, -0.3, 0.8)         # volrender's default: w HG(g1) + (1-w) HG(g2)
ISO_PHASE = (0.0, 0.0, 1.0)
TARGETS = (0.05, 0.02)                 # relative RMSE for time-to-error


def log(msg):
    print(msg, flush=True)


def rel_rmse(img, ref) -> float:
    img, ref = np.asarray(img, np.float64), np.asarray(ref, np.float64)
    return float(np.sqrt(np.mean((img - ref) ** 2) / np.mean(ref ** 2)))


def compare(img, ref) -> dict:
    """Error of img against ref, plus the systematic part: the image-mean ratio and the
    least-squares scale s minimising |s img - ref| with the error left after it."""
    img, ref = np.asarray(img, np.float64), np.asarray(ref, np.float64)
    s = float((img * ref).sum() / max((img * img).sum(), 1e-300))
    return {"rel_rmse": rel_rmse(img, ref), "rmse": float(np.sqrt(np.mean((img - ref) ** 2))),
            "mean_ratio": float(img.mean() / ref.mean()), "ls_scale": s,
            "rel_rmse_after_scale": rel_rmse(s * img, ref)}


def downsample(a, f):
    h, w, c = a.shape
    return a.reshape(h // f, f, w // f, f, c).mean(axis=(1, 3))


def fmt(v):
    return ",".join(f"{float(x):.9g}" for x in v)


class Clock:
    """Wall and CPU seconds of a block: CPU of this process (every thread: PoCL's and
    Dr.Jit's workers run in it) plus that of finished child processes (vdb_render)."""

    def __enter__(self):
        self.w0, self.c0 = time.perf_counter(), self._cpu()
        return self

    def __exit__(self, *exc):
        self.wall, self.cpu = time.perf_counter() - self.w0, self._cpu() - self.c0

    @staticmethod
    def _cpu():
        ch = resource.getrusage(resource.RUSAGE_CHILDREN)
        return time.process_time() + ch.ru_utime + ch.ru_stime


def loadavg():
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


# --------------------------------------------------------------------------- volrender

def vr_render(b, cam, sun, scene, phase, step, shadow_step, spp, seed, dev):
    s = VolumeSettings(density_scale=scene["density_scale"], albedo=ALBEDO, phase=phase,
                       step=step, shadow_step=shadow_step, spp=spp, seed=seed)
    with Clock() as c:
        r = render_volume(b, cam, [sun], s, dev)
    return r.rgba[..., :3].astype(np.float64), c, r.kernel_ms


def scaled_camera(cam, f):
    return camera_mod.Camera(cam.origin, cam.target, cam.up, cam.fov, cam.width * f, cam.height * f)


def reference(b, cam, sun, scene, phase, step, shadow_step, factor, seeds, dev, label):
    """Mean of one render per seed at 1 spp on a factor x factor sub-pixel grid (factor 1:
    pixel centres), box-downsampled; its standard error from the two halves."""
    big = scaled_camera(cam, factor)
    imgs, secs = [], []
    for seed in seeds:
        img, c, _ = vr_render(b, big, sun, scene, phase, step, shadow_step, 1, seed, dev)
        imgs.append(downsample(img, factor))
        secs.append(c.wall)
        log(f"  reference {label}: seed {seed} {c.wall:.1f} s")
    h = len(imgs) // 2
    a, c = np.mean(imgs[:h], axis=0), np.mean(imgs[h:], axis=0)
    ref = np.mean(imgs, axis=0)
    return ref, {"step_voxels": step, "shadow_step_voxels": shadow_step, "spp": 1,
                 "supersample": factor, "seeds": list(seeds), "render_s": secs,
                 "halves_rel_rmse": rel_rmse(a, c),
                 "std_error_rel": rel_rmse(a, c) / 2.0,
                 "note": ("std_error_rel = rel. RMSE between the two halves / 2: the noise "
                          "of the mean (step jitter only; the sub-pixel positions are the "
                          "same in every seed)")}


# --------------------------------------------------------------------------- vdb_render

def vdb_mapping(b, cam, sun, scene):
    """vdb_render options for the vdb scene, and the mapping that justifies each."""
    m = np.asarray(b.index_to_world, np.float64)[:3, :3]
    cols = np.linalg.norm(m, axis=0)
    uniform = bool(np.allclose(cols, cols.mean(), rtol=1e-6) and
                   np.allclose(m.T @ m, np.diag(cols ** 2), atol=1e-9 * cols.mean() ** 2))
    if not uniform:
        warnings.warn("the grid's voxels are not cubes: vdb_render's per-voxel coefficients "
                      "cannot match a per-world-unit sigma in every direction")
    vs = float(cols.mean())
    sig_t_voxel = scene["density_scale"] * vs
    colour = sun.irradiance / (4.0 * math.pi)
    fov_h = math.degrees(2.0 * math.atan(math.tan(math.radians(cam.fov) / 2.0) * cam.width / cam.height))
    opts = ["-name", b.grid_name, "-res", f"{cam.width}x{cam.height}",
            "-translate", fmt(cam.origin), "-lookat", fmt(cam.target), "-up", fmt(cam.up),
            "-fov", f"{fov_h:.9g}",
            "-scatter", fmt([ALBEDO * sig_t_voxel] * 3), "-absorb", fmt([(1 - ALBEDO) * sig_t_voxel] * 3),
            "-light", fmt([*(-np.asarray(sun.direction)), colour, colour, colour]),
            "-gain", "0", "-cutoff", "1e-6", "-compression", "none", "-cpus", "0", "-v"]
    mapping = {
        "camera": "-translate = origin, -lookat = target, -up = up (aim: camera -z at the target)",
        "fov": (f"vdb_render -fov is the HORIZONTAL field of view (focal length from the "
                f"aperture width): fov_h = 2 atan(tan(fov_v/2) W/H) = {fov_h:.6g} deg for "
                f"volrender's vertical {cam.fov:g} deg"),
        "coefficients": (f"-scatter/-absorb are per VOXEL length (vdb_render marches in index "
                         f"space): scatter = albedo * density_scale * voxel_size = "
                         f"{ALBEDO * sig_t_voxel:.6g}, absorb = (1-albedo) * density_scale * "
                         f"voxel_size = {(1 - ALBEDO) * sig_t_voxel:.6g} (voxel size {vs:.6g})"),
        "light": ("-light X,Y,Z points TOWARDS the light (the shadow ray's direction): "
                  "minus volrender's propagation direction"),
        "light_colour": (f"vdb_render adds albedo * colour * T_light * T * (1 - exp(-sigma_t dt)) "
                         f"per step: no phase function, so colour = E * p_iso = E / (4 pi) = "
                         f"{colour:.6g} for E = {sun.irradiance:g}, with volrender's phase "
                         f"isotropic (0,0,1)"),
        "gain": "-gain 0: vdb_render's fake multiple scattering (shadow density / (1 + gain t)) off",
        "cutoff": ("-cutoff 1e-6: density below it is skipped, and a ray stops when "
                   "|T_rgb|^2 < cutoff (T < 5.8e-4); volrender stops at T < 1e-5"),
        "pixels": "vdb_render: one ray through each pixel centre (no pixel samples for volumes)",
        "sampling": ("vdb_render samples at t = step * ceil(t0/step) on each active span "
                     "(deterministic); volrender at t0 + (k + u) step, u random per pixel"),
        "background": "none: vdb_render's RGB is the in-scattered light only (volrender background 0)",
        "voxel_cubic": uniform,
    }
    return opts, mapping


RT_TIME = re.compile(r"ray-tracing[^\n]*\n[^\n]*completed in ([0-9.eE+-]+) sec")


def read_exr_rgb(path):
    import OpenEXR
    with OpenEXR.File(str(path), separate_channels=True) as f:
        ch = f.parts[0].channels
        return np.stack([np.asarray(ch[c].pixels, np.float64) for c in "RGB"], axis=-1)


def run_vdb_render(exe, path, opts, out, repeat):
    cmd = [exe, str(path), str(out), *opts]
    walls, cpus, renders = [], [], []
    for _ in range(repeat):
        with Clock() as c:
            p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode != 0:
            raise RuntimeError(f"vdb_render failed ({p.returncode}): {p.stderr.strip()[-400:]}")
        m = RT_TIME.search(p.stdout)
        walls.append(c.wall)
        cpus.append(c.cpu)
        renders.append(float(m.group(1)) if m else float("nan"))
    return cmd, read_exr_rgb(out), walls, cpus, renders


def vdb_section(args, b, cam, sun, scene, dev, exe, tmp):
    log("vdb scene: isotropic phase, pixel centres")
    ref_step = (0.25, 0.5) if args.quick else (0.1, 0.25)
    ref, ref_info = reference(b, cam, sun, scene, ISO_PHASE, *ref_step, 1, (2001, 2002), dev,
                              "pixel centres")
    opts, mapping = vdb_mapping(b, cam, sun, scene)
    steps = [(1.0, 3.0), (0.5, 1.0)] if args.quick else [(1.0, 3.0), (1.0, 1.0), (0.5, 1.0), (0.25, 0.5)]
    out = tmp / "vdb.exr"
    rows = []
    # warm-up: file cache, TBB start-up
    subprocess.run([exe, str(args.file), str(out), *opts, "-step", "2", "-shadowstep", "4"],
                   capture_output=True, text=True)
    vr_render(b, cam, sun, scene, ISO_PHASE, 0.5, 1.0, 1, 0, dev)          # program build
    for st, sst in steps:
        cmd, img, walls, cpus, renders = run_vdb_render(exe, args.file, [*opts, "-step", f"{st:g}",
                                                                   "-shadowstep", f"{sst:g}"],
                                                  out, args.repeat)
        vimg, vwall, vcpu, vkern = None, [], [], []
        for _ in range(args.repeat):
            vimg, c, k = vr_render(b, cam, sun, scene, ISO_PHASE, st, sst, 1, 0, dev)
            vwall.append(c.wall)
            vcpu.append(c.cpu)
            vkern.append(k / 1e3)
        row = {"step_voxels": st, "shadow_step_voxels": sst,
               "vdb_render": {"command": " ".join(cmd), "render_s": stats(renders),
                              "process_wall_s": stats(walls), "process_cpu_s": stats(cpus),
                              **compare(img, ref)},
               "volrender": {"spp": 1, "seed": 0, "render_call_s": stats(vwall), "cpu_s": stats(vcpu),
                             "kernel_s": stats(vkern), **compare(vimg, ref)}}
        row["time_ratio_vdb_over_volrender"] = (row["vdb_render"]["render_s"]["median"]
                                                / row["volrender"]["render_call_s"]["median"])
        row["cpu_ratio_vdb_over_volrender"] = (row["vdb_render"]["process_cpu_s"]["median"]
                                               / row["volrender"]["cpu_s"]["median"])
        rows.append(row)
        log(f"  step {st:g}/{sst:g}: vdb_render {row['vdb_render']['render_s']['median']:.2f} s "
            f"(process {row['vdb_render']['process_wall_s']['median']:.2f} s) rel {row['vdb_render']['rel_rmse']:.4f} "
            f"mean ratio {row['vdb_render']['mean_ratio']:.4f} | volrender "
            f"{row['volrender']['render_call_s']['median']:.2f} s rel {row['volrender']['rel_rmse']:.4f} "
            f"| x{row['time_ratio_vdb_over_volrender']:.1f} (CPU x{row['cpu_ratio_vdb_over_volrender']:.1f})")
    # end to end, same step as volrender's default: the CLI as a process against vdb_render's
    cli = cli_timing(args, cam, sun, scene, tmp)
    return {"reference": ref_info, "mapping": mapping, "options": opts, "rows": rows, "cli": cli}


def cli_timing(args, cam, sun, scene, tmp):
    exe = ROOT / ".venv" / "bin" / "volrender"
    if not exe.exists():
        return None
    out = tmp / "vr.exr"
    cmd = [str(exe), "render", str(args.file), "-o", str(out), "--size", f"{cam.width}x{cam.height}",
           "--origin", fmt(cam.origin), "--target", fmt(cam.target), "--up", fmt(cam.up),
           "--fov", f"{cam.fov:g}", f"--sun={fmt([*sun.direction, sun.irradiance])}",
           "--density-scale", f"{scene['density_scale']:g}", "--albedo", f"{ALBEDO:g}",
           "--phase", fmt(ISO_PHASE), "--step", "0.5", "--shadow-step", "1", "--spp", "1",
           "--no-progress"]
    if args.device:
        cmd += ["--device", args.device]
    walls, cpus = [], []
    for _ in range(args.repeat):
        with Clock() as c:
            p = subprocess.run(cmd, capture_output=True, text=True)
        walls.append(c.wall)
        cpus.append(c.cpu)
        if p.returncode != 0:
            return {"command": " ".join(cmd), "error": p.stderr.strip()[-400:]}
    log(f"  volrender CLI process (step 0.5/1, 1 spp): {stats(walls)['median']:.2f} s")
    return {"command": " ".join(cmd), "process_wall_s": stats(walls), "process_cpu_s": stats(cpus),
            "note": "whole process: Python start, imports, VDB -> bricks, program build (cached), render, EXR"}


# --------------------------------------------------------------------------- Mitsuba

def import_mitsuba(variant):
    """(mitsuba module, variant, note). DRJIT_LIBLLVM_PATH defaults to Debian's LLVM 16."""
    if "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.exists(LIBLLVM16):
        os.environ["DRJIT_LIBLLVM_PATH"] = LIBLLVM16
    import mitsuba as mi
    tried = []
    for v in ([variant] if variant != "auto" else ["llvm_ad_rgb", "scalar_rgb"]):
        try:
            mi.set_variant(v)
            if v.startswith("llvm"):
                import drjit as dr
                x = mi.Float([1.0, 2.0]) + 1.0
                dr.eval(x)
            return mi, v, "; ".join(tried)
        except Exception as e:  # the LLVM backend fails with AttributeError/RuntimeError
            tried.append(f"{v}: {str(e).splitlines()[0][:200]}")
    raise RuntimeError("no usable Mitsuba variant (" + "; ".join(tried) + ")")


def dense_grid(b):
    """The brick layout as a dense array over local voxels 0..dims*8 (values at voxel
    centres, x-major [i, j, k]); zeros where no brick is stored."""
    n = np.asarray(b.dims, np.int64) * layout.BRICK + 1
    dense = np.zeros(tuple(int(v) for v in n), np.float32)
    d1, d2 = int(b.dims[1]), int(b.dims[2])
    for idx in np.flatnonzero(b.table >= 0):
        bx, r = divmod(int(idx), d1 * d2)
        by, bz = divmod(r, d2)
        sl = tuple(slice(c * layout.BRICK, c * layout.BRICK + layout.APRON) for c in (bx, by, bz))
        dense[sl] = b.data[b.table[idx]]
    return dense


def mitsuba_scene(mi, b, cam, sun, scene, phase, spp=1, max_depth=2, rr_depth=1000):
    """Scene dict (for mi.load_dict) and a JSON-able description of it. max_depth 2 is
    single scattering; volrender's --max-depth N is Mitsuba's N + 1 (Mitsuba counts the
    segment to the light)."""
    dense = dense_grid(b)
    n = np.array(dense.shape, np.float64)
    # Mitsuba's gridvolume spans [0,1]^3 with CELL-CENTRED data: data[z, y, x] sits at
    # ((x, y, z) + 0.5) / res. volrender's local voxel l sits at local coordinate l, so the
    # grid's unit cube is the local box [-0.5, n - 0.5]: to_world = L2W . T(-0.5) . S(n).
    t = np.eye(4)
    t[:3, 3] = -0.5
    grid_to_world = np.asarray(b.local_to_world, np.float64) @ t @ np.diag([*n, 1.0])
    # the bounding cube [-1, 1]^3 -> the same box
    cube_to_world = grid_to_world @ np.array([[.5, 0, 0, .5], [0, .5, 0, .5], [0, 0, .5, .5], [0, 0, 0, 1.]])
    g1, g2, w = phase
    if w >= 1.0:
        ph = {"type": "hg", "g": g1}
    else:
        # blendphase: p = (1 - weight) phase1 + weight phase2 (weight = share of phase2)
        ph = {"type": "blendphase", "weight": 1.0 - w,
              "phase1": {"type": "hg", "g": g1}, "phase2": {"type": "hg", "g": g2}}
    T = mi.ScalarTransform4f
    desc = {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": max_depth, "rr_depth": rr_depth},
        "sensor": {"type": "perspective", "fov": cam.fov, "fov_axis": "y",
                   "to_world": f"look_at(origin={list(cam.origin)}, target={list(cam.target)}, up={list(cam.up)})",
                   "film": {"type": "hdrfilm", "width": cam.width, "height": cam.height,
                            "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "sun": {"type": "directional", "direction": list(sun.direction),
                "irradiance": {"type": "rgb", "value": sun.irradiance}},
        "volume": {"type": "cube", "to_world": cube_to_world.tolist(), "bsdf": {"type": "null"},
                   "interior": {"type": "heterogeneous", "albedo": ALBEDO,
                                "scale": scene["density_scale"],
                                "sigma_t": {"type": "gridvolume",
                                            "grid": f"VolumeGrid(dense[x,y,z].transpose(2,1,0)[..., None]), "
                                                    f"shape (z,y,x,1) = {[*dense.shape[::-1], 1]}",
                                            "to_world": grid_to_world.tolist()},
                                "phase": ph}},
    }
    d = {
        "type": "scene",
        "integrator": dict(desc["integrator"]),
        "sensor": {**desc["sensor"], "to_world": T.look_at(origin=list(map(float, cam.origin)),
                                                           target=list(map(float, cam.target)),
                                                           up=list(map(float, cam.up)))},
        "sun": desc["sun"],
        "volume": {**desc["volume"], "to_world": T(cube_to_world.tolist()),
                   "interior": {**desc["volume"]["interior"],
                                "sigma_t": {"type": "gridvolume",
                                            "grid": mi.VolumeGrid(np.ascontiguousarray(dense.transpose(2, 1, 0))[..., None]),
                                            "to_world": T(grid_to_world.tolist())}}},
    }
    return d, desc, grid_to_world


def grid_probe(mi, b, grid_to_world, n_points=4000):
    """Max |Mitsuba gridvolume - volrender trilinear| at random world points in the box."""
    vol = mi.load_dict({"type": "gridvolume", "grid": mi.VolumeGrid(
        np.ascontiguousarray(dense_grid(b).transpose(2, 1, 0))[..., None]),
        "to_world": mi.ScalarTransform4f(grid_to_world.tolist())})
    lo, hi = b.world_bounds()
    pts = lo + (hi - lo) * np.random.default_rng(1).random((n_points, 3))
    ours = b.sample_world(pts)
    if mi.variant().startswith("scalar"):
        pts, ours = pts[:300], ours[:300]
        vals = []
        for p in pts:
            it = mi.Interaction3f()
            it.p = mi.Point3f(*map(float, p))
            vals.append(float(vol.eval_1(it)))
        theirs = np.array(vals)
    else:
        it = mi.Interaction3f()
        it.p = mi.Point3f(*[pts[:, i].astype(np.float32) for i in range(3)])
        theirs = np.array(vol.eval_1(it), np.float64)
    return float(np.abs(theirs - ours).max()), float(np.abs(ours).max())


def curve_fit(points):
    """Least squares err^2 = a / spp + b over points with spp >= 2 (random pixel
    positions): a = noise^2 at 1 spp, b = the floor (systematic difference + the
    reference's own error). b is poorly determined when a / spp >> b: a diagnostic."""
    pts = [p for p in points if p["spp"] >= 2]
    if len(pts) < 2:
        return None
    A = np.array([[1.0 / p["spp"], 1.0] for p in pts])
    y = np.array([p["rel_rmse"] ** 2 for p in pts])
    (a, bb), *_ = np.linalg.lstsq(A, y, rcond=None)
    sec_per_spp = float(np.median([p["time_s"] / p["spp"] for p in pts]))
    return {"noise_1spp": float(math.sqrt(max(a, 0.0))), "floor": float(math.sqrt(max(bb, 0.0))),
            "floor_sq": float(bb), "sec_per_spp": sec_per_spp}


def time_to_error(points, target):
    """Time to reach a relative RMSE: log-log interpolation between the measured points
    that bracket it; at or before the first point, that point's time (an upper bound);
    beyond the last, extrapolated from the highest-spp point with err ~ 1/sqrt(spp) and
    that point's seconds per spp (flagged: optimistic if an error floor remains)."""
    pts = sorted(points, key=lambda p: p["time_s"])
    if not pts:
        return {"time_s": None, "how": "no points"}
    for i, p in enumerate(pts):
        if p["rel_rmse"] <= target:
            if i == 0:
                return {"time_s": p["time_s"], "spp": p["spp"],
                        "how": f"first point ({p['spp']} spp) already below: an upper bound"}
            q = pts[i - 1]
            f = (math.log(target) - math.log(q["rel_rmse"])) / (math.log(p["rel_rmse"]) - math.log(q["rel_rmse"]))
            t = math.exp(math.log(q["time_s"]) + f * (math.log(p["time_s"]) - math.log(q["time_s"])))
            return {"time_s": t, "how": f"interpolated between {q['spp']} and {p['spp']} spp"}
    last = max(pts, key=lambda p: p["spp"])
    spp = last["spp"] * (last["rel_rmse"] / target) ** 2
    return {"time_s": spp * last["time_s"] / last["spp"], "spp": spp,
            "how": f"extrapolated from {last['spp']} spp with err ~ 1/sqrt(spp)"}


def mitsuba_section(args, b, cam, sun, scene, dev, mi, variant, note):
    log(f"Mitsuba scene: phase {MIXED_PHASE}, box filter; Mitsuba variant {variant}"
        + (f" (not available: {note})" if note else ""))
    ref_step = (0.25, 0.5) if args.quick else (0.1, 0.25)
    ref, ref_info = reference(b, cam, sun, scene, MIXED_PHASE, *ref_step, 3, (1001, 1002), dev, "3x3 sub-pixels")
    d, desc, g2w = mitsuba_scene(mi, b, cam, sun, scene, MIXED_PHASE)
    probe, vmax = grid_probe(mi, b, g2w)
    log(f"  grid probe: max |mitsuba - volrender| = {probe:.2e} (values up to {vmax:.3g})")
    with Clock() as c:
        sc = mi.load_dict(d)
    load_s = c.wall
    with Clock() as c:
        np.asarray(mi.render(sc, spp=1, seed=999))
    warm_s = c.wall
    mi_points = []
    for spp in args.mi_spp:
        with Clock() as c:
            img = np.asarray(mi.render(sc, spp=spp, seed=spp), np.float64)[..., :3]
        mi_points.append({"spp": spp, "wall_s": c.wall, "cpu_s": c.cpu, **compare(img, ref)})
        log(f"  mitsuba {spp:5d} spp {c.wall:7.2f} s (CPU {c.cpu:7.2f} s) rel {mi_points[-1]['rel_rmse']:.4f} "
            f"mean ratio {mi_points[-1]['mean_ratio']:.4f}")
    del sc
    vr_render(b, cam, sun, scene, MIXED_PHASE, 0.5, 1.0, 1, 0, dev)    # program build
    vr_points = []
    for spp in args.vr_spp:
        img, c, k = vr_render(b, cam, sun, scene, MIXED_PHASE, 0.5, 1.0, spp, spp, dev)
        vr_points.append({"spp": spp, "wall_s": c.wall, "cpu_s": c.cpu, "kernel_s": k / 1e3,
                          "step_voxels": 0.5, "shadow_step_voxels": 1.0, **compare(img, ref)})
        log(f"  volrender {spp:3d} spp {c.wall:7.2f} s (CPU {c.cpu:7.2f} s) rel {vr_points[-1]['rel_rmse']:.4f} "
            f"mean ratio {vr_points[-1]['mean_ratio']:.4f}")
    cores = os.cpu_count() or 1
    fits, tte = {}, {}
    for basis in ("wall", "cpu"):
        # time axis: wall seconds, or CPU seconds / cores (a stand-in that other load on
        # the machine inflates less)
        for p in (*vr_points, *mi_points):
            p["time_s"] = p["wall_s"] if basis == "wall" else p["cpu_s"] / cores
        fits[basis] = {"volrender": curve_fit(vr_points), "mitsuba": curve_fit(mi_points)}
        # like for like: volrender's spp >= 2 (random positions in the pixel, as Mitsuba's
        # every spp); "volrender_all" also counts 1 spp, which goes through the pixel centre
        curves = {"volrender_box": [p for p in vr_points if p["spp"] >= 2],
                  "volrender_all": vr_points, "mitsuba": mi_points}
        tte[basis] = {}
        for target in TARGETS:
            row = {name: time_to_error(pts, target) for name, pts in curves.items()}
            a, c = row["volrender_box"]["time_s"], row["mitsuba"]["time_s"]
            row["ratio_mitsuba_over_volrender_box"] = (c / a) if a and c else None
            tte[basis][f"{target:g}"] = row
            def sec(x):
                return "n/a" if x is None else f"{x:.2f} s"
            log(f"  [{basis}] time to {target:.0%}: volrender {sec(a)} ({row['volrender_box']['how']}; "
                f"with 1 spp: {sec(row['volrender_all']['time_s'])}), mitsuba {sec(c)} "
                f"({row['mitsuba']['how']})"
                + ("" if row["ratio_mitsuba_over_volrender_box"] is None
                   else f": x{row['ratio_mitsuba_over_volrender_box']:.0f}"))
    for p in (*vr_points, *mi_points):
        p["time_s"] = p["wall_s"] if args.time == "wall" else p["cpu_s"] / cores
    return {"reference": ref_info, "variant": variant, "variant_fallback": note,
            "versions": {"mitsuba": importlib.metadata.version("mitsuba"),
                         "drjit": importlib.metadata.version("drjit"),
                         "DRJIT_LIBLLVM_PATH": os.environ.get("DRJIT_LIBLLVM_PATH")},
            "scene": desc, "grid_probe_max_abs_diff": probe, "grid_max": vmax,
            "load_s": load_s, "first_render_s": warm_s, "mitsuba": mi_points,
            "volrender": vr_points, "fit": fits, "time_to_error": tte,
            "mapping": {
                "phase": ("blendphase weight = 1 - w, phase1 = hg(g1), phase2 = hg(g2): Mitsuba's "
                          "blendphase is (1 - weight) phase1 + weight phase2; its hg has the same "
                          "sign as volrender (g > 0 forward)"),
                "fov": "fov_axis = 'y' (Mitsuba's default is 'x'); fov = volrender's vertical fov",
                "grid": ("gridvolume data[z, y, x] = dense[x, y, z] (transpose(2, 1, 0)); cell-centred "
                         "[0,1]^3, so to_world = local_to_world . T(-0.5) . S(n) puts sample l at voxel centre l"),
                "medium": "heterogeneous: sigma_t = scale * grid, scale = density_scale, albedo = albedo",
                "bounds": "a cube with a null BSDF around the same box carries the medium",
                "sun": "directional: direction = propagation direction, irradiance = E",
                "integrator": "volpath max_depth = 2 (single scattering), rr_depth = 1000 (no roulette)",
                "pixels": "hdrfilm rfilter box, independent sampler: the same box-filter estimand as volrender's spp >= 2",
                "background": "no environment emitter: background 0 on both sides",
            }}


# --------------------------------------------------------------------------- path tracing

PATH_FILE = DEFAULT_FILE.parent / "wdas_cloud_sixteenth.vdb"
PATH_TARGET = 0.02


def noise_stats(imgs, secs, spp):
    """Per-pixel noise of an unbiased estimator from independent batches of `spp`
    samples: its expected error against the truth is its standard deviation, so
    rel_noise_1spp = sqrt(mean per-pixel variance of one batch x spp) / value rms, and
    the time to a relative RMSE e is (rel_noise_1spp / e)^2 x seconds per spp."""
    imgs = np.asarray(imgs, np.float64)
    mean = imgs.mean(0)
    var = imgs.var(0, ddof=1)
    rms = float(np.sqrt((mean ** 2).mean()))
    rel1 = float(np.sqrt(var.mean() * spp) / rms)
    per_spp = float(np.median(secs) / spp)
    return mean, var / len(imgs), {"batches": len(imgs), "spp_per_batch": spp,
                                   "total_spp": len(imgs) * spp, "batch_s": list(map(float, secs)),
                                   "s_per_spp": per_spp, "rel_noise_1spp": rel1,
                                   "value_rms": rms,
                                   "time_to_target_s": (rel1 / PATH_TARGET) ** 2 * per_spp,
                                   "spp_to_target": (rel1 / PATH_TARGET) ** 2}


def path_section(args, dev, mi, variant):
    """volrender --estimator path against Mitsuba volpath at the same max depth on the
    WDAS cloud: agreement (image mean, per-pixel z of the difference) and the time each
    needs to reach 2% relative RMSE, from the measured noise (both are unbiased)."""
    path = args.path_file
    if not path.exists():
        return {"skipped": f"{path} not found"}
    b = vdb.load_volume(path)
    w, h = args.path_size
    cam = camera_mod.frame_bounds(*b.world_bounds(), w, h, fov=40.0)
    sun = Sun(SUN_DIR, 6.0)
    scale = 0.05 if path.stem.startswith("wdas") else SCENES.get(path.stem, {}).get("density_scale", 1.0)
    depth = args.path_depth
    log(f"path scene: {path.name} {w}x{h}, density x{scale}, albedo {ALBEDO}, phase {MIXED_PHASE}, "
        f"volrender --max-depth {depth} = Mitsuba max_depth {depth + 1}")
    s = VolumeSettings(density_scale=scale, albedo=ALBEDO, phase=MIXED_PHASE, estimator="path",
                       max_depth=depth, spp=args.path_vr_spp)
    render_volume(b, cam, [sun], replace(s, spp=1), dev)                 # program build
    vr_imgs, vr_secs, vr_cpu = [], [], []
    for k in range(args.path_batches):
        with Clock() as c:
            r = render_volume(b, cam, [sun], replace(s, seed=500 + k), dev)
        vr_imgs.append(r.rgba[..., :3])
        vr_secs.append(c.wall)
        vr_cpu.append(c.cpu)
    v_mean, v_var, v_stats = noise_stats(vr_imgs, vr_secs, args.path_vr_spp)
    v_stats["cpu_s_per_spp"] = float(np.median(vr_cpu) / args.path_vr_spp)
    log(f"  volrender: {v_stats['total_spp']} spp, {v_stats['s_per_spp'] * 1e3:.1f} ms/spp, "
        f"noise at 1 spp {v_stats['rel_noise_1spp']:.1%}")
    d, desc, _ = mitsuba_scene(mi, b, cam, sun, {"density_scale": scale}, MIXED_PHASE,
                               max_depth=depth + 1, rr_depth=5)
    sc = mi.load_dict(d)
    np.asarray(mi.render(sc, spp=1, seed=99))                             # JIT warm-up
    mi_imgs, mi_secs, mi_cpu = [], [], []
    for k in range(args.path_batches):
        with Clock() as c:
            img = np.asarray(mi.render(sc, spp=args.path_mi_spp, seed=700 + k), np.float64)[..., :3]
        mi_imgs.append(img)
        mi_secs.append(c.wall)
        mi_cpu.append(c.cpu)
    del sc
    m_mean, m_var, m_stats = noise_stats(mi_imgs, mi_secs, args.path_mi_spp)
    m_stats["cpu_s_per_spp"] = float(np.median(mi_cpu) / args.path_mi_spp)
    log(f"  mitsuba: {m_stats['total_spp']} spp, {m_stats['s_per_spp'] * 1e3:.1f} ms/spp, "
        f"noise at 1 spp {m_stats['rel_noise_1spp']:.1%}")
    # the variance floor keeps pixels whose few batches happened to agree exactly (dim
    # pixels, or the sky) from dividing by ~0
    floor = (1e-4 * v_stats["value_rms"]) ** 2
    z = (m_mean - v_mean) / np.sqrt(np.maximum(m_var + v_var, floor))
    lit = (v_mean + m_mean).max(axis=-1) > 1e-3 * max(float(v_mean.max()), 1e-30)
    se_ratio = float(np.sqrt(m_var.sum() / m_mean.sum() ** 2 + v_var.sum() / v_mean.sum() ** 2))
    agree = {"mean_ratio_mitsuba_over_volrender": float(m_mean.mean() / v_mean.mean()),
             "mean_ratio_se": se_ratio,
             "z_rms": float(np.sqrt((z[lit] ** 2).mean())),
             "frac_abs_z_over_3": float((np.abs(z[lit]) > 3).mean()),
             "frac_abs_z_over_4": float((np.abs(z[lit]) > 4).mean()),
             "pixels": int(lit.sum()),
             "note": ("z = (Mitsuba - volrender) / sqrt(se_M^2 + se_V^2) per pixel and channel "
                      "(se from K batches each); the same estimand gives z about t-distributed: "
                      "rms ~ sqrt((K-1)/(K-3)) (1.18 for K = 8) and ~2% beyond 3 for K = 8 "
                      "(0.27% for a normal)")}
    ratio = {basis: (m_stats[k] * m_stats["spp_to_target"]) / (v_stats[k] * v_stats["spp_to_target"])
             for basis, k in (("wall", "s_per_spp"), ("cpu", "cpu_s_per_spp"))}
    scale_px = 640 * 480 / (w * h)
    log(f"  agreement: image mean Mitsuba / volrender {agree['mean_ratio_mitsuba_over_volrender']:.4f} "
        f"(+- {se_ratio:.4f}), per-pixel z rms {agree['z_rms']:.2f}, |z| > 3: {agree['frac_abs_z_over_3']:.2%}")
    log(f"  time to {PATH_TARGET:.0%}: volrender {v_stats['time_to_target_s']:.1f} s, Mitsuba "
        f"{m_stats['time_to_target_s']:.1f} s at {w}x{h} (x{scale_px:.0f} at 640x480): "
        f"Mitsuba / volrender x{ratio['wall']:.1f} (CPU x{ratio['cpu']:.1f})")
    return {"file": str(path), "size": [w, h], "density_scale": scale, "albedo": ALBEDO,
            "phase": MIXED_PHASE, "volrender_max_depth": depth, "mitsuba_max_depth": depth + 1,
            "mitsuba_rr_depth": 5, "volrender_rr_depth": 4, "variant": variant,
            "volrender": v_stats, "mitsuba": m_stats, "agreement": agree,
            "target_rel_rmse": PATH_TARGET, "time_ratio_mitsuba_over_volrender": ratio,
            "time_to_target_640x480_s": {"volrender": v_stats["time_to_target_s"] * scale_px,
                                         "mitsuba": m_stats["time_to_target_s"] * scale_px,
                                         "how": "scaled by the pixel count from the measured size"},
            "scene": desc}


# --------------------------------------------------------------------------- plot

def plot(payload, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter
    ms, vs = payload.get("mitsuba_scene"), payload.get("vdb_scene")
    ps = payload.get("path_scene")
    ps = ps if ps and "volrender" in ps else None
    cores = payload["cpu_count"] or 1
    if payload["time_basis"] == "wall":
        xlabel = "render time (wall), s"
        vr_t = lambda r: r["volrender"]["render_call_s"]["median"]  # noqa: E731
        vdb_t = lambda r: r["vdb_render"]["render_s"]["median"]  # noqa: E731
    else:
        xlabel = f"CPU time / {cores} cores, s"
        vr_t = lambda r: r["volrender"]["cpu_s"]["median"] / cores  # noqa: E731
        vdb_t = lambda r: r["vdb_render"]["process_cpu_s"]["median"] / cores  # noqa: E731
    panels = [p for p in (ms, vs, ps) if p]
    fig, axes = plt.subplots(1, len(panels), figsize=(6.2 * len(panels), 4.4), squeeze=False)
    axes = list(axes[0])
    if ps:
        ax = axes.pop()
        for name, st, col in (("volrender --estimator path", ps["volrender"], "C0"),
                              (f"Mitsuba volpath ({ps['variant']})", ps["mitsuba"], "C1")):
            per = st["s_per_spp"] if payload["time_basis"] == "wall" else st["cpu_s_per_spp"] / cores
            spp = np.geomspace(1, 4 * st["spp_to_target"], 50)
            ax.loglog(spp * per, st["rel_noise_1spp"] / np.sqrt(spp), "-", color=col, label=name)
            ax.loglog([st["total_spp"] * per], [st["rel_noise_1spp"] / np.sqrt(st["total_spp"])], "o",
                      color=col)
        ax.axhline(ps["target_rel_rmse"], color="grey", lw=0.7, ls=":")
        w, h = ps["size"]
        ax.set_xlabel(xlabel)
        ax.set_ylabel("relative RMSE (from the measured noise)")
        ax.set_title(f"path tracing, {Path(ps['file']).name} {w}x{h}, depth {ps['volrender_max_depth']} "
                     f"(dots: what was rendered)", fontsize=9)
        ax.legend(fontsize=7)
    if ms:
        ax = axes.pop(0)
        vr = ms["volrender"]
        rand = [p for p in vr if p["spp"] >= 2]
        ax.loglog([p["time_s"] for p in rand], [p["rel_rmse"] for p in rand], "o-", color="C0",
                  label="volrender (PoCL), step 0.5/1 voxel")
        one = [p for p in vr if p["spp"] == 1]
        if one:
            ax.loglog([p["time_s"] for p in one], [p["rel_rmse"] for p in one], "o", mfc="none",
                      color="C0", label="volrender 1 spp (pixel centre)")
        for p in vr:
            ax.annotate(f"{p['spp']}", (p["time_s"], p["rel_rmse"]), fontsize=7,
                        xytext=(3, 3), textcoords="offset points")
        mp = ms["mitsuba"]
        ax.loglog([p["time_s"] for p in mp], [p["rel_rmse"] for p in mp], "s-", color="C1",
                  label=f"Mitsuba {ms['versions']['mitsuba']} {ms['variant']}, volpath depth 2")
        for p in mp:
            ax.annotate(f"{p['spp']}", (p["time_s"], p["rel_rmse"]), fontsize=7,
                        xytext=(3, 3), textcoords="offset points")
        for t in TARGETS:
            ax.axhline(t, color="grey", lw=0.7, ls=":")
        ax.axhline(ms["reference"]["std_error_rel"], color="k", lw=0.7, ls="--",
                   label="reference std. error")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("relative RMSE vs volrender reference")
        ax.set_title("two-lobe HG phase, box filter (numbers: spp)", fontsize=9)
        ax.legend(fontsize=7)
    if vs:
        ax = axes.pop(0)
        rows = vs["rows"]
        lab = [f"{r['step_voxels']:g}/{r['shadow_step_voxels']:g}" for r in rows]
        ax.loglog([vr_t(r) for r in rows],
                  [r["volrender"]["rel_rmse"] for r in rows], "o-", color="C0", label="volrender 1 spp (PoCL)")
        ax.loglog([vdb_t(r) for r in rows],
                  [r["vdb_render"]["rel_rmse"] for r in rows], "^-", color="C2", label="vdb_render (OpenVDB 10)")
        ax.loglog([vdb_t(r) for r in rows],
                  [r["vdb_render"]["rel_rmse_after_scale"] for r in rows], "^:", color="C2", mfc="none",
                  label="vdb_render after best scale")
        for r, l in zip(rows, lab):
            ax.annotate(l, (vr_t(r), r["volrender"]["rel_rmse"]),
                        fontsize=7, xytext=(3, 3), textcoords="offset points")
            ax.annotate(l, (vdb_t(r), r["vdb_render"]["rel_rmse"]),
                        fontsize=7, xytext=(3, 3), textcoords="offset points")
        ax.axhline(vs["reference"]["std_error_rel"], color="k", lw=0.7, ls="--", label="reference std. error")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("relative RMSE vs volrender reference")
        ax.set_title("isotropic phase, pixel centres (numbers: step/shadow step, voxels)", fontsize=9)
        ax.legend(fontsize=7, loc="lower left")
    for ax in fig.axes:
        ax.xaxis.set_minor_formatter(NullFormatter())
    size = payload["size"]
    fig.suptitle((f"{payload['file']} {size[0]}x{size[1]}, " if ms or vs else "") + payload["device"],
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# --------------------------------------------------------------------------- tables

def tables(payload) -> str:
    """Markdown tables of a results payload (docs/peers.md pastes them)."""
    out = []
    cores = payload.get("cpu_count") or 1
    vs = payload.get("vdb_scene")
    if vs and "rows" in vs:
        ref = vs["reference"]
        out += [f"vdb scene (isotropic phase, pixel centres); reference: volrender step "
                f"{ref['step_voxels']:g}/{ref['shadow_step_voxels']:g} voxel, {len(ref['seeds'])} seeds, "
                f"std. error {ref['std_error_rel']:.2%}. Times: median of {len(vs['rows'][0]['vdb_render']['render_s']['runs'])}.", "",
                "| step / shadow step (voxels) | vdb_render render s (CPU s / cores) | volrender render s (CPU s / cores) "
                "| time ratio | vdb_render rel. RMSE | vdb_render mean ratio | after best scale | volrender 1 spp rel. RMSE |",
                "|---|---:|---:|---:|---:|---:|---:|---:|"]
        for r in vs["rows"]:
            v, w = r["vdb_render"], r["volrender"]
            out.append(f"| {r['step_voxels']:g} / {r['shadow_step_voxels']:g} "
                       f"| {v['render_s']['median']:.2f} ({v['process_cpu_s']['median'] / cores:.2f}) "
                       f"| {w['render_call_s']['median']:.2f} ({w['cpu_s']['median'] / cores:.2f}) "
                       f"| x{r['time_ratio_vdb_over_volrender']:.1f} (CPU x{r['cpu_ratio_vdb_over_volrender']:.1f}) "
                       f"| {v['rel_rmse']:.2%} | {v['mean_ratio']:.3f} | {v['rel_rmse_after_scale']:.2%} "
                       f"| {w['rel_rmse']:.2%} |")
        cli = vs.get("cli") or {}
        if "process_wall_s" in cli:
            r05 = next((r for r in vs["rows"] if r["step_voxels"] == 0.5 and r["shadow_step_voxels"] == 1.0), None)
            if r05:
                out += ["", f"Whole processes at step 0.5/1: vdb_render {r05['vdb_render']['process_wall_s']['median']:.2f} s, "
                            f"`volrender render` {cli['process_wall_s']['median']:.2f} s (Python start-up, imports, "
                            f"VDB to bricks, program build from cache, render, EXR)."]
        out.append("")
    ms = payload.get("mitsuba_scene")
    if ms and "mitsuba" in ms:
        ref = ms["reference"]
        out += [f"Mitsuba scene (phase {tuple(ms['phase'])}, box filter); reference: volrender step "
                f"{ref['step_voxels']:g}/{ref['shadow_step_voxels']:g} voxel on {ref['supersample']}x"
                f"{ref['supersample']} sub-pixel centres, {len(ref['seeds'])} seeds, std. error "
                f"{ref['std_error_rel']:.2%}; Mitsuba {ms['versions']['mitsuba']} {ms['variant']}.", "",
                "| renderer | spp | wall s | CPU s / cores | rel. RMSE | image-mean ratio |",
                "|---|---:|---:|---:|---:|---:|"]
        for name, pts in (("volrender, step 0.5/1", ms["volrender"]), ("Mitsuba volpath", ms["mitsuba"])):
            for p in pts:
                out.append(f"| {name} | {p['spp']} | {p['wall_s']:.2f} | {p['cpu_s'] / cores:.2f} "
                           f"| {p['rel_rmse']:.2%} | {p['mean_ratio']:.4f} |")
        out += ["", "| target rel. RMSE | basis | volrender (spp >= 2) | volrender (with 1 spp) | Mitsuba | Mitsuba / volrender |",
                "|---:|---|---:|---:|---:|---:|"]
        for basis, rows in ms["time_to_error"].items():
            for target, row in rows.items():
                def cell(x):
                    t = x["time_s"]
                    return "n/a" if t is None else f"{t:.2f} s" + (" (extrap.)" if "extrapolated" in x["how"]
                                                                 else " (<=)" if "upper bound" in x["how"] else "")
                ratio = row["ratio_mitsuba_over_volrender_box"]
                out.append(f"| {float(target):.0%} | {basis} | {cell(row['volrender_box'])} | {cell(row['volrender_all'])} "
                           f"| {cell(row['mitsuba'])} | {'n/a' if ratio is None else f'x{ratio:.0f}'} |")
    ps = payload.get("path_scene")
    if ps and "volrender" in ps:
        v, m, a = ps["volrender"], ps["mitsuba"], ps["agreement"]
        w, h = ps["size"]
        out += ["", f"Path tracing ({Path(ps['file']).name}, {w}x{h}, volrender --max-depth "
                f"{ps['volrender_max_depth']} = Mitsuba volpath max_depth {ps['mitsuba_max_depth']}, "
                f"{ps['variant']}); errors from the measured noise of {v['batches']} independent "
                f"batches each.", "",
                "| renderer | spp (batches x spp) | ms per spp (wall) | CPU s / core per spp | noise at 1 spp | time to 2% here | at 640x480 |",
                "|---|---:|---:|---:|---:|---:|---:|"]
        cores = payload.get("cpu_count") or 1
        for name, st in (("volrender path", v), ("Mitsuba volpath", m)):
            t640 = ps["time_to_target_640x480_s"]["volrender" if st is v else "mitsuba"]
            out.append(f"| {name} | {st['total_spp']} ({st['batches']} x {st['spp_per_batch']}) "
                       f"| {st['s_per_spp'] * 1e3:.1f} | {st['cpu_s_per_spp'] / cores:.3f} "
                       f"| {st['rel_noise_1spp']:.0%} | {st['time_to_target_s']:.1f} s | {t640:.0f} s |")
        r = ps["time_ratio_mitsuba_over_volrender"]
        out += ["", f"Image mean Mitsuba / volrender {a['mean_ratio_mitsuba_over_volrender']:.4f} "
                f"(standard error {a['mean_ratio_se']:.4f}); per pixel and channel the difference "
                f"over its standard error has rms {a['z_rms']:.2f} and exceeds 3 in "
                f"{a['frac_abs_z_over_3']:.2%} of {a['pixels']} pixels. Time to 2%: Mitsuba / "
                f"volrender x{r['wall']:.1f} wall, x{r['cpu']:.1f} CPU."]
    return "\n".join(out)


# --------------------------------------------------------------------------- main

def ints(text):
    return [int(v) for v in text.split(",") if v]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default=None, help="WxH (default 320x240; 160x120 with --quick)")
    ap.add_argument("--file", type=Path, default=DEFAULT_FILE,
                    help=f"VDB file (default {DEFAULT_FILE}; the bundled scenes/demo_cloud.vdb also works)")
    ap.add_argument("--quick", action="store_true",
                    help="160x120, reference step 0.25/0.5 voxel, two vdb_render steps: about 1-2 minutes")
    ap.add_argument("--device", default=None, help="volrender's OpenCL device (default PoCL)")
    ap.add_argument("--density-scale", type=float, default=None, help="override the file's scene table")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs for the vdb_render comparison")
    ap.add_argument("--mitsuba-variant", default="auto", help="auto = llvm_ad_rgb, else scalar_rgb")
    ap.add_argument("--mi-spp", type=ints, default=None, help="Mitsuba spp list (default 1,4,16,64,256)")
    ap.add_argument("--vr-spp", type=ints, default=None, help="volrender spp list (default 1,2,4,8,16)")
    ap.add_argument("--no-vdb-render", action="store_true", help="leave out OpenVDB's vdb_render")
    ap.add_argument("--no-mitsuba", action="store_true", help="leave out Mitsuba 3")
    ap.add_argument("--no-path", action="store_true", help="skip the path-traced comparison")
    ap.add_argument("--path-only", action="store_true",
                    help="only the path-traced comparison (no vdb_render, no single scattering)")
    ap.add_argument("--path-file", type=Path, default=PATH_FILE,
                    help="volume of the path-traced comparison (default: the WDAS cloud)")
    ap.add_argument("--path-size", default=None, help="its image size (default 160x120; quick 80x60)")
    ap.add_argument("--path-depth", type=int, default=None,
                    help="volrender --max-depth (Mitsuba max_depth is one more; default volrender's)")
    ap.add_argument("--path-batches", type=int, default=None, help="independent batches (default 8; quick 4)")
    ap.add_argument("--path-vr-spp", type=int, default=None, help="volrender spp per batch (default 64)")
    ap.add_argument("--path-mi-spp", type=int, default=None, help="Mitsuba spp per batch (default 16)")
    ap.add_argument("--time", choices=["wall", "cpu"], default="wall",
                    help="time axis of the plot: wall seconds, or CPU seconds / cores (both are recorded)")
    ap.add_argument("--tag", default=None, help="added to the results' name: peers_<device>-<tag>.json")
    ap.add_argument("--table", type=Path, default=None, metavar="RESULTS.json",
                    help="only print the Markdown tables of an earlier run")
    args = ap.parse_args(argv)
    if args.table is not None:
        import json
        print(tables(json.loads(args.table.read_text())))
        return 0
    if not args.file.exists():
        log(f"bench/peers.py: {missing_data(str(args.file))}; or give --file "
            f"scenes/demo_cloud.vdb to compare on the bundled cloud")
        return 2
    size = args.size or ("160x120" if args.quick else "320x240")
    width, height = (int(v) for v in size.lower().split("x"))
    args.mi_spp = args.mi_spp or [1, 4, 16, 64, 256]
    args.vr_spp = args.vr_spp or [1, 2, 4, 8, 16]
    from volrender.volume import MAX_DEPTH
    args.path_size = tuple(int(v) for v in (args.path_size or ("80x60" if args.quick else "160x120"))
                           .lower().split("x"))
    args.path_depth = args.path_depth or MAX_DEPTH
    args.path_batches = args.path_batches or (4 if args.quick else 8)
    args.path_vr_spp = args.path_vr_spp or (16 if args.quick else 64)
    args.path_mi_spp = args.path_mi_spp or (4 if args.quick else 16)
    t_start = time.perf_counter()
    load_before = loadavg()

    dev = device.get(args.device)
    b = vdb.load_volume(args.file)
    scene = dict(SCENES.get(args.file.stem, dict(density_scale=1.0, fov=40.0, irradiance=6.0)))
    if args.density_scale is not None:
        scene["density_scale"] = args.density_scale
    cam = camera_mod.frame_bounds(*b.world_bounds(), width, height, fov=scene["fov"])
    sun = Sun(SUN_DIR, scene["irradiance"])
    common = {"file": str(args.file), "grid": b.grid_name, "size": [width, height],
              "camera": {"origin": list(cam.origin), "target": list(cam.target), "up": list(cam.up),
                         "fov_vertical_deg": cam.fov, "framing": "volrender.camera.frame_bounds (default view)"},
              "sun": {"direction": list(sun.direction), "irradiance": sun.irradiance},
              "density_scale": scene["density_scale"], "albedo": ALBEDO, "background": [0, 0, 0],
              "voxel_size": b.voxel_size, "index_to_world": np.asarray(b.index_to_world).tolist()}
    log(f"peers: {args.file.name} {width}x{height} on {dev.name}; load average {load_before}")
    if load_before and load_before[0] > 1.5:
        log("peers: warning: the machine is busy (load average above 1.5); times will be inflated")
    payload = {"benchmark": "peers", "quick": args.quick, **device_info(dev),
               "cpu_count": os.cpu_count(), "loadavg_before": load_before, "scene": common,
               "time_basis": args.time,
               "file": args.file.name, "size": [width, height],
               "metric": "relative RMSE = sqrt(mean((img - ref)^2) / mean(ref^2)) over all pixels and RGB"}
    with tempfile.TemporaryDirectory(prefix="peers-") as tmpd:
        tmp = Path(tmpd)
        exe = shutil.which("vdb_render")
        if args.no_vdb_render or args.path_only:
            payload["vdb_scene"] = None
        elif exe is None:
            log("peers: vdb_render not found (apt-get install libopenvdb-tools); skipping it")
            payload["vdb_scene"] = {"skipped": "vdb_render not installed"}
        elif args.file.suffix.lower() != ".vdb":
            log("peers: vdb_render needs a .vdb file; skipping it")
            payload["vdb_scene"] = {"skipped": "input is not a .vdb"}
        else:
            ver = subprocess.run([exe, "-version"], capture_output=True, text=True).stdout.strip()
            payload["vdb_scene"] = {"phase": ISO_PHASE, "vdb_render_version": ver,
                                    **vdb_section(args, b, cam, sun, scene, dev, exe, tmp)}
    if args.no_mitsuba:
        payload["mitsuba_scene"] = None
    else:
        try:
            mi, variant, note = import_mitsuba(args.mitsuba_variant)
        except Exception as e:
            log(f"peers: Mitsuba unavailable ({str(e).splitlines()[0]}); skipping it "
                "(bash run.sh peers installs mitsuba 3.5.x)")
            payload["mitsuba_scene"] = {"skipped": str(e)}
        else:
            if args.path_only:
                payload["mitsuba_scene"] = None
            else:
                payload["mitsuba_scene"] = {"phase": MIXED_PHASE,
                                            **mitsuba_section(args, b, cam, sun, scene, dev, mi,
                                                              variant, note)}
            if not args.no_path:
                payload["path_scene"] = path_section(args, dev, mi, variant)

    payload["loadavg_after"] = loadavg()
    payload["total_s"] = time.perf_counter() - t_start
    out = write_json(result_path("peers", dev, "-".join(t for t in (args.tag, "quick" if args.quick else None) if t)), payload)
    ran = {k: (v if v and "skipped" not in v else None) for k, v in payload.items()
           if k in ("mitsuba_scene", "vdb_scene", "path_scene")}
    if any(ran.values()):
        plot({**payload, **ran}, out.with_suffix(".png"))
    log(tables(payload))
    log(f"wrote {out}" + (f" and {out.with_suffix('.png').name}" if any(ran.values()) else "")
        + f" in {payload['total_s']:.0f} s")
    return 0


if __name__ == "__main__":
    rc = main()
    if "mitsuba" in sys.modules:
        # Mitsuba 3.5's own module-level objects outlive Dr.Jit at interpreter exit, which
        # it reports as ~22 "variable leaks" even for a trivial scene: harmless; skip the
        # teardown (every output is written and closed by now)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(rc)
    sys.exit(rc)
