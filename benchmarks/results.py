"""Regenerate ``docs/RESULTS.md``: every benchmark section, our numbers beside the sources'.

Each module in ``benchmarks/sections/`` provides ``TITLE`` (str), ``ORDER`` (int) and
``build(quick: bool) -> str`` returning the section's Markdown (figures go to
``docs/figures/``). A section's output is kept in ``docs/results/NAME.md`` so that
``--only NAME`` reruns one section and the whole file is reassembled from all of them.

Usage::

    python benchmarks/results.py --out docs/RESULTS.md [--only NAME ...] [--quick]
"""

from __future__ import annotations

import argparse
import importlib.util
import platform
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SECTIONS = HERE / "sections"
FRAGMENTS = ROOT / "docs" / "results"

HEADER = """# geofix results

Written by `make results` (`python benchmarks/results.py`); never edited by hand. Every
number below is regenerated from the scenarios in `benchmarks/scenarios/` with their seeds.
Each section puts the source's reported numbers beside ours, and says plainly where they
disagree.
"""


def load_sections() -> dict:
    """Import every section module, keyed by file stem, ordered by ``ORDER``."""
    modules = {}
    sys.path.insert(0, str(SECTIONS))
    sys.path.insert(0, str(HERE))
    for path in sorted(SECTIONS.glob("*.py")):
        if path.stem.startswith("_"):
            continue
        spec = importlib.util.spec_from_file_location(f"sections.{path.stem}", path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module  # so a worker process can unpickle its functions
        spec.loader.exec_module(module)
        modules[path.stem] = module
    return dict(sorted(modules.items(), key=lambda kv: getattr(kv[1], "ORDER", 100)))


def build_section(name: str, module, quick: bool) -> Path:
    """Run one section and store its Markdown fragment."""
    t0 = time.perf_counter()
    print(f"[results] {name}: {module.TITLE} ...", flush=True)
    text = module.build(quick=quick).rstrip() + "\n"
    elapsed = time.perf_counter() - t0
    FRAGMENTS.mkdir(parents=True, exist_ok=True)
    path = FRAGMENTS / f"{name}.md"
    path.write_text(f"{text}\n_Section generated in {elapsed:.0f} s._\n")
    print(f"[results] {name}: done in {elapsed:.0f} s", flush=True)
    return path


def assemble(out: Path, modules: dict) -> None:
    """Concatenate the stored fragments, in section order, into ``out``."""
    parts = [HEADER, _machine_line()]
    for name, module in modules.items():
        fragment = FRAGMENTS / f"{name}.md"
        if fragment.exists():
            parts.append(fragment.read_text())
        else:
            parts.append(f"## {module.TITLE}\n\n_Not generated yet: run `make results`._\n")
    tmp = out.with_suffix(".tmp")
    tmp.write_text("\n".join(parts))
    tmp.replace(out)


def _machine_line() -> str:
    import os

    return (
        f"Machine: {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"{platform.machine()}. Times are wall-clock seconds on that machine.\n"
    )


def main() -> None:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description="Regenerate docs/RESULTS.md")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "RESULTS.md")
    parser.add_argument("--only", nargs="*", default=None, help="section names to rerun")
    parser.add_argument("--quick", action="store_true", help="fewer trials (smoke run)")
    args = parser.parse_args()
    modules = load_sections()
    unknown = set(args.only or []) - set(modules)
    if unknown:
        parser.error(f"unknown sections {sorted(unknown)}; known: {sorted(modules)}")
    for name, module in modules.items():
        if args.only is None or name in args.only:
            build_section(name, module, args.quick)
    assemble(args.out, modules)
    print(f"[results] wrote {args.out}")


if __name__ == "__main__":
    main()
