"""Time per TERCOM match: a +-150-cell window (301 x 301 candidates) with 110 points.

Reports the numba kernel against a plain-numpy reference on the same problem (a ratio in
the same run, not an absolute time), and the absolute time per match for the record.

Usage: ``python benchmarks/bench_tercom.py [--repeat 5]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from geofix.maps.grid import Grid
from geofix.match.tercom import Tercom
from geofix.problem import MatchProblem


def make_problem(rng: np.random.Generator, points: int = 110, half_cells: int = 150):
    """A gravity-like random map and a straight 110-point track in its middle."""
    n = 2 * half_cells + points + 40
    yy, xx = np.mgrid[0:n, 0:n] * 100.0
    z = sum(
        rng.normal(0, 10) * np.sin(rng.uniform(1e-4, 1e-3) * xx + rng.uniform(1e-4, 1e-3) * yy)
        for _ in range(10)
    )
    grid = Grid(z, 0.0, 0.0, 100.0, 100.0, kind="gravity", units="mGal")
    start = np.array([(half_cells + 20) * 100.0] * 2)
    track = start + np.arange(points)[:, None] * np.array([80.0, 30.0])
    measured = grid.sample(track[:, 0], track[:, 1])[:, None] + rng.normal(0, 1, (points, 1))
    return MatchProblem(
        grid=grid,
        indicated=track + 250.0,
        heading=np.full(points, np.arctan2(80, 30)),
        offsets=np.zeros((1, 2)),
        measured=measured,
        sigma_position=np.full(points, half_cells * 100.0 / 3),
        times=np.arange(points) * 20.0,
        noise_std=1.0,
    )


def numpy_reference(problem: MatchProblem, ox: np.ndarray, oy: np.ndarray) -> np.ndarray:
    """MSD surface with plain numpy broadcasting (the baseline)."""
    px, py = problem.indicated[:, 0], problem.indicated[:, 1]
    vx = px[None, None, :] + ox[None, :, None]
    vy = py[None, None, :] + oy[:, None, None]
    m = problem.grid.sample(vx, vy)
    return np.mean((m - problem.measured[:, 0]) ** 2, axis=-1)


def best_time(fn, repeat: int) -> float:
    """Best wall time of ``repeat`` calls, seconds."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    """Run the benchmark and print a small table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    problem = make_problem(rng)
    matcher = Tercom(window_m=150 * 100.0)
    matcher.match(problem, rng)  # compile once
    ox, oy = matcher.candidate_offsets(problem)
    t_numba = best_time(lambda: matcher.match(problem, rng), args.repeat)
    t_numpy = best_time(lambda: numpy_reference(problem, ox, oy), max(1, args.repeat // 2))
    print(f"candidates: {len(ox)} x {len(oy)}, points: {problem.n}")
    print(f"tercom match (numba kernel + integrity): {t_numba * 1e3:.1f} ms")
    print(f"numpy broadcasting reference:           {t_numpy * 1e3:.1f} ms")
    print(f"speed-up over numpy: {t_numpy / t_numba:.1f}x")


if __name__ == "__main__":
    main()
