"""Numerical kernels of the point-mass filter, all on log-densities.

A point-mass grid is ``N0 x N1`` nodes along two orthonormal axes (the columns of ``axes``),
``spacing`` metres apart along each, centred on ``centre``. Node ``[i, j]`` sits at
``centre + axes @ ((i - m0) * spacing[0], (j - m1) * spacing[1])`` with
``m_k = (N_k - 1) / 2``. A grid's ``shape`` is an int ``N`` (square) or a pair ``(N0, N1)``.
Weights are kept as natural logarithms normalised to ``logsumexp = 0``; no function here
takes the exponential of anything but ``log_weight - max(log_weight)``, so a density
however peaked never underflows to an all-zero grid, and never produces NaN.
"""

from __future__ import annotations

import numpy as np

from geofix.filters import _grid_kernels as grid_kernels
from geofix.memory import cells_bytes, check_allocation

THREE_TAP_MAX_SIGMA = 0.8
"""Largest kernel sigma (in nodes) for the three-tap kernel; wider ones are sampled Gaussians
(at 0.8 node both have the exact variance ``sigma^2`` to better than 1e-5)."""


#: Float arrays of one value per node a regrid allocates (positions, densities, the
#: convolution's passes, the offsets): checked against the memory budget before it.
REGRID_COPIES = 12


def check_regrid(shape) -> None:
    """Refuse, against the memory budget, a regrid onto ``shape`` nodes before it runs."""
    n0, n1 = (int(shape), int(shape)) if np.ndim(shape) == 0 else (int(n) for n in shape)
    check_allocation(cells_bytes(n0, n1, copies=REGRID_COPIES), f"pmf regrid to {n0} x {n1} nodes")


