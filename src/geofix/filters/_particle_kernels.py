"""Compiled loops of the particle filters: the motion move, systematic resampling, ranges.

They give the very numbers of the numpy expressions they replace (element-wise the same
operations in the same order; the resampling indices by the same comparisons), without
the temporaries a few-thousand-particle step otherwise allocates.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def moved(particles, displacement, sd, draws):  # pragma: no cover - compiled
    """``particles + displacement + sd * draws`` (``(M, 2)``, metres), in numpy's order."""
    out = np.empty_like(particles)
    for i in range(particles.shape[0]):
        for c in range(particles.shape[1]):
            out[i, c] = (particles[i, c] + displacement[c]) + sd * draws[i, c]
    return out


@numba.njit(cache=True, nogil=True)
def systematic_indices(cumulative, u, count):  # pragma: no cover - compiled
    """``searchsorted(cumulative, (u + arange(count)) / count, side="right")``.

    The pointers increase, so one merge pass over ``cumulative`` finds them all.
    """
    out = np.empty(count, dtype=np.int64)
    i = 0
    n = cumulative.shape[0]
    for j in range(count):
        pointer = (u + j) / count
        while i < n and cumulative[i] <= pointer:
            i += 1
        out[j] = i
    return out


@numba.njit(cache=True, nogil=True)
def column_ranges(values):  # pragma: no cover - compiled
    """``np.ptp(values, axis=0)`` of finite ``(M, d)`` values, in one row-order pass."""
    low = values[0].copy()
    high = values[0].copy()
    for i in range(1, values.shape[0]):
        for c in range(values.shape[1]):
            v = values[i, c]
            if v < low[c]:
                low[c] = v
            elif v > high[c]:
                high[c] = v
    return high - low
