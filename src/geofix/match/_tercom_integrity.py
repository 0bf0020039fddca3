"""Moments of the TERCOM pseudo-likelihood over the cost surface, in one compiled pass.

The weight of candidate ``(j, k)`` is ``exp(-factor * (cost[j, k] - best))`` (zero for
NaN or infinite costs), normalised over the surface; the fix covariance is the weighted
spread of the candidate offsets around their weighted mean, and the ambiguity mass the
weight farther than ``radius`` from the best candidate. Only candidates whose weight is
non-zero in double precision are visited twice.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def surface_moments(cost, best, factor, ox, oy, j_best, k_best, radius):  # pragma: no cover
    """``(mean_x, mean_y, cxx, cyy, cxy, far_mass)`` of the normalised weights.

    Parameters
    ----------
    cost : numpy.ndarray
        ``(J, K)`` cost surface (NaN / inf = no weight).
    best : float
        Lowest finite cost.
    factor : float
        ``samples / scale`` of the pseudo-likelihood.
    ox, oy : numpy.ndarray
        ``(K,)`` and ``(J,)`` candidate offsets, metres.
    j_best, k_best : int
        Indices of the best candidate.
    radius : float
        Exclusion radius, metres.
    """
    n_rows, n_cols = cost.shape
    keep_j = np.empty(cost.size, dtype=np.int64)
    keep_k = np.empty(cost.size, dtype=np.int64)
    keep_w = np.empty(cost.size)
    count = 0
    total = sx = sy = 0.0
    for j in range(n_rows):
        dy = oy[j] - oy[j_best]
        for k in range(n_cols):
            c = cost[j, k]
            if c != c or c == np.inf:
                continue
            w = np.exp(-factor * (c - best))
            if w == 0.0:
                continue
            dx = ox[k] - ox[k_best]
            keep_j[count], keep_k[count], keep_w[count] = j, k, w
            count += 1
            total += w
            sx += w * dx
            sy += w * dy
    mx, my = sx / total, sy / total
    cxx = cyy = cxy = far = 0.0
    for q in range(count):
        w = keep_w[q] / total
        dx = ox[keep_k[q]] - ox[k_best]
        dy = oy[keep_j[q]] - oy[j_best]
        cxx += w * (dx - mx) ** 2
        cyy += w * (dy - my) ** 2
        cxy += w * (dx - mx) * (dy - my)
        if np.hypot(dx, dy) > radius:
            far += w
    return mx, my, cxx, cyy, cxy, far
