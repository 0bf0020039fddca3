"""Integrity checks shared by the batch matchers: terrain SNR and information covariance.

A matcher's own integrity test (a residual that fits the noise, a cost surface with one
clear minimum) says nothing on terrain flatter than the sensor noise: there every
position fits, and a residual-only flag passes a confident wrong fix. Two terrain-based
checks, independent of how the matcher searched:

- :func:`terrain_snr` -- the standard deviation of the map over the matched footprints in
  sensor-noise sigmas; a fix on terrain whose relief drowns in the noise (ratio below
  the matcher's ``min_terrain_snr``: 1 for TERCOM, ICCP and ICP, 0.6 for GA-SCA, whose
  rival test covers the rest) cannot be told from its neighbours and is flagged ambiguous;
- :func:`information_covariance` -- the Cramér–Rao bound of a rigid translation of the
  matched track (:mod:`geofix.measurement`: map gradients at every footprint, sensor
  plus map-error variance), combined with the INS prior of the matching window, and
  :func:`cover_covariance`, which widens a matcher's own covariance to be no smaller than
  that bound (a Laplace approximation of a noisy residual surface can be arbitrarily
  narrow on a flat map; no unbiased estimator does better than the bound).

:func:`terrain_integrity` applies both to a matcher's fix in one call. The bound is
local: on a plain with micro-relief (a 2 m survey of ripples) it is a few metres while
the cost surface has many equally good minima far apart, so only the flag, not the
covariance, guards against a wrong fix there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geofix.measurement import beam_gradients, predict_track, sample_information
from geofix.problem import MatchProblem


def _footprint_values(problem: MatchProblem, track, heading=None, beams=None) -> np.ndarray:
    """Map values at the footprints of the measured (non-NaN) beams, NaN-free."""
    beams = np.arange(problem.offsets.shape[0]) if beams is None else np.asarray(beams)
    heading = problem.heading if heading is None else heading
    values = predict_track(problem.grid, track, heading, problem.offsets[beams])
    values = values[np.isfinite(problem.measured[:, beams])]
    return values[np.isfinite(values)]


def terrain_snr(problem: MatchProblem, track: np.ndarray, heading=None, beams=None) -> float:
    """Terrain-to-noise ratio along a track: map std over its footprints / sensor noise.

    Parameters
    ----------
    problem : MatchProblem
        Map, headings, beam offsets, measurements (footprints of missing measurements
        are left out) and ``noise_std`` (map units).
    track : numpy.ndarray
        ``(n, 2)`` vehicle positions, metres.
    heading : numpy.ndarray, optional
        ``(n,)`` headings of the track, radians clockwise from north (default: the
        problem's indicated headings).
    beams : array_like of int, optional
        Beam indices to use (default: all).

    Returns
    -------
    float
        ``std(map at the footprints) / noise_std`` (dimensionless); ``inf`` without noise,
        0 when fewer than two footprints are on valid data.
    """
    values = _footprint_values(problem, track, heading, beams)
    if values.size < 2:
        return 0.0
    if problem.noise_std <= 0:
        return float("inf")
    return float(np.std(values) / problem.noise_std)


def residual_design_effect(residual: np.ndarray) -> float:
    """How many times fewer independent residuals a fit has than it has values.

    The variance of the residuals' sum over that of independent ones (Kish's design
    effect): within each ping (a map error shared by the beams of a swath), times along
    the track (one that persists from ping to ping). Within: ``sum_k b_k^2 m_k^2 /
    (s^2 sum_k b_k)`` with ``m_k`` the mean centred residual of ping ``k`` over its
    ``b_k`` beams and ``s^2`` their variance (1 for independent beams, ``b`` for a shared
    error). Along: ``1 + 2 sum_j rho_j`` over the lags of the ping means' autocorrelation
    up to the first that is not positive (the initial positive sequence). Each factor at
    least 1.

    Parameters
    ----------
    residual : numpy.ndarray
        ``(n, b)`` measured minus map along the fitted track, map units (NaN: missing).

    Returns
    -------
    float
        The design effect, at least 1 (1 with fewer than two values or no spread).
    """
    r = np.asarray(residual, dtype=float)
    r = r.reshape(r.shape[0], -1)
    ok = np.isfinite(r)
    if ok.sum() < 2:
        return 1.0
    centred = np.where(ok, r - r[ok].mean(), 0.0)
    var = float(np.sum(centred**2) / ok.sum())
    if var <= 0:
        return 1.0
    counts = ok.sum(axis=1)
    pings = counts > 0
    means = centred.sum(axis=1)[pings] / counts[pings]
    within = float(np.sum(counts[pings] ** 2 * means**2) / (var * counts.sum()))
    return max(within, 1.0) * _along_track_effect(means)


def _along_track_effect(series: np.ndarray) -> float:
    """``1 + 2 sum_j rho_j`` over the initial positive autocorrelations, at least 1."""
    x = series - series.mean()
    n = x.size
    denom = float(np.dot(x, x))
    if n < 3 or denom <= 0:
        return 1.0
    total = 1.0
    for lag in range(1, n // 2):
        rho = float(np.dot(x[:-lag], x[lag:])) / denom
        if rho <= 0:
            break
        total += 2.0 * rho
    return total


def information_covariance(
    problem: MatchProblem, track: np.ndarray, heading=None, beams=None
) -> np.ndarray:
    """Cramér–Rao bound of a rigid translation of ``track``, with the window's INS prior.

    ``(sum_k sum_b g g^T / var + I / sigma_p^2)^-1`` with ``g`` the map gradient at every
    footprint of a measured beam, ``var`` its sensor plus map-error variance
    (:meth:`MatchProblem.beam_noise_var`) and
    ``sigma_p`` the largest prior sigma of the problem (the matchers search a window of a
    few of them, so the fix is never less certain than the prior).

    Parameters
    ----------
    problem : MatchProblem
        Map, beam offsets, measurements, per-beam noise (map units) and
        ``sigma_position`` (metres).
    track : numpy.ndarray
        ``(n, 2)`` matched vehicle positions, metres.
    heading : numpy.ndarray, optional
        ``(n,)`` headings of the matched track, radians (default: the indicated ones).
    beams : array_like of int, optional
        Beam indices the matcher used (default: all).

    Returns
    -------
    numpy.ndarray
        ``(2, 2)`` covariance bound, m^2.
    """
    beams = np.arange(problem.offsets.shape[0]) if beams is None else np.asarray(beams)
    heading = problem.heading if heading is None else heading
    gx, gy = beam_gradients(problem.grid, track, heading, problem.offsets[beams], "bilinear")
    var = np.maximum(problem.beam_noise_var()[beams], 1e-12)
    info = sample_information(gx, gy, var, valid=np.isfinite(problem.measured[:, beams]))
    prior_var = max(float(np.max(problem.sigma_position)), problem.grid.cell_size) ** 2
    return np.linalg.inv(info.sum(axis=0) + np.eye(2) / prior_var)


def cover_covariance(covariance, bound: np.ndarray) -> np.ndarray:
    """A covariance no smaller than either input (in the positive-semidefinite order).

    In the frame where ``covariance`` is the identity, the eigenvalues of ``bound`` below
    1 are raised to 1: the result is ``covariance`` widened only along the directions in
    which ``bound`` is larger.

    Parameters
    ----------
    covariance : numpy.ndarray or None
        ``(2, 2)`` a matcher's own covariance, m^2 (None or unusable: ``bound`` is used).
    bound : numpy.ndarray
        ``(2, 2)`` positive-definite lower bound, m^2.

    Returns
    -------
    numpy.ndarray
        ``(2, 2)`` symmetric covariance, m^2.
    """
    bound = np.asarray(bound, float)
    if covariance is None or not np.isfinite(covariance).all():
        return bound.copy()
    try:
        chol = np.linalg.cholesky(np.asarray(covariance, float))
    except np.linalg.LinAlgError:
        return bound.copy()
    inv = np.linalg.inv(chol)
    values, vectors = np.linalg.eigh(inv @ bound @ inv.T)
    lift = chol @ vectors * np.sqrt(np.maximum(values, 1.0))
    out = lift @ lift.T
    return 0.5 * (out + out.T)


@dataclass(frozen=True, eq=False)
class TerrainIntegrity:
    """Terrain-based integrity of one fix.

    Attributes
    ----------
    covariance : numpy.ndarray
        ``(2, 2)`` the matcher's covariance widened to the information bound, m^2.
    flat : bool
        True when the terrain-to-noise ratio is below the matcher's threshold.
    snr : float
        Terrain-to-noise ratio along the fix (dimensionless).
    """

    covariance: np.ndarray
    flat: bool
    snr: float


def terrain_integrity(
    problem: MatchProblem, track, covariance, min_snr: float, heading=None, beams=None
) -> TerrainIntegrity:
    """Terrain SNR flag and bound-covering covariance of a fix, in one call.

    Parameters
    ----------
    problem : MatchProblem
        The matched problem.
    track : numpy.ndarray
        ``(n, 2)`` matched vehicle positions, metres.
    covariance : numpy.ndarray or None
        ``(2, 2)`` the matcher's own covariance of the fix, m^2.
    min_snr : float
        Smallest terrain-to-noise ratio at which the fix is trusted (dimensionless).
    heading : numpy.ndarray, optional
        ``(n,)`` headings of the matched track, radians (default: the indicated ones).
    beams : array_like of int, optional
        Beam indices the matcher used (default: all).

    Returns
    -------
    TerrainIntegrity
        ``cover_covariance(covariance, information_covariance(...))``, the flag and the
        ratio.
    """
    snr = terrain_snr(problem, track, heading, beams)
    bound = information_covariance(problem, track, heading, beams)
    return TerrainIntegrity(cover_covariance(covariance, bound), bool(snr < min_snr), snr)
