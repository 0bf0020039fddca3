r"""The genie-aided bound with the map's error correlated: the exact posterior, whole mission.

The genie of :mod:`geofix.evaluate.ambiguity` tells the estimator the INS drift, so that
only the start error ``e_0`` is unknown; its minimum mean-square error
``E[tr Var(e_0 | y)]`` bounds every estimator of the real problem (information cannot
hurt the best estimator), and on a smooth field it is the tightest of the bounds: it is
the posterior itself, every mode of it. There the readings are independent given the
position. With the map's error correlated between readings (and an unknown constant
offset) they are not: the likelihood of a start error is Gaussian in the whole mission's
residuals,

    log p(y | e_0) = -1/2 r(e_0)^T R^-1 r(e_0) + const,   r(e_0) = y - m(q + e0_true - e_0),

``q`` the true footprints, ``m`` the map the estimator reads and ``R`` the readings'
covariance of :func:`geofix.evaluate.crlb_correlated.reading_covariance` (sensor noise,
the white rest of the map error, the correlated error, the offsets). One Cholesky factor
of ``R`` serves every hypothesis. Given a map posterior
(:func:`geofix.maps.error_posterior.map_posterior`) ``m`` is its mean and the correlated
error its covariance: the problem of a vehicle whose map is the field plus an error.

The posterior is computed on a grid along the prior's principal axes (five prior
standard deviations each side), and again about its mean when it is narrower than four
nodes of that grid. One field only, and one factor of the readings' covariance: a
gravimeter's hundreds of readings, not a multibeam mission's thousands of beams (refused
with the memory estimate).
"""

from __future__ import annotations

import numpy as np

from geofix.evaluate.ambiguity import initial_offset_prior
from geofix.evaluate.crlb import _prior_of
from geofix.evaluate.zzb_correlated import (
    one_field_problem,
    readings_factor,
    whitened_misfits,
)
from geofix.filters._grid_ops import grid_moments
from geofix.maps.error_posterior import MapPosterior
from geofix.maps.grid import Grid

__all__ = ["GENIE_NODES", "correlated_map_genie"]

#: Nodes along each axis of the genie's grid.
GENIE_NODES = 121
#: Its half-width, prior standard deviations (first pass) or posterior ones (second).
GENIE_EXTENT_SIGMAS = 5.0
#: A posterior narrower than this many nodes is computed again on a grid about it.
MIN_SD_NODES = 4.0


def correlated_map_genie(
    trial,
    grid: Grid,
    error_rms: float = 0.0,
    error_corr_m: float = 0.0,
    offset_std=None,
    beam_var=None,
    posterior: MapPosterior | None = None,
) -> float:
    """The genie's posterior variance of the start error, map error correlated, m^2.

    Parameters
    ----------
    trial : Trial
        The mission: true and indicated tracks, beams, readings (NaN beams carry
        nothing), its ``prior_map`` (None: the seabed ``grid``), INS error model (the
        prior of the start error). One field: a trial with further ``fields`` is refused.
    grid : Grid
        The seabed: the map the readings were drawn from.
    error_rms : float
        Standard deviation of the map error correlated along the track, map units (0:
        none; not used with ``posterior``).
    error_corr_m : float
        Its correlation length, metres (> 0 when ``error_rms`` > 0).
    offset_std : float, optional
        The still offset's prior 1-sigma, map units (0: known); default the prior map's.
    beam_var : float or array_like, optional
        The declared measurement variance, map units squared.
    posterior : MapPosterior, optional
        The field given the prior map when the map's error was added to the field.

    Returns
    -------
    float
        ``trace Var(e_0 | y)``, m^2 (0 when the start error is known): its mean over
        trials bounds the end point's mean-square error of every estimator.

    Raises
    ------
    ValueError
        An rms without a positive length, or a trial with further fields.
    MemoryBudgetError
        The readings' covariance or the shifted reads would not fit the memory budget.
    """
    trial, error = one_field_problem(
        trial, error_rms, error_corr_m, posterior, "the correlated genie bound"
    )
    mean, prior = initial_offset_prior(trial)
    values, axes = np.linalg.eigh(prior)
    if not values.min() > 0:
        return 0.0
    sd = np.sqrt(values)
    beams, factor = readings_factor(trial, grid, error, offset_std, beam_var)
    readings = np.asarray(trial.measured, float)[beams.sample, beams.beam]
    start_error = np.asarray(trial.indicated[0], float) - np.asarray(trial.truth[0], float)
    # a start error e_0 = mean + centre + (u a_0 + v a_1) reads at q + (start_error - e_0)
    reader = _Reader(_prior_of(trial, grid), beams.footprint + start_error - mean, readings, factor)
    inverse = np.linalg.inv(prior)
    centre, cov = _posterior(reader, inverse, np.zeros(2), axes, sd)
    spread, along = np.linalg.eigh(cov)
    spread = np.sqrt(np.clip(spread, 0.0, None))
    step = 2.0 * GENIE_EXTENT_SIGMAS * sd.max() / (GENIE_NODES - 1)
    if spread.min() < MIN_SD_NODES * step:
        centre, cov = _posterior(reader, inverse, centre, along, np.maximum(spread, 1e-3 * sd))
    return float(np.trace(cov))


class _Reader:
    """The whitened residuals' squared norm of every hypothesised start error."""

    def __init__(self, prior_map: Grid, footprint, readings, factor) -> None:
        self.prior_map = prior_map
        self.footprint = np.asarray(footprint, float)
        self.readings = np.asarray(readings, float)
        self.factor = factor

    def misfit(self, errors: np.ndarray) -> np.ndarray:
        """``(S,)`` ``r^T R^-1 r`` at each ``(S, 2)`` start error about the prior's mean."""
        return whitened_misfits(self.prior_map, self.footprint, self.readings, self.factor, errors)


def _posterior(reader: _Reader, prior_inverse, centre, axes, width) -> tuple:
    """Mean ``(2,)`` and covariance ``(2, 2)`` of the start error on a grid, metres.

    The grid is :data:`GENIE_NODES` a side about ``centre`` (m, about the prior's mean)
    along the columns of ``axes``, its half-width :data:`GENIE_EXTENT_SIGMAS` times
    ``width`` (m, per axis); the prior's inverse covariance ``prior_inverse``.
    """
    half = GENIE_NODES // 2
    u, v = (np.arange(-half, half + 1) * GENIE_EXTENT_SIGMAS * w / half for w in width)
    errors = centre + u[:, None, None] * axes[:, 0] + v[None, :, None] * axes[:, 1]
    flat = errors.reshape(-1, 2)
    log_post = -0.5 * reader.misfit(flat) - 0.5 * np.einsum(
        "si,ij,sj->s", flat, prior_inverse, flat
    )
    mu_u, mu_v, c_uu, c_uv, c_vv = grid_moments(log_post.reshape(u.size, v.size), u, v)
    local = np.array([[c_uu, c_uv], [c_uv, c_vv]])
    return centre + axes @ np.array([mu_u, mu_v]), axes @ local @ axes.T
