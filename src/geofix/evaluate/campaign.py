"""Campaigns: every trial of a scenario with every method, in a process pool or on Dask.

:func:`run_campaign` checks the methods, the output folder and trial 0 before anything
runs, prepares the map once in the calling process (:func:`campaign_map`), hands the
tasks still to do -- one trial index with the methods still to run on it, so each trial
is simulated once for all of them (:class:`~geofix.evaluate.runner.TaskRunner`) -- to an
executor, and writes the results to the store (:mod:`geofix.evaluate.store`) as they
complete, so an interrupted campaign resumes where it stopped. The executors: this
process (``jobs=1``), the local process pool (:mod:`geofix.evaluate._pool`) or a Dask
cluster (:mod:`geofix.evaluate._dask`). The generator of method ``m`` on trial ``i``
depends only on ``(seed, i, m)``: the same command gives the same table whatever the
number of jobs or the scheduler (wall times aside).

Beside each trial's results the worker computes the trial's bounds
(:func:`geofix.evaluate.bounds.trial_info`: the Cramér–Rao bounds, and the valid bound's
terms when asked) and keeps its true end point; they go to the store's ``trial_bounds``
table (trials resumed without them are filled in by the calling process). They give the
summary's ``crlb_m`` (error-state bound), ``crlb_track_m``, ``crlb_rw_m`` (random-walk
bound), ``crlb_batch_m``, ``valid_bound_m`` and ``valid_bound_track_m``, and the
Mahalanobis distance of each end error used by the false-fix rule.
"""

from __future__ import annotations

import dataclasses
import os
from collections import Counter
from collections.abc import Callable, Generator, Iterator
from contextlib import closing
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from geofix.errors import ConfigError, GeofixError
from geofix.evaluate._dask import run_dask
from geofix.evaluate._pool import (  # noqa: F401 - also importable from here
    START_METHOD_ENV,
    check_jobs,
    run_pool,
    usable_cores,
    worker_start_method,
)
from geofix.evaluate._shared_map import campaign_map
from geofix.evaluate.bounds import TrialInfo, crlb_summary, trial_info, valid_bound
from geofix.evaluate.metrics import end_mahalanobis, summarize
from geofix.evaluate.runner import Done, Task, TaskRunner
from geofix.evaluate.store import (
    STORE_NAME,
    SUMMARY_NAME,
    Batches,
    ResultStore,
    scenario_hash,
    store_errors,
    write_summary,
)
from geofix.evaluate.summary import CampaignSummary
from geofix.maps.grid import Grid
from geofix.methods import parse_method_spec
from geofix.sim.scenario import Scenario, with_overrides
from geofix.sim.simulate import simulate_trial
from geofix.sim.trial import Trial


@dataclass
class CampaignResult:
    """The outcome of :func:`run_campaign`.

    Parameters
    ----------
    scenario : str
        Scenario name.
    trials : int
        Number of trials (indices ``0 .. trials-1``).
    frame : pandas.DataFrame
        One row per (method, trial), methods in the order given, trials ascending (see
        :meth:`geofix.evaluate.store.ResultStore.to_frame` for the columns), plus
        ``end_mahalanobis`` (end error against the method's last covariance, NaN
        without one) and ``crlb_m`` (the trial's recursive bound, metres).
    summary : CampaignSummary
        The bounds and every method's :class:`~geofix.evaluate.summary.MethodStats`;
        ``summary.to_json()`` is what ``summary.json`` holds. ``crlb_m`` is the
        error-state CRLB on the end-point RMS error over the trials,
        ``sqrt(mean_i trace(P_n))`` metres (variances averaged, then the root);
        ``crlb_track_m`` the same averaged over the samples as well (the bound on the
        track RMS); ``crlb_rw_m`` the random-walk bound on the end-point RMS;
        ``crlb_batch_m`` the same for a rigid batch fix of the last leg (None if singular
        on some trial). See :mod:`geofix.evaluate.crlb`.
    paths : dict
        ``{"store": results.sqlite, "summary": summary.json}``.
    computed : int
        Number of (method, trial) results computed by this call (the rest were resumed).
    scenario_hash : str
        Key of the scenario's rows in the store (per-sample arrays for plots:
        ``ResultStore(out_dir).to_frame(scenario_hash, arrays=True)``).
    """

    scenario: str
    trials: int
    frame: pd.DataFrame
    summary: CampaignSummary
    paths: dict = field(default_factory=dict)
    computed: int = 0
    scenario_hash: str = ""


