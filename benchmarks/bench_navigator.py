"""Time one navigator update on the real EX1811 pings (432 beams) and the server round trip.

The map is gridded from the same survey at 50 m (``geofix grid``), the INS drift is
simulated on the GNSS track (500 m initial error, seed 1). For every method the 50 pings
are replayed; the time of each ``measure`` (one update: NIS, gating, the filter's
update, the estimate) is recorded once the navigator has converged, with the default 64
evenly spread beams per update and with all 432. The server round trip is the same pings
sent through ``geofix serve`` over 127.0.0.1 (``geofix.client``); its overhead
(``server_overhead_ms``) is the median, over pings, of the round trip minus the update the
server's own navigator made for that ping (its ``measure``, timed inside the server
thread): what serving adds to the update it carries (JSON both ways, the checks, the
socket, the thread wake-ups). ``server_overhead_paired_ms`` is the round trip minus the
same update made offline just before by an identical navigator (which must give the very
same estimate), and ``second_twin_penalty_ms`` the server's update minus that offline one
(what running an identical navigator second costs in caches, about 0). ``server_cpu_ms``
is the server's request handling called in-process (JSON in and out, checks, no socket)
minus the offline update. A yardstick (a 300 x 300 matrix product, timed in the same run)
shows how loaded the machine was; on this shared machine the speed of the very same
compiled update changes by up to 1.5x from one half-second to the next, so compare
medians of one run.

Usage: ``python benchmarks/bench_navigator.py [--methods pmf mpf pf sitan] [--json]``

All-beam ``pmf`` update (``NUMBA_NUM_THREADS=1``): 29.5 ms median on an idle machine with
the prediction-array likelihood; with the fused compiled likelihood (unchecked reads
where the whole swath is on the map, vectorised sums) the paired same-run ratio against
that path (``bench_fused_likelihood.py``: navigator by navigator on the same pings,
estimates within 1e-13 m) was 0.57-0.71 over runs on a busy machine and 0.62 on a quiet
one, where this benchmark then gave 11.5-14.9 ms (``pf``: 89.7 ms).

All-beam ``mpf`` update: 53-89 ms median while its field variance (the discretisation
noise, ``geofix.filters.pf.spread_field_variance``) read 2000 particles x 432 beams x 3
positions, about 80 % of the update; with at most ~128 000 particle-beam differences (296
particles for 432 beams, the estimate within ~1 % of the all-particle one) 17.8-19.8 ms
on the quick stretches of the machine and 27-29 ms on its slow ones (the same compiled
likelihood, 2.2 M bilinear reads of 5000 particles, took 10 ms or 18 ms).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from geofix.logs import read_mission
from geofix.logs.gridmap import grid_log
from geofix.maps import load_grid
from geofix.maps.gridding import load_map_error
from geofix.navigator import Navigator, NavigatorSettings
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
    nav = Navigator(grid, method, settings, SEED, error, ins_model=inputs.ins_model)
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


def round_trip_times(grid, error, mission, inputs, method: str) -> dict:
    """Per converged ping, seconds (lists under the keys below).

    ``rtt``: the ``ping`` round trip over loopback (client encoding included);
    ``served``: the update the server's own navigator made for that ping (its
    ``measure``, timed inside the server thread); ``local``: the same update made
    offline by an identical navigator right before (which must give the same estimate);
    ``handled``: the server's handling of the same request line in-process.
    """
    from geofix.client import Client, ping_message
    from geofix.server import Session, serve_in_thread

    settings = NavigatorSettings(noise_std=NOISE_STD)
    model = inputs.ins_model
    offline = Navigator(grid, method, settings, SEED, error, ins_model=model)
    session = Session(grid, method, settings, SEED, error, ins_model=model)
    deg = np.rad2deg(inputs.heading)
    rad = np.deg2rad(deg)
    out: dict[str, list] = {"rtt": [], "served": [], "local": [], "handled": []}
    served: list[float] = []
    server = serve_in_thread(grid, method, "127.0.0.1", settings, SEED, error, model)
    with server as addr, Client(*addr) as client, _timing_server_updates(served):
        client.init(mission.times[0], *inputs.indicated[0], inputs.sigma[0], deg[0])
        offline.init(mission.times[0], inputs.indicated[0], inputs.sigma[0], rad[0])
        session.handle(json.dumps(client_init(mission, inputs, deg)).encode())
        for k in range(mission.n):
            if k:
                client.nav(mission.times[k], *inputs.indicated[k], deg[k])
                offline.motion(mission.times[k], inputs.indicated[k], rad[k])
                nav_msg = {"type": "nav", "t": float(mission.times[k])}
                nav_msg.update(x=float(inputs.indicated[k, 0]), y=float(inputs.indicated[k, 1]))
                session.handle(json.dumps({**nav_msg, "heading_deg": float(deg[k])}).encode())
            t0 = time.perf_counter()
            est = offline.measure(mission.times[k], mission.ping(k))
            t1 = time.perf_counter()
            reply = client.ping(mission.times[k], mission.ping(k))
            t_reply = time.perf_counter()
            line = json.dumps(ping_message(mission.times[k], mission.ping(k))).encode()
            t2 = time.perf_counter()
            in_process = session.handle(line)
            t3 = time.perf_counter()
            assert (in_process["x"], in_process["y"]) == (reply["x"], reply["y"])
            assert (reply["x"], reply["y"]) == (est.position[0], est.position[1])
            if reply["status"] == "converged" and k > 0:
                out["local"].append(t1 - t0)
                out["rtt"].append(t_reply - t1)
                out["served"].append(served[-1])
                out["handled"].append(t3 - t2)
    return out


@contextlib.contextmanager
def _timing_server_updates(times: list):
    """Record, in ``times``, the seconds of every ``Navigator.measure`` made off the main
    thread (by the server's navigators) while the block runs."""
    original = Navigator.measure
    main = threading.main_thread()

    def timed(self, *args, **kwargs):
        t0 = time.perf_counter()
        result = original(self, *args, **kwargs)
        if threading.current_thread() is not main:
            times.append(time.perf_counter() - t0)
        return result

    Navigator.measure = timed
    try:
        yield
    finally:
        Navigator.measure = original


def client_init(mission, inputs, deg) -> dict:
    """The ``init`` request of the benchmark's navigator."""
    return {
        "type": "init",
        "t": float(mission.times[0]),
        "x": float(inputs.indicated[0, 0]),
        "y": float(inputs.indicated[0, 1]),
        "sigma_m": float(inputs.sigma[0]),
        "heading_deg": float(deg[0]),
    }


def run(methods: list[str]) -> dict:
    """Median milliseconds per method: update (64 and 432 beams), round trip, overhead."""
    with tempfile.TemporaryDirectory() as tmp:
        grid, error, mission, inputs = setup(Path(tmp))
        rows = {"yardstick_matmul_ms": yardstick_ms(), "methods": {}}
        for method in methods:
            update_times(grid, error, mission, inputs, method, 64)  # warm-up (numba, caches)
            used = update_times(grid, error, mission, inputs, method, 64)
            full = update_times(grid, error, mission, inputs, method, None)
            times = round_trip_times(grid, error, mission, inputs, method)
            med = {
                k: 1e3 * float(np.median(v)) if v else None
                for k, v in (("update_ms", used), ("update_all_beams_ms", full))
            }
            rtt = times["rtt"]
            med["round_trip_ms"] = 1e3 * float(np.median(rtt))
            med["server_overhead_ms"] = 1e3 * float(np.median(np.subtract(rtt, times["served"])))
            paired = np.subtract(rtt, times["local"])
            med["server_overhead_paired_ms"] = 1e3 * float(np.median(paired))
            med["second_twin_penalty_ms"] = 1e3 * float(
                np.median(np.subtract(times["served"], times["local"]))
            )
            med["server_cpu_ms"] = 1e3 * float(
                np.median(np.subtract(times["handled"], times["local"]))
            )
            med["converged_pings"] = len(used)
            rows["methods"][method] = med
    return rows


def main() -> None:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", nargs="*", default=["pmf", "mpf", "pf", "sitan"])
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
