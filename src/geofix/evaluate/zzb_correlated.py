r"""The Ziv–Zakai bound of the end point with the map's error correlated along the track.

:func:`geofix.evaluate.crlb_correlated.correlated_map_crlb` bounds the end point of the
problem a vehicle with an imperfect prior map has (a still, unknown offset; the map's
error correlated between every two readings), but as every Cramér–Rao bound it adds up
the map's gradients at the true footprints: where the readings' likelihood keeps far modes
(a smooth field, a map error of kilometres that a wrong path's residuals can absorb) it
lies far below what any estimator reaches. The Ziv–Zakai bound sees those modes
(:mod:`geofix.evaluate.zzb`); this is its version for the same reading covariance.

**The problem bounded.** As for :func:`geofix.evaluate.zzb.zzb_track`, the estimator is
told the INS drift after the start, so only the initial offset ``e_0`` is unknown, with
the Gaussian prior ``P`` of :func:`geofix.evaluate.ambiguity.initial_offset_prior`; extra
information cannot make the best estimator worse, so the bound on ``e_0`` bounds the end
point's error of any estimator. The readings of the whole mission are jointly Gaussian
about the prior map read at their footprints, with the covariance ``R`` of the correlated
bound: each beam's white variance (sensor noise plus the map error beyond the correlated
part), the offset's prior variance common to every reading, and ``s^2 exp(-|q_i -
q_j|^2 / (2 L^2))`` between the footprints ``q``
(:func:`geofix.evaluate.crlb_correlated.reading_covariance`).

**The bound.** Two start offsets ``delta`` apart give readings of the same covariance
``R`` whose means differ by ``m(q) - m(q - delta)``, the prior map read at the true
footprints and at the footprints shifted by ``-delta``; the least error probability
between them is ``Q(d / 2)`` with ``d^2 = (m(q) - m(q - delta))^T R^-1 (m(q) - m(q -
delta))``, so the pair term and the integral are :func:`geofix.evaluate.zzb.pair_term`
and :func:`geofix.evaluate.zzb.ziv_zakai_integral` on the grids of shifts of
:class:`geofix.evaluate.zzb.ShiftLadder`. On a plane ``d^2 = delta^T G^T R^-1 G delta``
and the bound is the linear-Gaussian posterior ``(P^-1 + G^T R^-1 G)^-1`` up to the
shift grid's resolution (the tests hold the two together). A shifted footprint off the
map reads nothing where the sensor read a value: that pair is told apart (``A = 0``).

**Cost.** One Cholesky factor of ``R`` (every valid beam of the mission) and, per shift,
the map read at every beam: a gravimeter's hundreds of readings are nothing, a multibeam
mission's tens of thousands of beams are refused with the memory estimate
(:func:`geofix.memory.check_allocation`). One field only: a bound that left a further
field's readings out would not bound an estimator that uses them, so a trial with
further fields is refused.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import cholesky, solve_triangular

from geofix.evaluate.ambiguity import initial_offset_prior, likelihood_width
from geofix.evaluate.crlb import _prior_of, trial_offset_model
from geofix.evaluate.crlb_correlated import (
    check_correlated_error,
    posterior_problem,
    reading_covariance,
    trial_beams,
)
from geofix.evaluate.zzb import ShiftLadder, bound_of_levels, shift_levels
from geofix.maps.error_posterior import MapPosterior
from geofix.maps.grid import Grid
from geofix.memory import cells_bytes, check_allocation

__all__ = [
    "CORRELATED_LADDER",
    "correlated_map_zzb",
    "one_field_problem",
    "readings_factor",
    "whitened_misfits",
]

#: The shift grids of the correlated bound: the track bound's.
CORRELATED_LADDER = ShiftLadder()
#: Shifts whose reads are held at once (the memory of one batch: this many times the
#: readings, three copies).
SHIFT_BATCH = 4096


def correlated_map_zzb(
    trial,
    grid: Grid,
    error_rms: float = 0.0,
    error_corr_m: float = 0.0,
    offset_std=None,
    beam_var=None,
    ladder: ShiftLadder | None = None,
    posterior: MapPosterior | None = None,
) -> float:
    """Ziv–Zakai bound on the end point's position error, the map error correlated, m^2.

    Parameters
    ----------
    trial : Trial
        The mission: true track and headings, beams, readings (NaN beams carry nothing),
        its ``prior_map`` (None: the seabed ``grid`` is the prior) and INS error model
        (the prior of the start error). One field: a trial with further ``fields`` is
        refused.
    grid : Grid
        The seabed: the map the readings were drawn from.
    error_rms : float
        Standard deviation ``s`` of the map error correlated along the track, map units
        (0: none).
    error_corr_m : float
        Its correlation length ``L``, metres (> 0 when ``error_rms`` > 0).
    offset_std : float, optional
        The still offset's prior 1-sigma, map units (0: known); default the prior map's
        (:func:`geofix.evaluate.crlb.trial_offset_model`).
    beam_var : float or array_like, optional
        The declared measurement variance, map units squared; default
        :func:`geofix.evaluate.crlb.trial_beam_variance`.
    ladder : ShiftLadder, optional
        The grids of shifts (default :data:`CORRELATED_LADDER`).
    posterior : MapPosterior, optional
        The field given the prior map when the map's error was added to the field: the
        shifted reads are its mean's and the correlated error its covariance
        (:func:`geofix.evaluate.crlb_correlated.correlated_map_crlb`).

    Returns
    -------
    float
        Lower bound on ``E|e_hat - e|^2`` at the last sample, m^2 (0 when the start
        error is known).

    Raises
    ------
    ValueError
        ``error_rms`` > 0 without a positive ``error_corr_m``, or the trial has further
        fields.
    MemoryBudgetError
        The readings' covariance or the shifted reads would not fit the memory budget.
    """
    trial, error = one_field_problem(
        trial, error_rms, error_corr_m, posterior, "the correlated Ziv-Zakai bound"
    )
    ladder = ladder or CORRELATED_LADDER
    _, prior = initial_offset_prior(trial)
    values, axes = np.linalg.eigh(prior)
    if not values.min() > 0:
        return 0.0
    sd = np.sqrt(values)
    beams, factor = readings_factor(trial, grid, error, offset_std, beam_var)
    prior_map = _prior_of(trial, grid)
    footprint = beams.footprint
    read = prior_map.sample(footprint[:, 0], footprint[:, 1])
    width = float(np.min(likelihood_width(trial, prior_map, beams.white.mean())))
    levels = shift_levels(sd, width, ladder)
    d2 = [_distances(prior_map, footprint, read, factor, axes, u, v) for u, v in levels]
    return bound_of_levels(levels, d2, sd)


def one_field_problem(trial, error_rms: float, error_corr_m: float, posterior, bound: str):
    """The trial and correlated error of a bound that takes one field (:func:`posterior_problem`).

    Parameters
    ----------
    trial : Trial
        The mission.
    error_rms, error_corr_m : float
        The Gaussian correlated error (map units, metres), without ``posterior``.
    posterior : MapPosterior or None
        The field given the prior map.
    bound : str
        The bound's name, for the message.

    Raises
    ------
    ValueError
        An rms without a positive length, or a trial with further fields.
    """
    check_correlated_error(error_rms, error_corr_m)
    trial, error = posterior_problem(trial, error_rms, error_corr_m, posterior)
    if getattr(trial, "fields", ()):
        raise ValueError(f"{bound} takes one field; the trial has more")
    return trial, error


def readings_factor(trial, grid: Grid, error, offset_std, beam_var):
    """The trial's valid beams and the lower Cholesky factor of their covariance.

    Parameters
    ----------
    trial : Trial
        The mission (one field).
    grid : Grid
        The seabed.
    error : CorrelatedError
        The correlated map error.
    offset_std : float or None
        The still offset's prior 1-sigma, map units; default the prior map's.
    beam_var : float, array_like or None
        The declared measurement variance, map units squared.

    Returns
    -------
    tuple
        ``(beams, factor (N, N))`` (:func:`geofix.evaluate.crlb_correlated.trial_beams`).

    Raises
    ------
    MemoryBudgetError
        The readings' covariance would not fit the memory budget.
    """
    beams = trial_beams(trial, grid, error.rms, beam_var)
    count = beams.sample.size
    check_allocation(cells_bytes(count, count, copies=3), f"the covariance of {count} readings")
    std, _ = trial_offset_model(trial, grid, offset_std, 0.0)
    n = np.asarray(trial.truth).shape[0]
    cov = reading_covariance(beams, std, error, n, 0)
    return beams, cholesky(cov, lower=True, overwrite_a=True)


def whitened_misfits(prior_map: Grid, footprint, reference, factor, shifts) -> np.ndarray:
    """``(S,)`` ``r^T R^-1 r`` of ``r = reference - map(footprint - shift)`` per shift.

    Parameters
    ----------
    prior_map : Grid
        The map the estimator reads.
    footprint : numpy.ndarray
        ``(N, 2)`` the readings' footprints, metres.
    reference : numpy.ndarray
        ``(N,)`` what the shifted reads are compared with, map units.
    factor : numpy.ndarray
        ``(N, N)`` lower Cholesky factor of ``R``.
    shifts : numpy.ndarray
        ``(S, 2)`` shifts, metres.

    Returns
    -------
    numpy.ndarray
        The misfits (inf where a shift reads off the map).
    """
    check_allocation(
        cells_bytes(min(SHIFT_BATCH, shifts.shape[0]), footprint.shape[0], copies=3),
        f"the map read at {footprint.shape[0]} footprints for {SHIFT_BATCH} shifts",
    )
    out = np.empty(shifts.shape[0])
    for start in range(0, shifts.shape[0], SHIFT_BATCH):
        batch = shifts[start : start + SHIFT_BATCH]
        x = footprint[None, :, 0] - batch[:, None, 0]
        y = footprint[None, :, 1] - batch[:, None, 1]
        diff = reference[None, :] - prior_map.sample(x, y)  # (S, N)
        off = ~np.isfinite(diff).all(axis=1)
        white = solve_triangular(factor, np.where(np.isfinite(diff), diff, 0.0).T, lower=True)
        out[start : start + batch.shape[0]] = np.where(off, np.inf, np.sum(white * white, axis=0))
    return out


def _distances(prior_map: Grid, footprint, read, factor, axes, u, v) -> np.ndarray:
    """``(u.size, v.size)`` ``d^2`` of every shift ``u a_0 + v a_1`` (inf: read off the map).

    Parameters
    ----------
    prior_map : Grid
        The map the estimator reads.
    footprint : numpy.ndarray
        ``(N, 2)`` the readings' true footprints, metres.
    read : numpy.ndarray
        ``(N,)`` the prior map there.
    factor : numpy.ndarray
        ``(N, N)`` lower Cholesky factor of the readings' covariance.
    axes : numpy.ndarray
        ``(2, 2)`` the prior's principal axes as columns.
    u, v : numpy.ndarray
        Shifts along them, metres.
    """
    shifts = (u[:, None, None] * axes[:, 0] + v[None, :, None] * axes[:, 1]).reshape(-1, 2)
    return whitened_misfits(prior_map, footprint, read, factor, shifts).reshape(u.size, v.size)
