"""Paired all-beam navigator updates: the fused likelihood against the prediction-array path.

Two ``pmf`` navigators take the same EX1811 pings (all 432 beams, the setup of
``bench_navigator.py``): one with the point-mass update as it is (one compiled pass over
nodes x beams, :func:`geofix.measurement.node_grid_log_likelihood`), one with the
reference update that builds the ``(nodes, beams)`` predictions
(:func:`~geofix.measurement.predict_measurements`), their node field variance and then
the log-likelihood. The two are timed ping by ping in turn, so a busy machine slows both
alike; the printed ratio (fused / reference median update) is the same-run measure, and
the two navigators' estimates must agree.

Usage: ``NUMBA_NUM_THREADS=1 python benchmarks/bench_fused_likelihood.py [--runs 3]``
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

import bench_navigator as bn
from geofix.filters import _grid_ops as ops
from geofix.filters.pmf import Pmf, node_field_variance
from geofix.measurement import log_likelihood, predict_measurements
from geofix.navigator import Navigator, NavigatorSettings


class ReferencePmf(Pmf):
    """The point-mass update through the ``(nodes, beams)`` prediction array."""

    def update(self, state, obs, grid, rng):
        if not np.isfinite(obs.values).any():
            return state
        xy = ops.node_positions(*state.frame, state.shape)
        predicted = predict_measurements(grid, xy, obs.heading, obs.offsets)
        var = obs.noise_var
        if self.discretisation_noise:
            var = var + node_field_variance(predicted, obs.values)
        lw = ops.normalise(state.log_weight + log_likelihood(predicted, obs.values, var))
        return replace(state, log_weight=lw, evaluations=state.evaluations + xy.size // 2)


def paired_run(grid, error, mission, inputs) -> tuple[np.ndarray, np.ndarray, float]:
    """Seconds per converged update ``(fused, reference)`` and the largest estimate gap, m."""
    settings = NavigatorSettings(noise_std=bn.NOISE_STD, max_update_beams=None)
    navs = [
        Navigator(grid, f, settings, seed=bn.SEED, map_error=error) for f in (Pmf(), ReferencePmf())
    ]
    for nav in navs:
        nav.init(mission.times[0], inputs.indicated[0], inputs.sigma[0], inputs.heading[0])
    times, gap = ([], []), 0.0
    for k in range(mission.n):
        ests = []
        for nav, out in zip(navs, times, strict=True):
            if k:
                nav.motion(mission.times[k], inputs.indicated[k], inputs.heading[k])
            t0 = time.perf_counter()
            est = nav.measure(mission.times[k], mission.ping(k))
            seconds = time.perf_counter() - t0
            ests.append(est)
            if est.status == "converged" and k > 0:
                out.append(seconds)
        gap = max(gap, float(np.hypot(*(ests[0].position - ests[1].position))))
    return np.asarray(times[0]), np.asarray(times[1]), gap


def main() -> None:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        grid, error, mission, inputs = bn.setup(Path(tmp))
        paired_run(grid, error, mission, inputs)  # warm-up: numba, caches
        print(f"yardstick (300x300 matmul): {bn.yardstick_ms():.2f} ms")
        for _ in range(args.runs):
            fused, reference, gap = paired_run(grid, error, mission, inputs)
            print(
                f"fused {1e3 * np.median(fused):.2f} ms, reference {1e3 * np.median(reference):.2f}"
                f" ms, ratio {np.median(fused) / np.median(reference):.3f}, largest estimate "
                f"gap {gap:.2e} m"
            )


if __name__ == "__main__":
    main()
