"""Weighted hypothesis sets: log-weights, the effective sample size, resampling.

The machinery the point-mass and particle filters share: normalised log-weights
(:func:`log_normalised`, :func:`linear_weights`), the effective sample size
(:func:`effective_sample_size`), the systematic resample (:func:`systematic_resample`)
and the progressive correction of an update too sharp for a sparse set
(:class:`ProgressiveCorrection`, Oudjane & Musso 2000).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, TypeVar

import numpy as np
from scipy.special import logsumexp

from geofix.errors import ConfigError
from geofix.filters import _particle_kernels as kernels

#: Float arrays of one value per particle a resample allocates (indices, positions, the
#: roughening draws, weights, the offsets): checked against the memory budget before it.
RESAMPLE_COPIES = 12

S = TypeVar("S")


def linear_weights(log_weight: np.ndarray) -> np.ndarray:
    """Linear weights summing to one from log-weights (shifted by their maximum first)."""
    w = np.exp(log_weight - log_weight.max())
    return w / w.sum()


def log_normalised(log_weight: np.ndarray) -> np.ndarray:
    """``log_weight - scipy.special.logsumexp(log_weight)`` for ``(M,)`` log-weights.

    The same numbers, bit for bit (:func:`log_sum_exp_first`), without scipy's
    generic-array overhead, which dominates a few-thousand-particle step.
    """
    return log_weight - log_sum_exp_first(log_weight)


def log_sum_exp_first(values: np.ndarray) -> np.ndarray:
    """``scipy.special.logsumexp(values, axis=0)`` bit for bit, without its overhead.

    Each column's maximal terms kept out of the sum (``log1p(s) + log(m) + max``, ``m``
    the count of maximal entries, ``s`` the sum of the others' ``exp(a - max)`` over
    ``m``), as scipy computes it; a non-finite maximum anywhere goes to scipy.

    Parameters
    ----------
    values : numpy.ndarray
        ``(K, ...)`` log-values.

    Returns
    -------
    numpy.ndarray
        ``(...)`` the log of each column's sum of exponentials.
    """
    values = np.asarray(values, dtype=float)
    top = values.max(axis=0)
    if not np.isfinite(top).all():
        return logsumexp(values, axis=0)
    at_top = values == top
    count = np.count_nonzero(at_top, axis=0).astype(float)
    shifted = values - top
    shifted[at_top] = -np.inf
    total = np.exp(shifted).sum(axis=0)
    total = np.where(total != 0, total / count, total)
    return np.log1p(total) + np.log(count) + top


def effective_sample_size(weights: np.ndarray) -> float:
    """``1 / sum(w^2)`` of normalised weights ``(M,)``: between 1 and ``M``."""
    return float(1.0 / np.sum(np.asarray(weights, dtype=float) ** 2))


def systematic_resample(weights: np.ndarray, rng: np.random.Generator, count=None) -> np.ndarray:
    """Indices ``(count,)`` of a systematic resample of normalised ``weights`` ``(M,)``.

    One uniform draw ``u`` places ``count`` (default ``M``) pointers at ``(u + j) / count``;
    particle ``i`` is copied once for each pointer falling in its slice of the cumulative
    weights, so it appears ``floor(count w_i)`` or ``ceil(count w_i)`` times.
    """
    m = weights.shape[0] if count is None else int(count)
    u = rng.random()
    cumulative = np.cumsum(weights)
    cumulative[-1] = 1.0
    # searchsorted(cumulative, (u + arange(m)) / m, side="right") in one merge pass
    return kernels.systematic_indices(cumulative, float(u), m)


def stage_fraction(log_weight: np.ndarray, ll: np.ndarray, remaining: float, min_ess) -> float:
    """Largest fraction (at most ``remaining``) of ``ll`` that keeps ``min_ess`` particles.

    The effective sample size of ``log_weight + a ll`` falls as ``a`` grows; bisection
    finds the largest ``a`` keeping ``min(min_ess, M / 2)``, never below
    ``1e-3 remaining`` (so that the stages always progress).

    Parameters
    ----------
    log_weight : numpy.ndarray
        ``(M,)`` normalised log-weights.
    ll : numpy.ndarray
        ``(M,)`` log-likelihood to apply, nats.
    remaining : float
        Share of ``ll`` not applied yet, in ``(0, 1]``.
    min_ess : float
        Effective particles to keep.
    """
    wanted = min(float(min_ess), 0.5 * log_weight.size)

    def ess(a: float) -> float:
        return effective_sample_size(np.exp(log_normalised(log_weight + a * ll)))

    if ess(remaining) >= wanted:
        return remaining
    low, high = 0.0, remaining
    for _ in range(30):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if ess(mid) >= wanted else (low, mid)
    return max(low, 1e-3 * remaining)


def check_progressive(name: str, min_update_ess: float, stages: int) -> None:
    """Refuse a progressive-correction setting that cannot work (ConfigError)."""
    if not (np.isfinite(min_update_ess) and min_update_ess >= 1) or stages < 0:
        raise ConfigError(
            f"{name}: min_update_ess must be >= 1 and progressive_stages >= 0, "
            f"got {min_update_ess} and {stages}"
        )


@dataclass(frozen=True)
class ProgressiveCorrection:
    """The progressive correction of an update too sharp for a sparse weighted set.

    Parameters
    ----------
    min_update_ess : float
        Effective particles each stage keeps.
    stages : int
        Most stages before the rest of the likelihood is applied at once (0: off).
    min_cells : float
        Least share of one particle, map cells, at which a set counts as sparse.
    """

    min_update_ess: float = 100.0
    stages: int = 4
    min_cells: float = 0.05

    def apply(self, state: S, likelihood: Callable[[S], np.ndarray], spread, rng) -> tuple:
        """Apply ``likelihood(state)`` to the weights, in stages while the set is sparse.

        ``state`` has ``log_weight``, ``spacing`` and ``cell``; ``spread(state, rng)``
        resamples and spreads the copies between stages: the largest fraction of the
        log-likelihood that keeps ``min_update_ess`` effective particles
        (:func:`stage_fraction`), the likelihood read again at the moved particles, and so
        on, at most ``stages`` times.

        Parameters
        ----------
        state : PfState or MpfState
            The weighted set before the update.
        likelihood : callable
            ``likelihood(state) -> (M,)`` log-likelihood of the set's particles, nats.
        spread : callable
            ``spread(state, rng) -> state``: resample and spread the copies.
        rng : numpy.random.Generator
            Random draws of the spreading.

        Returns
        -------
        tuple
            The updated state and the number of likelihood evaluations.
        """
        current: Any = state
        remaining, reads = 1.0, 0
        for stage in range(self.stages + 1):
            ll = likelihood(current)
            reads += ll.size
            sparse = current.spacing > self.min_cells * current.cell
            if stage == self.stages or not sparse:
                share = remaining
            else:
                share = stage_fraction(current.log_weight, ll, remaining, self.min_update_ess)
            current = replace(current, log_weight=log_normalised(current.log_weight + share * ll))
            remaining -= share
            if remaining <= 0.0:
                break
            current = spread(current, rng)
        return current, reads


__all__ = [
    "RESAMPLE_COPIES",
    "ProgressiveCorrection",
    "check_progressive",
    "effective_sample_size",
    "linear_weights",
    "log_normalised",
    "stage_fraction",
    "systematic_resample",
]
