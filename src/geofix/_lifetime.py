"""Worker processes die with their parent: the parent-death signal, armed at import.

A campaign's pool workers are started with the ``spawn`` method: a fresh interpreter that
imports geofix (and numpy, numba, ...) while it unpickles its task, which takes seconds.
To leave no worker behind when the parent is killed during that time, ``import geofix``
arms the parent-death signal first thing in such a process (``prctl(PR_SET_PDEATHSIG,
SIGKILL)`` on Linux) -- see :func:`arm_in_spawned_worker`. The rest (a watchdog thread,
ignoring Ctrl-C) is done by :mod:`geofix.evaluate._workers` once the worker runs.

Only the standard library is used here: this module is imported before anything else.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import signal
import sys

#: Environment variable holding the pid of the process that starts workers.
PARENT_PID_ENV = "GEOFIX_WORKER_PARENT_PID"
_PR_SET_PDEATHSIG = 1


def arm_parent_death_signal() -> bool:
    """Ask the kernel to SIGKILL this process when its parent dies (Linux only).

    Returns
    -------
    bool
        True when armed, False where ``prctl`` is not available.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        return libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def arm_in_spawned_worker() -> None:
    """Arm the parent-death signal if this process is a multiprocessing child starting up.

    A process that multiprocessing is bootstrapping (``spawn`` / ``forkserver``) after a
    geofix process announced itself in :data:`PARENT_PID_ENV` (:func:`announce_parent`)
    arms the signal, exits at once if that process is already gone, and then announces
    itself to its own children. Elsewhere: nothing.
    """
    try:
        from multiprocessing import process
    except ImportError:  # pragma: no cover - stripped-down interpreters
        return
    if not getattr(process.current_process(), "_inheriting", False):
        return
    expected = os.environ.get(PARENT_PID_ENV)
    if expected is None:
        return
    arm_parent_death_signal()
    if expected.isdigit() and not _alive(int(expected)):
        os._exit(1)  # the parent died before the signal was armed
    os.environ[PARENT_PID_ENV] = str(os.getpid())


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, owned by someone else
        return True
    return True


def announce_parent() -> None:
    """Mark this process as the parent of the workers it is about to start."""
    os.environ[PARENT_PID_ENV] = str(os.getpid())
