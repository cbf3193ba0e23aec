"""Settings fields with their one default, help text, range and names.

Every render knob is a field of a frozen settings dataclass (VolumeSettings in
volume.py, GlassSettings in glass.py, both extending CommonSettings here, and View in
camera.py). Its metadata says how it is checked, how the command line spells it and
which scene-file key sets it, so the CLI, scene files and Python share one default
and one range:

    step: float = knob(0.5, "primary step, voxels", check=positive, toml=("render", "step"))

`check_value` reports a bad value under the name the user wrote it with (`--step`,
`scene.toml: [render].step` or `step=`); `check_fields` runs every check of a settings
object (its __post_init__ calls it).
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import os
from dataclasses import dataclass, field

import numpy as np

from .dispatch import Dispatch
from .errors import UserError


# Value kinds of scene-file keys (scene.py checks them; the ranges are the knobs' checks).
NUM, VEC3, VEC, SIZE, PATH, STRS = "number", "vec3", "vec", "size", "path", "strings"
ENV = "environment"          # R,G,B (a list in scene files) or a file path


def knob(default, help: str, *, check=None, flag: str | None = "", toml=None, kind=None,
         parse=None, metavar=None, choices=None, show_default=True):
    """A dataclass field carrying its option metadata.

    flag: CLI spelling ('' = `--name-with-dashes`; None = not on the command line). A bool
    field is a switch: default False gives `--name`, default True gives the `flag` given
    (e.g. `--no-tree`), which sets it to False.
    check: value -> None or a phrase like "must be > 0" (see the checks below).
    toml: (section, key) of the scene file that sets it, or None; kind: the scene-file
    value kind (bool, int, str or one of NUM, VEC3, VEC, SIZE, PATH, STRS; default: from
    the default value).
    parse: argparse type for the CLI value.
    """
    if kind is None:
        kind = {bool: bool, int: int, float: NUM, str: str}.get(type(default))
        if isinstance(default, tuple) and len(default) == 3:
            kind = VEC3
    meta = {"help": help, "check": check, "flag": flag, "toml": toml, "kind": kind,
            "parse": parse, "metavar": metavar, "choices": choices, "show_default": show_default}
    if isinstance(default, (list, dict, set)):
        raise TypeError("mutable defaults are not allowed; use a tuple")
    return field(default=default, metadata={"knob": meta})


def knobs(cls):
    """[(field, metadata)] of a settings class, in declaration order."""
    return [(f, f.metadata["knob"]) for f in dataclasses.fields(cls) if "knob" in f.metadata]


def flag_of(f, meta) -> str | None:
    """The CLI spelling of a field (None when it has none)."""
    if meta["flag"] is None:
        return None
    return meta["flag"] or "--" + f.name.replace("_", "-")


def override_key(f, meta) -> str:
    """The Python keyword for a field: its CLI flag with underscores (`no_tree`), or its
    name when it has no flag."""
    flag = flag_of(f, meta)
    return flag[2:].replace("-", "_") if flag else f.name


def check_value(meta, value, where: str):
    """Raise UserError "<where> must be ..., got <value>" when value fails meta's check."""
    check = meta["check"]
    if check is None:
        return
    problem = check(value)
    if problem:
        raise UserError(f"{where} {problem}, got {_show(value)}")


def check_fields(obj):
    """Run every field check of a settings object (errors name the CLI flag). An integral
    float where an integer is expected (spp=2.0, as numpy and JSON hand them over) becomes
    that integer first."""
    for f, meta in knobs(type(obj)):
        value = getattr(obj, f.name)
        if coerce(meta, value) is not value:
            object.__setattr__(obj, f.name, coerce(meta, value))
        flag = flag_of(f, meta)
        check_value(meta, getattr(obj, f.name), flag if flag and not _is_switch(f) else f.name)


def _is_switch(f) -> bool:
    return f.type in ("bool", bool)


def _show(value):
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, tuple):
        return ",".join(_show(v) for v in value)
    return repr(value) if isinstance(value, str) else str(value)


# ---------------------------------------------------------------------- CLI parsers
# argparse types: they raise ArgumentTypeError, which argparse reports as a usage error.

