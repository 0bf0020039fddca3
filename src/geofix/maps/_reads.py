"""Compiled bilinear map reads for many hypotheses times many beams.

The reads of :func:`geofix.filters.measurement.predict_measurements`: every hypothesis
``i`` at fractional cell ``(row[i], col[i])`` and every beam ``j`` offset by
``(orow[j], ocol[j])`` cells reads the map bilinearly; NaN outside ``[0, n - 1]`` along
either axis and wherever a cell of the stencil is NaN (the rule of
:meth:`geofix.maps.grid.Grid.sample` and of ``scipy.ndimage.map_coordinates`` with
``order=1, mode="constant", cval=nan``). One loop in compiled code instead of a
``(2, m * b)`` coordinate array: several times faster on a converged point-mass grid
read by a multibeam ping, and no temporary arrays.
"""

from __future__ import annotations

import numba
import numpy as np

_VEC = numba.types.Array(numba.float64, 1, "C", readonly=True)
_SIGNATURE = numba.float64[:, :](
    numba.types.Array(numba.float64, 2, "C", readonly=True), _VEC, _VEC, _VEC, _VEC
)


@numba.njit(_SIGNATURE, cache=True)
def _reads(values, row, col, orow, ocol):  # pragma: no cover - compiled
    ny, nx = values.shape
    out = np.empty((row.shape[0], orow.shape[0]))
    for i in range(row.shape[0]):
        for j in range(orow.shape[0]):
            r = row[i] + orow[j]
            c = col[i] + ocol[j]
            if not (r >= 0.0 and c >= 0.0 and r <= ny - 1 and c <= nx - 1):
                out[i, j] = np.nan
                continue
            r0 = min(int(r), ny - 2)
            c0 = min(int(c), nx - 2)
            fr = r - r0
            fc = c - c0
            out[i, j] = (values[r0, c0] * (1.0 - fc) + values[r0, c0 + 1] * fc) * (1.0 - fr) + (
                values[r0 + 1, c0] * (1.0 - fc) + values[r0 + 1, c0 + 1] * fc
            ) * fr
    return out


def bilinear_reads(values, row, col, orow, ocol) -> np.ndarray:
    """``(m, b)`` bilinear reads of ``values`` at ``(row[i] + orow[j], col[i] + ocol[j])``.

    Parameters
    ----------
    values : numpy.ndarray
        ``(ny, nx)`` map values (NaN = no data).
    row, col : numpy.ndarray
        ``(m,)`` fractional cell indices of the hypotheses.
    orow, ocol : numpy.ndarray
        ``(b,)`` beam offsets, cells.
    """

    def vec(a):
        a = np.ascontiguousarray(a, dtype=np.float64)
        a.setflags(write=False)
        return a

    grid = np.ascontiguousarray(values, dtype=np.float64)
    if grid.flags.writeable:
        grid = grid.copy()
        grid.setflags(write=False)
    return _reads(grid, vec(row), vec(col), vec(orow), vec(ocol))


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
    """``(mean(d0^2) + mean(d1^2)) / 12`` over finite neighbour differences of the
    measured beams of ``predicted`` ``(N0, N1, b)`` (see
    :func:`geofix.filters.pmf.node_field_variance`)."""
    p = np.ascontiguousarray(predicted, dtype=np.float64)
    p.setflags(write=False)
    y = np.ascontiguousarray(measured, dtype=np.float64)
    y.setflags(write=False)
    return float(_node_field_variance(p, y))
