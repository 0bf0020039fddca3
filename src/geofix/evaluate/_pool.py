"""The local process pool of a campaign: start method, worker set-up, chunks, submission.

Starting local workers (:func:`worker_start_method`): on Linux they are forked from the
calling process when that is safe -- no other Python thread runs, and numba's threading
layer is not started (``import geofix`` starts none) or is a fork-safe one (GNU OpenMP
is not) -- and spawned otherwise. A spawned worker imports geofix, numpy, pandas, numba
and pydantic and loads its compiled kernels before its first trial, which can take
longer than a whole small campaign on one core (``benchmarks/bench_campaign.py``
measures it), while a forked one starts at once with all of that inherited; a
forkserver would still import once and its workers' parent is not the campaign's, which
the parent-death watchdog (:mod:`geofix.evaluate._workers`) relies on. The start method
does not change a result: every trial's generators depend only on the seed, the trial
and the method.

The map is held once per machine: forked workers share the calling process's read-only
pages, spawned ones map one read-only shared-memory copy
(:mod:`geofix.evaluate._shared_map`). Tasks are submitted a few per worker at a time, so
memory does not grow with the number of trials, in chunks of about
:data:`CHUNK_TARGET_S` of measured work (one task at first; never more than the tasks
left over twice the workers), so that quick trials do not spend their time in sending
tasks and results.
"""

from __future__ import annotations

import contextlib
import itertools
import multiprocessing
import os
import sys
import threading
import time
import warnings
from collections.abc import Callable, Generator, Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool

from geofix import _threads
from geofix.errors import ConfigError, GeofixError, GeofixWarning
from geofix.evaluate import _shared_map
from geofix.evaluate._workers import bind_to_parent, sigint_deferred, stop_workers
from geofix.evaluate.runner import Done, Task, TaskRunner
from geofix.maps.grid import Grid
from geofix.sim.trial import Trial

#: Tasks in flight per worker: enough to keep every worker busy, few enough that memory
#: does not grow with the number of trials.
IN_FLIGHT_PER_WORKER = 4
#: Environment variable forcing how local workers start: ``spawn``, or ``fork`` (still
#: only where it is safe, see :func:`worker_start_method`). Unset: fork where safe.
START_METHOD_ENV = "GEOFIX_START_METHOD"
_START_METHODS = ("fork", "spawn")
_FORK_SAFE_NUMBA_LAYERS = ("workqueue", "tbb")
#: Wanted duration of one chunk of tasks sent to a local worker, seconds: long enough
#: that sending the tasks and receiving their results (work of the calling process,
#: which shares the cores with the workers) is a small part of it.
CHUNK_TARGET_S = 0.05
#: Most tasks in one chunk (a killed campaign loses at most the chunks in flight).
MAX_CHUNK = 32

_WORKER_GRID: Grid | None = None


def check_jobs(jobs: int | None) -> int:
    """The number of local workers to use: ``jobs``, at most :func:`usable_cores`.

    None gives the usable cores; more than them warns (at the caller of the caller)
    and gives the usable cores.

    Raises
    ------
    ConfigError
        ``jobs`` is below 1.
    """
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
    parallel kernel, even on one thread; ``workqueue`` and ``tbb`` are fork-safe. The
    native pools of OpenBLAS and jemalloc handle fork themselves.
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


def _pool_chunk(runner: TaskRunner, chunk: list[Task]) -> tuple[list[Done], float]:
    """Run the tasks of a chunk in this worker: their results and the seconds they took."""
    grid = _WORKER_GRID
    if grid is None:  # pragma: no cover - _init_worker maps it in every worker
        raise RuntimeError("campaign worker has no map: its initializer did not run")
    start = time.perf_counter()
    done = [runner(grid, task) for task in chunk]
    return done, time.perf_counter() - start


