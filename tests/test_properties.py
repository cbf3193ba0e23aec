"""Property-based tests (hypothesis) of the scene parser and the partition tree.

Scene files: documents generated from the schema are written as real TOML text and read
through scene.load (tomllib included). Valid ones parse to exactly their values; a
single wrong-typed or unknown key is refused with a one-line UserError naming the file
and the key by its full path; arbitrary documents either parse or raise UserError, never
another exception; and valid scenes go through the whole CLI to a finite image or a
one-line error. (test_scene.py fuzzes parse() on decoded dicts; test_tree.py fuzzes the
tree with numpy-generated degenerate clouds.)

Tree: point sets drawn by hypothesis itself (so failures shrink to a minimal cloud):
lattices full of duplicates, collinear and single points, wide magnitudes. The
invariants hold, every point is in exactly one leaf, and the float32 boxes the kernel
reads still contain every float32 sphere.
"""
import datetime
import math
import string

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings, strategies as st

from volrender import cli, glass, scene_file, spheres, tree as tree_mod
from volrender.errors import UserError
from volrender.cloud import PointCloud

FAST = settings(max_examples=40, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])


# ------------------------------------------------------------------ a tiny TOML writer

def toml_str(s: str) -> str:
    out = []
    for ch in s:
        if ch in '"\\':
            out.append("\\" + ch)
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return toml_str(v)
    if isinstance(v, (datetime.datetime, datetime.date, datetime.time)):
        return v.isoformat()
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{toml_key(k)} = {toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def toml_key(k: str) -> str:
    bare = k and all(c in string.ascii_letters + string.digits + "_-" for c in k)
    return k if bare else toml_str(k)


def to_toml(doc: dict) -> str:
    lines = []
    for name, table in doc.items():
        if isinstance(table, list) and table and all(isinstance(t, dict) for t in table):
            for t in table:
                lines.append(f"[[{toml_key(name)}]]")
                lines += [f"{toml_key(k)} = {toml_value(v)}" for k, v in t.items()]
        elif isinstance(table, dict):
            lines.append(f"[{toml_key(name)}]")
            lines += [f"{toml_key(k)} = {toml_value(v)}" for k, v in table.items()]
        else:
            lines.insert(0, f"{toml_key(name)} = {toml_value(table)}")   # top-level key
    return "\n".join(lines) + "\n"


def test_the_writer_round_trips():
    import tomllib
    doc = {"a": {"s": 'q"\\\n\x7f\x01é', "f": 1e300, "l": [1, 2.5, True], "d": datetime.date(2020, 1, 2)},
           "lights": [{"x": 1}, {"y": "z"}], "key with space": {"k": -0.0}}
    assert tomllib.loads(to_toml(doc)) == doc


# ------------------------------------------------------------------ schema-driven scenes

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
INT64 = st.integers(-(2 ** 63), 2 ** 63 - 1)


def valid_value(kind, key):
    if kind is bool:
        return st.booleans()
    if kind is int:
        return INT64
    if kind is scene_file.NUM:
        return st.one_of(finite, st.integers(-10 ** 6, 10 ** 6))
    if kind is str:
        return st.text(max_size=8)
    if kind == scene_file.VEC3:
        return st.lists(st.one_of(finite, st.integers(-100, 100)), min_size=3, max_size=3)
    if kind == scene_file.SIZE:
        return st.lists(st.integers(1, 32768), min_size=2, max_size=2)
    if kind == scene_file.PATH:
        return st.just("pts.xyz")
    if kind == scene_file.ENV:         # a map file or a uniform radiance
        return st.one_of(st.just("pts.xyz"),
                         st.lists(st.one_of(finite, st.integers(0, 100)), min_size=1, max_size=3))
    raise AssertionError(kind)


def wrong_value(kind):
    """A value of the wrong type for `kind` (TOML-expressible)."""
    anything = st.one_of(st.booleans(), INT64, st.floats(), st.text(max_size=5),
                         st.lists(st.integers(-3, 3), max_size=4),
                         st.dates(), st.dictionaries(st.sampled_from("ab"), st.integers(), max_size=2))
    if kind is bool:
        return anything.filter(lambda v: not isinstance(v, bool))
    if kind is int:          # an integral float is an integer there (spp = 2.0, issue 37)
        return anything.filter(lambda v: isinstance(v, bool) or not isinstance(v, (int, float))
                               or (isinstance(v, float) and not (math.isfinite(v)
                                                                 and v.is_integer())))
    if kind is scene_file.NUM:
        return anything.filter(lambda v: isinstance(v, bool) or not isinstance(v, (int, float))
                               or (isinstance(v, float) and not math.isfinite(v)))
    if kind is str:
        return anything.filter(lambda v: not isinstance(v, str))
    if kind == scene_file.VEC3:
        return st.one_of(anything.filter(lambda v: not isinstance(v, list)),
                         st.lists(st.floats(-5, 5), max_size=6).filter(lambda v: len(v) != 3),
                         st.lists(st.one_of(st.booleans(), st.text(max_size=2),
                                            st.sampled_from([math.nan, math.inf])),
                                  min_size=3, max_size=3))
    if kind == scene_file.SIZE:
        return st.one_of(anything.filter(lambda v: not isinstance(v, list)),
                         st.lists(st.integers(-5, 40000), min_size=2, max_size=2)
                         .filter(lambda v: not all(1 <= x <= 32768 for x in v)),
                         st.lists(st.booleans(), min_size=2, max_size=2),
                         st.lists(st.integers(1, 9), max_size=4).filter(lambda v: len(v) != 2))
    if kind == scene_file.PATH:
        return st.one_of(anything.filter(lambda v: not isinstance(v, str)), st.just(""),
                         st.just("missing.ply"), st.just("."), st.just("a\x00b"), st.just("x" * 300))
    if kind == scene_file.ENV:
        return st.one_of(st.booleans(), st.dates(), st.just(""), st.just("missing.exr"),
                         st.just("."), st.lists(st.text(max_size=2), min_size=1, max_size=3),
                         st.lists(st.floats(-5, 5), min_size=4, max_size=6))
    raise AssertionError(kind)


@st.composite
def valid_scene(draw):
    doc = {}
    pts = {}
    if draw(st.booleans()):
        pts["file"] = "pts.xyz"
    else:
        pts["generator"] = draw(st.text(max_size=8))
        pts["count"] = draw(st.integers(1, scene_file.MAX_COUNT))
    for key in ("seed", "radius"):
        if draw(st.booleans()):
            pts[key] = draw(valid_value(scene_file.SCHEMA["points"][key], key))
    doc["points"] = pts
    for name in ("material", "camera", "environment", "render"):
        keys = draw(st.lists(st.sampled_from(sorted(scene_file.SCHEMA[name])), unique=True))
        if keys or draw(st.booleans()):
            doc[name] = {k: draw(valid_value(scene_file.SCHEMA[name][k], k)) for k in keys}
    lights = []
    for _ in range(draw(st.integers(0, 3))):
        kind = draw(st.sampled_from(["sun", "point"]))
        need = "direction" if kind == "sun" else "position"
        allowed = {"sun": ["irradiance", "color"], "point": ["intensity", "color"]}[kind]
        light = {"type": kind, need: draw(valid_value(scene_file.VEC3, need))}
        for k in draw(st.lists(st.sampled_from(allowed), unique=True)):
            light[k] = draw(valid_value(scene_file.SCHEMA["lights"][k], k))
        lights.append(light)
    if lights:
        doc["lights"] = lights
    return doc


def keys_of(doc):
    """(section, index or None, key) of every key in a scene document."""
    out = []
    for name, table in doc.items():
        if name == "lights":
            out += [(name, i, k) for i, t in enumerate(table) for k in t]
        else:
            out += [(name, None, k) for k in table]
    return out


def where(name, i, key):
    return f"[[lights]] #{i + 1}.{key}" if name == "lights" else f"[{name}].{key}"


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("scenes")
    (d / "pts.xyz").write_text("0 0 0\n0.4 0 0\n0 0.4 0 \n")
    return d


def load_text(scene_dir, text):
    path = scene_dir / "s.toml"
    path.write_text(text, encoding="utf-8")
    return path, scene_file.read(path)


def expected(kind, v, base):
    if kind is scene_file.NUM:
        return float(v)
    if kind == scene_file.VEC3:
        return tuple(float(x) for x in v)
    if kind == scene_file.SIZE:
        return tuple(v)
    if kind == scene_file.PATH or (kind == scene_file.ENV and isinstance(v, str)):
        return (base / v).resolve()
    if kind == scene_file.ENV:
        return tuple(float(x) for x in v)
    return v


@FAST
@given(doc=valid_scene())
def test_valid_scenes_parse_to_their_values(scene_dir, doc):
    _, got = load_text(scene_dir, to_toml(doc))
    assert set(got) == set(doc)
    for name, i, key in keys_of(doc):
        kind = scene_file.SCHEMA[name][key]
        want = doc[name][i][key] if i is not None else doc[name][key]
        have = got[name][i][key] if i is not None else got[name][key]
        assert have == expected(kind, want, scene_dir), where(name, i, key)


@FAST
@given(doc=valid_scene(), data=st.data())
def test_one_wrong_value_is_named_by_its_key(scene_dir, doc, data):
    name, i, key = data.draw(st.sampled_from(keys_of(doc)))
    assume(not (name == "lights" and key == "type"))        # the type picks the schema
    bad = data.draw(wrong_value(scene_file.SCHEMA[name][key]))
    (doc[name][i] if i is not None else doc[name])[key] = bad
    with pytest.raises(UserError) as err:
        load_text(scene_dir, to_toml(doc))
    msg = str(err.value)
    assert "\n" not in msg and str(scene_dir / "s.toml") in msg
    assert where(name, i, key) in msg, msg


IDENT = st.text(string.ascii_lowercase + "_", min_size=1, max_size=8)


@FAST
@given(doc=valid_scene(), data=st.data())
def test_an_unknown_key_or_section_is_named(scene_dir, doc, data):
    sections = [n for n in doc if n != "lights"]
    name = data.draw(st.sampled_from(sections + ["lights"] if "lights" in doc else sections))
    key = data.draw(IDENT.filter(lambda k: k not in scene_file.SCHEMA[name]))
    table = doc[name][0] if name == "lights" else doc[name]
    table[key] = data.draw(valid_value(scene_file.NUM, key))
    with pytest.raises(UserError) as err:
        load_text(scene_dir, to_toml(doc))
    msg = str(err.value)
    assert "\n" not in msg
    assert where(name, 0, key) in msg and "known keys" in msg, msg
    section = data.draw(IDENT.filter(lambda k: k not in scene_file.SCHEMA))
    doc[section] = {}
    table.pop(key)
    with pytest.raises(UserError, match=rf"unknown section \[{section}\]"):
        load_text(scene_dir, to_toml(doc))


toml_leaf = st.one_of(st.booleans(), INT64, st.floats(), st.text(max_size=6),
                      st.dates(), st.times(), st.datetimes())
toml_any = st.recursive(toml_leaf, lambda inner: st.one_of(
    st.lists(inner, max_size=3), st.dictionaries(st.text(max_size=4), inner, max_size=3)),
    max_leaves=8)
SECTION_NAMES = st.sampled_from(sorted(scene_file.SCHEMA) + ["bogus", "Points", ""])
KEY_NAMES = st.sampled_from(sorted({k for t in scene_file.SCHEMA.values() for k in t} | {"x", ""}))


@FAST
@given(doc=st.dictionaries(SECTION_NAMES, st.one_of(
    st.dictionaries(KEY_NAMES, toml_any, max_size=5),
    st.lists(st.dictionaries(KEY_NAMES, toml_any, max_size=4), min_size=1, max_size=2),
    toml_leaf), max_size=5))
def test_arbitrary_documents_parse_or_raise_a_user_error(scene_dir, doc):
    try:
        load_text(scene_dir, to_toml(doc))
    except UserError as exc:
        assert "\n" not in str(exc)


@FAST
@given(raw=st.one_of(st.binary(max_size=200), st.text(max_size=200)))
def test_garbage_files_raise_a_user_error(scene_dir, raw):
    path = scene_dir / "g.toml"
    if isinstance(raw, bytes):
        path.write_bytes(raw)
    else:
        path.write_text(raw, encoding="utf-8")
    try:
        scene_file.read(path)
    except UserError as exc:
        assert "\n" not in str(exc) and str(path) in str(exc)


# ------------------------------------------------------------------ end to end

def in_range(lo, hi):
    return st.floats(lo, hi, allow_nan=False)


RENDERABLE = {      # values in ranges the renderer accepts, and cheap ones
    "count": st.integers(1, 40), "seed": st.integers(-5, 2 ** 40), "radius": in_range(0.0, 0.3),
    "ior": in_range(1 / 16, 16), "glow": in_range(0, 3), "reflectivity": in_range(0, 2),
    "fov": in_range(1, 170), "spp": st.integers(1, 2), "bounces": st.integers(1, 3),
    "blend": in_range(0, 0.5), "leaf_size": st.integers(1, 8), "epsilon": in_range(1e-6, 1e-2),
    "max_steps": st.integers(1, 64), "irradiance": in_range(0, 5), "intensity": in_range(0, 5),
}


@st.composite
def renderable_scene(draw):
    doc = draw(valid_scene())
    doc.get("render", {}).pop("size", None)
    doc.get("environment", {}).pop("map", None)
    pts = doc["points"]
    if "generator" in pts:
        pts["generator"] = draw(st.sampled_from(["blob", "uniform_box", "glass_gather", "nope"]))
    for name, i, key in keys_of(doc):
        table = doc[name][i] if i is not None else doc[name]
        if key in RENDERABLE:
            table[key] = draw(RENDERABLE[key])
        elif scene_file.SCHEMA[name][key] == scene_file.VEC3:
            table[key] = draw(st.lists(in_range(-3, 3), min_size=3, max_size=3))
    return doc


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(doc=renderable_scene())
def test_valid_scenes_render_or_fail_in_one_line(scene_dir, capsys, doc):
    """Through the whole CLI: exit 0 with a finite image, or 2 with one line on stderr."""
    path = scene_dir / "r.toml"
    path.write_text(to_toml(doc), encoding="utf-8")
    out = scene_dir / "r.npy"
    out.unlink(missing_ok=True)
    code = cli.main(["render", str(path), "-o", str(out), "--size", "8x6", "--no-progress"])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    if code == 0:
        assert np.isfinite(np.load(out)).all()
    else:
        errors = [l for l in err.splitlines() if l.startswith("volrender: error: ")]
        assert code == 2 and len(errors) == 1, err
        assert not out.exists()


# ------------------------------------------------------------------ the tree

def clouds():
    lattice = st.lists(st.tuples(*[st.integers(-2, 2).map(float)] * 3), min_size=1, max_size=120)
    wide = st.lists(st.tuples(*[st.floats(-1e6, 1e6, allow_nan=False)] * 3), min_size=1, max_size=80)

    @st.composite
    def collinear(draw):
        t = draw(st.lists(st.floats(-10, 10, allow_nan=False), min_size=1, max_size=100))
        d = draw(st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 3))
        o = draw(st.tuples(*[st.floats(-1e3, 1e3, allow_nan=False)] * 3))
        return [tuple(np.add(o, np.multiply(s, d))) for s in t]

    single = st.tuples(*[st.floats(-1e9, 1e9, allow_nan=False)] * 3).map(lambda p: [p])
    dup = st.tuples(st.tuples(*[st.floats(-5, 5, allow_nan=False)] * 3), st.integers(1, 200)) \
        .map(lambda pn: [pn[0]] * pn[1])
    return st.one_of(lattice, wide, collinear(), single, dup)


