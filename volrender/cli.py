"""Command line: `volrender render | view | convert | tree | info | bench`. It parses the
options (the parser is built from the knobs), runs the command (commands.py) and turns what
goes wrong into one line and an exit status; nothing else. Process hygiene (warnings,
signals, stream guards) lives in process.py, the option table in scene_file.py."""
from __future__ import annotations

import argparse
import dataclasses
import logging
import re
import sys
import warnings

from . import __version__, atomic, commands, process
from .camera import View
from .device import BuildError
from .errors import SPELLING, UserError, opencl_message, printable, suggest
from .glass import GlassSettings
from .scene_file import options
from .settings import floats, number, pair
from .volume import VolumeSettings


# ---------------------------------------------------------------- argument parsing

class Formatter(argparse.RawDescriptionHelpFormatter):
    """Defaults are written into each help text once (from the settings classes)."""


class Parser(argparse.ArgumentParser):
    """Usage errors as one line, like every other error (subparsers inherit it)."""

    def error(self, message):
        unknown = re.match(r"unrecognized arguments: (.*)", message)
        choice = re.match(r"argument (\S+): invalid choice: '([^']*)' \(choose from (.*)\)",
                          message)
        if unknown:           # "unknown option --spps; did you mean --spp?"; peers' -res
            words = [w.split("=")[0] for w in unknown.group(1).split()
                     if w.startswith("-") and not _NUMBER.match(w)]
            if words:
                known = [o[2:] for o in self._all_options()]
                close = suggest(words[0].lstrip("-"), known, lambda o: f"--{o}")
                message = f"unknown option {printable(words[0])}" + (f"; {close}" if close else "")
        elif choice:          # `volrender rendr`: "did you mean render?"
            known = re.findall(r"'([^']*)'", choice.group(3))
            close = suggest(choice.group(2), known)
            what = "command" if choice.group(1) == "COMMAND" else f"value for {choice.group(1)}"
            message = (f"unknown {what} {printable(repr(choice.group(2)))}; "
                       + (close or f"choose from {', '.join(known)}"))
        self.exit(2, f"volrender: error: {message}; see `{self.prog} --help`\n")

    def _all_options(self) -> list:
        """The long options of this parser and of its subcommands."""
        out = []
        for action in self._actions:
            out += [o for o in action.option_strings if o.startswith("--")]
            for sub in (getattr(action, "choices", None) or {}).values() \
                    if isinstance(action, argparse._SubParsersAction) else ():
                out += sub._all_options()
        return list(dict.fromkeys(out))


def add_common(p):
    p.add_argument("--device", default=None,
                   help="OpenCL device: substring of 'platform / device' or 'P:D' "
                        "(default: $VOLRENDER_DEVICE, else PoCL)")
    p.add_argument("--debug", action="store_true", help="show tracebacks and build logs")
    p.add_argument("-v", "--verbose", action="store_true",
                   help="log program builds and timings, and print the camera used")


def _show(value) -> str:
    if isinstance(value, tuple):
        if len(value) == 2 and all(isinstance(v, int) for v in value):
            return f"{value[0]}x{value[1]}"
        return ",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in value)
    return f"{value:g}" if isinstance(value, float) else str(value)


def add_option(group, opt, default):
    """One render option from its settings knob (help and default written once)."""
    meta = opt.meta
    text = meta["help"]
    bounds = getattr(meta["check"], "range", None)
    if meta["show_default"] and default is not None and meta["kind"] is not bool:
        text += f" (default: {_show(default)}{f'; range {bounds}' if bounds else ''})"
    elif bounds:
        text += f" (range {bounds})"
    kw = dict(dest=opt.key, default=None, help=text)
    if meta["kind"] is bool:
        group.add_argument(opt.flag, action="store_true", **kw)
        return
    if opt.key == "aov":
        group.add_argument(opt.flag, action="append", choices=meta["choices"], **kw)
        return
    parse = meta["parse"] or {float: number(opt.flag), "number": number(opt.flag),
                              int: number(opt.flag, int)}.get(meta["kind"], str)
    if meta["choices"]:
        kw["choices"] = meta["choices"]
    group.add_argument(opt.flag, type=parse, metavar=meta["metavar"], **kw)