def run_campaign(
    scenario: Scenario,
    methods: list[str],
    trials: int | None = None,
    seed: int | None = None,
    jobs: int | None = None,
    out_dir: str | Path = "out",
    scheduler=None,
    progress: Callable[[int, int], None] | None = None,
    valid_bound: bool = False,
) -> CampaignResult:
    """Run every method on the first ``trials`` trials of a scenario, resuming stored work.

    Parameters
    ----------
    scenario : Scenario
        The mission family.
    methods : list of str
        Method specifications (``"tercom:metric=mad"``); each is a key of the summary,
        exactly as given.
    trials, seed : int, optional
        Override the scenario's number of trials and seed.
    jobs : int, optional
        Local worker processes (default: the number of CPUs); 1 runs in this process.
        Ignored when ``scheduler`` is given. Workers are forked where that is safe
        (Linux, see :func:`worker_start_method`), else spawned: a script calling this
        with ``jobs > 1`` needs the usual ``if __name__ == "__main__":`` guard.
    out_dir : str or pathlib.Path
        Folder of ``results.sqlite`` and ``summary.json``.
    scheduler : str or object, optional
        A Dask scheduler address or cluster, handed to ``distributed.Client``.
    progress : callable, optional
        Called as ``progress(done, total)`` with the number of (method, trial) results
        computed so far and to compute in this call: once before the first, then after
        each (:class:`geofix.console.ProgressBar` draws a bar on the terminal).
    valid_bound : bool
        Also compute every trial's valid bound (the larger of the error-state CRLB, the
        Ziv–Zakai bound and the genie's MMSE under the simulator's prior of the start
        error, :mod:`geofix.evaluate.bounds`; far costlier than the CRLBs), store it and
        summarise it as ``valid_bound_m`` and ``valid_bound_track_m``.

    Returns
    -------
    CampaignResult
        The results table and its summary (errors in metres, times in seconds).

    Raises
    ------
    GeofixError
        Before any trial runs and before the store is created: an unknown or badly set
        method (ConfigError), a missing or unusable map (MapError), a track leaving the
        map on trial 0 (TrackOffMapError).

    Examples
    --------
    >>> import tempfile
    >>> import geofix
    >>> scen = geofix.load_scenario("builtin:azores_demo")
    >>> out = tempfile.mkdtemp()
    >>> result = geofix.run_campaign(scen, ["tercom", "pmf"], trials=2, jobs=1, out_dir=out)
    >>> list(result.summary.methods), result.summary.trials
    (['tercom', 'pmf'], 2)
    >>> result.summary.methods["tercom"].success_rate["3c"] is not None
    True
    """
    scenario = with_overrides(scenario, trials, seed)
    parsed = _parse_methods(methods)
    jobs = check_jobs(jobs)
    out = Path(out_dir)
    check_out_dir(out)
    grid = campaign_map(scenario)
    first = simulate_trial(scenario, grid, 0)
    check_methods_fit(parsed, first)
    runner = TaskRunner(simulate_trial, scenario, valid_bound)
    shash = scenario_hash(scenario)
    with store_errors(out / STORE_NAME), ResultStore(out) as store:
        done_keys = store.done_keys(shash)
        n_tasks, total = _pending_count(parsed, scenario.trials, done_keys)
        tasks = _pending_tasks(parsed, scenario.trials, done_keys)
        computed = 0
        report = progress or _no_progress
        store.open_bounds()
        # local workers start here, before the first report (a progress bar's thread)
        results = _executor(jobs, scheduler, n_tasks)(runner, grid, tasks, first)
        with closing(results), Batches(store) as batches:
            report(0, total)
            for done, info in results:
                for spec, index, result in done:
                    store.record(scenario.name, shash, spec, index, result, commit=False)
                store.record_bounds(shash, info, commit=False)
                batches.recorded()
                computed += len(done)
                report(computed, total)
        infos = _all_infos(store, shash, runner, grid, first)
        frame = _campaign_frame(store.to_frame(shash, arrays=True), list(parsed), scenario.trials)
    frame = _with_integrity(frame, infos)
    result = _finish(scenario, grid, frame, out, store.path, computed, infos, valid_bound)
    return dataclasses.replace(result, scenario_hash=shash)