class Chunker:
    """Cut the task stream into chunks of about :data:`CHUNK_TARGET_S` of work.

    The first chunks hold one task; from then on the size follows the measured mean
    duration of a task in the workers, and never exceeds the tasks left over twice the
    workers (so that the last chunks still share out evenly).

    Parameters
    ----------
    tasks : iterator
        The tasks.
    left : int, optional
        The number of tasks in the stream (None: unknown, no such cap).
    jobs : int
        The number of workers.
    """

    def __init__(self, tasks: Iterator[Task], left: int | None = None, jobs: int = 1) -> None:
        self.tasks = tasks
        self.left = left
        self.jobs = max(int(jobs), 1)
        self.count = 0
        self.seconds = 0.0

    def observe(self, count: int, seconds: float) -> None:
        """Record that ``count`` tasks took ``seconds`` in a worker."""
        self.count += count
        self.seconds += seconds

    def unpack(self, result: tuple[list[Done], float]) -> list[Done]:
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

    def next(self) -> list[Task]:
        """The next chunk (empty when the tasks are exhausted)."""
        chunk = list(itertools.islice(self.tasks, self.size()))
        if self.left is not None:
            self.left -= len(chunk)
        return chunk


def run_pool(
    jobs: int,
    runner: TaskRunner,
    grid: Grid,
    tasks: Iterator[Task],
    total: int | None = None,
    first_trial: Trial | None = None,
) -> Generator[Done, None, None]:
    """Local worker processes sharing one read-only map; started now, results lazily.

    Parameters
    ----------
    jobs : int
        Worker processes.
    runner : TaskRunner
        Runs one task.
    grid : Grid
        The prepared map.
    tasks : iterator
        The tasks, made one at a time.
    total : int, optional
        The number of tasks (caps the chunks near the end).
    first_trial : Trial, optional
        A trial the calling process has already simulated (reused when the task run
        here before forking is its trial).

    Returns
    -------
    iterator
        The tasks' results as they complete; the workers are started (and the first
        tasks sent) before this returns.
    """
    results = _pool_results(jobs, runner, grid, tasks, total, first_trial)
    next(results)  # workers start (and the first tasks go out) before any progress report
    return results


def _pool_results(jobs: int, runner, grid, tasks, total=None, first_trial=None) -> Generator:
    """Yield None once the workers are started, then their results (bounded submission)."""
    method = worker_start_method()
    tasks = iter(tasks)
    first = None
    if method == "fork":
        first, method = _first_task_here(runner, grid, tasks, first_trial)
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
                    return pool.submit(_pool_chunk, runner, chunk)

            try:
                left = None if total is None else total - (first is not None)
                chunker = Chunker(tasks, left, jobs)
                chunks = iter(chunker.next, [])  # sized as the results come in
                limit = jobs * IN_FLIGHT_PER_WORKER
                results = bounded(submit, chunks, limit, chunker.unpack)
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


def _first_task_here(runner, grid, tasks: Iterator, first_trial=None) -> tuple:
    """Run the first task in this process, serially, before forking: ``(done, method)``.

    The forked workers then inherit its loaded kernels and warmed-up methods instead of
    each loading them again. ``method`` falls back to ``"spawn"`` should the run have
    left this process unsafe to fork; ``done`` is None when there is no task.
    """
    task = next(tasks, None)
    if task is None:
        return None, "fork"
    with _threads.serial_kernels_only():
        done = runner(grid, task, first_trial)
    return done, "fork" if _fork_is_safe() else "spawn"


def bounded(submit: Callable, works: Iterator, limit: int, unpack=None) -> Iterator:
    """Submit the first ``limit`` works now; then results as they complete (:func:`_drain`).

    At most ``limit`` futures are in flight. ``unpack`` turns a future's result into the
    results it stands for (a chunk's tasks); by default the result itself.

    Parameters
    ----------
    submit : callable
        ``submit(work) -> Future``.
    works : iterator
        The works to submit.
    limit : int
        Most futures in flight.
    unpack : callable, optional
        ``unpack(result) -> list of results``.
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
