r"""The marginalised (Rao–Blackwellised) particle filter on the INS error state.

The navigation error is the linear state of :mod:`geofix.nav.errstate`,
``x = [dp, x_l]``: the horizontal position error ``dp`` (the only part the terrain or
gravity measurement sees) and the linear INS error states ``x_l`` (velocity error, tilt,
accelerometer bias, gyro drifts, heading error; scale and bias of a DVL dead reckoning;
the bias of an aiding DVL). After Schön, Gustafsson & Nordlund (2005), "Marginalized
particle filters for mixed linear/nonlinear state-space models", IEEE Trans. Signal
Processing 53(7), and Nordlund & Gustafsson (2009), "Marginalized particle filter for
accurate and reliable terrain-aided navigation", IEEE Trans. Aerospace and Electronic
Systems 45(4):

- particles carry ``dp`` (the vehicle position is ``indicated - dp``), each with the mean
  ``m_i`` of a Kalman filter on ``x_l`` given its position history. The linear part's
  model does not depend on the particle, so every Kalman filter has the same covariance
  ``P``: one ``(d_l, d_l)`` matrix for the whole set, and the per-particle work is a few
  matrix products over all particles at once;
- **predict** (``x_k = F_k x_{k-1} + w_k``): the joint prediction of ``[dp, x_l]`` given
  the particle's ``dp`` and ``N(m_i, P)`` has mean ``F_k [dp_i, m_i]`` and the shared
  covariance ``S = F_k diag(0, P) F_k^T + Q_k``; the new ``dp_i`` is drawn from its
  ``dp`` marginal (``S_pp``) and the linear mean and covariance are conditioned on it
  (``m_i = mu_l + S_lp S_pp^-1 (dp_i - mu_p)``, ``P = S_ll - S_lp S_pp^-1 S_pl``): the
  "measurement" of the linear states by the particle's motion, with the correlated process
  noise of the exact discretisation handled in one step;
- **update**: the terrain / gravity likelihood of every particle's footprints, the same
  code as the point-mass and particle filters
  (:meth:`~geofix.filters.likelihood.TerrainLikelihood.particles`, the likelihood
  flattening of :func:`~geofix.filters.likelihood.spread_field_variance` while the set is
  sparse, or each particle's own with ``field_variance=local``); with an
  aiding DVL, the velocity measurement ``v_INS - v_DVL = C x_l + noise`` updates every
  Kalman filter (shared gain) and weighs each particle by its marginal likelihood
  ``N(y; C m_i, C P C^T + R)``. ``v_INS`` is the indicated displacement over the step
  divided by its duration;
- resampling (systematic, at ``ESS < resample_threshold * M``), the particle count rule
  and the stratified prior are those of :mod:`geofix.filters.pf`. The INS error is
  (nearly) noise-free, so a particle's motion determines its linear states exactly and
  ``P`` collapses: the uncertainty then lives in the spread of the ``m_i``, and copies
  made by resampling would never separate again. After each resampling the joint
  vectors ``z_i = [dp_i, m_i]`` are therefore moved by the kernel of Liu & West (2001,
  "Combined parameter and state estimation in simulation-based filtering"):
  ``z_i <- mean + a (z_i - mean) + h e_i``, ``e_i ~ N(0, C)`` with ``C`` the weighted
  covariance of the set before resampling and ``a = sqrt(1 - h^2)`` (the set's mean and
  covariance are kept). Two points make the move keep the filter consistent:

  * the uncertainty lives in the whole joint ``z`` (dimension ``d = 2 + d_l``), so the
    bandwidth is Musso, Oudjane & Le Gland's (2001) ``h = (4 / ((d + 2) M))^(1/(d+4))``
    for ``d`` dimensions (the two-dimension value, about half as wide, let the linear
    states' spread dwindle resampling after resampling: the position covariance shrank
    below the Cramér–Rao bound and the filter ended sure of a wrong position). The
    kernel is Rao–Blackwellised: ``e_i``'s ``dp`` part is drawn, the linear means
    follow its regression, and the linear part's conditional covariance
    ``h^2 (C_ll - C_lp C_pp^-1 C_pl)`` is added to the shared ``P`` instead of being
    drawn;
  * a global Gaussian kernel is only right for a near-Gaussian set. A set spread over
    several modes (a wide prior on ambiguous terrain) would have its particles pulled
    towards the global mean and thrown between the modes, losing the true one;
    while the positions' Mardia kurtosis says the set is not near-Gaussian
    (:func:`near_gaussian`) the resampled positions are only jittered within their own
    share of the area (``spacing / sqrt(12)`` per axis, the linear means following),
    and so are they where the particles carry offsets learnt along their paths and pool
    them (:meth:`Mpf.offset_pool_of`: by default on profile pings, a single-beam
    echosounder or a gravimeter): the kernel move would carry a copy away from the path
    its offset was learnt on.

The INS error is (nearly) noise-free, so its states are in effect static parameters of
each particle's path, and a particle filter on static parameters degenerates: once the
set has collapsed onto the survivors of a wide prior, the copies share a few linear means,
the shared ``P`` has shrunk with every motion, and the set can end a few metres wide
while hundreds of metres off. Every prediction therefore adds a
small position random walk, ``position_walk_cells`` map cells per square root of a second
(default 2e-4: 1.1 m per 30 s step on a 1 km map, 9 mm per 20 s step on a 10 m map), the
unmodelled part of the motion (the map's interpolation error, the vehicle's unlogged
manoeuvres): the particles keep exploring around the terrain's peak, and the linear
states learn a little less from each particle's motion.

An update sharper than a sparse set can represent (many beams on a prior lattice a
fraction of a cell apart: a few particles would keep all the weight, by the luck of
where the lattice fell) is applied in stages (progressive correction, Oudjane & Musso
2000, "Progressive correction for regularized particle filters", FUSION): the largest
fraction of the log-likelihood that leaves ``min_update_ess`` effective particles, then
a resample whose copies are spread uniformly over the share of the particle they copy,
and the likelihood read again at the moved particles, until the whole likelihood is in.

The prior is the error state's (the simulator's second moments), read from
``problem.ins_model`` (:class:`~geofix.nav.errstate.InsErrorModel`, put there
for simulated trials); the error state is built along the *indicated* track. With
``prior=simulator`` the start position error's prior is instead the distribution the
simulator draws it from (a bias and a spread), for comparison with the bound that holds
for any estimator (:mod:`geofix.evaluate.zzb`). The
estimate is the weighted mean and covariance of the particle positions.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from geofix.errors import ConfigError, MatchError
from geofix.filters._fields import (
    taken_offsets,
    update_particle_fields,
)
from geofix.filters._weights import (
    RESAMPLE_COPIES,
    effective_sample_size,
    linear_weights,
    log_normalised,
    systematic_resample,
)
from geofix.filters.base import Motion, Observation
from geofix.filters.hypothesis_offset import HypothesisOffset, shared_offsets
from geofix.filters.motion import InsErrorState
from geofix.filters.pf import ParticleSettings, pooled_offsets_of
from geofix.maps.grid import Grid
from geofix.measurement import predict_measurements
from geofix.memory import cells_bytes, check_allocation
from geofix.nav.errstate import ErrorState, error_state, step_matrices
from geofix.problem import MatchProblem

_P = slice(0, 2)
_L = slice(2, None)
#: Floor of the position variance of one prediction, m^2 (keeps ``S_pp`` invertible).
MIN_STEP_VAR = 1e-6
#: Fewest beams of a ping that tells its own offset (a swath); fewer make a profile,
#: whose offset the particles learn along their paths (:meth:`Mpf.offset_pool_of`).
PROFILE_BEAMS = 3
#: ``offset_pool`` of an ``mpf`` left unset, on profile pings (particle spacings; 0 on
#: a swath's): :meth:`Mpf.offset_pool_of`.
PROFILE_OFFSET_POOL = 2.0

PRIORS = ("moments", "simulator")
"""Priors of the start position error :class:`Mpf` can hold (its ``prior`` setting)."""


@dataclass(frozen=True, eq=False)
class MpfState:
    """An immutable marginalised particle set.

    Parameters
    ----------
    dp : numpy.ndarray
        ``(M, 2)`` position error of every particle, metres (position = indicated - dp).
    linear : numpy.ndarray
        ``(M, d_l)`` Kalman means of the linear states.
    cov : numpy.ndarray
        ``(d_l, d_l)`` their shared covariance.
    log_weight : numpy.ndarray
        ``(M,)`` normalised log-weights.
    indicated : numpy.ndarray
        ``(2,)`` indicated position at the current sample, metres.
    step : int
        Current sample index.
    model : ErrorState
        The error model along the indicated track.
    dvl : numpy.ndarray or None
        ``(n, 2)`` ``v_INS - v_DVL`` at every sample, m/s, when a DVL aids.
    cell, spacing : float
        Map cell and typical particle spacing, metres.
    evaluations, resamples : int
        Likelihoods evaluated and resampling steps so far.
    offset : HypothesisOffset or None
        Each particle's common offset (``map_model=imperfect``), from the first ping on.
    field_offsets : tuple
        The same per further field (:attr:`MatchProblem.fields`, in order; None for a
        field without one), from its first ping on.
    profile : bool
        The last ping was a profile's (fewer than :data:`PROFILE_BEAMS` beams).
    """

    dp: np.ndarray
    linear: np.ndarray
    cov: np.ndarray
    log_weight: np.ndarray
    indicated: np.ndarray
    step: int
    model: ErrorState
    dvl: np.ndarray | None
    cell: float
    spacing: float = 0.0
    evaluations: int = 0
    resamples: int = 0
    offset: HypothesisOffset | None = None
    field_offsets: tuple = ()
    profile: bool = False

    @property
    def positions(self) -> np.ndarray:
        """``(M, 2)`` absolute particle positions, metres."""
        return self.indicated - self.dp

    @functools.cached_property
    def weights(self) -> np.ndarray:
        """``(M,)`` linear weights summing to one (read-only, computed once per state)."""
        w = linear_weights(self.log_weight)
        w.setflags(write=False)
        return w

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean ``(2,)`` and covariance ``(2, 2)`` of the positions, m and m^2."""
        return weighted_moments(self.positions, self.weights)

    def mode(self) -> np.ndarray:
        """The position ``(2,)`` of the highest-weight particle, metres."""
        return np.asarray(self.positions[int(np.argmax(self.log_weight))], dtype=float)

    def points(self) -> tuple[np.ndarray, np.ndarray]:
        """``(positions (M, 2), log_weight (M,))``."""
        return self.positions, self.log_weight

    def node_area(self) -> None:
        """None: the particles are a random sample, not nodes with cells."""
        return None