# which help group each render option joins: by owner, with a few common ones moved
GROUPS = [("image and camera", "view"), ("lights", "lights"), ("volumes (.vdb, .npz)", "volume"),
          ("molten glass (point clouds)", "glass"), ("sampling and dispatch", "common")]
_GROUP_OF = {"shadows": "lights", "env": "lights"}


def add_render_options(r):
    defaults = {**{f.name: f.default for f in dataclasses.fields(View)},
                **{f.name: f.default for f in dataclasses.fields(VolumeSettings)},
                **{f.name: f.default for f in dataclasses.fields(GlassSettings)}}
    groups = {owner: r.add_argument_group(title) for title, owner in GROUPS}
    lg = groups["lights"]
    lg.description = "default: one sun, direction -0.6,-1,-0.5, E=6"
    lg.add_argument("--sun", type=floats(4, name="--sun"), action="append", default=None,
                    metavar="DX,DY,DZ,E", help="sun: propagation direction and irradiance, E in "
                                               "0..1e30 (repeatable)")
    lg.add_argument("--point-light", type=floats(4, name="--point-light"), action="append",
                    default=None, metavar="X,Y,Z,I",
                    help="point light: position and intensity, irradiance I/r^2; I in 0..1e30 "
                         "(repeatable)")
    lg.add_argument("--no-lights", action="store_true", default=None,
                    help="no lights: absorption and emission only")
    for opt in options().values():
        group = groups[_GROUP_OF.get(opt.field, opt.owner)]
        add_option(group, opt, defaults[opt.field])


def add_camera_options(t):
    """tree: the render's camera options (the image size is --window-size), so the view
    is the render's."""
    g = t.add_argument_group("camera (as render's: the view is the render's camera)")
    defaults = {f.name: f.default for f in dataclasses.fields(View)}
    for opt in options().values():
        if opt.owner == "view" and opt.field != "size":
            add_option(g, opt, defaults[opt.field])
    g.add_argument("--camera", default=None, metavar="CAM.toml",
                   help="the camera of a --camera-out file (options given beside it win)")


