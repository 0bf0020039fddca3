"""Campaign memory, ``--jobs`` scaling and ``--trials 1000000`` start-up, in the suite.

Part of the pytest-benchmark suite (``make bench``); runs :mod:`bench_campaign`'s
measurements (child processes watched with psutil). ``GEOFIX_BENCH_CELLS`` sets the map
side (default 10 000, the goal's map: its campaigns peak near 0.6 GB now that the map is
read straight into float32); ``GEOFIX_BENCH_WATCH`` the seconds each ``--trials
1000000`` run is watched (default 20).
"""

from __future__ import annotations

import os

import bench_campaign as bc

CELLS = int(os.environ.get("GEOFIX_BENCH_CELLS", "10000"))
WATCH_S = float(os.environ.get("GEOFIX_BENCH_WATCH", "20"))


def test_campaign_memory_scaling_startup(figures):
    report = bc.campaign_figures(CELLS, WATCH_S)
    figures["campaign"] = report
    assert report["memory_jobs1"]["peak_pss_bytes"] > 0
