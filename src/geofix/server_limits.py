"""The limits of ``geofix serve``: connections, bytes, sizes, memory, time, log lines.

:class:`ServerLimits` holds the settings (each with a default, listed in the README's
server section); :class:`MemoryLedger` keeps the server's memory under the budget across
connections; :class:`UpdateWorkers` runs the updates off the event loop; :class:`RateLog`
writes one line per cause of trouble and counts the repeats instead of writing them.
"""

from __future__ import annotations

import concurrent.futures
import os
import queue
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from geofix.errors import ConfigError, MemoryBudgetError
from geofix.memory import format_bytes, memory_budget_bytes

MAX_LINE_BYTES = 1 << 20
"""Longest request line, bytes (1 MiB: about 30 000 beams of three numbers)."""


@dataclass(frozen=True)
class ServerLimits:
    """Limits of one server (defaults in brackets).

    Parameters
    ----------
    max_connections : int
        Connections served at once (256); one more gets an error line and is closed.
    max_line_bytes : int
        Longest request line, bytes (1 MiB); a longer line, newline or not, gets an error
        line and the connection is closed, so no connection buffers more than this.
    max_points : int
        Most particles or grid nodes of one connection's filter (4 000 000), whatever the
        memory budget allows.
    workers : int
        Threads running updates (4): one connection's update runs on one of them, so a
        heavy connection holds one thread and the others answer the rest.
    heavy_points : int
        A connection whose filter may hold more points than this (250 000, above the
        defaults of ``pf`` and ``pmf``) is heavy: its updates run on their own
        ``heavy_workers`` threads at a lower scheduling priority (``heavy_nice``), so on a
        busy machine the ordinary connections' updates go first.
    heavy_workers : int
        Threads running the heavy connections' updates (2).
    heavy_nice : int
        Niceness added to those threads (10; where the system allows per-thread
        priorities, Linux).
    update_timeout_s : float
        Time budget of one update, seconds (60): an update still running after it gets an
        error reply, and the connection starts again from a new navigator (``init``).
    memory_bytes : int or None
        The server's memory budget, bytes (None: :func:`geofix.memory.memory_budget_bytes`,
        ``--memory-budget``): every connection's filter state and line buffer plus the
        temporaries of the ``workers + heavy_workers`` largest updates stay below it.
    log_interval_s : float
        A log line's cause is written once per this many seconds (10); the repeats in
        between are counted in the next line.
    """

    max_connections: int = 256
    max_line_bytes: int = MAX_LINE_BYTES
    max_points: int = 4_000_000
    workers: int = 4
    heavy_points: int = 250_000
    heavy_workers: int = 2
    heavy_nice: int = 10
    update_timeout_s: float = 60.0
    memory_bytes: int | None = None
    log_interval_s: float = 10.0

    def __post_init__(self) -> None:
        for name in (
            "max_connections",
            "max_line_bytes",
            "max_points",
            "workers",
            "heavy_points",
            "heavy_workers",
        ):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ConfigError(f"server: {name} must be a positive integer, got {value!r}")
        if isinstance(self.heavy_nice, bool) or not isinstance(self.heavy_nice, int):
            raise ConfigError(f"server: heavy_nice must be an integer, got {self.heavy_nice!r}")
        for name in ("update_timeout_s", "log_interval_s"):
            if not 0 < float(getattr(self, name)) < float("inf"):
                raise ConfigError(f"server: {name} must be positive and finite")

    def budget(self) -> int:
        """The memory budget, bytes."""
        return memory_budget_bytes() if self.memory_bytes is None else int(self.memory_bytes)


@dataclass
class _Reservation:
    state: float
    update: float


@dataclass
class MemoryLedger:
    """The memory promised to connections, checked against one budget.

    Each connection holds a reservation: its filter's state and line buffer, kept for
    the connection's life, and its update's temporaries, which exist only while one of
    the ``workers`` threads runs it. The total is the sum of the states plus the
    ``workers`` largest update sizes: the most that can be in use at any moment.
    """

    budget: float
    workers: int
    _held: dict[int, _Reservation] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def total(self, held: dict[int, _Reservation] | None = None) -> float:
        """Bytes promised: states plus the ``workers`` largest updates."""
        held = self._held if held is None else held
        updates = sorted((r.update for r in held.values()), reverse=True)[: self.workers]
        return sum(r.state for r in held.values()) + sum(updates)

    def reserve(self, key: int, state: float, update: float, what: str) -> None:
        """Hold ``state`` + ``update`` bytes for ``key`` (replacing what it held).

        Parameters
        ----------
        key : int
            The holder (a connection's id).
        state : float
            Bytes held for the holder's life (its filter's state and line buffer).
        update : float
            Bytes of one update's temporaries (counted among the ``workers`` largest).
        what : str
            What the memory is for, named in the error message.

        Raises
        ------
        MemoryBudgetError
            The total would exceed the budget; ``key`` keeps what it held.
        """
        with self._lock:
            trial = {**self._held, key: _Reservation(float(state), float(update))}
            need = self.total(trial)
            if not need <= self.budget:
                left = max(self.budget - self.total(), 0.0)
                raise MemoryBudgetError(
                    f"{what} would need {format_bytes(state + update)}; the server's memory "
                    f"budget {format_bytes(self.budget)} has {format_bytes(left)} left"
                )
            self._held = trial

    def release(self, key: int) -> None:
        """Drop ``key``'s reservation."""
        with self._lock:
            self._held.pop(key, None)

    def holders(self) -> int:
        """Reservations held."""
        return len(self._held)


