"""Scene files: validation with messages that name the key, and property-based fuzzing."""
import pytest
from hypothesis import given, settings, strategies as st

from volrender import scene_file
from volrender.errors import UserError

GOOD = """
[points]
generator = "blob"
count = 200

[material]
ior = 1.45
absorption = [0.1, 0.5, 2.0]

[[lights]]
type = "sun"
direction = [-0.5, -1, -0.3]
irradiance = 3

[[lights]]
type = "point"
position = [0, 2, 0]
intensity = 10

[render]
size = [64, 48]
bounces = 3
"""


def write(tmp_path, text, name="s.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_good_scene_parses(tmp_path):
    s = scene_file.read(write(tmp_path, GOOD))
    assert s["points"] == {"generator": "blob", "count": 200}
    assert s["material"]["absorption"] == (0.1, 0.5, 2.0)
    assert [l["type"] for l in s["lights"]] == ["sun", "point"]
    assert s["render"]["size"] == (64, 48)


def test_paths_resolve_relative_to_the_scene(tmp_path):
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "pts.xyz").write_text("0 0 0\n")
    s = scene_file.read(write(tmp_path, '[points]\nfile = "pts.xyz"\n', "sub/s.toml"))
    assert s["points"]["file"] == (tmp_path / "sub" / "pts.xyz").resolve()


@pytest.mark.parametrize("text, words", [
    ('[points]\ngenerator = "blob"\ncount = 5\n[material]\niro = 1.5\n', ["[material].iro", "ior"]),
    ('[points]\ngenerator = "blob"\ncount = 5\n[materials]\n', ["[materials]", "material"]),
    ('[points]\ngenerator = "blob"\ncount = "many"\n', ["[points].count", "integer"]),
    ('[points]\ngenerator = "blob"\ncount = 5\n[material]\nabsorption = [1, 2]\n', ["absorption", "3"]),
    ('[points]\ngenerator = "blob"\ncount = 5\n[render]\nsize = [0, 10]\n', ["size"]),
    ('[points]\nfile = "missing.ply"\n', ["missing.ply", "does not exist"]),
    ('[material]\nior = 1.5\n', ["[points]"]),
    ('[points]\ngenerator = "blob"\n', ["count"]),
    ('[points]\ngenerator = "blob"\ncount = 5\n[[lights]]\ntype = "spot"\n', ["spot"]),
    ('[points]\ngenerator = "blob"\ncount = 5\n[[lights]]\ntype = "sun"\n', ["direction"]),
    ('[points]\ngenerator = "blob"\ncount = 5\n[[lights]]\ntype = "sun"\ndirection = [0,-1,0]\n'
     'position = [1, 2, 3]\n', ["position"]),
    ('[points\n', ["TOML"]),
])
def test_bad_scenes_name_the_problem(tmp_path, text, words):
    p = write(tmp_path, text)
    with pytest.raises(UserError) as err:
        scene_file.read(p)
    msg = str(err.value)
    assert "\n" not in msg and str(p) in msg
    for w in words:
        assert w in msg, (w, msg)


toml_scalar = st.one_of(st.integers(-10, 10), st.floats(allow_nan=True, allow_infinity=True),
                        st.booleans(), st.text(max_size=5),
                        st.lists(st.floats(-5, 5), max_size=4))


@settings(max_examples=200, deadline=None)
@given(st.dictionaries(st.sampled_from(sorted(scene_file.SCHEMA) + ["bogus"]),
                       st.dictionaries(st.sampled_from(["file", "generator", "count", "ior", "size",
                                                        "type", "direction", "radius", "x"]),
                                       toml_scalar, max_size=4), max_size=4))
def test_parser_never_fails_other_than_with_a_user_error(tmp_path_factory, raw):
    """Whatever the (already TOML-decoded) content, the parser accepts it or raises
    UserError: never a TypeError or KeyError."""
    if "lights" in raw:
        raw["lights"] = [raw["lights"]]
    try:
        scene_file.parse(raw, tmp_path_factory.getbasetemp())
    except UserError as exc:
        assert "\n" not in str(exc)


def test_timings_measure_the_spacing_only_of_clouds_without_radii():
    """Scene.timings (a frozen Timings record): the load always; the radii only where the spacing
    of a cloud without radii was measured."""
    import numpy as np
    import volrender
    rng = np.random.default_rng(1)
    bare = volrender.load_scene(rng.random((200, 3)), size=(8, 6))
    sized = volrender.load_scene(np.c_[rng.random((200, 3)), np.full(200, 0.05)], size=(8, 6))
    assert bare.timings.radii is not None and bare.timings.radii > 0
    assert sized.timings.radii is None
    assert bare.timings.load >= 0 and sized.timings.load > 0
    assert volrender.Scene.of(sized.camera, (), sized.content).timings.load == 0.0
    with pytest.raises(AttributeError):             # a frozen record
        bare.timings.load = 0.0
