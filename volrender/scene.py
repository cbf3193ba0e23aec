"""Scene files (TOML) -> validated plain values. Unknown keys and wrong types are errors
that name the file and the key by its full path, e.g. `[material].iro`.

    [points]                 # a point cloud: file = ..., or generator = ... with count
    file = "cloud.ply"       # relative to the scene file
    radius = 0.02            # overrides per-point radii

    [material]               # molten glass
    color = [1.0, 0.6, 0.3]
    ior = 1.5
    absorption = [0.3, 1.0, 2.5]   # per unit length
    reflectivity = 1.0
    glow = 0.6

    [camera]                 # optional: default framing fits the cloud
    origin = [0, 1, 4]
    target = [0, 0.5, 0]
    fov = 35

    [[lights]]
    type = "sun"             # or "point" with position and intensity
    direction = [-0.5, -1, -0.3]
    irradiance = 3

    [environment]
    map = "sky.exr"          # equirectangular EXR; default: procedural sky

    [render]
    size = [640, 480]
    spp = 4
    bounces = 4
    blend = 0.05
"""
from __future__ import annotations

import math
import tomllib
from pathlib import Path

from .errors import UserError

NUM = (int, float)
MAX_COUNT = 50_000_000          # [points].count, as the CLI's GENERATOR:COUNT
VEC3 = "vec3"
SIZE = "size"
PATH = "path"

SCHEMA = {
    "points": {"file": PATH, "generator": str, "count": int, "seed": int, "radius": NUM},
    "material": {"color": VEC3, "ior": NUM, "absorption": VEC3, "reflectivity": NUM, "glow": NUM},
    "camera": {"origin": VEC3, "target": VEC3, "up": VEC3, "fov": NUM},
    "lights": {"type": str, "direction": VEC3, "irradiance": NUM, "position": VEC3,
               "intensity": NUM, "color": VEC3},
    "environment": {"map": PATH},
    "render": {"size": SIZE, "spp": int, "seed": int, "bounces": int, "blend": NUM,
               "leaf_size": int, "epsilon": NUM, "max_steps": int, "shadows": bool,
               "tree": bool, "shadow_angle": NUM, "dispatch": str, "relax": NUM},
}


def _check(value, kind, where, base: Path):
    def bad(want):
        raise UserError(f"{where} must be {want}, got {value!r}")
    if kind is bool:
        return value if isinstance(value, bool) else bad("true or false")
    if kind is int:
        return value if isinstance(value, int) and not isinstance(value, bool) else bad("an integer")
    if kind is NUM:
        if isinstance(value, bool) or not isinstance(value, NUM) or not math.isfinite(value):
            bad("a finite number")
        return float(value)
    if kind is str:
        return value if isinstance(value, str) else bad("a string")
    if kind == VEC3:
        if (not isinstance(value, list) or len(value) != 3
                or not all(isinstance(v, NUM) and not isinstance(v, bool) and math.isfinite(v)
                           for v in value)):
            bad("a list of 3 finite numbers")
        return tuple(float(v) for v in value)
    if kind == SIZE:
        if (not isinstance(value, list) or len(value) != 2
                or not all(isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= 32768
                           for v in value)):
            bad("[width, height] with integers 1..32768")
        return tuple(value)
    if kind == PATH:
        if not isinstance(value, str) or not value:
            bad("a file path")
        try:        # a NUL byte or an over-long name raise ValueError / OSError here
            path = (base / value).resolve()
            exists, is_dir = path.exists(), path.is_dir()
        except (OSError, ValueError) as exc:
            reason = getattr(exc, "strerror", None) or str(exc)
            raise UserError(f"{where} is not a usable file path ({reason}): {value[:80]!r}",
                            fix="give the path of an existing file") from None
        if not exists:
            raise UserError(f"{where} names {value!r}, which does not exist (paths are relative "
                            f"to the scene file)")
        if is_dir:
            raise UserError(f"{where} names {value!r}, which is a directory",
                            fix="give the path of a file")
        return path
    raise AssertionError(kind)


def _section(table, name, where, base):
    if not isinstance(table, dict):
        raise UserError(f"{where} must be a table")
    schema = SCHEMA[name]
    out = {}
    for key, value in table.items():
        if key not in schema:
            raise UserError(f"unknown key {where}.{key}",
                            fix=f"known keys: {', '.join(sorted(schema))}")
        out[key] = _check(value, schema[key], f"{where}.{key}", base)
    return out


def load(path) -> dict:
    """Parse and validate a scene file; returns {section: {key: value}} with 'lights' a
    list and paths resolved relative to the file."""
    path = Path(path)
    if not path.is_file():
        raise UserError("no such scene file", path=path)
    try:
        raw = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise UserError(f"not valid TOML ({exc})", path=path, fix="fix the syntax") from None
    try:
        return parse(raw, path.parent)
    except UserError as exc:
        raise UserError(str(exc), path=path) from None


def parse(raw: dict, base: Path = Path(".")) -> dict:
    scene = {}
    for name, table in raw.items():
        if name not in SCHEMA:
            raise UserError(f"unknown section [{name}]", fix=f"known sections: {', '.join(sorted(SCHEMA))}")
        if name == "lights":
            if not isinstance(table, list):
                raise UserError("lights must be an array of tables: write [[lights]]")
            scene[name] = [_light(_section(t, name, f"[[lights]] #{i + 1}", base), i)
                           for i, t in enumerate(table)]
        else:
            scene[name] = _section(table, name, f"[{name}]", base)
    pts = scene.get("points")
    if pts is None:
        raise UserError("the scene has no [points] section", fix="add [points] with file = ... or generator = ...")
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


def load_cloud(scene: dict):
    """(PointCloud, radius or None) from a parsed scene's [points] section."""
    from . import points
    pts = scene["points"]
    if "file" in pts:
        cloud = points.load_points(pts["file"])
    else:
        if not 1 <= pts["count"] <= MAX_COUNT:
            raise UserError(f"[points].count must be in [1, 5e7], got {pts['count']}")
        cloud = points.generate(pts["generator"], pts["count"], pts.get("seed", 0))
    return cloud, pts.get("radius")
