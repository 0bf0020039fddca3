"""GA-SCA time per match on the source 000 benchmark scenarios, compiled vs numpy engine.

Part of the pytest-benchmark suite (``make bench``; see ``bench_tercom.py`` for why
pytest-benchmark). The yardstick is the same matcher with ``engine=numpy`` (the former
vectorised numpy fitness and operators) on the same trials, run alternately; both use
the same random draws, so their fixes -- and the mean errors recorded here -- agree.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest

from geofix.evaluate.runner import method_rng, run_trial
from geofix.methods import parse_method_spec
from geofix.sim import simulate
from geofix.sim.scenario import load_scenario

SCENARIOS = Path(__file__).resolve().parent / "scenarios"
SPEC = "ga-sca:mu1=40"
TRIALS = int(os.environ.get("GEOFIX_BENCH_GA_TRIALS", "6"))
GOAL_S = 0.1


def _run(method, trials, grid, seed):
    t0 = time.perf_counter()
    results = [run_trial(method, t, grid, method_rng(seed, t.index, SPEC)) for t in trials]
    return results, time.perf_counter() - t0


@pytest.mark.parametrize("name", ["source000_a_150", "source000_b_150"])
def test_ga_sca_source000(name, figures):
    scen = load_scenario(SCENARIOS / f"{name}.yaml")
    grid = simulate.prepare_map(scen)
    trials = [simulate.simulate_trial(scen, grid, i) for i in range(TRIALS)]
    fast, slow = parse_method_spec(SPEC), parse_method_spec(SPEC + ",engine=numpy")
    _run(fast, trials[:1], grid, scen.seed)  # warm-up
    _run(slow, trials[:1], grid, scen.seed)
    ratios, fast_times, fast_errors, slow_errors = [], [], [], []
    for trial in trials:  # alternate trial by trial: both see the same load
        (s,), ts = _run(slow, [trial], grid, scen.seed)
        (f,), tf = _run(fast, [trial], grid, scen.seed)
        ratios.append(ts / tf)
        fast_times.append(f.time_s)
        fast_errors.append(f.end_error_m)
        slow_errors.append(s.end_error_m)
    figures[f"ga_sca_{name}"] = {
        "trials": TRIALS,
        "median_time_per_match_s": float(np.median(fast_times)),
        "ratio_vs_numpy_engine": float(np.median(ratios)),
        "ratio_spread": [float(min(ratios)), float(max(ratios))],
        "mean_end_error_m": float(np.mean(fast_errors)),
        "mean_end_error_numpy_engine_m": float(np.mean(slow_errors)),
        "goal_s": GOAL_S,
    }
    assert np.allclose(fast_errors, slow_errors, atol=1e-6)
