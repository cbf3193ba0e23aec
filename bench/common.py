"""Shared helpers for benchmarks: device description, timing statistics, JSON output."""
from __future__ import annotations

import datetime
import json
import os
import platform
import statistics
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"     # $VOLRENDER_BENCH_RESULTS instead (tests)
CONVERTED = ROOT / "bench" / "data"          # .npz conversions (git-ignored), e.g. for the GPU


def shared_data() -> Path:
    """The real third-party files: $VOLRENDER_SHARED_DATA, else ../shared/data beside the
    checkout (a user's clone has none; data/README.md there says where they come from)."""
    env = os.environ.get("VOLRENDER_SHARED_DATA")
    return Path(env) if env else ROOT.parent / "shared" / "data"


def find_volume(name: str, need_openvdb=None) -> Path | None:
    """shared_data()/vdb/NAME.vdb, else bench/data/NAME.npz (its `volrender convert`);
    a .vdb only where OpenVDB imports (need_openvdb: a callable saying so)."""
    vdb = shared_data() / "vdb" / f"{name}.vdb"
    if vdb.is_file() and (need_openvdb is None or need_openvdb()):
        return vdb
    npz = CONVERTED / f"{name}.npz"
    return npz if npz.is_file() else None


def missing_data(what: str) -> str:
    """The message for a benchmark whose real input is absent (it exits non-zero)."""
    return (f"{what} not found: put the real files in {shared_data() / 'vdb'} (or set "
            f"VOLRENDER_SHARED_DATA to a folder holding vdb/), or convert them into "
            f"{CONVERTED} with `volrender convert FILE.vdb {CONVERTED}/NAME.npz`")


def git_commit() -> str:
    """The checkout's commit (+ "-dirty" with uncommitted changes), or "unknown";
    $VOLRENDER_COMMIT when set (bench/gpu.sh: the GPU machine gets a copy of the working
    tree whose git metadata is not the checkout's)."""
    if os.environ.get("VOLRENDER_COMMIT"):
        return os.environ["VOLRENDER_COMMIT"]
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True,
                             text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return (sha or "unknown") + ("-dirty" if dirty else "")


def device_info(dev) -> dict:
    """What a result was measured on and with: device, driver, commit, version, argv.
    Timings are warm (each benchmark renders once untimed first, building the program)
    unless a field says cold."""
    import volrender
    d = dev.device
    return {"device": dev.name, "version": d.version.strip(), "driver": d.driver_version.strip(),
            "compute_units": int(d.max_compute_units), "host": platform.node(),
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "commit": git_commit(), "volrender": volrender.__version__, "argv": sys.argv,
            "timing": "warm"}


def result_path(name: str, dev, tag: str | None = None, suffix=".json") -> Path:
    """bench/results/NAME_<device>[-TAG].json ($VOLRENDER_BENCH_RESULTS instead of
    bench/results): --tag adds to the device, never replaces it."""
    folder = Path(os.environ.get("VOLRENDER_BENCH_RESULTS") or RESULTS)
    return folder / f"{name}_{device_tag(dev)}{'-' + tag if tag else ''}{suffix}"


def stats(values) -> dict:
    values = sorted(values)
    return {"median": statistics.median(values), "min": values[0], "max": values[-1],
            "runs": values}


def write_json(path: Path, payload: dict) -> Path:
    """Write results atomically (volrender.atomic: an interrupted benchmark leaves the
    previous results whole and no temporary file)."""
    from volrender import atomic
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic.write_bytes(path, json.dumps(payload, indent=1).encode(), "results")
    return path


def device_tag(dev) -> str:
    name = dev.device.name.lower()
    return "gpu-" + "".join(c for c in name if c.isalnum())[:16] if "nvidia" in dev.name.lower() \
        else "pocl"


