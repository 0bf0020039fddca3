r"""The INS drift inside a matching window: what it adds to the covariance of a fix's end.

A batch matcher fits one rigid offset ``o`` to the whole window (a leg) and moves the
indicated track by it; the fix of the last sample is ``indicated[n-1] + o``. The INS
error ``e_k`` (indicated minus true, metres) is not one offset: it changes along the
window. Linearising the fit around the truth, sample ``k`` with per-sample Fisher
information ``I_k`` (``sum_b g g^T / var`` over its beams, ``g`` the map gradient)
pulls the offset towards ``-e_k``, and the least-squares offset is the
information-weighted mean

    o = -sum_k W_k e_k,      W_k = (sum_j I_j)^-1 I_k,      sum_k W_k = I.

The end point is therefore wrong by

    r = e_{n-1} + o = sum_k W_k (e_{n-1} - e_k),

which no matcher's own covariance (the spread of its cost surface under the sensor noise)
contains. The start error of the window (common to every ``e_k``) cancels, so only the
growth of the error inside the window matters. Its covariance, added to the matcher's
own, is :func:`leg_drift_covariance`; two descriptions of the growth are used:

**Independent increments** (:func:`increment_drift_covariance`; any problem). Write
``e_k = e_0 + sum_{j=1..k} d_j`` with independent increments ``d_j`` of per-axis variance
``s_j = sigma_j^2 - sigma_{j-1}^2`` (``sigma`` the problem's prior sigma per axis,
``sigma_position``; negative differences count as 0). Exchanging the sums,

    r = sum_k W_k sum_{j>k} d_j = sum_{j=1..n-1} S_j d_j,     S_j = sum_{k<j} W_k

(``S_j`` the share of the weight on the samples *before* increment ``j``), so

    Cov(r) = sum_j s_j S_j S_j^T,

per axis ``sum_j s_j (j/n)^2`` with equal weights. An increment near the start moves
few samples' share and hardly matters; one near the end moves the end alone and counts
almost in full.

**The INS error-state model** (:func:`model_drift_covariance`; where the problem carries
``ins_model``). The error is ``e_k = H x_k`` with ``x_k = F_k x_{k-1} + w_k``
(:mod:`geofix.nav.errstate`), whose increments are correlated: a velocity error is a ramp
``e_k = e_0 + v t_k``, with ``r = v (t_{n-1} - mean_k t_k)``, i.e. per axis
``sigma_v^2 (T/2)^2`` over an evenly sampled window of duration ``T`` (the increment
model, built from ``sigma_k = sigma_v t_k``, gives about ``sigma_v^2 T^2/2`` for the same
ramp on a first window, and more on later ones: it is the cruder of the two). Here
``Cov(r)`` is exact for the linear model: ``r = sum_k A_k H x_k`` with ``A_k = -W_k``
(plus ``I`` at the last sample) is rewritten backwards, ``lam_{n-1} = A_{n-1} H``,
``lam_k = A_k H + lam_{k+1} F_{k+1}``, as ``r = lam_0 x_0 + sum_{k>=1} lam_k w_k``, so
``Cov(r) = lam_0 P lam_0^T + sum_k lam_k Q_k lam_k^T``. The states at the window's
first sample have the free navigator's covariance at that time (a batch fix resets the
position only; the position does not feed the other states, and its own share cancels
in ``r``), propagated from the alignment at time 0 along a straight line at the window's
first velocity (the turns before the window, which couple the heading error into the
velocity error, are left out).

The problem's ``times`` count from that alignment (a trial's sample times do).

Both describe a rigid offset fitted by (linearised) least squares: TERCOM, IOAP and the
coarse stage of TERCOM-ICP. Matchers that also fit a rotation or a scale (ICCP, ICP,
TERCOM-ICP's fine stage, GA-SCA) absorb part of a smooth drift (a similarity transform
absorbs a constant velocity error on a straight track entirely), so for them the term is
conservative. ABC-MHD matches each position locally, not by one offset over the leg,
and does not use it.
"""

from __future__ import annotations

import numpy as np

from geofix.errors import MatchError
from geofix.measurement import beam_gradients, sample_information
from geofix.nav.errstate import InsErrorModel, error_state, step_velocities
from geofix.problem import MatchProblem, registered_covariance