def floats(n_min: int, n_max: int | None = None, name: str = "value"):
    """Comma-separated finite floats, n_min..n_max of them."""
    n_max = n_max or n_min

    def parse(text: str):
        try:
            vals = tuple(float(v) for v in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{name}: expected numbers separated by commas, got {text!r}") from None
        if not n_min <= len(vals) <= n_max:
            want = f"{n_min}" if n_min == n_max else f"{n_min} to {n_max}"
            raise argparse.ArgumentTypeError(f"{name}: expected {want} numbers, got {len(vals)} in {text!r}")
        if not all(map(math.isfinite, vals)):
            raise argparse.ArgumentTypeError(f"{name}: values must be finite, got {text!r}")
        return vals
    parse.__name__ = name
    return parse


def pair(name: str, lo: int = 1, hi: int = 32768):
    """WxH: two integers in [lo, hi]."""
    def parse(text: str):
        try:
            w, h = (int(v) for v in text.lower().split("x"))
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name}: expected WxH such as 640x480, got {text!r}") from None
        if not (lo <= w <= hi and lo <= h <= hi):
            raise argparse.ArgumentTypeError(f"{name}: must be {lo}..{hi} per side, got {text!r}")
        return w, h
    parse.__name__ = name
    return parse


def number(name: str, kind=float):
    """A finite float (or int)."""
    def parse(text: str):
        try:
            v = kind(text)
        except ValueError:
            what = "an integer" if kind is int else "a number"
            raise argparse.ArgumentTypeError(f"{name}: expected {what}, got {text!r}") from None
        if kind is float and not math.isfinite(v):
            raise argparse.ArgumentTypeError(f"{name}: must be finite, got {text!r}")
        return v
    parse.__name__ = name
    return parse


def env_value(text: str):
    """--env: 1 or 3 comma-separated numbers (a uniform radiance), else a file path."""
    try:
        return floats(1, 3, "--env")(text)
    except argparse.ArgumentTypeError:
        if all(c in "0123456789.,+-eE " for c in text):
            raise                 # numbers, but malformed: say so rather than "no such file"
        return text


env_value.__name__ = "--env"


# ---------------------------------------------------------------------- the checks

def _num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


def _integral(v) -> bool:
    """A float (Python or numpy) that holds an integer exactly: 2.0, not 2.5 nor inf."""
    return isinstance(v, (float, np.floating)) and math.isfinite(v) and float(v).is_integer()


def coerce(meta, value):
    """`value` as the field holds it: an integral float as an int where the check wants an
    integer, a size's integral floats as ints; anything else unchanged (the check judges)."""
    if getattr(meta["check"], "integer", False) and _integral(value):
        return int(value)
    if meta["kind"] == SIZE and isinstance(value, tuple):
        return integers(value)
    return value


def integers(values):
    """`values` (a tuple) with each integral float as an int (size=(320.0, 240.0))."""
    return tuple(int(v) if _integral(v) else v for v in values)


def in_range(lo, hi, *, integer=False, allow_none=False):
    """Finite number (an integer with integer=True) in [lo, hi]."""
    def check(v):
        if v is None and allow_none:
            return None
        ok = _int(v) if integer else _num(v)
        if not ok or not lo <= v <= hi:
            kind = "an integer" if integer else "a finite number"
            return f"must be {kind} in [{lo:g}, {hi:g}]"
        return None
    check.range = f"{lo}..{hi}" if integer else f"{lo:g}..{hi:g}"
    check.integer = integer
    return check


def rgb(lo=0.0, hi=math.inf, n=(3,)):
    """n finite numbers in [lo, hi] (n: the allowed counts)."""
    def check(v):
        if not (isinstance(v, tuple) and len(v) in n and all(_num(c) and lo <= c <= hi for c in v)):
            bound = f">= {lo:g}" if hi == math.inf else f"in [{lo:g}, {hi:g}]"
            count = " or ".join(map(str, n))
            return f"takes {count} finite values {bound}"
        return None
    check.range = f">= {lo:g} each" if hi == math.inf else f"{lo:g}..{hi:g} each"
    return check


def one_of(values):
    def check(v):
        return None if v in values else f"must be one of {', '.join(map(str, values))}"
    return check


def boolean(v):
    return None if isinstance(v, bool) else "must be true or false"


# ---------------------------------------------------------------------- shared settings

