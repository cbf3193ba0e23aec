"""The package's modules import each other without a circle: every import counts, those
inside functions too (a lazy import hides a circle from Python, not from a reader). No
module takes another one's private name (`_x`): a name another module uses is part of its
interface and is spelt so.

Imports go at the top of a file, so that its head lists what it uses. An import inside a
function is for a reason: an optional extra or a heavy module (pyopencl, PIL, OpenEXR,
pyvista, pyoidn, openvdb, laspy, dask, scipy, matplotlib...), a module of the package that
`volrender --help` does not load (image, vdb, inspect, denoise... : kept off the start-up
path, `python -X importtime -m volrender --help`), or a standard-library module that costs
start-up time (subprocess, multiprocessing, tomllib, html). The test of inner imports fails
on the two that never have a reason: a module the file already imports at its top, and a
module of CHEAP_STDLIB (loaded by `import volrender` anyway); INNER_ALLOWED says why else."""
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


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def private_imports(pkg=PKG) -> list:
    """'module: name' for each private name a module of the package takes from another
    one: `from .x import _y` (or volrender.x), or `x._y` on a module it imported."""
    mods = {p.stem for p in pkg.glob("*.py")}
    out = []
    for p in sorted(pkg.glob("*.py")):
        tree = ast.parse(p.read_text(), str(p))
        aliases = set()                     # local names bound to modules of the package
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                module = node.module or ""
                whole = (node.level == 1 and not module) or module == "volrender"
                inner = node.level == 1 or module.startswith("volrender.")
                for a in node.names:
                    if whole and a.name in mods:
                        aliases.add(a.asname or a.name)
                    elif (whole or inner) and _private(a.name):
                        out.append(f"{p.stem}: {a.name}")
            elif isinstance(node, ast.Import):
                aliases |= {a.asname for a in node.names
                            if a.asname and a.name.startswith("volrender.")}
        out += [f"{p.stem}: {node.value.id}.{node.attr}" for node in ast.walk(tree)
                if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                and node.value.id in aliases and _private(node.attr)]
    return out


# 'module: name' -> why it cannot be public (none now)
PRIVATE_ALLOWED: dict = {}


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


def test_no_module_takes_another_ones_private_name():
    assert [f for f in private_imports() if f not in PRIVATE_ALLOWED] == []


def test_the_private_import_finder_finds_both_forms(tmp_path):
    """`from .a import _x`, `from volrender.a import _x` and `a._x` are found; `__all__`,
    a module's own private names and public names are not."""
    (tmp_path / "a.py").write_text("_x = 1\ny = 2\n__all__ = ['y']\nprint(_x)\n")
    (tmp_path / "b.py").write_text("from .a import _x, y\n")
    (tmp_path / "c.py").write_text("def f():\n    from volrender.a import _x\n")
    (tmp_path / "d.py").write_text("from . import a as m\nprint(m._x, m.y, m.__all__)\n")
    (tmp_path / "e.py").write_text("from . import a\nprint(a.y)\n")
    assert private_imports(tmp_path) == ["b: _x", "c: _x", "d: m._x"]


# standard-library modules that `import volrender` loads anyway: importing them at the top costs
# nothing (measured: python -X importtime -m volrender --help)
CHEAP_STDLIB = frozenset("""argparse atexit base64 codecs collections contextlib copy dataclasses
datetime enum errno fcntl fnmatch functools glob hashlib importlib io itertools json logging math
numbers operator os pathlib pickle random re resource shutil signal stat string struct sys
tempfile textwrap threading time traceback typing warnings weakref""".split())

# 'module: imported module' -> why it stays inside a function
INNER_ALLOWED = {
    "__init__: os": "the start-up signal handler: nothing is imported before the handler is "
                    "set, and os only when a signal comes",
}


def _top_modules(tree) -> set:
    """The modules a file imports at its top ('.x' for the package's)."""
    out = set()
    for node in tree.body:
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = "." * node.level + (node.module or "")
            out.add(base)
            if node.level and not node.module:
                out |= {"." + a.name for a in node.names}
    return out


def inner_imports(pkg=PKG) -> list:
    """'module:line imported' for each import inside a function of a module that the file
    already imports at its top, or that is in CHEAP_STDLIB."""
    out = []
    for p in sorted(pkg.glob("*.py")):
        tree = ast.parse(p.read_text(), str(p))
        top = _top_modules(tree)
        for fn in ast.walk(tree):
            if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for node in ast.walk(fn):
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level and not node.module:
                    names = ["." + a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom):
                    names = ["." * node.level + node.module]
                else:
                    continue
                for m in names:
                    if (m in top or (not m.startswith(".") and m in CHEAP_STDLIB)) and \
                            f"{p.stem}: {m}" not in INNER_ALLOWED:
                        out.append(f"{p.stem}:{node.lineno} {m}")
    return sorted(set(out))


def test_imports_inside_functions_have_a_reason():
    assert inner_imports() == [], "import it at the top of the file (see this module's docstring)"


def test_the_inner_import_finder(tmp_path):
    """An inner import of a module the top imports (either form), or of a cheap standard
    module, is found; optional, heavy, lazy-package and costly standard modules are not."""
    (tmp_path / "a.py").write_text(
        "import os\nfrom . import b\nfrom .c import x\n"
        "def f():\n    import os.path\n    from .b import y\n    from .c import z\n"
        "    import json\n    from . import d\n    import subprocess\n    import pyopencl\n"
        "    if x:\n        from . import c\n")
    assert inner_imports(tmp_path) == ["a:13 .c", "a:6 .b", "a:7 .c", "a:8 json"]


LONG = 500          # lines; a module above it says why at its top ("Long file: ...")


def long_files(pkg=PKG) -> list:
    """'module (lines)' for each module of the package above LONG lines whose docstring
    gives no reason."""
    out = []
    for p in sorted(pkg.glob("*.py")):
        text = p.read_text()
        n = text.count("\n")
        doc = ast.get_docstring(ast.parse(text, str(p))) or ""
        if n > LONG and "Long file:" not in doc:
            out.append(f"{p.stem} ({n})")
    return out


def test_long_modules_say_why(tmp_path):
    assert long_files() == [], "split the module, or write 'Long file: why' in its docstring"
    (tmp_path / "a.py").write_text('"""A."""\n' + "x = 1\n" * (LONG + 1))
    (tmp_path / "b.py").write_text('"""B.\n\nLong file: one idea."""\n' + "x = 1\n" * LONG)
    assert long_files(tmp_path) == [f"a ({LONG + 2})"]


def test_no_test_module_imports_another():
    """Shared test code lives in tests/helpers.py, tests/reference.py and conftest.py
    fixtures; a test module that imports another runs that module's fixtures and globals."""
    tests = Path(__file__).resolve().parent
    names = {p.stem for p in tests.glob("test_*.py")}
    found = []
    for p in sorted(tests.glob("test_*.py")):
        for node in ast.walk(ast.parse(p.read_text(), str(p))):
            mods = [node.module] if isinstance(node, ast.ImportFrom) and node.level == 0 else \
                [a.name for a in node.names] if isinstance(node, ast.Import) else []
            found += [f"{p.stem}: {m}" for m in mods if m in names]
    assert found == []
