"""docs/options.md and docs/scene_format.md are what volrender.manual generates from the
knobs and the scene schema (regenerate: python -m volrender.manual)."""
from conftest import ROOT

from volrender import manual, scene_file


def test_generated_references_are_current():
    docs = ROOT / "docs"
    assert (docs / "options.md").read_text() == manual.options_markdown(), \
        "docs/options.md is stale: run python -m volrender.manual"
    assert (docs / "scene_format.md").read_text() == manual.scene_markdown(), \
        "docs/scene_format.md is stale: run python -m volrender.manual"


def test_every_option_and_scene_key_is_documented():
    text = manual.options_markdown()
    for opt in scene_file.options().values():
        assert f"`{opt.key}`" in text, opt.key
    keys = manual.scene_markdown()
    for section, table in scene_file.SCHEMA.items():
        for key in table:
            assert f"| `{key}` |" in keys, (section, key)
