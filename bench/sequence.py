"""Frame sequences on Dask: frames per second against the number of workers.

    volrender bench sequence [--file smoke] [--frames 48] [--size 640x480]
        [--workers 1,2] [--chunk K] [--device SPEC] [--format exr] [--points N] [--tag TAG]

Makes a sequence of --frames .npz frames from one real volume (the file's bricks with a
transform that drifts a little per frame, so every frame is a separate file to load),
then renders it with render_sequence on a LocalCluster of N workers for each N of
--workers. Each worker first renders one frame untimed (its programs are then built);
the timed run renders every frame. On a host with several GPUs each worker gets its own
GPU (sequence.device_per_worker); with one device all workers share it. Records frames
per second, the speed-up over 1 worker (target: >= 0.9 N with a device per worker), the
spread of per-frame times, and where a frame's time goes (load, setup and upload,
kernel, write), in bench/results/sequence_<device>.json. --points N: a sequence of
N-sphere point clouds instead (each frame builds its own acceleration: the record splits
the build out); --workers 0: in this process, without Dask.
"""
from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import (CONVERTED, device_info, find_volume, missing_data,  # noqa: E402
                          result_path, write_json)
from volrender import device, sequence, vdb  # noqa: E402
from volrender.bricks import Bricks  # noqa: E402

DENSITY = {"smoke": 1.0, "wdas_cloud_sixteenth": 0.05, "dragon_with_xform": 1.0}


def make_frames(src: Path, n: int, folder: Path) -> Path:
    """n frames of src's bricks, drifting by a tenth of a voxel per frame."""
    b = vdb.load_volume(src)
    for f in range(1, n + 1):
        m = np.array(b.index_to_world, np.float64)
        m[:3, 3] += m[:3, 0] * 0.1 * f
        Bricks(b.origin, b.dims, b.table, b.data, b.majorant, m,
                   grid_name=b.grid_name).save_npz(folder / f"frame_{f:04d}.npz")
    return folder / "frame_####.npz"


def make_point_frames(n_points: int, n: int, folder: Path) -> Path:
    """n .npy frames of a blob of n_points spheres (centre, radius) moving across: every
    frame its own cloud, so every frame builds its acceleration."""
    from volrender import generators
    base = generators.blob(n_points, seed=1)
    arr = np.column_stack([base.centers, base.radii]).astype(np.float32)
    for f in range(1, n + 1):
        arr[:, 0] += 0.02
        np.save(folder / f"frame_{f:04d}.npy", arr)
    return folder / "frame_####.npy"


def run_serial(pattern, n_frames, out, size, opts, dev_spec, fmt, piped=True, split=True,
               writer="process"):
    """The sequence in this process (workers=0): no Dask, one device; as the pipeline
    render_sequence runs (volrender/pipeline.py), or (piped=False) one frame after another
    as before it (sequence.render_chunk per frame, the same camera); split=False: the
    pipeline with each frame's set-up (build, uploads) in the launching thread, as before
    render.prepare (only the load and the write overlap); writer="thread": the pipeline
    writing in its write thread, as before frame_writer.py (the GIL shared by all three
    stages)."""
    import importlib
    import os
    from unittest import mock
    render_mod = importlib.import_module("volrender.render")     # (volrender.render: the function)
    if dev_spec:
        os.environ["VOLRENDER_DEVICE"] = dev_spec
    frame1 = sequence.parse_pattern(str(pattern)).path(1)
    cam = sequence.sequence_camera({1: frame1}, {**opts, "size": size})[0]
    kw = {**opts, "size": size, **sequence.camera_overrides(cam)}
    sequence.render_chunk([(1, frame1, out / f"warm.{fmt}")], kw, {})       # programs
    if not piped:
        pat = sequence.parse_pattern(str(pattern))
        t = time.perf_counter()             # render_sequence's camera and options, as it does
        cam, _, extra, _ = sequence.sequence_camera({f: pat.path(f) for f in range(1, n_frames + 1)},
                                                    {**opts, "size": size})
        kw = {**opts, "size": size, **extra, **sequence.camera_overrides(cam)}
        records = [r for f in range(1, n_frames + 1) for r in sequence.render_chunk(
            [(f, pat.path(f), out / f"u_{f:04d}.{fmt}")], kw, {"exposure": 0.0, "tonemap": "filmic"})]
        res = summarise(records, time.perf_counter() - t)
        res.update(workers="0, one frame after another", cluster_start_s=0.0, gpus=[], chunk=None)
        return res
    def inline(scene, dev, builder=None):           # everything left to finish()
        return render_mod.Prepared(scene, dev)
    from volrender import frame_writer
    with mock.patch.object(render_mod, "prepare", render_mod.prepare if split else inline), \
            mock.patch.dict(os.environ, {frame_writer.MODE_ENV: writer}):
        r = sequence.render_sequence(str(pattern), str(out / f"f_####.{fmt}"), f"1-{n_frames}",
                                     workers=0, size=size, **opts)
    res = summarise(r.records, r.wall_s)
    res.update(workers=0 if split and writer == "process" else
               "0, set-up in the launching thread" if not split else "0, writes in a thread",
               cluster_start_s=0.0, gpus=[], chunk=None)
    unpiped = sorted(out.glob(f"u_*.{fmt}"))
    if unpiped:                 # the one-by-one run's files, where it ran first: same bytes?
        res["same_bytes_as_one_by_one"] = all(
            u.read_bytes() == (out / f"f_{u.name[2:]}").read_bytes() for u in unpiped)
    return res


