"""Compiled loops of the point-mass grid: moments, support reach, log of a convolution.

Each kernel replaces a chain of small numpy calls on the ``(N0, N1)`` log-weights of
:mod:`geofix.filters._grid_ops` by one or two passes (the grid is a few thousand nodes, so
per-call overhead, not arithmetic, was the cost). Element-wise results are those of the
numpy expressions; sums run in row order instead of numpy's pairwise order, so moments
agree with the numpy reference to a few units in the last place (the tests compare them).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def grid_moments(log_weight, u, v):  # pragma: no cover - compiled
    """``(mu_u, mu_v, c_uu, c_uv, c_vv)`` of the normalised weights along the grid axes.

    ``u`` ``(N0,)`` and ``v`` ``(N1,)`` are the node coordinates, metres; the moments are
    those of ``w = exp(log_weight - max) / sum``: means and second central moments, m and
    m^2 (without the grid's resolution term).
    """
    n0, n1 = log_weight.shape
    top = log_weight.max()
    w = np.empty((n0, n1))
    total = 0.0
    for i in range(n0):
        for j in range(n1):
            e = np.exp(log_weight[i, j] - top)
            w[i, j] = e
            total += e
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
def log_of_convolved(p, log_weight, top, floor_shift, tiny):  # pragma: no cover - compiled
    """``max(log p, log_weight - top + floor_shift) + top`` (``log 0 = -inf``), element-wise."""
    out = np.empty_like(p)
    n0, n1 = p.shape
    for i in range(n0):
        for j in range(n1):
            floor = log_weight[i, j] - top + floor_shift
            q = p[i, j]
            lp = np.log(max(q, tiny)) if q > 0.0 else -np.inf
            out[i, j] = (lp if lp > floor else floor) + top
    return out


@numba.njit(cache=True, nogil=True)
def normalised(log_weight):  # pragma: no cover - compiled
    """``log_weight - (max + log(sum(exp(log_weight - max))))``: logsumexp = 0."""
    top = log_weight.max()
    flat = log_weight.ravel()
    total = 0.0
    for i in range(flat.size):
        total += np.exp(flat[i] - top)
    return log_weight - (top + np.log(total))


@numba.njit(cache=True, nogil=True)
def _correlate_axis(p, kernel, axis):  # pragma: no cover - compiled
    """``scipy.ndimage.correlate1d(p, kernel, axis, mode="constant")`` of a 2-D array.

    Each output sums ``kernel[t] * p[.. + t - half ..]`` over the taps that land inside
    the array, in increasing ``t`` (taps outside add nothing, so they are not visited):
    along axis 0 a tap at a time over whole contiguous rows, along axis 1 a contiguous
    window per element; the same additions in the same order either way.
    """
    n0, n1 = p.shape
    size = kernel.size
    half = size // 2
    out = np.zeros_like(p)
    if axis == 0:
        for i in range(n0):
            for t in range(max(0, half - i), min(size, n0 + half - i)):
                w = kernel[t]
                src = p[i + t - half]
                dst = out[i]
                for j in range(n1):
                    dst[j] += w * src[j]
    else:
        for i in range(n0):
            row = p[i]
            for j in range(n1):
                acc = 0.0
                for t in range(max(0, half - j), min(size, n1 + half - j)):
                    acc += kernel[t] * row[j + t - half]
                out[i, j] = acc
    return out


@numba.njit(cache=True, nogil=True)
def convolve_log(log_weight, k0, k1, tiny):  # pragma: no cover - compiled
    """The whole of :func:`geofix.filters._grid_ops.convolve_log` in one compiled call."""
    top = log_weight.max()
    p = np.exp(log_weight - top)
    p = _correlate_axis(_correlate_axis(p, k0, 0), k1, 1)
    shift = np.log(k0[k0.size // 2]) + np.log(k1[k1.size // 2])
    return normalised(log_of_convolved(p, log_weight, top, shift, tiny))
