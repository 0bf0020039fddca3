"""Campaigns: every trial of a scenario with every method, in a process pool or on Dask.

The map is loaded and prepared once, in the calling process, stored in float32 when
that rounds no value by more than a hundredth of the sensor noise
(:mod:`geofix.evaluate._shared_map`; a metric netCDF map is read straight into float32,
block by block, never as a full float64 copy), and held once per machine: forked local
workers share the calling process's read-only pages, spawned ones map one read-only
shared-memory copy, Dask workers get it by one broadcast ``scatter``. Tasks
are submitted a few per worker at a time, so memory does not grow with the number of
trials. A task is one trial
index with the methods still to run on it, so each trial is simulated once per task. A
local worker receives its tasks in chunks of about :data:`CHUNK_TARGET_S` of measured
work (one task at first; never more than the tasks left over twice the workers), so that
quick trials do not spend their time in sending tasks and results: on 400 TERCOM trials
of about 4 ms, chunks took ``--jobs 2`` from 1.4x to 1.65-1.7x the speed of ``--jobs 1``.
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

Starting local workers (:func:`worker_start_method`): on Linux they are forked from the
calling process when that is safe -- no other Python thread runs, and numba's threading
layer is not started (``import geofix`` starts none) or is a fork-safe one (GNU OpenMP
is not) -- and spawned otherwise. Measured on the 40-trial TERCOM
benchmark (``benchmarks/bench_campaign.py``): a spawned worker spends seconds importing
geofix, numpy, pandas, numba and pydantic and loading its compiled kernels before its
first trial, longer than the whole campaign takes on one core, while a forked one starts
in milliseconds with all of that inherited; a forkserver would still import once and
its workers' parent is not the campaign's, which the parent-death watchdog relies on.
The pool is started before the first progress report (a progress bar may start a
thread). The start method does not change a result: every trial's generators depend
only on the seed, the trial and the method.
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import itertools
import json
import multiprocessing
import os
import sqlite3
import sys
import threading
import time
import warnings
from collections import Counter
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import closing
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from geofix import _threads
from geofix._atomic import write_text_atomic
from geofix.errors import ConfigError, GeofixError, GeofixWarning
from geofix.evaluate import _shared_map
from geofix.evaluate._workers import bind_to_parent, sigint_deferred, stop_workers
from geofix.evaluate.crlb import rms_bound, scenario_beam_variance, trial_crlb
from geofix.evaluate.metrics import end_mahalanobis, summarize
from geofix.evaluate.runner import TrialResult, method_rng, run_trial
from geofix.evaluate.store import STORE_NAME, ResultStore, scenario_hash, store_errors
from geofix.evaluate.summary import CampaignSummary
from geofix.maps.grid import Grid
from geofix.methods import parse_method_spec
from geofix.sim.scenario import Scenario, with_overrides

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
    jobs = _check_jobs(jobs)
    out = Path(out_dir)
    check_out_dir(out)
    simulate = importlib.import_module("geofix.sim.simulate")
    grid = campaign_map(scenario)
    check_methods_fit(parsed, simulate.simulate_trial(scenario, grid, 0))
    shash = scenario_hash(scenario)
    with store_errors(out / STORE_NAME), ResultStore(out) as store:
        done_keys = store.done_keys(shash)
        n_tasks, n_results = _pending_count(parsed, scenario.trials, done_keys)
        tasks = _pending_tasks(parsed, scenario.trials, done_keys)
        backend = _backend(jobs, scheduler, n_tasks)
        computed = 0
        report = progress or _no_progress
        total = n_results
        bounds = _open_bounds(store)
        # local workers start here, before the first report (a progress bar's thread)
        results = backend(simulate.simulate_trial, scenario, grid, tasks)
        with closing(results), _Batches(store) as batches:
            report(0, total)
            for done, info in results:
                for spec, index, result in done:
                    store.record(scenario.name, shash, spec, index, result, commit=False)
                _record_info(bounds, shash, info, commit=False)
                batches.recorded()
                computed += len(done)
                report(computed, total)
        infos = _all_infos(bounds, shash, scenario, grid, simulate.simulate_trial)
        frame = _campaign_frame(store.to_frame(shash, arrays=True), list(parsed), scenario.trials)
    frame = _with_integrity(frame, infos)
    result = _finish(scenario, grid, frame, out, store.path, computed, infos)
    return dataclasses.replace(result, scenario_hash=shash)


def campaign_map(scenario: Scenario) -> Grid:
    """The scenario's map as a campaign holds it (and simulates its trials on).

    Prepared once (:func:`geofix.sim.simulate.prepare_map`), read straight into float32
    where that rounds no value by more than a hundredth of the sensor noise, and stored
    so (:mod:`geofix.evaluate._shared_map`): ``simulate_trial(scenario, campaign_map(
    scenario), i)`` is the campaign's trial ``i``.
    """
    simulate = importlib.import_module("geofix.sim.simulate")
    noise = scenario.sensor.noise_std
    grid = simulate.prepare_map(scenario, _shared_map.float32_within(noise))
    return _shared_map.as_storage(grid, noise)


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
    for name in (SUMMARY_NAME, "results.sqlite"):
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


def _pending_tasks(parsed: dict, trials: int, done: set) -> Iterator[_Task]:
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


def _finish(scenario, grid, frame, out: Path, store_path: Path, computed: int, infos: dict):
    chosen = [infos[i] for i in range(scenario.trials)]
    summary = CampaignSummary(
        scenario=scenario.name,
        trials=scenario.trials,
        crlb_m=rms_bound([i.crlb_var_m2 for i in chosen]),
        crlb_batch_m=rms_bound([i.crlb_batch_var_m2 for i in chosen]),
        crlb_track_m=rms_bound([i.crlb_track_var_m2 for i in chosen]),
        crlb_rw_m=rms_bound([i.crlb_rw_var_m2 for i in chosen]),
        methods=summarize(frame, grid.cell_size),
    )
    summary_path = out / SUMMARY_NAME
    text = json.dumps(summary.to_json(), indent=2, allow_nan=False) + "\n"
    write_text_atomic(summary_path, text)  # whole or absent: a report never reads half
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


#: Longest time recorded results wait for their commit, seconds. A commit costs about
#: 0.3 ms in the calling process (as much as a tenth of a quick trial, on cores it shares
#: with the workers), so results are committed in batches; a campaign killed outright
#: loses at most this much work, which a rerun does again.
COMMIT_INTERVAL_S = 0.05


class _Batches:
    """Commit the store's open transaction every :data:`COMMIT_INTERVAL_S`, and on exit.

    On exit the batch is committed whatever ends the loop (the last result, Ctrl-C, a
    worker that died), so nothing recorded is lost.
    """

    def __init__(self, store: ResultStore) -> None:
        self.store = store
        self.last = time.perf_counter()

    def recorded(self) -> None:
        """Results were recorded: commit them if the last commit is old enough."""
        now = time.perf_counter()
        if now - self.last >= COMMIT_INTERVAL_S:
            self.store.commit()
            self.last = now

    def __enter__(self) -> _Batches:
        return self

    def __exit__(self, *exc) -> None:
        self.store.commit()


def _open_bounds(store: ResultStore) -> sqlite3.Connection:
    """The store's connection, its ``trial_bounds`` side table created if missing."""
    db = store.connection
    try:
        db.execute(_BOUNDS_SCHEMA)
        have = {row[1] for row in db.execute("PRAGMA table_info(trial_bounds)")}
        for column in _BOUNDS_COLUMNS:
            if column not in have:  # a store of an earlier version: its rows are refilled
                db.execute(f"ALTER TABLE trial_bounds ADD COLUMN {column} REAL")
        db.commit()
    except sqlite3.Error as exc:
        raise GeofixError(f"cannot open results store {store.path}: {exc}") from None
    return db


