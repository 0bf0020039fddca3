"""Campaign memory, ``--jobs`` scaling and ``--trials 1000000`` start-up, in the suite.

Part of the pytest-benchmark suite (``make bench``); runs :mod:`bench_campaign`'s
measurements (child processes watched with psutil). ``GEOFIX_BENCH_CELLS`` sets the map
side (default 5000: a 10 000 x 10 000 map is 0.8 GB in float64 and too much for a
machine shared with others; the bytes-per-cell figures do not depend on the side).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import bench_campaign as bc

CELLS = int(os.environ.get("GEOFIX_BENCH_CELLS", "5000"))


def test_campaign_memory_scaling_startup(figures):
    report = {"cells": CELLS}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        big = bc.make_map(folder / "big.nc", CELLS)
        scen = bc.scenario_file(folder, big, CELLS, 4)
        for jobs in (1, 2):
            run = bc.watch_campaign(scen, jobs, 4, folder / f"m{jobs}", 1800.0)
            run["bytes_per_cell"] = run["peak_pss_bytes"] / CELLS**2
            report[f"memory_jobs{jobs}"] = run
        report["memory_ratio"] = (
            report["memory_jobs2"]["peak_pss_bytes"] / report["memory_jobs1"]["peak_pss_bytes"]
        )
        small = bc.make_map(folder / "small.nc", 800)
        scen = bc.scenario_file(folder, small, 800, 40)
        runs = {j: bc.watch_campaign(scen, j, 40, folder / f"s{j}", 1800.0) for j in (1, 2)}
        report["scaling"] = {f"jobs{j}": r for j, r in runs.items()}
        report["scaling"]["speedup"] = runs[1]["wall_s"] / runs[2]["wall_s"]
        report["startup"] = bc.watch_campaign(scen, 2, 10**6, folder / "u", 30.0)
    figures["campaign"] = report
    assert report["memory_jobs1"]["peak_pss_bytes"] > 0
