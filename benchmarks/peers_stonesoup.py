"""Stone Soup's point-mass and particle filters on the very trials geofix's filters see.

Benchmark-only (Stone Soup is the ``bench`` extra, never imported by the package or its
tests). Every trial is simulated from its scenario and seed exactly as the campaign runner
does (``simulate_trial(scenario, grid, index)``), so geofix's ``pmf`` / ``pf`` and Stone
Soup's filters run on identical truth, INS track and measurements. Stone Soup filters the
position *error* ``e = position - indicated`` (a random walk: ``F = I``, ``Q = q I`` with
``q`` the step's ``Motion.process_var``), and reads the map through a measurement model
whose function is geofix's own :func:`~geofix.measurement.predict_measurements`
(off-map beams read a value ``1e6`` field units away from the measurement), so the two
sides share the map reading and differ only in the filter machinery:

- ``PointMassPredictor`` / ``PointMassUpdater`` (Stone Soup's Lagrangian PMF: the grid is
  rebuilt around the covariance each step, weights in linear space, FFT convolution) with
  the same ``N x N`` points and ``sFactor`` = our ``extent_sigmas``;
- ``ParticlePredictor`` / ``ParticleUpdater`` with ``ESSResampler`` (systematic, ESS < M/2),
  the same number of particles as our ``pf``, no regulariser.

Identical likelihood: our ``pmf`` and ``pf`` run here with ``discretisation_noise=False``
and ``map_model=exact`` (Stone Soup has neither term) and the random-walk motion model
(``model=rw``, Stone Soup's), so both sides weigh every hypothesis by the same Gaussian
of the same beams with the same variance; our grid and particle count are fixed
(``max_points = points``, ``max_particles = particles``) as Stone Soup's are. The time
ratio (Stone Soup's time per trial over ours, same trials, same run) is printed per filter.

Usage::

    python benchmarks/peers_stonesoup.py --scenario azores-demo --trials 10 --points 61

Measured (Stone Soup 1.9.1, one core each, a 2-core machine running nothing else: the
median over trials of the paired per-trial time ratios, Stone Soup's over ours) -- from the
filters results section (``benchmarks/results.py --only filters``: 10, 10 and 8 trials):

=====================  =====  =====
scenario               pmf    pf
=====================  =====  =====
azores-demo            3.2    3.3
source004_main         4.7    3.6
source001_rugged       3.2    3.8
=====================  =====  =====

With the likelihood summed one hypothesis per compiled call (about 70 ns of call
overhead each, as much as 20 map reads) the same machine gave 2.3 / 2.0 (azores-demo) and
2.2 / 2.8 (source001_rugged); before the compiled fused likelihood and grid loops the
comparison gave 1.9 / 1.6, 2.2 / 1.7 and 3.4 / 2.5. Single trials vary (the section
prints the range of the per-trial ratios): a trial that meets a slow stretch of a shared
machine moves its ratio by up to 1.5x either way.
"""

from __future__ import annotations

import argparse
import time
from datetime import datetime, timedelta

import numpy as np

OFF_MAP_MISS = 1e6
"""Field units between the measurement and what an off-map beam reads (pdf -> 0)."""


def _measurement_model_class():
    """Stone Soup measurement model reading the geofix map at ``indicated + error``."""
    from stonesoup.base import Property
    from stonesoup.models.measurement.nonlinear import NonLinearGaussianMeasurement
    from stonesoup.types.array import StateVectors

    from geofix.measurement import predict_measurements

    class TerrainMeasurement(NonLinearGaussianMeasurement):
        """Field read at every beam from ``indicated + error`` (state = position error)."""

        geogrid: object = Property(doc="geofix Grid")
        indicated: np.ndarray = Property(doc="(2,) indicated position, metres")
        heading: float = Property(doc="heading, radians")
        offsets: np.ndarray = Property(doc="(b, 2) beam offsets, metres")
        fill: np.ndarray = Property(doc="(b,) value read by off-map beams")

        @property
        def ndim_meas(self) -> int:
            return self.offsets.shape[0]

        def function(self, state, noise=False, **kwargs):
            err = np.asarray(state.state_vector, dtype=float).reshape(2, -1)
            positions = (self.indicated[:, None] + err).T
            pred = predict_measurements(self.geogrid, positions, self.heading, self.offsets)
            pred = np.where(np.isfinite(pred), pred, self.fill)
            return StateVectors(pred.T)

    return TerrainMeasurement