@dataclass(frozen=True)
class Mpf(ParticleSettings):
    """Marginalised particle filter settings.

    The particle settings it shares with :class:`~geofix.filters.pf.Pf` are those of
    :class:`~geofix.filters.pf.ParticleSettings`.

    Parameters
    ----------
    regularise : bool
        Move the resampled particles with a shrunk Gaussian kernel (see the module text).
    use_dvl : bool
        Fold in an aiding DVL's velocity when the problem has one.
    position_walk_cells : float
        Position random walk added to every prediction, map cells per square root of a
        second (see :meth:`predict`).
    prior : str
        The prior of the start position error: ``moments`` (zero mean, the simulator's
        second moments: what a navigator that knows only the INS's error budget holds,
        the default) or ``simulator`` (the very distribution the simulator draws it from,
        ``N(initial_offset, initial_std^2)`` per axis: a filter told the INS's bias, to
        measure against a bound that holds for any estimator on the trials).
    offset_pool : float or None
        As :class:`~geofix.filters.pf.ParticleSettings`'s, pooling and jittering the
        copies within their share instead of the kernel move; None (the default):
        :data:`PROFILE_OFFSET_POOL` on profile pings and 0 on a swath's
        (:meth:`offset_pool_of`).
    """

    name: ClassVar[str] = "mpf"
    #: The filter needs an INS error model (``problem.ins_model``; a navigator's ``ins_model``).
    needs_ins_model: ClassVar[bool] = True

    regularise: bool = True
    use_dvl: bool = True
    position_walk_cells: float = 2e-4
    prior: str = "moments"
    offset_pool: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.prior not in PRIORS:
            raise ConfigError(f"mpf: prior must be one of {', '.join(PRIORS)}, got {self.prior!r}")
        if not (np.isfinite(self.position_walk_cells) and self.position_walk_cells >= 0):
            raise ConfigError(
                f"mpf: position_walk_cells must be finite and >= 0, got {self.position_walk_cells}"
            )

    def offset_pool_of(self, state: MpfState) -> float:
        """The ``offset_pool`` the set is resampled with, particle spacings.

        The setting when given. Unset: :data:`PROFILE_OFFSET_POOL` where the last ping
        was a profile's (:attr:`MpfState.profile`), whose offset the particles learn
        along their paths, and 0 on a swath's, which tells its own. Unpooled on
        profiles, the kernel move carried copies away from their paths' offsets and a
        gravimeter's filter over a 3 km prior ended one trial in sixteen 18.6 km off
        (RESULTS, *Fused fields*, gravity alone); jittered but unpooled, the filter
        claimed ``converged`` beyond 3 sigma on 138 of 2542 pings of the real ship tracks
        against ETOPO1, pooled on none. Jittered on a swath's pings, the filter lost
        five trials of eight on the identical multibeam map of *Imperfect maps* (the
        kernel move is what keeps a collapsing swath set's linear states spread).
        """
        if self.offset_pool is not None:
            return float(self.offset_pool)
        return PROFILE_OFFSET_POOL if state.profile else 0.0

    # ------------------------------------------------------------------ protocol
    def initialize(self, problem: MatchProblem, rng: np.random.Generator) -> MpfState:
        """A stratified sample of the error state's position prior, Kalman means given it.

        Raises
        ------
        MatchError
            The problem carries no INS error model, or no particle lies on the map.
        """
        model = problem.ins_model
        if model is None:
            raise MatchError("mpf: the problem has no INS error model (problem.ins_model)")
        es = error_state(model, problem.times, problem.indicated)
        mean = np.zeros(2)
        if self.prior == "simulator":
            es = es.with_simulator_position_prior()
            mean = np.asarray(model.initial_offset, dtype=float)
        cell = problem.grid.cell_size
        p0 = es.prior_cov
        p0[_P, _P] += (1e-3 * cell) ** 2 * np.eye(2)
        sd = np.sqrt(np.diag(p0[_P, _P]))
        dev, h = self.stratified(sd, cell, rng)
        dp = mean + dev
        start = np.asarray(problem.indicated[0], dtype=float)
        if not np.isfinite(
            predict_measurements(problem.grid, start - dp, 0.0, np.zeros((1, 2)))
        ).any():
            raise MatchError("mpf: the prior particles lie entirely off the map")
        inv = np.linalg.inv(p0[_P, _P])
        log_weight = -0.5 * np.einsum("mi,ij,mj->m", dev, inv, dev)
        gain = p0[_L, _P] @ inv
        return MpfState(
            dp=dp,
            linear=_times(dev, gain),
            cov=_sym(p0[_L, _L] - gain @ p0[_P, _L]),
            log_weight=log_normalised(log_weight),
            indicated=start,
            step=0,
            model=es,
            dvl=InsErrorState(self.use_dvl).dvl_innovations(problem, es),
            cell=cell,
            spacing=h,
        )

    def predict(self, state: MpfState, motion: Motion, rng: np.random.Generator) -> MpfState:
        """Resample if the ESS is low, then the joint prediction conditioned on the new dp.

        The position part of the prediction covariance gains the random walk
        ``(position_walk_cells * cell)^2 * dt`` per axis (m^2; at least
        :data:`MIN_STEP_VAR`), see the module text.

        Parameters
        ----------
        state : MpfState
            The state after the last update.
        motion : Motion
            The INS motion of the step (displacement, m; duration, s; process variance, m^2).
        rng : numpy.random.Generator
            Random draws of the step.
        """
        if effective_sample_size(state.weights) < self.resample_threshold * state.dp.shape[0]:
            state = self._resample(state, rng)
            width = self.offset_pool_of(state) * state.spacing
            state = pooled_offsets_of(state, state.positions, width)
        if state.offset is not None:
            state = replace(state, offset=state.offset.after(motion))
        if state.field_offsets:
            moved = tuple(None if o is None else o.after(motion) for o in state.field_offsets)
            state = replace(state, field_offsets=moved)
        k = state.step
        model, f, q = step_matrices(
            state.model, k, motion.displacement, motion.dt, motion.process_var
        )
        s = f[:, _L] @ state.cov @ f[:, _L].T + q
        walk = (self.position_walk_cells * state.cell) ** 2 * max(float(motion.dt), 0.0)
        s_pp = s[_P, _P] + max(walk, MIN_STEP_VAR) * np.eye(2)
        mean = _times(state.dp, f[:, _P]) + _times(state.linear, f[:, _L])
        dp = mean[:, _P] + _times(rng.standard_normal(state.dp.shape), np.linalg.cholesky(s_pp))
        gain = np.linalg.solve(s_pp, s[_P, _L]).T
        linear = mean[:, _L] + _times(dp - mean[:, _P], gain)
        return replace(
            state,
            dp=dp,
            linear=linear,
            cov=_sym(s[_L, _L] - gain @ s[_P, _L]),
            indicated=state.indicated + np.asarray(motion.displacement, dtype=float),
            step=k + 1,
            model=model,
        )

    #: The update weighs further fields (``fields``): the sum of their log-likelihoods.
    fuses_fields: ClassVar[bool] = True

    def update(
        self, state: MpfState, obs: Observation, grid: Grid, rng, fields: tuple = ()
    ) -> MpfState:
        """Terrain likelihood of every particle; the DVL's Kalman update when it aids.

        An update so sharp that it would leave fewer than ``min_update_ess`` effective
        particles of a sparse set (its share wider than ``progressive_min_cells`` map
        cells) is applied in stages (progressive correction, Oudjane & Musso 2000): the
        largest fraction of the log-likelihood that keeps that many, then a resample
        whose copies are spread over the share of the particle they copy (its linear
        means following), the likelihood read again at the moved particles, and so on,
        at most ``progressive_stages`` times before the rest is applied at once.

        Parameters
        ----------
        state : MpfState
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
        log_weight = state.log_weight
        state = replace(state, profile=np.asarray(obs.values).size < PROFILE_BEAMS)
        if state.dvl is not None and np.isfinite(state.dvl[obs.index]).all():
            state, log_weight = self._dvl_update(state, state.dvl[obs.index], log_weight)
            state = replace(state, log_weight=log_normalised(log_weight))
        if fields:
            state = replace(state, log_weight=log_normalised(log_weight))
            return self._update_fields(state, obs, grid, rng, fields)
        if not np.isfinite(obs.values).any():
            return replace(state, log_weight=log_normalised(log_weight))
        if self.carries_offset and state.offset is None:
            state = replace(
                state,
                offset=self.started_offset(state.log_weight.shape, obs),
            )
        model = self.likelihood

        def likelihood(current: MpfState) -> np.ndarray:
            return model.particles(
                grid,
                obs,
                current.positions,
                current.spacing,
                current.cell,
                current.offset,
                rng,
            )

        state, reads = self.progressive.apply(state, likelihood, self._spread_copies, rng)
        if state.offset is not None:
            state = replace(state, offset=state.offset.updated(grid, state.positions, obs))
        return shared_offsets(replace(state, evaluations=state.evaluations + reads))

    def _update_fields(self, state: MpfState, obs: Observation, grid: Grid, rng, fields):
        """The primary ping (when it has a value) and every further field's, summed."""
        return update_particle_fields(self, state, obs, grid, rng, fields, _points)

    def _spread_copies(self, state: MpfState, rng) -> MpfState:
        """Resample (same count) and spread each copy over its original's square share."""
        count = state.dp.shape[0]
        index = systematic_resample(state.weights, rng, count)
        joint = np.hstack([state.dp, state.linear])
        _, cov = weighted_moments(joint, state.weights)
        jitter = state.spacing * (rng.random((count, 2)) - 0.5)
        moved = _jittered(joint[index], jitter, cov)
        return replace(
            state,
            dp=moved[:, _P],
            linear=moved[:, _L],
            log_weight=np.full(count, -np.log(count)),
            resamples=state.resamples + 1,
            offset=None if state.offset is None else state.offset.take(index),
            field_offsets=taken_offsets(state.field_offsets, index),
        )

    def mode(self, state: MpfState) -> np.ndarray:
        """The position ``(2,)`` the filter reports as its most likely one: the weighted mean.

        The navigator's MLE of a marginalised set
        (:func:`~geofix.filters.state.mode_position`); the highest-weight particle is
        :meth:`MpfState.mode`.
        """
        return state.moments()[0]

    def estimate(self, state: MpfState) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean ``(2,)`` and covariance ``(2, 2)`` of the positions, m and m^2."""
        return state.moments()

    def is_ambiguous(self, state: MpfState) -> bool:
        """More than ``ambiguity_mass`` of the weight beyond the radius around the mean."""
        mean, _ = self.estimate(state)
        far = np.hypot(*(state.positions - mean).T) > self.ambiguity_radius_cells * state.cell
        return bool(state.weights[far].sum() > self.ambiguity_mass)

    # ------------------------------------------------------------------ helpers
    def _dvl_update(self, state: MpfState, y: np.ndarray, log_weight: np.ndarray):
        assert state.model.velocity_map is not None  # only called with DVL innovations
        c = state.model.velocity_map[:, _L]
        r = state.model.velocity_noise_var * np.eye(2)
        s = c @ state.cov @ c.T + r
        gain = np.linalg.solve(s, c @ state.cov).T
        innovation = y - _times(state.linear, c)
        log_weight = log_weight - 0.5 * np.einsum(
            "mi,ij,mj->m", innovation, np.linalg.inv(s), innovation
        )
        linear = state.linear + _times(innovation, gain)
        cov = _sym(state.cov - gain @ c @ state.cov)
        return replace(state, linear=linear, cov=cov), log_weight

    def _move(self, joint, mean, cov, linear_cov, rng) -> tuple[np.ndarray, np.ndarray]:
        """Liu & West's shrunk kernel move of the resampled ``[dp, m]`` (variance kept).

        The kernel ``N(0, h^2 C)`` is split into its ``dp`` marginal, drawn, and the
        linear states given ``dp``: their regression on the drawn ``dp`` moves the means,
        their conditional covariance ``h^2 (C_ll - C_lp C_pp^-1 C_pl)`` is added to the
        shared Kalman covariance (Rao–Blackwellised, no draw). ``h`` is the bandwidth of
        the whole joint dimension ``d``.

        Returns
        -------
        tuple of numpy.ndarray
            The moved ``(M, d)`` joint vectors and the ``(d_l, d_l)`` Kalman covariance.
        """
        count, dim = joint.shape
        h = kernel_bandwidth(count, dim)
        moved = mean + np.sqrt(1.0 - h * h) * (joint - mean)
        c_pp = _sym(cov[_P, _P])
        values, vectors = np.linalg.eigh(c_pp)
        factor = vectors * np.sqrt(np.clip(values, 0.0, None))
        jitter = h * _times(rng.standard_normal((count, 2)), factor)
        reg = _regression(cov)
        moved[:, _P] += jitter
        moved[:, _L] += _times(jitter, reg)
        conditional = _sym(cov[_L, _L] - reg @ cov[_P, _L])
        values, vectors = np.linalg.eigh(conditional)
        conditional = (vectors * np.clip(values, 0.0, None)) @ vectors.T
        return moved, _sym(linear_cov + h * h * conditional)

    def _resample(self, state: MpfState, rng: np.random.Generator) -> MpfState:
        """Systematic resample to the particle count of the posterior box, then moved."""
        _, pos_cov = self.estimate(state)
        sd = np.sqrt(np.clip(np.linalg.eigvalsh(pos_cov), 0.0, None))
        area = float(np.prod(2.0 * self.extent_sigmas * sd))
        count = self.particle_count(area, state.cell)
        width = 2 + state.linear.shape[1]
        check_allocation(
            cells_bytes(count, width, copies=RESAMPLE_COPIES), f"mpf resample to {count} particles"
        )
        joint = np.hstack([state.dp, state.linear])
        w = state.weights
        mean, cov = weighted_moments(joint, w)
        index = systematic_resample(w, rng, count)
        joint = joint[index]
        linear_cov = state.cov
        spacing = float(np.sqrt(area / count))
        pooled_paths = self.offset_pool_of(state) > 0 and _path_offsets(state)
        if self.regularise and (pooled_paths or not near_gaussian(state.dp, w)):
            joint = _roughen(joint, cov, spacing, rng)
        elif self.regularise:
            joint, linear_cov = self._move(joint, mean, cov, linear_cov, rng)
        dp, linear = joint[:, _P], joint[:, _L]
        return replace(
            state,
            dp=dp,
            linear=linear,
            cov=linear_cov,
            log_weight=np.full(count, -np.log(count)),
            spacing=spacing,
            resamples=state.resamples + 1,
            offset=None if state.offset is None else state.offset.take(index),
            field_offsets=taken_offsets(state.field_offsets, index),
        )


def _path_offsets(state: MpfState) -> bool:
    """The particles carry offsets learnt along their own paths.

    The kernel move would carry a copy about half the set's spread from the path its
    offset was learnt on; jitter within the share keeps it there.
    """
    return state.offset is not None or any(o is not None for o in state.field_offsets)


def _points(state: MpfState) -> np.ndarray:
    """The ``(M, 2)`` positions of a state, metres."""
    return state.positions


#: Range of Mardia's kurtosis of the particle positions within which the set is taken as
#: near-Gaussian (a 2-D Gaussian has 8).
GAUSSIAN_KURTOSIS = (6.5, 12.0)


def near_gaussian(dp: np.ndarray, weights: np.ndarray) -> bool:
    """Whether a weighted 2-D set looks Gaussian enough for a global kernel move.

    Mardia's (1970) multivariate kurtosis ``b = sum_i w_i (d_i^T C^-1 d_i)^2`` (``d_i`` the
    deviations from the weighted mean, ``C`` the weighted covariance) is 8 for a 2-D
    Gaussian; a set split into well separated modes has less (equal modes: about 6), a
    set with a small far mode more (a 4 % mode many sigmas out: over 20). Outside
    :data:`GAUSSIAN_KURTOSIS` the set is not near-Gaussian.

    Parameters
    ----------
    dp : numpy.ndarray
        ``(M, 2)`` positions, metres.
    weights : numpy.ndarray
        ``(M,)`` normalised weights.

    Returns
    -------
    bool
        True when the kurtosis lies in :data:`GAUSSIAN_KURTOSIS`.
    """
    mean, cov = weighted_moments(dp, weights)
    d = dp - mean
    if not np.linalg.det(cov) > 0:
        return False
    mahalanobis = np.einsum("mi,ij,mj->m", d, np.linalg.inv(cov), d)
    kurtosis = float(weights @ mahalanobis**2)
    return GAUSSIAN_KURTOSIS[0] <= kurtosis <= GAUSSIAN_KURTOSIS[1]


def _regression(cov: np.ndarray) -> np.ndarray:
    """``C_lp C_pp^-1`` ``(d_l, 2)``: the linear states' regression on ``dp`` in ``cov``."""
    return np.linalg.lstsq(_sym(cov[_P, _P]), cov[_P, _L], rcond=1e-12)[0].T