def _record_info(db: sqlite3.Connection, shash: str, info: TrialInfo, commit: bool = True) -> None:
    row = (
        shash,
        info.index,
        info.crlb_var_m2,
        info.crlb_batch_var_m2,
        *info.truth_end,
        info.crlb_track_var_m2,
        info.crlb_rw_var_m2,
    )
    names = "scenario_hash, trial, crlb_var_m2, crlb_batch_var_m2, truth_end_x, truth_end_y, "
    names += ", ".join(_BOUNDS_COLUMNS)
    db.execute(f"INSERT OR REPLACE INTO trial_bounds ({names}) VALUES ({', '.join('?' * 8)})", row)
    if commit:
        db.commit()


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


def _check_jobs(jobs: int | None) -> int:
    cores = usable_cores()
    if jobs is None:
        return cores
    jobs = int(jobs)
    if jobs < 1:
        raise ConfigError(f"jobs (--jobs) must be at least 1, got {jobs}")
    if jobs > cores:
        warnings.warn(
            f"--jobs {jobs} is more than the {cores} usable cores; using {cores}",
            GeofixWarning,
            stacklevel=3,
        )
        return cores
    return jobs


def usable_cores() -> int:
    """CPU cores this process may run on (its affinity mask where the system has one)."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _backend(jobs: int, scheduler, n_tasks: int) -> Callable:
    if scheduler is not None:
        return lambda *args: _run_dask(scheduler, *args)
    if jobs == 1 or n_tasks <= 1:
        return _run_inline
    workers = min(jobs, n_tasks)

    def pool(simulate_trial, scenario, grid, tasks):
        return _run_pool(workers, simulate_trial, scenario, grid, tasks, total=n_tasks)

    return pool


def _run_inline(simulate_trial, scenario, grid, tasks) -> Iterator[_Done]:
    for task in tasks:
        yield run_task(simulate_trial, scenario, grid, task)


_WORKER_GRID: Grid | None = None
# Tasks in flight per local worker: enough to keep every worker busy, few enough that
# memory does not grow with the number of trials.
_IN_FLIGHT_PER_WORKER = 4
#: Environment variable forcing how local workers start: ``spawn``, or ``fork`` (still
#: only where it is safe, see :func:`worker_start_method`). Unset: fork where safe.
START_METHOD_ENV = "GEOFIX_START_METHOD"
_START_METHODS = ("fork", "spawn")
_FORK_SAFE_NUMBA_LAYERS = ("workqueue", "tbb")


def worker_start_method() -> str:
    """How local campaign workers are started now: ``"fork"`` or ``"spawn"``.

    ``fork`` on Linux when no other Python thread runs and numba's threading layer is
    not started or is fork-safe (:func:`_fork_is_safe`), else ``spawn``. ``GEOFIX_START_METHOD
    =spawn`` always spawns.

    Raises
    ------
    ConfigError
        ``GEOFIX_START_METHOD`` is neither ``fork`` nor ``spawn``.
    """
    asked = os.environ.get(START_METHOD_ENV, "").strip().lower() or "fork"
    if asked not in _START_METHODS:
        raise ConfigError(f"{START_METHOD_ENV} must be one of {_START_METHODS}, got {asked!r}")
    if asked == "spawn" or not sys.platform.startswith("linux"):
        return "spawn"
    return "fork" if _fork_is_safe() else "spawn"


def _fork_is_safe() -> bool:
    """No other Python thread, and no numba thread pool that a fork would break.

    A fork copies only the calling thread: a lock another Python thread holds would stay
    held in the child. numba's ``omp`` layer (GNU OpenMP) once started in the parent
    -- by any parallel kernel run or loaded from the cache -- hangs the child's first
    parallel kernel, even on one thread (measured); ``workqueue`` and ``tbb`` are
    fork-safe. The native pools of OpenBLAS and jemalloc handle fork themselves.
    """
    if threading.active_count() > 1:
        return False
    parallel = sys.modules.get("numba.np.ufunc.parallel")
    if parallel is None or not getattr(parallel, "_is_initialized", False):
        return True
    try:
        return parallel.threading_layer() in _FORK_SAFE_NUMBA_LAYERS
    except ValueError:  # pragma: no cover - initialized means a layer was chosen
        return False


def _init_worker(source, parent_pid: int | None = None) -> None:
    """Pool initializer: die with the parent; take the map; one numba thread.

    ``source`` is the map itself in a forked worker (its pages shared with the parent,
    read-only) or a :class:`~geofix.evaluate._shared_map.SharedGridHandle` to map.
    """
    global _WORKER_GRID
    if parent_pid is not None:
        bind_to_parent(parent_pid)
    _WORKER_GRID = source if isinstance(source, Grid) else _shared_map.attach(source)
    _threads.use_serial_kernels()  # one thread per worker: no thread pool to start


def _pool_chunk(simulate_trial, scenario, chunk: list[_Task]) -> tuple[list[_Done], float]:
    """Run the tasks of a chunk in this worker: their results and the seconds they took."""
    grid = _WORKER_GRID
    if grid is None:  # pragma: no cover - _init_worker maps it in every worker
        raise RuntimeError("campaign worker has no map: its initializer did not run")
    start = time.perf_counter()
    done = [run_task(simulate_trial, scenario, grid, task) for task in chunk]
    return done, time.perf_counter() - start


#: Wanted duration of one chunk of tasks sent to a local worker, seconds: long enough
#: that sending the tasks and receiving their results (about 1 ms a future in the calling
#: process, which shares the cores with the workers) is a small part of it.
CHUNK_TARGET_S = 0.05
#: Most tasks in one chunk (a killed campaign loses at most the chunks in flight).
MAX_CHUNK = 32


class _Chunker:
    """Cut the task stream into chunks of about :data:`CHUNK_TARGET_S` of work.

    The first chunks hold one task; from then on the size follows the measured mean
    duration of a task in the workers, and never exceeds the tasks left over twice the
    workers (so that the last chunks still share out evenly). ``left`` is the number of
    tasks in the stream (None: unknown, no such cap).
    """

    def __init__(self, tasks: Iterator[_Task], left: int | None = None, jobs: int = 1) -> None:
        self.tasks = tasks
        self.left = left
        self.jobs = max(int(jobs), 1)
        self.count = 0
        self.seconds = 0.0

    def observe(self, count: int, seconds: float) -> None:
        """Record that ``count`` tasks took ``seconds`` in a worker."""
        self.count += count
        self.seconds += seconds

    def unpack(self, result: tuple[list[_Done], float]) -> list[_Done]:
        """The results of a finished chunk (:func:`_pool_chunk`), its duration recorded."""
        done, seconds = result
        self.observe(len(done), seconds)
        return done

    def size(self) -> int:
        """Tasks in the next chunk."""
        if self.count == 0 or self.seconds <= 0.0:
            return 1
        per_task = self.seconds / self.count
        size = min(MAX_CHUNK, max(1, int(CHUNK_TARGET_S / per_task + 1e-9)))
        if self.left is not None:
            size = min(size, max(1, self.left // (2 * self.jobs)))
        return size

    def next(self) -> list[_Task]:
        """The next chunk (empty when the tasks are exhausted)."""
        chunk = list(itertools.islice(self.tasks, self.size()))
        if self.left is not None:
            self.left -= len(chunk)
        return chunk


def _run_pool(
    jobs: int, simulate_trial, scenario, grid, tasks, total: int | None = None
) -> Iterator[_Done]:
    """Local worker processes sharing one read-only map; started now, results lazily."""
    results = _pool_results(jobs, simulate_trial, scenario, grid, tasks, total)
    next(results)  # workers start (and the first tasks go out) before any progress report
    return results


def _pool_results(
    jobs: int, simulate_trial, scenario, grid, tasks, total: int | None = None
) -> Iterator:
    """Yield None once the workers are started, then their results (bounded submission)."""
    method = worker_start_method()
    tasks = iter(tasks)
    first = None
    if method == "fork":
        first, method = _first_task_here(simulate_trial, scenario, grid, tasks)
    context = multiprocessing.get_context(method)
    with contextlib.ExitStack() as stack:
        if method == "fork":  # the workers inherit the map's pages: nothing to copy
            source = grid
        else:
            source = stack.enter_context(_shared_map.SharedGrid(grid, grid.values.dtype)).handle
        pool = ProcessPoolExecutor(
            jobs, context, initializer=_init_worker, initargs=(source, os.getpid())
        )
        finished = False
        try:

            def submit(chunk):
                with sigint_deferred():  # a worker started by this submit holds Ctrl-C
                    return pool.submit(_pool_chunk, simulate_trial, scenario, chunk)

            try:
                left = None if total is None else total - (first is not None)
                chunker = _Chunker(tasks, left, jobs)
                chunks = iter(chunker.next, [])  # sized as the results come in
                limit = jobs * _IN_FLIGHT_PER_WORKER
                results = _bounded(submit, chunks, limit, chunker.unpack)
                yield None
                if first is not None:
                    yield first
                yield from results
            except BrokenProcessPool:
                raise GeofixError(
                    "a worker process died (killed, or out of memory); finished trials are "
                    "stored: run the same command to resume"
                ) from None
            finished = True
        finally:
            if finished:
                pool.shutdown(wait=True)
            else:
                stop_workers(pool)


def _first_task_here(simulate_trial, scenario, grid, tasks: Iterator) -> tuple:
    """Run the first task in this process, serially, before forking: ``(done, method)``.

    The forked workers then inherit its loaded kernels and warmed-up methods instead of
    each loading them again (about 0.1 s a worker for TERCOM, as long as a dozen of its
    trials). ``method`` falls back to ``"spawn"`` should the run have left this process
    unsafe to fork; ``done`` is None when there is no task.
    """
    task = next(tasks, None)
    if task is None:
        return None, "fork"
    with _threads.serial_kernels_only():
        done = run_task(simulate_trial, scenario, grid, task)
    return done, "fork" if _fork_is_safe() else "spawn"


def _bounded(submit: Callable, works: Iterator, limit: int, unpack=None) -> Iterator:
    """Submit the first ``limit`` works now; then results as they complete (:func:`_drain`).

    At most ``limit`` futures are in flight. ``unpack`` turns a future's result into the
    results it stands for (a chunk's tasks); by default the result itself.
    """
    pending = {submit(work) for work in itertools.islice(works, limit)}
    return _drain(submit, works, pending, unpack)


def _drain(submit: Callable, works: Iterator, pending: set, unpack=None) -> Iterator:
    """Results of the ``pending`` futures as they complete, one new work per finished one."""
    while pending:
        finished, pending = wait(pending, return_when=FIRST_COMPLETED)
        for future in finished:
            results = [future.result()] if unpack is None else unpack(future.result())
            for work in itertools.islice(works, 1):
                pending.add(submit(work))
            yield from results


def _run_dask(scheduler, simulate_trial, scenario, grid, tasks) -> Iterator[_Done]:
    """Connect now (a bad address fails before the progress bar), then run lazily."""
    client = _dask_client(scheduler)
    return _dask_results(client, scheduler, simulate_trial, scenario, grid, tasks)


def _dask_results(client, scheduler, simulate_trial, scenario, grid, tasks) -> Iterator[_Done]:
    import distributed

    with _quiet_dask_logs(), client:
        try:
            shared = client.scatter(grid, broadcast=True)
            limit = _IN_FLIGHT_PER_WORKER * max(1, len(client.scheduler_info()["workers"]))
            tasks = iter(tasks)

            def submit(task):
                return client.submit(run_task, simulate_trial, scenario, shared, task, pure=False)

            running = distributed.as_completed([submit(t) for t in itertools.islice(tasks, limit)])
            try:
                for future in running:
                    for task in itertools.islice(tasks, 1):
                        running.add(submit(task))
                    yield future.result()
            finally:
                with contextlib.suppress(Exception):
                    client.cancel(list(running.futures))
        except _dask_lost_errors() as exc:
            raise GeofixError(
                f"Dask scheduler {_label(scheduler)} lost the campaign's workers "
                f"({type(exc).__name__}); finished trials are stored: rerun to resume"
            ) from None


#: Seconds to wait for a Dask scheduler (environment ``GEOFIX_DASK_TIMEOUT`` overrides).
DASK_CONNECT_TIMEOUT_S = 10.0


def _label(scheduler) -> str:
    return repr(scheduler) if isinstance(scheduler, str) else type(scheduler).__name__


@contextlib.contextmanager
def _quiet_dask_logs():
    """Silence Dask's own log records (reconnect tracebacks) while a campaign runs on it.

    A lost cluster is reported once, as a :class:`GeofixError`, by :func:`_dask_results`.
    """
    import logging

    names = [n for n in list(logging.root.manager.loggerDict) if n.startswith("distributed")]
    loggers = [logging.getLogger(n) for n in ["distributed", *names]]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.setLevel(level)


def _dask_client(scheduler):
    """A ``distributed.Client``; GeofixError in one line when it cannot connect."""
    import distributed

    try:
        timeout = float(os.environ.get("GEOFIX_DASK_TIMEOUT", DASK_CONNECT_TIMEOUT_S))
    except ValueError:
        timeout = DASK_CONNECT_TIMEOUT_S
    try:
        return distributed.Client(scheduler, timeout=timeout)
    except (OSError, ValueError, TypeError, TimeoutError) as exc:
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise GeofixError(f"cannot use Dask scheduler {_label(scheduler)}: {first}") from None


def _dask_lost_errors() -> tuple[type[BaseException], ...]:
    """Exceptions that mean the Dask cluster went away (not a trial's own error)."""
    import asyncio
    import concurrent.futures

    import distributed

    errors: list = [asyncio.CancelledError, concurrent.futures.CancelledError, OSError]
    errors += [getattr(distributed, n, None) for n in ("KilledWorker", "TimeoutError")]
    for module, name in (
        ("distributed.client", "FutureCancelledError"),
        ("distributed.comm.core", "CommClosedError"),
        ("distributed.scheduler", "KilledWorker"),
    ):
        errors.append(getattr(importlib.import_module(module), name, None))
    return tuple(e for e in errors if isinstance(e, type))