@settings(max_examples=60, deadline=None)
@given(pts=clouds(), leaf_size=st.integers(1, 12), margin=st.sampled_from([0.0, 1e-3, 2.0]),
       axis=st.sampled_from(["longest", "cycle"]), data=st.data())
def test_tree_invariants_and_one_leaf_per_point(pts, leaf_size, margin, axis, data):
    c = np.array(pts, np.float64)
    n = len(c)
    r = np.array(data.draw(st.lists(st.floats(0, 3), min_size=n, max_size=n)))
    t = tree_mod.build(c, r, leaf_size=leaf_size, margin=margin, axis=axis)
    tree_mod.check_invariants(t, c, r)
    leaves = np.arange(t.first_leaf, t.n_nodes)
    owner = np.full(n, -1)
    for k in leaves:
        idx = t.spheres(k)
        assert (owner[idx] == -1).all(), "a point is in two leaves"
        owner[idx] = k
    assert (owner >= 0).all(), "a point is in no leaf"
    lc = t.count[leaves]
    assert lc.max() <= leaf_size and lc.max() - lc.min() <= 1


@settings(max_examples=30, deadline=None)
@given(pts=clouds(), leaf_size=st.integers(1, 8), data=st.data())
def test_float32_boxes_contain_the_float32_spheres(pts, leaf_size, data):
    """The kernel prunes with float32 node boxes against float32 spheres (both relative
    to the scene centre). pack_scene rounds each float64 box outwards by one float32 ulp
    of the box; the float32 sphere can still poke out by the rounding of its own centre
    and radius (half an ulp each), which exceeds the box's ulp when the box edge is near
    0 but the centre is not (found by this test: sphere y 1.88351336 -> 1.88351333,
    r = 2, box lo_y -0.1164866), and the float64 box itself forgets radii below the
    float64 resolution of the world coordinates (a point at z = 1 with r = 1e-30). So:
    contained up to one float32 ulp of |centre| + r plus float64 rounding of the world
    coordinates; a node bound may then exceed d_i by that much, a rounding-level
    difference."""
    c = np.array(pts, np.float64)
    n = len(c)
    r = np.array(data.draw(st.lists(st.floats(0, 3), min_size=n, max_size=n)))
    sc = spheres.pack_scene(PointCloud(c, r), glass.GlassSettings(leaf_size=leaf_size, blend=0.0))
    s = sc.spheres.astype(np.float64)
    nodes = sc.nodes
    lo = np.stack([nodes[f"lo_{a}"] for a in "xyz"], 1).astype(np.float64)
    hi = np.stack([nodes[f"hi_{a}"] for a in "xyz"], 1).astype(np.float64)
    first = sc.first_leaf
    leaf_of = np.concatenate([np.full(int(nodes["count"][k]), k) for k in range(first, 2 * first)])
    assert len(leaf_of) == n
    tol = np.spacing((np.abs(s[:, :3]) + s[:, 3:]).astype(np.float32)).astype(np.float64)
    tol += 4 * np.finfo(np.float64).eps * (np.abs(s[:, :3] + sc.centre) + s[:, 3:])   # world, f64
    node = leaf_of
    while True:
        assert (lo[node] <= s[:, :3] - s[:, 3:] + tol).all()
        assert (hi[node] >= s[:, :3] + s[:, 3:] - tol).all()
        if (node == 1).all():
            break
        node = node // 2
