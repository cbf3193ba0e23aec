"""The light cache (issue 33): the light reaching the medium, baked once per scene and
lights on the device (cl/bake_light.cl) and read trilinearly by the marcher
(cl/light_cache.h) instead of a shadow march per sample per light.

Nodes sit every `cell` voxels inside each occupied brick (8 / cell + 1 per axis, the faces
shared with the neighbours); each holds every light's shadow optical depth and, with an
environment, the L1 harmonics of its banded light over 14 fixed directions, and, with
multiple scattering (choice.ms_orders), the L1 harmonics of scattering orders 2 and up
propagated over the nodes along the same directions (cl/bake_light.cl ms_gather). The cache
belongs to the volume's content like the uploaded bricks: `Scene.replace` with another
camera reuses it, other lights, environment or medium settings bake it again.

The cost model (`choose`) counts shadow-march samples: the bake's (nodes x marches per
node x a chord), the cached render's exact near parts, and the exact march's (its camera
samples inside occupied bricks, each brick's world volume over the pixel footprint at its
distance times the step, x marches per sample x the chord). The node spacing is the one
that costs least; `auto` bakes where that is below the exact march.
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np

from . import layout
from .dispatch import is_gpu, upload
from .light_dirs import ENV_DIRS, env_quadrature, ms_dirs

MODES = ("auto", "on", "off")
# node spacings the cost model picks from; 8 (brick corners) is valid when asked for, but
# the sky term, which has no exact near part, is off by +3 % there on WDAS (docs/error_time.md)
CELLS = (1, 2, 4)
ENV_CH = 12
MAX_BYTES = 512 << 20          # the cache is coarsened until it fits
# a light's shadow is marched exactly over this many node spacings from the sample, and
# read from the cache beyond (cl/light_cache.h vr_cached_tau): dense media shade within a
# voxel of their lit surface, sharper than trilinear nodes can hold
NEAR_CELLS = 2.0
# ... only where the medium's typical optical depth across a node spacing (the mean sigma_t
# of its non-zero voxels x the spacing) is above NEAR_TAU: in thinner media the nodes'
# trilinear tau is near the exact one and the near march is most of the kernel (320x240,
# 4 spp, PoCL, against the near part: smoke (0.31 a 4-voxel spacing) x2.5 faster, 1.5 %
# relative RMSE on covered pixels, mean x0.997; dragon (0.34) x2.5, 0.5 %; 0190 (0.14 at
# 2 voxels) x1.8, 0.7 %; docs/error_time.md); WDAS (6.9) keeps it (without: x0.89, 13.7 %)
NEAR_TAU = 1.0
T_CUT_TAU = math.log(1e5)      # camera rays stop below transmittance 1e-5 (render_volume.cl)
MS_CH = 12                     # the propagated orders' channels (L1 harmonics, as the sky's)
# the geometric tail after the last propagated order (cl/bake_light.cl ms_finish): its
# ratio to the order before, at most this (and the albedo)
MS_TAIL = 0.9
# the gather marches' longest step, node spacings (the step is shorter where the medium is
# dense: cl/bake_light.cl VR_MS_MFP): one spacing, half of one in media of typical optical
# depth above MS_DENSE_TAU (docs/error_time.md: one spacing costs WDAS (tau 123) 23.7 ->
# 25.8 %, and smoke, dragon and 0190 nothing, for a 25-40 % shorter bake)
MS_STEP_CELLS = (1.0, 0.5)
MS_DENSE_TAU = 32.0
# the bake's sky marches step this many node spacings (at least the shadow step; with
# 4-voxel nodes 2 voxels: the bake's first pass 2x cheaper; covered-pixel error smoke 6.0 ->
# 5.9 %, WDAS 23.6 -> 21.6 %, as exp(-tau) of a coarser midpoint sum is brighter on
# average (Jensen), which offsets the orders' deficit there; the dense furnace 0.98 ->
# 1.00; 1 spacing overshot it, x1.03; docs/error_time.md)
ENV_STEP_CELLS = 0.5
# a gather march stops where its transmittance (summed over rgb) falls below this, the
# rest of the ray taken as its last sample (cl/bake_light.cl VR_MS_T_STOP; 0.03: smoke's
# bake -10 %, the error as marching on to 3e-3)
MS_T_STOP = 0.03
# with scattering orders, auto bakes where that costs up to this many times the exact
# march (which takes the octave bands): on the real files the orders' covered-pixel error
# is 0.2-0.9x the bands' (docs/error_time.md)
MS_WORTH = 2.0
# the orders propagated where --ms-orders is not given: MS_ORDERS, or FINE_ORDERS where the
# nodes are at most 2 voxels apart in a dense medium (typical optical depth above
# MS_DENSE_TAU): there the nodes resolve the light's peak at the lit surface and the
# explicit orders carry it (WDAS on the H200 at 1080p, covered pixels: 1-voxel nodes 12.3 %
# with 3 orders, 7.1 % with 6, 6.5 % with 10; 2-voxel 17.4 / 13.3 % with 3 / 6; the
# thinner files gain nothing or overshoot: dragon at 1 voxel 5.2 -> 6.8 %;
# docs/error_time.md)
MS_ORDERS = 3
FINE_ORDERS = 6
# on a GPU a dense medium takes the finest of FINE_CELLS whose bake is predicted within
# GPU_BAKE_MS (the cost model's CPU choice, 4-voxel nodes there, leaves WDAS at 22.7 %):
# predicted as nodes x (orders + 2 passes) x GPU_NODE_PASS_MS, the H200's slowest pass
# measured (smoke's 1-voxel gathers: 23 ms for 2.3M nodes; WDAS's 6 orders at 1 voxel took
# 28 ms for 0.96M nodes, predicted 77)
FINE_CELLS = (1, 2)
GPU_BAKE_MS = 100.0
GPU_NODE_PASS_MS = 1e-5


# distinct nodes per occupied brick where shared nodes are baked once (bake_nodes): its
# (BRICK / c)^3 interior ones times this for the faces on the medium's surface (4-voxel
# nodes: smoke 1.15, WDAS 1.22, dragon 1.31, 0190 1.53; 2-voxel: 1.08-1.25)
SHARED_SURFACE = 1.25


def baked_per_brick(cell: int, gpu: bool) -> float:
    """Nodes the bake computes per occupied brick: every one on GPUs and at 1-voxel nodes,
    the distinct ones otherwise (bake_nodes)."""
    if gpu or cell == 1:
        return float(nodes_per_brick(cell))
    return min(float(nodes_per_brick(cell)), SHARED_SURFACE * (layout.BRICK // cell) ** 3)


def near_length(bricks, choice) -> float:
    """World length of the exact part of a cached shadow ray (choice.near_cells node
    spacings)."""
    return float(choice.near_cells * choice.cell * bricks.voxel_size)


def near_cells(cell: int, sigma_voxel) -> float:
    """The node spacings marched exactly: NEAR_CELLS where the optical depth across one
    (sigma_voxel: the medium's typical sigma_t x a voxel, world; None: unknown) is above
    NEAR_TAU, else 0."""
    return NEAR_CELLS if sigma_voxel is None or sigma_voxel * cell > NEAR_TAU else 0.0


@dataclass(frozen=True)
class Choice:
    cell: int                  # node spacing, voxels (0: no cache)
    nodes: int
    channels: int
    cost: float                # predicted shadow-march samples: bake + the near parts
    exact: float               # the same for the exact march
    reason: str
    ms_orders: int = 0         # scattering orders propagated over the nodes (0: none)
    ms_step_cells: float = MS_STEP_CELLS[0]   # their gather's longest step, node spacings
    near_cells: float = NEAR_CELLS             # the shadows' exact part, node spacings

    @property
    def nbytes(self) -> int:
        return 4 * self.nodes * self.channels

    def note(self) -> str:
        if not self.cell:
            return f"light cache off ({self.reason})"
        ms = (f", scattering orders 2-{self.ms_orders + 1} propagated over them"
              if self.ms_orders else "")
        if not self.near_cells:
            ms += ", shadows read from them alone (the medium is thin across a spacing)"
        return (f"light cache: nodes every {self.cell} voxel{'s' if self.cell > 1 else ''}{ms} "
                f"({self.nodes / 1e3:.0f}k nodes x {self.channels} channels, "
                f"{self.nbytes / 2**20:.1f} MB): bake and near marches ~{self.cost / 1e6:.3g}M "
                f"shadow samples against ~{self.exact / 1e6:.3g}M for the exact march "
                f"({self.reason}); --light-cache off for the exact march")


def nodes_per_brick(cell: int) -> int:
    return (layout.BRICK // cell + 1) ** 3


def camera_samples(bricks, camera, step_world, spp) -> float:
    """Estimated camera samples inside occupied bricks: per brick in front of the camera,
    its world volume over (pixel footprint at its distance x the step), times spp."""
    idx = np.flatnonzero(np.asarray(bricks.table) >= 0)
    if idx.size == 0:
        return 0.0
    b = np.stack(np.unravel_index(idx, tuple(int(d) for d in bricks.dims)), axis=1)
    l2w = np.asarray(bricks.local_to_world, np.float64)
    centres = (b + 0.5) * layout.BRICK
    world = centres @ l2w[:3, :3].T + l2w[:3, 3]
    vox_vol = abs(float(np.linalg.det(l2w[:3, :3])))
    dist = np.linalg.norm(world - np.asarray(camera.origin, np.float64), axis=1)
    pix = 2.0 * math.tan(math.radians(camera.fov) / 2.0) / camera.height   # per unit distance
    area = (np.maximum(dist, 1e-30) * pix) ** 2
    return float(np.sum(vox_vol * layout.BRICK ** 3 / (area * step_world))) * spp


def orders_for(cell: int, tau: float, ms_orders) -> int:
    """The orders to propagate: ms_orders where given (0: none), else MS_ORDERS, or
    FINE_ORDERS on nodes at most 2 voxels apart in a dense medium (tau above
    MS_DENSE_TAU)."""
    if ms_orders is not None:
        return int(ms_orders)
    return FINE_ORDERS if cell <= 2 and tau > MS_DENSE_TAU else MS_ORDERS


def gpu_fine(slots: int, tau: float, ms_orders=None):
    """(cell, predicted bake ms): the finest of FINE_CELLS a GPU bakes for a dense medium
    (tau above MS_DENSE_TAU) within GPU_BAKE_MS, or None."""
    if tau <= MS_DENSE_TAU:
        return None
    for cell in FINE_CELLS:
        ms = slots * nodes_per_brick(cell) * (orders_for(cell, tau, ms_orders) + 2) * GPU_NODE_PASS_MS
        if ms <= GPU_BAKE_MS:
            return cell, ms
    return None


def choose(bricks, settings, camera, n_lights: int, env: bool, cell=None,
           tau: float = 0.0, ms_orders: int | None = 0, gpu: bool = False,
           sigma_voxel: float | None = None) -> Choice:
    """The cache for this scene, from a cost model counted in shadow-march samples:
    a bake costs the nodes it computes (baked_per_brick) x (marches per node) x the chord, the cached render's exact near
    parts (camera samples) x lights x 2c / shadow step, the exact march (camera samples) x
    (marches per sample) x the chord, the chord being the edge of a cube of the occupied
    bricks' volume over the shadow step. The node spacing c minimises bake + near parts
    over CELLS (settings.light_cache_cell fixes it), within MAX_BYTES; `auto` bakes where
    that is below the exact march's count. Cell 0 where the mode is off, the estimator is
    not the march or nothing lights the medium. ms_orders: scattering orders to propagate
    over the nodes (each a march along the ENV_DIRS directions per node, counted twice: it
    reads the nodes at every step; None: orders_for's); auto then bakes up to MS_WORTH x
    the exact march's count. On a GPU (gpu) a dense medium with orders takes the nodes
    gpu_fine says its bake affords there, whatever the count. sigma_voxel:
    the medium's typical sigma_t x a voxel (near_cells; None: the near part everywhere)."""
    mode = settings.light_cache
    slots = int(bricks.n_slots)
    fine = gpu_fine(slots, tau, ms_orders) if gpu and ms_orders != 0 else None
    orders = 0 if ms_orders == 0 else orders_for(4, tau, ms_orders)   # (channels: any > 0)
    channels = n_lights + (ENV_CH if env else 0) + (MS_CH if orders else 0)
    per_sample = n_lights + (1 if env else 0)

    def off(why):
        return Choice(0, 0, channels, 0.0, 0.0, why, 0)
    if mode == "off":
        return off("--light-cache off")
    if settings.estimator != "march":
        return off(f"the {settings.estimator} estimator traces its own shadows")
    if channels == 0 or slots == 0:
        return off("nothing lights the medium")
    step = settings.step * float(bricks.voxel_size)
    samples = camera_samples(bricks, camera, step, settings.spp) * min(1.0, T_CUT_TAU / max(tau, 1e-30))
    chord = (slots * layout.BRICK ** 3) ** (1.0 / 3.0) / settings.shadow_step

    ms_cells = MS_STEP_CELLS[tau > MS_DENSE_TAU]

    def cost(c):
        # the sky's and the gathers' marches step ENV_STEP_CELLS and ms_cells node
        # spacings (at least the shadow step), not the shadow step: their samples scale by
        # that ratio (WDAS on PoCL, 2- and 1-voxel bakes against 4: x7 and x39 of CPU
        # measured, x9.3 and x54 counted so, x4.6 and x27 counted at the shadow step)
        def thin(cells):
            return settings.shadow_step / max(settings.shadow_step, cells * c)
        k = 0 if ms_orders == 0 else orders_for(c, tau, ms_orders)   # the orders at c
        per = n_lights + (ENV_DIRS * thin(ENV_STEP_CELLS) if env else 0) \
            + 2 * ENV_DIRS * k * thin(ms_cells)
        near = samples * n_lights * min(chord, near_cells(c, sigma_voxel) * c / settings.shadow_step)
        return slots * baked_per_brick(c, gpu) * per * chord + near
    exact = samples * per_sample * chord
    fits = [c for c in (8, *CELLS) if slots * nodes_per_brick(c) * channels * 4 <= MAX_BYTES]
    if cell or settings.light_cache_cell:
        cell = cell or settings.light_cache_cell
        why = f"--light-cache-cell {cell}"
    elif fine is not None and fine[0] in fits:
        cell = fine[0]
        why = (f"a dense medium (typical optical depth {tau:.3g}) on a GPU: {cell}-voxel "
               f"nodes resolve its lit surface, their bake predicted ~{fine[1]:.0f} ms")
    else:
        cell = min([c for c in CELLS if c in fits] or [8], key=cost)
        why = f"{cell}-voxel nodes cost least"
        worth = MS_WORTH if orders else 1.0
        if mode == "auto" and cost(cell) >= worth * exact:
            return Choice(0, 0, channels, cost(cell), exact,
                          f"auto: its bake and near marches, ~{cost(cell) / 1e6:.3g}M samples, "
                          f"would cost more than {'%g x ' % worth if worth != 1 else ''}the "
                          f"exact march's ~{exact / 1e6:.3g}M")
    orders = 0 if ms_orders == 0 else orders_for(cell, tau, ms_orders)
    return Choice(cell, slots * nodes_per_brick(cell), channels, cost(cell), exact, why,
                  orders, MS_STEP_CELLS[tau > MS_DENSE_TAU], near_cells(cell, sigma_voxel))


def occupied_slots(bricks) -> np.ndarray:
    """(n, 4) int32: (bx, by, bz, slot) of every occupied brick."""
    table = np.asarray(bricks.table)
    idx = np.flatnonzero(table >= 0)
    out = np.zeros((len(idx), 4), np.int32)
    out[:, :3] = np.stack(np.unravel_index(idx, tuple(int(d) for d in bricks.dims)), axis=1)
    out[:, 3] = table[idx]
    return out


@dataclass
class LightCache:
    buffer: object             # cl.Buffer of float32
    choice: Choice
    bake_ms: float
    passes_ms: dict = dataclasses.field(default_factory=dict)   # per bake pass: wall ms
    passes_cpu_ms: dict = dataclasses.field(default_factory=dict)   # ... the process's CPU ms


def builds(content) -> int:
    """How many times the content's light cache was baked."""
    return content.store.get("light_cache_builds", 0)


def get(content, device, features, params, lights_packed, environment,
        choice: Choice, similar=None) -> LightCache:
    """The content's cache on `device` for these features (the marcher's flags), params,
    packed lights and environment: baked on the first call, reused while they stay the
    same (only the latest per device is kept). similar: (albedo, extinction) per channel
    of the medium the propagated orders scatter in (volume.ms_medium)."""
    memo = content.store.get("env_quadrature")
    if memo is None or memo[0] is not environment:
        memo = (environment, env_quadrature(environment))
        content.store["env_quadrature"] = memo
    env = memo[1]
    flags = dataclasses.replace(features, light_cache=choice.cell, tiled=False, tile_w=1,
                                tile_h=1, tile_cap=0, depth=False).flags()
    key = (tuple(sorted(flags.items())), params.tobytes(), np.asarray(lights_packed).tobytes(),
           np.asarray(env).tobytes(), choice.ms_orders, np.asarray(similar).tobytes())
    slot = ("light_cache", device.device.int_ptr)
    hit = content.store.get(slot)
    if hit is not None and hit[0] == key:
        return hit[1]
    content.store.pop(slot, None)          # free the old one before baking anew
    cache = bake(content.bricks, device, flags, params, lights_packed, env, choice,
                 content.buffer(device, "table"), content.buffer(device, "data"), similar)
    content.store[slot] = (key, cache)
    content.store["light_cache_builds"] = builds(content) + 1
    return cache


def env_step(bricks, choice, params) -> float:
    """World step of the bake's sky marches (cl/bake_light.cl): ENV_STEP_CELLS node
    spacings, at least the shadow step."""
    return max(float(params["shadow_step"][0]),
               ENV_STEP_CELLS * choice.cell * float(bricks.voxel_size))


def ms_step(bricks, choice, params) -> float:
    """Longest world step of the orders' gather marches (cl/bake_light.cl ms_gather:
    they step a quarter of a mean free path, between the shadow step and this):
    choice.ms_step_cells node spacings, at least the shadow step."""
    return max(float(params["shadow_step"][0]),
               choice.ms_step_cells * choice.cell * float(bricks.voxel_size))


def bake_nodes(occ, cell: int, shared: bool = True):
    """(todo, pairs) for cl/bake_light.cl over the occupied bricks occ (occupied_slots):
    todo (m, 2) int32, (index into occ, node) of each distinct node (a node on a face shared
    by neighbouring bricks is the same point: baked once, in the first brick holding it);
    pairs (k, 2) int32, (node index, the index it copies), node index = slot x
    nodes_per_brick + node, for each of the others. shared False: every node of every
    brick baked, no pairs (on GPUs, and at 1-voxel nodes, finding the shared ones costs more
    host time than they save: smoke's 2.3M 1-voxel nodes take ~0.5 s of numpy for 1.4x
    fewer; at 4 voxels 13 ms for 2.9x fewer, 87k -> 30k)."""
    n = layout.BRICK // cell + 1
    nodes = nodes_per_brick(cell)
    if not shared or len(occ) == 0:
        todo = np.stack([np.repeat(np.arange(len(occ)), nodes),
                         np.tile(np.arange(nodes), len(occ))], axis=1).astype(np.int32)
        return todo, np.zeros((0, 2), np.int32)
    ijk = np.stack(np.unravel_index(np.arange(nodes), (n, n, n)), axis=1) * cell
    pos = (occ[:, None, :3].astype(np.int64) * layout.BRICK + ijk[None]).reshape(-1, 3)
    pos -= pos.min(axis=0)
    span = pos.max(axis=0) + 1
    key = (pos[:, 0] * span[1] + pos[:, 1]) * span[2] + pos[:, 2]
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    k = np.repeat(np.arange(len(occ)), nodes)
    node = np.tile(np.arange(nodes), len(occ))
    once = np.sort(first)                  # each point's first entry, in brick order
    todo = np.stack([k[once], node[once]], axis=1).astype(np.int32)
    at = occ[k, 3].astype(np.int64) * nodes + node
    src = at[first[inverse.ravel()]]
    dup = src != at
    pairs = np.stack([at[dup], src[dup]], axis=1).astype(np.int32)
    return todo, pairs


def bake(bricks, device, flags, params, lights_packed, env, choice, table, data,
         similar=None) -> LightCache:
    """Run cl/bake_light.cl over every node of every occupied brick (then, with
    choice.ms_orders, its ms_source and that many ms_gather passes)."""
    import pyopencl as cl
    ctx, q = device.context, device.queue
    occ = occupied_slots(bricks)
    todo, pairs = bake_nodes(occ, choice.cell, shared=choice.cell > 1 and not is_gpu(device))
    n = len(todo)
    out = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, max(4, 4 * int(bricks.n_slots) *
                                                      nodes_per_brick(choice.cell) * choice.channels))
    kernel = device.kernel("bake_light", flags)
    local = 64
    t0 = time.perf_counter()
    passes, cpu = {}, {}

    def done(name, t=[t0, time.process_time()]):   # each pass's times (a finish per pass)
        q.finish()
        now, now_cpu = time.perf_counter(), time.process_time()
        passes[name] = 1e3 * (now - t[0])
        cpu[name] = 1e3 * (now_cpu - t[1])
        t[:] = now, now_cpu
    glob = (-(-n // local) * local,)
    lights_buf, params_buf, occ_buf = upload(ctx, lights_packed), upload(ctx, params), upload(ctx, occ)
    todo_buf, pairs_buf = upload(ctx, todo), upload(ctx, pairs)
    copy = device.kernel("bake_light", flags, "copy_nodes")

    def copied(buf, nch):                          # the shared nodes' other copies
        if len(pairs):
            copy(q, (-(-len(pairs) * nch // local) * local,), (local,), buf, pairs_buf,
                 np.int32(len(pairs)), np.int32(nch))
    kernel(q, glob, (local,), params_buf, lights_buf,
           table, data, upload(ctx, np.asarray(env, np.float32)), occ_buf, todo_buf, out,
           np.int32(n), np.float32(env_step(bricks, choice, params)))
    done("bake_light")
    if choice.ms_orders:
        nbytes = max(4, 4 * 3 * int(bricks.n_slots) * nodes_per_brick(choice.cell))
        orders = [cl.Buffer(ctx, cl.mem_flags.READ_WRITE, nbytes) for _ in range(3)]
        total = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, nbytes)
        total1 = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, 3 * nbytes)
        device.kernel("bake_light", flags, "ms_source")(
            q, glob, (local,), params_buf, lights_buf, occ_buf, todo_buf, out, orders[0],
            np.int32(n))
        done("ms_source")
        alb, ext = (cl.cltypes.make_float4(*map(float, v), 0.0) for v in similar)
        gather = device.kernel("bake_light", flags, "ms_gather",
                               options=(f"-DVR_MS_T_STOP={MS_T_STOP:.6g}f",))
        dirs = upload(ctx, ms_dirs())
        # the once-scattered light towards each direction at the nodes: the first gather's
        # source (3 floats per direction per node; freed after the bake)
        once = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, ENV_DIRS * nbytes)
        device.kernel("bake_light", flags, "ms_once")(
            q, glob, (local,), params_buf, lights_buf, occ_buf, todo_buf, out, dirs, once,
            np.int32(n))
        copied(once, 3 * ENV_DIRS)                 # the gathers read their sources trilinearly
        done("ms_once")
        k_orders = choice.ms_orders
        for k in range(k_orders):
            gather(q, glob, (local,), params_buf, table, data, dirs, occ_buf, todo_buf,
                   once if k == 0 else orders[k % 3],
                   orders[(k + 1) % 3], total, total1, np.int32(n), alb, ext,
                   np.float32(ms_step(bricks, choice, params)), np.int32(k == 0))
            copied(orders[(k + 1) % 3], 3)
            done(f"ms_gather{k + 1}")
        r_max = np.minimum(np.asarray(similar[0], np.float64), MS_TAIL)
        kn = k_orders
        device.kernel("bake_light", flags, "ms_finish")(
            q, glob, (local,), occ_buf, todo_buf, total, total1, orders[max(kn - 2, 0) % 3],
            orders[(kn - 1) % 3], orders[kn % 3], out, np.int32(n),
            cl.cltypes.make_float4(*map(float, r_max), 0.0))
        done("ms_finish")
    copied(out, choice.channels)
    q.finish()
    return LightCache(out, choice, 1e3 * (time.perf_counter() - t0), passes, cpu)


def cached(content, device) -> LightCache:
    """The content's latest cache on `device` (baked by a render or volume.plan)."""
    return content.store[("light_cache", device.device.int_ptr)][1]


def read_back(content, device):
    """The baked nodes, (slots, n, n, n, channels) float32, and the occupied bricks
    (occupied_slots); tests and diagnostics."""
    import pyopencl as cl
    cache = cached(content, device)
    n = layout.BRICK // cache.choice.cell + 1
    out = np.empty((int(content.bricks.n_slots), n, n, n, cache.choice.channels), np.float32)
    cl.enqueue_copy(device.queue, out, cache.buffer)
    device.queue.finish()
    return out, occupied_slots(content.bricks)


def probe(content, device, flags, local):
    """The cache's channels as the marcher reads them (cl/light_cache.h) at local points
    (n, 3) inside occupied bricks: (n, channels); flags: the marcher's (its plan's
    features); tests."""
    import pyopencl as cl
    cache = cached(content, device)
    kernel = device.kernel("bake_light", dict(flags), "probe_light_cache")
    pts = np.zeros((len(local), 4), np.float32)
    pts[:, :3] = local
    out = cl.Buffer(device.context, cl.mem_flags.WRITE_ONLY, 4 * len(local) * cache.choice.channels)
    dims = np.zeros(1, cl.cltypes.int4)
    dims[0] = tuple(int(d) for d in content.bricks.dims) + (0,)
    kernel(device.queue, (len(local),), None, upload(device.context, pts),
           content.buffer(device, "table"), dims[0], cache.buffer, out)
    host = np.empty((len(local), cache.choice.channels), np.float32)
    cl.enqueue_copy(device.queue, host, out)
    device.queue.finish()
    return host
