"""README.md's Figures block is what bench.figures writes from bench/results/*.json
(regenerate: python -m bench.figures)."""
import json
import re
import shutil

import pytest
from conftest import ROOT

from bench import figures


def test_readme_figures_are_current():
    readme = (ROOT / "README.md").read_text()
    assert readme.count(figures.BEGIN) == 1 and readme.count(figures.END) == 1
    assert figures.current(readme) == figures.block(), \
        "README.md's figures are stale: run python -m bench.figures"


def test_every_figure_is_printed_and_every_placeholder_has_a_source():
    used = set(re.findall(r"{(\w+)}", figures.TEMPLATE))
    assert used == set(figures.FIGURES) | set(figures.NAMES)


def test_no_measured_number_is_typed_into_the_template():
    """Every digit of the block is a {figure} read from a result or a LITERALS phrase (a
    name, a size that picks the row, a target): a number typed in drifts from its file."""
    assert figures.hand_written_numbers() == []
    typed = figures.TEMPLATE.replace("×{edge_worst} at worst", "×1.56 at worst")
    assert len(figures.hand_written_numbers(typed)) == 1

def test_a_changed_result_changes_the_readme(tmp_path, monkeypatch):
    """The block reads the files: a new 10⁶ build total shows in both lines that cite it."""
    shutil.copytree(figures.RESULTS, tmp_path, dirs_exist_ok=True,
                    ignore=shutil.ignore_patterns("*.png"))
    path = tmp_path / figures.BUILD
    data = json.loads(path.read_text())
    next(r for r in data["rows"] if r["n"] == 1000000)["total_ms"] = 1234.4
    path.write_text(json.dumps(data))
    monkeypatch.setattr(figures, "RESULTS", tmp_path)
    text = figures.block()
    assert "10⁶ spheres 1.23 s" in text and "(1234 ms, above)" in text
    assert "×4.1 over" in text


def test_get_picks_one_entry():
    data = {"rows": [{"n": 1, "v": 10, "k": "a"}, {"n": 2, "v": 20, "k": "a"},
                     {"n": 2, "v": 30, "k": "b"}]}
    assert figures.get(data, "rows[n=1].v") == 10
    assert figures.get(data, "rows[n=2][k=b].v") == 30
    assert figures.get(data, "rows[1].v") == 20
    with pytest.raises(KeyError):
        figures.get(data, "rows[n=2].v")


def test_formats():
    assert [figures.ms(x) for x in (9.93, 34.226, 112.99, 1597.66)] == \
        ["9.9", "34.2", "113", "1 598"]