def build_parser():
    parser = Parser(
        prog="volrender", formatter_class=Formatter,
        description="Render OpenVDB volumes and point clouds (as molten glass) with OpenCL "
                    "(PoCL by default).",
        epilog="Examples:\n  volrender render smoke.vdb -o smoke.png --sun 0,-1,-1,3\n"
               "  volrender render bunny.ply -o bunny.exr --spp 4\n"
               "  volrender convert smoke.vdb smoke.npz\n  volrender info")
    parser.add_argument("--version", action="version", version=f"volrender {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    r = sub.add_parser("render", formatter_class=Formatter, help="render a volume or a point cloud",
                       description="Render an OpenVDB grid (.vdb) or a converted brick file "
                                   "(.npz) with single scattering, shadow rays and a mixed "
                                   "Henyey-Greenstein phase; or a point cloud (.ply, .xyz, "
                                   ".csv, .txt, .npy, a generator NAME:COUNT such as "
                                   "glass_gather:2000, or a scene .toml) as molten glass. "
                                   "Command-line options override the scene file; an option "
                                   "the input's kind does not read is an error.")
    r.add_argument("input", nargs="+", help="IN.vdb, IN.npz, POINTS (.ply/.xyz/.csv/.txt/.npy/"
                                            ".las/.laz), GENERATOR:COUNT, or SCENE.toml; a "
                                            "sequence: a pattern (smoke_####.vdb, quoted globs) "
                                            "or several files (an unquoted glob)")
    r.add_argument("-o", "--output", required=True,
                   help="OUT.exr (linear premultiplied RGBA + layers), OUT.npy (float32 HxWx4) "
                        "or OUT.png (tone-mapped sRGB, opaque; --transparent: straight alpha); never one of the "
                        "inputs; a symlink is written through")
    before = {a.dest for a in r._actions}
    add_render_options(r)
    r.set_defaults(render_dests=(*(a.dest for a in r._actions if a.dest not in before), "camera"))
    cg = [g for g in r._action_groups if g.title == "image and camera"][0]
    cg.add_argument("--camera", default=None, metavar="CAM.toml",
                    help="reuse a camera written by --camera-out (options given beside it win)")
    cg.add_argument("--camera-out", default=None, metavar="CAM.toml",
                    help="also write the camera used (origin, target, up, fov, size) as TOML")
    sq = r.add_argument_group(
        "sequences", "IN and -o as patterns: smoke_####.vdb (any number of #; @ as #), "
                     "smoke_$F4.vdb, smoke_%04d.vdb, "
                     "or a quoted glob 'smoke_*.vdb' (input only); one camera for every frame")
    sq.add_argument("--frames", default=None, metavar="A-B[xSTEP]",
                    help="frames to render: A-B, A-BxSTEP (A-B:STEP too), A-BySTEP (the frames "
                         "STEP skips), N, or a comma-separated list; default: every file the "
                         "pattern matches")
    sq.add_argument("--workers", type=_int("--workers"), default=None, metavar="N",
                    help="Dask workers of a LocalCluster on this machine; 0 renders in this "
                         "process (default: one per GPU, else one per 8 CPU cores; range 0..1024)")
    sq.add_argument("--scheduler", default=None, metavar="tcp://HOST:8786",
                    help="submit to an existing Dask cluster (`dask scheduler`, `dask worker`; "
                         "inputs and outputs on a shared filesystem)")
    sq.add_argument("--chunk", type=_int("--chunk"), default=None, metavar="K",
                    help="frames per task (default: enough tasks to keep every worker busy, "
                         "at most 8 frames each; range 1..1000000)")
    sq.add_argument("--skip-existing", action="store_true",
                    help="keep frames whose output exists and reads whole at this size (resume "
                         "an interrupted run); one that does not is rendered again and named")
    o = r.add_argument_group("output")
    o.add_argument("--exposure", type=_exposure, default=0.0,
                   help="PNG only: exposure in stops, in [-64, 64] (default: 0)")
    o.add_argument("--view", "--tonemap", dest="tonemap", choices=list(VIEW_CHOICES),
                   default="filmic", metavar="{filmic,standard,agx,aces}",
                   help="PNG only: the view transform. filmic: volrender's shoulder (identity "
                        "up to 0.5, mid-tones as rendered, highlights rolled off to white; the "
                        "default, as before); standard: sRGB clipped at 1 (Blender's Standard; "
                        "clamp is its older name); aces: ACES 1.0 SDR video; both through "
                        "OpenColorIO's built-in ACES config; agx: from the OpenColorIO config "
                        "$OCIO names (Blender's). --tonemap is its older name")
    o.add_argument("--png-bits", type=int, choices=[8, 16], default=8,
                   help="PNG only: bits per channel of the sRGB "
                        "file (default: 8)")
    o.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="progress bar (default: when stderr is a terminal)")
    add_common(r)

    w = sub.add_parser("view", formatter_class=Formatter,
                       help="view a volume or a point cloud in the browser, progressively",
                       description="Serve a viewer (viser) that renders INPUT here and shows "
                                   "it in a browser: small and one sample while the camera "
                                   "moves, accumulating samples when it stops; controls for "
                                   "the look; a button saves the image, its camera (for "
                                   "--camera) and the command that renders it. The still size "
                                   "follows the browser's canvas unless --size is given. "
                                   "docs/viewer.md")
    w.add_argument("input", help="IN.vdb, IN.npz, POINTS (.ply/.xyz/.csv/.txt/.npy/.las/.laz), "
                                 "GENERATOR:COUNT, or SCENE.toml")
    before = {a.dest for a in w._actions}
    add_render_options(w)
    w.set_defaults(render_dests=(*(a.dest for a in w._actions if a.dest not in before), "camera"))
    [g for g in w._action_groups if g.title == "image and camera"][0].add_argument(
        "--camera", default=None, metavar="CAM.toml",
        help="start from a camera written by --camera-out or by the viewer's save button")
    wv = w.add_argument_group("viewer")
    wv.add_argument("--port", type=_int("--port"), default=8080,
                    help="port it serves (default: 8080)")
    wv.add_argument("--host", default="127.0.0.1",
                    help="address it listens on (default: 127.0.0.1, this machine only; a remote "
                         "one through `ssh -N -L PORT:localhost:PORT HOST`; 0.0.0.0: every "
                         "interface, unauthenticated)")
    wv.add_argument("--save-dir", default=".", metavar="DIR",
                    help="where the save button writes view_NNNN.png, .camera.toml and .sh "
                         "(default: the current directory)")
    wv.add_argument("--exposure", type=_exposure, default=0.0,
                    help="initial exposure in stops (a control in the viewer)")
    wv.add_argument("--view", "--tonemap", dest="tonemap", choices=list(VIEW_CHOICES),
                    default="filmic", metavar="{filmic,standard,agx,aces}",
                    help="initial view transform (a control in the viewer)")
    add_common(w)

    c = sub.add_parser("convert", formatter_class=Formatter,
                       help="convert a VDB grid to volrender's brick file (.npz)",
                       description="Write the sparse brick layout of a VDB grid to .npz, so it "
                                   "can be rendered where OpenVDB is not installed.")
    c.add_argument("input", help="IN.vdb")
    c.add_argument("output", help="OUT.npz")
    c.add_argument("--grid", default=None,
                   help="density grid (default: 'density', else the only float fog-volume grid)")
    c.add_argument("--emission-grid", default=None, help="also convert this emission grid")
    c.add_argument("--temperature-grid", default=None,
                   help="also convert this temperature grid (colours the emission)")
    c.add_argument("--debug", action="store_true", help="show tracebacks")
    c.add_argument("-v", "--verbose", action="store_true", help="log what is done")

    t = sub.add_parser("tree", formatter_class=Formatter,
                       help="show the partition tree of a point cloud, or a volume's bricks (pyvista)",
                       description="Draw the node boxes of the partition tree the renderer builds "
                                   "(coloured by depth, points coloured by leaf), or the occupied "
                                   "bricks of a volume (coloured by their maximum density).")
    t.add_argument("input", help="POINTS (.ply/.xyz/.csv/.txt/.npy), GENERATOR:COUNT, SCENE.toml, "
                                 "or a volume (.vdb/.npz)")
    t.add_argument("--leaf-size", type=_int("--leaf-size"), default=None,
                   help="points per leaf (default: 16, as render)")
    t.add_argument("--radius", type=_float("--radius"), default=None,
                   help="sphere radius (default: the file's, else half the median spacing)")
    t.add_argument("--blend", type=_float("--blend"), default=0.0,
                   help="inflate node boxes by this margin (default: 0)")
    t.add_argument("--grid", default=None, help="volume grid name (default: 'density')")
    t.add_argument("--cells", action="store_true",
                   help="points: draw the glass support cells that hold a list, coloured by "
                        "list length, instead of the tree")
    lv = t.add_mutually_exclusive_group()
    lv.add_argument("--depth", type=_int("--depth"), default=None, help="show only this level")
    lv.add_argument("--leaves", action="store_true", help="show only the leaves")
    lv.add_argument("--max-depth", type=_int("--max-depth"), default=None, help="show levels 0..D")
    add_camera_options(t)
    t.add_argument("--show", action="store_true", help="open an interactive window")
    t.add_argument("--screenshot", default=None, metavar="OUT.png", help="render off-screen to a PNG")
    t.add_argument("--export", default=None, metavar="OUT.vtm", help="write the boxes (.vtm, .vtk, .vtp)")
    t.add_argument("--window-size", type=_pair("--window-size"), default=(1024, 768), metavar="WxH",
                   help="window or screenshot size (default: 1024x768)")
    t.add_argument("--debug", action="store_true", help="show tracebacks")
    t.add_argument("-v", "--verbose", action="store_true", help="log what is done")

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
    i.add_argument("input", nargs="*", help="optional: volume or point files to describe "
                   "(.vdb, .npz, .ply, .xyz, ...; several, or a glob)")
    add_common(i)
    return parser


