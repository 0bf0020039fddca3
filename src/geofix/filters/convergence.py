r"""The KL-divergence term of the navigator's convergence test.

MBARI's TRN (Meduna, Rock & McEwen 2008, "Low-cost terrain relative navigation for
long-range AUVs", OCEANS; Meduna 2011, PhD thesis, Stanford) calls a point-mass filter
converged only when its posterior is close to a Gaussian: besides a small spread and a
mean near the mode, the Kullback-Leibler divergence ``KL(p || q)`` of the posterior ``p``
to the Gaussian ``q`` of the same mean and covariance must be small. A multi-modal or
heavy-tailed posterior (an ambiguous fix) fails it even when its covariance is small.

The estimators, in **nats**:

- **a point-mass grid** (nodes ``x_i`` with weights ``w_i`` on cells of area ``A``, the
  node spacing product): the Riemann sum of ``int p log(p / q)``,
  ``KL = sum_i w_i log(w_i / (A q(x_i)))`` (:func:`kl_grid`), exact for a fine grid;
- **a particle set** (a weighted random sample: no density at the particles), a binned
  divergence (:func:`kl_to_gaussian`):

1. whiten: ``z = L^{-1} (x - mean)`` with ``L L^T = cov`` (the set's weighted mean and
   covariance), so that ``q`` becomes the standard normal;
2. bin ``z`` on a ``bins x bins`` lattice over ``[-extent, extent]^2`` whose outer bins
   reach to infinity (no mass is lost), giving bin masses ``P_j``; the Gaussian's masses
   ``Q_j`` are products of standard-normal interval masses;
3. ``KL = sum_j P_j log(P_j / Q_j)``. Binning can only lower a divergence
   (data-processing inequality), so this is a lower bound of the continuous ``KL(p||q)``
   that tightens as the bins shrink;
4. for a particle set (a random sample) the plug-in estimate is biased upwards by about
   ``(k - 1) / (2 N_eff)`` (Miller 1955), ``k`` the occupied bins and ``N_eff = 1 /
   sum w_i^2``; that term is subtracted (the result clipped at 0). A grid's weights are
   not a sample: no correction.
"""

from __future__ import annotations

import numpy as np
from scipy.special import logsumexp, ndtr

from geofix.filters.state import FilterState

KL_BINS = 16
"""Bins per whitened axis of the KL estimate."""
KL_EXTENT = 4.0
"""Half-width of the binned box, standard deviations (the outer bins reach to infinity)."""


def kl_to_gaussian(
    points, weights, sample: bool = False, bins: int = KL_BINS, extent: float = KL_EXTENT
) -> float:
    """Binned ``KL(p || N(mean, cov))`` of a weighted 2-D point set, nats.

    Parameters
    ----------
    points : array_like
        ``(n, 2)`` positions, metres.
    weights : array_like
        ``(n,)`` non-negative weights (normalised here).
    sample : bool
        The points are a random sample (particles): subtract the Miller-Madow bias.
    bins : int
        Bins per whitened axis.
    extent : float
        Half-width of the binned box, standard deviations.

    Returns
    -------
    float
        The divergence, nats (0 for a degenerate set: a single point or a zero spread).
    """
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    w = np.asarray(weights, dtype=float).ravel()
    total = w.sum()
    if points.shape[0] < 2 or not total > 0:
        return 0.0
    w = w / total
    mean = w @ points
    d = points - mean
    cov = (d * w[:, None]).T @ d
    try:
        chol = np.linalg.cholesky(0.5 * (cov + cov.T))
    except np.linalg.LinAlgError:
        return 0.0
    z = np.linalg.solve(chol, d.T).T
    inner = np.linspace(-extent, extent, bins + 1)
    index = [np.clip(np.searchsorted(inner, z[:, a]) - 1, -1, bins) + 1 for a in (0, 1)]
    p = np.zeros((bins + 2, bins + 2))
    np.add.at(p, (index[0], index[1]), w)
    edges = np.concatenate([[-np.inf], inner, [np.inf]])
    mass = np.diff(ndtr(edges))  # (bins + 2,) standard-normal interval masses
    q = np.outer(mass, mass)
    occupied = p > 0
    kl = float(np.sum(p[occupied] * np.log(p[occupied] / q[occupied])))
    if sample:
        n_eff = 1.0 / float(np.sum(w * w))
        kl -= (int(occupied.sum()) - 1) / (2.0 * n_eff)
    return max(kl, 0.0)


def kl_grid(points, weights, cell_area: float) -> float:
    """``KL(p || N(mean, cov))`` of a density on grid nodes (Riemann sum), nats.

    Parameters
    ----------
    points : array_like
        ``(n, 2)`` node positions, metres.
    weights : array_like
        ``(n,)`` node masses (normalised here).
    cell_area : float
        Area of one node's cell, m^2.

    Returns
    -------
    float
        The divergence, nats, clipped at 0 (0 for a degenerate spread).
    """
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    w = np.asarray(weights, dtype=float).ravel()
    total = w.sum()
    if points.shape[0] < 2 or not total > 0 or not cell_area > 0:
        return 0.0
    w = w / total
    mean = w @ points
    d = points - mean
    cov = 0.5 * (d * w[:, None]).T @ d
    cov = cov + cov.T
    sign, logdet = np.linalg.slogdet(cov)
    if sign <= 0:
        return 0.0
    maha = np.einsum("ni,ij,nj->n", d, np.linalg.inv(cov), d)
    log_q = -0.5 * maha - np.log(2.0 * np.pi) - 0.5 * logdet
    keep = w > 0
    kl = float(np.sum(w[keep] * (np.log(w[keep]) - np.log(cell_area) - log_q[keep])))
    return max(kl, 0.0)


def posterior_points(state) -> tuple[np.ndarray, np.ndarray, float | None] | None:
    """``(points (n, 2), weights (n,), cell_area)`` of a grid or particle state, else None.

    ``cell_area`` (m^2) for a point-mass grid, None for a particle set (a sample).

    The state's weighted posterior points
    (:meth:`~geofix.filters.state.FilterState.points`) with their weights normalised; a
    state without any (an EKF's) gives None.
    """
    found = state.points() if isinstance(state, FilterState) else None
    if found is None:
        return None
    points, log_weight = found
    log_weight = np.asarray(log_weight, dtype=float)
    weights = np.exp(log_weight - logsumexp(log_weight))
    return np.asarray(points, dtype=float), weights.ravel(), state.node_area()


def posterior_kl(state) -> float:
    """``KL`` of a filter state's posterior to its Gaussian, nats (NaN if it has no points)."""
    found = posterior_points(state)
    if found is None:
        return float("nan")
    points, weights, cell_area = found
    if cell_area is None:
        return kl_to_gaussian(points, weights, sample=True)
    return kl_grid(points, weights, cell_area)


__all__ = ["KL_BINS", "KL_EXTENT", "kl_grid", "kl_to_gaussian", "posterior_kl", "posterior_points"]
