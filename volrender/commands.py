"""The commands: `volrender render | convert | tree | info | bench | view` once cli.py has
parsed their options. Each takes the argparse namespace and returns the exit status; a
UserError it raises becomes cli's one-line error."""
from __future__ import annotations

import importlib
import os
import sys
import time
import warnings
from pathlib import Path

import numpy

from . import __version__, atomic, device as device_mod, process
from .camera import describe as describe_camera, write_camera_file
from .device import resolve
from .errors import UserError, printable
from .files import check_input, refuse_overwrite
from .render import check_image_memory, image_problems, render
from .scene import request
from .scene_file import options
from .sequence import is_pattern, render_sequence
from .settings import in_range


def camera_overrides(args) -> dict:
    """The camera options given to `volrender tree`."""
    keys = [o.key for o in options().values() if o.owner == "view" and o.field != "size"]
    return {k: getattr(args, k) for k in keys + ["camera"] if getattr(args, k, None) is not None}


def render_overrides(args) -> dict:
    """The load_scene overrides the user gave on the command line."""
    return {k: getattr(args, k) for k in args.render_dests if getattr(args, k, None) is not None}


def describe(scene, img=None) -> str:
    """The status line's summary; with the image, the acceleration the render used."""
    s = scene.settings
    spp = img.info.spp if img is not None else s.spp     # the samples taken
    done = ", denoised" if img is not None and img.info.denoised else ""
    if scene.kind == "volume":
        return f"{spp} spp{done}"
    accel = img.info.accel if img is not None else s.accel
    model = f", {img.info.model}" if img is not None and img.info.model else ""
    return f"{len(scene.content.cloud.centers)} spheres, {spp} spp, accel {accel}{model}{done}"


def look_problems(img, scene) -> list[str]:
    """Warnings for an image that came out empty or saturated, with the fix (render()
    warns with them: render.image_problems)."""
    return image_problems(img, scene.kind)


SEQUENCE_OPTIONS = ("frames", "workers", "scheduler", "chunk", "skip_existing")


def time_breakdown(scene, img, write_s) -> str:
    """Where a render's time went (-v): load, radii (clouds without radii), tree and cells
    (glass: the scene's acceleration, 0 when reused), the program set-up, the kernels, the
    rest of the launches, the denoiser's guides and OIDN (when denoised) and the write."""
    parts = [("load", scene.timings.load), ("radii", scene.timings.radii)]
    if scene.kind == "glass":
        parts += [("tree", img.info.tree_ms / 1e3),
                  ("cells", img.info.cells_ms / 1e3)]
    build = sum(v for k, v in parts[2:]) if scene.kind == "glass" else 0.0
    setup = max(img.info.setup_ms / 1e3 - build, 0.0)
    parts += [("setup", setup), ("kernel", img.kernel_ms / 1e3),
              ("launch overhead", max(img.wall_ms - img.kernel_ms, 0.0) / 1e3),
              ("guides", img.info.guides_ms / 1e3 or None),
              ("denoise", img.info.denoise_ms / 1e3 or None), ("write", write_s)]
    return ", ".join(f"{k} {v:.3f} s" for k, v in parts if v is not None)


def cmd_sequence(args):
    from .denoise import decide
    overrides = render_overrides(args)
    on, note = decide(overrides.get("denoise", "auto"), Path(args.output).suffix)
    if note:
        process.say(f"volrender: {note}")
    overrides["denoise"] = "on" if on else "off"          # auto resolved by the output
    r = render_sequence(args.input, args.output, args.frames, workers=args.workers,
                        scheduler=args.scheduler, chunk=args.chunk,
                        skip_existing=args.skip_existing, device=args.device,
                        progress=args.progress, exposure=args.exposure, tonemap=args.tonemap,
                        say=lambda note: process.say(f"volrender: {note}"),
                        camera_out=args.camera_out, verbose=args.verbose, **overrides)
    for rec in r.failed:
        print(f"volrender: error: frame {rec.frame} ({rec.input}): {rec.error}",
              file=sys.stderr)
    done = sum(rec.status == "ok" for rec in r.records)
    skipped = sum(rec.status == "skipped" for rec in r.records)
    process.say(f"wrote {done} frames ({skipped} skipped, {len(r.failed)} failed) in {r.wall_s:.1f} s "
        f"({r.fps:.2f} frames/s, {r.workers or 'no'} Dask workers); record {r.record_path}")
    if r.failed:
        print(f"volrender: error: {len(r.failed)} frames failed: "
              f"{', '.join(str(rec.frame) for rec in r.failed)}", file=sys.stderr)
        return 2
    return 0


