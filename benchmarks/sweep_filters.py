"""Loss rate, RMS and time of filter settings over many trials of one scenario.

The sweep behind the measured numbers in the docstrings of :class:`geofix.filters.pf.Pf`
(losses over 1000 ``source002_bank`` trials) and :class:`geofix.filters.pmf.Pmf`
(``max_points`` on that scenario's error-state prior). Every trial is simulated as a
campaign simulates it (:func:`geofix.evaluate.campaign.campaign_map`) and every setting
runs on it with the generator ``method_rng(seed, trial, stream)``, the same for all
settings (paired draws); ``--stream`` picks another set of random numbers.

Usage: ``python benchmarks/sweep_filters.py source002_bank pf pf:roughening=0.5
--trials 1000 [--stream pf] [--lost-m 1000] [--jobs 2]``
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def _setup(name: str):
    from geofix.evaluate.campaign import campaign_map
    from sections._common import scenario

    scen = scenario(name)
    return scen, campaign_map(scen)


_CACHE: dict = {}


def _trial(args) -> list[tuple[float, float, float]]:
    """``[(end error m, mean square track error m^2, time s)]`` of every setting."""
    from geofix.evaluate.runner import method_rng, run_trial
    from geofix.methods import parse_method_spec
    from geofix.sim.simulate import simulate_trial

    name, specs, stream, index = args
    if name not in _CACHE:
        _CACHE[name] = _setup(name)
    scen, grid = _CACHE[name]
    trial = simulate_trial(scen, grid, index)
    rng_of = lambda: method_rng(scen.seed, index, stream)  # noqa: E731 - one per setting
    return [
        (r.end_error_m, float(np.nanmean(np.asarray(r.error) ** 2)), r.time_s)
        for r in (run_trial(parse_method_spec(s), trial, grid, rng_of()) for s in specs)
    ]


def main() -> None:
    """Print one line per setting: RMS end and track error, losses, worst error, time."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario")
    parser.add_argument("specs", nargs="+")
    parser.add_argument("--trials", type=int, default=60)
    parser.add_argument("--stream", default="pf", help="random stream (method_rng's spec)")
    parser.add_argument("--lost-m", type=float, default=1000.0, help="end error of a loss, m")
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    tasks = [(args.scenario, args.specs, args.stream, i) for i in range(args.trials)]
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = np.array(list(pool.map(_trial, tasks, chunksize=4)))  # (trials, specs, 3)
    for j, spec in enumerate(args.specs):
        error, track, seconds = rows[:, j, 0], rows[:, j, 1], rows[:, j, 2]
        print(
            f"{spec:40s} RMS {np.sqrt(np.nanmean(error**2)):9.1f} m  "
            f"track {np.sqrt(np.nanmean(track)):9.1f} m  "
            f"lost {int((error > args.lost_m).sum()):4d} of {args.trials}  "
            f"worst {np.nanmax(error):9.1f} m  time {seconds.mean() * 1e3:7.1f} ms"
        )


if __name__ == "__main__":
    main()
