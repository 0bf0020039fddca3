"""Lifetime of campaign worker processes: they die with their parent, and Ctrl-C is the
parent's business.

A worker of the local process pool calls :func:`bind_to_parent` from the pool's
initializer. Then

- on Linux, the kernel sends it ``SIGKILL`` when the parent dies, however it dies
  (``prctl(PR_SET_PDEATHSIG)``), and
- everywhere, a daemon thread polls the parent's pid and ends the worker within
  :data:`WATCHDOG_PERIOD_S` seconds once the parent is gone (the fallback where
  ``prctl`` is missing, and the guard against the race of a parent dying before the
  signal was armed);
- ``SIGINT`` is ignored: a Ctrl-C in the terminal reaches the whole process group, and
  the parent, which owns the store, stops the workers itself (:func:`stop_workers`)
  instead of every worker printing its own traceback.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import os
import signal
import sys
import threading
import time

#: Seconds between two checks of the parent's pid by the watchdog thread.
WATCHDOG_PERIOD_S = 0.5
_PR_SET_PDEATHSIG = 1


def bind_to_parent(parent_pid: int) -> None:
    """Make this process end when process ``parent_pid`` ends; ignore Ctrl-C.

    Parameters
    ----------
    parent_pid : int
        Pid of the process that started this worker (``os.getpid()`` in the parent).
    """
    with contextlib.suppress(ValueError, OSError):  # not the main thread / no signals
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    _arm_parent_death_signal()
    if os.getppid() != parent_pid:
        os._exit(1)
    thread = threading.Thread(
        target=_watch_parent, args=(parent_pid,), name="geofix-parent-watchdog", daemon=True
    )
    thread.start()


def _arm_parent_death_signal() -> bool:
    """``prctl(PR_SET_PDEATHSIG, SIGKILL)`` on Linux; False where it is not available."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        return libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


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
