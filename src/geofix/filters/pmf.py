r"""The point-mass filter (PMF): Bayes' recursion for the 2-D position on a moving grid.

The posterior of the vehicle position is held as log-weights on an ``N0 x N1`` grid of
position hypotheses (Bergman 1999; Anonsen & Hallingstad for HUGIN). Each sample:

- **predict**: the grid is moved by the INS displacement (exact: only its centre moves)
  and the weights are convolved with the INS-error motion kernel, an isotropic Gaussian
  of per-axis variance ``Motion.process_var`` (separable, so two 1-D passes along the grid
  axes whatever their orientation);
- **update**: the field every beam would read from every node is taken from the map and
  the Gaussian log-likelihood (off-map footprints penalised) is added to the log-weights,
  in one compiled pass over nodes and beams
  (:func:`~geofix.measurement.node_grid_log_likelihood`, the same numbers as
  :func:`~geofix.measurement.predict_measurements` followed by
  :func:`~geofix.measurement.log_likelihood`). The variance is the sensor's plus the map's
  (``Observation.noise_var``) plus, by default, the spread of the field within one grid
  node (``discretisation_noise``; see :class:`Pmf`): each node's own, the field's change
  over its cell at its own beams, an offset common to them
  (``field_variance=local``, :meth:`~geofix.filters.likelihood.TerrainLikelihood.nodes`).
  One global variance for every node (``field_variance=global``) can let a node a little
  off the truth on rough terrain lose many nats in one sample against a wrong mode on
  flat ground, and the true mode fall below ``support_nats`` for good.

Everything stays in log space (:mod:`geofix.filters._grid_ops`), so a likelihood however
peaked gives no underflow and no NaN. The convolution is two direct 1-D passes (compiled
with the rest of the step's grid loops, :mod:`geofix.filters._grid_kernels`) rather than
an FFT: as a sum of non-negative terms they are exact in the tails, where FFT round-off
(1e-16 of the peak) would plant mass that later likelihoods, added in log space, could
amplify.

**The grid follows the posterior.** Before each prediction the posterior mean ``m`` and
covariance ``P`` are computed; the ideal grid is centred on ``m``, its axes along the
eigenvectors of ``P + q I`` (``q`` the coming process variance) and its half-extent
``e_i = extent_sigmas`` standard deviations along each (never below what ``points`` nodes
at ``min_spacing_cells`` map cells span). The log-density is moved onto the ideal grid by
linear interpolation when the current grid is off by more than ``regrid_ratio`` in node
spacing or node count (any direction) or by ``regrid_shift`` of its half-extent in
position; the zoom is limited to ``max_zoom`` per step. The half-extent never leaves out
a node whose log-weight is within ``support_nats`` of the peak: the moments of a posterior
with a dominant wrong mode and a small true one (a chance fit of a few samples, 1e-4 of the
mass) describe the wrong mode alone, and a grid fitted to them would drop the true mode
for good just before the next samples reject the wrong one by hundreds of nats. A
converged posterior thus lives on a small, fine grid; a spreading or multi-modal one on
a wide grid.

**The node count follows the posterior's width.** The grid has ``points`` nodes per axis
(spacing ``2 e_i / (points - 1)``) as long as that spacing is at most
``max_spacing_cells`` map cells. A wider posterior -- typically the prior of a large
initial error, many map cells across -- gets more nodes instead, as many as keep the
spacing at ``max_spacing_cells`` (up to ``max_points`` per axis, beyond which the spacing
grows again). The reason: the likelihood of a multibeam swath or of a long track is often
narrower than one map cell, so a grid coarser than the map samples it at points that may
all miss the true peak by a sizeable part of it, while a chance fit elsewhere is hit
squarely; over many samples that bias compounds into a confident wrong fix. Once the
posterior has shrunk the count falls back to ``points``, so the extra cost is paid only
in the first, wide steps.

**Integrity.** :meth:`Pmf.is_ambiguous` is True when more than ``ambiguity_mass`` of the
posterior lies farther than ``ambiguity_radius_cells`` map cells from the posterior mean
(the reported fix): a multi-modal posterior, or one too wide to trust at that radius.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from geofix.errors import ConfigError
from geofix.filters import _grid_kernels as grid_kernels
from geofix.filters import _grid_ops as ops
from geofix.filters._grid_ops import REGRID_COPIES, check_regrid
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
from geofix.filters.likelihood import (
    TerrainLikelihood,
    check_field_variance,
    check_student_dof,
    node_field_variance,
)
from geofix.filters.motion import (
    ErrorStateTrack,
    InsErrorState,
    RandomWalk,
    check_motion_model,
    takes_error_state,
)
from geofix.filters.nuisance import check_map_model
from geofix.maps.grid import Grid
from geofix.problem import MatchProblem


@dataclass(frozen=True, eq=False)
class PmfState:
    """An immutable point-mass posterior.

    Parameters
    ----------
    log_weight : numpy.ndarray
        ``(N0, N1)`` normalised log-weights of the nodes (``logsumexp = 0``).
    centre : numpy.ndarray
        ``(2,)`` absolute position of the middle node, metres.
    axes : numpy.ndarray
        ``(2, 2)`` orthonormal grid directions as columns (``x, y`` components).
    spacing : numpy.ndarray
        ``(2,)`` node spacing along each grid axis, metres.
    cell : float
        Map cell size, metres (sets the spacing floor and the ambiguity radius).
    evaluations : int
        Node likelihoods evaluated so far.
    regrids : int
        Times the log-density was moved onto a new grid.
    track : ErrorStateTrack or None
        The error-state motion model's own part (``model=errstate``): the Kalman filter of
        the INS error state along the indicated track, and the DVL's innovations.
    offset : HypothesisOffset or None
        Each node's common offset (``map_model=imperfect``), from the first ping on.
    field_offsets : tuple
        The same per further field (:attr:`MatchProblem.fields`, in order; None for a
        field without one), from its first ping on.
    """

    log_weight: np.ndarray
    centre: np.ndarray
    axes: np.ndarray
    spacing: np.ndarray
    cell: float
    evaluations: int = 0
    regrids: int = 0
    track: ErrorStateTrack | None = None
    offset: HypothesisOffset | None = None
    field_offsets: tuple = ()

    @property
    def frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(centre, axes, spacing)`` of the grid."""
        return self.centre, self.axes, self.spacing

    @property
    def shape(self) -> tuple[int, int]:
        """Nodes along each grid axis ``(N0, N1)``."""
        return self.log_weight.shape

    @functools.cached_property
    def node_offsets(self) -> tuple[np.ndarray, np.ndarray]:
        """``(u (N0,), v (N1,))`` node coordinates along the grid axes, metres (cached)."""
        return ops.node_offsets(self.shape, self.spacing)

    @functools.cached_property
    def _moments(self) -> tuple[np.ndarray, np.ndarray]:
        return ops.moments(self.log_weight, *self.frame, offsets=self.node_offsets)

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean ``(2,)`` and covariance ``(2, 2)``, metres and m^2.

        Computed once per state (it is immutable, and every step asks for them more than
        once); the arrays returned are copies.
        """
        mean, cov = self._moments
        return mean.copy(), cov.copy()

    def mode(self) -> np.ndarray:
        """Position ``(2,)`` of the node of highest weight, metres."""
        log_weight = self.log_weight
        i, j = np.unravel_index(int(np.argmax(log_weight)), log_weight.shape)
        u = np.array([i, j]) - 0.5 * (np.array(log_weight.shape) - 1)
        centre, axes, spacing = self.frame
        return np.asarray(centre + axes @ (u * spacing), dtype=float)

    def points(self) -> tuple[np.ndarray, np.ndarray]:
        """``(node positions (N0 N1, 2), log_weight (N0 N1,))``, row-major over the grid."""
        centre, axes, spacing = self.frame
        shape = np.array(self.log_weight.shape)
        i, j = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
        u = np.stack([i.ravel(), j.ravel()], axis=1) - 0.5 * (shape - 1)
        return centre + (u * spacing) @ np.asarray(axes).T, self.log_weight.ravel()

    def node_area(self) -> float:
        """Area of one node's cell, m^2 (the product of the node spacings)."""
        return float(np.prod(self.spacing))