def _no_progress(done: int, total: int) -> None:
    """The default progress report: none."""


def check_out_dir(out: Path) -> None:
    """Refuse an output folder the campaign could not finish in, before any trial runs.

    Raises
    ------
    GeofixError
        ``out`` is a file, ``out/summary.json`` or ``out/results.sqlite`` is a folder, or
        ``out`` (or the nearest existing parent) is not writable.
    """
    if out.exists() and not out.is_dir():
        raise GeofixError(f"--out {out} is a file, not a folder")
    for name in (SUMMARY_NAME, STORE_NAME):
        if (out / name).is_dir():
            raise GeofixError(f"{out / name} is a folder; remove it or choose another --out")
    existing = next((p for p in (out, *out.parents) if p.exists()), None)
    if existing is not None and not os.access(existing, os.W_OK | os.X_OK):
        raise GeofixError(f"--out {out}: cannot write in {existing} (permission denied)")


def check_methods_fit(parsed: dict[str, object], trial) -> None:
    """Refuse a method that cannot work with the scenario's sensor (e.g. ICP on one beam).

    A method class may declare ``min_beams`` (a ``ClassVar``): the fewest beams per
    sample it needs.

    Raises
    ------
    ConfigError
        Naming the method, what it needs and what the sensor gives.
    """
    beams = int(np.asarray(trial.offsets).shape[0])
    for spec, method in parsed.items():
        need = int(getattr(method, "min_beams", 1))
        if beams < need:
            raise ConfigError(
                f"method {spec!r} needs a sensor with at least {need} beams per sample "
                f"(a multibeam swath); the scenario's {trial.sensor} gives {beams}"
            )


def _parse_methods(methods: list[str]) -> dict[str, object]:
    if isinstance(methods, str) or not methods:
        raise ConfigError("give at least one method specification, as a list of strings")
    if len(set(methods)) != len(methods):
        raise ConfigError(f"method specifications repeated: {list(methods)}")
    return {spec: parse_method_spec(spec) for spec in methods}


def _pending_tasks(parsed: dict, trials: int, done: set) -> Iterator[Task]:
    """The tasks still to run, made one at a time (memory does not grow with ``trials``)."""
    for index in range(trials):
        todo = [(spec, m) for spec, m in parsed.items() if (spec, index) not in done]
        if todo:
            yield index, todo


def _pending_count(parsed: dict, trials: int, done: set) -> tuple[int, int]:
    """``(tasks, results)`` still to compute: trials with a pending method, and pairs."""
    per_trial = Counter(index for spec, index in done if spec in parsed and index < trials)
    results = trials * len(parsed) - sum(per_trial.values())
    full = sum(1 for count in per_trial.values() if count == len(parsed))
    return trials - full, results


def _campaign_frame(frame: pd.DataFrame, specs: list[str], trials: int) -> pd.DataFrame:
    frame = frame[frame["method"].isin(specs) & (frame["trial"] < trials)].copy()
    order = {spec: k for k, spec in enumerate(specs)}
    frame["_order"] = frame["method"].map(order)
    frame = frame.sort_values(["_order", "trial"], kind="stable").drop(columns="_order")
    return frame.reset_index(drop=True)


