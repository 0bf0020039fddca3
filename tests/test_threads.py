"""Parallel kernels and their serial twins: the same numbers, and no thread pool started."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"

_SCRIPT = """
import numpy as np
import numba.np.ufunc.parallel as parallel
from geofix import _threads
from geofix.maps.synthetic import fractal_terrain
from geofix.match import tercom
from geofix.match._tercom_loop import MARGINAL, loop_sums
rng = np.random.default_rng(4)
grid = fractal_terrain((120, 120), 10.0, rng=rng, std=15.0)
col = 40.0 + np.cumsum(rng.uniform(0.3, 0.9, 30))
row = 50.0 + np.cumsum(rng.uniform(0.2, 0.8, 30))
h = grid.values[row.astype(int), col.astype(int)] + rng.normal(0, 0.5, 30)
kc = np.arange(-20, 21, dtype=np.int64)
kr = np.arange(-15, 16, dtype=np.int64)
values = np.ascontiguousarray(grid.values)
with _threads.serial_kernels_only():
    serial = loop_sums(values, col, row, h, kc, kr, 0)[0]
    serial_marginal = loop_sums(values, col, row, h, kc, kr, MARGINAL)[0]
started_by_serial = parallel._is_initialized
both = loop_sums(values, col, row, h, kc, kr, 0)[0]
both_marginal = loop_sums(values, col, row, h, kc, kr, MARGINAL)[0]
print(
    started_by_serial,
    parallel._is_initialized,
    np.array_equal(serial, both),
    np.array_equal(serial_marginal, both_marginal),
)
"""


def test_serial_twin_gives_the_parallel_numbers_without_starting_the_pool():
    env = {**os.environ, "PYTHONPATH": str(SRC), "NUMBA_NUM_THREADS": "2"}
    done = subprocess.run(
        [sys.executable, "-c", _SCRIPT], env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["False", "True", "True", "True"]


def test_every_parallel_kernel_has_a_serial_twin():
    # A kernel compiled with parallel=True directly would start numba's thread pool in a
    # campaign's parent and so stop it forking its workers: go through _threads.twins.
    offenders = [
        f"{path.relative_to(SRC)}:{n}"
        for path in sorted((SRC / "geofix").rglob("*.py"))
        if path.name != "_threads.py"
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if re.search(r"parallel\s*=\s*True", line)
    ]
    assert offenders == []
