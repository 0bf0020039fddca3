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
  (``field_variance=local``, :func:`~geofix.measurement.node_grid_local_log_likelihood`).
  One global variance for every node (``field_variance=global``) let a node ~160 m off
  the truth on rough terrain lose ~17 nats in one sample against a wrong mode on flat
  ground, and the true mode fell below ``support_nats`` for good.

Everything stays in log space (:mod:`geofix.filters._grid_ops`), so a likelihood however
peaked gives no underflow and no NaN. The convolution is two direct 1-D passes (compiled
with the rest of the step's grid loops, :mod:`geofix.filters._grid_kernels`) rather than
an FFT: on the 61 x 61 grid with kernels of 3 to 73 taps direct passes were faster than
``scipy.signal.fftconvolve``, and as a sum of non-negative terms they are exact in the
tails, where FFT round-off (1e-16 of the peak) would plant mass that later likelihoods,
added in log space, could amplify.

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
squarely; over many samples that bias compounds into a confident wrong fix (a 61-node
prior grid over a 30 km error on a 1 km map put 2 km between nodes and converged on wrong
places in a third of the runs). Once the posterior has shrunk the count falls back to
``points``, so the extra cost is paid only in the first, wide steps.

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

from geofix._measurement_kernels import node_field_variance_kernel
from geofix.errors import ConfigError, MatchError
from geofix.filters import _grid_kernels as grid_kernels
from geofix.filters import _grid_ops as ops
from geofix.filters._pmf_errstate import conditional_motion, dvl_update, replace_marginal
from geofix.filters.base import Motion, Observation, RecursiveFilter
from geofix.filters.hypothesis_offset import HypothesisOffset, mixed_offsets, regridded_offsets
from geofix.filters.nuisance import check_map_model
from geofix.filters.pf import check_field_variance, uses_local_field
from geofix.maps.grid import Grid
from geofix.measurement import (
    local_field_log_likelihood,
    log_likelihood,
    node_grid_local_log_likelihood,
    node_grid_log_likelihood,
    predict_measurements,
)
from geofix.memory import cells_bytes, check_allocation
from geofix.nav.errstate import ErrorState, error_state, step_matrices, step_velocities
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
    kf : tuple or None
        ``(mu (d,), Sigma (d, d))`` of the INS error state (``model=errstate``).
    errstate : ErrorState or None
        The error model along the indicated track (``model=errstate``).
    indicated : numpy.ndarray or None
        ``(2,)`` indicated position at the current sample (``model=errstate``), metres.
    step : int
        Current sample index.
    dvl : numpy.ndarray or None
        ``(n, 2)`` ``v_INS - v_DVL`` at every sample, m/s, when a DVL aids
        (``model=errstate``).
    offset : HypothesisOffset or None
        Each node's common offset (``map_model=imperfect``), from the first ping on.
    """

    log_weight: np.ndarray
    centre: np.ndarray
    axes: np.ndarray
    spacing: np.ndarray
    cell: float
    evaluations: int = 0
    regrids: int = 0
    kf: tuple[np.ndarray, np.ndarray] | None = None
    errstate: ErrorState | None = None
    indicated: np.ndarray | None = None
    step: int = 0
    dvl: np.ndarray | None = None
    offset: HypothesisOffset | None = None

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
    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean ``(2,)`` and covariance ``(2, 2)``, metres and m^2.

        Cached: the state is immutable, and every step asks for them more than once.
        """
        return ops.moments(self.log_weight, *self.frame, offsets=self.node_offsets)


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
        Most nodes per axis (odd, at least ``points``). 301 keeps a 16-beam update of the
        full grid near 10 ms; at 0.5 cell spacing it resolves a prior of +-75 cells. A
        wider prior gets coarser nodes: ``source002_bank``'s error-state prior is 0.8
        cells apart at 301, and ``model=errstate`` locks 1 of its 60 trials on a mode
        13 km off; ``max_points=501`` (0.48 cells) loses none, the trial 6 % longer. 501
        as the default changes nothing measurable on source 000 / 001 (30 trials each)
        while their first updates, now on up to 501 x 501 nodes, make a trial up to 2.6
        times longer (``benchmarks/sweep_filters.py``).
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
        :data:`~geofix.filters.pf.LOCAL_MAX_SPACING_CELLS` map cells (a coarser grid
        takes the global one). ``global``: one variance for the whole grid, the mean
        over nodes and beams (the earlier model).
    ambiguity_radius_cells : float
        Radius around the fix, map cells, for the integrity flag.
    ambiguity_mass : float
        Posterior share beyond that radius above which the fix is flagged ambiguous.
    model : str
        Motion model: ``rw`` (the INS error as a white random walk of per-axis variance
        ``Motion.process_var``) or ``errstate`` (the INS error state of
        :mod:`geofix.nav.errstate`, its prior the simulator's second moments, from
        ``problem.ins_model``; see :mod:`geofix.filters._pmf_errstate`). With
        ``use_dvl`` the error-state model folds in an aiding DVL's velocity, as ``mpf``
        does (:func:`geofix.filters._pmf_errstate.dvl_update`).
    use_dvl : bool
        Fold in an aiding DVL's velocity when the problem has one (``model=errstate``;
        the random-walk model has no velocity state to aid).
    map_model : str
        What the likelihood assumes of the prior map: ``imperfect`` (default),
        ``adaptive`` or ``exact`` (:data:`geofix.filters.nuisance.MAP_MODELS`).

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
    model: str = "rw"
    use_dvl: bool = True
    map_model: str = "imperfect"

    def __post_init__(self) -> None:
        if self.model not in ("rw", "errstate"):
            raise ConfigError(f"pmf: model must be rw or errstate, got {self.model!r}")
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
        """The error-state motion model needs an INS error model (``problem.ins_model``)."""
        return self.model == "errstate"

    # ------------------------------------------------------------------ the recursion
    def initialize(self, problem: MatchProblem, rng: np.random.Generator) -> PmfState:
        """Gaussian prior ``N(indicated[0], sigma_position[0]^2 I)`` on a square grid.

        Raises
        ------
        MatchError
            No node of the prior grid lies on valid map data.
        """
        if self.model == "errstate":
            return self._initialize_errstate(problem)
        cell = problem.grid.cell_size
        floor = self.min_spacing_cells * cell * (self.points - 1) / (2 * self.extent_sigmas)
        sigma = max(float(problem.sigma_position[0]), floor)
        centre = np.asarray(problem.indicated[0], dtype=float)
        spacing, shape = self.grid_layout(np.full(2, self.extent_sigmas * sigma), cell)
        xy = ops.node_positions(centre, np.eye(2), spacing, shape)
        if not np.isfinite(predict_measurements(problem.grid, xy, 0.0, np.zeros((1, 2)))).any():
            raise MatchError("pmf: the prior grid lies entirely off the map")
        log_weight = ops.gaussian_log_density(xy, centre, sigma**2 * np.eye(2))
        return PmfState(ops.normalise(log_weight), centre, np.eye(2), spacing, cell)

    def predict(self, state: PmfState, motion: Motion, rng: np.random.Generator) -> PmfState:
        """Follow the posterior with the grid, convolve with the motion kernel, shift."""
        if self.model == "errstate":
            return self._predict_errstate(state, motion)
        state = self._follow(state, motion.process_var)
        sd = np.sqrt(motion.process_var)
        k0, k1 = (
            ops.motion_kernel(sd / h, n - 1)
            for h, n in zip(state.spacing, state.shape, strict=True)
        )
        kernels = (k0, k1)
        log_weight = ops.convolve_log(state.log_weight, kernels)
        centre = state.centre + np.asarray(motion.displacement, dtype=float)
        offset = state.offset
        if offset is not None:
            mean = mixed_offsets(state.log_weight, offset.mean, kernels)
            offset = replace(offset, mean=mean).predicted(motion.dt)
        return replace(state, log_weight=log_weight, centre=centre, offset=offset)

    def update(self, state: PmfState, obs: Observation, grid: Grid, rng) -> PmfState:
        """Add every node's measurement log-likelihood (all beams at once).

        With ``model=errstate`` and an aiding DVL, the DVL velocity first updates the
        error-state Kalman filter and weighs the nodes.
        """
        if state.dvl is not None and np.isfinite(state.dvl[obs.index]).all():
            state = self._dvl_update(state, state.dvl[obs.index])
        if not np.isfinite(obs.values).any():
            return state
        if self.carries_offset and state.offset is None:
            state = replace(state, offset=HypothesisOffset.start(state.shape, obs))
        if state.offset is not None:
            return self._update_with_offsets(state, obs, grid)
        if self.discretisation_noise and uses_local_field(self, state.spacing.max(), state.cell):
            return self._update_local(state, obs, grid)
        if obs.bias_var > 0 or grid.interpolation != "bilinear":
            return self._update_reference(state, obs, grid)
        # One compiled pass over nodes x beams (the reference path -- node_positions,
        # predict_measurements, node_field_variance, log_likelihood -- to ~1e-15 relative).
        u, v = state.node_offsets
        ll, _ = node_grid_log_likelihood(
            grid,
            (state.centre, state.axes, u, v),
            obs.heading,
            obs.offsets,
            obs.values,
            obs.noise_var,
            self.discretisation_noise,
        )
        log_weight = ops.normalise(state.log_weight + ll)
        return replace(state, log_weight=log_weight, evaluations=state.evaluations + ll.size)

    def _update_local(self, state: PmfState, obs: Observation, grid: Grid) -> PmfState:
        """The update with every node's own field variation within its cell.

        One compiled pass over the nodes (one more row and column read for the last
        nodes' differences); through the prediction arrays with a common offset or a map
        read other than bilinear.
        """
        if obs.bias_var == 0 and grid.interpolation == "bilinear":
            u, v = state.node_offsets
            frame = (state.centre, state.axes, u, v)
            args = (obs.heading, obs.offsets, obs.values, obs.noise_var)
            ll = node_grid_local_log_likelihood(grid, frame, state.spacing, *args)
            log_weight = ops.normalise(state.log_weight + ll)
            return replace(state, log_weight=log_weight, evaluations=state.evaluations + ll.size)
        xy = ops.node_positions(*state.frame, state.shape)
        sides = (state.axes * state.spacing).T  # rows: one node step along each grid axis
        ll = local_field_log_likelihood(
            grid,
            xy,
            obs.heading,
            obs.offsets,
            obs.values,
            obs.noise_var,
            sides,
            obs.bias_var,
        )
        log_weight = ops.normalise(state.log_weight + ll)
        return replace(state, log_weight=log_weight, evaluations=state.evaluations + ll.size)

    @property
    def carries_offset(self) -> bool:
        """Each node carries its own common offset (``map_model=imperfect``)."""
        return self.map_model == "imperfect"

    def offset_moments(self, state: PmfState) -> tuple[float, float] | None:
        """The posterior offset's mean and variance (map units), or None without one."""
        if state.offset is None:
            return None
        return state.offset.moments(np.exp(state.log_weight))

    def _update_with_offsets(self, state: PmfState, obs: Observation, grid: Grid) -> PmfState:
        """The update marginalised over each node's own offset ``N(b_i, P)``, then the offsets'.

        The nodes' predictions are read once for both (the local field variance reads its
        own, with the nodes' sides).
        """
        offset = state.offset
        assert offset is not None
        xy = ops.node_positions(*state.frame, state.shape)
        predicted = predict_measurements(grid, xy, obs.heading, obs.offsets)
        if self.discretisation_noise and uses_local_field(self, state.spacing.max(), state.cell):
            sides = (state.axes * state.spacing).T
            args = (obs.heading, obs.offsets, obs.values, obs.noise_var, sides)
            ll = local_field_log_likelihood(grid, xy, *args, offset.var, offset.mean)
        else:
            shifted = predicted + offset.mean[..., None]
            var = obs.noise_var
            if self.discretisation_noise:
                var = var + node_field_variance(shifted, obs.values)
            ll = log_likelihood(shifted, obs.values, var, offset.var)
        return replace(
            state,
            log_weight=ops.normalise(state.log_weight + ll),
            evaluations=state.evaluations + ll.size,
            offset=offset.updated(grid, xy, obs, predicted),
        )

    def _update_reference(self, state: PmfState, obs: Observation, grid: Grid) -> PmfState:
        """The update through the prediction array.

        For the common-offset likelihood and for map reads other than bilinear, which the
        fused pass does not cover.
        """
        xy = ops.node_positions(*state.frame, state.shape)
        predicted = predict_measurements(grid, xy, obs.heading, obs.offsets)
        var = obs.noise_var  # a float or a read-only (b,) array: never changed in place
        if self.discretisation_noise:
            var = var + node_field_variance(predicted, obs.values)
        log_weight = ops.normalise(
            state.log_weight + log_likelihood(predicted, obs.values, var, obs.bias_var)
        )
        return replace(state, log_weight=log_weight, evaluations=state.evaluations + xy.size // 2)

    def estimate(self, state: PmfState) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean ``(2,)`` and covariance ``(2, 2)``, metres and m^2."""
        mean, cov = state.moments
        return mean.copy(), cov.copy()

    def is_ambiguous(self, state: PmfState) -> bool:
        """More than ``ambiguity_mass`` of the posterior beyond the radius around the mean."""
        mean, _ = self.estimate(state)
        radius = self.ambiguity_radius_cells * state.cell
        return ops.mass_beyond(state.log_weight, *state.frame, mean, radius) > self.ambiguity_mass

    # ------------------------------------------------------------------ error state
    def _initialize_errstate(self, problem: MatchProblem) -> PmfState:
        model = problem.ins_model
        if model is None:
            raise MatchError("pmf: model=errstate needs the INS error model (problem.ins_model)")
        es = error_state(model, problem.times, problem.indicated)
        cell = problem.grid.cell_size
        floor = self.min_spacing_cells * cell * (self.points - 1) / (2 * self.extent_sigmas)
        sigma = es.prior_cov
        sigma[:2, :2] += floor**2 * np.eye(2)
        centre = np.asarray(problem.indicated[0], dtype=float)
        half = self.extent_sigmas * np.sqrt(np.diag(sigma[:2, :2]))
        spacing, shape = self.grid_layout(half, cell)
        xy = ops.node_positions(centre, np.eye(2), spacing, shape)
        if not np.isfinite(predict_measurements(problem.grid, xy, 0.0, np.zeros((1, 2)))).any():
            raise MatchError("pmf: the prior grid lies entirely off the map")
        # position = indicated - dp: the position prior is N(indicated, Sigma_pp)
        log_weight = ops.gaussian_log_density(xy, centre, sigma[:2, :2])
        return PmfState(
            ops.normalise(log_weight),
            centre,
            np.eye(2),
            spacing,
            cell,
            kf=(np.zeros(es.dim), sigma),
            errstate=es,
            indicated=centre,
            dvl=self._dvl_innovations(problem, es),
        )

    def _dvl_innovations(self, problem: MatchProblem, es: ErrorState) -> np.ndarray | None:
        """``v_INS - v_DVL`` ``(n, 2)`` m/s (``v_INS`` the indicated step velocity)."""
        dvl = problem.dvl_velocity
        if not self.use_dvl or dvl is None or es.velocity_map is None:
            return None
        return step_velocities(problem.times, problem.indicated) - np.asarray(dvl, float)

    def _dvl_update(self, state: PmfState, y: np.ndarray) -> PmfState:
        """The DVL's velocity: node log-likelihoods and the Kalman update of the error state."""
        es = state.errstate
        assert es is not None and es.velocity_map is not None and state.kf is not None
        assert state.indicated is not None
        dp = state.indicated - ops.node_positions(*state.frame, state.shape)
        log_like, kf = dvl_update(*state.kf, es.velocity_map, es.velocity_noise_var, y, dp)
        log_weight = ops.normalise(state.log_weight + log_like.reshape(state.shape))
        return replace(state, log_weight=log_weight, kf=kf)

    def _predict_errstate(self, state: PmfState, motion: Motion) -> PmfState:
        es, k = state.errstate, state.step
        assert es is not None and state.kf is not None and state.indicated is not None
        mean, cov = self.estimate(state)
        mu, sigma = replace_marginal(state.kf[0], state.kf[1], state.indicated - mean, cov)
        es, f, q = step_matrices(es, k, motion.displacement, motion.dt, motion.process_var)
        g, h, kernel = conditional_motion(mu, sigma, f, q)
        indicated = state.indicated + np.asarray(motion.displacement, dtype=float)
        shift = indicated - g @ state.indicated - h  # position' = G position + shift
        moved_mean = g @ mean + shift
        moved_cov = g @ cov @ g.T + kernel
        moved = replace(state, centre=g @ state.centre + shift, axes=g @ state.axes)
        (centre, axes, spacing), shape = self.ideal_frame(moved, moved_mean, moved_cov)
        check_regrid(shape)
        g_inv = np.linalg.inv(g)
        pulled = (g_inv @ (centre - shift), g_inv @ axes, spacing)
        fallback = (mean, g_inv @ moved_cov @ g_inv.T)
        log_weight = ops.resample_grid(state.log_weight, state.frame, pulled, fallback, shape)
        along = np.einsum("ij,ik,kj->j", axes, kernel, axes)  # K along the new grid axes
        k0, k1 = (
            ops.motion_kernel(np.sqrt(max(v, 0.0)) / s) for v, s in zip(along, spacing, strict=True)
        )
        kernels = (k0, k1)
        mu_next = f @ mu
        sigma_next = f @ sigma @ f.T + q
        offset = state.offset
        if offset is not None:
            moved_offsets = regridded_offsets(offset.mean, state.frame, pulled, shape)
            mixed = mixed_offsets(log_weight, moved_offsets, kernels)
            offset = replace(offset, mean=mixed).predicted(motion.dt)
        return replace(
            state,
            offset=offset,
            log_weight=ops.convolve_log(log_weight, kernels),
            centre=centre,
            axes=axes,
            spacing=spacing,
            kf=(mu_next, 0.5 * (sigma_next + sigma_next.T)),
            errstate=es,
            indicated=indicated,
            step=k + 1,
            regrids=state.regrids + 1,
        )

    # ------------------------------------------------------------------ the moving grid
    def _follow(self, state: PmfState, process_var: float) -> PmfState:
        """Move the log-density onto the ideal grid for the coming prediction if needed."""
        mean, cov = self.estimate(state)
        frame, shape = self.ideal_frame(state, mean, cov + process_var * np.eye(2))
        if not self._off_frame(state, frame, shape):
            return state
        check_regrid(shape)
        log_weight = ops.resample_grid(state.log_weight, state.frame, frame, (mean, cov), shape)
        offset = state.offset
        if offset is not None:
            moved = regridded_offsets(offset.mean, state.frame, frame, log_weight.shape)
            offset = replace(offset, mean=moved)
        centre, axes, spacing = frame
        return replace(
            state,
            offset=offset,
            log_weight=log_weight,
            centre=centre,
            axes=axes,
            spacing=spacing,
            regrids=state.regrids + 1,
        )

    def ideal_frame(self, state: PmfState, mean: np.ndarray, cov: np.ndarray) -> tuple:
        """``((centre, axes, spacing), shape)`` covering ``+-extent_sigmas`` of ``N(mean, cov)``.

        The half-extent along each principal axis is ``extent_sigmas`` standard deviations,
        and at least the reach of the nodes within ``support_nats`` of the peak
        (:meth:`support_half_extent`), changed by at most ``max_zoom`` from the current
        grid's; node spacing and count follow from it (:meth:`grid_layout`).
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

    def _off_frame(self, state: PmfState, frame: tuple, shape: tuple) -> bool:
        """True when ``state``'s grid is too far from ``frame`` in spacing, size or position."""
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


#: Float arrays of one value per node a regrid allocates (positions, densities, the
#: convolution's passes, the offsets): checked against the memory budget before it.
REGRID_COPIES = 12


def check_regrid(shape) -> None:
    """Refuse, against the memory budget, a regrid onto ``shape`` nodes before it runs."""
    n0, n1 = (int(shape), int(shape)) if np.ndim(shape) == 0 else (int(n) for n in shape)
    check_allocation(cells_bytes(n0, n1, copies=REGRID_COPIES), f"pmf regrid to {n0} x {n1} nodes")


def _singular_values(m: np.ndarray) -> tuple[float, float]:
    """Singular values of the ``2 x 2`` matrix ``m[:, :2]`` (closed form, ``>= 0``)."""
    (a, b), (c, d) = m[0, :2].tolist(), m[1, :2].tolist()
    p, q, r = a * a + c * c, a * b + c * d, b * b + d * d  # m^T m
    mid, dev = 0.5 * (p + r), math.hypot(0.5 * (p - r), q)
    return math.sqrt(mid + dev), math.sqrt(max(mid - dev, 0.0))


def node_field_variance(predicted: np.ndarray, measured: np.ndarray) -> float:
    """Variance of the field within one grid node, map units squared.

    Parameters
    ----------
    predicted : numpy.ndarray
        ``(N0, N1, b)`` field each beam reads from each node (NaN off the map).
    measured : numpy.ndarray
        ``(b,)`` measurement; only the beams it holds count.

    Returns
    -------
    float
        ``(mean(d0^2) + mean(d1^2)) / 12`` with ``d0``, ``d1`` the field differences between
        neighbouring nodes along each grid axis (a position uniform over one node's cell);
        0 when no difference is finite.
    """
    return node_field_variance_kernel(predicted, measured)  # one compiled pass
