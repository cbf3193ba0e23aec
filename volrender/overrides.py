"""The options a scene is given, checked before anything loads (scene.request): keyword
overrides and scene-file keys as {option key: (value, where)}, their kinds, their field
values, and the lights they name. `where` is the flag, keyword or `FILE: [section].key`
that errors name."""
from __future__ import annotations

import argparse

import numpy as np

from .errors import UserError, option_name, suggest
from .lights import PointLight, Sun
from .settings import ENV, MAX_VALUE, SIZE, STRS, VEC, VEC3, check_value, coerce, pair
from .scene_file import EXTRA_KEYS, finite, options

KIND_NAMES = {"volume": "volumes", "glass": "molten glass (point clouds)"}


def explicit_keys(overrides) -> set:
    """Option keys given as overrides (not from a file)."""
    by_field = {o.field: o.key for o in options().values()}
    return {by_field.get(k, k) for k, v in overrides.items() if v is not None}


def _plain(value):
    """numpy arrays and scalars as tuples and Python numbers; lists as tuples."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (list, tuple)):
        return tuple(_plain(v) for v in value)
    return value


def _python_value(opt, value, where):
    """A keyword's value in the form the settings hold: one number where the option takes
    one value (albedo=0.99: grey), "WxH" for sizes, one string for a list of strings."""
    value = _plain(value)
    kind, check = opt.meta["kind"], opt.meta["check"]
    if kind == SIZE and isinstance(value, str):
        try:
            return pair(where)(value)
        except argparse.ArgumentTypeError as exc:
            raise UserError(str(exc)) from None
    if kind == STRS and isinstance(value, str):
        return (value,)
    if kind == ENV and finite(value):
        return (float(value),)               # env=0.5: a grey uniform radiance
    if kind in (VEC, VEC3) and finite(value) and check is not None and check((value,)) is None:
        return (float(value),)
    return value


def _light_values(key, value, where):
    """sun= / point_light=: one (x, y, z, power) tuple or a list of them, each 4 finite
    numbers; lights=: Sun and PointLight objects."""
    value = _plain(value) if key != "lights" else value
    if key in ("sun", "point_light"):
        if isinstance(value, tuple) and value and all(finite(v) for v in value):
            value = (value,)                 # one light given as one tuple
        what = "DX,DY,DZ,E" if key == "sun" else "X,Y,Z,I"
        if not isinstance(value, tuple) or not all(
                isinstance(v, tuple) and len(v) == 4 and all(map(finite, v)) for v in value):
            raise UserError(f"{where} takes 4 finite numbers ({what}) or a list of such "
                            f"tuples, got {value!r}")
        value = tuple(tuple(float(c) for c in v) for v in value)
    if key == "lights":
        if isinstance(value, (Sun, PointLight)):
            value = (value,)
        if not isinstance(value, (list, tuple)) or not all(
                isinstance(v, (Sun, PointLight)) for v in value):
            raise UserError(f"{where} takes a list of volrender.Sun and volrender.PointLight, "
                            f"got {value!r}")
    return value


def _negates(opt) -> bool:
    """Whether opt is a switch that turns its field off (`--no-tree` sets use_tree=False)."""
    return opt.meta["kind"] is bool and opt.key != opt.field


def given_from_overrides(overrides) -> dict:
    """{option key: (field value, where)} for keyword overrides. Keys are the CLI flags
    with underscores (`no_tree=True`); a field's own name works too (`use_tree=False`)."""
    opts = options()
    by_field = {opt.field: opt for opt in opts.values()}
    given = {}
    for key, value in overrides.items():
        if value is None:
            continue
        if key in EXTRA_KEYS:
            flag = "--" + key.replace("_", "-")
            given[key] = (_light_values(key, value, flag), flag)
            continue
        opt = opts.get(key) or by_field.get(key)
        if opt is None:
            raise UserError(f"unknown option {key!r}",
                            fix=suggest(key, [*opts, *EXTRA_KEYS, *by_field], option_name) or
                            "`volrender render --help` and docs/options.md list them")
        value = _python_value(opt, value, opt.flag if key == opt.key else f"{key}=")
        if key == opt.key and _negates(opt):
            if not isinstance(value, bool):
                raise UserError(f"{opt.flag} is a switch: give True or False, got {value!r}")
            value = not value
        given[opt.key] = (value, opt.flag if key == opt.key else f"{key}=")
    return given