def cmd_render(args):
    from . import image
    image.check_view(args.tonemap)           # an OpenColorIO view that is missing: now
    if len(args.input) > 1:                  # the shell expanded a glob: a sequence of files
        return cmd_sequence(args)
    args.input = args.input[0]
    if args.frames is not None or is_pattern(args.input):
        return cmd_sequence(args)
    given = [o for o in SEQUENCE_OPTIONS if getattr(args, o) not in (None, False)]
    if given:
        raise UserError(f"--{given[0].replace('_', '-')} applies to sequences only, but "
                        f"{args.input} is one file", fix="give an input pattern (smoke_####.vdb)")
    from .denoise import decide
    overrides = render_overrides(args)
    req = request(args.input, **overrides)         # every option checked, nothing loaded
    on, denoise_note = decide(req.settings.denoise, Path(args.output).suffix)
    if req.settings.denoise != ("on" if on else "off"):     # auto resolved by the output
        overrides["denoise"] = "on" if on else "off"
        req = request(args.input, **overrides)
    aovs = req.settings.aovs if req.kind == "volume" else ()
    out_path = image.check_output(args.output, aovs, create=True)    # made at the write
    refuse_overwrite(out_path, req.inputs, shown=args.output)
    dev = resolve(args.device)
    check_image_memory(*req.view.size, dev, len(aovs))
    try:
        scene = req.load(device=dev)
    except MemoryError:
        raise UserError("out of host memory while reading it", path=args.input,
                        fix="render a smaller volume or cloud, or free memory") from None
    for note in [*scene.notes, *([denoise_note] if denoise_note else [])]:
        process.say(f"volrender: {note}")
    if args.verbose:
        process.say(f"volrender: {describe_camera(scene.camera)}")
    with warnings.catch_warnings():          # the denoiser's absence was said above
        warnings.filterwarnings("ignore", message="not denoised")
        img = render(scene, dev, progress=args.progress)
    if img.info.light_cache:          # the light cache's cost model (issue 33)
        process.say(f"volrender: {img.info.light_cache}")
    if img.info.adaptive:
        process.say(f"volrender: {img.info.adaptive}")
    t_write = time.perf_counter()
    img.save(out_path, exposure=args.exposure, tonemap=args.tonemap, png_bits=args.png_bits)
    if args.verbose:
        if img.info.note:
            process.say(f"volrender: {img.info.note}")
        print(f"volrender: time: {time_breakdown(scene, img, time.perf_counter() - t_write)}",
              file=sys.stderr)
    if args.camera_out:
        write_camera_file(scene.camera, args.camera_out)
    process.say(f"wrote {printable(out_path)} ({img.width}x{img.height}, {describe(scene, img)}) in {img.seconds:.2f} s "
        f"(kernel {img.kernel_ms / 1e3:.2f} s) on {img.device}")
    return 0


def cmd_convert(args):
    from . import vdb
    src, dst = Path(args.input), Path(args.output)
    if src.suffix.lower() != ".vdb":
        raise UserError("convert reads OpenVDB files", path=src, fix="give a .vdb input")
    if dst.suffix.lower() != ".npz":
        raise UserError("convert writes .npz brick files", path=dst, fix="name the output OUT.npz")
    check_input(src, "volume file", fix="give a .vdb file")
    real = atomic.destination(dst, "brick cache")
    if not real.parent.is_dir() or not os.access(real.parent, os.W_OK | os.X_OK):
        raise UserError("output directory does not exist or is not writable", path=dst,
                        fix="choose a writable directory")
    refuse_overwrite(real, [src], "convert", shown=args.output)
    t0 = time.perf_counter()
    bricks = vdb.load_bricks(src, grid=args.grid, emission_grid=args.emission_grid,
                             temperature_grid=args.temperature_grid)
    bricks.save_npz(dst)
    n = len(bricks.majorant)
    print(f"wrote {printable(dst)}: grid {printable(repr(bricks.grid_name))}, {n} bricks of 8^3 "
          f"(of {int(bricks.dims.prod())}), voxel size {bricks.voxel_size:.6g}, "
          f"in {time.perf_counter() - t0:.2f} s", file=sys.stderr)
    return 0


