"""Time one navigator update on the real EX1811 pings (432 beams) and the server round trip.

The map is gridded from the same survey at 50 m (``geofix grid``), the INS drift is
simulated on the GNSS track (500 m initial error, seed 1). For every method the 50 pings
are replayed; the time of each ``measure`` (one update: NIS, gating, the filter's
update, the estimate) is recorded once the navigator has converged, with the default 64
evenly spread beams per update and with all 432. The server round trip is the same pings
sent through ``geofix serve`` over 127.0.0.1 (``geofix.client``), minus the offline update
time. A yardstick (a 300 x 300 matrix product, timed in the same run) shows how loaded the
machine was.

Usage: ``python benchmarks/bench_navigator.py [--methods pmf pf sitan] [--json]``
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from geofix.filters.online import NavigatorSettings
from geofix.logs import read_mission
from geofix.logs.gridmap import grid_log
from geofix.maps import load_grid
from geofix.maps.gridding import load_map_error
from geofix.navigator import Navigator
from geofix.replay import replay_inputs

CELL_M = 50.0
INITIAL_ERROR_M = 500.0
SEED = 1
NOISE_STD = 4.0


def setup(folder: Path):
    """``(grid, map_error, mission, inputs)`` of the benchmark."""
    grid_log("builtin:ex1811", CELL_M, folder / "ex1811.nc")
    grid = load_grid(folder / "ex1811.nc")
    error = load_map_error(folder / "ex1811.nc")
    mission = read_mission("builtin:ex1811", frame=grid.meta["projection"])
    return grid, error, mission, replay_inputs(mission, None, INITIAL_ERROR_M, SEED)


def yardstick_ms(repeat: int = 20) -> float:
    """Median time of a 300 x 300 float64 matrix product, milliseconds."""
    a = np.random.default_rng(0).standard_normal((300, 300))
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        a @ a
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def update_times(grid, error, mission, inputs, method: str, beams) -> list[float]:
    """Seconds of every ``measure`` made while the navigator was converged."""
    settings = NavigatorSettings(noise_std=NOISE_STD, max_update_beams=beams)
    nav = Navigator(grid, method, settings, seed=SEED, map_error=error)
    nav.init(mission.times[0], inputs.indicated[0], inputs.sigma[0], inputs.heading[0])
    out = []
    for k in range(mission.n):
        if k:
            nav.motion(mission.times[k], inputs.indicated[k], inputs.heading[k])
        t0 = time.perf_counter()
        est = nav.measure(mission.times[k], mission.ping(k))
        if est.status == "converged" and k > 0:
            out.append(time.perf_counter() - t0)
    return out


def round_trip_times(grid, error, mission, inputs, method: str) -> list[float]:
    """Seconds of every ``ping`` request over loopback once converged."""
    from geofix.client import Client
    from geofix.server import serve_in_thread

    settings = NavigatorSettings(noise_std=NOISE_STD)
    deg = np.rad2deg(inputs.heading)
    out = []
    server = serve_in_thread(grid, method, settings=settings, seed=SEED, map_error=error)
    with server as addr, Client(*addr) as client:
        client.init(mission.times[0], *inputs.indicated[0], inputs.sigma[0], deg[0])
        for k in range(mission.n):
            if k:
                client.nav(mission.times[k], *inputs.indicated[k], deg[k])
            t0 = time.perf_counter()
            reply = client.ping(mission.times[k], mission.ping(k))
            if reply["status"] == "converged" and k > 0:
                out.append(time.perf_counter() - t0)
    return out


def run(methods: list[str]) -> dict:
    """Median milliseconds per method: update (64 and 432 beams), round trip, overhead."""
    with tempfile.TemporaryDirectory() as tmp:
        grid, error, mission, inputs = setup(Path(tmp))
        rows = {"yardstick_matmul_ms": yardstick_ms(), "methods": {}}
        for method in methods:
            update_times(grid, error, mission, inputs, method, 64)  # warm-up (numba, caches)
            used = update_times(grid, error, mission, inputs, method, 64)
            full = update_times(grid, error, mission, inputs, method, None)
            rtt = round_trip_times(grid, error, mission, inputs, method)
            med = {
                k: 1e3 * float(np.median(v)) if v else None
                for k, v in (
                    ("update_ms", used),
                    ("update_all_beams_ms", full),
                    ("round_trip_ms", rtt),
                )
            }
            if med["update_ms"] is not None and med["round_trip_ms"] is not None:
                med["server_overhead_ms"] = med["round_trip_ms"] - med["update_ms"]
            med["converged_pings"] = len(used)
            rows["methods"][method] = med
    return rows


def main() -> None:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", nargs="*", default=["pmf", "pf", "sitan"])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args()
    result = run(args.methods)
    if args.json:
        print(json.dumps(result))
        return
    print(f"yardstick (300x300 matmul): {result['yardstick_matmul_ms']:.2f} ms")
    for method, row in result["methods"].items():
        parts = [f"{k} {v:.2f}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()]
        print(f"{method}: " + ", ".join(parts))


if __name__ == "__main__":
    main()
