"""Command line: `volrender render | convert | info`."""
from __future__ import annotations

import argparse
import logging
import os
import re
import sys
import time
import warnings
from pathlib import Path

from . import __version__
from .errors import UserError

VOLUME_SUFFIXES = (".vdb", ".npz")


# ---------------------------------------------------------------- argument parsing

def floats(n_min: int, n_max: int | None = None, name: str = "value"):
    """argparse type: comma-separated floats, n_min..n_max of them."""
    n_max = n_max or n_min

    def parse(text: str):
        try:
            vals = tuple(float(v) for v in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name}: expected numbers separated by commas, got {text!r}")
        if not n_min <= len(vals) <= n_max:
            want = f"{n_min}" if n_min == n_max else f"{n_min} to {n_max}"
            raise argparse.ArgumentTypeError(f"{name}: expected {want} numbers, got {len(vals)} in {text!r}")
        return vals
    return parse


def size(text: str):
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WxH such as 640x480, got {text!r}")
    if not (1 <= w <= 32768 and 1 <= h <= 32768):
        raise argparse.ArgumentTypeError(f"image size must be 1..32768 per side, got {text!r}")
    return w, h


class Formatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    pass


def add_common(p):
    p.add_argument("--device", default=None,
                   help="OpenCL device: substring of 'platform / device' or 'P:D' "
                        "(default: $VOLRENDER_DEVICE, else PoCL)")
    p.add_argument("--debug", action="store_true", help="show tracebacks and build logs")
    p.add_argument("-v", "--verbose", action="store_true", help="log program builds and timings")


def build_parser():
    parser = argparse.ArgumentParser(
        prog="volrender", formatter_class=Formatter,
        description="Render OpenVDB volumes with OpenCL (PoCL by default).",
        epilog="Examples:\n  volrender render smoke.vdb -o smoke.png --sun 0,-1,-1,3\n"
               "  volrender convert smoke.vdb smoke.npz\n  volrender info")
    parser.add_argument("--version", action="version", version=f"volrender {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    r = sub.add_parser("render", formatter_class=Formatter, help="render a volume to an image",
                       description="Render an OpenVDB grid (.vdb) or a converted brick file "
                                   "(.npz) with single scattering, shadow rays and a mixed "
                                   "Henyey-Greenstein phase.")
    r.add_argument("input", help="IN.vdb or IN.npz")
    r.add_argument("-o", "--output", required=True, help="OUT.exr (linear RGBA), .npy, or .png")
    g = r.add_argument_group("image and camera")
    g.add_argument("--size", type=size, default=(640, 480), metavar="WxH", help="image size")
    g.add_argument("--origin", type=floats(3, name="--origin"), metavar="X,Y,Z",
                   help="camera position (default: frame the volume's bounds)")
    g.add_argument("--target", type=floats(3, name="--target"), metavar="X,Y,Z",
                   help="point looked at (default: the bounds' centre)")
    g.add_argument("--up", type=floats(3, name="--up"), default=(0.0, 1.0, 0.0), metavar="X,Y,Z")
    g.add_argument("--fov", type=float, default=40.0, help="vertical field of view, degrees")
    g.add_argument("--spp", type=int, default=1, help="samples per pixel (box filter)")
    g.add_argument("--seed", type=int, default=0, help="random seed")
    g.add_argument("--background", type=floats(1, 3, "--background"), default=(0.0,),
                   metavar="R,G,B", help="radiance behind the volume (one value = grey)")
    lg = r.add_argument_group("lights (default: one sun, direction -0.6,-1,-0.5, E=6)")
    lg.add_argument("--sun", type=floats(4, name="--sun"), action="append", default=[],
                    metavar="DX,DY,DZ,E", help="sun: propagation direction and irradiance (repeatable)")
    lg.add_argument("--point-light", type=floats(4, name="--point-light"), action="append",
                    default=[], metavar="X,Y,Z,I", help="point light: position and intensity (repeatable)")
    lg.add_argument("--no-lights", action="store_true", help="no lights: absorption and emission only")
    lg.add_argument("--no-shadows", action="store_true", help="lights are not attenuated by the volume")
    m = r.add_argument_group("medium")
    m.add_argument("--grid", default=None, help="density grid (default: 'density', else the only float fog grid)")
    m.add_argument("--density-scale", type=float, default=1.0, help="sigma_t = scale * grid value")
    m.add_argument("--albedo", type=float, default=0.9, help="single-scattering albedo")
    m.add_argument("--phase", type=floats(1, 3, "--phase"), default=(0.6, -0.3, 0.8),
                   metavar="G1,G2,W", help="w*HG(g1) + (1-w)*HG(g2); one value = single lobe; "
                                           "g > 0 scatters forward; |g| clamped to 0.999")
    m.add_argument("--emission-grid", default=None, help="grid emitting light (e.g. flame); off by default")
    m.add_argument("--emission-scale", type=float, default=1.0, help="emitted radiance per unit length per grid value")
    m.add_argument("--emission-temperature", type=float, default=1500.0, help="blackbody colour of the emission, K")
    q = r.add_argument_group("quality")
    q.add_argument("--step", type=float, default=0.5, help="primary step, voxels")
    q.add_argument("--shadow-step", type=float, default=1.0, help="shadow-ray step, voxels")
    q.add_argument("--no-skip", action="store_true", help="march empty bricks too (reference for skipping)")
    o = r.add_argument_group("output")
    o.add_argument("--aov", action="append", default=[], choices=["depth", "transmittance"],
                   help="extra EXR layer (repeatable): depth -> Z, transmittance -> T")
    o.add_argument("--exposure", type=float, default=0.0, help="PNG only: exposure in stops")
    o.add_argument("--tonemap", choices=["filmic", "clamp"], default="filmic", help="PNG only")
    o.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="progress bar (default: when stderr is a terminal)")
    add_common(r)

    c = sub.add_parser("convert", formatter_class=Formatter,
                       help="convert a VDB grid to volrender's brick file (.npz)",
                       description="Write the sparse brick layout of a VDB grid to .npz, so it "
                                   "can be rendered where OpenVDB is not installed.")
    c.add_argument("input", help="IN.vdb")
    c.add_argument("output", help="OUT.npz")
    c.add_argument("--grid", default=None, help="density grid (default: 'density', else the only float fog grid)")
    c.add_argument("--emission-grid", default=None, help="also convert this emission grid")
    c.add_argument("--debug", action="store_true", help="show tracebacks")
    c.add_argument("-v", "--verbose", action="store_true")

    i = sub.add_parser("info", formatter_class=Formatter,
                       help="list OpenCL devices and versions, or describe an input file")
    i.add_argument("input", nargs="?", help="optional: a .vdb or .npz to describe")
    add_common(i)
    return parser


