"""pytest-benchmark fixtures of the performance suite (``make bench``).

Each benchmark stores its goal figures -- a measured ratio against its yardstick in the
same run, the absolute times beside it -- under a key of the session's ``figures``
dict, written as JSON at the end of the session to ``$GEOFIX_BENCH_FIGURES`` (default
``out/bench/figures.json``), from which ``benchmarks/sections/performance.py`` writes the
performance section of ``docs/RESULTS.md``.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


@pytest.fixture(scope="session")
def figures():
    """A dict of figures, saved as JSON when the session ends."""
    store: dict = {}
    yield store
    path = Path(os.environ.get("GEOFIX_BENCH_FIGURES", HERE.parent / "out/bench/figures.json"))
    path.parent.mkdir(parents=True, exist_ok=True)
    old = json.loads(path.read_text()) if path.exists() else {}
    path.write_text(json.dumps({**old, **store}, indent=2, default=float) + "\n")
