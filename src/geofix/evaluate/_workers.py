"""Lifetime of campaign worker processes: they die with their parent; Ctrl-C is its own.

A worker of the local process pool calls :func:`bind_to_parent` from the pool's
initializer. Then

- on Linux, the kernel sends it ``SIGKILL`` when the parent dies, however it dies
  (``prctl(PR_SET_PDEATHSIG)``; armed already while the worker imports, see
  :mod:`geofix._lifetime`), and
- everywhere, a daemon thread polls the parent's pid and ends the worker within
  :data:`WATCHDOG_PERIOD_S` seconds once the parent is gone (the fallback where
  ``prctl`` is missing, and the guard against the race of a parent dying before the
  signal was armed);
- ``SIGINT`` is ignored: a Ctrl-C in the terminal reaches the whole process group, and
  the parent, which owns the store, stops the workers itself (:func:`stop_workers`)
  instead of every worker printing its own traceback. The parent starts its workers
  inside :func:`sigint_deferred`, so that they hold a Ctrl-C from their very first
  instruction (one while a worker still imports would otherwise print a traceback).
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time

from geofix._lifetime import announce_parent, arm_parent_death_signal

#: Seconds between two checks of the parent's pid by the watchdog thread.
WATCHDOG_PERIOD_S = 0.5


@contextlib.contextmanager
def sigint_deferred():
    """Block ``SIGINT`` in this thread for the duration; a Ctrl-C meanwhile comes after.

    Worker processes started now inherit the blocked signal, so a Ctrl-C while they still
    import stays pending in them until :func:`bind_to_parent` ignores it; in this process
    it is delivered (as KeyboardInterrupt) when the block ends. Starting a spawned worker
    can take seconds (its interpreter must start to read its arguments), so ignoring the
    signal instead would lose a Ctrl-C. A no-op where signal masks do not exist.
    """
    announce_parent()
    block = getattr(signal, "pthread_sigmask", None)
    if block is None:
        yield
        return
    previous = block(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        block(signal.SIG_SETMASK, previous)


def bind_to_parent(parent_pid: int) -> None:
    """Make this process end when process ``parent_pid`` ends; ignore Ctrl-C.

    Parameters
    ----------
    parent_pid : int
        Pid of the process that started this worker (``os.getpid()`` in the parent).
    """
    with contextlib.suppress(ValueError, OSError):  # not the main thread / no signals
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # discards a pending Ctrl-C
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    arm_parent_death_signal()
    if os.getppid() != parent_pid:
        os._exit(1)
    thread = threading.Thread(
        target=_watch_parent, args=(parent_pid,), name="geofix-parent-watchdog", daemon=True
    )
    thread.start()


def _watch_parent(parent_pid: int) -> None:
    while True:
        if os.getppid() != parent_pid:
            os._exit(1)
        time.sleep(WATCHDOG_PERIOD_S)


def stop_workers(pool) -> None:
    """Terminate the processes of a ``ProcessPoolExecutor`` now (after Ctrl-C or an error).

    Pending tasks are cancelled and running ones are abandoned: their results were never
    stored, so a rerun computes them again.
    """
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        with contextlib.suppress(Exception):
            process.terminate()
    for process in processes:
        with contextlib.suppress(Exception):
            process.join(timeout=5)
