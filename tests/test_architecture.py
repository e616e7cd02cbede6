"""The structure of the code (issue 17): no import cycle in uqflow/ and solvers/, no private
name imported from another package, and a report layer that names no method and no solver.

Read from the source with ``ast`` (nothing is imported but the registries of (c)), so a cycle
hidden by an import inside a function, or behind a package's ``__init__``, is found as well.
"""

from __future__ import annotations

import ast
import re
from contextlib import contextmanager
from functools import lru_cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("uqflow", "solvers")


# ----------------------------------------------------------------------------- the modules

@lru_cache(maxsize=None)
def modules() -> dict[str, Path]:
    """Every module of the packages by dotted name (a package by its ``__init__.py``)."""
    found = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            found[".".join(parts)] = path
    return found


def is_package(name: str) -> bool:
    return modules()[name].name == "__init__.py"


@lru_cache(maxsize=None)
def tree_of(name: str) -> ast.Module:
    return ast.parse(modules()[name].read_text(encoding="utf-8"), str(modules()[name]))


def _type_checking_only(node: ast.AST) -> bool:
    test = getattr(node, "test", None)
    return isinstance(node, ast.If) and (
        isinstance(test, ast.Name) and test.id == "TYPE_CHECKING"
        or isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def import_nodes(name: str):
    """Every import statement of module ``name``, at any depth (inside functions too), but
    those under ``if TYPE_CHECKING:``, which never run."""
    def visit(node):
        for child in ast.iter_child_nodes(node):
            if _type_checking_only(child):
                for other in child.orelse:
                    yield from visit_one(other)
                continue
            yield from visit_one(child)

    def visit_one(node):
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        yield from visit(node)

    yield from visit(tree_of(name))


def _base_of(name: str, node: ast.ImportFrom) -> str:
    """The absolute module a ``from ... import`` names (relative imports resolved)."""
    if not node.level:
        return node.module or ""
    package = name if is_package(name) else name.rpartition(".")[0]
    for _ in range(node.level - 1):
        package = package.rpartition(".")[0]
    return f"{package}.{node.module}" if node.module else package


def _ancestors(name: str) -> list[str]:
    parts = name.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts))]


def imported_modules(name: str):
    """(module, line) for every module of the packages that module ``name`` imports.

    ``from a.b import c`` imports ``a.b.c`` when that is a module, else ``a.b``. Importing a
    module first runs the ``__init__`` of every package above it that is not yet imported;
    those above ``name`` itself are (Python imported them to reach ``name``), the others
    count: ``uqflow.methods.base`` importing ``uqflow.report.tables`` runs
    ``uqflow/report/__init__.py`` and whatever that imports.
    """
    known = modules()
    mine = {*_ancestors(name), name}
    for node in import_nodes(name):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        else:
            base = _base_of(name, node)
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base
                       for a in node.names]
        for target in targets:
            for module in (*_ancestors(target), target):
                if module in known and module not in mine:
                    yield module, node.lineno


def import_graph() -> dict[str, dict[str, int]]:
    """{module: {imported module: first line importing it}}."""
    graph = {}
    for name in modules():
        edges: dict[str, int] = {}
        for target, line in imported_modules(name):
            edges.setdefault(target, line)
        graph[name] = edges
    return graph