def _finish(scenario, grid, frame, out: Path, store_path, computed: int, infos, valid: bool):
    chosen = [infos[i] for i in range(scenario.trials)]
    end, track = valid_bound(chosen) if valid else (None, None)
    crlb = crlb_summary(chosen)
    summary = CampaignSummary(
        scenario=scenario.name,
        trials=scenario.trials,
        crlb_m=crlb["crlb_m"],
        crlb_batch_m=crlb["crlb_batch_m"],
        crlb_track_m=crlb["crlb_track_m"],
        crlb_rw_m=crlb["crlb_rw_m"],
        valid_bound_m=end,
        valid_bound_track_m=track,
        methods=summarize(frame, grid.cell_size),
    )
    summary_path = write_summary(out, summary.to_json())
    return CampaignResult(
        scenario=scenario.name,
        trials=scenario.trials,
        frame=frame,
        summary=summary,
        paths={"store": store_path, "summary": summary_path},
        computed=computed,
    )


def _all_infos(store: ResultStore, shash: str, runner: TaskRunner, grid: Grid, first) -> dict:
    """Stored trial infos of a scenario, computing (and storing) those that are missing."""
    infos = store.trial_bounds(shash)
    scenario = runner.scenario
    for index in range(scenario.trials):
        info = infos.get(index)
        if info is None or _incomplete(info, runner.valid_bound):
            trial = first if index == 0 else runner.simulate_trial(scenario, grid, index)
            infos[index] = trial_info(scenario, grid, trial, runner.valid_bound)
            store.record_bounds(shash, infos[index])
    return infos


def _incomplete(info: TrialInfo, valid: bool) -> bool:
    """The stored info lacks a bound (a store of an earlier version, or not asked then)."""
    missing = np.isnan([info.crlb_var_m2, info.crlb_rw_var_m2]).any()
    return bool(missing or (valid and not info.has_valid_bound))


def _with_integrity(frame: pd.DataFrame, infos: dict) -> pd.DataFrame:
    """Add each trial's integrity and bound columns; drop the per-sample array columns.

    ``end_mahalanobis``, ``crlb_m`` and ``track_ms_m2`` (mean squared error along the
    track, m^2).
    """
    frame = frame.copy()
    ends = [np.asarray(infos[int(t)].truth_end) for t in frame["trial"]]
    frame["end_mahalanobis"] = [
        end_mahalanobis(est[-1] - end, cov)
        for est, end, cov in zip(frame["estimate"], ends, frame["covariance"], strict=True)
    ]
    frame["crlb_m"] = [float(np.sqrt(infos[int(t)].crlb_var_m2)) for t in frame["trial"]]
    frame["track_ms_m2"] = [float(np.mean(np.asarray(e, float) ** 2)) for e in frame["error"]]
    return frame.drop(columns=["estimate", "error", "covariance"])


def _executor(jobs: int, scheduler, n_tasks: int) -> Callable[..., Generator[Done, None, None]]:
    """``execute(runner, grid, tasks, first_trial)``: the local pool, Dask or this process."""
    if scheduler is not None:
        return lambda runner, grid, tasks, first: run_dask(scheduler, runner, grid, tasks)
    if jobs == 1 or n_tasks <= 1:
        return _run_inline
    workers = min(jobs, n_tasks)
    return lambda runner, grid, tasks, first: run_pool(workers, runner, grid, tasks, n_tasks, first)


def _run_inline(runner: TaskRunner, grid: Grid, tasks, first: Trial | None) -> Generator:
    """Run the tasks in this process, one after the other."""
    for task in tasks:
        yield runner(grid, task, first)


def _run_dask(scheduler, simulate, scenario: Scenario, grid: Grid, tasks) -> Iterator[Done]:
    """:func:`geofix.evaluate._dask.run_dask` of the tasks, trials from ``simulate``."""
    return run_dask(scheduler, TaskRunner(simulate, scenario), grid, tasks)
