"""Compiled kernels with and without numba's thread pool, and which of them a process runs.

A kernel compiled with ``parallel=True`` starts numba's threading layer the first time it
is loaded and run; with GNU OpenMP (numba's ``omp`` layer, its default where installed) a
process whose layer has started can no longer fork campaign workers safely. Every
parallel kernel therefore has a serial twin (:func:`twins`: the same Python source
compiled without ``parallel``, so ``prange`` is ``range``; the kernels here write each
output element from one iteration, so both give the same numbers bit for bit), run where
the pool is not wanted: in a campaign worker (one thread each), while a campaign runs its
first trial in the calling process before forking its workers (who then inherit the
loaded kernels instead of loading them again), and whenever ``NUMBA_NUM_THREADS=1``.
"""

from __future__ import annotations

import contextlib
import types
from collections.abc import Callable, Iterator

import numba

_serial_depth = 0
_serial_process = False


def _serial_kernels() -> bool:
    """True when compiled kernels should run on the calling thread only (see module)."""
    return _serial_process or _serial_depth > 0 or numba.config.NUMBA_NUM_THREADS == 1  # type: ignore[attr-defined]


def use_serial_kernels() -> None:
    """Run the serial twins in this process from now on (a campaign worker)."""
    global _serial_process
    _serial_process = True


@contextlib.contextmanager
def serial_kernels_only() -> Iterator[None]:
    """Run the serial twins while the block runs."""
    global _serial_depth
    _serial_depth += 1
    try:
        yield
    finally:
        _serial_depth -= 1


def twins(py_func: Callable, signatures=None, **flags) -> tuple[Callable, Callable]:
    """``(parallel, serial)`` compiled kernels of one Python function.

    Parameters
    ----------
    py_func : callable
        The kernel's Python source (loops over ``numba.prange``).
    signatures : list, optional
        Eager signatures, handed to ``numba.njit``.
    **flags
        Other ``numba.njit`` options (``cache=True``...), for both kernels.

    Notes
    -----
    The serial twin is a copy of ``py_func`` under the qualified name
    ``<name>_serial``, so that numba's on-disk cache keeps the two compilations in
    separate files.
    """
    serial = types.FunctionType(
        py_func.__code__,
        py_func.__globals__,
        f"{py_func.__name__}_serial",
        py_func.__defaults__,
        py_func.__closure__,
    )
    serial.__qualname__ = f"{py_func.__qualname__}_serial"
    serial.__doc__ = py_func.__doc__
    serial.__module__ = py_func.__module__
    args = () if signatures is None else (signatures,)
    return (
        numba.njit(*args, parallel=True, **flags)(py_func),
        numba.njit(*args, **flags)(serial),
    )


def pick(kernels: tuple[Callable, Callable]) -> Callable:
    """The twin of ``kernels`` (from :func:`twins`) this process should run now."""
    return kernels[1] if _serial_kernels() else kernels[0]