def summarise(records, wall_s) -> dict:
    ok = [r for r in records if r.status == "ok"]
    secs = sorted(r.seconds for r in ok)

    def mean(key):
        return statistics.fmean(getattr(r, key) for r in ok) if ok else 0.0
    return {"frames": len(ok), "failed": len(records) - len(ok), "wall_s": wall_s,
            "fps": len(ok) / wall_s if wall_s > 0 else 0.0,
            "frame_s": {"min": secs[0], "median": statistics.median(secs), "max": secs[-1]} if secs else {},
            "mean_s": {k: mean(f"{k}_s") for k in ("load", "build", "setup", "kernel", "render",
                                                   "write")},
            "workers_used": sorted({r.worker for r in ok}),
            "devices": sorted({r.device for r in ok})}


def run(pattern, n_frames, out, n_workers, size, opts, chunk, dev_spec, fmt):
    from distributed import Client, LocalCluster
    import logging
    import os
    for name in ("distributed", "distributed.scheduler", "distributed.nanny"):
        logging.getLogger(name).setLevel(logging.ERROR)
    gpus = [] if dev_spec else sequence.gpu_specs()
    env = {"VOLRENDER_DEVICE": dev_spec} if dev_spec else {}
    if not dev_spec and not gpus:
        env["POCL_MAX_PTHREAD_COUNT"] = str(max(1, (os.cpu_count() or 1) // n_workers))
    t_start = time.perf_counter()
    cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                           dashboard_address=None, env=env, silence_logs=logging.ERROR)
    client = Client(cluster)
    try:
        if gpus:
            client.register_plugin(sequence.device_per_worker(gpus))
        start_s = time.perf_counter() - t_start
        opts = dict(size=size, **opts)
        warm = out / "warm"
        warm.mkdir(exist_ok=True)
        # one untimed frame per worker: each builds its programs
        frame1 = sequence.parse_pattern(str(pattern)).path(1)
        cam = sequence.sequence_camera({1: frame1}, opts)[0]
        kw = {**opts, **sequence.camera_overrides(cam)}
        futs = [client.submit(sequence.render_chunk, [(1, frame1, warm / f"w{i}.{fmt}")], kw, {},
                              pure=False, workers=[w]) for i, w in enumerate(client.scheduler_info()["workers"])]
        client.gather(futs)
        r = sequence.render_sequence(str(pattern), str(out / f"f_####.{fmt}"), f"1-{n_frames}",
                                     client=client, chunk=chunk, **opts)
        res = summarise(r.records, r.wall_s)
        res.update(workers=n_workers, cluster_start_s=start_s,
                   gpus=gpus, chunk=chunk)
        return res
    finally:
        client.close()
        cluster.close()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--file", default="smoke",
                    help="a real volume by name (shared data or bench/data/NAME.npz) or a path")
    ap.add_argument("--frames", type=int, default=48, help="frames in the sequence (default: 48)")
    ap.add_argument("--size", default="640x480", help="image size WxH (default: 640x480)")
    ap.add_argument("--workers", default="1,2", help="worker counts, comma-separated (default: 1,2)")
    ap.add_argument("--chunk", type=int, default=None, help="frames per task (default: automatic)")
    ap.add_argument("--device", default=None,
                    help="one OpenCL device for every worker (default: a GPU per worker, else PoCL)")
    ap.add_argument("--format", default="exr", choices=["exr", "npy", "png"],
                    help="output format; writing is part of a frame's time (default: exr)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a render option for every frame (load_scene's keyword), e.g. "
                         "glass_model=fast; repeatable")
    ap.add_argument("--points", type=int, default=0, metavar="N",
                    help="a point-cloud sequence of N-sphere blobs instead of a volume")
    ap.add_argument("--unpiped", action="store_true",
                    help="with --workers 0: first render the frames one after another as "
                         "before the pipeline (issue 35), then as the pipeline before "
                         "render.prepare (set-up in the launching thread), then with its "
                         "writes in a thread (before frame_writer.py), for their frames/s "
                         "and bytes")
    ap.add_argument("--tag", default=None, help="added to the results' name: sequence_<device>-<tag>.json")
    args = ap.parse_args(argv)
    width, height = (int(v) for v in args.size.lower().split("x"))
    src = None
    if not args.points:
        src = Path(args.file) if Path(args.file).suffix else find_volume(args.file)
        if src is None or not src.is_file():
            sys.exit(f"bench/sequence.py: {missing_data(args.file)}")
    dev = device.get(args.device or (sequence.gpu_specs() or [None])[0])
    counts = [int(v) for v in args.workers.split(",") if v]
    density = DENSITY.get(Path(args.file).stem, 1.0)
    opts = {} if args.points else {"density_scale": density}
    for item in args.set:
        key, _, value = item.partition("=")
        try:
            value = float(value) if "." in value or value.isdigit() else value
        except ValueError:
            pass
        opts[key] = int(value) if isinstance(value, float) and value.is_integer() and \
            "." not in item.partition("=")[2] else value
    folder = Path(tempfile.mkdtemp(prefix="volrender-seq-", dir=CONVERTED if CONVERTED.is_dir() else None))
    rows = []
    try:
        t0 = time.perf_counter()
        pattern = make_point_frames(args.points, args.frames, folder) if args.points else \
            make_frames(src, args.frames, folder)
        what = f"{args.points}-sphere clouds" if args.points else src.name
        print(f"made {args.frames} frames of {what} in {time.perf_counter() - t0:.1f} s", flush=True)
        if args.unpiped and 0 in counts:
            counts = ["unpiped", "inline", "thread"] + counts
        for n in counts:
            out = folder / f"out{0 if n in ('unpiped', 'inline', 'thread') else n}"
            out.mkdir(exist_ok=True)
            if n in (0, "unpiped", "inline", "thread"):
                row = run_serial(pattern, args.frames, out, (width, height), opts, args.device,
                                 args.format, piped=n != "unpiped", split=n != "inline",
                                 writer="thread" if n in ("inline", "thread") else "process")
            else:
                row = run(pattern, args.frames, out, n, (width, height), opts, args.chunk,
                          args.device, args.format)
            rows.append(row)
            row["speedup"] = row["fps"] / rows[0]["fps"] if rows[0]["fps"] else 0.0
            m = row["mean_s"]
            print(f"{n} workers: {row['fps']:.2f} frames/s (x{row['speedup']:.2f} of {counts[0]}), "
                  f"frame {row['frame_s'].get('median', 0):.3f} s median "
                  f"[load {m['load']:.3f}, build {m['build']:.3f}, setup+upload {m['setup']:.3f}, "
                  f"kernel {m['kernel']:.3f}, write {m['write']:.3f}], cluster start "
                  f"{row['cluster_start_s']:.1f} s", flush=True)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    path = result_path("sequence", dev, args.tag)
    write_json(path, {"benchmark": "sequence", **device_info(dev),
                      "file": str(src) if src else f"blob:{args.points} frames",
                      "frames": args.frames, "size": [width, height], "format": args.format,
                      "options": opts,
                      "density_scale": density, "rows": rows})
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