# ---------------------------------------------------------------- commands

def cmd_render(args):
    from . import camera as camera_mod, device as device_mod, image, vdb
    from .lights import DEFAULT_LIGHTS, PointLight, Sun
    from .render import VolumeSettings, render_volume

    src = Path(args.input)
    if src.suffix.lower() not in VOLUME_SUFFIXES:
        raise UserError(f"unsupported input type {src.suffix or '(none)'!r}", path=src,
                        fix="give a .vdb or .npz volume")
    aovs = tuple(dict.fromkeys(args.aov))
    out_path = image.check_output(args.output, aovs)
    if not 0.0 < args.fov < 180.0:
        raise UserError(f"--fov must be in (0, 180) degrees, got {args.fov}")

    bg = args.background * 3 if len(args.background) == 1 else args.background
    phase = (args.phase[0], 0.0, 1.0) if len(args.phase) == 1 else args.phase
    settings = VolumeSettings(
        density_scale=args.density_scale, albedo=args.albedo, phase=phase, background=bg,
        step=args.step, shadow_step=args.shadow_step, spp=args.spp, seed=args.seed,
        shadows=not args.no_shadows, skip_empty=not args.no_skip,
        emission_scale=args.emission_scale, emission_temperature=args.emission_temperature,
        depth="depth" in aovs)
    if args.no_lights and (args.sun or args.point_light):
        raise UserError("--no-lights contradicts --sun/--point-light; drop one of them")
    lights = [Sun(tuple(s[:3]), s[3]) for s in args.sun]
    lights += [PointLight(tuple(p[:3]), p[3]) for p in args.point_light]
    if not lights and not args.no_lights:
        lights = list(DEFAULT_LIGHTS)

    dev = device_mod.get(args.device)
    t0 = time.perf_counter()
    bricks = vdb.load_volume(src, grid=args.grid, emission_grid=args.emission_grid)
    t_load = time.perf_counter() - t0
    lo, hi = bricks.world_bounds()
    width, height = args.size
    cam = camera_mod.frame_bounds(lo, hi, width, height, fov=args.fov, up=args.up)
    if args.origin or args.target:
        cam = camera_mod.Camera(args.origin or cam.origin, args.target or cam.target,
                                args.up, args.fov, width, height)

    result = render_volume(bricks, cam, lights, settings, dev, progress=args.progress)
    layers = {}
    if "depth" in aovs:
        layers["depth"] = result["depth"]
    if "transmittance" in aovs:
        layers["transmittance"] = 1.0 - result["rgba"][..., 3]
    image.write_image(out_path, result["rgba"], layers or None,
                      exposure=args.exposure, tonemap=args.tonemap)
    print(f"wrote {out_path} ({width}x{height}, {args.spp} spp) in "
          f"{result['wall_ms'] / 1e3:.2f} s (load {t_load:.2f} s) on {dev.name}", file=sys.stderr)
    return 0