def information_weights(
    problem: MatchProblem, track: np.ndarray, heading=None, beams=None
) -> np.ndarray:
    """Matrix weights ``W_k = (sum_j I_j)^-1 I_k`` of the samples in a rigid-offset fit.

    Parameters
    ----------
    problem : MatchProblem
        Map, beam offsets, measurements (missing ones carry no information) and per-beam
        noise (:meth:`MatchProblem.beam_noise_var`, map units squared).
    track : numpy.ndarray
        ``(n, 2)`` matched vehicle positions, metres (where the gradients are read).
    heading : numpy.ndarray, optional
        ``(n,)`` headings of the matched track, radians (default: the indicated ones).
    beams : array_like of int, optional
        Beam indices the matcher used (default: all).

    Returns
    -------
    numpy.ndarray
        ``(n, 2, 2)`` dimensionless weights summing to the identity; equal weights
        ``I / n`` where the map gives no information at all (a flat window), and a
        vanishing share of equal weight (``1e-9`` of the total information) where the
        information is singular, so that the sum stays invertible.
    """
    n = problem.n
    beams = np.arange(problem.beams) if beams is None else np.asarray(beams)
    heading = problem.heading if heading is None else heading
    gx, gy = beam_gradients(problem.grid, track, heading, problem.offsets[beams], "bilinear")
    var = np.maximum(problem.beam_noise_var()[beams], 1e-12)
    info = sample_information(gx, gy, var, valid=np.isfinite(problem.measured[:, beams]))
    info = np.nan_to_num(info, nan=0.0, posinf=0.0)
    total = info.sum(axis=0)
    scale = float(np.trace(total))
    if not (np.isfinite(scale) and scale > 0):
        return np.broadcast_to(np.eye(2) / n, (n, 2, 2)).copy()
    ridge = 1e-9 * scale
    info = info + np.eye(2) * (ridge / n)
    return np.linalg.inv(total + np.eye(2) * ridge) @ info


def _matrix_weights(weights, n: int) -> np.ndarray:
    """``(n, 2, 2)`` weights from ``None`` (equal), ``(n,)`` scalars or ``(n, 2, 2)``."""
    if weights is None:
        return np.broadcast_to(np.eye(2) / n, (n, 2, 2)).copy()
    w = np.asarray(weights, dtype=float)
    if w.shape == (n,):
        return w[:, None, None] * np.eye(2)
    if w.shape != (n, 2, 2):
        raise ValueError(f"weights must be (n,) or (n, 2, 2) with n = {n}, got {w.shape}")
    return w


def increment_drift_covariance(sigma, weights=None) -> np.ndarray:
    """Covariance of the end point minus the weighted mean, independent increments.

    ``sum_j s_j S_j S_j^T`` with ``s_j = max(sigma_j^2 - sigma_{j-1}^2, 0)`` and
    ``S_j = sum_{k<j} W_k`` (derivation in the module docstring).

    Parameters
    ----------
    sigma : array_like
        ``(n,)`` per-axis 1-sigma of the INS position error at each sample, metres.
    weights : array_like, optional
        ``(n,)`` scalar or ``(n, 2, 2)`` matrix weights of the samples, summing to 1 (the
        identity); equal by default.

    Returns
    -------
    numpy.ndarray
        ``(2, 2)`` covariance, m^2 (zero when ``sigma`` does not grow).
    """
    sigma = np.asarray(sigma, dtype=float).reshape(-1)
    n = sigma.size
    w = _matrix_weights(weights, n)
    steps = np.maximum(np.diff(sigma**2), 0.0)
    before = np.cumsum(w, axis=0)[:-1]  # S_j for j = 1 .. n-1
    cov = np.einsum("j,jab,jcb->ac", steps, before, before)
    return 0.5 * (cov + cov.T)


