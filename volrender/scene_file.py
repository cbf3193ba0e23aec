"""Scene files (TOML) and the option table they share with the command line.

`options()` maps every override key (the CLI flag with underscores) to the settings field
it sets (VolumeSettings, GlassSettings, camera.View, CommonSettings: settings.knob); the
scene-file SCHEMA follows from it. `read`/`parse` check each key's type and reject unknown
keys and sections by full path (`[material].iro`); scene.load_scene then checks ranges and
kinds. Paths resolve relative to the file.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path

from .camera import View
from .errors import UserError, suggest
from .files import check_input, read_toml
from .glass import GlassSettings
from .settings import ENV, NUM, PATH, SIZE, STRS, VEC, VEC3, CommonSettings, knobs, override_key
from .volume import VolumeSettings

MAX_COUNT = 50_000_000          # [points].count and GENERATOR:COUNT


# --------------------------------------------------------------------------- options

@dataclass(frozen=True)
class Option:
    key: str                          # override keyword (CLI flag with underscores)
    field: str                        # settings field it sets
    owner: str                        # "common", "volume", "glass" or "view"
    meta: dict

    @property
    def flag(self) -> str:
        return "--" + self.key.replace("_", "-")


def _options() -> dict[str, Option]:
    out = {}
    common = {f.name for f, _ in knobs(CommonSettings)}
    for cls, owner in ((View, "view"), (CommonSettings, "common"), (VolumeSettings, "volume"),
                       (GlassSettings, "glass")):
        for f, meta in knobs(cls):
            if owner != "common" and f.name in common:
                continue
            key = override_key(f, meta)
            out[key] = Option(key, f.name, owner, meta)
    return out


LIGHT_KEYS = ("sun", "point_light", "no_lights", "lights")
EXTRA_KEYS = LIGHT_KEYS + ("camera",)     # override keys that are not settings fields


@functools.lru_cache(maxsize=None)
def options() -> dict[str, Option]:
    """Every override key -> Option (the CLI builds its render options from these)."""
    return _options()


# --------------------------------------------------------------------------- scene files

def _schema() -> dict:
    """Scene-file sections -> key -> value kind (bool, int, str or settings.NUM ...)."""
    schema = {"points": {"file": PATH, "generator": str, "count": int, "seed": int},
              "volume": {"file": PATH}, "material": {}, "camera": {},
              "lights": {"type": str, "direction": VEC3, "irradiance": NUM, "position": VEC3,
                         "intensity": NUM, "color": VEC3},
              "environment": {}, "render": {}}
    for opt in options().values():
        if opt.meta["toml"]:
            section, key = opt.meta["toml"]
            schema[section][key] = opt.meta["kind"]
    return schema


def finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _check_type(value, kind, where, base: Path):
    def bad(want):
        raise UserError(f"{where} must be {want}, got {value!r}")
    if kind is bool:
        return value if isinstance(value, bool) else bad("true or false")
    if kind is int:
        if finite(value) and float(value).is_integer():
            return int(value)    # spp = 2.0 (integral floats are integers here)
        return bad("an integer")
    if kind is str:
        return value if isinstance(value, str) else bad("a string")
    if kind == NUM:
        return float(value) if finite(value) else bad("a finite number")
    if kind == ENV:              # a uniform R,G,B or a map file
        return _check_type(value, VEC if isinstance(value, (list, int, float)) else PATH,
                           where, base)
    if kind == VEC and finite(value):
        value = [value]          # one number = one value (e.g. albedo = 0.9)
    if kind in (VEC3, VEC):
        n = (3,) if kind == VEC3 else (1, 2, 3)
        if not (isinstance(value, list) and len(value) in n and all(map(finite, value))):
            bad("a list of 3 finite numbers" if kind == VEC3 else "a list of 1 to 3 finite numbers")
        return tuple(float(v) for v in value)
    if kind == SIZE:
        if (not isinstance(value, list) or len(value) != 2
                or not all(finite(v) and float(v).is_integer() and 1 <= v <= 32768
                           for v in value)):
            bad("[width, height] with integers 1..32768")
        return tuple(int(v) for v in value)
    if kind == STRS:
        if not (isinstance(value, list) and all(isinstance(v, str) for v in value)):
            bad("a list of strings")
        return tuple(value)
    if kind == PATH:
        if not isinstance(value, str) or not value:
            bad("a file path")
        try:        # a NUL byte or an over-long name raise ValueError / OSError here
            path = (base / value).resolve()        # a loop raises RuntimeError on 3.11
            exists, is_dir = path.exists(), path.is_dir()
        except (OSError, ValueError, RuntimeError) as exc:
            reason = getattr(exc, "strerror", None) or str(exc)
            raise UserError(f"{where} is not a usable file path ({reason}): {value[:80]!r}",
                            fix="give the path of an existing file") from None
        if not exists:
            raise UserError(f"{where} names {value!r}, which does not exist (paths are relative "
                            f"to the scene file)")
        if is_dir:
            raise UserError(f"{where} names {value!r}, which is a directory",
                            fix="give the path of a file")
        try:
            check_input(path, "file")
        except UserError as exc:             # a FIFO, a device, an unreadable file
            raise UserError(f"{where} names {value!r}: {str(exc).split(': ', 1)[-1]}") from None
        return path
    raise AssertionError(kind)


def _section(table, name, where, base):
    if not isinstance(table, dict):
        raise UserError(f"{where} must be a table")
    schema = SCHEMA[name]
    out = {}
    for key, value in table.items():
        if key not in schema:
            close = suggest(key, schema, lambda k: f"{where}.{k}")
            raise UserError(f"unknown key {where}.{key}" + (f"; {close}" if close else ""),
                            fix=f"known keys: {', '.join(sorted(schema))}")
        out[key] = _check_type(value, schema[key], f"{where}.{key}", base)
    return out


def read(path) -> dict:
    """Parse and type-check a scene file: {section: {key: value}}, 'lights' a list, paths
    resolved relative to the file."""
    path = check_input(path, "scene file")
    raw = read_toml(path, "scene file")
    try:
        return parse(raw, path.parent)
    except UserError as exc:
        raise UserError(str(exc), path=path) from None


def parse(raw: dict, base: Path = Path(".")) -> dict:
    scene = {}
    for name, table in raw.items():
        if name not in SCHEMA:
            close = suggest(name, SCHEMA, lambda k: f"[{k}]")
            raise UserError(f"unknown section [{name}]" + (f"; {close}" if close else ""),
                            fix=f"known sections: {', '.join(sorted(SCHEMA))}")
        if name == "lights":
            if not isinstance(table, list):
                raise UserError("lights must be an array of tables: write [[lights]]")
            scene[name] = [_light(_section(t, name, f"[[lights]] #{i + 1}", base), i)
                           for i, t in enumerate(table)]
        else:
            scene[name] = _section(table, name, f"[{name}]", base)
    pts, vol = scene.get("points"), scene.get("volume")
    if pts is None and vol is None:
        raise UserError("the scene has no [points] or [volume] section",
                        fix="add [points] with file = ... or generator = ..., or [volume] with file = ...")
    if pts is not None and vol is not None:
        raise UserError("the scene has both [points] and [volume]; a scene renders one of them")
    if vol is not None:
        if "file" not in vol:
            raise UserError("[volume] needs file = ...")
        for section in ("material",):
            if section in scene:
                raise UserError(f"[{section}] applies to point clouds (molten glass), not to "
                                "a [volume]", fix=f"remove [{section}]")
        return scene
    if ("file" in pts) == ("generator" in pts):
        raise UserError("[points] needs exactly one of file = ... or generator = ...")
    if "generator" in pts and "count" not in pts:
        raise UserError("[points].generator needs count = N")
    if "count" in pts and not 1 <= pts["count"] <= MAX_COUNT:
        raise UserError(f"[points].count must be in [1, 5e7], got {pts['count']}")
    return scene


def _light(d, i):
    where = f"[[lights]] #{i + 1}"
    kind = d.get("type")
    need = {"sun": ("direction",), "point": ("position",)}
    if kind not in need:
        raise UserError(f"{where}.type must be \"sun\" or \"point\", got {kind!r}")
    for key in need[kind]:
        if key not in d:
            raise UserError(f"{where} ({kind}) needs {key}")
    extra = {"sun": {"position", "intensity"}, "point": {"direction", "irradiance"}}[kind] & set(d)
    if extra:
        raise UserError(f"{where}: a {kind} light has no {', '.join(sorted(extra))}")
    return d


SCHEMA = _schema()