def render_points(cloud, camera, lights, settings, device, progress=None, variant=None,
                  launch=None):
    """A PointCloud rendered through the public path (Scene.of, render): a render.Image.
    The one render wrapper of bench/ and tests/ (tests/helpers.py imports it)."""
    from volrender.render import render
    from volrender.scene import GlassContent, Scene
    scene = Scene.of(camera, lights, GlassContent(cloud, settings))
    return render(scene, device, progress=progress, variant=variant, launch=launch)


def render_volume(bricks, camera, lights, settings, device, progress=None, launch=None):
    """Bricks rendered through the public path (Scene.of, render): a render.Image."""
    from volrender.render import render
    from volrender.scene import Scene, VolumeContent
    scene = Scene.of(camera, lights, VolumeContent(bricks, settings))
    return render(scene, device, progress=progress, launch=launch)


# The tiled volume kernel's culling alone (cl/volume_tile.h vr_tile_cull), per tile: how
# many occupied bricks its list keeps and, where asked, which. bench volume reports the
# list lengths; tests/test_dispatch_volume.py checks the lists against the rays.
CULL_SRC = r'''
#include "common.h"
#include "structs.h"
#include "volume.h"
#include "volume_tile.h"
__kernel __attribute__((reqd_work_group_size(VR_TILE_W, VR_TILE_H, 1)))
void tile_lists(__constant Camera* cam, __constant VolumeParams* vp,
                __global const int4* occ, int n_occ, __global int* counts,
                __global float4* lists, int keep, int y0)
{
    __local float4 list[VR_TILE_CAP];
    __local volatile int n_list;
    vr_tile_cull(cam, vp, occ, n_occ, y0, 0.0f, list, &n_list);
    int tile = get_group_id(1) * get_num_groups(0) + get_group_id(0);
    int lid = get_local_id(1) * VR_TILE_W + get_local_id(0);
    if (lid == 0)
        counts[tile] = n_list;
    for (int i = lid; keep && i < min(n_list, VR_TILE_CAP); i += VR_TILE_W * VR_TILE_H)
        lists[tile * VR_TILE_CAP + i] = list[i];
}
'''


def tile_lists(dev, b, cam, tile, cap=None, lists=True):
    """Per tile of a tiled launch over Bricks b: (counts (ny, nx): the bricks vr_tile_cull
    keeps, above cap where the list overflowed; lists (ny, nx, cap, 4): which (brick
    coordinates), None without `lists`; the number of occupied bricks). cap: the list's
    capacity (default the renderer's, features.VOLUME_TILE_CAP)."""
    import pyopencl as cl
    from volrender.dispatch import upload
    from volrender.features import VOLUME_TILE_CAP, VolumeFeatures
    from volrender.volume import occupied_bricks, volume_params
    f = VolumeFeatures(tiled=True, tile_w=int(tile[0]), tile_h=int(tile[1]),
                       tile_cap=int(cap or VOLUME_TILE_CAP))
    k = cl.Kernel(dev.build(CULL_SRC, f.flags(), "tile_lists"), "tile_lists")
    params, w2l = volume_params(b)
    occ = occupied_bricks(b)
    nx, ny = -(-cam.width // tile[0]), -(-cam.height // tile[1])
    counts = np.zeros(nx * ny, np.int32)
    out = np.zeros((nx * ny, f.tile_cap, 4) if lists else (1, 1, 4), np.float32)
    ctx = dev.context
    d_counts = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, counts.nbytes)
    d_lists = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, out.nbytes)
    k(dev.queue, (nx * tile[0], ny * tile[1]), tuple(tile), upload(ctx, cam.pack(w2l)),
      upload(ctx, params), upload(ctx, occ), np.int32(len(occ)), d_counts, d_lists,
      np.int32(bool(lists)), np.int32(0))
    cl.enqueue_copy(dev.queue, counts, d_counts)
    if lists:
        cl.enqueue_copy(dev.queue, out, d_lists)
    dev.queue.finish()
    return (counts.reshape(ny, nx), out.reshape(ny, nx, f.tile_cap, 4) if lists else None,
            len(occ))