# tree's own numbers, checked before the input is read (the others are render's knobs)
TREE_RANGES = {"blend": (0, 1e18, False), "depth": (0, 2**31, True), "max_depth": (0, 2**31, True)}


def cmd_tree(args):
    from . import inspect
    for key, (lo, hi, integer) in TREE_RANGES.items():
        problem = in_range(lo, hi, integer=integer, allow_none=True)(getattr(args, key))
        if problem:
            raise UserError(f"--{key.replace('_', '-')} {problem}, got {getattr(args, key)!r}")
    view = dict(depth=args.depth, leaves=args.leaves, max_depth=args.max_depth,
                screenshot=args.screenshot, export=args.export, show=args.show,
                window_size=args.window_size)
    t = inspect.inspect_input(args.input, leaf_size=args.leaf_size, radius=args.radius,
                              blend=args.blend, grid=args.grid, cells=args.cells,
                              camera=camera_overrides(args), **view)
    done = [p for p in (args.screenshot, args.export) if p]
    if done:
        process.say(f"wrote {', '.join(map(str, done))} ({type(t).__name__.lower()})")
    return 0


def cmd_info(args):
    if args.input:
        from .info import describe
        for path in args.input:
            for line in describe(path, args.device):
                print(line)
        return 0
    import pyopencl
    print(f"volrender {__version__}, python {sys.version.split()[0]}, numpy {numpy.__version__}, "
          f"pyopencl {pyopencl.VERSION_TEXT}")
    for name, mod in (("OpenEXR", "OpenEXR"), ("pyvista", "pyvista")):
        try:
            m = __import__(mod)
            print(f"{name} {getattr(m, '__version__', '?')}")
        except ImportError as exc:
            print(f"{name}: not available ({exc})")
    try:
        from .vdb import import_openvdb
        ov = import_openvdb()
        print(f"OpenVDB {'.'.join(map(str, getattr(ov, 'LIBRARY_VERSION', ('?',))))} ({ov.__name__})")
    except UserError as exc:
        print(f"OpenVDB: not available ({exc})")
    chosen = device_mod.choose(args.device)[1]
    for i, j, p, d in device_mod.all_devices():
        mark = "*" if d.int_ptr == chosen.int_ptr else " "
        print(f"{mark} {i}:{j} {device_mod.describe(p, d)} | {d.version.strip()} | "
              f"driver {d.driver_version.strip()} | {d.max_compute_units} compute units")
    return 0


def bench_dir() -> Path:
    """bench/ of the source checkout (benchmarks are not installed with the package)."""
    root = Path(__file__).resolve().parents[1]
    if not (root / "bench" / "common.py").is_file():
        raise UserError("volrender bench needs the source checkout (bench/ beside volrender/)",
                        fix="run it from a git clone of volrender")
    return root


def cmd_bench(args):
    root = bench_dir()
    try:
        import matplotlib  # noqa: F401  (every benchmark plots its results)
    except ImportError as exc:
        raise UserError(f"matplotlib is not installed ({exc})",
                        fix="pip install 'volrender[bench]' (bash run.sh setup installs it)") from None
    sys.path.insert(0, str(root))
    module = importlib.import_module(f"bench.{args.name}")
    extra = list(args.args)
    if args.device and "--device" not in extra:
        extra = ["--device", args.device, *extra]
    sys.argv[0] = f"volrender bench {args.name}"      # the benchmark's usage line
    return module.main(extra) or 0


def cmd_view(args):
    from .viewer import cmd_view as view
    return view(args)