def node_offsets(shape, spacing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Node coordinates along each grid axis relative to the centre, metres.

    ``shape`` is ``N`` or ``(N0, N1)``; the result is ``(N0,)`` and ``(N1,)``.
    """
    n0, n1 = (int(shape), int(shape)) if np.ndim(shape) == 0 else (int(n) for n in shape)
    u = (np.arange(n0) - 0.5 * (n0 - 1)) * spacing[0]
    v = (np.arange(n1) - 0.5 * (n1 - 1)) * spacing[1]
    return u, v


def node_positions(centre, axes, spacing, shape) -> np.ndarray:
    """Absolute ``(x, y)`` of every node, metres, shape ``(N0, N1, 2)``."""
    u, v = node_offsets(shape, spacing)
    return centre + u[:, None, None] * axes[:, 0] + v[None, :, None] * axes[:, 1]


def normalise(log_weight: np.ndarray) -> np.ndarray:
    """Log-weights shifted so that they sum (in linear space) to one.

    In numpy: its exponential is vectorised (AVX2/AVX-512), unlike the scalar one a
    compiled loop calls, and a grid's exponentials are most of the work.
    """
    lw = np.asarray(log_weight, dtype=float)
    top = lw.max()
    shifted = lw - top
    return shifted - np.log(np.exp(shifted).sum())


def gaussian_log_density(positions, mean, cov) -> np.ndarray:
    """Log of the 2-D normal density ``N(mean, cov)`` at ``positions`` ``(..., 2)``, 1/m^2."""
    d = np.asarray(positions, dtype=float) - mean
    inv = np.linalg.inv(cov)
    quad = np.einsum("...i,ij,...j->...", d, inv, d)
    return -0.5 * quad - 0.5 * np.log(np.linalg.det(2.0 * np.pi * cov))


def grid_moments(log_weight: np.ndarray, u: np.ndarray, v: np.ndarray) -> tuple:
    """``(mu_u, mu_v, c_uu, c_uv, c_vv)`` of ``exp(log_weight)`` (normalised) along the axes.

    ``u`` ``(N0,)``, ``v`` ``(N1,)``: node coordinates, metres; means in m, second central
    moments in m^2, without the grid's resolution term. The exponentials are numpy's
    (vectorised), the sums one compiled pass
    (:func:`geofix.filters._grid_kernels.weight_moments`).
    """
    lw = np.asarray(log_weight, dtype=float)
    return grid_kernels.weight_moments(np.exp(lw - lw.max()), u, v)


def moments(log_weight, centre, axes, spacing, offsets=None) -> tuple[np.ndarray, np.ndarray]:
    """Mean ``(2,)`` (metres) and covariance ``(2, 2)`` (m^2) of a normalised grid.

    The covariance includes the grid's own resolution, ``spacing^2 / 12`` per axis (the
    variance of a position spread uniformly over one node's cell), so that a posterior
    collapsed on one node still reports the uncertainty its grid can resolve.
    ``offsets`` is the grid's ``node_offsets`` when the caller has it already.
    """
    log_weight = np.asarray(log_weight, dtype=float)
    u, v = node_offsets(log_weight.shape, spacing) if offsets is None else offsets
    mu_u, mu_v, c_uu, c_uv, c_vv = grid_moments(log_weight, u, v)
    resolution = np.asarray(spacing, float) ** 2 / 12.0
    local = np.array([[c_uu + resolution[0], c_uv], [c_uv, c_vv + resolution[1]]])
    return centre + axes @ np.array([mu_u, mu_v]), axes @ local @ axes.T


def mass_beyond(log_weight, centre, axes, spacing, point, radius: float) -> float:
    """Share of the grid's probability farther than ``radius`` metres from ``point``."""
    w = np.exp(log_weight - log_weight.max())
    u, v = node_offsets(w.shape, spacing)
    p = axes.T @ (np.asarray(point, float) - centre)
    far = (u[:, None] - p[0]) ** 2 + (v[None, :] - p[1]) ** 2 > radius**2
    return float(w[far].sum() / w.sum())


def motion_kernel(sigma_nodes: float, max_half: int | None = None) -> np.ndarray:
    """A symmetric discrete kernel of variance ``sigma_nodes^2`` (node units), summing to one.

    Three taps ``[a, 1 - 2a, a]`` with ``a = sigma^2 / 2`` below
    :data:`THREE_TAP_MAX_SIGMA` (exact variance even for a motion much smaller than a
    node); above it a Gaussian sampled out to 5 sigma, convolved with such a three-tap
    kernel that makes up the variance lost to sampling and truncation, so the variance
    is exact there too.

    ``max_half`` (nodes): on a grid of ``max_half + 1`` nodes no tap farther out can
    reach a node, so a wider kernel (a motion far larger than the grid, e.g. a huge INS
    error) is returned as its central ``2 max_half + 1`` taps, each the Gaussian density
    at the tap (the full kernel's weights up to a common factor, which the normalised
    log-density does not see) -- instead of allocating and convolving taps that only
    cost time.
    """
    s = float(sigma_nodes)
    if s <= THREE_TAP_MAX_SIGMA:
        a = 0.5 * s * s
        return np.array([a, 1.0 - 2.0 * a, a])
    if max_half is not None and 5.0 * s > max_half + 1:
        u = np.arange(-int(max_half), int(max_half) + 1)
        return np.exp(-0.5 * (u / s) ** 2) / (s * np.sqrt(2.0 * np.pi))
    half = int(np.ceil(5.0 * s))
    u = np.arange(-half, half + 1)
    k = np.exp(-0.5 * (u / s) ** 2)
    k /= k.sum()
    a = 0.5 * max(s * s - float(k @ u**2), 0.0)
    return np.convolve(k, [a, 1.0 - 2.0 * a, a])


def convolve_log(log_weight: np.ndarray, kernels: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Convolve a log-density with a separable kernel, staying finite everywhere.

    The convolution runs in linear space on ``exp(log_weight - max)`` (two 1-D passes,
    exact sums of non-negative terms, mass leaving the grid is lost). Where that underflows
    to zero the result is bounded below by the node's own contribution,
    ``log_weight + log(centre tap 0) + log(centre tap 1)``, which is finite. The passes
    are one compiled call (:func:`geofix.filters._grid_kernels.correlate_separable`), the
    exponentials and logarithms numpy's vectorised ones.
    """
    k0, k1 = (np.ascontiguousarray(k, dtype=float) for k in kernels)
    lw = np.ascontiguousarray(log_weight, dtype=float)
    top = lw.max()
    p = grid_kernels.correlate_separable(np.exp(lw - top), k0, k1)
    floor = lw + (np.log(k0[k0.size // 2]) + np.log(k1[k1.size // 2]) - top)
    with np.errstate(divide="ignore"):
        log_p = np.log(np.maximum(p, np.finfo(float).tiny))
    log_p[p <= 0.0] = -np.inf
    return normalise(np.maximum(log_p, floor) + top)


GridFrame = tuple[np.ndarray, np.ndarray, np.ndarray]
"""``(centre (2,), axes (2, 2), spacing (2,))`` of a point-mass grid, metres."""


def resample_grid(
    log_weight: np.ndarray,
    old: GridFrame,
    new: GridFrame,
    fallback: tuple[np.ndarray, np.ndarray],
    shape: int | tuple[int, int] | None = None,
) -> np.ndarray:
    """Move a log-density from grid ``old`` onto grid ``new`` by linear interpolation.

    Parameters
    ----------
    log_weight : numpy.ndarray
        ``(N0, N1)`` normalised log-weights on ``old``.
    old, new : tuple
        ``(centre (2,), axes (2, 2), spacing (2,))`` of each grid, metres.
    fallback : tuple
        ``(mean (2,), cov (2, 2))`` of a Gaussian used for new nodes outside the old grid
        (never above the old grid's smallest density).
    shape : int or tuple, optional
        Nodes of the new grid, ``N`` or ``(N0, N1)``; the old grid's shape by default.

    Returns
    -------
    numpy.ndarray
        Normalised log-weights on ``new``, of ``shape``.
    """
    u, v = node_offsets(log_weight.shape if shape is None else shape, new[2])
    log_density = np.ascontiguousarray(log_weight, dtype=float) - np.log(np.prod(old[2]))
    stacked_old = np.vstack([old[0], np.asarray(old[1]).T, old[2]]).astype(float)
    mean, cov = (np.asarray(a, dtype=float) for a in fallback)
    normaliser = -0.5 * np.log(np.linalg.det(2.0 * np.pi * cov))
    stacked_fallback = np.vstack([mean, np.linalg.inv(cov), [normaliser, 0.0]])
    new_axes = np.ascontiguousarray(new[1], dtype=float)
    centre = np.asarray(new[0], dtype=float)
    values = grid_kernels.resampled_log_density(
        log_density, stacked_old, centre, new_axes, u, v, stacked_fallback
    )
    return normalise(values + np.log(np.prod(new[2])))