class UpdateWorkers:
    """A fixed number of daemon threads running submitted calls in submission order.

    Unlike :class:`concurrent.futures.ThreadPoolExecutor`, the interpreter does not wait
    for a running update when the server stops (its threads are daemons).
    """

    def __init__(self, count: int, name: str = "geofix-update", nice: int = 0) -> None:
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._nice = int(nice)
        self._threads = [
            threading.Thread(target=self._run, name=f"{name}-{i}", daemon=True)
            for i in range(count)
        ]
        for thread in self._threads:
            thread.start()

    def submit(self, fn: Callable, *args) -> concurrent.futures.Future:
        """Run ``fn(*args)`` on a worker; its future."""
        future: concurrent.futures.Future = concurrent.futures.Future()
        self._jobs.put((future, fn, args))
        return future

    def shutdown(self) -> None:
        """Stop taking jobs; queued ones are cancelled, running ones left to finish."""
        for _ in self._threads:
            self._jobs.put(None)

    def _run(self) -> None:
        if self._nice:
            _lower_thread_priority(self._nice)
        while True:
            job = self._jobs.get()
            if job is None:
                return
            future, fn, args = job
            if not future.set_running_or_notify_cancel():
                continue
            try:
                future.set_result(fn(*args))
            except BaseException as exc:  # handed to the waiting connection
                future.set_exception(exc)


def _lower_thread_priority(nice: int) -> None:
    """Add ``nice`` to the calling thread's niceness (Linux: threads have their own)."""
    try:
        tid = threading.get_native_id()
        now = os.getpriority(os.PRIO_PROCESS, tid)
        os.setpriority(os.PRIO_PROCESS, tid, min(now + nice, 19))
    except (AttributeError, OSError):
        pass  # no per-thread priority here: the threads still keep the loop free


class RateLog:
    """One log line per cause, at most once per ``interval_s``; repeats are counted.

    Parameters
    ----------
    interval_s : float
        Least time between two lines of one cause, seconds.
    write : callable, optional
        Writes one line (default: standard error, flushed).
    """

    def __init__(self, interval_s: float = 10.0, write: Callable[[str], None] | None = None):
        self.interval_s = float(interval_s)
        self._write = write or _stderr_line
        self._last: dict[str, float] = {}
        self._quiet: dict[str, int] = {}
        self._lock = threading.Lock()

    def __call__(self, cause: str, detail: str = "") -> None:
        """Log ``cause: detail`` unless ``cause`` was logged within the interval."""
        now = time.monotonic()
        with self._lock:
            last = self._last.get(cause)
            if last is not None and now - last < self.interval_s:
                self._quiet[cause] = self._quiet.get(cause, 0) + 1
                return
            self._last[cause] = now
            repeats = self._quiet.pop(cause, 0)
        more = f" ({repeats} more since the last such line)" if repeats else ""
        text = f"{cause}: {detail}" if detail else cause
        self._write(" ".join(f"geofix serve: {text}{more}".split()))


def _stderr_line(line: str) -> None:
    try:
        sys.stderr.write(line + "\n")
        sys.stderr.flush()
    except (OSError, ValueError):  # a closed or full stderr must not stop the server
        pass


FD_RESERVE = 16
"""File descriptors kept free beside the connections (map files, a refused socket, logs)."""


def descriptor_headroom() -> int | None:
    """Connections the file-descriptor limit leaves room for (None: no limit known).

    The soft ``RLIMIT_NOFILE`` minus the descriptors open now minus :data:`FD_RESERVE`.
    """
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    except (ImportError, OSError, ValueError):
        return None
    if soft == resource.RLIM_INFINITY:
        return None
    try:
        used = len(os.listdir("/proc/self/fd"))
    except OSError:
        used = 32
    return max(1, int(soft) - used - FD_RESERVE)


def describe_os_error(exc: BaseException) -> str:
    """``"EMFILE Too many open files"`` for an OSError; the type name otherwise."""
    if isinstance(exc, OSError) and exc.errno is not None:
        import errno

        code = errno.errorcode.get(exc.errno, str(exc.errno))
        return f"{code} {exc.strerror or os.strerror(exc.errno)}"
    return type(exc).__name__
