"""The layer order: every import inside the package runs downward (or within a layer).

And no two modules import each other, directly or round a longer loop: the module graph
of every geofix import (lazy ones and ``importlib.import_module("geofix...")`` included)
has no cycle.
"""

import ast
import sys
from pathlib import Path

import pytest

import geofix

PACKAGE = Path(geofix.__file__).parent

#: Bottom up. A module may import its own layer's package and any layer below it; modules
#: on one line are siblings that do not import each other.
LAYERS = (
    (
        "errors",
        "conventions",
        "_strict",
        "_version",
        "_lifetime",
        "_measurement_kernels",
        "_threads",
    ),
    ("memory", "_atomic"),
    ("maps",),
    ("nav", "sensors"),
    ("problem", "_likelihood_kernels"),
    ("measurement",),
    ("sim",),
    ("match", "filters", "logs"),
    ("methods",),
    ("navigator",),
    ("evaluate",),
    ("plot", "console"),
    ("report",),
    ("server_limits",),
    ("replay", "server", "client"),
    ("cli",),
    ("__main__",),
)
RANK = {name: rank for rank, names in enumerate(LAYERS) for name in names}


def _unit(module: str) -> str:
    """The layer unit of a dotted module name inside geofix (``geofix.maps.io`` -> maps)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def _imports(path: Path) -> list[tuple[int, str]]:
    """``(line, module)`` of every geofix import in a file, lazy ones included.

    ``importlib.import_module("geofix.x")`` with a literal name counts as an import of
    ``geofix.x``.
    """
    return [(line, module) for line, module, *_ in _import_nodes(path)]


def _import_nodes(path: Path) -> list[tuple[int, str, bool, list[str]]]:
    """``(line, module, typing_only, submodules)`` of every geofix import in a file.

    ``typing_only``: the import sits under ``if TYPE_CHECKING:`` (annotations only; it
    never runs). ``submodules``: the names ``from module import name`` may mean
    (``module.name``).
    """
    tree = ast.parse(path.read_text())
    typing_nodes = {
        id(child)
        for node in ast.walk(tree)
        if isinstance(node, ast.If) and _is_type_checking(node.test)
        for stmt in node.body
        for child in ast.walk(stmt)
    }
    found = []
    for node in ast.walk(tree):
        names: list[str] = []
        submodules: list[str] = []
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
            submodules = [f"{node.module}.{a.name}" for a in node.names]
            if node.module == "geofix":  # a submodule by name, or a public name
                names = [f"geofix.{a.name}" for a in node.names if a.name in RANK]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif _is_import_module(node):
            names = [node.args[0].value]
        typing_only = id(node) in typing_nodes
        found += [(node.lineno, n, typing_only, submodules) for n in names if _in_geofix(n)]
    return found


def _in_geofix(name: str) -> bool:
    return name == "geofix" or name.startswith("geofix.")


def _is_type_checking(test: ast.expr) -> bool:
    """``TYPE_CHECKING`` or ``typing.TYPE_CHECKING``."""
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _is_import_module(node: ast.AST) -> bool:
    """A call ``importlib.import_module("...")`` (or ``import_module("...")``) of a literal."""
    if not (isinstance(node, ast.Call) and node.args):
        return False
    func = node.func
    name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
    first = node.args[0]
    return (
        name == "import_module" and isinstance(first, ast.Constant) and isinstance(first.value, str)
    )


def _sources():
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE)
        if rel == Path("__init__.py"):
            continue  # the public namespace gathers every layer
        yield rel.parts[0].removesuffix(".py"), path


def upward_imports() -> list[str]:
    """Every import that runs upward or sideways, as ``file:line unit -> unit``."""
    bad = []
    for unit, path in _sources():
        for line, module in _imports(path):
            target = _unit(module)
            if target == unit or target == "":
                continue
            if RANK[target] >= RANK[unit]:
                rel = path.relative_to(PACKAGE)
                bad.append(f"{rel}:{line} {unit} -> {target}")
    return bad


def _module_name(path: Path) -> str:
    """The dotted name of a source file (``maps/io.py`` -> ``geofix.maps.io``)."""
    parts = path.relative_to(PACKAGE).with_suffix("").parts
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(("geofix", *parts))


def import_graph() -> dict[str, set[str]]:
    """Module -> the geofix modules it imports (lazy ones too; not ``TYPE_CHECKING`` ones).

    ``from geofix.a import b`` is an import of ``geofix.a.b`` when that is a module, else of
    ``geofix.a``. The root ``geofix/__init__.py`` (the public namespace) is left out.
    """
    paths = {_module_name(path): path for _, path in _sources()}
    for path in PACKAGE.rglob("__init__.py"):
        if path != PACKAGE / "__init__.py":
            paths[_module_name(path)] = path
    graph: dict[str, set[str]] = {}
    for name, path in paths.items():
        targets = set()
        for _, module, typing_only, submodules in _import_nodes(path):
            if not typing_only:
                named = [m for m in submodules if m in paths]
                targets.update(named or [_resolve(module, paths)])
        graph[name] = targets - {name, "geofix"}
    return graph


def _resolve(module: str, known) -> str:
    """The module an import names: itself, or the nearest enclosing known module."""
    while module not in known and "." in module:
        module = module.rsplit(".", 1)[0]
    return module


def import_cycles() -> list[str]:
    """Every cycle of the import graph, as ``a -> b -> a`` (one per strongly linked set)."""
    graph = import_graph()
    cycles = []
    for group in _strongly_connected(graph):
        if len(group) > 1:
            cycles.append(" -> ".join([*_loop_through(sorted(group)[0], group, graph)]))
    return sorted(cycles)


def _strongly_connected(graph: dict[str, set[str]]) -> list[set[str]]:
    """Tarjan's strongly connected components of ``graph`` (iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph.get(root, ()))))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is None:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    group = set()
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        group.add(member)
                        if member == node:
                            break
                    groups.append(group)
            elif child not in index:
                index[child] = low[child] = len(index)
                stack.append(child)
                on_stack.add(child)
                work.append((child, iter(sorted(graph.get(child, ())))))
            elif child in on_stack:
                low[node] = min(low[node], index[child])
    return groups