def _roughen(joint: np.ndarray, cov: np.ndarray, spacing: float, rng) -> np.ndarray:
    """Jitter ``dp`` within one particle's share (per-axis 1-sigma ``spacing / sqrt(12)``).

    The move of a spread-out, possibly multimodal set: local (a kernel built from the
    set's covariance would throw particles between the modes). The linear means follow
    their regression on the jitter in ``cov``, the set's ``(d, d)`` covariance.
    """
    jitter = spacing / np.sqrt(12.0) * rng.standard_normal((joint.shape[0], 2))
    return _jittered(joint, jitter, cov)


def _jittered(joint: np.ndarray, jitter: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """``joint`` with ``dp`` moved by ``jitter`` ``(M, 2)``, the linear means following.

    The linear means move by their regression on ``dp`` in ``cov`` (the set's ``(d, d)``
    covariance), so a moved particle keeps the linear states its new position implies.
    """
    out = joint.copy()
    out[:, _P] += jitter
    out[:, _L] += _times(jitter, _regression(cov))
    return out


def weighted_moments(rows: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean ``(d,)`` and covariance ``(d, d)`` of ``rows`` ``(M, d)``.

    ``weights`` ``(M,)`` are normalised; the covariance is the weighted second central
    moment (no small-sample correction).
    """
    mean = weights @ rows
    d = rows - mean
    return mean, (d * weights[:, None]).T @ d


def kernel_bandwidth(count: int, dim: int) -> float:
    """Kernel bandwidth ``h = (4 / ((d + 2) M))^(1 / (d + 4))`` of ``M`` points in ``d`` dims.

    The Gaussian-optimal (Silverman) bandwidth, as Musso, Oudjane & Le Gland (2001) use it
    for the regularised particle filter; ``d`` is the whole joint ``[dp, x_l]``.
    """
    return float((4.0 / ((dim + 2.0) * count)) ** (1.0 / (dim + 4.0)))


def _times(rows: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """``rows @ matrix.T`` for ``(M, i)`` rows and a small ``(j, i)`` matrix."""
    return rows @ matrix.T


def _sym(a: np.ndarray) -> np.ndarray:
    return 0.5 * (a + a.T)
