r"""The bootstrap particle filter (PF): the same recursion as the PMF with weighted samples.

``particles`` position hypotheses (absolute ``x, y``, metres) carry log-weights. Each
sample:

- **predict**: when the effective sample size ``ESS = 1 / sum(w^2)`` has fallen below
  ``resample_threshold * particles``, the set is resampled systematically (one uniform
  draw) and roughened (Gordon, Salmond & Smith 1993: a normal jitter of standard deviation
  ``roughening * E_i * M^(-1/2)`` along each axis ``i``, ``E_i`` the spread (max - min) of
  the particles along it, ``M`` their number, 2 the dimension); then every particle moves
  by the INS displacement plus a normal draw of per-axis variance ``Motion.process_var``
  (the bootstrap proposal: the motion prior);
- **update**: the same measurement model as the PMF
  (:func:`~geofix.filters.measurement.predict_measurements` at every particle, every beam,
  :func:`~geofix.filters.measurement.log_likelihood` with off-map handling) is added to
  the log-weights. Weights stay in log space; the estimate is the weighted mean and
  covariance.

Resampling happens at the start of the prediction, so that the estimate after an update
comes from the weighted set (less Monte-Carlo noise than from a freshly resampled one).
The integrity flag is the PMF's: more than ``ambiguity_mass`` of the weight farther than
``ambiguity_radius_cells`` map cells from the weighted mean. All draws use the ``rng``
handed to the filter.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np
from scipy.special import logsumexp

from geofix.errors import ConfigError, MatchError
from geofix.filters.base import Motion, Observation, RecursiveFilter
from geofix.filters.measurement import log_likelihood, predict_measurements
from geofix.maps.grid import Grid
from geofix.match.base import MatchProblem
from geofix.match.registry import register


@dataclass(frozen=True, eq=False)
class PfState:
    """An immutable weighted particle set.

    Parameters
    ----------
    particles : numpy.ndarray
        ``(M, 2)`` absolute positions, metres.
    log_weight : numpy.ndarray
        ``(M,)`` normalised log-weights (``logsumexp = 0``).
    cell : float
        Map cell size, metres (for the ambiguity radius).
    evaluations : int
        Particle likelihoods evaluated so far.
    resamples : int
        Number of resampling steps so far.
    """

    particles: np.ndarray
    log_weight: np.ndarray
    cell: float
    evaluations: int = 0
    resamples: int = 0

    @property
    def weights(self) -> np.ndarray:
        """``(M,)`` linear weights summing to one."""
        w = np.exp(self.log_weight - self.log_weight.max())
        return w / w.sum()


@register
@dataclass(frozen=True)
class Pf(RecursiveFilter):
    """Bootstrap particle filter settings.

    Parameters
    ----------
    particles : int
        Number of particles ``M`` (at least 10).
    resample_threshold : float
        Resample when ``ESS < resample_threshold * M`` (0.5, the common choice).
    roughening : float
        Gordon's roughening constant ``K`` (0.2 in Gordon et al. 1993); 0 switches it off.
    ambiguity_radius_cells : float
        Radius around the fix, map cells, for the integrity flag.
    ambiguity_mass : float
        Weight beyond that radius above which the fix is flagged ambiguous.
    """

    name: ClassVar[str] = "pf"

    particles: int = 5000
    resample_threshold: float = 0.5
    roughening: float = 0.2
    ambiguity_radius_cells: float = 3.0
    ambiguity_mass: float = 0.05

    def __post_init__(self) -> None:
        if self.particles < 10:
            raise ConfigError(f"pf: particles must be at least 10, got {self.particles}")
        if not 0.0 <= self.resample_threshold <= 1.0 or self.roughening < 0:
            raise ConfigError("pf: resample_threshold must be in [0, 1], roughening >= 0")

    def initialize(self, problem: MatchProblem, rng: np.random.Generator) -> PfState:
        """Particles drawn from ``N(indicated[0], sigma_position[0]^2 I)``, equal weights.

        Raises
        ------
        MatchError
            No particle lies on valid map data.
        """
        sigma = float(problem.sigma_position[0])
        start = np.asarray(problem.indicated[0], dtype=float)
        particles = start + sigma * rng.standard_normal((self.particles, 2))
        if not problem.grid.contains(particles[:, 0], particles[:, 1]).any():
            raise MatchError("pf: the prior particles lie entirely off the map")
        log_weight = np.full(self.particles, -np.log(self.particles))
        return PfState(particles, log_weight, problem.grid.cell_size)

    def predict(self, state: PfState, motion: Motion, rng: np.random.Generator) -> PfState:
        """Resample and roughen if the ESS is low, then move by the INS plus process noise."""
        if effective_sample_size(state.weights) < self.resample_threshold * self.particles:
            state = self._resample(state, rng)
        noise = np.sqrt(motion.process_var) * rng.standard_normal(state.particles.shape)
        particles = state.particles + np.asarray(motion.displacement, dtype=float) + noise
        return replace(state, particles=particles)

    def update(self, state: PfState, obs: Observation, grid: Grid, rng) -> PfState:
        """Add every particle's measurement log-likelihood (all beams at once)."""
        if not np.isfinite(obs.values).any():
            return state
        predicted = predict_measurements(grid, state.particles, obs.heading, obs.offsets)
        log_weight = state.log_weight + log_likelihood(predicted, obs.values, obs.noise_var)
        return replace(
            state,
            log_weight=log_weight - logsumexp(log_weight),
            evaluations=state.evaluations + state.particles.shape[0],
        )

    def estimate(self, state: PfState) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean ``(2,)`` and covariance ``(2, 2)``, metres and m^2."""
        w = state.weights
        mean = w @ state.particles
        d = state.particles - mean
        return mean, (d * w[:, None]).T @ d

    def is_ambiguous(self, state: PfState) -> bool:
        """More than ``ambiguity_mass`` of the weight beyond the radius around the mean."""
        mean, _ = self.estimate(state)
        far = np.hypot(*(state.particles - mean).T) > self.ambiguity_radius_cells * state.cell
        return bool(state.weights[far].sum() > self.ambiguity_mass)

    def _resample(self, state: PfState, rng: np.random.Generator) -> PfState:
        index = systematic_resample(state.weights, rng)
        particles = state.particles[index]
        if self.roughening > 0:
            spread = np.ptp(particles, axis=0)
            sd = self.roughening * spread * particles.shape[0] ** (-1.0 / 2.0)
            particles = particles + sd * rng.standard_normal(particles.shape)
        log_weight = np.full(particles.shape[0], -np.log(particles.shape[0]))
        return replace(
            state, particles=particles, log_weight=log_weight, resamples=state.resamples + 1
        )


def effective_sample_size(weights: np.ndarray) -> float:
    """``1 / sum(w^2)`` of normalised weights ``(M,)``: between 1 and ``M``."""
    return float(1.0 / np.sum(np.asarray(weights, dtype=float) ** 2))


def systematic_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices ``(M,)`` of a systematic resample of normalised ``weights`` ``(M,)``.

    One uniform draw ``u`` places ``M`` pointers at ``(u + j) / M``; particle ``i`` is
    copied once for each pointer falling in its slice of the cumulative weights, so it
    appears ``floor(M w_i)`` or ``ceil(M w_i)`` times.
    """
    m = weights.shape[0]
    pointers = (rng.random() + np.arange(m)) / m
    cumulative = np.cumsum(weights)
    cumulative[-1] = 1.0
    return np.searchsorted(cumulative, pointers, side="right")