def model_drift_covariance(model: InsErrorModel, times, reference, weights=None) -> np.ndarray:
    """Covariance of the end point minus the weighted mean under the INS error-state model.

    Parameters
    ----------
    model : InsErrorModel
        The navigator's datasheet model (:mod:`geofix.nav.errstate`).
    times : array_like
        ``(n,)`` sample times of the window, seconds from the alignment (time 0, where
        the model's prior holds).
    reference : array_like
        ``(n, 2)`` positions of the window (the indicated track), metres; only its steps
        are used.
    weights : array_like, optional
        ``(n,)`` scalar or ``(n, 2, 2)`` matrix weights of the samples, summing to 1 (the
        identity); equal by default.

    Returns
    -------
    numpy.ndarray
        ``(2, 2)`` covariance of ``e_{n-1} - sum_k W_k e_k``, m^2 (derivation in the
        module docstring).
    """
    times = np.asarray(times, dtype=float).reshape(-1)
    reference = np.asarray(reference, dtype=float).reshape(-1, 2)
    n = times.size
    w = _matrix_weights(weights, n)
    if n < 2:
        return np.zeros((2, 2))
    lead = 0
    if times[0] > 0:  # the alignment at time 0, straight at the window's first velocity
        u0 = step_velocities(times[:2], reference[:2])[0]
        times = np.concatenate([[0.0], times])
        reference = np.vstack([reference[0] - u0 * times[1], reference])
        lead = 1
    es = error_state(model, times, reference)
    cov = es.prior_cov
    for k in range(lead):
        cov = es.transitions[k] @ cov @ es.transitions[k].T + es.process_cov[k]
    cov = cov.copy()
    cov[:2, :] = 0.0  # the start position is common to every sample and cancels in r
    cov[:, :2] = 0.0
    # r = sum_k A_k H x_k with A_k = -W_k, plus I at the last sample; backwards,
    # lam_k = A_k H + lam_{k+1} F_{k+1} gives r = lam_0 x_0 + sum_{k>=1} lam_k w_k.
    h = es.position_map
    gains = -w @ h
    gains[-1] += h
    lam = np.empty_like(gains)
    lam[-1] = gains[-1]
    for k in range(n - 2, -1, -1):
        lam[k] = gains[k] + lam[k + 1] @ es.transitions[lead + k]
    out = lam[0] @ cov @ lam[0].T
    out += np.einsum("kad,kde,kbe->ab", lam[1:], es.process_cov[lead:], lam[1:])
    return 0.5 * (out + out.T)


def leg_drift_covariance(
    problem: MatchProblem, track: np.ndarray, heading=None, beams=None
) -> np.ndarray:
    """What the INS drift inside the window adds to the covariance of a fix's last sample.

    The information-weighted end-minus-mean covariance of the INS error
    (:func:`information_weights`): from the error-state model when the problem carries
    ``ins_model`` (:func:`model_drift_covariance`), else from the growth of
    ``sigma_position`` as independent increments (:func:`increment_drift_covariance`).

    Parameters
    ----------
    problem : MatchProblem
        The matched window.
    track : numpy.ndarray
        ``(n, 2)`` the fix's track, metres.
    heading : numpy.ndarray, optional
        ``(n,)`` headings of the fix's track, radians (default: the indicated ones).
    beams : array_like of int, optional
        Beam indices the matcher used (default: all).

    Returns
    -------
    numpy.ndarray
        ``(2, 2)`` covariance, m^2; zero for a window without drift.
    """
    weights = information_weights(problem, track, heading, beams)
    if problem.ins_model is not None:
        return model_drift_covariance(problem.ins_model, problem.times, problem.indicated, weights)
    return increment_drift_covariance(problem.sigma_position, weights)


def with_leg_drift(
    problem: MatchProblem, covariance, track: np.ndarray, heading=None, beams=None
) -> tuple[np.ndarray | None, np.ndarray]:
    """A rigid-offset fix's own covariance plus the drift inside its window.

    And plus the map's stated registration (:func:`geofix.problem.registered_covariance`).

    Parameters
    ----------
    problem : MatchProblem
        The matched window.
    covariance : numpy.ndarray or None
        ``(2, 2)`` the matcher's own covariance of the offset, m^2 (None: none given).
    track : numpy.ndarray
        ``(n, 2)`` the fix's track, metres.
    heading, beams : optional
        As for :func:`leg_drift_covariance`.

    Returns
    -------
    tuple
        ``(covariance + drift + registration, drift)``, m^2 (``(None, drift)`` without a
        covariance: the sensor part is unknown, so the sum would claim too much).
    """
    try:
        drift = leg_drift_covariance(problem, track, heading, beams)
    except (OverflowError, FloatingPointError):
        drift = np.full((2, 2), np.inf)
    if not np.isfinite(drift).all():
        raise MatchError(
            "the INS error model grows beyond any finite covariance within the leg "
            "(ins / dvl noise and bias settings too large)"
        )
    if covariance is None:
        return None, drift
    return registered_covariance(problem.grid, np.asarray(covariance, dtype=float) + drift), drift
