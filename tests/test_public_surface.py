"""The public surface is documented: numpydoc ``Parameters`` where a call takes several
arguments, and no measured figures (timings, speed-ups) in any docstring.

The public surface is every function and method whose name does not start with an
underscore, in a module none of whose path parts does either (the methods of public
classes included). Counted here: those taking three or more arguments besides ``self``
and ``cls`` (``*args`` counts as one).
"""

from __future__ import annotations

import ast
import inspect
import re
from pathlib import Path

import pytest

import geofix

PACKAGE = Path(geofix.__file__).parent

#: Least share of public functions and methods of three or more arguments with a
#: numpydoc ``Parameters`` section.
MIN_DOCUMENTED_SHARE = 0.90

#: A measured figure in prose: "2.6 times faster", "4x slower", "a speed-up of", "2 ns a
#: read", "10 ms per ping". A docstring states what a function does, not how fast it ran
#: on one machine (the measured numbers live in docs/RESULTS.md).
MEASURED_FIGURE = re.compile(
    r"\b(?:\d+(?:\.\d+)?|two|three|four|five|six|seven|eight|nine|ten|twenty|hundred)"
    r"\s*(?:x|×|times)\s+(?:faster|slower|quicker)\b"
    r"|\bspeed-?ups?\s+of\b"
    r"|\b\d+(?:\.\d+)?\s*(?:ns|µs|us|ms)\s+(?:per|a|an|each)\b",
    re.IGNORECASE,
)


def _is_public_module(path: Path) -> bool:
    parts = path.relative_to(PACKAGE).parts
    return not any(part.startswith("_") and part != "__init__.py" for part in parts)


def _argument_count(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    a = node.args
    names = [x.arg for x in (*a.posonlyargs, *a.args, *a.kwonlyargs)]
    return len([n for n in names if n not in ("self", "cls")]) + (a.vararg is not None)


def _public_callables(tree: ast.Module):
    """``(qualified name, node)`` of the module's public functions and public methods."""
    functions = (ast.FunctionDef, ast.AsyncFunctionDef)
    for node in tree.body:
        if getattr(node, "name", "_").startswith("_"):
            continue
        if isinstance(node, functions):
            yield node.name, node
        elif isinstance(node, ast.ClassDef):
            for item in node.body:
                if isinstance(item, functions) and not item.name.startswith("_"):
                    yield f"{node.name}.{item.name}", item


def _has_parameters(doc: str | None) -> bool:
    return bool(doc) and re.search(r"^\s*Parameters\n\s*-{3,}", doc, re.MULTILINE) is not None


def _sources():
    return sorted(PACKAGE.rglob("*.py"))


def test_most_public_functions_of_several_arguments_document_them():
    documented, missing = 0, []
    for path in filter(_is_public_module, _sources()):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for name, node in _public_callables(tree):
            if _argument_count(node) < 3:
                continue
            if _has_parameters(ast.get_docstring(node)):
                documented += 1
            else:
                missing.append(f"{path.relative_to(PACKAGE)}: {name}")
    total = documented + len(missing)
    share = documented / total
    assert share >= MIN_DOCUMENTED_SHARE, (
        f"{documented} of {total} public functions/methods of three or more arguments "
        f"({share:.0%}) have a Parameters section; without one:\n" + "\n".join(missing)
    )


def _takes_arguments(obj) -> bool:
    try:
        signature = inspect.signature(obj)
    except (TypeError, ValueError):  # no signature to read: nothing to document
        return False
    variadic = (inspect.Parameter.VAR_POSITIONAL, inspect.Parameter.VAR_KEYWORD)
    return any(p.kind not in variadic for p in signature.parameters.values())


@pytest.mark.parametrize("name", sorted(n for n in geofix.__all__ if not n.startswith("_")))
def test_every_name_of_the_namespace_documents_its_parameters(name):
    obj = getattr(geofix, name)
    if not (inspect.isclass(obj) or callable(obj)) or not _takes_arguments(obj):
        return
    docs = [inspect.getdoc(obj)]
    if inspect.isclass(obj):  # numpydoc: on the class, or on its __init__
        docs.append(inspect.getdoc(obj.__init__))
    assert any(_has_parameters(d) for d in docs), f"geofix.{name} has no Parameters section"


def _docstrings(tree: ast.Module):
    kinds = (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)
    for node in ast.walk(tree):
        if isinstance(node, kinds):
            doc = ast.get_docstring(node, clean=False)
            if doc:
                yield getattr(node, "name", "module docstring"), doc


def test_no_docstring_quotes_a_measured_figure():
    found = []
    for path in _sources():
        for name, doc in _docstrings(ast.parse(path.read_text(encoding="utf-8"))):
            text = " ".join(doc.split())  # a figure may be cut by a line break
            found += [
                f"{path.relative_to(PACKAGE)}: {name}: {m.group(0)!r}"
                for m in MEASURED_FIGURE.finditer(text)
            ]
    assert not found, "measured figures in docstrings:\n" + "\n".join(found)


@pytest.mark.parametrize(
    "text",
    [
        "2.6 times faster than",
        "four times slower",
        "a 3x faster read",
        "a speed-up of",
        "about 2 ns a read",
        "10 ms per ping",
    ],
)
def test_the_figure_pattern_finds_figures(text):
    assert MEASURED_FIGURE.search(text)


@pytest.mark.parametrize(
    "text",
    [
        "faster than ``max_speed_m_s``",
        "many times slower",
        "the quicker of the two",
        "a 2 % speed error",
        "timeout in seconds",
    ],
)
def test_the_figure_pattern_leaves_prose_alone(text):
    assert not MEASURED_FIGURE.search(text)
