"""Run one method on one trial: the leg logic, timing and the errors against the truth.

A batch matcher (``recursive`` False) is handed one leg at a time. Leg 0 uses the free INS
track; after each fix the INS is reset to the fix's last position, so leg ``k`` sees

- indicated positions ``fix_end[k-1] + (ins[j] - ins[r])`` for its samples ``j``, where
  ``r`` is the last sample of leg ``k-1`` (the INS displacement since the reset, added to
  the fix), and
- a prior 1-sigma ``sqrt(var_fix + max(sigma[j]**2 - sigma[r]**2, 0))``: the previous
  fix's own uncertainty (the larger eigenvalue of its covariance, floored at a quarter
  cell squared and capped at the free INS variance ``sigma[r]**2``; ``sigma[0]**2`` when
  the fix gives no usable covariance) plus the INS error grown since the reset.

A batch fix's covariance already holds the INS drift inside its own leg (the error of the
leg's last sample against the mean error its one offset fits,
:func:`geofix.match.drift.leg_drift_covariance`): that is the covariance the campaign
scores (NEES, false fixes) and the one handed to the next leg.

A recursive method (``recursive`` True) is handed the whole mission as one problem and
returns its estimate at every sample.

A campaign's unit of work is a *task* (:class:`TaskRunner`): one trial index with the
methods still to run on it, so the trial is simulated once for all of them, and its
bounds (:func:`geofix.evaluate.bounds.trial_info`) are computed where it was simulated.
"""

from __future__ import annotations

import dataclasses
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from geofix.errors import GeofixError, MemoryBudgetError
from geofix.evaluate.bounds import TrialInfo, trial_info
from geofix.maps.grid import Grid
from geofix.problem import Fix, MatchProblem
from geofix.sim.scenario import Scenario
from geofix.sim.trial import Trial


@dataclass(frozen=True, eq=False)
class TrialResult:
    """The outcome of one method on one trial.

    Parameters
    ----------
    estimate : numpy.ndarray
        ``(n, 2)`` estimated positions, metres; NaN for samples never estimated (after a
        failure).
    error : numpy.ndarray
        ``(n,)`` horizontal distance between estimate and truth, metres.
    end_error_m : float
        Error at the last sample, metres (NaN when failed).
    mean_track_error_m, max_track_error_m : float
        Mean and maximum of ``error`` along the track, metres.
    leg_errors_m : tuple of float
        Error at the last sample of every leg, metres.
    time_s : float
        Wall time spent inside the method's ``match`` calls, seconds.
    n_calls : int
        Number of ``match`` calls (legs matched, or 1 for a recursive method).
    ambiguous : bool
        True when any fix was flagged ambiguous by the method.
    covariance : numpy.ndarray or None
        ``(2, 2)`` covariance of the last position, m^2, when the method gives one.
    evaluations : int
        Map look-ups or candidate scores spent, summed over calls.
    failed : bool
        True when the method raised a :class:`~geofix.errors.GeofixError`.
    message : str
        The error message of a failed trial, else ``""``.
    """

    estimate: np.ndarray
    error: np.ndarray
    end_error_m: float
    mean_track_error_m: float
    max_track_error_m: float
    leg_errors_m: tuple
    time_s: float
    n_calls: int
    ambiguous: bool
    covariance: np.ndarray | None
    evaluations: int
    failed: bool = False
    message: str = ""


def method_rng(seed: int, index: int, spec: str) -> np.random.Generator:
    """The generator handed to method ``spec`` on trial ``index`` of a scenario.

    Parameters
    ----------
    seed : int
        The scenario's seed.
    index : int
        Trial number.
    spec : str
        Method specification string; hashed with CRC-32 (stable across processes and
        runs, unlike Python's ``hash``).

    Returns
    -------
    numpy.random.Generator
        ``default_rng([seed, index, crc32(spec)])``.
    """
    return np.random.default_rng([seed, index, zlib.crc32(spec.encode("utf-8"))])


