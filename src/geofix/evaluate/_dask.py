"""A campaign on a Dask cluster: the map broadcast once, tasks a few per worker at a time.

The map goes to every worker by one broadcast ``scatter``; results come back as they
finish and are stored by the calling process, so an interrupted campaign resumes the
same way as a local one. A cluster that goes away ends the campaign with one
:class:`~geofix.errors.GeofixError` (Dask's own log records silenced meanwhile).
"""

from __future__ import annotations

import contextlib
import importlib
import itertools
import os
from collections.abc import Generator, Iterator

from geofix.errors import GeofixError
from geofix.evaluate._pool import IN_FLIGHT_PER_WORKER
from geofix.evaluate.runner import Done, Task, TaskRunner
from geofix.maps.grid import Grid

#: Seconds to wait for a Dask scheduler (environment ``GEOFIX_DASK_TIMEOUT`` overrides).
DASK_CONNECT_TIMEOUT_S = 10.0


def run_dask(
    scheduler, runner: TaskRunner, grid: Grid, tasks: Iterator[Task]
) -> Generator[Done, None, None]:
    """Connect now (a bad address fails before the progress bar), then run lazily.

    Parameters
    ----------
    scheduler : str or object
        A Dask scheduler address or cluster, handed to ``distributed.Client``.
    runner : TaskRunner
        Runs one task (sent to the workers).
    grid : Grid
        The prepared map.
    tasks : iterator
        The tasks, made one at a time.

    Raises
    ------
    GeofixError
        The scheduler cannot be reached.
    """
    client = _dask_client(scheduler)
    return _dask_results(client, scheduler, runner, grid, tasks)


def _dask_results(client, scheduler, runner, grid, tasks) -> Generator[Done, None, None]:
    import distributed

    with _quiet_dask_logs(), client:
        try:
            shared = client.scatter(grid, broadcast=True)
            limit = IN_FLIGHT_PER_WORKER * max(1, len(client.scheduler_info()["workers"]))
            tasks = iter(tasks)

            def submit(task):
                return client.submit(runner, shared, task, pure=False)

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
