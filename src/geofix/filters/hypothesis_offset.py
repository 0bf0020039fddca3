r"""A common offset carried by every hypothesis of a filter: Rao-Blackwellised.

Readings and prior map differ by an offset common to every beam of a ping (a tide, a datum
or sound-speed error, a gravimeter's offset and drift, the part of a map error correlated
over more than a swath): ``y = h(x) + beta 1 + e``. Given a hypothesised position path the
offset is linear and Gaussian, so each hypothesis (a point-mass node, a particle) carries
its own offset mean ``b_i`` -- the running, variance-weighted mean of its own residuals --
and the filter marginalises each ping over ``N(b_i, P)``
(:func:`geofix.measurement.common_bias_log_likelihood` on predictions shifted by ``b_i``).
A hypothesis on the true path sees residuals that agree with one offset; a wrong one
sees residuals that wander. One ping of a single beam tells the position nothing when
its offset is unknown, but the sequence does, as a terrain profile matched with its mean
removed does.

``P`` is common to the hypotheses: after a ping of ``n`` beams of variance ``v`` it is
``P / (1 + P sum 1/v)`` for every hypothesis that read them all, and it grows by
``walk * dt`` between pings (a random walk, so an offset that drifts is followed). The
hypotheses are moved, resampled, convolved and regridded by their filter; this value
follows them (:meth:`HypothesisOffset.take`, :func:`mixed_offsets`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import ndimage

from geofix.filters._grid_ops import node_positions
from geofix.filters.base import Observation
from geofix.maps.grid import Grid
from geofix.measurement import predict_measurements
from geofix.memory import cells_bytes, check_allocation


@dataclass(frozen=True)
class HypothesisOffset:
    """Each hypothesis's offset mean and the common variance, map units.

    Parameters
    ----------
    mean : numpy.ndarray
        Offset mean of each hypothesis (measured minus map), map units; the shape of the
        filter's hypotheses (``(M,)`` particles, ``(N0, N1)`` nodes).
    var : float
        Variance of every hypothesis's offset, map units squared.
    walk : float
        Variance gained per second, map units squared per second.
    """

    mean: np.ndarray
    var: float
    walk: float

    @classmethod
    def start(cls, shape, obs: Observation) -> HypothesisOffset | None:
        """The prior ``N(0, obs.bias_var)`` for every hypothesis, or None without one.

        Parameters
        ----------
        shape : int or tuple
            The hypotheses' shape.
        obs : Observation
            The first ping: ``bias_var`` the offset's prior variance, ``bias_walk`` its
            growth per second; None unless ``bias_per_hypothesis`` and ``bias_var > 0``.
        """
        if not (obs.bias_per_hypothesis and obs.bias_var > 0):
            return None
        return cls(np.zeros(shape), float(obs.bias_var), float(obs.bias_walk))

    def predicted(self, dt: float) -> HypothesisOffset:
        """The offsets ``dt`` seconds later: the variance grows by ``walk * dt``."""
        return replace(self, var=self.var + self.walk * max(float(dt), 0.0))

    def take(self, index) -> HypothesisOffset:
        """The offsets of the hypotheses ``index`` (a resample's copies)."""
        return replace(self, mean=self.mean[index])

    def moments(self, weights) -> tuple[float, float]:
        """Mean and variance of the offset over the posterior ``weights`` (summing to one).

        Returns
        -------
        tuple of float
            ``sum w_i b_i`` and ``P + sum w_i (b_i - bbar)^2``, map units and squared.
        """
        w = np.asarray(weights, dtype=float).reshape(-1)
        b = self.mean.reshape(-1)
        mean = float(w @ b)
        return mean, self.var + float(w @ (b - mean) ** 2)

    def updated(self, grid: Grid, positions, obs: Observation, predicted=None) -> HypothesisOffset:
        """Each hypothesis's offset after the ping (a scalar Kalman step per hypothesis).

        ``b_i <- b_i + P T_i / (1 + P S_i)``, ``T_i = sum (y - h_i - b_i) / v``,
        ``S_i = sum 1 / v`` over the hypothesis's valid beams; ``P <- P / (1 + P S)`` with
        ``S`` the most any hypothesis had (those that read the whole ping).

        Parameters
        ----------
        grid : Grid
            The prior map.
        positions : numpy.ndarray
            ``(..., 2)`` the hypotheses after the ping's weighting, metres, in the shape of
            :attr:`mean`.
        obs : Observation
            The ping, with the variance it was weighed with.
        predicted : numpy.ndarray, optional
            ``(..., b)`` the ping's every beam read at ``positions``, map units, when the
            filter has them already (read here otherwise).
        """
        positions = np.asarray(positions, dtype=float)
        count = int(np.prod(positions.shape[:-1]))
        beams = int(np.isfinite(obs.values).sum())
        check_allocation(cells_bytes(count * max(beams, 1), copies=3), "per-hypothesis offsets")
        use = np.isfinite(obs.values)
        if predicted is None:
            offsets = np.asarray(obs.offsets, dtype=float)[use]
            flat = positions.reshape(-1, 2)
            predicted = predict_measurements(grid, flat, obs.heading, offsets)
        else:
            predicted = np.asarray(predicted, dtype=float)[..., use]
        predicted = predicted.reshape(count, -1)
        var = np.broadcast_to(np.asarray(obs.noise_var, dtype=float), obs.values.shape)[use]
        residual = obs.values[use] - predicted - self.mean.reshape(-1, 1)
        valid = np.isfinite(residual)
        w = np.where(valid, 1.0 / var, 0.0)
        s = w.sum(axis=1)
        t = (w * np.where(valid, residual, 0.0)).sum(axis=1)
        mean = self.mean.reshape(-1) + self.var * t / (1.0 + self.var * s)
        most = float(s.max()) if s.size else 0.0
        return replace(
            self, mean=mean.reshape(self.mean.shape), var=self.var / (1.0 + self.var * most)
        )


def mixed_offsets(log_weight: np.ndarray, mean: np.ndarray, kernels) -> np.ndarray:
    """Node offsets after the point-mass prediction's convolution, moment-matched.

    The mass arriving at a node comes from its neighbours with the motion kernel's
    weights; its offset mean is the mass-weighted mean of theirs
    (``conv(p b) / conv(p)``). Where no mass arrives (below 1e-300 of the peak) the
    node keeps its own.

    Parameters
    ----------
    log_weight : numpy.ndarray
        ``(N0, N1)`` log-weights before the convolution.
    mean : numpy.ndarray
        ``(N0, N1)`` offset means before it, map units.
    kernels : tuple of numpy.ndarray
        The 1-D motion kernels along each grid axis.

    Returns
    -------
    numpy.ndarray
        ``(N0, N1)`` offset means after it.
    """
    p = np.exp(log_weight - log_weight.max())
    num, den = p * mean, p
    for axis, kernel in enumerate(kernels):
        num = ndimage.convolve1d(num, kernel, axis=axis, mode="constant")
        den = ndimage.convolve1d(den, kernel, axis=axis, mode="constant")
    arrived = den > 1e-300
    return np.where(arrived, num / np.where(arrived, den, 1.0), mean)


def regridded_offsets(mean: np.ndarray, old, new, shape) -> np.ndarray:
    """Node offsets moved from grid ``old`` onto grid ``new`` by linear interpolation.

    Parameters
    ----------
    mean : numpy.ndarray
        ``(N0, N1)`` offset means on ``old``, map units.
    old, new : tuple
        ``(centre (2,), axes (2, 2), spacing (2,))`` of each grid, metres.
    shape : tuple
        ``(M0, M1)`` nodes of the new grid.

    Returns
    -------
    numpy.ndarray
        ``(M0, M1)`` offset means (a new node beyond the old grid takes its nearest
        old node's).
    """
    centre, axes, spacing = new
    xy = node_positions(centre, axes, spacing, shape) - np.asarray(old[0], dtype=float)
    along = xy @ np.asarray(old[1], dtype=float)  # coordinates along the old axes
    n0, n1 = mean.shape
    rows = along[..., 0] / old[2][0] + 0.5 * (n0 - 1)
    cols = along[..., 1] / old[2][1] + 0.5 * (n1 - 1)
    return ndimage.map_coordinates(mean, [rows, cols], order=1, mode="nearest")


__all__ = ["HypothesisOffset", "mixed_offsets", "regridded_offsets"]
