"""Compiled loops of the point-mass grid: moments, support reach, separable correlation.

Each kernel replaces a chain of small numpy calls on the ``(N0, N1)`` log-weights of
:mod:`geofix.filters._grid_ops` by one or two passes (the grid is a few thousand nodes, so
per-call overhead, not arithmetic, was the cost). Element-wise results are those of the
numpy expressions; sums run in row order instead of numpy's pairwise order, so moments
agree with the numpy reference to a few units in the last place (the tests compare them).
"""

from __future__ import annotations

import numba
import numpy as np

from geofix.maps.mapread import bilinear_at


@numba.njit(cache=True, nogil=True)
def weight_moments(weights, u, v):  # pragma: no cover - compiled
    """``(mu_u, mu_v, c_uu, c_uv, c_vv)`` of non-negative grid weights along the grid axes.

    ``weights`` ``(N0, N1)`` need not sum to one (they are divided by their sum; they are
    overwritten with the normalised ones); ``u`` ``(N0,)`` and ``v`` ``(N1,)`` are the node
    coordinates, metres. Means and second central moments, m and m^2 (without the grid's
    resolution term).
    """
    n0, n1 = weights.shape
    w = weights
    total = 0.0
    for i in range(n0):
        for j in range(n1):
            total += w[i, j]
    wu = np.zeros(n0)
    wv = np.zeros(n1)
    for i in range(n0):
        for j in range(n1):
            x = w[i, j] / total
            w[i, j] = x
            wu[i] += x
            wv[j] += x
    mu_u = 0.0
    for i in range(n0):
        mu_u += wu[i] * u[i]
    mu_v = 0.0
    for j in range(n1):
        mu_v += wv[j] * v[j]
    c_uu = 0.0
    for i in range(n0):
        c_uu += wu[i] * (u[i] - mu_u) ** 2
    c_vv = 0.0
    for j in range(n1):
        c_vv += wv[j] * (v[j] - mu_v) ** 2
    c_uv = 0.0
    for i in range(n0):
        row = 0.0
        for j in range(n1):
            row += w[i, j] * (v[j] - mu_v)
        c_uv += (u[i] - mu_u) * row
    return mu_u, mu_v, c_uu, c_uv, c_vv


@numba.njit(cache=True, nogil=True)
def support_reach(log_weight, threshold, centre, axes, u, v, point, directions):
    """``(2,)`` largest ``|(node - point) . directions[:, k]|``, metres.

    Over the nodes whose log-weight is at or above ``threshold``; node ``[i, j]`` sits at
    ``centre + u[i] axes[:, 0] + v[j] axes[:, 1]``.
    """
    out = np.zeros(2)  # pragma: no cover - compiled
    for i in range(u.shape[0]):
        for j in range(v.shape[0]):
            if not log_weight[i, j] >= threshold:
                continue
            x = centre[0] + u[i] * axes[0, 0] + v[j] * axes[0, 1] - point[0]
            y = centre[1] + u[i] * axes[1, 0] + v[j] * axes[1, 1] - point[1]
            for k in range(2):
                r = abs(x * directions[0, k] + y * directions[1, k])
                if r > out[k]:
                    out[k] = r
    return out


@numba.njit(cache=True, nogil=True)
def _correlate_rows(p, kernel):  # pragma: no cover - compiled
    """``scipy.ndimage.correlate1d(p, kernel, axis=0, mode="constant")`` of a 2-D array.

    Each output sums ``kernel[t] * p[i + t - half]`` over the taps that land inside the
    array, in increasing ``t`` (taps outside add nothing, so they are not visited), a tap
    at a time over whole contiguous rows: no loop carries a sum from one element to the
    next, so the inner loop vectorises.
    """
    n0, n1 = p.shape
    size = kernel.size
    half = size // 2
    out = np.zeros_like(p)
    for i in range(n0):
        dst = out[i]
        for t in range(max(0, half - i), min(size, n0 + half - i)):
            w = kernel[t]
            src = p[i + t - half]
            for j in range(n1):
                dst[j] += w * src[j]
    return out


@numba.njit(cache=True, nogil=True)
def correlate_separable(p, k0, k1):  # pragma: no cover - compiled
    """``correlate1d`` along axis 0 with ``k0``, then along axis 1 with ``k1``.

    The second pass runs on the transpose, so that it too goes a tap at a time over
    contiguous rows (along the rows themselves a tap's shifted index defeats
    vectorisation); each output's additions are in the same order either way.
    """
    rows = _correlate_rows(p, k0)
    return _correlate_rows(np.ascontiguousarray(rows.T), k1).T


@numba.njit(cache=True, nogil=True)
def resampled_log_density(log_density, old, new_centre, new_axes, u, v, fallback):
    """Log-density of a grid read at the nodes of another, ``(u.size, v.size)``.

    ``log_density`` ``(N0, N1)`` lies on the grid ``old`` = ``(centre (2,), axes (2, 2),
    spacing (2,))`` stacked as a ``(4, 2)`` array (centre, the two axis columns as rows,
    spacing); the new nodes sit at ``new_centre + u[i] new_axes[:, 0] + v[j] new_axes[:,
    1]``. Inside the old grid: its bilinear interpolant
    (:func:`geofix.maps.mapread.bilinear_at`, as ``scipy.ndimage.map_coordinates`` with
    ``order=1``); outside: ``min(fallback Gaussian, log_density.min())`` with
    ``fallback`` ``(4, 2)`` = mean, inverse covariance (two rows), ``(log normaliser, 0)``.
    """
    n0, n1 = log_density.shape  # pragma: no cover - compiled
    lowest = log_density.min()
    out = np.empty((u.shape[0], v.shape[0]))
    for i in range(u.shape[0]):
        for j in range(v.shape[0]):
            x = new_centre[0] + u[i] * new_axes[0, 0] + v[j] * new_axes[0, 1]
            y = new_centre[1] + u[i] * new_axes[1, 0] + v[j] * new_axes[1, 1]
            dx, dy = x - old[0, 0], y - old[0, 1]
            f0 = (dx * old[1, 0] + dy * old[1, 1]) / old[3, 0] + 0.5 * (n0 - 1)
            f1 = (dx * old[2, 0] + dy * old[2, 1]) / old[3, 1] + 0.5 * (n1 - 1)
            if 0.0 <= f0 <= n0 - 1 and 0.0 <= f1 <= n1 - 1:
                out[i, j] = bilinear_at(log_density, f1, f0)  # (column, row)
            else:
                ex, ey = x - fallback[0, 0], y - fallback[0, 1]
                quad = ex * (fallback[1, 0] * ex + fallback[1, 1] * ey)
                quad += ey * (fallback[2, 0] * ex + fallback[2, 1] * ey)
                out[i, j] = min(fallback[3, 0] - 0.5 * quad, lowest)
    return out
