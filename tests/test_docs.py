"""The documentation: gallery scripts run, the API pages cover the public namespace.

A full ``make docs`` takes minutes on two cores, so the suite checks its parts: every
gallery script runs and draws, the namespace page lists every name of ``geofix.__all__``
and renders in a small Sphinx build without a warning, and the pages cite no file that is
not in the repository.
"""

from __future__ import annotations

import importlib.util
import re
import runpy
import sys
from pathlib import Path

import pytest

import geofix

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
EXAMPLES = sorted((ROOT / "examples").glob("plot_*.py"))
#: Top-level units that are not part of the library's API (the command line and its drawing).
NOT_API = {"cli", "console", "__main__"}

pytestmark = pytest.mark.slow


def _docs_conf():
    """The Sphinx configuration module, imported from docs/conf.py."""
    spec = importlib.util.spec_from_file_location("geofix_docs_conf", DOCS / "conf.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _public_names() -> list[str]:
    return [n for n in geofix.__all__ if not n.startswith("_")]


def test_there_are_four_to_six_gallery_scripts():
    assert 4 <= len(EXAMPLES) <= 6


@pytest.mark.parametrize("script", EXAMPLES, ids=lambda p: p.stem)
def test_gallery_script_runs_and_draws(script, monkeypatch, tmp_path):
    matplotlib = pytest.importorskip("matplotlib")
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(plt, "show", lambda *a, **k: None)
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    plt.close("all")
    runpy.run_path(str(script), run_name="__main__")
    figures = [plt.figure(n) for n in plt.get_fignums()]
    assert figures, f"{script.name} drew no figure"
    assert all(fig.axes for fig in figures)
    plt.close("all")


def test_gallery_scripts_use_only_public_names():
    for script in EXAMPLES:
        for line in script.read_text().splitlines():
            if line.startswith(("import geofix", "from geofix")):
                module = line.split()[1]
                assert not any(part.startswith("_") for part in module.split(".")), line
                if line.startswith("from"):
                    names = line.split(" import ")[1].split(",")
                    assert not any(n.strip().startswith("_") for n in names), line


def test_namespace_page_lists_every_public_name(tmp_path):
    conf = _docs_conf()
    page = conf.write_namespace_page(tmp_path / "namespace.rst").read_text()
    entries = {line.strip() for line in page.splitlines() if line.startswith("   ")}
    assert set(_public_names()) <= entries
    grouped = [n for names in conf.namespace_entries().values() for n in names]
    assert sorted(grouped) == sorted(_public_names())


def test_namespace_page_follows_all(monkeypatch, tmp_path):
    conf = _docs_conf()
    monkeypatch.setattr(geofix, "fresh_function", lambda: None, raising=False)
    monkeypatch.setattr(geofix, "__all__", [*geofix.__all__, "fresh_function"])
    page = conf.write_namespace_page(tmp_path / "namespace.rst").read_text()
    assert "Functions\n---------" in page
    assert "   fresh_function" in page


def test_every_library_module_is_in_the_layer_page():
    listed = {
        line.strip().removeprefix("geofix.")
        for line in (DOCS / "api" / "modules.rst").read_text().splitlines()
        if line.strip().startswith("geofix.")
    }
    package = Path(geofix.__file__).parent
    units = {
        p.stem if p.is_file() else p.name
        for p in package.iterdir()
        if (p.suffix == ".py" or (p / "__init__.py").exists()) and p.name != "__init__.py"
    }
    public = {u for u in units if not u.startswith("_")} - NOT_API
    assert public <= listed, f"modules missing from docs/api/modules.rst: {public - listed}"


def test_namespace_page_builds_without_a_warning(tmp_path):
    pytest.importorskip("sphinx")
    pytest.importorskip("numpydoc")
    from sphinx.application import Sphinx

    src = tmp_path / "src"
    (src / "_templates").mkdir(parents=True)
    conf = _docs_conf()
    conf.write_namespace_page(src / "index.rst")
    for name in ("class.rst", "module.rst"):
        template = DOCS / "_templates" / "autosummary" / name
        (src / "_templates" / "autosummary").mkdir(exist_ok=True)
        (src / "_templates" / "autosummary" / name).write_text(template.read_text())
    (src / "modules.rst").write_text("Modules\n=======\n")
    (src / "conf.py").write_text(
        "extensions = ['sphinx.ext.autodoc', 'sphinx.ext.autosummary', 'numpydoc']\n"
        "templates_path = ['_templates']\nautosummary_generate = True\n"
        "numpydoc_show_class_members = False\nnumpydoc_xref_param_type = False\n"
        "autodoc_typehints = 'none'\ndefault_role = 'literal'\n"
        "suppress_warnings = ['toc.not_included']\n"
    )
    out = tmp_path / "html"
    warnings = tmp_path / "warnings.txt"
    sys.path.insert(0, str(ROOT / "src"))
    try:
        with warnings.open("w") as stream:
            app = Sphinx(src, src, out, tmp_path / "doctrees", "html", warning=stream, status=None)
            app.build()
    finally:
        sys.path.remove(str(ROOT / "src"))
    assert warnings.read_text() == ""
    for name in _public_names():
        page = out / "generated" / f"geofix.{name}.html"
        assert page.exists(), name
        assert f"geofix.{name}" in page.read_text()


#: An absolute path into a machine's own folders (home, root or a work tree).
MACHINE_PATH = re.compile(r"(?<![\w.~])/(?:home|root|work)/\w")


def test_pages_cite_only_what_the_repository_holds():
    written_by_hand = [p for p in DOCS.glob("*.md") if p.name != "RESULTS.md"]
    package = Path(geofix.__file__).parent
    pages = [*written_by_hand, *DOCS.glob("guide/*.md"), *EXAMPLES, *package.rglob("*.py")]
    for page in pages:
        text = page.read_text()
        assert "ALGORITHMS.md" not in text, page.name
        assert not MACHINE_PATH.search(text), page.name


def test_every_guide_page_is_in_the_guide_navigation():
    toctree = (DOCS / "guide" / "index.md").read_text()
    entries = set(re.search(r"```\{toctree\}\n(.*?)```", toctree, flags=re.S).group(1).split())
    pages = {p.stem for p in DOCS.glob("guide/*.md")} - {"index"}
    assert pages <= entries, pages - entries
    assert "guide/index" in (DOCS / "index.md").read_text()
    assert (DOCS / "_templates" / "layout.html").exists()


def _printed_by(page: Path, tmp_path, capsys) -> str:
    (code,) = re.findall(r"```python\n(.*?)```", page.read_text(), flags=re.S)
    exec(compile(code, str(page), "exec"), {"__name__": "guide"})
    return capsys.readouterr().out.strip()


def test_navigator_guide_prints_what_the_page_says(tmp_path, monkeypatch, capsys):
    page = DOCS / "guide" / "navigator.md"
    monkeypatch.chdir(tmp_path)
    printed = _printed_by(page, tmp_path, capsys)
    assert f"`{printed}`" in " ".join(page.read_text().split())


def test_replay_guide_table_is_what_the_command_prints(tmp_path):
    from geofix.cli import REPLAY_COLUMNS
    from geofix.logs.gridmap import grid_log
    from geofix.replay import replay_log

    _, path = grid_log("builtin:ex1811", 50.0, tmp_path / "ex1811_50m.nc")
    result, _ = replay_log("builtin:ex1811", str(path), ["pmf", "pf"], None, 500.0, 1)
    text = " ".join((DOCS / "guide" / "replay.md").read_text().split())
    for name, row in result.summary["methods"].items():
        cells = [row[key] for _, key in REPLAY_COLUMNS]
        assert " │ ".join([f"│ {name}", *(f"{v:.1f}" for v in cells)]) in text, name
    assert " ┃ ".join(["┃ method", *(head for head, _ in REPLAY_COLUMNS)]) in text
    assert f'"converged_pings": {result.summary["methods"]["pmf"]["converged_pings"]}' in text


def test_generated_pages_of_the_last_build_are_cleared(tmp_path):
    conf = _docs_conf()
    for name in ("geofix.Navigator", "geofix.gone.Thing"):
        (tmp_path / f"{name}.rst").write_text(f"{name}\n")
    (tmp_path / "keep.txt").write_text("")
    removed = conf.clear_generated_pages(tmp_path)
    assert {p.stem for p in removed} == {"geofix.Navigator", "geofix.gone.Thing"}
    assert [p.name for p in tmp_path.iterdir()] == ["keep.txt"]
