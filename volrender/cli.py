"""Command line: `volrender render | convert | info`."""
from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import re
import sys
import time
import warnings
from pathlib import Path

from . import __version__
from .dispatch import parse_tile
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


class Parser(argparse.ArgumentParser):
    """Usage errors as one line, like every other error (subparsers inherit it)."""

    def error(self, message):
        self.exit(2, f"volrender: error: {message}; see `{self.prog} --help`\n")


def add_common(p):
    p.add_argument("--device", default=None,
                   help="OpenCL device: substring of 'platform / device' or 'P:D' "
                        "(default: $VOLRENDER_DEVICE, else PoCL)")
    p.add_argument("--debug", action="store_true", help="show tracebacks and build logs")
    p.add_argument("-v", "--verbose", action="store_true", help="log program builds and timings")


def build_parser():
    parser = Parser(
        prog="volrender", formatter_class=Formatter,
        description="Render OpenVDB volumes with OpenCL (PoCL by default).",
        epilog="Examples:\n  volrender render smoke.vdb -o smoke.png --sun 0,-1,-1,3\n"
               "  volrender convert smoke.vdb smoke.npz\n  volrender info")
    parser.add_argument("--version", action="version", version=f"volrender {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    r = sub.add_parser("render", formatter_class=Formatter, help="render a volume or a point cloud",
                       description="Render an OpenVDB grid (.vdb) or a converted brick file "
                                   "(.npz) with single scattering, shadow rays and a mixed "
                                   "Henyey-Greenstein phase; or a point cloud (.ply, .xyz, "
                                   ".csv, .txt, .npy, a generator NAME:COUNT such as "
                                   "glass_gather:2000, or a scene .toml) as molten glass. "
                                   "Command-line options override the scene file.")
    r.add_argument("input", help="IN.vdb, IN.npz, POINTS (.ply/.xyz/.csv/.txt/.npy), "
                                 "GENERATOR:COUNT, or SCENE.toml")
    r.add_argument("-o", "--output", required=True, help="OUT.exr (linear RGBA), .npy, or .png")
    g = r.add_argument_group("image and camera")
    g.add_argument("--size", type=size, default=None, metavar="WxH", help="image size (default: 640x480)")
    g.add_argument("--origin", type=floats(3, name="--origin"), metavar="X,Y,Z",
                   help="camera position (default: frame the volume's bounds)")
    g.add_argument("--target", type=floats(3, name="--target"), metavar="X,Y,Z",
                   help="point looked at (default: the bounds' centre)")
    g.add_argument("--up", type=floats(3, name="--up"), default=(0.0, 1.0, 0.0), metavar="X,Y,Z")
    g.add_argument("--fov", type=float, default=None, help="vertical field of view, degrees (default: 40)")
    g.add_argument("--spp", type=int, default=None, help="samples per pixel, box filter (default: 1)")
    g.add_argument("--seed", type=int, default=None, help="random seed (default: 0)")
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
    q.add_argument("--estimator", choices=["march", "track"], default="march",
                   help="volumes: march (ray marching: --step/--shadow-step, biased, low noise) or "
                        "track (delta/ratio tracking on brick majorants: unbiased, noisier)")
    q.add_argument("--no-skip", action="store_true", help="march empty bricks too (reference for skipping)")
    q.add_argument("--dispatch", choices=["auto", "fragment", "tiled"], default=None,
                   help="fragment: one independent work-item per pixel, launched in --tile "
                        "blocks; tiled: work-groups own screen tiles and cull the scene into "
                        "local memory first; auto: fragment, measured faster on PoCL and the "
                        "H200 (default: auto)")
    q.add_argument("--tile", type=parse_tile, default=None, metavar="WxH",
                   help="work-group size in pixels: fragment's blocks, tiled's tiles (default: 8x8)")
    gl = r.add_argument_group("molten glass (point clouds; defaults in volrender.glass.GlassSettings)")
    gl.add_argument("--radius", type=float, default=None,
                    help="sphere radius for every point (default: the file's radii, else half "
                         "the median neighbour spacing)")
    gl.add_argument("--blend", type=float, default=None,
                    help="smooth-union width k, world units; 0 = plain union (default: twice the median radius)")
    gl.add_argument("--leaf-size", type=int, default=None, help="points per tree leaf (default: 16)")
    gl.add_argument("--no-tree", action="store_true", help="brute force over all spheres (reference)")
    gl.add_argument("--bounces", type=int, default=None, help="surface events per path (default: 6)")
    gl.add_argument("--ior", type=float, default=None, help="index of refraction (default: 1.5)")
    gl.add_argument("--absorption", type=floats(3, name="--absorption"), default=None, metavar="R,G,B",
                    help="Beer-Lambert coefficient inside glass, per unit length (default: 0.15,0.6,1.6)")
    gl.add_argument("--color", type=floats(3, name="--color"), default=None, metavar="R,G,B",
                    help="colour of the glow (default: 1,0.42,0.12)")
    gl.add_argument("--reflectivity", type=float, default=None, help="scale on Fresnel reflection (default: 1)")
    gl.add_argument("--glow", type=float, default=None, help="hot-glass emission per unit length (default: 0.6)")
    gl.add_argument("--epsilon", type=float, default=None, help="relative hit threshold (default: 1e-4)")
    gl.add_argument("--max-steps", type=int, default=None, help="sphere-tracing steps per ray (default: 256)")
    gl.add_argument("--relax", type=float, default=None,
                    help="over-relaxed sphere tracing, factor in [1, 1.9]; 1 = plain (default: 1.6)")
    gl.add_argument("--env", default=None, metavar="ENV.exr",
                    help="equirectangular environment (default: procedural sky)")
    gl.add_argument("--opaque", action="store_true", help="no refraction: shaded opaque spheres")
    gl.add_argument("--shadow-angle", type=float, default=None, metavar="DEG",
                    help="angular radius of the lights: 0 = hard shadows, more = soft (default: 0)")
    gl.add_argument("--no-point-colors", action="store_true",
                    help="ignore the cloud's per-point colours (use --color everywhere)")
    o = r.add_argument_group("output")
    o.add_argument("--aov", action="append", default=[], choices=["depth", "transmittance"],
                   help="volumes: extra EXR layer (repeatable): depth -> Z, transmittance -> T")
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

    t = sub.add_parser("tree", formatter_class=Formatter,
                       help="show the partition tree of a point cloud, or a volume's bricks (pyvista)",
                       description="Draw the node boxes of the partition tree the renderer builds "
                                   "(coloured by depth, points coloured by leaf), or the occupied "
                                   "bricks of a volume (coloured by their maximum density).")
    t.add_argument("input", help="POINTS (.ply/.xyz/.csv/.txt/.npy), GENERATOR:COUNT, SCENE.toml, "
                                 "or a volume (.vdb/.npz)")
    t.add_argument("--leaf-size", type=int, default=16, help="points per leaf (default: 16, as render)")
    t.add_argument("--radius", type=float, default=None,
                   help="sphere radius (default: the file's, else half the median spacing)")
    t.add_argument("--blend", type=float, default=0.0, help="inflate node boxes by this margin")
    t.add_argument("--grid", default=None, help="volume grid name")
    lv = t.add_mutually_exclusive_group()
    lv.add_argument("--depth", type=int, default=None, help="show only this level")
    lv.add_argument("--leaves", action="store_true", help="show only the leaves")
    lv.add_argument("--max-depth", type=int, default=None, help="show levels 0..D")
    t.add_argument("--show", action="store_true", help="open an interactive window")
    t.add_argument("--screenshot", default=None, metavar="OUT.png", help="render off-screen to a PNG")
    t.add_argument("--export", default=None, metavar="OUT.vtm", help="write the boxes (.vtm, .vtk, .vtp)")
    t.add_argument("--window-size", type=size, default=(1024, 768), metavar="WxH")
    t.add_argument("--debug", action="store_true", help="show tracebacks")
    t.add_argument("-v", "--verbose", action="store_true")

    b = sub.add_parser("bench", formatter_class=Formatter, help="run a benchmark (source checkout)",
                       description="Run a benchmark from bench/; results (JSON + plot, with the "
                                   "device string) go to bench/results/. Options after NAME go to "
                                   "the benchmark: `volrender bench spheres --help`.\n\n" +
                                   "\n".join(f"  {k:8s} {v}" for k, v in BENCHMARKS.items()))
    b.add_argument("name", choices=sorted(BENCHMARKS), help="which benchmark")
    b.add_argument("args", nargs=argparse.REMAINDER, help="options for the benchmark")
    add_common(b)

    i = sub.add_parser("info", formatter_class=Formatter,
                       help="list OpenCL devices and versions, or describe an input file")
    i.add_argument("input", nargs="?", help="optional: a .vdb or .npz to describe")
    add_common(i)
    return parser


