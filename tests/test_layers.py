"""The layer order: every import inside the package runs downward (or within a layer)."""

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
    ("plot", "console", "report"),
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
    """``(line, module)`` of every geofix import in a file, lazy ones included."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
            if node.module == "geofix":  # a submodule by name, or a public name
                names = [f"geofix.{a.name}" for a in node.names if a.name in RANK]
            found += [(node.lineno, n) for n in names if n.startswith("geofix")]
        elif isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names if a.name.startswith("geofix")]
    return found


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