def tile_size(v):
    """A work-group tile WxH: 1..64 per side, at most 1024 work-items."""
    ok = (isinstance(v, tuple) and len(v) == 2 and all(_int(c) and 1 <= c <= 64 for c in v)
          and v[0] * v[1] <= 1024)
    return None if ok else "is out of range (WxH with 1..64 per side and W*H <= 1024)"


_SEED = in_range(-2 ** 63, 2 ** 64 - 1, integer=True)
_SEED.range = "any 64-bit integer"


# Largest radiance-like value accepted anywhere (lights, background, emission, glow...):
# far below float32's 3.4e38, so sums over samples and lights stay finite.
MAX_VALUE = 1e30


def env_ok(v):
    """An environment: None, a file path, or 3 radiances >= 0 (1 value = grey)."""
    if v is None or (isinstance(v, str) and v) or isinstance(v, os.PathLike):
        return None
    return rgb(0, MAX_VALUE, n=(1, 3))(v) and \
        "takes R,G,B (or one value) >= 0 as a uniform radiance, or the path of a map"


@dataclass(frozen=True)
class CommonSettings:
    """Knobs both renderers read."""
    spp: int = knob(1, "samples per pixel (box filter, stratified)",
                    check=in_range(1, 65536, integer=True), toml=("render", "spp"),
                    parse=number("--spp", int))
    seed: int = knob(0, "random seed", check=_SEED,
                     toml=("render", "seed"), parse=number("--seed", int))
    shadows: bool = knob(True, "lights are not attenuated on their way (unshadowed lights)",
                         check=boolean, flag="--no-shadows", toml=("render", "shadows"))
    dispatch: str = knob("auto", "fragment: one independent work-item per pixel, launched in "
                         "--tile blocks; tiled: work-groups own screen tiles and cull the scene "
                         "into local memory first; auto: fragment (measured faster on PoCL and "
                         "the H200)", check=one_of(("auto", "fragment", "tiled", "fragment-driver")),
                         choices=("auto", "fragment", "tiled"), toml=("render", "dispatch"))
    tile: tuple = knob((8, 8), "work-group size in pixels: fragment's blocks, tiled's tiles "
                       "(1..64 per side, W*H <= 1024)", check=tile_size,
                       metavar="WxH", parse=pair("--tile", 1, 64), toml=("render", "tile"),
                       kind=SIZE)
    transparent: bool = knob(False, "PNG: straight alpha (the background, sky and environment "
                             "kept only where nothing covers the pixel, for compositing) instead "
                             "of the opaque picture (default: opaque, as the render looks; EXR "
                             "is always premultiplied RGBA)", check=boolean,
                             toml=("render", "transparent"))
    denoise: str = knob("auto", "Open Image Denoise guided by the render's albedo (and "
                        "normals, for glass; the `denoise` extra): auto denoises PNG outputs and writes EXR/NPY as "
                        "rendered (an EXR denoised with on keeps the noisy image and the guides "
                        "as layers); from Python auto is off", check=one_of(("auto", "on", "off")),
                        choices=("auto", "on", "off"), toml=("render", "denoise"))
    env: str | tuple | None = knob(
        None, "environment: R,G,B (a uniform radiance; one value = grey) or an "
        "equirectangular map (.exr, .hdr, .npy; centre looks along -z, top row up). Glass reflects "
        "and refracts it (default: a procedural sky over a checker ground); a volume is lit by "
        "it and shows it behind (default: none)", metavar="R,G,B|ENV.exr", parse=env_value,
        check=env_ok, toml=("environment", "map"), kind=ENV, show_default=False)

    def __post_init__(self):
        if isinstance(self.env, (int, float)) and not isinstance(self.env, bool):
            object.__setattr__(self, "env", (self.env,))
        if isinstance(self.env, tuple) and len(self.env) == 1:
            object.__setattr__(self, "env", tuple(self.env) * 3)
        if isinstance(self.env, tuple) and all(map(_num, self.env)):
            object.__setattr__(self, "env", tuple(float(v) for v in self.env))
        elif self.env is not None and not isinstance(self.env, (str, tuple)):
            object.__setattr__(self, "env", str(self.env))      # a pathlib.Path
        check_fields(self)
        Dispatch(self.dispatch, tuple(self.tile))     # raises UserError when invalid