@dataclass(frozen=True)
class Pmf(RecursiveFilter):
    """Point-mass filter: the Bayesian recursion on a grid that follows the posterior.

    Defaults are documented choices (see the module text).

    Parameters
    ----------
    points : int
        Nodes per grid axis ``N`` (odd, at least 5) of a grid fine enough at that count.
        61 resolves a converged Gaussian with 6 nodes per sigma at ``extent_sigmas = 5``.
    max_spacing_cells : float
        Largest node spacing, map cells, that a wide posterior is given more nodes to
        keep (0.5: two nodes per cell, so the true position is never more than a quarter
        of a cell from a node along each axis).
    max_points : int
        Most nodes per axis (odd, at least ``points``); at 0.5 cell spacing 301 resolves a
        prior of +-75 cells, and a wider prior gets coarser nodes.
    extent_sigmas : float
        Half-extent of the grid in posterior standard deviations along each principal
        axis (also of the prior grid, in prior sigmas).
    min_spacing_cells : float
        Floor of the node spacing, map cells.
    regrid_ratio : float
        Move to the ideal grid when the node spacing differs from it by more than this
        factor in any direction.
    regrid_shift : float
        ... or when the posterior mean has left the middle by more than this share of the
        grid's half-extent.
    max_zoom : float
        Largest change of the grid's half-extent in one regrid (both ways).
    support_nats : float
        Nodes whose log-weight is within this of the peak stay on the grid (20: modes
        down to 2e-9 of the peak survive until the data rule them out).
    discretisation_noise : bool
        Add to the measurement variance the field's variance within one node
        (``mean((delta_field between neighbouring nodes)^2) / 12`` summed over both grid
        axes): while the grid is coarse the likelihood is flattened to what the grid can
        resolve instead of being aliased; it vanishes as the grid refines.
    field_variance : str
        ``local`` (default): every node its own discretisation noise, the field's change
        to the next node along each grid axis at its own beams, as one offset within the
        cell common to the beams (:func:`~geofix.measurement.node_grid_local_log_likelihood`):
        a node a fraction of a cell off the truth on rough terrain is not over-penalised,
        nor a wrong one on flat ground over-rewarded; while the node spacing is at most
        :data:`~geofix.filters.likelihood.LOCAL_MAX_SPACING_CELLS` map cells (a coarser grid
        takes the global one). ``global``: one variance for the whole grid, the mean
        over nodes and beams (the earlier model).
    ambiguity_radius_cells : float
        Radius around the fix, map cells, for the integrity flag.
    ambiguity_mass : float
        Posterior share beyond that radius above which the fix is flagged ambiguous.
    model : str
        Motion model: ``auto`` (default: ``errstate`` when the problem has an INS error
        model, ``rw`` when it has none), ``rw`` (the INS error as a white random walk of
        per-axis variance ``Motion.process_var``) or ``errstate`` (the INS error state of
        :mod:`geofix.nav.errstate`, its prior the simulator's second moments, from
        ``problem.ins_model``; see :mod:`geofix.filters.motion`). With ``use_dvl`` the
        error-state model folds in an aiding DVL's velocity, as ``mpf`` does
        (:func:`geofix.filters.motion.dvl_update`).
    use_dvl : bool
        Fold in an aiding DVL's velocity when the problem has one (``model=errstate``;
        the random-walk model has no velocity state to aid).
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
        A slower walk rate weighed beside the declared one wherever a faster one is, as a
        factor on the declared walk below 1 (0: none). None (the default):
        :data:`geofix.filters.hypothesis_offset.SLOW_OFFSET_WALK`, 0.01 (with the declared
        1e-3, a walk of 1e-5 map units squared per second: about 0.2 m or mGal in an
        hour). An offset that stands still (a datum, a steady gravimeter) reads almost as
        well under the declared walk as standing; weighed beside it, the slow rate gives
        the position the information such an offset leaves it.
    offset_walk : float or None
        Variance the common offset gains per second, map units squared per second (a
        tide, a datum, a gravimeter's drift); 0: an offset that does not move. None (the
        default): the stepper's settings (the navigator's ``depth_bias_walk``, 1e-3).
        Where the offset really is constant, the declared walk widens the covariance
        beyond the errors: the section *Imperfect maps* shows both.
    offset_per_hypothesis : bool or None
        Carry the common offset per hypothesis on every ping (True), on none (False), or
        as the stepper's settings say (None, the default: every ping;
        :attr:`geofix.filters.loop.FilterStepper.carries_offset`). On a depth map the
        multibeam pings' offsets weigh a faster walk beside the declared one
        (:func:`geofix.filters.nuisance.default_fast_offset_walk`); the section
        *Imperfect maps* measures ``offset_per_hypothesis=false`` beside the default.
    offset_rates : str
        How the hypotheses weigh the offset's walk rates
        (:data:`geofix.filters.hypothesis_offset.OFFSET_RATES`): ``own`` (the default),
        each by its own residuals; ``shared``, a still offset beside the declared and
        fast walks, the choice between the steady two (still or declared) made by the
        posterior over every hypothesis, so that a hypothesis off the track cannot
        explain its residuals by a drift the others do not see; ``pooled``, as
        ``shared`` and then every rate's probability pooled with the posterior's
        (:data:`geofix.filters.hypothesis_offset.RATE_POOLING`), so that it cannot explain
        them by a fast map error the others do not see either.
    student_dof : float or None
        Degrees of freedom of a Student-t likelihood per ping (None, the default: the
        Gaussian): the Gaussian of every ping's covariance with its variance scaled by
        one inverse-gamma factor, so that a ping whose beams are all off together (a
        spike, a wrong sound speed, a stretch of map in gross error) moves the
        posterior by a bounded amount (:func:`geofix.measurement.student_t`). 4 is a
        common choice; above about 30 it is the Gaussian.
    offset_smooth_m : float or None
        A smooth offset's length scale along the track, metres (0: none): each node
        weighs beside its walks an offset that varies smoothly with the distance
        travelled (a Matern-3/2 process of that length at the offset's prior variance,
        carried as a level and its rate per metre;
        :meth:`geofix.filters.hypothesis_offset.HypothesisOffset.with_smooth`), as a map
        error correlated over kilometres reads along a track. With ``offset_rates=own``
        only. None (the default): the map kind's
        (:func:`geofix.filters.nuisance.default_offset_smooth`: 2 km on a gravity map,
        none on a depth or magnetic map; none with ``offset_rates`` ``shared`` or
        ``pooled``).

    References
    ----------
    .. [1] Bergman, N. (1999). Recursive Bayesian estimation: navigation and tracking
       applications. PhD thesis, Linköping University, Dissertation No. 579.
    .. [2] Anonsen, K. B., & Hallingstad, O. (2006). Terrain aided underwater navigation
       using point mass and particle filters. Proc. IEEE/ION PLANS 2006, 1027-1035.

    Examples
    --------
    >>> import geofix
    >>> scen = geofix.load_scenario("builtin:azores_demo")
    >>> grid = geofix.prepare_map(scen)
    >>> trial = geofix.simulate_trial(scen, grid, 0)
    >>> fix = geofix.Pmf().match(trial.problem(grid), np.random.default_rng(0))
    >>> fix.track.shape == trial.truth.shape
    True
    """

    name: ClassVar[str] = "pmf"

    points: int = 61
    max_spacing_cells: float = 0.5
    max_points: int = 301
    extent_sigmas: float = 5.0
    min_spacing_cells: float = 0.01
    regrid_ratio: float = 1.4
    regrid_shift: float = 0.2
    max_zoom: float = 4.0
    support_nats: float = 20.0
    discretisation_noise: bool = True
    field_variance: str = "local"
    ambiguity_radius_cells: float = 3.0
    ambiguity_mass: float = 0.05
    model: str = "auto"
    use_dvl: bool = True
    map_model: str = "imperfect"
    fast_offset_walk: float | None = None
    slow_offset_walk: float | None = None
    offset_walk: float | None = None
    offset_rates: str = "own"
    offset_per_hypothesis: bool | None = None
    student_dof: float | None = None
    offset_smooth_m: float | None = None

    def __post_init__(self) -> None:
        check_student_dof(self.name, self.student_dof)
        if self.fast_offset_walk is not None:
            walk_factors(self.fast_offset_walk)
        if self.slow_offset_walk is not None:
            walk_factors(0.0, self.slow_offset_walk)
        check_offset_walk(self.name, self.offset_walk)
        check_offset_rates(self.name, self.offset_rates)
        check_offset_smooth(self.name, self.offset_smooth_m, self.offset_rates)
        check_offset_per_hypothesis(self.name, self.offset_per_hypothesis)
        check_motion_model("pmf", self.model)
        if self.points < 5 or self.points % 2 == 0:
            raise ConfigError(f"pmf: points must be odd and at least 5, got {self.points}")
        if self.max_points < self.points or self.max_points % 2 == 0:
            raise ConfigError(f"pmf: max_points must be odd and >= points, got {self.max_points}")
        if min(self.extent_sigmas, self.min_spacing_cells, self.max_spacing_cells) <= 0:
            raise ConfigError("pmf: extent_sigmas and the spacings must be positive")
        if self.regrid_ratio <= 1 or self.max_zoom <= 1:
            raise ConfigError("pmf: regrid_ratio and max_zoom must exceed 1")
        check_field_variance("pmf", self.field_variance)
        check_map_model("pmf", self.map_model)

    @property
    def needs_ins_model(self) -> bool:
        """``model=errstate`` needs an INS error model (``problem.ins_model``); ``auto`` not."""
        return self.model == "errstate"

    def motion_model_for(self, problem: MatchProblem) -> RandomWalk | InsErrorState:
        """The motion model the ``model`` setting selects for ``problem``.

        ``auto`` takes the error state when ``problem.ins_model`` is set, the random walk
        otherwise (:mod:`geofix.filters.motion`).
        """
        if takes_error_state(self.model, problem):
            return InsErrorState(self.use_dvl)
        return RandomWalk()

    def motion_model_of(self, state: PmfState) -> RandomWalk | InsErrorState:
        """The motion model a state was started with (an error-state track or none)."""
        return InsErrorState(self.use_dvl) if state.track is not None else RandomWalk()

    @property
    def likelihood(self) -> TerrainLikelihood:
        """The terrain measurement model of these settings."""
        dof = np.inf if self.student_dof is None else float(self.student_dof)
        return TerrainLikelihood(self.discretisation_noise, self.field_variance, dof)

    def memory_points(self) -> tuple[str, int]:
        """``("pmf", most nodes)`` the filter may hold (:mod:`geofix.filters.sizing`)."""
        return self.name, int(self.max_points) ** 2

    # ------------------------------------------------------------------ the recursion
    def initialize(self, problem: MatchProblem, rng: np.random.Generator) -> PmfState:
        """The motion model's prior on a square grid.

        ``N(indicated[0], sigma_position[0]^2 I)`` with the random walk; the error
        state's position prior with the error state (:meth:`motion_model_for`).

        Raises
        ------
        MatchError
            No node of the prior grid lies on valid map data (or ``model=errstate``
            without an INS error model).
        """
        log_weight, centre, spacing, extra = self.motion_model_for(problem).prior(self, problem)
        cell = problem.grid.cell_size
        return PmfState(log_weight, centre, np.eye(2), spacing, cell, **extra)

    def predict(self, state: PmfState, motion: Motion, rng: np.random.Generator) -> PmfState:
        """The motion model's prediction: the grid follows the posterior and moves.

        The weights are convolved with the motion kernel
        (:meth:`~geofix.filters.motion.RandomWalk.predict`,
        :meth:`~geofix.filters.motion.InsErrorState.predict`).

        Parameters
        ----------
        state : PmfState
            The state after the last update.
        motion : Motion
            The INS motion of the step (displacement, m; duration, s; process variance, m^2).
        rng : numpy.random.Generator
            Random draws of the step.
        """
        return self.motion_model_of(state).predict(self, state, motion)

    #: The update weighs further fields (``fields``): the sum of their log-likelihoods.
    fuses_fields: ClassVar[bool] = True

    def update(
        self, state: PmfState, obs: Observation, grid: Grid, rng, fields: tuple = ()
    ) -> PmfState:
        """Add every node's measurement log-likelihood (all beams at once).

        With ``model=errstate`` and an aiding DVL, the DVL velocity first updates the
        error-state Kalman filter and weighs the nodes (the motion model's ``aid``).
        Each further field adds its own log-likelihood at the same nodes, read on its own
        map at the nodes' positions (metres), its discretisation noise from its map's
        cell; its own offset per node when the ping asks for one (as the primary's).

        Parameters
        ----------
        state : PmfState
            The predicted state.
        obs : Observation
            The ping (beam offsets, m; values and variances, map units).
        grid : Grid
            The prior map.
        rng : numpy.random.Generator
            Random draws of the update.
        fields : tuple
            ``(Observation, Grid)`` of every further field at this sample (map units of
            that map; ``()``: none).
        """
        state = self.motion_model_of(state).aid(state, obs)
        if fields:
            return self._update_fields(state, obs, grid, fields)
        if not np.isfinite(obs.values).any():
            return state
        if self.carries_offset and state.offset is None:
            state = replace(state, offset=self.started_offset(state.shape, obs))
        ll, offset = self.likelihood.nodes(grid, obs, state)
        return shared_offsets(
            replace(
                state,
                log_weight=ops.normalise(state.log_weight + ll),
                evaluations=state.evaluations + ll.size,
                offset=offset,
            )
        )

    def started_offset(self, shape, obs: Observation) -> HypothesisOffset | None:
        """The nodes' offsets at their first ping (:meth:`HypothesisOffset.start`)."""
        return HypothesisOffset.start(
            shape,
            obs,
            self.fast_offset_walk,
            self.offset_rates,
            self.slow_offset_walk,
            None if self.offset_smooth_m is None else float(self.offset_smooth_m),
        )

    def _update_fields(self, state: PmfState, obs: Observation, grid: Grid, fields) -> PmfState:
        """The primary ping (when it has a value) and every further field's, summed."""
        ll: np.ndarray | float = 0.0
        offset = state.offset
        if np.isfinite(obs.values).any():
            if self.carries_offset and state.offset is None:
                state = replace(state, offset=self.started_offset(state.shape, obs))
            ll, offset = self.likelihood.nodes(grid, obs, state)
        evaluations = int(np.size(ll)) if np.ndim(ll) else 0
        count = len(state.field_offsets)
        field_offsets = list(state.field_offsets) + [None] * (len(fields) - count)
        for i, (field_obs, field_grid) in enumerate(fields):
            if not np.isfinite(field_obs.values).any():
                continue
            own = field_offsets[i]
            if own is None and self.carries_offset:
                own = self.started_offset(state.shape, field_obs)
            alone = replace(state, cell=field_grid.cell_size, offset=own)
            field_ll, field_offsets[i] = self.likelihood.nodes(field_grid, field_obs, alone)
            ll = ll + field_ll
            evaluations += field_ll.size
        if not evaluations:
            return state
        return shared_offsets(
            replace(
                state,
                log_weight=ops.normalise(state.log_weight + ll),
                evaluations=state.evaluations + evaluations,
                offset=offset,
                field_offsets=tuple(field_offsets),
            )
        )

    @property
    def carries_offset(self) -> bool:
        """Each node carries its own common offset (``map_model=imperfect``)."""
        return self.map_model == "imperfect"

    def offset_moments(
        self, state: PmfState, field: int | None = None
    ) -> tuple[float, float] | None:
        """The posterior offset's mean and variance (map units), or None without one.

        ``field``: that further field's offset (its index in ``fields``) instead.
        """
        offset = state.offset
        if field is not None:
            offset = state.field_offsets[field] if field < len(state.field_offsets) else None
        if offset is None:
            return None
        return offset.moments(np.exp(state.log_weight))

    def estimate(self, state: PmfState) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean ``(2,)`` and covariance ``(2, 2)``, metres and m^2."""
        return state.moments()

    def is_ambiguous(self, state: PmfState) -> bool:
        """More than ``ambiguity_mass`` of the posterior beyond the radius around the mean."""
        mean, _ = self.estimate(state)
        radius = self.ambiguity_radius_cells * state.cell
        return ops.mass_beyond(state.log_weight, *state.frame, mean, radius) > self.ambiguity_mass

    # ------------------------------------------------------------------ the moving grid
    def ideal_frame(self, state: PmfState, mean: np.ndarray, cov: np.ndarray) -> tuple:
        """``((centre, axes, spacing), shape)`` covering ``+-extent_sigmas`` of ``N(mean, cov)``.

        The half-extent along each principal axis is ``extent_sigmas`` standard deviations,
        and at least the reach of the nodes within ``support_nats`` of the peak
        (:meth:`support_half_extent`), changed by at most ``max_zoom`` from the current
        grid's; node spacing and count follow from it (:meth:`grid_layout`).

        Parameters
        ----------
        state : PmfState
            The current grid and posterior.
        mean : numpy.ndarray
            ``(2,)`` mean of the posterior to cover, metres.
        cov : numpy.ndarray
            ``(2, 2)`` its covariance, m^2.
        """
        values, axes = np.linalg.eigh(cov)
        half = self.extent_sigmas * np.sqrt(np.clip(values, 0.0, None))
        half = np.maximum(half, self.support_half_extent(state, mean, axes))
        current = 0.5 * state.spacing * (np.array(state.shape) - 1)
        half = np.clip(half, current.min() / self.max_zoom, current.max() * self.max_zoom)
        spacing, shape = self.grid_layout(half, state.cell)
        return (np.asarray(mean, dtype=float), axes, spacing), shape

    def support_half_extent(self, state: PmfState, centre, axes) -> np.ndarray:
        """Half-widths of the posterior's support along ``axes`` about ``centre``.

        ``(2,)`` metres: every node within ``support_nats`` of the peak log-weight, plus
        one node spacing.

        Parameters
        ----------
        state : PmfState
            The current grid and posterior.
        centre : numpy.ndarray
            ``(2,)`` centre of the new grid, metres.
        axes : numpy.ndarray
            ``(2, 2)`` its orthonormal axes as columns.
        """
        threshold = float(state.log_weight.max() - self.support_nats)
        u, v = state.node_offsets
        reach = grid_kernels.support_reach(
            state.log_weight,
            threshold,
            state.centre,
            state.axes,
            u,
            v,
            np.asarray(centre, dtype=float),
            np.ascontiguousarray(axes, dtype=float),
        )
        return reach + state.spacing.max()

    def grid_layout(self, half_extent: np.ndarray, cell: float) -> tuple:
        """Node ``spacing`` ``(2,)`` (metres) and ``shape`` ``(N0, N1)`` for a half-extent.

        ``points`` nodes per axis when that spacing is at most ``max_spacing_cells`` map
        cells (and never below ``min_spacing_cells``); otherwise the odd node count that
        keeps it there, at most ``max_points``.

        Parameters
        ----------
        half_extent : numpy.ndarray
            ``(2,)`` half-width of the grid along each of its axes, metres.
        cell : float
            Map cell size, metres.
        """
        base = self.points - 1
        half = np.maximum(half_extent, 0.5 * base * self.min_spacing_cells * cell)
        wanted = 2.0 * np.ceil(half / (self.max_spacing_cells * cell))
        intervals = np.clip(wanted, base, self.max_points - 1)
        return 2.0 * half / intervals, tuple(int(i) + 1 for i in intervals)

    def off_frame(self, state: PmfState, frame: tuple, shape: tuple) -> bool:
        """True when ``state``'s grid is too far from ``frame`` in spacing, size or position.

        Parameters
        ----------
        state : PmfState
            The current grid.
        frame : tuple
            ``(centre (2,), axes (2, 2), spacing (2,))`` of the ideal grid, metres.
        shape : tuple
            ``(N0, N1)`` nodes of the ideal grid.
        """
        centre, axes, spacing = frame
        basis = state.axes * state.spacing
        # one solve for the new node steps and the shift, in units of the current steps
        solved = np.linalg.solve(basis, np.column_stack([axes * spacing, centre - state.centre]))
        limit = math.log(self.regrid_ratio)
        if max(abs(math.log(s)) if s > 0 else math.inf for s in _singular_values(solved)) > limit:
            return True
        size = np.log(np.sort(np.array(shape) - 1) / np.sort(np.array(state.shape) - 1))
        if np.max(np.abs(size)) > limit:
            return True
        half = 0.5 * (np.array(state.shape) - 1)
        return bool(np.max(np.abs(solved[:, 2]) / half) > self.regrid_shift)


def _singular_values(m: np.ndarray) -> tuple[float, float]:
    """Singular values of the ``2 x 2`` matrix ``m[:, :2]`` (closed form, ``>= 0``)."""
    (a, b), (c, d) = m[0, :2].tolist(), m[1, :2].tolist()
    p, q, r = a * a + c * c, a * b + c * d, b * b + d * d  # m^T m
    mid, dev = 0.5 * (p + r), math.hypot(0.5 * (p - r), q)
    return math.sqrt(mid + dev), math.sqrt(max(mid - dev, 0.0))


__all__ = ["REGRID_COPIES", "Pmf", "PmfState", "check_regrid", "node_field_variance"]