def _exposure(text):
    v = number("--exposure")(text)
    if not -64 <= v <= 64:
        raise argparse.ArgumentTypeError(f"--exposure: must be in [-64, 64] stops, got {text!r}")
    return v


def _int(name):
    return number(name, int)


def _float(name):
    return number(name)


def _pair(name):
    return pair(name)


BENCHMARKS = {"spheres": "molten glass against sphere count: dispatch, tree, lighting, uber-kernel",
              "volume": "volume files: skipping, fragment vs tiled dispatch",
              "error": "error against run time for every speed knob",
              "peers": "comparison with vdb_render and Mitsuba 3 (bash run.sh peers installs them)",
              "sequence": "frame sequences on Dask: frames per second against worker count",
              "launch": "launch granularity: adaptive launch overhead, time to stop on signals",
              "build": "acceleration build time (tree, support cells) against sphere count",
              "edge": "support-cell edge against build and render time: the automatic edge's fit",
              "whole": "the whole command a user waits for, default against the alternatives",
              "latency": "a single command's time outside the kernel: start, imports, PNG",
              "viewer": "the viewer's frames: per second while moving, time to a converged still"}




# ---------------------------------------------------------------- dispatch

COMMANDS = {"render": commands.cmd_render, "convert": commands.cmd_convert,
            "tree": commands.cmd_tree, "info": commands.cmd_info, "bench": commands.cmd_bench,
            "view": commands.cmd_view}


