r"""The bootstrap particle filter (PF): the same recursion as the PMF with weighted samples.

``M`` position hypotheses (absolute ``x, y``, metres) carry log-weights. Each sample:

- **predict**: when the effective sample size ``ESS = 1 / sum(w^2)`` has fallen below
  ``resample_threshold * particles``, the set is resampled systematically (one uniform
  draw) and roughened (Gordon, Salmond & Smith 1993: a normal jitter of standard deviation
  ``roughening * E_i * M^(-1/2)`` along each axis ``i``, ``roughening`` 0.5 by default
  (half a particle spacing), ``E_i`` the spread (max - min) of the particles along
  it, ``M`` their number, 2 the dimension); then every particle moves
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
  (:class:`~geofix.filters.likelihood.TerrainLikelihood`).

The integrity flag is the PMF's: more than ``ambiguity_mass`` of the weight farther than
``ambiguity_radius_cells`` map cells from the weighted mean. All draws use the ``rng``
handed to the filter.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from geofix.errors import ConfigError, MatchError
from geofix.filters import _particle_kernels as kernels
from geofix.filters._fields import (
    field_offset,
    taken_offsets,
    update_particle_fields,
)
from geofix.filters._weights import (
    RESAMPLE_COPIES,
    ProgressiveCorrection,
    check_progressive,
    effective_sample_size,
    linear_weights,
    log_normalised,
    systematic_resample,
)
from geofix.filters.base import Motion, Observation, RecursiveFilter
from geofix.filters.hypothesis_offset import (
    HypothesisOffset,
    check_offset_per_hypothesis,
    check_offset_rates,
    check_offset_smooth,
    check_offset_walk,
    shared_offsets,
    walk_factors,
)
from geofix.filters.likelihood import TerrainLikelihood, check_field_variance, check_student_dof
from geofix.filters.motion import ErrorStateTrack, check_motion_model, takes_error_state
from geofix.filters.nuisance import check_map_model
from geofix.filters.particle_motion import (
    error_state_aid,
    error_state_predict,
    error_state_prior,
)
from geofix.maps.grid import Grid
from geofix.measurement import predict_measurements
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
    field_offsets : tuple
        The same per further field (:attr:`MatchProblem.fields`, in order; None for a
        field without one), from its first ping on.
    track : ErrorStateTrack or None
        The INS error state's Kalman filter with the error-state motion model
        (:mod:`geofix.filters.particle_motion`); None with the random walk.
    """

    particles: np.ndarray
    log_weight: np.ndarray
    cell: float
    spacing: float = 0.0
    evaluations: int = 0
    resamples: int = 0
    offset: HypothesisOffset | None = None
    field_offsets: tuple = ()
    track: ErrorStateTrack | None = None

    @functools.cached_property
    def weights(self) -> np.ndarray:
        """``(M,)`` linear weights summing to one (read-only, computed once per state)."""
        w = linear_weights(self.log_weight)
        w.setflags(write=False)
        return w

    @functools.cached_property
    def _moments(self) -> tuple[np.ndarray, np.ndarray]:
        w = self.weights
        mean = w @ self.particles
        d = self.particles - mean
        return mean, (d * w[:, None]).T @ d

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean ``(2,)`` and covariance ``(2, 2)``, m and m^2 (once per state)."""
        mean, cov = self._moments
        return mean.copy(), cov.copy()

    def mode(self) -> np.ndarray:
        """The highest-weight particle ``(2,)``, metres."""
        return np.asarray(self.particles[int(np.argmax(self.log_weight))], dtype=float)

    def points(self) -> tuple[np.ndarray, np.ndarray]:
        """``(particles (M, 2), log_weight (M,))``."""
        return self.particles, self.log_weight

    def node_area(self) -> None:
        """None: the particles are a random sample, not nodes with cells."""
        return None


@dataclass(frozen=True)
class ParticleSettings(RecursiveFilter):
    """The settings every particle filter shares (:class:`Pf`, :class:`~geofix.filters.mpf.Mpf`).

    Parameters
    ----------
    particles : int
        Least number of particles ``M`` (at least 10).
    max_particles : int
        Most particles, however wide the posterior.
    max_spacing_cells : float
        Wanted spacing of the particles, map cells, that a wide posterior is given more
        particles to keep (0.5, as the PMF's nodes).
    extent_sigmas : float
        Half-width of the box of the stratified prior and of the area that sets ``M``, in
        posterior standard deviations.
    discretisation_noise : bool
        Flatten the likelihood by the field's variance within one particle's share of the
        area (see the module text of :mod:`geofix.filters.pf`).
    field_variance : str
        ``global``: one field variance for every particle
        (:func:`~geofix.filters.likelihood.spread_field_variance`); ``local``: each
        particle's own field variation within its share, common to its beams
        (:class:`~geofix.filters.likelihood.TerrainLikelihood`). ``global`` stays the
        default here: the particle filters' lost trials on a two-mode posterior come from
        resampling it with a handful of particles in the true mode, which the local
        variance does not prevent.
    resample_threshold : float
        Resample when ``ESS < resample_threshold * M`` (0.5, the common choice).
    min_update_ess, progressive_stages, progressive_min_cells
        Progressive correction of a too sharp update on a sparse set
        (:class:`~geofix.filters._weights.ProgressiveCorrection`): effective particles
        kept per stage, most stages (0 switches it off), and the least share (map cells)
        at which a set counts as sparse.
    ambiguity_radius_cells : float
        Radius around the fix, map cells, for the integrity flag.
    ambiguity_mass : float
        Weight beyond that radius above which the fix is flagged ambiguous.
    map_model : str
        What the likelihood assumes of the prior map: ``imperfect`` (default),
        ``adaptive`` or ``exact`` (:data:`geofix.filters.nuisance.MAP_MODELS`).
    fast_offset_walk : float or None
        A second, faster walk rate of the per-hypothesis offset (pings of one or two
        beams, or every ping with ``offset_per_hypothesis``), as a factor on the declared
        walk, each hypothesis weighing both by its own residuals
        (:func:`geofix.filters.hypothesis_offset.walk_factors`; 0: the declared
        rate alone). None (the default): the map kind's
        (:func:`geofix.filters.nuisance.default_fast_offset_walk`: 10 on a gravity map and
        for a depth map's multibeam pings, 0 for its profiles and on a magnetic map).
    slow_offset_walk : float or None
        A slower walk rate weighed beside the declared one wherever a faster one is, as
        :class:`geofix.filters.pmf.Pmf`'s: a factor below 1 on the declared walk, None
        (the default) :data:`geofix.filters.hypothesis_offset.SLOW_OFFSET_WALK` (0.01),
        0 none.
    offset_walk : float or None
        The common offset's walk, map units squared per second, as
        :class:`geofix.filters.pmf.Pmf`'s: 0 an offset that does not move, None (the
        default) the navigator's ``depth_bias_walk`` (1e-3).
    offset_pool : float or None
        Width, in particle spacings (the typical distance between neighbours after a
        resampling), over which each resampled particle's per-path offset is averaged
        with its neighbours' (weighted by a tent kernel, :func:`~geofix.filters.
        hypothesis_offset.pooled_offsets`), as the point-mass convolution mixes its
        nodes'; ``mpf`` then jitters its copies within their share instead of the kernel
        move. 0 (or None) leaves each particle its own path's offset (``pf``'s default
        is 2, see :class:`Pf`; ``mpf``'s, None, is 2 on profile pings and 0 on a
        swath's, :meth:`geofix.filters.mpf.Mpf.offset_pool_of`). A map error
        correlated over more than a swath reads, along one path, as an offset that
        follows a misleading stretch of map; pooled, the neighbours' paths temper it.
    offset_per_hypothesis : bool or None
        Where the particles carry the common offset per hypothesis, as
        :class:`geofix.filters.pmf.Pmf`'s: every ping (True), none (False), or the
        stepper's settings (None, the default: every ping).
    offset_rates : str
        How the particles weigh the offset's walk rates, as
        :class:`geofix.filters.pmf.Pmf`'s: ``own`` (the default), ``shared`` or
        ``pooled`` (:data:`geofix.filters.hypothesis_offset.OFFSET_RATES`).
    student_dof : float or None
        As :class:`geofix.filters.pmf.Pmf`'s: a Student-t likelihood per ping of that
        many degrees of freedom (None, the default: the Gaussian).
    offset_smooth_m : float or None
        As :class:`geofix.filters.pmf.Pmf`'s: a smooth offset of that length scale
        along the track, metres, weighed beside the walks (0: none; None, the default:
        the map kind's, 2 km on a gravity map).
    """

    name: ClassVar[str] = "particles"

    particles: int = 5000
    max_particles: int = 200_000
    max_spacing_cells: float = 0.5
    extent_sigmas: float = 4.0
    discretisation_noise: bool = True
    field_variance: str = "global"
    resample_threshold: float = 0.5
    min_update_ess: float = 100.0
    progressive_stages: int = 4
    progressive_min_cells: float = 0.05
    ambiguity_radius_cells: float = 3.0
    ambiguity_mass: float = 0.05
    map_model: str = "imperfect"
    fast_offset_walk: float | None = None
    slow_offset_walk: float | None = None
    offset_walk: float | None = None
    offset_pool: float | None = 0.0
    offset_rates: str = "own"
    offset_per_hypothesis: bool | None = None
    student_dof: float | None = None
    offset_smooth_m: float | None = None

    def __post_init__(self) -> None:
        check_student_dof(self.name, self.student_dof)
        pool = self.offset_pool
        if pool is not None and not (np.isfinite(pool) and pool >= 0):
            raise ConfigError(f"{self.name}: offset_pool must be finite and >= 0")
        if self.fast_offset_walk is not None:
            walk_factors(self.fast_offset_walk)
        if self.slow_offset_walk is not None:
            walk_factors(0.0, self.slow_offset_walk)
        check_offset_walk(self.name, self.offset_walk)
        check_offset_rates(self.name, self.offset_rates)
        check_offset_smooth(self.name, self.offset_smooth_m, self.offset_rates)
        check_offset_per_hypothesis(self.name, self.offset_per_hypothesis)
        name = self.name
        if self.particles < 10 or self.max_particles < self.particles:
            raise ConfigError(
                f"{name}: particles must be at least 10 and at most max_particles, "
                f"got {self.particles}"
            )
        check_progressive(name, self.min_update_ess, self.progressive_stages)
        if self.max_spacing_cells <= 0 or self.extent_sigmas <= 0:
            raise ConfigError(f"{name}: max_spacing_cells and extent_sigmas must be positive")
        if not 0.0 <= self.resample_threshold <= 1.0:
            raise ConfigError(f"{name}: resample_threshold must be in [0, 1]")
        check_field_variance(name, self.field_variance)
        check_map_model(name, self.map_model)

    @property
    def likelihood(self) -> TerrainLikelihood:
        """The terrain measurement model of these settings."""
        dof = np.inf if self.student_dof is None else float(self.student_dof)
        return TerrainLikelihood(self.discretisation_noise, self.field_variance, dof)

    @property
    def progressive(self) -> ProgressiveCorrection:
        """The progressive correction of these settings."""
        return ProgressiveCorrection(
            self.min_update_ess, self.progressive_stages, self.progressive_min_cells
        )

    def stratified(self, sd: np.ndarray, cell: float, rng) -> tuple[np.ndarray, float]:
        """One particle at a random point of each square of a lattice over the prior box.

        Parameters
        ----------
        sd : numpy.ndarray
            ``(2,)`` the prior's standard deviation along x and y, metres.
        cell : float
            The map's cell, metres.
        rng : numpy.random.Generator
            The draws within the squares.

        Returns
        -------
        tuple
            ``(M, 2)`` deviations from the prior's centre (metres, the box
            ``+-extent_sigmas * sd``) and the lattice's spacing (metres).
        """
        side = 2.0 * self.extent_sigmas * sd
        count = self.particle_count(float(side[0] * side[1]), cell)
        h = float(np.sqrt(side[0] * side[1] / count))
        per_axis = np.maximum(np.ceil(side / h).astype(int), 1)
        while per_axis.prod() > self.max_particles:
            per_axis = np.maximum(per_axis - 1, 1)
        step = side / per_axis
        axes = [(np.arange(m) - 0.5 * m) * s for m, s in zip(per_axis, step, strict=True)]
        lattice = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 2)
        return lattice + step * rng.random(lattice.shape), float(np.sqrt(step.prod()))

    def memory_points(self) -> tuple[str, int]:
        """``(family, most particles)`` the filter may hold (:mod:`geofix.filters.sizing`)."""
        return self.name, int(self.max_particles)

    def particle_count(self, area: float, cell: float) -> int:
        """Particles for a posterior box of ``area`` m^2 on a map of ``cell`` metres.

        ``area / (max_spacing_cells * cell)^2``, clipped to ``[particles, max_particles]``.
        """
        wanted = area / (self.max_spacing_cells * cell) ** 2
        return int(np.clip(np.ceil(wanted), self.particles, self.max_particles))

    @property
    def carries_offset(self) -> bool:
        """Each particle carries its own common offset (``map_model=imperfect``)."""
        return self.map_model == "imperfect"

    def started_offset(self, shape, obs: Observation) -> HypothesisOffset | None:
        """The particles' offsets at their first ping (:meth:`HypothesisOffset.start`)."""
        return HypothesisOffset.start(
            shape,
            obs,
            self.fast_offset_walk,
            self.offset_rates,
            self.slow_offset_walk,
            None if self.offset_smooth_m is None else float(self.offset_smooth_m),
        )

    def offset_moments(self, state, field: int | None = None) -> tuple[float, float] | None:
        """The posterior offset's mean and variance (map units), or None without one.

        ``field``: that further field's offset (its index in ``fields``) instead.
        """
        offset = state.offset if field is None else field_offset(state, field)
        return None if offset is None else offset.moments(state.weights)


@dataclass(frozen=True)
class Pf(ParticleSettings):
    """Bootstrap particle filter over the horizontal position (systematic resampling).

    The settings it shares with :class:`~geofix.filters.mpf.Mpf` are those of
    :class:`ParticleSettings`.

    Parameters
    ----------
    roughening : float
        The roughening constant ``K`` of Gordon et al. (1993), 0.5 by default: the copies
        of a resampled particle are spread over half the gap to its neighbours (``E
        M^(-1/2)`` is the spacing of ``M`` particles over a range ``E`` in two
        dimensions). With the paper's 0.2 (``pf:roughening=0.2``) they stay within a
        fifth of a spacing, and on a likelihood sharp against that spacing (a multibeam
        ping on a map with correlated error, two fields fused) the set collapses onto the
        particles that happened to lie nearest a wrong point and cannot move off it; with
        1 a coarse map's flat likelihood lets the jitter carry the set away. 0 switches
        it off.
    model : str
        Motion model: ``auto`` (default: ``errstate`` when the problem has an INS error
        model, ``rw`` when it has none), ``rw`` (every particle moves by the INS
        displacement plus a white random walk of per-axis variance ``Motion.process_var``)
        or ``errstate`` (the INS error state of :mod:`geofix.nav.errstate`, one Kalman
        filter beside the particles: :mod:`geofix.filters.particle_motion`).
    use_dvl : bool
        Fold in an aiding DVL's velocity when the problem has one (error state only).
    offset_pool : float
        As :class:`ParticleSettings`'s, 2 particle spacings by default: on the real ship
        tracks against ETOPO1 at 10' at seeds held out from the choice, the unpooled
        filter claims ``converged`` with its error beyond 3 sigma on 41 of 2061 pings,
        pooled on none of 1819 (``pf:offset_pool=0`` is the unpooled filter; RESULTS,
        *Real ship tracks*).

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

    roughening: float = 0.5
    model: str = "auto"
    use_dvl: bool = True
    offset_pool: float = 2.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.roughening < 0:
            raise ConfigError(f"pf: roughening must be >= 0, got {self.roughening}")
        check_motion_model("pf", self.model)

    @property
    def needs_ins_model(self) -> bool:
        """``model=errstate`` needs an INS error model (``problem.ins_model``); ``auto`` not."""
        return self.model == "errstate"

    def uses_error_state(self, problem: MatchProblem) -> bool:
        """Whether the motion model for ``problem`` is the INS error state.

        ``errstate``, or ``auto`` on a problem with an INS error model.
        """
        return takes_error_state(self.model, problem)

    def initialize(self, problem: MatchProblem, rng: np.random.Generator) -> PfState:
        """A stratified sample of the motion model's position prior.

        One particle uniformly in each square of a lattice over the ``+-extent_sigmas``
        box (as many squares as :meth:`particle_count` allows), log-weighted by the prior
        density: ``N(indicated[0], sigma_position[0]^2 I)`` with the random walk, the error
        state's position prior with the error state (:meth:`uses_error_state`).

        Raises
        ------
        MatchError
            No particle lies on valid map data (or ``model=errstate`` without an INS
            error model).
        """
        if self.uses_error_state(problem):
            prior = error_state_prior(self, problem, rng)
            _prior_on_map(problem, prior.particles)
            return PfState(
                prior.particles,
                log_normalised(prior.log_weight),
                problem.grid.cell_size,
                spacing=prior.spacing,
                track=prior.track,
            )
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
        _prior_on_map(problem, particles)
        log_weight = -0.5 * np.sum((particles - start) ** 2, axis=1) / sigma**2
        return PfState(particles, log_normalised(log_weight), cell, spacing=h)

    def predict(self, state: PfState, motion: Motion, rng: np.random.Generator) -> PfState:
        """Resample and roughen if the ESS is low, then move by the motion model.

        The random walk moves every particle by the INS displacement plus process noise;
        the error state carries them through its affine motion
        (:func:`~geofix.filters.particle_motion.error_state_predict`).

        Parameters
        ----------
        state : PfState
            The state after the last update.
        motion : Motion
            The INS motion of the step (displacement, m; duration, s; process variance, m^2).
        rng : numpy.random.Generator
            Random draws of the step.
        """
        count = state.particles.shape[0]
        if effective_sample_size(state.weights) < self.resample_threshold * count:
            state = self._resample(state, rng)
            width = float(self.offset_pool or 0.0) * state.spacing
            state = pooled_offsets_of(state, _points(state), width)
        if state.offset is not None:
            state = replace(state, offset=state.offset.after(motion))
        if state.field_offsets:
            moved = tuple(None if o is None else o.after(motion) for o in state.field_offsets)
            state = replace(state, field_offsets=moved)
        if state.track is not None:
            particles, track = error_state_predict(
                state.particles, state.moments(), state.track, motion, rng
            )
            return replace(state, particles=particles, track=track)
        draws = rng.standard_normal(state.particles.shape)
        displacement = np.asarray(motion.displacement, dtype=float)
        particles = kernels.moved(
            np.ascontiguousarray(state.particles, dtype=float),
            displacement,
            float(np.sqrt(motion.process_var)),
            draws,
        )  # state.particles + displacement + sqrt(process_var) * draws, one pass
        return replace(state, particles=particles)

    #: The update weighs further fields (``fields``): the sum of their log-likelihoods.
    fuses_fields: ClassVar[bool] = True

    def update(
        self, state: PfState, obs: Observation, grid: Grid, rng, fields: tuple = ()
    ) -> PfState:
        """Add every particle's measurement log-likelihood (all beams at once).

        An update so sharp that it would leave fewer than ``min_update_ess`` effective
        particles of a sparse set (its share wider than ``progressive_min_cells`` map
        cells: the stratified prior lattice, or a resampled wide posterior) is applied in
        stages (progressive correction, Oudjane & Musso 2000): the largest fraction of the
        log-likelihood that keeps that many
        (:func:`~geofix.filters._weights.stage_fraction`), then a resample whose copies
        are spread uniformly over the share of the particle they copy, the likelihood read
        again at the moved particles, and so on, at most
        ``progressive_stages`` times before the rest is applied at once. Without it a
        many-beam first ping on a half-cell lattice leaves one particle.

        Parameters
        ----------
        state : PfState
            The predicted state.
        obs : Observation
            The ping (beam offsets, m; values and variances, map units).
        grid : Grid
            The prior map.
        rng : numpy.random.Generator
            Random draws of the update.
        fields : tuple
            ``(Observation, Grid)`` of every further field at this sample (map units of
            that map; ``()``: none): each adds its log-likelihood at the same particles,
            read on its own map, its offset marginalised in its ping (never carried per
            particle), within the same progressive correction.
        """
        if state.track is not None:
            log_weight, track = error_state_aid(state.particles, state.log_weight, state.track, obs)
            state = replace(state, log_weight=log_normalised(log_weight), track=track)
        if fields:
            return self._update_fields(state, obs, grid, rng, fields)
        if not np.isfinite(obs.values).any():
            return state
        if self.carries_offset and state.offset is None:
            state = replace(
                state,
                offset=self.started_offset(state.log_weight.shape, obs),
            )
        model = self.likelihood

        def likelihood(current: PfState) -> np.ndarray:
            return model.particles(
                grid,
                obs,
                current.particles,
                current.spacing,
                current.cell,
                current.offset,
                rng,
            )

        state, reads = self.progressive.apply(state, likelihood, self._spread_copies, rng)
        if state.offset is not None:
            state = replace(state, offset=state.offset.updated(grid, state.particles, obs))
        return shared_offsets(replace(state, evaluations=state.evaluations + reads))

    def _update_fields(self, state: PfState, obs: Observation, grid: Grid, rng, fields):
        """The primary ping (when it has a value) and every further field's, summed."""
        return update_particle_fields(self, state, obs, grid, rng, fields, _points)

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
            field_offsets=taken_offsets(state.field_offsets, index),
        )

    def estimate(self, state: PfState) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean ``(2,)`` and covariance ``(2, 2)``, metres and m^2."""
        return state.moments()

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
            field_offsets=taken_offsets(state.field_offsets, index),
        )


def pooled_offsets_of(state, points: np.ndarray, width: float):
    """``state`` with its offsets pooled over ``width`` metres (0: unchanged)."""
    if width <= 0 or (state.offset is None and not any(state.field_offsets)):
        return state

    def pool(offset):
        return None if offset is None else offset.pooled(points, state.log_weight, width)

    return replace(
        state,
        offset=pool(state.offset),
        field_offsets=tuple(pool(o) for o in state.field_offsets),
    )


def _prior_on_map(problem: MatchProblem, particles: np.ndarray) -> None:
    """Refuse (MatchError) a prior set whose particles all lie off the map."""
    if not np.isfinite(predict_measurements(problem.grid, particles, 0.0, np.zeros((1, 2)))).any():
        raise MatchError("pf: the prior particles lie entirely off the map")


def _points(state: PfState) -> np.ndarray:
    """The ``(M, 2)`` positions of a state, metres."""
    return state.particles


__all__ = ["ParticleSettings", "Pf", "PfState"]
