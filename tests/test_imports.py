"""The package's modules import each other without a circle: every import counts, those
inside functions too (a lazy import hides a circle from Python, not from a reader)."""
import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "volrender"


def import_graph(pkg=PKG) -> dict:
    """{module: {modules of the package it imports}} from the source (ast)."""
    mods = {p.stem for p in pkg.glob("*.py")}
    graph = {}
    for p in pkg.glob("*.py"):
        deps = set()
        for node in ast.walk(ast.parse(p.read_text(), str(p))):
            if isinstance(node, ast.ImportFrom):
                if node.level == 1 and node.module is None:          # from . import x, y
                    deps |= {a.name for a in node.names if a.name in mods}
                elif node.level == 1 or (node.module or "").startswith("volrender."):
                    name = (node.module or "").removeprefix("volrender.").split(".")[0]
                    deps.add(name)
                elif node.module == "volrender":
                    deps |= {a.name for a in node.names if a.name in mods}
            elif isinstance(node, ast.Import):
                deps |= {a.name.split(".")[1] for a in node.names
                         if a.name.startswith("volrender.")}
        graph[p.stem] = (deps & mods) - {p.stem}
    return graph


def cycles(graph) -> list:
    """The strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_package_has_no_import_cycle():
    graph = import_graph()
    assert len(graph) > 20 and graph["render"] >= {"glass", "volume", "dispatch"}
    assert cycles(graph) == []


def test_the_cycle_finder_finds_a_hidden_cycle(tmp_path):
    """A circle made only by an import inside a function is found."""
    (tmp_path / "a.py").write_text("from . import b\n")
    (tmp_path / "b.py").write_text("def f():\n    from .c import g\n")
    (tmp_path / "c.py").write_text("def g():\n    from .a import x\n")
    (tmp_path / "d.py").write_text("from .a import x\n")
    assert cycles(import_graph(tmp_path)) == [["a", "b", "c"]]
