r"""The Cramér–Rao bound with the map's error correlated along the track.

:func:`geofix.evaluate.crlb.imperfect_map_crlb` adds the prior map's error to every beam
as white noise. A map error correlated over a few kilometres is nothing of the kind: along
a track it reads as a slowly changing offset, the same on neighbouring beams and pings, so
it neither averages out over pings as white noise would nor hides the terrain's shape as a
fresh offset per ping would. The bound of the problem a vehicle with such a map has takes
every reading of the mission at once.

The model, linearised on the true track: the INS error state ``x_k`` (or the random-walk
position error without an INS model) with its prior, transitions and process noise
(:class:`geofix.evaluate.crlb.LinearMotion`), the DVL's velocity rows at every sample when
the trial has one, and every beam ``y_i = g_i^T H x_{k(i)} + e_i`` with the prior map's
gradient ``g_i`` at the true footprint. The errors ``e`` are jointly Gaussian with the
covariance

    R = diag(v_i)                                  sensor noise + white map error
      + s^2 exp(-|q_i - q_j|^2 / (2 L^2))          the primary field's correlated map error
      + sum_f c_f^2 1_f 1_f^T                      every field's constant, unknown offset

over the beams' true footprints ``q`` (the Gaussian covariance of
:func:`geofix.sim.seabed.gaussian_field`, standard deviation ``s``, correlation length
``L``). All of it is linear and Gaussian, so the bound on the last state is the covariance
of that state given every reading (the posterior CRLB of a linear-Gaussian model is its
posterior covariance):

    P_n|y = P_n - C_ny (G Z G^T + R)^-1 C_ny^T

with ``Z`` the prior covariance of the states' measured parts at every sample, ``G`` the
beams' and DVL rows' coefficients on them, and ``C_ny`` the last state's covariance with
the readings. With no correlated error it is the recursion of
:func:`geofix.evaluate.crlb.offset_state_crlb` with a still offset (the tests hold the two
together), with an infinite correlation length a constant offset of variance
``c^2 + s^2``, and with a vanishing one white noise of variance ``v + s^2``.

Its cost is that of one Cholesky factor of ``R``'s size (every valid beam and DVL row of
the mission): a single-beam gravimeter's hundreds of readings are nothing, a multibeam
mission's tens of thousands of beams are refused with the memory estimate
(:func:`geofix.memory.check_allocation`); there the white approximation stands.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from geofix.evaluate.crlb import (
    LinearMotion,
    _field_gradients,
    _prior_of,
    error_state_motion,
    map_error_variance_at_track,
    random_walk_motion,
    trial_beam_variance,
    trial_error_state,
    trial_offset_model,
)
from geofix.maps.error_posterior import MapPosterior
from geofix.maps.grid import Grid
from geofix.measurement import beam_gradients
from geofix.memory import cells_bytes, check_allocation
from geofix.problem import footprint_xy

__all__ = [
    "CorrelatedError",
    "check_correlated_error",
    "correlated_map_crlb",
    "gaussian_covariance",
    "posterior_problem",
    "reading_covariance",
    "state_covariances",
    "trial_beams",
]


def correlated_map_crlb(
    trial,
    grid: Grid,
    error_rms: float = 0.0,
    error_corr_m: float = 0.0,
    offset_std=None,
    beam_var=None,
    posterior: MapPosterior | None = None,
) -> float:
    """Bound on the end point's position error with the map error correlated, m^2.

    Parameters
    ----------
    trial : Trial
        The mission: true track and headings, beams, readings (NaN beams carry nothing),
        its ``prior_map`` (None: the seabed ``grid`` is the prior), ``ins_model`` (None:
        the random-walk position model of ``sigma_position``) and further fields.
    grid : Grid
        The seabed: the map the primary field's readings were drawn from.
    error_rms : float
        Standard deviation ``s`` of the primary field's map error correlated along the
        track, its units (0: none). Its share of the map error at the track is taken out of
        the white part: each beam's white variance is its declared one plus what the map's
        error at the track has beyond ``s^2``
        (:func:`geofix.evaluate.crlb.map_error_variance_at_track`).
    error_corr_m : float
        Its correlation length ``L``, metres (> 0 when ``error_rms`` > 0).
    offset_std : float or array_like, optional
        Every field's constant offset's prior 1-sigma, map units (one for all or one per
        field; 0: known); default each prior map's
        (:func:`geofix.evaluate.crlb.trial_offset_model`).
    beam_var : float or array_like, optional
        The primary field's declared measurement variance, its units squared; default
        :func:`geofix.evaluate.crlb.trial_beam_variance`.
    posterior : MapPosterior, optional
        The field given the prior map when the map's error was added to the field
        (:func:`geofix.maps.error_posterior.map_posterior`): the gradients are its mean's
        and the correlated part of ``R`` its covariance, in place of the prior map's and
        of ``error_rms`` over ``error_corr_m`` (which are then not used). Without it the
        field is the prior map less an error independent of the map.

    Returns
    -------
    float
        ``trace(H P_n|y H^T)``, m^2: the sum of both axes' variance bounds at the last
        sample.

    Raises
    ------
    ValueError
        ``error_rms`` > 0 without a positive ``error_corr_m``, or either negative.
    MemoryBudgetError
        The readings' covariance would not fit the memory budget.
    """
    check_correlated_error(error_rms, error_corr_m)
    trial, error = posterior_problem(trial, error_rms, error_corr_m, posterior)
    es = trial_error_state(trial)
    motion = random_walk_motion(trial.sigma_position) if es is None else error_state_motion(es)
    beams = trial_beams(trial, grid, error.rms, beam_var)
    std, _ = trial_offset_model(trial, grid, offset_std, 0.0)
    n = np.asarray(trial.truth).shape[0]
    extra = 0 if motion.extra_rows is None else motion.extra_rows.shape[0]
    size = beams.sample.size + n * extra
    m = 2 + extra
    check_allocation(
        cells_bytes(size, size, copies=4) + cells_bytes(n * m, n * m, copies=2),
        f"the correlated-error bound's covariance of {size} readings",
    )
    cov = reading_covariance(beams, std, error, n, extra)
    last, z, cross = state_covariances(motion)
    coef, sample = _coefficients(beams, motion, n)
    flat = z.transpose(0, 2, 1, 3).reshape(n * m, n * m)
    index = sample[:, None] * m + np.arange(m)
    design = np.zeros((size, n * m))
    np.put_along_axis(design, index, coef, axis=1)
    cov += design @ flat @ design.T
    gain = cross.reshape(motion.dim, n * m) @ design.T
    posterior = last - gain @ cho_solve(cho_factor(cov, overwrite_a=True), gain.T)
    h = motion.position_map
    return float(np.trace(h @ posterior @ h.T))


@dataclass(frozen=True)
class CorrelatedError:
    """The primary field's map error correlated between readings.

    Parameters
    ----------
    rms : float
        Its standard deviation at a reading, map units (0: none).
    corr_m : float
        The correlation length of its Gaussian covariance, metres (with ``covariance``
        None).
    covariance : callable, optional
        ``covariance(points (k, 2)) -> (k, k)``, map units squared, in place of the
        Gaussian covariance (a map posterior's).
    """

    rms: float = 0.0
    corr_m: float = 0.0
    covariance: Callable[[np.ndarray], np.ndarray] | None = None

    def between(self, points: np.ndarray) -> np.ndarray:
        """``(k, k)`` the error's covariance between ``points`` (metres), map units squared."""
        if self.covariance is not None:
            return np.asarray(self.covariance(points), dtype=float)
        return gaussian_covariance(points, self.rms, self.corr_m)


def posterior_problem(trial, error_rms: float, error_corr_m: float, posterior):
    """The trial and correlated error a bound takes, with or without a map posterior.

    Parameters
    ----------
    trial : Trial
        The mission.
    error_rms, error_corr_m : float
        The Gaussian correlated error's standard deviation (map units) and length
        (metres), used without ``posterior``.
    posterior : MapPosterior or None
        The field given the prior map (:func:`geofix.maps.error_posterior.map_posterior`).

    Returns
    -------
    tuple
        ``(trial, CorrelatedError)``: with ``posterior`` the trial with its prior map the
        posterior's mean and the error the posterior's covariance; otherwise the trial and
        the Gaussian error of ``error_rms`` over ``error_corr_m``.
    """
    if posterior is None:
        return trial, CorrelatedError(float(error_rms), float(error_corr_m))
    error = CorrelatedError(math.sqrt(max(posterior.variance, 0.0)), 0.0, posterior.covariance)
    return replace(trial, prior_map=posterior.mean), error


def gaussian_covariance(points: np.ndarray, rms: float, corr_m: float) -> np.ndarray:
    """``rms^2 exp(-|q_i - q_j|^2 / (2 L^2))`` between points, built in place.

    Parameters
    ----------
    points : numpy.ndarray
        ``(k, 2)`` positions, metres.
    rms : float
        Standard deviation, map units.
    corr_m : float
        Correlation length ``L``, metres (> 0).

    Returns
    -------
    numpy.ndarray
        ``(k, k)`` covariance, map units squared.
    """
    q = np.asarray(points, dtype=float)
    q = (q - q.mean(axis=0)) / corr_m
    corr = q @ q.T  # exp(-|qi - qj|^2 / 2) = exp(qi.qj - |qi|^2/2 - |qj|^2/2), in place
    half = 0.5 * np.sum(q * q, axis=1)
    corr -= half[:, None]
    corr -= half[None, :]
    np.minimum(corr, 0.0, out=corr)
    corr[np.diag_indices(q.shape[0])] = 0.0
    np.exp(corr, out=corr)
    corr *= rms**2
    return corr


def check_correlated_error(error_rms: float, error_corr_m: float) -> None:
    """Refuse a negative rms or length, or an rms without a positive length (ValueError)."""
    if error_rms < 0 or error_corr_m < 0 or (error_rms > 0 and not error_corr_m > 0):
        raise ValueError(
            "error_rms must be >= 0 and error_corr_m > 0 with it, got "
            f"{error_rms} and {error_corr_m}"
        )


class _Beams:
    """Every valid beam of a trial as one reading: sample, gradient, field, footprint, var.

    ``beam`` is each reading's beam index in its field's readings at its sample.
    """

    def __init__(self, sample, gradient, field, footprint, white, beam) -> None:
        self.sample = np.asarray(sample, int)
        self.beam = np.asarray(beam, int)
        self.gradient = np.asarray(gradient, float)
        self.field = np.asarray(field, int)
        self.footprint = np.asarray(footprint, float)
        self.white = np.asarray(white, float)


def trial_beams(trial, grid: Grid, error_rms: float, beam_var) -> _Beams:
    """The trial's valid beams, the primary field's first (field 0), then each further one.

    Each beam's white variance is the declared one plus the map's error at the track
    beyond ``error_rms^2``; its gradient is the prior map's at its true footprint.
    """
    prior = _prior_of(trial, grid)
    declared = trial_beam_variance(trial) if beam_var is None else beam_var
    excess = max(map_error_variance_at_track(trial, grid, prior) - error_rms**2, 0.0)
    gx, gy = beam_gradients(prior, trial.truth, trial.true_heading, trial.offsets, "bilinear")
    fx, fy = footprint_xy(
        np.asarray(trial.truth, float),
        np.asarray(trial.true_heading, float),
        np.asarray(trial.offsets, float),
    )
    var = np.broadcast_to(np.asarray(declared, float) + excess, gx.shape)
    valid = np.isfinite(trial.measured) & np.isfinite(gx) & np.isfinite(gy)
    parts = [(gx, gy, var, valid, np.stack([fx, fy], axis=-1), 0)]
    for number, field in enumerate(getattr(trial, "fields", ()), start=1):
        hx, hy, hvar, hvalid = _field_gradients(trial, field, prior=True)
        where = np.zeros((*hx.shape, 2))  # uncorrelated: its footprints are not used
        parts.append((hx, hy, np.broadcast_to(hvar, hx.shape), hvalid, where, number))
    sample, gradient, field_of, footprint, white, beam = [], [], [], [], [], []
    for px, py, pvar, pvalid, pfoot, number in parts:
        k, b = np.nonzero(pvalid)
        sample.append(k)
        beam.append(b)
        gradient.append(np.column_stack([px[k, b], py[k, b]]))
        field_of.append(np.full(k.size, number))
        footprint.append(pfoot[k, b])
        white.append(np.maximum(pvar[k, b], 1e-12))
    return _Beams(
        np.concatenate(sample),
        np.concatenate(gradient),
        np.concatenate(field_of),
        np.concatenate(footprint),
        np.concatenate(white),
        np.concatenate(beam),
    )


def reading_covariance(
    beams: _Beams, offset_std, error: CorrelatedError, n: int, extra: int
) -> np.ndarray:
    """``R``: the beams' errors (white, correlated, offsets), then the DVL rows' (unit).

    Parameters
    ----------
    beams : _Beams
        The trial's valid beams (:func:`trial_beams`).
    offset_std : float or array_like
        Every field's constant offset's prior 1-sigma, map units.
    error : CorrelatedError
        The primary field's correlated map error.
    n, extra : int
        Samples, and DVL rows per sample (0: none).

    Returns
    -------
    numpy.ndarray
        ``(N + n extra, N + n extra)`` covariance, map units squared (the DVL rows' unit).
    """
    count = beams.sample.size
    cov = np.zeros((count + n * extra, count + n * extra))
    beam = cov[:count, :count]
    beam[np.diag_indices(count)] = beams.white
    for field, std in enumerate(np.asarray(offset_std, float)):
        index = np.flatnonzero(beams.field == field)
        beam[np.ix_(index, index)] += std**2
    if error.rms > 0:
        primary = np.flatnonzero(beams.field == 0)
        beam[np.ix_(primary, primary)] += error.between(beams.footprint[primary])
    cov[count:, count:] = np.eye(n * extra)
    return cov


def _coefficients(beams: _Beams, motion: LinearMotion, n: int) -> tuple:
    """Each reading's coefficients on its sample's measured part ``z_k = (H x_k, C x_k)``."""
    extra = 0 if motion.extra_rows is None else motion.extra_rows.shape[0]
    m = 2 + extra
    coef = np.zeros((beams.sample.size, m))
    coef[:, :2] = beams.gradient
    rows = np.repeat(np.arange(n), extra)
    dvl = np.zeros((rows.size, m))
    if extra:
        dvl[np.arange(rows.size), 2 + np.tile(np.arange(extra), n)] = 1.0
    return np.vstack([coef, dvl]), np.concatenate([beams.sample, rows])


def state_covariances(motion: LinearMotion) -> tuple:
    """The prior covariances of a linear motion's measured parts, and of its last state.

    The measured part at sample ``k`` is ``z_k = E x_k`` with ``E = (H; C)``: the position
    error and, with a DVL, its whitened velocity rows. With ``P_k`` the prior covariance of
    ``x_k`` (``P_{k+1} = F_k P_k F_k^T + Q_k``) and ``Cov(x_l, x_k) = F_{l-1} ... F_k P_k``
    for ``l >= k``.

    Parameters
    ----------
    motion : LinearMotion
        The vehicle's error state, ``n`` samples (``n - 1`` transitions).

    Returns
    -------
    tuple of numpy.ndarray
        ``(P_n (d, d), Z (n, n, m, m), X (d, n, m))``: the last state's prior covariance,
        ``Z[l, k] = Cov(z_l, z_k)`` and ``X[:, k] = Cov(x_n, z_k)``.
    """
    e = motion.position_map
    if motion.extra_rows is not None:
        e = np.vstack([e, motion.extra_rows])
    m, d = e.shape
    n = motion.transitions.shape[0] + 1
    z = np.empty((n, n, m, m))
    carried = np.empty((n, d, m))  # Cov(x_l, z_k) for k <= l, carried forward in l
    p = np.asarray(motion.prior_cov, float)
    for step in range(n):
        carried[step] = p @ e.T
        block = e @ carried[: step + 1]  # (step + 1, m, m): Cov(z_l, z_k), k <= l
        z[step, : step + 1] = block
        z[: step + 1, step] = block.transpose(0, 2, 1)
        if step < n - 1:
            f = motion.transitions[step]
            carried[: step + 1] = f @ carried[: step + 1]
            p = f @ p @ f.T + motion.process_cov[step]
    return p, z, carried.transpose(1, 0, 2)