def run_trial(method, trial: Trial, grid: Grid, rng: np.random.Generator) -> TrialResult:
    """Run ``method`` on ``trial`` and measure its errors against the truth.

    Parameters
    ----------
    method : Matcher
        Any object with ``match(problem, rng) -> Fix``; its class attribute ``recursive``
        (False when absent) chooses whole-mission or leg-by-leg matching.
    trial : Trial
        The mission (truth, INS indication, measurements).
    grid : Grid
        The prior map.
    rng : numpy.random.Generator
        Randomness for the method (see :func:`method_rng`).

    Returns
    -------
    TrialResult
        Estimates and errors (metres), timing (seconds). A method raising
        :class:`~geofix.errors.GeofixError` gives a result with ``failed=True`` and the
        message; any other exception propagates.
    """
    runner = _run_recursive if getattr(method, "recursive", False) else _run_legs
    log = _CallLog(np.full((trial.n, 2), np.nan))
    try:
        runner(method, trial, grid, rng, log)
    except MemoryBudgetError:
        raise  # a refused size is the user's input, not the method failing on this trial
    except GeofixError as exc:
        log.message = str(exc) or type(exc).__name__
    return _result(trial, log)


@dataclass
class _CallLog:
    """What the calls to a method produced so far (mutable, private to one run)."""

    estimate: np.ndarray
    time_s: float = 0.0
    n_calls: int = 0
    evaluations: int = 0
    ambiguous: bool = False
    covariance: np.ndarray | None = None
    message: str | None = None

    def call(self, method, problem: MatchProblem, rng: np.random.Generator) -> Fix:
        """Time one ``match`` call and fold its fix into the log."""
        self.n_calls += 1
        start = time.perf_counter()
        try:
            fix = method.match(problem, rng)
        finally:
            self.time_s += time.perf_counter() - start
        self.evaluations += int(fix.evaluations)
        self.ambiguous |= bool(fix.ambiguous)
        self.covariance = None if fix.covariance is None else np.asarray(fix.covariance, float)
        return fix


def _run_recursive(method, trial: Trial, grid: Grid, rng, log: _CallLog) -> None:
    fix = log.call(method, trial.problem(grid), rng)
    log.estimate[:] = np.asarray(fix.track, dtype=float)


def _run_legs(method, trial: Trial, grid: Grid, rng, log: _CallLog) -> None:
    fix_end = fix_cov = None
    for part in trial.leg_slices():
        if fix_end is None:
            problem = trial.problem(grid, part)
        else:
            problem = reset_problem(trial, grid, part, fix_end, part.start - 1, fix_cov)
        fix = log.call(method, problem, rng)
        track = np.asarray(fix.track, dtype=float)
        log.estimate[part] = track
        fix_end, fix_cov = track[-1], fix.covariance


def reset_problem(
    trial: Trial,
    grid: Grid,
    part: slice,
    fix_end: np.ndarray,
    reset: int,
    fix_covariance: np.ndarray | None = None,
) -> MatchProblem:
    """The problem of samples ``part`` after resetting the INS to a fix.

    Parameters
    ----------
    trial : Trial
        The mission.
    grid : Grid
        The prior map.
    part : slice
        Samples of the leg to match.
    fix_end : numpy.ndarray
        ``(2,)`` position of the previous fix at sample ``reset``, metres.
    reset : int
        Sample at which the INS was reset (the last sample of the previous leg).
    fix_covariance : numpy.ndarray, optional
        ``(2, 2)`` covariance of the previous fix, m^2.

    Returns
    -------
    MatchProblem
        Indicated track ``fix_end + ins[part] - ins[reset]`` (metres) and prior 1-sigma
        ``sqrt(var_fix + max(sigma[part]**2 - sigma[reset]**2, 0))`` (metres), ``var_fix``
        from :func:`fix_variance`.
    """
    indicated = fix_end + (trial.indicated[part] - trial.indicated[reset])
    sigma = trial.sigma_position
    grown = np.maximum(sigma[part] ** 2 - sigma[reset] ** 2, 0.0)
    start = fix_variance(fix_covariance, grid.cell_size, float(sigma[reset]), float(sigma[0]))
    problem = trial.problem(grid, part, indicated=indicated)
    return dataclasses.replace(problem, sigma_position=np.sqrt(start + grown))


