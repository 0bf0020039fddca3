"""Hausdorff distances between point sets, classic and mean (Dubuisson & Jain 1994).

For finite point sets ``A`` and ``B``:

- directed distance ``h(A, B) = max_{a in A} min_{b in B} |a - b|`` (classic) or
  ``d(A, B) = (1/|A|) sum_{a in A} min_{b in B} |a - b|`` (mean, Dubuisson & Jain's
  "modified Hausdorff distance" d_22);
- undirected distance ``max(h(A, B), h(B, A))`` (classic, scipy's
  :func:`scipy.spatial.distance.directed_hausdorff` both ways) or
  ``MHD(A, B) = max(d(A, B), d(B, A))`` (mean).

The mean variant is what source 003 screens gravity matches with: one outlying point moves
it by ``1/|A|`` of its distance instead of all of it.

Private to :mod:`geofix.match`; its user is :mod:`geofix.match.abc`.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.distance import directed_hausdorff


def _points(points, what: str) -> np.ndarray:
    arr = np.asarray(points, dtype=float)
    if arr.ndim != 2 or arr.shape[0] == 0:
        raise ValueError(f"{what} must be a non-empty (n, d) array of points")
    return arr


def directed_mean_distance(a, b) -> float:
    """Mean over the points of ``a`` of the distance to the nearest point of ``b``.

    Parameters
    ----------
    a, b : array_like
        ``(n, d)`` and ``(m, d)`` points, metres (any common unit).

    Returns
    -------
    float
        ``d(A, B)``, same unit as the points.
    """
    a = _points(a, "a")
    b = _points(b, "b")
    nearest, _ = cKDTree(b).query(a)
    return float(np.mean(nearest))


def mean_hausdorff(a, b) -> float:
    """Mean Hausdorff distance ``max(d(A, B), d(B, A))`` (Dubuisson & Jain 1994).

    Parameters
    ----------
    a, b : array_like
        ``(n, d)`` and ``(m, d)`` points, metres (any common unit).

    Returns
    -------
    float
        The distance, same unit as the points; 0 for identical sets.
    """
    return max(directed_mean_distance(a, b), directed_mean_distance(b, a))


def hausdorff(a, b) -> float:
    """Classic (max-min) Hausdorff distance, for comparison with :func:`mean_hausdorff`.

    Parameters
    ----------
    a, b : array_like
        ``(n, d)`` and ``(m, d)`` points.

    Returns
    -------
    float
        ``max(h(A, B), h(B, A))``, same unit as the points.
    """
    a = _points(a, "a")
    b = _points(b, "b")
    return max(directed_hausdorff(a, b)[0], directed_hausdorff(b, a)[0])


def batch_mean_hausdorff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Mean Hausdorff distance of many pairs of equally sized small point sets at once.

    Brute force over all point pairs (the sets compared in matching hold tens of points),
    vectorised over the leading axes.

    Parameters
    ----------
    a : numpy.ndarray
        ``(..., n, d)`` point sets.
    b : numpy.ndarray
        ``(..., m, d)`` point sets, leading axes broadcastable with ``a``'s.

    Returns
    -------
    numpy.ndarray
        ``(...)`` distances, same unit as the points.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    dist = np.linalg.norm(a[..., :, None, :] - b[..., None, :, :], axis=-1)
    d_ab = dist.min(axis=-1).mean(axis=-1)
    d_ba = dist.min(axis=-2).mean(axis=-1)
    return np.maximum(d_ab, d_ba)
