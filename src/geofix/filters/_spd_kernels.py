"""Compiled loop over many small symmetric positive definite systems.

A point-mass filter weighs every node of its grid with the same small Woodbury system
(:mod:`geofix.filters.offset_sums`): thousands of 3 x 3 or 5 x 5 matrices a ping.
LAPACK's batched solve and determinant pay a call's overhead per matrix; one Cholesky
factor per matrix, written out, gives the same numbers to rounding several times faster.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def quadratic_and_logdet(inner, u):  # pragma: no cover - compiled
    """``u_i^T A_i^-1 u_i`` and ``log det A_i`` of every SPD ``A_i`` (``inner[i]``).

    Parameters
    ----------
    inner : numpy.ndarray
        ``(m, k, k)`` symmetric positive definite matrices (the lower triangle is read).
    u : numpy.ndarray
        ``(m, k)`` vectors.

    Returns
    -------
    tuple of numpy.ndarray
        ``(m,)`` quadratic forms and ``(m,)`` log-determinants, through ``A_i = L L^T``:
        ``|L^-1 u_i|^2`` and ``2 sum log L_jj``. NaN where a matrix is not positive
        definite.
    """
    m, k = u.shape
    quad = np.empty(m)
    logdet = np.empty(m)
    factor = np.empty((k, k))
    z = np.empty(k)
    for i in range(m):
        total = 0.0
        logs = 0.0
        for j in range(k):
            s = inner[i, j, j]
            for p in range(j):
                s -= factor[j, p] * factor[j, p]
            d = np.sqrt(s) if s > 0.0 else np.nan
            factor[j, j] = d
            logs += np.log(d)
            for r in range(j + 1, k):
                t = inner[i, r, j]
                for p in range(j):
                    t -= factor[r, p] * factor[j, p]
                factor[r, j] = t / d
            t = u[i, j]
            for p in range(j):
                t -= factor[j, p] * z[p]
            z[j] = t / d
            total += z[j] * z[j]
        quad[i] = total
        logdet[i] = 2.0 * logs
    return quad, logdet