def fix_variance(covariance, cell_m: float, free_sigma: float, initial_sigma: float) -> float:
    """Per-axis prior variance a fix hands to the next leg, m^2.

    The larger eigenvalue of ``covariance`` (m^2), at least ``(cell_m / 2)^2`` (a matcher
    does not resolve a position within its cell) and at most ``free_sigma^2`` (the free
    INS's variance at the reset: a fix is never worse than no fix); ``initial_sigma^2``
    when the covariance is missing or not finite.

    Parameters
    ----------
    covariance : array_like or None
        ``(2, 2)`` covariance of the fix, m^2.
    cell_m : float
        Map cell size, metres.
    free_sigma : float
        1-sigma of the free INS at the reset, metres.
    initial_sigma : float
        1-sigma of the INS at the start, metres.
    """
    if covariance is None:
        return initial_sigma**2
    cov = np.asarray(covariance, dtype=float)
    if cov.shape != (2, 2) or not np.isfinite(cov).all():
        return initial_sigma**2
    largest = float(np.linalg.eigvalsh(0.5 * (cov + cov.T))[-1])
    return float(np.clip(largest, (0.5 * cell_m) ** 2, max(free_sigma**2, (0.5 * cell_m) ** 2)))


def _result(trial: Trial, log: _CallLog) -> TrialResult:
    error = np.hypot(*(log.estimate - trial.truth).T)
    ends = [part.stop - 1 for part in trial.leg_slices()]
    failed = log.message is not None
    nan = float("nan")
    return TrialResult(
        estimate=log.estimate,
        error=error,
        end_error_m=nan if failed else float(error[-1]),
        mean_track_error_m=nan if failed else float(error.mean()),
        max_track_error_m=nan if failed else float(error.max()),
        leg_errors_m=tuple(float(error[e]) for e in ends),
        time_s=float(log.time_s),
        n_calls=log.n_calls,
        ambiguous=log.ambiguous,
        covariance=log.covariance,
        evaluations=log.evaluations,
        failed=failed,
        message=log.message or "",
    )


#: A campaign task: a trial index and the ``(spec, method)`` pairs still to run on it.
Task = tuple[int, list[tuple[str, object]]]
#: What a task gives: its ``(spec, trial, result)`` triples and the trial's bounds.
Done = tuple[list[tuple[str, int, TrialResult]], TrialInfo]


@dataclass(frozen=True)
class TaskRunner:
    """Run a campaign's tasks: simulate the trial once, run its pending methods, bound it.

    Picklable (it is sent to local and Dask workers with the tasks).

    Parameters
    ----------
    simulate_trial : callable
        ``simulate_trial(scenario, grid, index) -> Trial``.
    scenario : Scenario
        The scenario (its seed seeds the methods' generators).
    valid_bound : bool
        Also compute each trial's valid-bound terms
        (:func:`geofix.evaluate.bounds.valid_bound_terms`).
    """

    simulate_trial: Callable
    scenario: Scenario
    valid_bound: bool = False

    def __call__(self, grid: Grid, task: Task, trial: Trial | None = None) -> Done:
        """Run one task on the prepared map.

        Parameters
        ----------
        grid : Grid
            The prepared map.
        task : tuple
            ``(index, [(spec, method), ...])``.
        trial : Trial, optional
            Trial ``index`` already simulated (used when its index matches).

        Returns
        -------
        tuple
            ``([(spec, index, TrialResult) per method], TrialInfo)``.
        """
        index, methods = task
        seed = self.scenario.seed
        if trial is None or trial.index != index:
            trial = self.simulate_trial(self.scenario, grid, index)
        _warm_up(methods, trial, grid, seed)
        done = [
            (spec, index, run_trial(method, trial, grid, method_rng(seed, index, spec)))
            for spec, method in methods
        ]
        return done, trial_info(self.scenario, grid, trial, self.valid_bound)


_WARMED: set[str] = set()


def _warm_up(methods, trial: Trial, grid: Grid, seed: int) -> None:
    """Run each method once, untimed, the first time this process meets it.

    Times per match then exclude one-time costs (lazy imports, compiled kernels loaded
    from the cache, first-touch allocations) that would otherwise land on whichever
    trial a worker happens to run first. Results are unaffected: every timed call gets
    its own freshly seeded generator.
    """
    for spec, method in methods:
        if spec not in _WARMED:
            run_trial(method, trial, grid, method_rng(seed, trial.index, spec))
            _WARMED.add(spec)
