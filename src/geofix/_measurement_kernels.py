"""Compiled sums of the measurement model: log-likelihoods and node field variance.

The Gaussian log-likelihood of many hypotheses, and the point-mass grid's field variance
between neighbouring nodes.

Used by :mod:`geofix.measurement` and :mod:`geofix.filters.pmf`; each has a numpy
reference in the tests. The map reads themselves are :mod:`geofix.maps.mapread`.
"""

from __future__ import annotations

import numba
import numpy as np

_VEC = numba.types.Array(numba.float64, 1, "C", readonly=True)
_LL_SIGNATURE = numba.float64[:](
    numba.types.Array(numba.float64, 2, "C", readonly=True), _VEC, _VEC, numba.float64
)


@numba.njit(_LL_SIGNATURE, cache=True)
def _log_likelihood(predicted, measured, var, off_map):  # pragma: no cover - compiled
    out = np.zeros(predicted.shape[0])
    for i in range(predicted.shape[0]):
        acc = 0.0
        for j in range(measured.shape[0]):
            if measured[j] != measured[j]:
                continue
            d = predicted[i, j] - measured[j]
            term = -0.5 * d * d / var[j]
            acc += term if np.isfinite(term) else off_map
        out[i] = acc
    return out


def gaussian_log_likelihood(predicted, measured, var, off_map: float) -> np.ndarray:
    """``(m,)`` sum over the finite ``measured`` beams of ``-0.5 (p - y)^2 / var``.

    A beam whose term is not finite (a NaN prediction: off the map) adds ``off_map``.
    ``predicted`` is ``(m, b)``, ``measured`` and ``var`` ``(b,)``.
    """
    p = np.ascontiguousarray(predicted, dtype=np.float64)
    p.setflags(write=False)
    y = np.ascontiguousarray(measured, dtype=np.float64)
    y.setflags(write=False)
    v = np.ascontiguousarray(np.broadcast_to(np.asarray(var, dtype=np.float64), y.shape))
    v.setflags(write=False)
    return _log_likelihood(p, y, v, float(off_map))


_NFV_SIGNATURE = numba.float64(numba.types.Array(numba.float64, 3, "C", readonly=True), _VEC)


@numba.njit(_NFV_SIGNATURE, cache=True)
def _node_field_variance(p, measured):  # pragma: no cover - compiled
    n0, n1, b = p.shape
    total = 0.0
    for axis in range(2):
        acc = 0.0
        count = 0
        for i in range(n0 - (1 if axis == 0 else 0)):
            for j in range(n1 - (1 if axis == 1 else 0)):
                for k in range(b):
                    if measured[k] != measured[k]:
                        continue
                    nxt = p[i + 1, j, k] if axis == 0 else p[i, j + 1, k]
                    d = nxt - p[i, j, k]
                    if d == d and np.isfinite(d):
                        acc += d * d
                        count += 1
        if count:
            total += acc / count
    return total / 12.0


def node_field_variance_kernel(predicted, measured) -> float:
    """Field variance between neighbouring nodes of a point-mass grid.

    ``(mean(d0^2) + mean(d1^2)) / 12`` over finite neighbour differences of the measured
    beams of ``predicted`` ``(N0, N1, b)`` (see :func:`geofix.filters.pmf.node_field_variance`).
    """
    p = np.ascontiguousarray(predicted, dtype=np.float64)
    p.setflags(write=False)
    y = np.ascontiguousarray(measured, dtype=np.float64)
    y.setflags(write=False)
    return float(_node_field_variance(p, y))