def given_from_file(doc, path) -> dict:
    """{option key: (field value, where)} for the settings keys of a parsed scene file."""
    by_toml = {opt.meta["toml"]: opt for opt in options().values() if opt.meta["toml"]}
    given = {}
    for section, table in doc.items():
        if section == "lights" or not isinstance(table, dict):
            continue
        for key, value in table.items():
            opt = by_toml.get((section, key))
            if opt is not None:
                given[opt.key] = (value, f"{path}: [{section}].{key}")
    return given


def check_kinds(given, kind, label):
    for key, (value, where) in given.items():
        if key in EXTRA_KEYS:
            continue
        owner = options()[key].owner
        if owner in ("volume", "glass") and owner != kind:
            raise UserError(f"{where} applies to {KIND_NAMES[owner]} only, but {label} is "
                            f"{'a volume' if kind == 'volume' else 'a point cloud'}",
                            fix=f"remove {where.split(': ')[-1]}")


def field_values(given, owners):
    """Checked {field: value} of the given keys whose owner is in owners."""
    out = {}
    for key, (value, where) in given.items():
        if key in EXTRA_KEYS:
            continue
        opt = options()[key]
        if opt.owner in owners:
            value = coerce(opt.meta, value)
            check_value(opt.meta, value, where)
            out[opt.field] = value
    return out


def check_light(kind, vec, power, color, where):
    """Ranges of one light (settings.MAX_VALUE bounds radiance-like values, so the packed
    float32 radiance, colour x power, stays finite)."""
    name = ("irradiance", "direction") if kind == "sun" else ("intensity", "position")
    if not 0.0 <= power <= MAX_VALUE:
        raise UserError(f"{where}: {name[0]} must be in [0, {MAX_VALUE:g}], got {power:g}")
    if not all(0.0 <= c <= MAX_VALUE for c in color) or max(color) * power > MAX_VALUE:
        raise UserError(f"{where}: color x {name[0]} must be in [0, {MAX_VALUE:g}], got "
                        f"{', '.join(f'{c:g}' for c in color)} x {power:g}")
    if kind == "sun":
        top = max(abs(v) for v in vec)
        if top == 0.0:
            raise UserError(f"{where}: the direction must not be zero")
    elif max(abs(v) for v in vec) > MAX_VALUE:
        raise UserError(f"{where}: position coordinates must be within +-{MAX_VALUE:g}")


def lights_given(given, doc, path=None):
    no_lights = given.get("no_lights", (False, ""))[0]
    explicit = [k for k in ("lights", "sun", "point_light") if k in given]
    if no_lights and explicit:
        raise UserError(f"--no-lights contradicts --{explicit[0].replace('_', '-')}; drop one of them")
    if no_lights:
        return ()
    if "lights" in given:
        return tuple(given["lights"][0])
    if "sun" in given or "point_light" in given:
        for key, kind in (("sun", "sun"), ("point_light", "point")):
            for v in given.get(key, ((),))[0]:
                if v:
                    check_light(kind, v[:3], v[3], (1.0, 1.0, 1.0),
                                 f"--{key.replace('_', '-')} {','.join(f'{x:g}' for x in v)}")
        out = [Sun(tuple(s[:3]), s[3]) for s in given.get("sun", ((),))[0] if s]
        out += [PointLight(tuple(p[:3]), p[3]) for p in given.get("point_light", ((),))[0] if p]
        return tuple(out)
    if doc.get("lights"):
        out = []
        for i, l in enumerate(doc["lights"]):
            where = f"{path}: [[lights]] #{i + 1}" if path else f"[[lights]] #{i + 1}"
            color = l.get("color", (1.0, 1.0, 1.0))
            if l["type"] == "sun":
                check_light("sun", l["direction"], l.get("irradiance", 1.0), color, where)
                out.append(Sun(l["direction"], l.get("irradiance", 1.0), color))
            else:
                check_light("point", l["position"], l.get("intensity", 1.0), color, where)
                out.append(PointLight(l["position"], l.get("intensity", 1.0), color))
        return tuple(out)
    return None                           # the defaults, turned to the up axis by load()