def _loop_through(start: str, group: set[str], graph: dict[str, set[str]]) -> list[str]:
    """A shortest loop ``start -> ... -> start`` inside ``group`` (breadth first)."""
    previous: dict[str, str] = {}
    frontier = [start]
    while frontier:
        following = []
        for node in frontier:
            for child in sorted(graph[node] & group):
                if child == start:
                    path = [node]
                    while path[-1] != start:
                        path.append(previous[path[-1]])
                    return [*reversed(path), start]
                if child not in previous:
                    previous[child] = node
                    following.append(child)
        frontier = following
    return [start, start]


def test_every_unit_has_a_layer():
    units = {unit for unit, _ in _sources()}
    assert units <= set(RANK), f"units without a layer: {sorted(units - set(RANK))}"


def test_imports_run_downward():
    assert upward_imports() == []


def test_the_check_catches_an_upward_import(tmp_path, monkeypatch):
    fake = tmp_path / "maps"
    fake.mkdir()
    (fake / "bad.py").write_text("from geofix.evaluate.metrics import summarize\n")
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", tmp_path)
    assert upward_imports() == ["maps/bad.py:1 maps -> evaluate"]


@pytest.mark.parametrize("name", ["geofix.sim.scenario", "geofix.maps.grid"])
def test_lazy_imports_are_seen(name):
    assert any(m == name for p in PACKAGE.rglob("*.py") for _, m in _imports(p))


def test_no_import_cycles():
    assert import_cycles() == []


def test_the_check_catches_a_cycle(tmp_path, monkeypatch):
    fake = tmp_path / "maps"
    fake.mkdir()
    (fake / "a.py").write_text("from geofix.maps.b import f\n")
    (fake / "b.py").write_text("def f():\n    from geofix.maps import c\n")
    (fake / "c.py").write_text('import importlib\nimportlib.import_module("geofix.maps.a")\n')
    (fake / "d.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from geofix.maps.a import g\n"
    )
    (fake / "e.py").write_text("from geofix.maps.d import h\n")
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", tmp_path)
    assert import_cycles() == ["geofix.maps.a -> geofix.maps.b -> geofix.maps.c -> geofix.maps.a"]


def test_import_module_literals_are_imports(tmp_path, monkeypatch):
    fake = tmp_path / "maps"
    fake.mkdir()
    (fake / "bad.py").write_text('import importlib\nimportlib.import_module("geofix.cli")\n')
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", tmp_path)
    assert upward_imports() == ["maps/bad.py:2 maps -> cli"]
