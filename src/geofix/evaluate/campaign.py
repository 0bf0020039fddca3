"""Campaigns: every trial of a scenario with every method, in a process pool or on Dask.

The map is loaded and prepared once, in the calling process, and shipped once to each
worker (the pool's initializer, or a broadcast ``scatter`` on Dask). A task is one trial
index with the methods still to run on it, so each trial is simulated once per task.
Workers return results; the calling process writes them to the store as they complete, so
an interrupted campaign resumes where it stopped. The generator of method ``m`` on trial
``i`` depends only on ``(seed, i, m)``: the same command gives the same table whatever the
number of jobs or the scheduler (wall times aside).

Beside each trial's results the worker computes the trial's Cramér–Rao bounds
(:func:`geofix.evaluate.crlb.trial_crlb`) and keeps its true end point; both go to a side
table ``trial_bounds`` of the same SQLite file (older stores gain it, and its newer
columns, on first use, and trials resumed without them are filled in by the calling
process). They give the summary's ``crlb_m`` (error-state bound), ``crlb_track_m``,
``crlb_rw_m`` (random-walk bound) and ``crlb_batch_m``, and the Mahalanobis distance of
each end error used by the false-fix rule.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import multiprocessing
import os
import sqlite3
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import closing
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from geofix.errors import ConfigError, GeofixError
from geofix.evaluate.crlb import rms_bound, scenario_beam_variance, trial_crlb
from geofix.evaluate.metrics import end_mahalanobis, summarize
from geofix.evaluate.runner import TrialResult, method_rng, run_trial
from geofix.evaluate.store import ResultStore, scenario_hash
from geofix.maps.grid import Grid
from geofix.match.registry import parse_method_spec
from geofix.sim.scenario import Scenario

SUMMARY_NAME = "summary.json"

# (spec, method) pairs of one task, and what a task returns: its (spec, trial, result)
# triples and the trial's bounds.
_Task = tuple[int, list[tuple[str, object]]]


@dataclass(frozen=True)
class TrialInfo:
    """Per-trial facts stored beside the results.

    Parameters
    ----------
    index : int
        Trial number.
    crlb_var_m2 : float
        Trace of the error-state CRLB at the last sample, m^2.
    crlb_batch_var_m2 : float
        ``trace(J^-1)`` of the batch CRLB of the last leg, m^2 (``inf`` if singular).
    truth_end : tuple of float
        True position at the last sample, metres.
    crlb_track_var_m2 : float
        Trace of the error-state CRLB averaged along the track, m^2.
    crlb_rw_var_m2 : float
        Trace of the random-walk CRLB at the last sample, m^2.
    """

    index: int
    crlb_var_m2: float
    crlb_batch_var_m2: float
    truth_end: tuple[float, float]
    crlb_track_var_m2: float = float("nan")
    crlb_rw_var_m2: float = float("nan")


_Done = tuple[list[tuple[str, int, TrialResult]], TrialInfo]


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
    summary : dict
        ``{"scenario", "trials", "crlb_m", "crlb_track_m", "crlb_rw_m", "crlb_batch_m",
        "methods": {spec: stats}}`` (see :func:`geofix.evaluate.metrics.summarize`), as
        written to ``summary.json``. ``crlb_m`` is the error-state CRLB on the end-point
        RMS error over the trials, ``sqrt(mean_i trace(P_n))`` metres (variances
        averaged, then the root); ``crlb_track_m`` the same averaged over the samples as
        well (the bound on the track RMS); ``crlb_rw_m`` the random-walk bound on the
        end-point RMS; ``crlb_batch_m`` the same for a rigid batch fix of the last leg
        (None if singular on some trial). See :mod:`geofix.evaluate.crlb`.
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
    summary: dict
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
    progress: bool = True,
) -> CampaignResult:
    """Run every method on trials ``0 .. trials-1`` of a scenario, resuming stored work.

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
        Ignored when ``scheduler`` is given. Workers are started with the ``spawn``
        method: a script calling this with ``jobs > 1`` needs the usual
        ``if __name__ == "__main__":`` guard.
    out_dir : str or pathlib.Path
        Folder of ``results.sqlite`` and ``summary.json``.
    scheduler : str or object, optional
        A Dask scheduler address or cluster, handed to ``distributed.Client``.
    progress : bool
        Show a progress bar on stderr.

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
    """
    scenario = _override(scenario, trials, seed)
    parsed = _parse_methods(methods)
    jobs = _check_jobs(jobs)
    simulate = importlib.import_module("geofix.sim.simulate")
    grid = simulate.prepare_map(scenario)
    simulate.simulate_trial(scenario, grid, 0)
    shash = scenario_hash(scenario)
    out = Path(out_dir)
    with ResultStore(out) as store:
        tasks = _pending_tasks(parsed, scenario.trials, store.done_keys(shash))
        backend = _backend(jobs, scheduler, len(tasks))
        results = backend(simulate.simulate_trial, scenario, grid, tasks)
        computed = 0
        bounds = _open_bounds(store.path)
        with (
            closing(bounds),
            closing(results),
            _Bar(progress, scenario.name, sum(len(t[1]) for t in tasks)) as bar,
        ):
            for done, info in results:
                for spec, index, result in done:
                    store.record(scenario.name, shash, spec, index, result)
                _record_info(bounds, shash, info)
                bar.advance(len(done))
                computed += len(done)
            infos = _all_infos(bounds, shash, scenario, grid, simulate.simulate_trial)
        frame = _campaign_frame(store.to_frame(shash, arrays=True), list(parsed), scenario.trials)
    frame = _with_integrity(frame, infos)
    result = _finish(scenario, grid, frame, out, store.path, computed, infos)
    return dataclasses.replace(result, scenario_hash=shash)


def _override(scenario: Scenario, trials: int | None, seed: int | None) -> Scenario:
    update = {}
    if trials is not None:
        if int(trials) < 1:
            raise ConfigError(f"trials must be at least 1, got {trials}")
        update["trials"] = int(trials)
    if seed is not None:
        update["seed"] = int(seed)
    return scenario.model_copy(update=update) if update else scenario


def _parse_methods(methods: list[str]) -> dict[str, object]:
    if isinstance(methods, str) or not methods:
        raise ConfigError("give at least one method specification, as a list of strings")
    if len(set(methods)) != len(methods):
        raise ConfigError(f"method specifications repeated: {list(methods)}")
    return {spec: parse_method_spec(spec) for spec in methods}


def _pending_tasks(parsed: dict, trials: int, done: set) -> list[_Task]:
    tasks = []
    for index in range(trials):
        todo = [(spec, m) for spec, m in parsed.items() if (spec, index) not in done]
        if todo:
            tasks.append((index, todo))
    return tasks


def _campaign_frame(frame: pd.DataFrame, specs: list[str], trials: int) -> pd.DataFrame:
    frame = frame[frame["method"].isin(specs) & (frame["trial"] < trials)].copy()
    order = {spec: k for k, spec in enumerate(specs)}
    frame["_order"] = frame["method"].map(order)
    frame = frame.sort_values(["_order", "trial"], kind="stable").drop(columns="_order")
    return frame.reset_index(drop=True)


def _finish(scenario, grid, frame, out: Path, store_path: Path, computed: int, infos: dict):
    chosen = [infos[i] for i in range(scenario.trials)]
    summary = {
        "scenario": scenario.name,
        "trials": scenario.trials,
        "crlb_m": rms_bound([i.crlb_var_m2 for i in chosen]),
        "crlb_track_m": rms_bound([i.crlb_track_var_m2 for i in chosen]),
        "crlb_rw_m": rms_bound([i.crlb_rw_var_m2 for i in chosen]),
        "crlb_batch_m": rms_bound([i.crlb_batch_var_m2 for i in chosen]),
        "methods": summarize(frame, grid.cell_size),
    }
    summary_path = out / SUMMARY_NAME
    summary_path.write_text(json.dumps(summary, indent=2, allow_nan=False) + "\n")
    return CampaignResult(
        scenario=scenario.name,
        trials=scenario.trials,
        frame=frame,
        summary=summary,
        paths={"store": store_path, "summary": summary_path},
        computed=computed,
    )


# --------------------------------------------------------------------------- execution
def run_task(simulate_trial: Callable, scenario: Scenario, grid: Grid, task: _Task) -> _Done:
    """Simulate trial ``task[0]`` once and run each of its pending methods on it.

    Parameters
    ----------
    simulate_trial : callable
        ``simulate_trial(scenario, grid, index) -> Trial``.
    scenario : Scenario
        The scenario (its seed seeds the methods' generators).
    grid : Grid
        The prepared map.
    task : tuple
        ``(index, [(spec, method), ...])``.

    Returns
    -------
    tuple
        ``([(spec, index, TrialResult) per method], TrialInfo)``.
    """
    index, methods = task
    trial = simulate_trial(scenario, grid, index)
    _warm_up(methods, trial, grid, scenario.seed)
    done = [
        (spec, index, run_trial(method, trial, grid, method_rng(scenario.seed, index, spec)))
        for spec, method in methods
    ]
    return done, trial_info(scenario, grid, trial)


_WARMED: set[str] = set()


def _warm_up(methods, trial, grid: Grid, seed: int) -> None:
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


def trial_info(scenario: Scenario, grid: Grid, trial) -> TrialInfo:
    """The CRLBs (per-beam sensor plus map-error variance) and true end point of a trial."""
    bound = trial_crlb(trial, grid, scenario_beam_variance(scenario, trial.offsets))
    end = np.asarray(trial.truth[-1], dtype=float)
    return TrialInfo(
        trial.index,
        bound.recursive_var_m2,
        bound.batch_var_m2,
        (float(end[0]), float(end[1])),
        bound.track_var_m2,
        bound.rw_var_m2,
    )


# --------------------------------------------------------------------------- trial bounds
_BOUNDS_SCHEMA = """
CREATE TABLE IF NOT EXISTS trial_bounds (
    scenario_hash TEXT NOT NULL,
    trial INTEGER NOT NULL,
    crlb_var_m2 REAL,
    crlb_batch_var_m2 REAL,
    truth_end_x REAL NOT NULL,
    truth_end_y REAL NOT NULL,
    crlb_track_var_m2 REAL,
    crlb_rw_var_m2 REAL,
    PRIMARY KEY (scenario_hash, trial)
)
"""
_BOUNDS_COLUMNS = ("crlb_track_var_m2", "crlb_rw_var_m2")


def _open_bounds(store_path: Path) -> sqlite3.Connection:
    """A connection to the store's ``trial_bounds`` side table (created if missing)."""
    try:
        db = sqlite3.connect(store_path)
        db.execute(_BOUNDS_SCHEMA)
        have = {row[1] for row in db.execute("PRAGMA table_info(trial_bounds)")}
        for column in _BOUNDS_COLUMNS:
            if column not in have:  # a store of an earlier version: its rows are refilled
                db.execute(f"ALTER TABLE trial_bounds ADD COLUMN {column} REAL")
        db.commit()
    except sqlite3.Error as exc:
        raise GeofixError(f"cannot open results store {store_path}: {exc}") from None
    return db


def _record_info(db: sqlite3.Connection, shash: str, info: TrialInfo) -> None:
    row = (shash, info.index, info.crlb_var_m2, info.crlb_batch_var_m2, *info.truth_end)
    row += (info.crlb_track_var_m2, info.crlb_rw_var_m2)
    names = "scenario_hash, trial, crlb_var_m2, crlb_batch_var_m2, truth_end_x, truth_end_y, "
    names += ", ".join(_BOUNDS_COLUMNS)
    with db:
        db.execute(
            f"INSERT OR REPLACE INTO trial_bounds ({names}) VALUES ({', '.join('?' * 8)})", row
        )


def _all_infos(db: sqlite3.Connection, shash: str, scenario, grid, simulate_trial) -> dict:
    """Stored trial infos of a scenario, computing (and storing) those that are missing."""
    cur = db.execute(
        "SELECT trial, crlb_var_m2, crlb_batch_var_m2, truth_end_x, truth_end_y, "
        + ", ".join(_BOUNDS_COLUMNS)
        + " FROM trial_bounds WHERE scenario_hash = ?",
        (shash,),
    )
    infos = {
        int(t): TrialInfo(int(t), _real(v), _real(b), (float(x), float(y)), _real(tr), _real(rw))
        for t, v, b, x, y, tr, rw in cur
    }
    for index in range(scenario.trials):
        info = infos.get(index)
        if info is None or np.isnan([info.crlb_var_m2, info.crlb_rw_var_m2]).any():
            infos[index] = trial_info(scenario, grid, simulate_trial(scenario, grid, index))
            _record_info(db, shash, infos[index])
    return infos


def _real(value) -> float:
    return float("nan") if value is None else float(value)


def _with_integrity(frame: pd.DataFrame, infos: dict) -> pd.DataFrame:
    """Add ``end_mahalanobis``, ``crlb_m`` and ``track_ms_m2`` (mean squared error along the
    track, m^2); drop the per-sample array columns."""
    frame = frame.copy()
    ends = [np.asarray(infos[int(t)].truth_end) for t in frame["trial"]]
    frame["end_mahalanobis"] = [
        end_mahalanobis(est[-1] - end, cov)
        for est, end, cov in zip(frame["estimate"], ends, frame["covariance"], strict=True)
    ]
    frame["crlb_m"] = [float(np.sqrt(infos[int(t)].crlb_var_m2)) for t in frame["trial"]]
    frame["track_ms_m2"] = [float(np.mean(np.asarray(e, float) ** 2)) for e in frame["error"]]
    return frame.drop(columns=["estimate", "error", "covariance"])


def _check_jobs(jobs: int | None) -> int:
    jobs = (os.cpu_count() or 1) if jobs is None else int(jobs)
    if jobs < 1:
        raise ConfigError(f"jobs must be at least 1, got {jobs}")
    return jobs


def _backend(jobs: int, scheduler, n_tasks: int) -> Callable:
    if scheduler is not None:
        return lambda *args: _run_dask(scheduler, *args)
    if jobs == 1 or n_tasks <= 1:
        return _run_inline
    return lambda *args: _run_pool(min(jobs, n_tasks), *args)


def _run_inline(simulate_trial, scenario, grid, tasks) -> Iterator[_Done]:
    for task in tasks:
        yield run_task(simulate_trial, scenario, grid, task)


_WORKER_GRID: Grid | None = None


def _init_worker(grid: Grid) -> None:
    """Pool initializer: keep the map for every task of this worker; one numba thread."""
    global _WORKER_GRID
    _WORKER_GRID = grid
    import numba

    numba.set_num_threads(1)


def _pool_task(simulate_trial, scenario, task) -> _Done:
    return run_task(simulate_trial, scenario, _WORKER_GRID, task)


def _run_pool(jobs: int, simulate_trial, scenario, grid, tasks) -> Iterator[_Done]:
    context = multiprocessing.get_context("spawn")
    pool = ProcessPoolExecutor(jobs, context, initializer=_init_worker, initargs=(grid,))
    try:
        futures = [pool.submit(_pool_task, simulate_trial, scenario, task) for task in tasks]
        for future in as_completed(futures):
            yield future.result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _run_dask(scheduler, simulate_trial, scenario, grid, tasks) -> Iterator[_Done]:
    import distributed

    with distributed.Client(scheduler) as client:
        shared = client.scatter(grid, broadcast=True)
        futures = [
            client.submit(run_task, simulate_trial, scenario, shared, task, pure=False)
            for task in tasks
        ]
        try:
            for future in distributed.as_completed(futures):
                yield future.result()
        finally:
            client.cancel(futures)


class _Bar:
    """A rich progress bar on stderr counting (method, trial) results."""

    def __init__(self, enabled: bool, name: str, total: int) -> None:
        self._progress = Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeRemainingColumn(),
            console=Console(stderr=True),
            disable=not enabled,
        )
        self._task = self._progress.add_task(name, total=total)

    def __enter__(self) -> _Bar:
        self._progress.start()
        return self

    def __exit__(self, *exc) -> None:
        self._progress.stop()

    def advance(self, n: int) -> None:
        """Count ``n`` more results."""
        self._progress.advance(self._task, n)


