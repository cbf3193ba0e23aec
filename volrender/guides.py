"""Denoising guides: albedo and normal images written by small kernels of their own
(cl/guide_volume.cl, cl/guide_glass.cl) that read the render kernel's own arguments by
name, so they follow the integrators without touching them. Each pixel averages
SPP[kind] jittered sub-pixel rays (1: the pixel's centre, as a 1-spp render's), taken as
clean by OIDN; glass on a CPU takes EDGE_SPP rays again on the one-ray guide's edges; a
volume's march takes VOLUME_STEP x the render's step. All measured against the denoised
error (bench/guides_spp.py, docs/benchmarks.md "Denoiser guides").

    albedo  H x W x 3 in [0, 1]   volumes: (1 - T) albedo + T min(behind, 1);
                                  glass: the first surface's tint, else the environment
    normal  H x W x 3 in [-1, 1]  volumes: -grad(density)/|grad| where T falls to 1/2;
                                  glass: the first surface's outward normal; 0: nothing

EXR layers (image.LAYERS): `Denoising Albedo.R/G/B`, `Denoising Normal.X/Y/Z` (Blender's
Denoising Data passes, what its Denoise node and OIDN's tools take) and, when denoised,
`Noisy Image.R/G/B/A`.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from .dispatch import Dispatch, Plan, is_gpu, run_rows, upload

# Rays a pixel. Volumes: 1 ray gave the same denoised error as 4 (smoke 320x240: relative
# RMSE 0.340 % both, guides 1.22 -> 0.20 s on PoCL); since auto's march steps up to 2
# voxels on CPUs, the guide keeps the render's own step (VOLUME_STEP 1): smoke 0.49 %
# denoised at 1x, 0.65 % at 2x, 1.1 % at 4x (the noisy image 0.59 %). Glass on CPUs: 1 ray,
# then EDGE_SPP where it has an edge (edges; the guides anti-alias the silhouette OIDN
# keeps); on GPUs, where 4 rays cost a few ms and edges' host pass more, GPU_GLASS_SPP.
SPP = {"volume": 1, "glass": 1}
EDGE_SPP = {"glass": 4}       # rays a pixel again where the one-ray guide has an edge (edges)
GPU_GLASS_SPP = 4
EDGE_COS = 0.9                # a normal turning by more than ~26 degrees to a neighbour's
EDGE_ALBEDO = 0.1             # an albedo channel moving by more than this to a neighbour's
VOLUME_STEP = 1.0             # the volume guide's march step, x the render's
T_STOP = 1e-4                 # the volume guide stops marching below this transmittance

ARGS = {"volume": ("cam", "vp", "table", "data", "env"),
        "glass": ("cam", "gp", "spheres", "nodes", "env", "colors", "bricks", "cells", "lists",
                  "entries")}
UNTILED = ("tiled", "tile_w", "tile_h", "tile_cap")


def plan(scene, main: Plan, spp: int | None = None, step: float = VOLUME_STEP,
         t_stop: float = T_STOP) -> Plan:
    """The guide launch beside a render's Plan `main` (volume.plan or glass.plan of the
    same scene): its arguments by name, the camera's samples set to `spp` (None:
    SPP[kind]), fragment
    dispatch (no tile lists); volumes march `step` x the render's step and stop where the
    transmittance falls below `t_stop` (cl/guide_volume.cl)."""
    options = tuple(main.build_options)
    if scene.kind == "volume":
        options += (f"-DVR_GUIDE_STEP={float(step)!r}f", f"-DVR_GUIDE_T_STOP={float(t_stop)!r}f")
    inputs = dict(main.inputs)
    cam = inputs["cam"].copy()
    cam["spp"] = SPP[scene.kind] if spp is None else spp
    inputs["cam"] = cam
    f = main.features
    plain = type(f)()
    features = dataclasses.replace(f, **{k: getattr(plain, k) for k in UNTILED if hasattr(f, k)})
    W, H = scene.camera.width, scene.camera.height
    return Plan(f"guide_{scene.kind}", features, [(n, inputs[n]) for n in ARGS[scene.kind]],
                [("albedo", (H, W, 4)), ("normal", (H, W, 4))],
                Dispatch("fragment", main.dispatch.tile), main.band_pixels,
                build_options=options)


def render_guides(scene, device, main: Plan, spp: int | None = None,
                  step: float = VOLUME_STEP, t_stop: float = T_STOP,
                  edge_spp: int | None = None) -> dict:
    """{'albedo': H x W x 3, 'normal': H x W x 3} float32 of the scene (see the module
    docstring), rendered on `device` beside the Plan `main`, `spp` rays a pixel (1: its
    centre; None: SPP[kind], for glass on a GPU GPU_GLASS_SPP); `step` and `t_stop` as
    plan's. Glass: the pixels on an edge of the first pass (edges()) are rendered again
    with `edge_spp` jittered rays (None: EDGE_SPP; at most spp: not again)."""
    import pyopencl as cl
    if scene.kind == "glass" and spp is None and is_gpu(device):
        spp, edge_spp = GPU_GLASS_SPP, 0
    p = plan(scene, main, spp, step, t_stop)
    kernel = device.kernel(p.entry, p.features.flags(), options=p.build_options)
    ctx = device.context
    args = [upload(ctx, a) if isinstance(a, np.ndarray) else a for _, a in p.inputs]
    outs = {name: cl.Buffer(ctx, cl.mem_flags.READ_WRITE, 4 * int(np.prod(shape)))
            for name, shape in p.outputs}
    run_rows(device, kernel, args + list(outs.values()), scene.camera.width,
             scene.camera.height, p.band_pixels, False, dispatch=p.dispatch, spp=p.spp)
    host = _read(device, outs, p.outputs)
    edge_spp = EDGE_SPP.get(scene.kind, 0) if edge_spp is None else edge_spp
    if scene.kind == "glass" and edge_spp > p.spp:
        pixels = np.flatnonzero(edges(host["albedo"], host["normal"])).astype(np.int32)
        if len(pixels):
            cam = dict(p.inputs)["cam"].copy()
            cam["spp"] = edge_spp
            args[0] = upload(ctx, cam)
            listed = device.kernel(p.entry, p.features.flags(), name=f"{p.entry}_list",
                                   options=p.build_options)
            listed(device.queue, (len(pixels),), None, *args, *outs.values(),
                   upload(ctx, pixels), np.int32(len(pixels)))
            host = _read(device, outs, p.outputs)
    return {name: np.ascontiguousarray(v[..., :3]) for name, v in host.items()}


def _read(device, outs, shapes) -> dict:
    import pyopencl as cl
    host = {}
    for name, shape in shapes:
        host[name] = np.empty(shape, np.float32)
        cl.enqueue_copy(device.queue, host[name], outs[name])
    device.queue.finish()
    return host


def edges(albedo, normal) -> np.ndarray:
    """H x W bool: the pixels of a one-ray guide whose 3 x 3 neighbourhood changes, where
    more rays a pixel would blend what they see: a surface against nothing (normal 0), and
    between surface pixels a normal turning by over EDGE_COS or an albedo channel moving by
    over EDGE_ALBEDO (the environment behind, smooth, is left to the one ray). Each of the
    four neighbour directions is compared once and marks both pixels of a pair."""
    n = np.moveaxis(np.asarray(normal[..., :3], np.float32), -1, 0)     # 3 x H x W planes
    a = np.moveaxis(np.asarray(albedo[..., :3], np.float32), -1, 0)
    hit = (n[0] != 0) | (n[1] != 0) | (n[2] != 0)
    H, W = hit.shape
    out = np.zeros((H, W), bool)
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
        p = (slice(0, H - dy), slice(max(0, -dx), W - max(0, dx)))         # a pixel
        q = (slice(dy, H), slice(max(0, dx), W - max(0, -dx)))             # its neighbour
        both = hit[p] & hit[q]
        turn = n[0][p] * n[0][q] + n[1][p] * n[1][q] + n[2][p] * n[2][q] < EDGE_COS
        tint = np.abs(a[0][p] - a[0][q]) > EDGE_ALBEDO
        tint |= np.abs(a[1][p] - a[1][q]) > EDGE_ALBEDO
        tint |= np.abs(a[2][p] - a[2][q]) > EDGE_ALBEDO
        pair = (hit[p] != hit[q]) | (both & (turn | tint))
        out[p] |= pair
        out[q] |= pair
    return out
