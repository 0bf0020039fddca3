"""Sphinx configuration of the geofix documentation (``make docs``).

The build needs no network, and neither does reading the site: no intersphinx
inventories, no remote images, the theme's assets and MathJax are copied into it. The API
page of the flat namespace is written from ``geofix.__all__`` at every build
(:func:`write_namespace_page`), so it follows the package without a hand-kept list.
"""

from __future__ import annotations

import inspect
import os
import re
import sys
from pathlib import Path

HERE = Path(__file__).parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT / "src"))
os.environ.setdefault("MPLBACKEND", "Agg")

import geofix  # noqa: E402

project = "geofix"
author = "the geofix developers"
copyright = "the geofix developers"
release = geofix.__version__
version = ".".join(release.split(".")[:2])

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinx-mathjax-offline",  # MathJax served from the site itself, no CDN
    "sphinx.ext.viewcode",
    "numpydoc",
    "myst_parser",
    "sphinx_gallery.gen_gallery",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "results", "auto_examples/*.ipynb", "**.py.md5"]
templates_path = ["_templates"]

# -- API ---------------------------------------------------------------------------------
autosummary_generate = True
autosummary_ignore_module_all = True
autosummary_imported_members = False
autodoc_default_options = {"members": True, "show-inheritance": False}
autodoc_typehints = "none"
autodoc_member_order = "bysource"
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False
default_role = "literal"
add_module_names = False

# -- Markdown pages ------------------------------------------------------------------------
myst_enable_extensions = ["dollarmath", "amsmath", "deflist", "colon_fence"]
myst_heading_anchors = 3
suppress_warnings = ["myst.header"]

# -- Gallery -------------------------------------------------------------------------------
sphinx_gallery_conf = {
    "examples_dirs": str(ROOT / "examples"),
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
    "matplotlib_animations": False,
    "image_scrapers": ("matplotlib",),
    "reset_modules": ("matplotlib",),
    "show_memory": False,
    "plot_gallery": "True",
}

# -- HTML ----------------------------------------------------------------------------------
html_theme = "pydata_sphinx_theme"
html_title = f"geofix {release}"
html_static_path: list[str] = []
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
    "header_links_before_dropdown": 6,
    "navbar_align": "left",
    "footer_start": ["copyright"],
    "footer_end": ["sphinx-version"],
}
html_show_sourcelink = False
html_context = {"default_mode": "light"}

# No remote inventories: the build runs offline.
intersphinx_mapping: dict = {}


def namespace_entries(module=geofix) -> dict[str, list[str]]:
    """The names of ``module.__all__`` grouped for the API page (dunder names left out)."""
    groups: dict[str, list[str]] = {"Classes": [], "Functions": [], "Exceptions": []}
    for name in sorted(getattr(module, "__all__", ())):
        if name.startswith("_"):
            continue
        obj = getattr(module, name)
        if inspect.isclass(obj) and issubclass(obj, BaseException):
            groups["Exceptions"].append(name)
        elif inspect.isclass(obj):
            groups["Classes"].append(name)
        else:
            groups["Functions"].append(name)
    return {title: names for title, names in groups.items() if names}


def write_namespace_page(path: Path = HERE / "api" / "namespace.rst") -> Path:
    """Write the page of the flat ``geofix`` namespace from ``geofix.__all__``."""
    lines = [
        "The ``geofix`` namespace",
        "========================",
        "",
        ".. This page is written by docs/conf.py from geofix.__all__ at every build.",
        "",
        "Everything below is importable as ``geofix.NAME``; it is the curated public face",
        "of the package. The modules of every layer are listed in :doc:`modules`.",
        "",
        ".. currentmodule:: geofix",
        "",
    ]
    for title, names in namespace_entries().items():
        lines += [title, "-" * len(title), "", ".. autosummary::", "   :toctree: generated", ""]
        lines += [f"   {name}" for name in names] + [""]
    text = "\n".join(lines)
    if not path.exists() or path.read_text() != text:
        path.write_text(text)
    return path


write_namespace_page()


def clear_generated_pages(folder: Path = HERE / "api" / "generated") -> list[Path]:
    """Delete the API pages autosummary wrote at the last build; the paths removed.

    autosummary writes a page per documented name and rewrites them at every build, but
    never deletes one: a name moved or renamed since the last build would leave a page
    that fails to import, or one outside every toctree (warnings, errors under ``-W``).
    """
    pages = sorted(folder.glob("*.rst"))
    for page in pages:
        page.unlink(missing_ok=True)
    return pages


#: ``0 .. n-1`` inside an inline literal: autosummary cuts the one-line summary at its
#: ". ", leaving the literal open; an ellipsis reads the same and is not cut.
_RANGE_IN_LITERAL = re.compile(r"``([^`]*?) \.\. ([^`]*?)``")


def _keep_ranges_whole(app, what, name, obj, options, lines) -> None:
    lines[:] = [_RANGE_IN_LITERAL.sub(r"``\1 … \2``", line) for line in lines]


def setup(app) -> None:
    """Clear the last build's API pages (before autosummary writes them); the hook above."""
    clear_generated_pages()
    app.connect("autodoc-process-docstring", _keep_ranges_whole)