def _detection(model_cls, problem, k: int, timestamp):
    """Stone Soup detection of sample ``k`` (missing beams dropped), or None."""
    from stonesoup.types.array import StateVector
    from stonesoup.types.detection import Detection

    values = problem.measured[k]
    use = np.isfinite(values)
    if not use.any():
        return None
    var = max(problem.noise_std**2 + problem.map_error_std**2, 1e-12)
    model = model_cls(
        ndim_state=2,
        mapping=(0, 1),
        noise_covar=var * np.eye(int(use.sum())),
        geogrid=problem.grid,
        indicated=np.asarray(problem.indicated[k], dtype=float),
        heading=float(problem.heading[k]),
        offsets=problem.offsets[use],
        fill=values[use] + OFF_MAP_MISS,
    )
    return Detection(StateVector(values[use]), timestamp=timestamp, measurement_model=model)


def _transition(q: float, dt: float):
    from stonesoup.models.transition.linear import (
        CombinedLinearGaussianTransitionModel,
        RandomWalk,
    )

    rate = q / max(dt, 1e-9)
    return CombinedLinearGaussianTransitionModel([RandomWalk(rate), RandomWalk(rate)])


def _run_loop(problem, prior, predictor_for, updater) -> np.ndarray:
    """Stone Soup's time loop; returns the estimated ``(n, 2)`` absolute track."""
    from stonesoup.types.hypothesis import SingleHypothesis

    from geofix.filters.base import motions

    model_cls = _measurement_model_class()
    t0 = datetime(2000, 1, 1)
    steps = motions(problem)
    state, track = prior, np.empty((problem.n, 2))
    for k in range(problem.n):
        stamp = t0 + timedelta(seconds=float(problem.times[k] - problem.times[0]))
        if k:
            step = steps[k - 1]
            state = predictor_for(step).predict(state, timestamp=stamp)
        det = _detection(model_cls, problem, k, stamp)
        if det is not None:
            state = updater.update(SingleHypothesis(state, det))
        track[k] = problem.indicated[k] + np.asarray(state.mean, dtype=float).ravel()[:2]
    return track


def stonesoup_pmf(problem, points: int = 61, s_factor: float = 5.0) -> np.ndarray:
    """Stone Soup's point-mass filter over the position error; ``(n, 2)`` track, metres."""
    from stonesoup.functions import grid_creation
    from stonesoup.predictor.pointmass import PointMassPredictor
    from stonesoup.types.array import StateVectors
    from stonesoup.types.state import PointMassState
    from stonesoup.updater.pointmass import PointMassUpdater

    sigma0 = max(float(problem.sigma_position[0]), 1e-3 * problem.grid.cell_size)
    cov0 = sigma0**2 * np.eye(2)
    npa = np.array([points, points])
    grid, delta, dims, centre, eig = grid_creation(np.zeros((2, 1)), cov0, s_factor, 2, npa)
    density = np.exp(-0.5 * np.sum(grid**2, axis=0) / sigma0**2) / (2 * np.pi * sigma0**2)
    prior = PointMassState(
        state_vector=StateVectors(grid),
        weight=density,
        grid_delta=delta,
        grid_dim=dims,
        center=centre,
        eigVec=eig,
        Npa=npa,
        timestamp=datetime(2000, 1, 1),
    )
    updater = PointMassUpdater(measurement_model=None, sFactor=s_factor)

    def predictor_for(step):
        return PointMassPredictor(_transition(step.process_var, step.dt), sFactor=s_factor)

    return _run_loop(problem, prior, predictor_for, updater)


def stonesoup_pf(problem, particles: int, rng: np.random.Generator) -> np.ndarray:
    """Stone Soup's bootstrap particle filter over the position error; ``(n, 2)`` track."""
    from stonesoup.predictor.particle import ParticlePredictor
    from stonesoup.resampler.particle import ESSResampler
    from stonesoup.types.array import StateVectors
    from stonesoup.types.state import ParticleState
    from stonesoup.updater.particle import ParticleUpdater

    sigma0 = float(problem.sigma_position[0])
    draws = sigma0 * rng.standard_normal((2, particles))
    prior = ParticleState(
        state_vector=StateVectors(draws),
        log_weight=np.full(particles, -np.log(particles)),
        timestamp=datetime(2000, 1, 1),
    )
    updater = ParticleUpdater(measurement_model=None, resampler=ESSResampler())

    def predictor_for(step):
        return ParticlePredictor(_transition(step.process_var, step.dt))

    return _run_loop(problem, prior, predictor_for, updater)