# ---------------------------------------------------------------- commands

POINT_SUFFIXES = (".ply", ".xyz", ".csv", ".txt", ".npy")


def input_kind(text: str) -> str:
    """'volume', 'points', 'scene' or 'generator' for a render input."""
    from . import points
    suffix = Path(text).suffix.lower()
    if suffix in VOLUME_SUFFIXES:
        return "volume"
    if suffix in POINT_SUFFIXES:
        return "points"
    if suffix == ".toml":
        return "scene"
    if ":" in text and text.split(":", 1)[0] in points.GENERATORS:
        return "generator"
    raise UserError(f"unsupported input type {suffix or '(none)'!r}", path=text,
                    fix=f"give a volume ({', '.join(VOLUME_SUFFIXES)}), points "
                        f"({', '.join(POINT_SUFFIXES)}), a scene (.toml) or GENERATOR:COUNT "
                        f"with GENERATOR one of {', '.join(points.GENERATORS)}")


def generated_cloud(text: str, seed: int = 0):
    """PointCloud from GENERATOR:COUNT."""
    from . import points
    name, _, count = text.partition(":")
    try:
        n = int(float(count))
    except ValueError:
        raise UserError(f"expected GENERATOR:COUNT such as {name}:2000, got {text!r}") from None
    if not 1 <= n <= 50_000_000:
        raise UserError(f"point count must be in [1, 5e7], got {n}")
    return points.generate(name, n, seed)


