r"""The particle filter's INS error-state motion model (``pf:model=errstate``).

The point-mass filter's error-state model (:class:`~geofix.filters.motion.InsErrorState`)
in particle form. The particles hold the (non-Gaussian) posterior of the position; one
Kalman filter holds the Gaussian ``N(mu, Sigma)`` of the whole INS error state
``x = [dp, x_l]`` of :mod:`geofix.nav.errstate` (``dp`` = indicated - position). Between
samples:

1. the Kalman filter takes the particles' weighted moments as the new marginal of ``dp``
   (:func:`~geofix.filters.motion.replace_marginal`);
2. given ``dp``, the next ``dp`` is Gaussian with a mean affine in ``dp`` (``G dp + h``)
   and a covariance ``K`` shared by every particle
   (:func:`~geofix.filters.motion.conditional_motion`): each particle is carried through
   the affine map and moved by a draw of ``N(0, K)``;
3. the Kalman filter predicts ``mu <- F mu``, ``Sigma <- F Sigma F^T + Q``.

An aiding DVL's velocity weighs each particle by its likelihood given the particle's
``dp`` and updates the Kalman filter (:func:`~geofix.filters.motion.dvl_update`). The
affine map carries what the terrain has taught about the INS drift (a velocity error
learnt from the particles' motion moves every particle), which the random walk of
``pf:model=rw`` cannot: there a drifting INS leaves the particles behind and the
covariance overconfident. Unlike :class:`~geofix.filters.mpf.Mpf`, the linear states are
one Gaussian for the whole set, not one Kalman mean per particle.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from geofix.errors import MatchError
from geofix.filters.base import Motion, Observation
from geofix.filters.motion import (
    ErrorStateTrack,
    InsErrorState,
    conditional_motion,
    dvl_update,
    replace_marginal,
)
from geofix.nav.errstate import error_state, step_matrices
from geofix.problem import MatchProblem

#: Variance added to the particles' position covariance when its smallest eigenvalue is
#: below it (m^2): a set collapsed onto one point (no roughening) would make the error
#: state's regression on ``dp`` singular.
MIN_POSITION_VAR = 1e-6


@dataclass(frozen=True)
class ParticlePrior:
    """A prior particle set: positions, log-weights and the motion model's own part.

    Parameters
    ----------
    particles : numpy.ndarray
        ``(M, 2)`` absolute positions, metres.
    log_weight : numpy.ndarray
        ``(M,)`` unnormalised log-weights.
    spacing : float
        Typical distance between neighbouring particles, metres.
    track : ErrorStateTrack or None
        The error state's Kalman filter (None for the random walk).
    """

    particles: np.ndarray
    log_weight: np.ndarray
    spacing: float
    track: ErrorStateTrack | None = None


def error_state_prior(settings, problem: MatchProblem, rng) -> ParticlePrior:
    """A stratified sample of the error state's position prior, the Kalman filter at its prior.

    Parameters
    ----------
    settings : ParticleSettings
        The filter (its lattice: :meth:`~geofix.filters.pf.ParticleSettings.stratified`).
    problem : MatchProblem
        The problem; its ``ins_model`` gives the prior.
    rng : numpy.random.Generator
        Random draws of the lattice.

    Raises
    ------
    MatchError
        The problem has no INS error model.
    """
    model = problem.ins_model
    if model is None:
        raise MatchError("pf: model=errstate needs the INS error model (problem.ins_model)")
    es = error_state(model, problem.times, problem.indicated)
    cell = problem.grid.cell_size
    sigma = es.prior_cov
    sigma[:2, :2] += (1e-3 * cell) ** 2 * np.eye(2)
    dev, spacing = settings.stratified(np.sqrt(np.diag(sigma[:2, :2])), cell, rng)
    start = np.asarray(problem.indicated[0], dtype=float)
    log_weight = -0.5 * np.einsum("mi,ij,mj->m", dev, np.linalg.inv(sigma[:2, :2]), dev)
    dvl = InsErrorState(settings.use_dvl).dvl_innovations(problem, es)
    track = ErrorStateTrack((np.zeros(es.dim), sigma), es, start, dvl=dvl)
    return ParticlePrior(start + dev, log_weight, spacing, track)


def error_state_predict(
    particles: np.ndarray,
    moments: tuple[np.ndarray, np.ndarray],
    track: ErrorStateTrack,
    motion: Motion,
    rng: np.random.Generator,
) -> tuple[np.ndarray, ErrorStateTrack]:
    """Carry the particles through the affine motion given ``dp`` and draw ``N(0, K)``.

    Parameters
    ----------
    particles : numpy.ndarray
        ``(M, 2)`` positions after the last update, metres.
    moments : tuple
        Their weighted mean ``(2,)`` (m) and covariance ``(2, 2)`` (m^2)
        (:meth:`~geofix.filters.pf.PfState.moments`).
    track : ErrorStateTrack
        The error state's Kalman filter at the current sample.
    motion : Motion
        The INS motion of the step (displacement, m; duration, s; process variance, m^2).
    rng : numpy.random.Generator
        Random draws of the step.

    Returns
    -------
    tuple
        The moved ``(M, 2)`` particles and the track at the next sample.
    """
    mean, cov = moments
    if np.linalg.eigvalsh(cov)[0] < MIN_POSITION_VAR:  # a collapsed set: never singular
        cov = cov + MIN_POSITION_VAR * np.eye(2)
    mu, sigma = replace_marginal(*track.kf, track.indicated - mean, cov)
    es, f, q = step_matrices(
        track.errstate, track.step, motion.displacement, motion.dt, motion.process_var
    )
    g, h, kernel = conditional_motion(mu, sigma, f, q)
    indicated = track.indicated + np.asarray(motion.displacement, dtype=float)
    shift = indicated - g @ track.indicated - h  # position' = G position + shift
    values, vectors = np.linalg.eigh(kernel)  # K may be a rounding error short of PSD
    root = vectors * np.sqrt(np.clip(values, 0.0, None))
    moved = particles @ g.T + shift + rng.standard_normal(particles.shape) @ root.T
    sigma_next = f @ sigma @ f.T + q
    kf = (f @ mu, 0.5 * (sigma_next + sigma_next.T))
    return moved, ErrorStateTrack(kf, es, indicated, track.step + 1, track.dvl)


def error_state_aid(
    particles: np.ndarray, log_weight: np.ndarray, track: ErrorStateTrack, obs: Observation
) -> tuple[np.ndarray, ErrorStateTrack]:
    """An aiding DVL's velocity at ``obs``'s sample: particle log-weights and the Kalman update.

    Returns ``(log_weight, track)`` unchanged when no DVL aids or its velocity is not
    finite at the sample.
    """
    dvl = track.dvl
    es = track.errstate
    if dvl is None or es.velocity_map is None or not np.isfinite(dvl[obs.index]).all():
        return log_weight, track
    dp = track.indicated - particles
    log_like, kf = dvl_update(*track.kf, es.velocity_map, es.velocity_noise_var, dvl[obs.index], dp)
    return log_weight + log_like, replace(track, kf=kf)


__all__ = [
    "MIN_POSITION_VAR",
    "ParticlePrior",
    "error_state_aid",
    "error_state_predict",
    "error_state_prior",
]
