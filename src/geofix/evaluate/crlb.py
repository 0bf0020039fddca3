"""Cramér–Rao lower bounds on the position error of terrain / gravity matching.

The measurement of beam ``b`` at sample ``k`` is ``h(p_k + r_kb) + noise`` with the map
``h`` read at the beam footprint ``p_k + r_kb`` and Gaussian noise of variance
``var_b`` (sensor plus map error). Its Fisher information about the vehicle position
``p_k`` is ``g g^T / var_b``, with ``g`` the map gradient at the footprint, so one
sample carries

    I_k = sum_b g_kb g_kb^T / var_b                       (2 x 2, 1/m^2)

read along the *true* track (the bound is a property of the terrain actually crossed).

- **Batch** bound (a rigid translation of a whole track, as TERCOM / ICCP estimate it):
  ``J = sum_k I_k`` and ``cov >= J^-1``; singular (infinite) on a flat or straight-ridge
  track.
- **Recursive** bound (posterior CRLB, Tichavský et al. 1998) for the filters, whose state
  is the position error with additive process noise ``Q_k`` per axis (the growth of the
  INS prior variance between samples, exactly as :func:`geofix.filters.base.motions`
  derives it) and a Gaussian prior of variance ``sigma_position[0]^2`` at the first
  sample::

      J_0 = I / sigma_0^2 + I_0
      J_k = (J_{k-1}^-1 + Q_k I)^-1 + I_k

  The bound on the RMS position error at sample ``k`` is ``sqrt(trace(J_k^-1))``.

Map gradients are central differences (:func:`geofix.maps.terrain.gradient`) read by
bilinear interpolation at every footprint; a gradient that cannot be formed (next to
no-data) carries no information. A gravimeter's first-order lag is ignored (the bound is
then slightly optimistic).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from geofix.maps.grid import Grid
from geofix.maps.terrain import gradient
from geofix.match.base import footprint_xy

#: Smallest per-step process variance, m^2 (the same floor as the filters' motion model).
MIN_PROCESS_VAR = 1e-6


@dataclass(frozen=True)
class TrialBound:
    """CRLBs of one trial (variances summed over both axes, m^2).

    Attributes
    ----------
    recursive_var_m2 : float
        ``trace(J_n^-1)`` of the recursive bound at the last sample, m^2.
    batch_var_m2 : float
        ``trace(J^-1)`` of the batch bound over the last leg, m^2 (``inf`` if singular).
    """

    recursive_var_m2: float
    batch_var_m2: float

    @property
    def recursive_m(self) -> float:
        """Bound on the end-point RMS error of a recursive filter, metres."""
        return float(np.sqrt(self.recursive_var_m2))

    @property
    def batch_m(self) -> float:
        """Bound on the RMS error of a rigid batch fix of the last leg, metres."""
        return float(np.sqrt(self.batch_var_m2))


@functools.lru_cache(maxsize=4)
def gradient_grids(grid: Grid) -> tuple[Grid, Grid]:
    """The map's gradient along x and y as two grids (NaN where it cannot be formed).

    Parameters
    ----------
    grid : Grid
        The map (cached by identity: a campaign worker computes it once).

    Returns
    -------
    tuple of Grid
        ``(gx, gy)`` in field units per metre, on the map's cells.
    """
    gx, gy = gradient(grid)
    return grid.with_values(gx), grid.with_values(gy)


def beam_gradients(grid: Grid, track, heading, offsets) -> tuple[np.ndarray, np.ndarray]:
    """Map gradient at every beam footprint of a track.

    Parameters
    ----------
    grid : Grid
        The map.
    track : array_like
        ``(n, 2)`` vehicle positions, metres.
    heading : array_like
        ``(n,)`` headings, radians clockwise from north.
    offsets : array_like
        ``(b, 2)`` body-frame beam offsets ``(across, along)``, metres.

    Returns
    -------
    tuple of numpy.ndarray
        ``(gx, gy)`` each ``(n, b)``, field units per metre; 0 where no gradient exists.
    """
    gxg, gyg = gradient_grids(grid)
    x, y = footprint_xy(
        np.asarray(track, float), np.asarray(heading, float), np.asarray(offsets, float)
    )
    gx = np.nan_to_num(gxg.sample(x, y), nan=0.0)
    gy = np.nan_to_num(gyg.sample(x, y), nan=0.0)
    return gx, gy


def sample_information(gx, gy, beam_var, valid=None) -> np.ndarray:
    """Fisher information of each sample about the vehicle position.

    Parameters
    ----------
    gx, gy : array_like
        ``(n, b)`` map gradients at the footprints, field units per metre.
    beam_var : float or array_like
        Measurement variance, field units squared: a scalar or ``(b,)`` per beam.
    valid : array_like of bool, optional
        ``(n, b)``; False for a missing measurement (it carries no information).

    Returns
    -------
    numpy.ndarray
        ``(n, 2, 2)`` information matrices, 1/m^2.
    """
    gx = np.asarray(gx, float)
    gy = np.asarray(gy, float)
    w = np.broadcast_to(1.0 / np.asarray(beam_var, float), gx.shape)
    if valid is not None:
        w = np.where(valid, w, 0.0)
    sxx = (w * gx * gx).sum(axis=-1)
    sxy = (w * gx * gy).sum(axis=-1)
    syy = (w * gy * gy).sum(axis=-1)
    return np.stack([np.stack([sxx, sxy], -1), np.stack([sxy, syy], -1)], -2)


def inverse_trace(info: np.ndarray) -> np.ndarray:
    """``trace(J^-1)`` of 2 x 2 information matrices, ``inf`` where singular.

    Parameters
    ----------
    info : numpy.ndarray
        ``(..., 2, 2)`` symmetric positive semi-definite matrices, 1/m^2.

    Returns
    -------
    numpy.ndarray
        ``(...)`` traces of the inverses, m^2 (``trace / det``).
    """
    info = np.asarray(info, float)
    trace = info[..., 0, 0] + info[..., 1, 1]
    det = info[..., 0, 0] * info[..., 1, 1] - info[..., 0, 1] * info[..., 1, 0]
    singular = det <= 1e-12 * np.maximum(trace, 1e-300) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(singular, np.inf, trace / np.where(singular, 1.0, det))


def batch_bound(info: np.ndarray) -> np.ndarray:
    """Covariance bound ``J^-1`` of a rigid translation estimated from samples ``info``.

    Parameters
    ----------
    info : numpy.ndarray
        ``(n, 2, 2)`` per-sample information, 1/m^2.

    Returns
    -------
    numpy.ndarray
        ``(2, 2)`` covariance bound, m^2; every entry ``inf`` when ``J`` is singular.
    """
    total = np.asarray(info, float).sum(axis=0)
    if not np.isfinite(inverse_trace(total)):
        return np.full((2, 2), np.inf)
    return np.linalg.inv(total)


def process_variances(sigma_position) -> np.ndarray:
    """Per-axis process variance of each step, m^2: ``max(diff(sigma^2), 1e-6)``.

    Parameters
    ----------
    sigma_position : array_like
        ``(n,)`` prior per-axis 1-sigma of the INS position error, metres.

    Returns
    -------
    numpy.ndarray
        ``(n - 1,)`` variances, m^2 (as :func:`geofix.filters.base.motions`).
    """
    return np.maximum(np.diff(np.asarray(sigma_position, float) ** 2), MIN_PROCESS_VAR)


def recursive_bound(info: np.ndarray, process_var, prior_var: float) -> np.ndarray:
    """Posterior CRLB of a random-walk position error at every sample.

    Parameters
    ----------
    info : numpy.ndarray
        ``(n, 2, 2)`` per-sample measurement information, 1/m^2.
    process_var : array_like
        ``(n - 1,)`` per-axis process variance of each step, m^2.
    prior_var : float
        Per-axis prior variance at the first sample, m^2 (floored at ``1e-6``: a start
        known exactly).

    Returns
    -------
    numpy.ndarray
        ``(n, 2, 2)`` covariance bounds ``J_k^-1``, m^2.
    """
    info = np.asarray(info, float)
    q = np.asarray(process_var, float)
    eye = np.eye(2)
    bounds = np.empty_like(info)
    j = eye / max(float(prior_var), MIN_PROCESS_VAR) + info[0]
    bounds[0] = _inverse_information(j)
    for k in range(1, info.shape[0]):
        j = _inverse_information(bounds[k - 1] + q[k - 1] * eye) + info[k]
        bounds[k] = _inverse_information(j)
    return bounds


def _inverse_information(j: np.ndarray) -> np.ndarray:
    """``inv(j)`` of a symmetric 2x2 information (or covariance) matrix.

    When ``j`` is singular in floating point (a huge prior variance next to a strong
    gradient along one direction leaves the other direction's information below the
    rounding of the first), its eigenvalues are floored at ``1e-15`` of the largest: the
    bound along the direction the data says nothing about is then huge, as it should be.
    """
    try:
        return np.linalg.inv(j)
    except np.linalg.LinAlgError:
        values, vectors = np.linalg.eigh(0.5 * (j + j.T))
        floor = max(float(np.max(np.abs(values))) * 1e-15, np.finfo(float).tiny)
        return (vectors / np.maximum(values, floor)) @ vectors.T


def trial_beam_variance(trial) -> np.ndarray:
    """Per-beam measurement variance a trial declares, field units squared.

    Parameters
    ----------
    trial : Trial
        Its ``beam_noise_std`` ``(b,)`` (or ``noise_std`` for every beam when it has none)
        and ``map_error_std``.

    Returns
    -------
    numpy.ndarray
        ``(b,)`` ``beam_noise_std^2 + map_error_std^2``; for a simulated trial equal to
        :func:`scenario_beam_variance` of its scenario.
    """
    beams = np.asarray(trial.offsets).shape[0]
    std = getattr(trial, "beam_noise_std", None)
    std = np.full(beams, float(trial.noise_std)) if std is None else np.asarray(std, float)
    return std**2 + float(trial.map_error_std) ** 2


def trial_information(trial, grid: Grid, beam_var=None) -> np.ndarray:
    """Per-sample information along a trial's true track, 1/m^2, shape ``(n, 2, 2)``.

    ``beam_var`` (field units squared, scalar or ``(b,)``) defaults to
    :func:`trial_beam_variance` (the trial's per-beam noise plus map error).
    """
    if beam_var is None:
        beam_var = trial_beam_variance(trial)
    beam_var = np.maximum(np.asarray(beam_var, float), 1e-12)
    gx, gy = beam_gradients(grid, trial.truth, trial.true_heading, trial.offsets)
    return sample_information(gx, gy, beam_var, valid=np.isfinite(trial.measured))


def trial_crlb(trial, grid: Grid, beam_var=None) -> TrialBound:
    """Recursive (whole mission) and batch (last leg) CRLBs of one trial.

    Parameters
    ----------
    trial : Trial
        The mission; its true track, headings, beam offsets, measurements (NaN beams carry
        no information) and prior ``sigma_position``.
    grid : Grid
        The map the measurements were drawn from.
    beam_var : float or array_like, optional
        Measurement variance, field units squared, scalar or ``(b,)`` per beam; default
        :func:`trial_beam_variance` (the trial's per-beam noise plus map error).

    Returns
    -------
    TrialBound
        ``trace`` of the bounds, m^2.
    """
    info = trial_information(trial, grid, beam_var)
    sigma = np.asarray(trial.sigma_position, float)
    rec = recursive_bound(info, process_variances(sigma), float(sigma[0]) ** 2)
    last = trial.leg_slices()[-1]
    batch = inverse_trace(info[last].sum(axis=0))
    return TrialBound(float(np.trace(rec[-1])), float(batch))


def scenario_beam_variance(scenario, offsets) -> np.ndarray:
    """Per-beam measurement variance of a scenario's sensor, field units squared.

    Parameters
    ----------
    scenario : Scenario
        Its ``sensor`` block (noise growing towards the swath edges, map error).
    offsets : numpy.ndarray
        ``(b, 2)`` beam offsets, metres.

    Returns
    -------
    numpy.ndarray
        ``(b,)`` sensor noise variance plus map-error variance.
    """
    from geofix.sensors.echosounder import beam_noise_std

    return beam_noise_std(offsets, scenario.sensor) ** 2 + scenario.sensor.map_error_std**2


def rms_bound(variances) -> float | None:
    """The RMS bound over trials, ``sqrt(mean(trace J^-1))``, metres (None if undefined).

    Parameters
    ----------
    variances : array_like
        Per-trial ``trace(J^-1)``, m^2 (NaN entries are skipped).

    Returns
    -------
    float or None
        Metres; None when no finite-or-infinite value is given or the mean is infinite.
    """
    v = np.asarray(variances, float)
    v = v[~np.isnan(v)]
    if v.size == 0:
        return None
    mean = float(v.mean())
    return float(np.sqrt(mean)) if np.isfinite(mean) else None