def pick(*values):
    """The first value that is not None."""
    return next((v for v in values if v is not None), None)


def cli_lights(args):
    from .lights import PointLight, Sun
    if args.no_lights and (args.sun or args.point_light):
        raise UserError("--no-lights contradicts --sun/--point-light; drop one of them")
    lights = [Sun(tuple(s[:3]), s[3]) for s in args.sun]
    lights += [PointLight(tuple(p[:3]), p[3]) for p in args.point_light]
    return lights or None


def check_image_memory(width: int, height: int, dev, n_layers: int = 0):
    """Refuse an image whose buffers cannot exist, before anything is loaded or allocated:
    the RGBA float32 buffer (plus one float per extra layer) must fit in one device
    allocation and in the device's memory, and a few copies of it in host memory."""
    import math
    pixels = width * height
    need = pixels * 4 * (4 + n_layers)
    gib = 1 << 30
    d = dev.device
    limit = min(int(d.max_mem_alloc_size) * (4 + n_layers) // 4, int(d.global_mem_size) // 2)
    where = f"on {dev.name}"
    try:
        host = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") // 3
    except (ValueError, OSError, AttributeError):
        host = None
    if host is not None and host < limit:
        limit, where = host, "in this machine's memory"
    if need > limit:
        side = int(math.sqrt(limit / (4 * (4 + n_layers)) * width / height))
        hint = f"e.g. {max(1, side)}x{max(1, side * height // width)}"
        raise UserError(f"a {width}x{height} image needs {need / gib:.1f} GiB of buffers, more than "
                        f"fits {where} ({limit / gib:.1f} GiB)",
                        fix=f"render a smaller --size ({hint} at most)")


def make_camera(args, lo, hi, scene_cam=None, scene_size=None):
    from . import camera as camera_mod
    scene_cam = scene_cam or {}
    width, height = pick(args.size, scene_size, (640, 480))
    fov = pick(args.fov, scene_cam.get("fov"), camera_mod.DEFAULT_FOV)
    if not 0.0 < fov < 180.0:
        raise UserError(f"--fov must be in (0, 180) degrees, got {fov}")
    up = pick(args.up if args.up != (0.0, 1.0, 0.0) else None, scene_cam.get("up"), (0.0, 1.0, 0.0))
    cam = camera_mod.frame_bounds(lo, hi, width, height, fov=fov, up=up)
    origin, target = pick(args.origin, scene_cam.get("origin")), pick(args.target, scene_cam.get("target"))
    if origin or target:
        cam = camera_mod.Camera(origin or cam.origin, target or cam.target, up, fov, width, height)
    return cam


def cmd_render(args):
    from . import image
    kind = input_kind(args.input)
    aovs = tuple(dict.fromkeys(args.aov))
    if aovs and kind != "volume":
        raise UserError(f"--aov {aovs[0]} is available for volumes only", path=args.input)
    out_path = image.check_output(args.output, aovs)
    if args.fov is not None and not 0.0 < args.fov < 180.0:
        raise UserError(f"--fov must be in (0, 180) degrees, got {args.fov}")
    lights = cli_lights(args)
    if args.size is not None:
        from . import device as device_mod
        check_image_memory(*args.size, device_mod.get(args.device), len(aovs))
    if kind == "volume":
        result, what = render_volume_input(args, lights, aovs)
    else:
        result, what = render_points_input(args, kind, lights)
    layers = {}
    if "depth" in aovs:
        layers["depth"] = result["depth"]
    if "transmittance" in aovs:
        layers["transmittance"] = 1.0 - result["rgba"][..., 3]
    image.write_image(out_path, result["rgba"], layers or None,
                      exposure=args.exposure, tonemap=args.tonemap)
    h, w = result["rgba"].shape[:2]
    print(f"wrote {out_path} ({w}x{h}, {what}) in {result['wall_ms'] / 1e3:.2f} s "
          f"(kernel {result['kernel_ms'] / 1e3:.2f} s) on {result['device']}", file=sys.stderr)
    return 0


def render_volume_input(args, lights, aovs):
    from . import device as device_mod, vdb
    from .lights import DEFAULT_LIGHTS
    from .volume import VolumeSettings, render_volume

    bg = args.background * 3 if len(args.background) == 1 else args.background
    phase = (args.phase[0], 0.0, 1.0) if len(args.phase) == 1 else args.phase
    spp = pick(args.spp, 1)
    settings = VolumeSettings(
        density_scale=args.density_scale, albedo=args.albedo, phase=phase, background=bg,
        step=args.step, shadow_step=args.shadow_step, spp=spp, seed=pick(args.seed, 0),
        shadows=not args.no_shadows, skip_empty=not args.no_skip,
        emission_scale=args.emission_scale, emission_temperature=args.emission_temperature,
        depth="depth" in aovs, estimator=args.estimator,
        dispatch=pick(args.dispatch, "auto"), tile=pick(args.tile, (8, 8)))
    if lights is None:
        lights = [] if args.no_lights else list(DEFAULT_LIGHTS)
    dev = device_mod.get(args.device)
    bricks = vdb.load_volume(Path(args.input), grid=args.grid, emission_grid=args.emission_grid)
    cam = make_camera(args, *bricks.world_bounds())
    result = render_volume(bricks, cam, lights, settings, dev, progress=args.progress)
    result["device"] = dev.name
    return result, f"{spp} spp"


def render_points_input(args, kind, lights):
    from . import device as device_mod, glass, points, scene as scene_mod
    from .lights import DEFAULT_LIGHTS, PointLight, Sun

    scene, radius = {}, None
    if kind == "scene":
        scene = scene_mod.load(args.input)
        cloud, radius = scene_mod.load_cloud(scene)
    elif kind == "generator":
        cloud = generated_cloud(args.input, pick(args.seed, 0))
    else:
        cloud = points.load_points(args.input)
    mat, rnd = scene.get("material", {}), scene.get("render", {})
    radius = pick(args.radius, radius)
    if radius is None and cloud.radii is None:
        radius = points.default_radius(cloud.centers)
        print(f"volrender: {len(cloud.centers)} points without radii: using radius {radius:.4g} "
              "(half the median neighbour spacing); set --radius", file=sys.stderr)
    values = dict(
        radius=radius, blend=pick(args.blend, rnd.get("blend")),
        leaf_size=pick(args.leaf_size, rnd.get("leaf_size")),
        use_tree=False if args.no_tree else rnd.get("tree"),
        bounces=pick(args.bounces, rnd.get("bounces")), ior=pick(args.ior, mat.get("ior")),
        absorption=pick(args.absorption, mat.get("absorption")),
        color=pick(args.color, mat.get("color")),
        reflectivity=pick(args.reflectivity, mat.get("reflectivity")),
        glow=pick(args.glow, mat.get("glow")), epsilon=pick(args.epsilon, rnd.get("epsilon")),
        max_steps=pick(args.max_steps, rnd.get("max_steps")), spp=pick(args.spp, rnd.get("spp")),
        relax=pick(args.relax, rnd.get("relax")),
        seed=pick(args.seed, rnd.get("seed")),
        env=pick(args.env, scene.get("environment", {}).get("map")),
        shadows=False if args.no_shadows else rnd.get("shadows"),
        refraction=False if args.opaque else None,
        shadow_angle=pick(args.shadow_angle, rnd.get("shadow_angle")),
        point_colors=False if args.no_point_colors else None,
        dispatch=pick(args.dispatch, rnd.get("dispatch")), tile=args.tile)
    settings = glass.GlassSettings(**{k: v for k, v in values.items() if v is not None})
    if settings.env is not None:
        settings = dataclasses.replace(settings, env=str(settings.env))
        if not Path(settings.env).is_file():
            raise UserError("no such environment map", path=settings.env)
    if lights is None:
        lights = [Sun(l["direction"], l.get("irradiance", 1.0), l.get("color", (1.0, 1.0, 1.0)))
                  if l["type"] == "sun" else
                  PointLight(l["position"], l.get("intensity", 1.0), l.get("color", (1.0, 1.0, 1.0)))
                  for l in scene.get("lights", [])]
        if not lights and not args.no_lights:
            lights = list(DEFAULT_LIGHTS)
    if args.no_lights:
        lights = []
    dev = device_mod.get(args.device)
    if args.size is None:              # --size was checked in cmd_render already
        check_image_memory(*pick(rnd.get("size"), (640, 480)), dev)
    radii = glass.sphere_radii(cloud, settings)
    cam = make_camera(args, *glass.sphere_bounds(cloud, radii), scene.get("camera"), rnd.get("size"))
    result = glass.render_points(cloud, cam, lights, settings, dev, progress=args.progress)
    result["device"] = dev.name
    return result, (f"{len(cloud.centers)} spheres, {settings.spp} spp, "
                    f"{'tree' if settings.use_tree else 'no tree'}")


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


def cmd_tree(args):
    from . import inspect
    view = dict(depth=args.depth, leaves=args.leaves, max_depth=args.max_depth,
                screenshot=args.screenshot, export=args.export, show=args.show,
                window_size=args.window_size)
    if input_kind(args.input) == "generator":
        t = inspect.show_cloud(generated_cloud(args.input), leaf_size=args.leaf_size, radius=args.radius,
                               blend=args.blend, **view)
    else:
        t = inspect.inspect_input(args.input, leaf_size=args.leaf_size, radius=args.radius,
                                  blend=args.blend, grid=args.grid, **view)
    done = [p for p in (args.screenshot, args.export) if p]
    if done:
        print(f"wrote {', '.join(map(str, done))} ({type(t).__name__.lower()})", file=sys.stderr)
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


BENCHMARKS = {"spheres": "molten glass against sphere count: dispatch, tree, lighting, uber-kernel",
              "volume": "volume files: skipping, fragment vs tiled dispatch",
              "error": "error against run time for every speed knob",
              "peers": "comparison with vdb_render and Mitsuba 3 (bash run.sh peers installs them)"}


def bench_dir() -> Path:
    """bench/ of the source checkout (benchmarks are not installed with the package)."""
    root = Path(__file__).resolve().parents[1]
    if not (root / "bench" / "common.py").is_file():
        raise UserError("volrender bench needs the source checkout (bench/ beside volrender/)",
                        fix="run it from a git clone of volrender")
    return root


def cmd_bench(args):
    root = bench_dir()
    sys.path.insert(0, str(root))
    import importlib
    module = importlib.import_module(f"bench.{args.name}")
    extra = list(args.args)
    if args.device and "--device" not in extra:
        extra = ["--device", args.device, *extra]
    return module.main(extra) or 0


COMMANDS = {"render": cmd_render, "convert": cmd_convert, "tree": cmd_tree, "info": cmd_info,
            "bench": cmd_bench}


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


_CL_OUT_OF_MEMORY = ("MEM_OBJECT_ALLOCATION_FAILURE", "OUT_OF_RESOURCES", "OUT_OF_HOST_MEMORY",
                     "INVALID_BUFFER_SIZE")


def _opencl_message(exc) -> str | None:
    """A one-line message for an OpenCL error (None when exc is not one)."""
    cl = sys.modules.get("pyopencl")
    if cl is None or not isinstance(exc, cl.Error):
        return None
    text = " ".join(str(exc).split())
    try:
        code = exc.code
    except Exception:                       # an Error built without a status record
        code = None
    oom = {getattr(cl.status_code, n) for n in _CL_OUT_OF_MEMORY if hasattr(cl.status_code, n)}
    if isinstance(exc, cl.MemoryError) or code in oom:
        return (f"the OpenCL device ran out of memory ({text}); render a smaller --size, fewer "
                "points or a smaller volume, or pick a device with more memory (--device)")
    return (f"OpenCL failed ({text}); try another --device, or rerun with --debug and report "
            "it as a volrender bug")


def _user_message(exc) -> str:
    """One line: a build error's compiler log is only shown with --debug."""
    from .device import BuildError
    text = str(exc)
    if "\n" not in text:
        return text
    if isinstance(exc, BuildError):
        return (text.splitlines()[0].rstrip(":") + "; this is a volrender bug: rerun with --debug "
                "to see the compiler log, and report it")
    return " ".join(text.split())


def _run(args) -> int:
    try:
        return COMMANDS[args.command](args)
    except UserError as exc:
        if args.debug:
            raise
        print(f"volrender: error: {_user_message(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("volrender: interrupted; no output written", file=sys.stderr)
        return 130
    except MemoryError:
        if args.debug:
            raise
        print("volrender: error: out of host memory; render a smaller image or volume", file=sys.stderr)
        return 2
    except Exception as exc:
        message = _opencl_message(exc)
        if message is None or args.debug:
            raise
        print(f"volrender: error: {message}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