def strongly_connected(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """Tarjan's strongly connected components with more than one module (iterative)."""
    index, low, on_stack, stack, found = {}, {}, set(), [], []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            advanced = False
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                    advanced = True
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def describe_cycle(component: list[str], graph) -> str:
    """A shortest loop through the component's first module, each step with its line, and
    the modules of the component."""
    inside = set(component)
    start = component[0]
    came_from: dict[str, str] = {}
    frontier = [start]
    while frontier and start not in came_from:
        following = []
        for node in frontier:
            for child in sorted(graph[node]):
                if child in inside and child not in came_from:
                    came_from[child] = node
                    following.append(child)
        frontier = following
    loop = [start]
    while True:
        loop.append(came_from[loop[-1]])
        if loop[-1] == start:
            break
    loop.reverse()
    steps = " -> ".join([loop[0], *(f"{b} (line {graph[a][b]})" for a, b in
                                    zip(loop, loop[1:]))])
    return f"{steps}  [all {len(component)} modules of this knot: {', '.join(component)}]"


def test_the_import_graph_sees_function_level_imports_and_package_inits():
    """The graph itself: an import inside a function is an edge, and importing a module of
    another package runs that package's __init__."""
    graph = import_graph()
    # uqflow/__init__.py imports uqflow.study inside load_study only
    assert "uqflow.study" in graph["uqflow"]
    # a package's __init__ importing its submodules: uqflow.methods takes its contract's names
    assert "uqflow.methods.base" in graph["uqflow.methods"]
    # a module inside a package does not re-run its own package's __init__
    assert "uqflow.methods" not in graph["uqflow.methods.pce"]
    cycle = {"a": {"b": 1}, "b": {"c": 2}, "c": {"a": 3}, "d": {"a": 4}}
    assert strongly_connected(cycle) == [["a", "b", "c"]]
    assert strongly_connected({"a": {"b": 1}, "b": {}}) == []


def test_no_import_cycle_in_uqflow_and_solvers():
    graph = import_graph()
    cycles = [describe_cycle(c, graph) for c in strongly_connected(graph)]
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


# ----------------------------------------------------------------------------- private names

def _private(part: str) -> bool:
    return part.startswith("_") and not (part.startswith("__") and part.endswith("__"))


def _package_of(name: str) -> str:
    return name if is_package(name) else name.rpartition(".")[0]


def _inside(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def private_imports(name: str) -> list[str]:
    """Private names module ``name`` takes from another package (ours or a library's):
    ``from X import _y``, ``import X._m``, and ``m._y`` where ``m`` is a module imported from
    another package (``import X as m``, or ``from X import m`` where ``X.m`` is ours)."""
    package = _package_of(name)
    found = []
    foreign_aliases: dict[str, str] = {}  # local name -> the other package's module
    for node in import_nodes(name):
        if isinstance(node, ast.ImportFrom):
            base = _base_of(name, node)
            if _inside(base, package):
                continue
            for alias in node.names:
                dotted = f"{base}.{alias.name}"
                if any(map(_private, dotted.split("."))):
                    found.append(f"{name}: from {base} import {alias.name} "
                                 f"(line {node.lineno})")
                if dotted in modules():
                    foreign_aliases[alias.asname or alias.name] = dotted
        else:
            for alias in node.names:
                if _inside(alias.name, package):
                    continue
                if any(map(_private, alias.name.split("."))):
                    found.append(f"{name}: import {alias.name} (line {node.lineno})")
                foreign_aliases[alias.asname or alias.name.partition(".")[0]] = \
                    alias.name if alias.asname else alias.name.partition(".")[0]
    for node in ast.walk(tree_of(name)):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and \
                node.value.id in foreign_aliases and _private(node.attr):
            found.append(f"{name}: {foreign_aliases[node.value.id]}.{node.attr} "
                         f"(line {node.lineno})")
    return found


def test_the_private_name_check_finds_each_form(tmp_path, monkeypatch):
    sources = {
        "uqflow/__init__.py": "",
        "uqflow/report/__init__.py": "",
        "uqflow/report/tables.py": "def _grid(): pass\n",
        "solvers/__init__.py": "",
        "solvers/x/__init__.py": "",
        "solvers/x/a.py": ("from uqflow.report.tables import _grid\n"
                           "import uqflow.report.tables as t\n"
                           "def f():\n    return t._grid\n"
                           "import numpy as np\nfrom scipy.stats import _qmc\n"
                           "v = np._NoValue, np.__version__\n"),
        "solvers/x/b.py": "from solvers.x.a import _helper\nfrom ._c import d\n",
        "solvers/x/_c.py": "d = 1\n",
    }
    for path, text in sources.items():
        (tmp_path / path).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / path).write_text(text)
    with _tree_at(tmp_path, monkeypatch):
        assert private_imports("solvers.x.a") == [
            "solvers.x.a: from uqflow.report.tables import _grid (line 1)",
            "solvers.x.a: from scipy.stats import _qmc (line 6)",
            "solvers.x.a: uqflow.report.tables._grid (line 4)",
            "solvers.x.a: numpy._NoValue (line 7)"]
        assert private_imports("solvers.x.b") == []  # its own package's private names


@contextmanager
def _tree_at(root: Path, monkeypatch):
    """The checks read the source tree at ``root`` inside the ``with`` block."""
    modules.cache_clear()
    tree_of.cache_clear()
    monkeypatch.setitem(globals(), "ROOT", root)
    try:
        yield
    finally:
        monkeypatch.undo()
        modules.cache_clear()
        tree_of.cache_clear()


def test_no_private_name_is_imported_from_another_package():
    found = [line for name in modules() for line in private_imports(name)]
    assert not found, "private names imported across packages:\n" + "\n".join(found)


# ----------------------------------------------------------------------------- the report layer

def registered_names() -> set[str]:
    """Every registered method and solver: its registry name and its class name."""
    import uqflow.methods  # noqa: F401 (registers the built-in methods)
    from uqflow.methods.base import method_registry
    from uqflow.solver import solver_registry

    names = set()
    for registry in (method_registry, solver_registry):
        for name in registry.names():
            names.add(name)
            names.add(registry.get(name).__name__)
    return names


def _docstrings(tree: ast.Module) -> set[int]:
    """ids of the docstring nodes of a module, its classes and functions."""
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and \
                    isinstance(body[0].value, ast.Constant) and \
                    isinstance(body[0].value.value, str):
                found.add(id(body[0].value))
    return found


def _identifiers(tree: ast.Module):
    for node in ast.walk(tree):
        if isinstance(node, ast.Name):
            yield node.id, node.lineno
        elif isinstance(node, ast.Attribute):
            yield node.attr, node.lineno
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            yield node.name, node.lineno
        elif isinstance(node, ast.arg):
            yield node.arg, node.lineno
        elif isinstance(node, ast.alias):
            yield (node.asname or node.name).rpartition(".")[2], getattr(node, "lineno", 0)
        elif isinstance(node, ast.keyword) and node.arg:
            yield node.arg, node.lineno


def names_in_source(path: Path, names: set[str]) -> list[str]:
    """Where the source at ``path`` names one of ``names``: in a string (not a docstring) as
    a word, or in an identifier (``monte-carlo`` as ``monte_carlo``, whole or between
    underscores; a class name whole)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    docstrings = _docstrings(tree)
    found = []
    words = {n: re.compile(rf"(?<![\w-]){re.escape(n)}(?![\w-])") for n in names}
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and \
                id(node) not in docstrings:
            for name, word in words.items():
                if word.search(node.value):
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno}: '{name}' in "
                                 f"{node.value[:60]!r}")
    snake = {n.replace("-", "_").lower(): n for n in names if n.islower() or "-" in n}
    classes = {n for n in names if not n.islower()}
    for identifier, line in _identifiers(tree):
        lowered = identifier.lower().strip("_")
        hit = identifier in classes or any(
            re.search(rf"(?:^|_){re.escape(s)}(?:_|$)", lowered) for s in snake)
        if hit:
            found.append(f"{path.relative_to(ROOT)}:{line}: identifier {identifier}")
    return sorted(set(found))


def test_the_name_check_finds_names_in_strings_and_identifiers(tmp_path, monkeypatch):
    source = tmp_path / "example.py"
    source.write_text('"""Docstrings may say monte-carlo."""\n'
                      'def _monte_carlo_column(kind):\n'
                      '    return kind == "monte-carlo" or MonteCarlo\n'
                      'label = f"{1} runs of mpm"\n'
                      'fine = "mpmx montecarlo"\n', encoding="utf-8")
    with _tree_at(tmp_path, monkeypatch):
        found = names_in_source(source, {"monte-carlo", "mpm", "MonteCarlo"})
    assert found == ["example.py:2: identifier _monte_carlo_column",
                     "example.py:3: 'monte-carlo' in 'monte-carlo'",
                     "example.py:3: identifier MonteCarlo",
                     "example.py:4: 'mpm' in ' runs of mpm'"]


def test_the_report_layer_names_no_method_and_no_solver():
    names = registered_names()
    assert {"monte-carlo", "mpm"} <= names  # the registries were read
    found = [hit for path in sorted((ROOT / "uqflow" / "report").rglob("*.py"))
             for hit in names_in_source(path, names)]
    assert not found, "uqflow/report names methods or solvers:\n" + "\n".join(found)


# ----------------------------------------------------------------------------- the result layout

def layout_names() -> set[str]:
    """The names of uqflow.layout that no other framework module should spell: every string
    constant but the CF attributes every solver writes too (units, long_name) and the short
    words that are also plain English (mean, sample, control, ...)."""
    from uqflow import layout

    words = {layout.UNITS, layout.LONG_NAME, layout.TITLE, layout.CONVENTIONS}
    names = {value for name, value in vars(layout).items()
             if name.isupper() and isinstance(value, str) and value not in words}
    return {n for n in names if "_" in n.strip("_") or n.startswith("__") or
            n in (layout.STATUS, layout.MESSAGE, layout.REALIZATION, layout.PARAMETER,
                  layout.STATISTIC, layout.WITH_SENSITIVITIES)}


def layout_spellings(path: Path, names: set[str]) -> list[str]:
    """String literals of ``path`` (not docstrings, not ``__all__``) equal to one of
    ``names``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    skipped = _docstrings(tree) | {  # the names a module exports are Python names
        id(c) for node in ast.walk(tree) if isinstance(node, ast.Assign) and
        any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets)
        for c in ast.walk(node.value)}
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and \
                id(node) not in skipped and node.value in names:
            found.add((node.lineno, f"{path.relative_to(ROOT)}:{node.lineno}: {node.value!r}"))
    return [text for _, text in sorted(found)]


def test_the_layout_check_finds_a_spelled_name(tmp_path, monkeypatch):
    source = tmp_path / "example.py"
    source.write_text('"""The status of a run."""\n__all__ = ["status"]\n'
                      'ok = runs["status"] == "ok"\nfine = runs[STATUS]\n', encoding="utf-8")
    with _tree_at(tmp_path, monkeypatch):
        assert layout_spellings(source, layout_names()) == ["example.py:3: 'status'"]


def test_only_the_layout_module_spells_the_result_layout():
    names = layout_names()
    assert {"status", "with_sensitivities", "__gradient", "solver_runs", "study_sha256"} <= names
    found = [hit for path in sorted((ROOT / "uqflow").rglob("*.py"))
             if path.name != "layout.py" for hit in layout_spellings(path, names)]
    assert not found, "result-layout names spelled outside uqflow/layout.py:\n" + \
        "\n".join(found)