def cmd_convert(args):
    from . import vdb
    src, dst = Path(args.input), Path(args.output)
    if src.suffix.lower() != ".vdb":
        raise UserError("convert reads OpenVDB files", path=src, fix="give a .vdb input")
    if dst.suffix.lower() != ".npz":
        raise UserError("convert writes .npz brick files", path=dst, fix="name the output OUT.npz")
    if not dst.parent.resolve().is_dir() or not os.access(dst.parent.resolve(), os.W_OK):
        raise UserError("output directory does not exist or is not writable", path=dst,
                        fix="choose a writable directory")
    t0 = time.perf_counter()
    bricks = vdb.load_bricks(src, grid=args.grid, emission_grid=args.emission_grid)
    bricks.save_npz(dst)
    n = len(bricks.majorant)
    print(f"wrote {dst}: grid {bricks.grid_name!r}, {n} bricks of 8^3 "
          f"(of {int(bricks.dims.prod())}), voxel size {bricks.voxel_size:.6g}, "
          f"in {time.perf_counter() - t0:.2f} s", file=sys.stderr)
    return 0


def cmd_info(args):
    from . import device as device_mod
    if args.input:
        from . import vdb
        src = Path(args.input)
        if src.suffix.lower() == ".vdb":
            for g in vdb.list_grids(src):
                print(f"{g.name:24s} {g.value_type:8s} {g.grid_class}")
            return 0
        b = vdb.load_volume(src)
        lo, hi = b.world_bounds()
        print(f"grid {b.grid_name!r}: {len(b.majorant)} bricks, dims {tuple(b.dims)}, "
              f"voxel size {b.voxel_size:.6g}, world bounds {tuple(lo)} .. {tuple(hi)}")
        return 0
    import numpy
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


COMMANDS = {"render": cmd_render, "convert": cmd_convert, "info": cmd_info}


def _warn_one_line(message, category, filename, lineno, file=None, line=None):
    print(f"volrender: warning: {message}", file=sys.stderr)


_NUMBER = re.compile(r"^-[0-9.]")


def join_negative_values(argv):
    """`--sun -1,-1,0,3` -> `--sun=-1,-1,0,3`: argparse would read '-1,...' as an option."""
    out, i = [], 0
    while i < len(argv):
        a = argv[i]
        if a.startswith("--") and "=" not in a and i + 1 < len(argv) and _NUMBER.match(argv[i + 1]):
            out.append(f"{a}={argv[i + 1]}")
            i += 2
        else:
            out.append(a)
            i += 1
    return out


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(join_negative_values(sys.argv[1:] if argv is None else list(argv)))
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="volrender: %(message)s")
    with warnings.catch_warnings():
        if not args.debug:
            warnings.showwarning = _warn_one_line
        return _run(args)


def _run(args) -> int:
    try:
        return COMMANDS[args.command](args)
    except UserError as exc:
        if args.debug:
            raise
        print(f"volrender: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("volrender: interrupted; no output written", file=sys.stderr)
        return 130
    except MemoryError:
        if args.debug:
            raise
        print("volrender: error: out of host memory; render a smaller image or volume", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