# --------------------------------------------------------------------------- printing
def summary_table(summary: dict) -> Table:
    """A printable table of a campaign summary.

    Parameters
    ----------
    summary : dict
        As returned in :attr:`CampaignResult.summary`.

    Returns
    -------
    rich.table.Table
        One row per method: trials, failures, mean / std / median / max end-point error
        and mean along-track error (metres), success rates within 100 m, 1 cell and
        3 cells (%), mean time per ``match`` call (milliseconds).
    """
    title = f"{summary['scenario']}: {summary['trials']} trials, errors in metres"
    table = Table(title=title)
    table.add_column("method", style="bold", no_wrap=True)
    for head, _ in _TABLE_COLUMNS:
        table.add_column(head, justify="right")
    for spec, stats in summary["methods"].items():
        table.add_row(spec, *(cell(stats) for _, cell in _TABLE_COLUMNS))
    return table


def _fmt(value: float | None, digits: int = 1, scale: float = 1.0) -> str:
    return "-" if value is None else f"{scale * value:.{digits}f}"


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.0f}%"


_TABLE_COLUMNS = (
    ("trials", lambda s: str(s["trials"])),
    ("failed", lambda s: str(s["failures"])),
    ("mean", lambda s: _fmt(s["mean_error_m"])),
    ("std", lambda s: _fmt(s["std_error_m"])),
    ("median", lambda s: _fmt(s["median_error_m"])),
    ("max", lambda s: _fmt(s["max_error_m"])),
    ("track", lambda s: _fmt(s["mean_track_error_m"])),
    ("≤100 m", lambda s: _pct(s["success_rate"]["100"])),
    ("≤1 cell", lambda s: _pct(s["success_rate"]["1c"])),
    ("≤3 cells", lambda s: _pct(s["success_rate"]["3c"])),
    ("ms/call", lambda s: _fmt(s["mean_time_s"], 2, 1e3)),
)
