"""TERCOM speed: the +-150-cell x 110-point goal, and the loop and FFT routes by size.

Benchmark suite: pytest-benchmark, chosen over asv because every figure here is a ratio
against a yardstick measured in the same run on the same (shared, noisy) machine, not a
history across commits -- asv's per-commit environments and separate processes would
cost minutes per run on two shared cores and add nothing to a same-run ratio, while
pytest-benchmark runs in the project's own environment, reuses its fixtures and writes
machine-readable JSON (``--benchmark-json``). Run with ``make bench``.

Yardstick: :func:`_yardsticks.numpy_tercom_rows`, the plain row-chunked numpy search.
``python benchmarks/bench_tercom.py`` still prints the headline ratio on its own.
"""

from __future__ import annotations

import dataclasses
import time

import numba
import numpy as np

from _yardsticks import numpy_tercom_rows, paired_ratio
from geofix.maps.grid import Grid
from geofix.match.tercom import Tercom, tercom_cost_surface
from geofix.problem import MatchProblem

GOAL_RATIO = 30.0


def make_problem(
    rng: np.random.Generator, points: int = 110, half_cells: int = 150, beams: int = 1
):
    """A gravity-like random map and a straight track in its middle (100 m cells)."""
    n = 2 * half_cells + points + 60
    yy, xx = np.mgrid[0:n, 0:n] * 100.0
    z = sum(
        rng.normal(0, 10) * np.sin(rng.uniform(1e-4, 1e-3) * xx + rng.uniform(1e-4, 1e-3) * yy)
        for _ in range(10)
    )
    grid = Grid(z, 0.0, 0.0, 100.0, 100.0, kind="gravity", units="mGal")
    start = np.array([(half_cells + 30) * 100.0] * 2)
    track = start + np.arange(points)[:, None] * np.array([80.0, 30.0])
    offsets = np.column_stack([np.linspace(-1500, 1500, beams), np.zeros(beams)])
    heading = np.full(points, np.arctan2(80, 30))
    problem = MatchProblem(
        grid=grid,
        indicated=track + 250.0,
        heading=heading,
        offsets=offsets,
        measured=np.zeros((points, beams)),
        sigma_position=np.full(points, half_cells * 100.0 / 3),
        times=np.arange(points) * 20.0,
        noise_std=1.0,
    )
    fx, fy = problem.footprint(track)
    measured = grid.sample(fx, fy) + rng.normal(0, 1, fx.shape)
    return MatchProblem(**{**problem.__dict__, "measured": measured})


def numpy_reference(problem: MatchProblem, ox: np.ndarray, oy: np.ndarray) -> np.ndarray:
    """MSD surface by the row-chunked numpy search (the yardstick)."""
    return numpy_tercom_rows(problem, ox, oy)


def best_time(fn, repeat: int) -> float:
    """Best wall time of ``repeat`` calls, seconds."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def _median_time(fn, repeat: int = 3) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def _surface_call(problem, ox, oy, route):
    return lambda: tercom_cost_surface(problem, ox, oy, route=route)


def test_tercom_150_cells_110_points(benchmark, figures):
    """The goal: a whole match (surface + integrity) against the numpy search."""
    problem = make_problem(np.random.default_rng(0))
    matcher = Tercom(window_m=150 * 100.0)
    ox, oy = matcher.candidate_offsets(problem)
    fix = matcher.match(problem)
    numpy_reference(problem, ox, oy)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        one = paired_ratio(lambda: matcher.match(problem), lambda: numpy_reference(problem, ox, oy))
        plain = dataclasses.replace(matcher, offset_std=0)
        msd_only = paired_ratio(
            lambda: plain.match(problem), lambda: numpy_reference(problem, ox, oy)
        )
        full = paired_ratio(
            lambda: tercom_cost_surface(problem, ox, oy, route="loop"),
            lambda: numpy_reference(problem, ox, oy),
            repeat=5,
        )
    finally:
        numba.set_num_threads(threads)
    two = None
    if numba.config.NUMBA_NUM_THREADS >= 2:
        numba.set_num_threads(2)
        try:
            two = paired_ratio(
                lambda: tercom_cost_surface(problem, ox, oy, route="loop"),
                lambda: numpy_reference(problem, ox, oy),
                repeat=5,
            )
        finally:
            numba.set_num_threads(threads)
    benchmark.pedantic(matcher.match, args=(problem,), rounds=5, iterations=1)
    figures["tercom_goal"] = {
        "candidates": int(ox.size * oy.size),
        "samples": int(problem.n),
        "route": fix.diagnostics["route"],
        "match_1_thread": one,
        "match_without_offset_1_thread": msd_only,
        "offset_probability": float(fix.diagnostics["offset_probability"]),
        "loop_surface_no_pruning_1_thread": full,
        "loop_surface_no_pruning_2_threads": two,
        "goal_ratio": GOAL_RATIO,
    }
    assert np.isfinite(one["ratio"])


SIZES = (  # (half-window cells, points, beams)
    (50, 110, 1),
    (150, 110, 1),
    (150, 30, 1),
    (150, 110, 33),
    (300, 110, 1),
)


def test_tercom_routes_by_size(figures):
    """Loop (no pruning) against FFT at each size, and the route the cost model picks."""
    rows = []
    numba_threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        for half, points, beams in SIZES:
            problem = make_problem(np.random.default_rng(1), points, half, beams)
            matcher = Tercom(window_m=half * 100.0)
            ox, oy = matcher.candidate_offsets(problem)
            row = {"half_cells": half, "points": points, "beams": beams}
            for route in ("loop", "fft"):
                tercom_cost_surface(problem, ox, oy, route=route)
                row[f"{route}_s"] = _median_time(_surface_call(problem, ox, oy, route))
            row["auto_picks"] = matcher.match(problem).diagnostics["route"]
            row["faster"] = "loop" if row["loop_s"] < row["fft_s"] else "fft"
            rows.append(row)
    finally:
        numba.set_num_threads(numba_threads)
    figures["tercom_routes"] = rows
    assert all(r["auto_picks"] in ("loop", "fft") for r in rows)


if __name__ == "__main__":
    problem = make_problem(np.random.default_rng(0))
    matcher = Tercom(window_m=150 * 100.0)
    ox, oy = matcher.candidate_offsets(problem)
    matcher.match(problem)
    print(paired_ratio(lambda: matcher.match(problem), lambda: numpy_reference(problem, ox, oy)))