def _timed(fn, *args) -> tuple[np.ndarray | None, float, str]:
    start = time.perf_counter()
    try:
        with np.errstate(all="ignore"):
            track = fn(*args)
    except Exception as exc:  # a peer failing is a result, not a crash of the benchmark
        return None, time.perf_counter() - start, f"{type(exc).__name__}: {exc}"
    return track, time.perf_counter() - start, ""


def compare(scen, trials: int, points: int = 61, particles: int = 5000) -> dict:
    """Run geofix's and Stone Soup's PMF and PF on trials ``0 .. trials-1`` of ``scen``.

    Returns
    -------
    dict
        ``{label: {"end_errors": (trials,) metres (NaN = failed / non-finite),
        "times": (trials,) seconds, "failures": int, "message": str}}`` for labels
        ``"geofix pmf"``, ``"stonesoup pmf"``, ``"geofix pf"``, ``"stonesoup pf"``.
    """
    from geofix.filters.pf import Pf
    from geofix.filters.pmf import Pmf
    from geofix.sim.simulate import prepare_map, simulate_trial

    grid = prepare_map(scen)
    # Same grid size and particle count as the peers: no adaptive growth. Identical
    # likelihood: no discretisation noise, the map taken as exact (Stone Soup has neither
    # term); the random-walk motion model, as Stone Soup's.
    same = {"discretisation_noise": False, "model": "rw", "map_model": "exact"}
    ours_pmf = Pmf(points=points, max_points=points, **same)
    ours_pf = Pf(particles=particles, max_particles=particles, **same)
    runs = {
        "geofix pmf": lambda p, r: ours_pmf.match(p, r).track,
        "stonesoup pmf": lambda p, r: stonesoup_pmf(p, points, ours_pmf.extent_sigmas),
        "geofix pf": lambda p, r: ours_pf.match(p, r).track,
        "stonesoup pf": lambda p, r: stonesoup_pf(p, particles, r),
    }
    out = {k: {"end_errors": [], "times": [], "failures": 0, "message": ""} for k in runs}
    warm = simulate_trial(scen, grid, 0).problem(grid)
    for fn in runs.values():  # one untimed run each: imports and caches are not timed
        _timed(fn, warm, np.random.default_rng(0))
    for index in range(trials):
        trial = simulate_trial(scen, grid, index)
        problem = trial.problem(grid)
        for label, fn in runs.items():
            rng = np.random.default_rng([scen.seed, index, 7])
            track, seconds, message = _timed(fn, problem, rng)
            error = np.nan if track is None else float(np.hypot(*(track[-1] - trial.truth[-1])))
            rec = out[label]
            rec["times"].append(seconds)
            rec["end_errors"].append(error)
            if not np.isfinite(error):
                rec["failures"] += 1
                rec["message"] = rec["message"] or message or "non-finite estimate"
    return {
        k: {**v, **{a: np.asarray(v[a]) for a in ("end_errors", "times")}} for k, v in out.items()
    }


def main() -> None:
    """Command-line entry point: print a small table for one scenario."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from sections._common import scenario

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="source004_main")
    parser.add_argument("--trials", type=int, default=5)
    parser.add_argument("--points", type=int, default=61)
    parser.add_argument("--particles", type=int, default=5000)
    args = parser.parse_args()
    if args.scenario == "azores-demo":
        from importlib import resources

        from geofix.sim.scenario import load_scenario

        scen = load_scenario(resources.files("geofix") / "scenarios" / "azores_demo.yaml")
    else:
        scen = scenario(args.scenario)
    result = compare(scen, args.trials, args.points, args.particles)
    for label, rec in result.items():
        e = rec["end_errors"]
        rms = float(np.sqrt(np.nanmean(e**2))) if np.isfinite(e).any() else float("nan")
        print(
            f"{label:14s} RMS end error {rms:9.2f} m   time/trial {rec['times'].mean():7.3f} s"
            f"   failures {rec['failures']} {rec['message'][:80]}"
        )
    for name, ratio in time_ratios(result).items():
        print(f"{name}: Stone Soup time / ours (median of trials) {ratio:6.2f}")


def time_ratios(result: dict) -> dict:
    """``{"pmf": r, "pf": r}``: median over trials of Stone Soup's time over ours.

    Each trial is run by both in turn, so a trial's ratio compares two runs made within a
    second of each other; the median of those paired ratios is less moved by the
    machine's speed changes than a ratio of mean times.
    """
    return {
        f: float(np.median(result[f"stonesoup {f}"]["times"] / result[f"geofix {f}"]["times"]))
        for f in ("pmf", "pf")
    }


if __name__ == "__main__":
    main()