_NUMBER = re.compile(r"^-[0-9.]")
VIEW_CHOICES = ("filmic", "standard", "agx", "aces", "clamp")     # image.TONEMAPS


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
    written_from = len(atomic.WRITTEN)       # what this command writes: WRITTEN[written_from:]
    streams = process.guard_streams()
    spelling = SPELLING.set("cli")            # errors name the flags, not Python keywords
    try:
        code, command = _main(argv, written_from)
        if code == 0:
            code = process.stdout_failed(command) or 0
        return code
    finally:
        SPELLING.reset(spelling)
        sys.stdout.flush()
        sys.stderr.flush()
        if argv is not None:                 # called from Python: give its streams back
            sys.stdout, sys.stderr = streams


def _main(argv, written_from) -> tuple:
    """(exit status, the command's name or None)."""
    command = None
    old = {}
    try:
        old = process.handle_signals()
        parser = build_parser()
        args = parser.parse_args(join_negative_values(sys.argv[1:] if argv is None else list(argv)))
        command = args.command
        logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                            format="volrender: %(message)s")
        with warnings.catch_warnings():
            if not args.debug:
                warnings.showwarning = process.warn_one_line
            code = _run(args, written_from)
        lost = process.lost_signal()         # a signal Python swallowed on the way
        if lost is not None:
            return process.interrupted(lost, atomic.WRITTEN[written_from:]), command
        return code, command
    except KeyboardInterrupt as exc:        # start-up, option parsing, or --debug
        if argv is not None and "--debug" in argv:
            raise
        return process.interrupted(exc, atomic.WRITTEN[written_from:]), command
    except Exception as exc:                # a signal inside a C extension's import
        signal_in = process.interrupt_within(exc)
        if signal_in is None:
            raise
        return process.interrupted(signal_in, atomic.WRITTEN[written_from:]), command
    finally:
        if argv is not None:                 # called from Python: its handlers back
            process.restore_signals(old)
        else:                                # the command is done, its status stands:
            process.ignore_signals()         # a late signal changes nothing, says nothing


def _user_message(exc) -> str:
    """One line: a build error's compiler log is only shown with --debug."""
    text = str(exc)
    if "\n" not in text:
        return text
    if isinstance(exc, BuildError):
        return (text.splitlines()[0].rstrip(":") + "; this is a volrender bug: rerun with --debug "
                "to see the compiler log, and report it")
    return " ".join(text.split())


def _run(args, written_from) -> int:
    try:
        return COMMANDS[args.command](args)
    except UserError as exc:
        if args.debug:
            raise
        process.say(f"volrender: error: {_user_message(exc)}")
        return 2
    except KeyboardInterrupt as exc:
        return process.interrupted(exc, atomic.WRITTEN[written_from:])
    except MemoryError:
        if args.debug:
            raise
        process.say("volrender: error: out of host memory; render a smaller image or volume")
        return 2
    except Exception as exc:
        signal_in = process.interrupt_within(exc)
        if signal_in is not None:            # a signal inside a C extension's import
            return process.interrupted(signal_in, atomic.WRITTEN[written_from:])
        message = opencl_message(exc)
        if message is None or args.debug:
            raise
        process.say(f"volrender: error: {message}")
        return 2


if __name__ == "__main__":
    sys.exit(main())
