r"""The bootstrap particle filter (PF): the same recursion as the PMF with weighted samples.

``M`` position hypotheses (absolute ``x, y``, metres) carry log-weights. Each sample:

- **predict**: when the effective sample size ``ESS = 1 / sum(w^2)`` has fallen below
  ``resample_threshold * particles``, the set is resampled systematically (one uniform
  draw) and roughened (Gordon, Salmond & Smith 1993: a normal jitter of standard deviation
  ``roughening * E_i * M^(-1/2)`` along each axis ``i``, ``E_i`` the spread (max - min) of
  the particles along it, ``M`` their number, 2 the dimension); then every particle moves
  by the INS displacement plus a normal draw of per-axis variance ``Motion.process_var``
  (the bootstrap proposal: the motion prior);
- **update**: the same measurement model as the PMF (the map read at every particle,
  every beam, and the Gaussian log-likelihood with off-map handling, in one compiled pass:
  :func:`~geofix.measurement.hypotheses_log_likelihood`) is added to the log-weights.
  Weights stay in log space; the estimate is the weighted mean and covariance.

Resampling happens at the start of the prediction, so that the estimate after an update
comes from the weighted set (less Monte-Carlo noise than from a freshly resampled one).

**A prior wide compared with the map cell.** A multibeam swath's likelihood is often
narrower than one map cell. ``particles`` random draws over a prior hundreds of cells
across leave most cells empty, so the particle nearest the truth may score worse than a
chance fit elsewhere, and the filter converges confidently on a wrong place. Three
measures, the PMF's in particle form:

- the particle count follows the posterior's area: ``M`` is the number of
  ``max_spacing_cells``-sided squares in the ``+-extent_sigmas`` box of the prior (then,
  at each resampling, of the current posterior), at least ``particles``, at most
  ``max_particles``;
- the prior is a stratified sample: one particle at a random point of each square of a
  lattice over the ``+-extent_sigmas`` box, weighted by the prior density (an importance
  sample with no empty cells and no clumps);
- while the particles are sparse the likelihood is flattened by the field's variance
  within one particle's share of the area (a square of side ``h``, ``h^2`` the box area
  over ``M``), estimated from the field's differences over ``h`` at a subset of the
  particles (``discretisation_noise``, as in the PMF); it vanishes as the set concentrates.
  ``field_variance=local`` gives every particle its own instead, the field's change over
  its share at its own beams, as one offset common to the beams
  (:func:`~geofix.measurement.local_field_log_likelihood`).

The integrity flag is the PMF's: more than ``ambiguity_mass`` of the weight farther than
``ambiguity_radius_cells`` map cells from the weighted mean. All draws use the ``rng``
handed to the filter.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np
from scipy.special import logsumexp

from geofix.errors import ConfigError, MatchError
from geofix.filters import _particle_kernels as kernels
from geofix.filters.base import Motion, Observation, RecursiveFilter
from geofix.filters.hypothesis_offset import HypothesisOffset
from geofix.filters.nuisance import check_map_model
from geofix.maps.grid import Grid
from geofix.measurement import (
    hypotheses_log_likelihood,
    local_field_log_likelihood,
    predict_measurements,
    shift_field_variance,
)
from geofix.memory import cells_bytes, check_allocation
from geofix.problem import MatchProblem


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
    spacing : float
        Typical distance between neighbouring particles ``h``, metres (0: dense).
    evaluations : int
        Particle likelihoods evaluated so far.
    resamples : int
        Number of resampling steps so far.
    offset : HypothesisOffset or None
        Each particle's common offset (``map_model=imperfect``), from the first ping on.
    """

    particles: np.ndarray
    log_weight: np.ndarray
    cell: float
    spacing: float = 0.0
    evaluations: int = 0
    resamples: int = 0
    offset: HypothesisOffset | None = None

    @functools.cached_property
    def weights(self) -> np.ndarray:
        """``(M,)`` linear weights summing to one (read-only, computed once per state)."""
        w = linear_weights(self.log_weight)
        w.setflags(write=False)
        return w

    @functools.cached_property
    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean ``(2,)`` and covariance ``(2, 2)``, m and m^2 (once per state)."""
        w = self.weights
        mean = w @ self.particles
        d = self.particles - mean
        return mean, (d * w[:, None]).T @ d


@dataclass(frozen=True)
class Pf(RecursiveFilter):
    """Bootstrap particle filter over the horizontal position (systematic resampling).

    Parameters
    ----------
    particles : int
        Least number of particles ``M`` (at least 10).
    max_particles : int
        Most particles, however wide the posterior (200 000 keeps a 41-beam update near
        0.2 s).
    max_spacing_cells : float
        Wanted spacing of the particles, map cells, that a wide posterior is given more
        particles to keep (0.5, as the PMF's nodes).
    extent_sigmas : float
        Half-width of the box of the stratified prior and of the area that sets ``M``, in
        posterior standard deviations.
    discretisation_noise : bool
        Flatten the likelihood by the field's variance within one particle's share of the
        area (see the module text).
    field_variance : str
        ``global``: one field variance for every particle (:func:`spread_field_variance`);
        ``local``: each particle's own field variation within its share, common to its
        beams (:func:`~geofix.measurement.local_field_log_likelihood`). ``global`` stays
        the default here: on ``source002_bank`` the particle filters' lost trials come
        from resampling a two-mode posterior with a handful of particles in the true mode,
        which the local variance does not prevent (it moves the loss to other trials).
        Over 1000 trials there, ``pf`` ends more than 1 km off on 7 (``roughening=0.5``:
        6, ``resample_threshold=0.1``: 3, not a significant difference), ``pmf`` on 2 and
        ``mpf`` on none (``benchmarks/sweep_filters.py source002_bank ... --trials 1000``).
    resample_threshold : float
        Resample when ``ESS < resample_threshold * M`` (0.5, the common choice).
    roughening : float
        Gordon's roughening constant ``K`` (0.2 in Gordon et al. 1993); 0 switches it off.
    min_update_ess, progressive_stages, progressive_min_cells
        Progressive correction of a too sharp update on a sparse set (:meth:`update`):
        effective particles kept per stage, most stages (0 switches it off), and the
        least share (map cells) at which a set counts as sparse.
    ambiguity_radius_cells : float
        Radius around the fix, map cells, for the integrity flag.
    ambiguity_mass : float
        Weight beyond that radius above which the fix is flagged ambiguous.
    map_model : str
        What the likelihood assumes of the prior map: ``imperfect`` (default),
        ``adaptive`` or ``exact`` (:data:`geofix.filters.nuisance.MAP_MODELS`).

    References
    ----------
    .. [1] Gordon, N. J., Salmond, D. J., & Smith, A. F. M. (1993). Novel approach to
       nonlinear/non-Gaussian Bayesian state estimation. IEE Proceedings F, 140(2),
       107-113.

    Examples
    --------
    >>> import geofix
    >>> geofix.Pf().name
    'pf'
    """

    name: ClassVar[str] = "pf"

    particles: int = 5000
    max_particles: int = 200_000
    max_spacing_cells: float = 0.5
    extent_sigmas: float = 4.0
    discretisation_noise: bool = True
    field_variance: str = "global"
    resample_threshold: float = 0.5
    roughening: float = 0.2
    min_update_ess: float = 100.0
    progressive_stages: int = 4
    progressive_min_cells: float = 0.05
    ambiguity_radius_cells: float = 3.0
    ambiguity_mass: float = 0.05
    map_model: str = "imperfect"

    def __post_init__(self) -> None:
        if self.particles < 10 or self.max_particles < self.particles:
            raise ConfigError(
                f"pf: particles must be at least 10 and at most max_particles, got {self.particles}"
            )
        check_progressive("pf", self.min_update_ess, self.progressive_stages)
        if self.max_spacing_cells <= 0 or self.extent_sigmas <= 0:
            raise ConfigError("pf: max_spacing_cells and extent_sigmas must be positive")
        if not 0.0 <= self.resample_threshold <= 1.0 or self.roughening < 0:
            raise ConfigError("pf: resample_threshold must be in [0, 1], roughening >= 0")
        check_field_variance("pf", self.field_variance)
        check_map_model("pf", self.map_model)

    def initialize(self, problem: MatchProblem, rng: np.random.Generator) -> PfState:
        """A stratified sample of ``N(indicated[0], sigma_position[0]^2 I)``.

        One particle uniformly in each square of a lattice over the ``+-extent_sigmas``
        box (as many squares as :meth:`particle_count` allows), log-weighted by the prior
        density.

        Raises
        ------
        MatchError
            No particle lies on valid map data.
        """
        cell = problem.grid.cell_size
        sigma = max(float(problem.sigma_position[0]), 1e-3 * cell)
        start = np.asarray(problem.indicated[0], dtype=float)
        side = 2.0 * self.extent_sigmas * sigma
        per_axis = int(np.ceil(np.sqrt(self.particle_count(side * side, cell))))
        per_axis -= per_axis**2 > self.max_particles
        h = side / per_axis
        corner = (np.arange(per_axis) - 0.5 * per_axis) * h
        lattice = np.stack(np.meshgrid(corner, corner, indexing="ij"), axis=-1).reshape(-1, 2)
        particles = start + lattice + h * rng.random(lattice.shape)
        if not np.isfinite(
            predict_measurements(problem.grid, particles, 0.0, np.zeros((1, 2)))
        ).any():
            raise MatchError("pf: the prior particles lie entirely off the map")
        log_weight = -0.5 * np.sum((particles - start) ** 2, axis=1) / sigma**2
        return PfState(particles, log_normalised(log_weight), cell, spacing=h)

    def particle_count(self, area: float, cell: float) -> int:
        """Particles for a posterior box of ``area`` m^2 on a map of ``cell`` metres.

        ``area / (max_spacing_cells * cell)^2``, clipped to ``[particles, max_particles]``.
        """
        wanted = area / (self.max_spacing_cells * cell) ** 2
        return int(np.clip(np.ceil(wanted), self.particles, self.max_particles))

    def predict(self, state: PfState, motion: Motion, rng: np.random.Generator) -> PfState:
        """Resample and roughen if the ESS is low, then move by the INS plus process noise."""
        count = state.particles.shape[0]
        if effective_sample_size(state.weights) < self.resample_threshold * count:
            state = self._resample(state, rng)
        if state.offset is not None:
            state = replace(state, offset=state.offset.predicted(motion.dt))
        draws = rng.standard_normal(state.particles.shape)
        displacement = np.asarray(motion.displacement, dtype=float)
        particles = kernels.moved(
            np.ascontiguousarray(state.particles, dtype=float),
            displacement,
            float(np.sqrt(motion.process_var)),
            draws,
        )  # state.particles + displacement + sqrt(process_var) * draws, one pass
        return replace(state, particles=particles)

    def update(self, state: PfState, obs: Observation, grid: Grid, rng) -> PfState:
        """Add every particle's measurement log-likelihood (all beams at once).

        An update so sharp that it would leave fewer than ``min_update_ess`` effective
        particles of a sparse set (its share wider than ``progressive_min_cells`` map
        cells: the stratified prior lattice, or a resampled wide posterior) is applied in
        stages (progressive correction, Oudjane & Musso 2000): the largest fraction of the
        log-likelihood that keeps that many (:func:`stage_fraction`), then a resample
        whose copies are spread uniformly over the share of the particle they copy, the
        likelihood read again at the moved particles, and so on, at most
        ``progressive_stages`` times before the rest is applied at once. Without it a
        64-beam first ping on a half-cell lattice leaves one particle.
        """
        if not np.isfinite(obs.values).any():
            return state
        if self.carries_offset and state.offset is None:
            state = replace(state, offset=HypothesisOffset.start(state.log_weight.shape, obs))

        def likelihood(current: PfState) -> np.ndarray:
            return particle_log_likelihood(self, grid, current, obs, rng)

        state, reads = staged_update(self, state, likelihood, self._spread_copies, rng)
        if state.offset is not None:
            state = replace(state, offset=state.offset.updated(grid, state.particles, obs))
        return replace(state, evaluations=state.evaluations + reads)

    @property
    def carries_offset(self) -> bool:
        """Each particle carries its own common offset (``map_model=imperfect``)."""
        return self.map_model == "imperfect"

    def offset_moments(self, state: PfState) -> tuple[float, float] | None:
        """The posterior offset's mean and variance (map units), or None without one."""
        return None if state.offset is None else state.offset.moments(state.weights)

    def _spread_copies(self, state: PfState, rng) -> PfState:
        """Resample (same count) and spread each copy uniformly over its original's share."""
        count = state.particles.shape[0]
        index = systematic_resample(state.weights, rng, count)
        jitter = state.spacing * (rng.random((count, 2)) - 0.5)
        return replace(
            state,
            particles=state.particles[index] + jitter,
            log_weight=np.full(count, -np.log(count)),
            resamples=state.resamples + 1,
            offset=None if state.offset is None else state.offset.take(index),
        )

    def estimate(self, state: PfState) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean ``(2,)`` and covariance ``(2, 2)``, metres and m^2."""
        mean, cov = state.moments
        return mean.copy(), cov.copy()

    def is_ambiguous(self, state: PfState) -> bool:
        """More than ``ambiguity_mass`` of the weight beyond the radius around the mean."""
        mean, _ = self.estimate(state)
        far = np.hypot(*(state.particles - mean).T) > self.ambiguity_radius_cells * state.cell
        return bool(state.weights[far].sum() > self.ambiguity_mass)

    def _resample(self, state: PfState, rng: np.random.Generator) -> PfState:
        """Systematic resample to :meth:`particle_count` of the posterior box, roughened."""
        _, cov = self.estimate(state)
        sd = np.sqrt(np.clip(np.linalg.eigvalsh(cov), 0.0, None))
        area = float(np.prod(2.0 * self.extent_sigmas * sd))
        count = self.particle_count(area, state.cell)
        check_allocation(
            cells_bytes(count, copies=RESAMPLE_COPIES), f"pf resample to {count} particles"
        )
        index = systematic_resample(state.weights, rng, count)
        particles = state.particles[index]
        if self.roughening > 0:
            spread = kernels.column_ranges(particles)  # np.ptp(particles, axis=0)
            sd = self.roughening * spread * particles.shape[0] ** (-1.0 / 2.0)
            particles = particles + sd * rng.standard_normal(particles.shape)
        log_weight = np.full(count, -np.log(count))
        spacing = float(np.sqrt(area / count))
        return replace(
            state,
            particles=particles,
            log_weight=log_weight,
            spacing=spacing,
            resamples=state.resamples + 1,
            offset=None if state.offset is None else state.offset.take(index),
        )


#: Float arrays of one value per particle a resample allocates (indices, positions, the
#: roughening draws, weights, the offsets): checked against the memory budget before it.
RESAMPLE_COPIES = 12


def linear_weights(log_weight: np.ndarray) -> np.ndarray:
    """Linear weights summing to one from log-weights (shifted by their maximum first)."""
    w = np.exp(log_weight - log_weight.max())
    return w / w.sum()


def log_normalised(log_weight: np.ndarray) -> np.ndarray:
    """``log_weight - scipy.special.logsumexp(log_weight)`` for ``(M,)`` log-weights.

    The same numbers, bit for bit, as scipy's ``logsumexp`` (its maximum terms kept out
    of the sum: ``log1p(s) + log(m) + max``, ``m`` the count of maximal entries, ``s`` the
    sum of the others' ``exp(a - max)`` over ``m``) without its generic-array overhead,
    which dominates a few-thousand-particle step; a non-finite maximum goes to scipy.
    """
    top = log_weight.max()
    if not np.isfinite(top):
        return log_weight - logsumexp(log_weight)
    at_top = log_weight == top
    count = float(np.count_nonzero(at_top))
    shifted = log_weight - top
    shifted[at_top] = -np.inf
    total = np.exp(shifted).sum()
    if total != 0:
        total = total / count
    return log_weight - (np.log1p(total) + np.log(count) + top)


def stage_fraction(log_weight: np.ndarray, ll: np.ndarray, remaining: float, min_ess) -> float:
    """Largest fraction (at most ``remaining``) of ``ll`` that keeps ``min_ess`` particles.

    The effective sample size of ``log_weight + a ll`` falls as ``a`` grows; bisection
    finds the largest ``a`` keeping ``min(min_ess, M / 2)``, never below
    ``1e-3 remaining`` (so that the stages always progress).
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


def staged_update(filt, state, likelihood: Callable, spread: Callable, rng) -> tuple:
    """Apply ``likelihood(state)`` to the weights, in stages while the set is sparse.

    The progressive correction of :meth:`Pf.update` and :meth:`~geofix.filters.mpf.Mpf.
    update`: ``filt`` holds ``min_update_ess``, ``progressive_stages`` and
    ``progressive_min_cells``; ``state`` its ``log_weight``, ``spacing`` and ``cell``;
    ``spread(state, rng)`` resamples and spreads the copies between stages. Returns the
    updated state and the number of likelihood evaluations.
    """
    remaining, reads = 1.0, 0
    for stage in range(filt.progressive_stages + 1):
        ll = likelihood(state)
        reads += ll.size
        sparse = state.spacing > filt.progressive_min_cells * state.cell
        if stage == filt.progressive_stages or not sparse:
            share = remaining
        else:
            share = stage_fraction(state.log_weight, ll, remaining, filt.min_update_ess)
        state = replace(state, log_weight=log_normalised(state.log_weight + share * ll))
        remaining -= share
        if remaining <= 0.0:
            break
        state = spread(state, rng)
    return state, reads


def check_progressive(name: str, min_update_ess: float, stages: int) -> None:
    """Refuse a progressive-correction setting that cannot work (ConfigError)."""
    if not (np.isfinite(min_update_ess) and min_update_ess >= 1) or stages < 0:
        raise ConfigError(
            f"{name}: min_update_ess must be >= 1 and progressive_stages >= 0, "
            f"got {min_update_ess} and {stages}"
        )


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


FIELD_VARIANCES = ("local", "global")
"""The discretisation-noise models of the filters (``field_variance``)."""


LOCAL_MAX_SPACING_CELLS = 1.0
"""Largest share side, map cells, at which ``field_variance=local`` is used; a coarser set
falls back to the global variance. Within one map cell the bilinear field is linear along
each axis, so its change over a side describes the field across the share; over several
cells it does not (on rough terrain the beams' variations within a share ten cells wide
are nearly independent, the global model's assumption, and the local slope misleads)."""


def uses_local_field(filt, side: float, cell: float) -> bool:
    """Whether ``filt`` takes the local field variance for a share of ``side`` metres.

    ``field_variance=local`` and ``0 < side <= LOCAL_MAX_SPACING_CELLS * cell``.
    """
    return filt.field_variance == "local" and 0 < side <= LOCAL_MAX_SPACING_CELLS * cell


def check_field_variance(name: str, value: str) -> None:
    """Raise :class:`ConfigError` unless ``value`` is one of :data:`FIELD_VARIANCES`."""
    if value not in FIELD_VARIANCES:
        raise ConfigError(f"{name}: field_variance must be local or global, got {value!r}")


def particle_log_likelihood(filt, grid: Grid, state: PfState, obs: Observation, rng):
    """``(M,)`` measurement log-likelihood of ``state``'s particles, discretisation noise in.

    ``filt`` gives ``discretisation_noise`` and ``field_variance``: none when off or the
    set is dense (``spacing`` 0); each particle's own field variance within its square
    share (``local``, while the share is at most :data:`LOCAL_MAX_SPACING_CELLS` map
    cells across); or one variance for all (``global``, :func:`spread_field_variance`,
    drawing from ``rng``).
    """
    var = obs.noise_var  # a float or a read-only (b,) array: never changed in place
    args = (obs.heading, obs.offsets, obs.values)
    bias_var, shift = obs.bias_var, None
    if state.offset is not None:  # each particle's own offset, N(b_i, P)
        bias_var, shift = state.offset.var, state.offset.mean
    if filt.discretisation_noise and state.spacing > 0:
        if uses_local_field(filt, state.spacing, state.cell):
            sides = state.spacing * np.eye(2)
            return local_field_log_likelihood(
                grid, state.particles, *args, var, sides, bias_var, shift
            )
        var = var + spread_field_variance(grid, state, obs, rng)
    return hypotheses_log_likelihood(grid, state.particles, *args, var, bias_var, shift)


FIELD_VARIANCE_SUBSET = 2000
"""Most particles used to estimate the field's variance within one particle's share."""

FIELD_VARIANCE_DIFFERENCES = FIELD_VARIANCE_SUBSET * 64
"""Most particle-beam differences per axis in that estimate: with more than 64 measured
beams, fewer particles (never below :data:`FIELD_VARIANCE_MIN_PARTICLES`)."""

FIELD_VARIANCE_MIN_PARTICLES = 64
"""Fewest particles used in that estimate (when the set has that many)."""


def field_variance_particles(particles: int, beams: int) -> int:
    """Particles drawn for the field variance of ``beams`` measured beams.

    ``min(particles, FIELD_VARIANCE_SUBSET)`` up to 64 beams; beyond, as many as keep
    ``particles x beams`` near :data:`FIELD_VARIANCE_DIFFERENCES` (an all-beam multibeam
    ping averages over hundreds of beams per particle already), but at least
    :data:`FIELD_VARIANCE_MIN_PARTICLES`.
    """
    by_reads = max(FIELD_VARIANCE_MIN_PARTICLES, FIELD_VARIANCE_DIFFERENCES // max(beams, 1))
    return min(particles, FIELD_VARIANCE_SUBSET, by_reads)


def spread_field_variance(grid: Grid, state: PfState, obs: Observation, rng) -> float:
    """Field variance within a square of side ``state.spacing``, map units squared.

    ``(mean(d_x^2) + mean(d_y^2)) / 12`` over the measured beams, ``d_x``, ``d_y`` the
    change of the field read by each beam when the vehicle moves by ``spacing`` along x
    and along y, at :func:`field_variance_particles` particles drawn with ``rng`` (the
    PMF's node-field variance with particles for nodes); 0 when no difference is finite.
    """
    use = np.isfinite(obs.values)
    m = state.particles.shape[0]
    pick = rng.choice(m, field_variance_particles(m, int(use.sum())), replace=False)
    return shift_field_variance(
        grid, state.particles[pick], obs.heading, obs.offsets, obs.values, state.spacing
    )
