r"""SITAN and the SITAN filter bank (source 002: Zheng, Wang, Bian, Ship Electronic Eng. 2008).

SITAN weighs a problem's primary field only: the further fields of a several-sensor
mission (:attr:`geofix.problem.MatchProblem.fields`) are weighed by PMF, PF and MPF.

SITAN (Sandia inertial terrain-aided navigation) is an extended Kalman filter on the
error state ``X = [dx, dy, dh, dvx, dvy]``:

- ``dx, dy`` -- correction of the INS position, east and north, metres: the estimate is
  ``indicated + [dx, dy]``;
- ``dh`` -- an additive bias of the measured field relative to the map, map units
  (depth-sensor / tide error for bathymetry, gravimeter bias for gravity). The source
  writes the measurement with ``-dh`` because its ``dh`` is the error of the vehicle's
  height; here ``dh`` is *measured minus map*, so its row entry is ``+1``. For a gravity
  map the state is the same bias, in mGal;
- ``dvx, dvy`` -- correction of the INS velocity, m/s.

Motion: ``X(k+1) = Phi X(k) + W(k)`` with ``Phi = [[1,0,0,T,0],[0,1,0,0,T],[0,0,1,0,0],
[0,0,0,1,0],[0,0,0,0,1]]`` (``T`` the step duration) and white ``W``: per-axis position
variance ``Motion.process_var`` (the growth of the INS prior variance over the step),
velocity variance ``velocity_walk^2 T`` and bias variance ``bias_walk^2 T``. The INS
prior's variance growth already holds the drift that the velocity states carry, so the
position noise is only the part of that growth the velocity states do not explain
(:func:`position_process_var`): the drift is not counted twice. ``drift_in_velocity=false``
restores the full growth as position noise, for an INS error known to be a pure position
random walk.

Measurement (stochastic terrain linearisation): one row per valid beam,
``H = [k_x, k_y, 1, 0, 0]`` with the slopes of a least-squares plane fitted to the map
around the beam's footprint at the current estimate over a patch of half-width
``patch_sigmas * sqrt(max eig P_pos)`` (at least one cell; rounded up to a ladder of
``cell * sqrt(2)^j`` so that bank filters share plane fits); innovation ``r = measured -
map(estimate) - dh``; ``R = noise_var + (plane-fit residual variance)`` per beam (the
residual is the linearisation error). Beams whose measurement is NaN or whose patch is
off the map are skipped. The update uses the Joseph form.

The bank (``sitan-bank``) runs ``N x N`` such filters at once (vectorised over filters),
started on a square lattice around the indicated position spanning ``+-span_sigmas``
prior sigmas. Each filter's normalised innovation ``WRS_j = r^T S^-1 r / b`` (``S`` the
innovation covariance from the predicted ``P(k+1/k)``; for one beam ``r^2 / S``, the
source's equation 7) is smoothed ``SWRS_j(k+1) = beta SWRS_j(k) + (1 - beta) WRS_j(k)``,
``SWRS_j(0) = 1`` (equations 8-9); the filter with the lowest SWRS is the estimate. The
source gives no values for ``N``, ``beta`` or the re-initialisation rule; the defaults and
the rule below are documented choices (see :class:`SitanBank`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from geofix.errors import ConfigError, MatchError
from geofix.filters.base import Motion, Observation, RecursiveFilter
from geofix.maps.grid import Grid
from geofix.maps.terrain import plane_stencil
from geofix.measurement import linearise
from geofix.memory import cells_bytes, check_allocation
from geofix.problem import MatchProblem

STATE_SIZE = 5
"""Length of the SITAN error state ``[dx, dy, dh, dvx, dvy]``."""

NO_DATA_WRS = 25.0
"""WRS charged to a bank filter none of whose beams can be linearised (its patches are off
the map) while other filters can: a 5-sigma miss, so an off-map filter is never chosen."""


# ---------------------------------------------------------------------- EKF kernels
def transition(dt: float) -> np.ndarray:
    """The source's state transition ``Phi`` over a step of ``dt`` seconds, ``(5, 5)``."""
    phi = np.eye(STATE_SIZE)
    phi[0, 3] = phi[1, 4] = dt
    return phi


def process_noise(dt: float, position_var: float, velocity_walk: float, bias_walk: float):
    """White process-noise covariance ``Q`` over one step, ``(5, 5)``.

    Parameters
    ----------
    dt : float
        Step duration, seconds.
    position_var : float
        Per-axis position variance gained over the step, m^2.
    velocity_walk : float
        Velocity random walk, m/s per sqrt(s).
    bias_walk : float
        Field-bias random walk, map units per sqrt(s).
    """
    return np.diag(
        [
            position_var,
            position_var,
            bias_walk**2 * dt,
            velocity_walk**2 * dt,
            velocity_walk**2 * dt,
        ]
    )


def ekf_predict(x: np.ndarray, cov: np.ndarray, phi: np.ndarray, q: np.ndarray):
    """Kalman prediction of ``M`` filters at once.

    Parameters
    ----------
    x : numpy.ndarray
        ``(M, 5)`` states.
    cov : numpy.ndarray
        ``(M, 5, 5)`` covariances.
    phi, q : numpy.ndarray
        ``(5, 5)`` transition and process noise.

    Returns
    -------
    tuple of numpy.ndarray
        Predicted ``(x, cov)``.
    """
    return x @ phi.T, phi @ cov @ phi.T + q


@dataclass(frozen=True, eq=False)
class LinearModel:
    """Linearised measurement of ``M`` filters, ``b`` beams each (invalid rows zeroed).

    ``innovation`` ``(M, b)`` measured minus predicted, map units; ``h`` ``(M, b, 5)``
    Jacobian rows; ``r_cov`` ``(M, b, b)`` measurement covariance (identity on invalid
    beams); ``valid`` ``(M, b)``.
    """

    innovation: np.ndarray
    h: np.ndarray
    r_cov: np.ndarray
    valid: np.ndarray


def ekf_update(x: np.ndarray, cov: np.ndarray, model: LinearModel):
    """Kalman update of ``M`` filters at once (Joseph form), with their normalised residuals.

    Parameters
    ----------
    x : numpy.ndarray
        ``(M, 5)`` predicted states.
    cov : numpy.ndarray
        ``(M, 5, 5)`` predicted covariances.
    model : LinearModel
        Innovations, Jacobians and covariances; invalid rows must be zero, with unit
        variance and no correlation.

    Returns
    -------
    x, cov : numpy.ndarray
        Updated states and covariances.
    wrs : numpy.ndarray
        ``(M,)`` ``r^T S^-1 r / b_valid`` (NaN where no beam is valid).
    """
    h, r = model.h, model.innovation
    s = h @ cov @ h.transpose(0, 2, 1) + model.r_cov
    gain = np.linalg.solve(s, h @ cov).transpose(0, 2, 1)  # (M, 5, b); S and P symmetric
    x_new = x + (gain @ r[..., None])[..., 0]
    a = np.eye(STATE_SIZE) - gain @ h
    cov_new = a @ cov @ a.transpose(0, 2, 1) + gain @ model.r_cov @ gain.transpose(0, 2, 1)
    cov_new = 0.5 * (cov_new + cov_new.transpose(0, 2, 1))
    n_valid = model.valid.sum(axis=1)
    chi2 = (r[:, None, :] @ np.linalg.solve(s, r[..., None]))[:, 0, 0]
    wrs = np.where(n_valid > 0, chi2 / np.maximum(n_valid, 1), np.nan)
    return x_new, cov_new, wrs


def position_sigma_max(cov: np.ndarray) -> np.ndarray:
    """Square root of the largest eigenvalue of the position block, metres, ``(M,)``."""
    a, b, d = cov[..., 0, 0], cov[..., 0, 1], cov[..., 1, 1]
    lam = 0.5 * (a + d) + np.sqrt(0.25 * (a - d) ** 2 + b**2)
    return np.sqrt(np.maximum(lam, 0.0))


PATCH_COPIES = 5
"""Float copies per filter, beam and plane-fit point of one linearisation (measured with
tracemalloc: about 4, the lattice's two coordinates, its map reads and their weights)."""


def patch_half_width(cov: np.ndarray, patch_sigmas: float, cell_m: float) -> np.ndarray:
    """Plane-fit half-widths, metres, ``(M,)``.

    ``patch_sigmas`` position sigmas, at least one cell, rounded up to the ladder
    ``cell_m * sqrt(2)^j`` (``j >= 0``).

    Parameters
    ----------
    cov : numpy.ndarray
        ``(M, 2, 2)`` (or ``(2, 2)``) position covariances, m^2.
    patch_sigmas : float
        Half-width of the patch in standard deviations.
    cell_m : float
        Map cell size, metres.
    """
    hw = np.maximum(patch_sigmas * position_sigma_max(cov), cell_m)
    steps = np.ceil(2.0 * np.log2(hw / cell_m) - 1e-9)
    return cell_m * np.sqrt(2.0) ** np.maximum(steps, 0.0)


def linear_model(
    grid: Grid, x: np.ndarray, cov: np.ndarray, obs: Observation, patch_sigmas, fit_corr_scale
):
    """Stochastic terrain linearisation of ``M`` filters around their estimates.

    Parameters
    ----------
    grid : Grid
        The map.
    x, cov : numpy.ndarray
        ``(M, 5)`` states and ``(M, 5, 5)`` covariances (patch size from the latter).
    obs : Observation
        The sample's measurement and geometry.
    patch_sigmas : float
        Patch half-width in position sigmas.
    fit_corr_scale : float
        Correlation length of the linearisation error between beams, in patch half-widths
        (0: independent beams); see :func:`measurement_covariance`.

    Returns
    -------
    model : LinearModel
        Rows for every filter and beam.
    lookups : int
        Map reads spent (plane-fit lattice points and predictions).
    """
    m, b = x.shape[0], obs.offsets.shape[0]
    positions = np.asarray(obs.indicated, dtype=float) + x[:, :2]
    widths = patch_half_width(cov, patch_sigmas, grid.cell_size)
    predicted, slopes = np.full((m, b), np.nan), np.full((m, b, 2), np.nan)
    fit_var = np.ones((m, b))
    lookups = 0
    for hw in np.unique(widths):
        idx = np.flatnonzero(widths == hw)
        points = plane_stencil(grid, float(hw)).shape[0]
        check_allocation(
            cells_bytes(idx.size, b, points, copies=PATCH_COPIES),
            f"terrain linearisation of {idx.size} filters x {b} beams x {points} map points",
        )
        lin = linearise(grid, positions[idx], obs.heading, obs.offsets, float(hw))
        predicted[idx], slopes[idx], fit_var[idx] = lin.predicted, lin.slopes, lin.fit_var
        lookups += idx.size * b * (plane_stencil(grid, float(hw)).shape[0] + 1)
    valid = (
        np.isfinite(np.asarray(obs.values, dtype=float))[None, :]
        & np.isfinite(predicted)
        & np.isfinite(slopes).all(axis=-1)
        & np.isfinite(fit_var)
    )
    h = np.zeros((m, b, STATE_SIZE))
    h[..., 0:2] = np.where(valid[..., None], slopes, 0.0)
    h[..., 2] = valid
    innovation = np.where(valid, obs.values - predicted - x[:, 2:3], 0.0)
    r_cov = measurement_covariance(
        obs, np.where(valid, fit_var, 0.0), fit_corr_scale * widths, valid
    )
    return LinearModel(innovation=innovation, h=h, r_cov=r_cov, valid=valid), lookups


def measurement_covariance(obs: Observation, fit_var, corr_length_m, valid) -> np.ndarray:
    """Measurement covariance of every filter's beams, ``(M, b, b)``.

    White sensor-plus-map noise ``obs.noise_var`` on the diagonal, plus the linearisation
    error (the plane-fit residual variance) correlated between beams ``i, j`` as
    ``exp(-d_ij^2 / (2 L^2))``, ``d_ij`` the distance between their footprints and ``L``
    ``corr_length_m`` (the beams of a swath share most of their patch, so their
    linearisation errors are nearly the same; treating them as independent makes a
    multibeam filter overconfident). Invalid beams get unit variance and no correlation.

    Parameters
    ----------
    obs : Observation
        Beam offsets and the white noise variance, map units^2 (``(b,)`` per beam, or a
        scalar for every beam).
    fit_var : numpy.ndarray
        ``(M, b)`` plane-fit residual variances, map units^2 (0 on invalid beams).
    corr_length_m : numpy.ndarray
        ``(M,)`` correlation length, metres (0: independent beams).
    valid : numpy.ndarray
        ``(M, b)`` usable beams.
    """
    offsets = np.asarray(obs.offsets, dtype=float)
    diag = np.where(valid, obs.noise_var, 1.0)
    if not np.any(corr_length_m):
        return (diag + fit_var)[..., None] * np.eye(offsets.shape[0])
    dist2 = ((offsets[:, None, :] - offsets[None, :, :]) ** 2).sum(axis=-1)
    length2 = np.maximum(np.asarray(corr_length_m, dtype=float), 1e-9)[:, None, None] ** 2
    corr = np.exp(-0.5 * dist2[None] / length2)
    sd = np.sqrt(fit_var)
    r_cov = corr * sd[:, :, None] * sd[:, None, :]
    both = valid[:, :, None] & valid[:, None, :]
    r_cov = np.where(both, r_cov, 0.0)
    return r_cov + diag[..., None] * np.eye(offsets.shape[0])


def initial_covariance(position_sigma: float, bias_sigma: float, velocity_sigma: float):
    """Diagonal prior covariance ``(5, 5)`` from per-state 1-sigmas (m, map units, m/s).

    Parameters
    ----------
    position_sigma : float
        Position 1-sigma, metres.
    bias_sigma : float
        Field bias 1-sigma, map units.
    velocity_sigma : float
        Velocity-error 1-sigma, m/s.
    """
    return np.diag(
        [position_sigma**2, position_sigma**2, bias_sigma**2, velocity_sigma**2, velocity_sigma**2]
    )


def _check_problem(problem: MatchProblem, who: str) -> None:
    if not np.isfinite(np.asarray(problem.measured, dtype=float)).any():
        raise MatchError(f"{who}: no finite measurement in the whole mission")


# ---------------------------------------------------------------------- settings
@dataclass(frozen=True)
class _EkfSettings:
    """Settings shared by :class:`Sitan` and :class:`SitanBank` (see their docstrings)."""

    name: ClassVar[str]

    patch_sigmas: float = 2.0
    fit_corr_scale: float = 0.0
    bias_sigma: float = 1.0
    bias_walk: float = 0.0
    velocity_sigma_m_s: float = 0.05
    velocity_walk: float = 1e-4
    beta: float = 0.95
    consistency_bound: float = 3.0
    drift_in_velocity: bool = True

    def __post_init__(self) -> None:
        if not 0.0 < self.beta < 1.0:
            raise ConfigError(f"{self.name}: beta must lie in (0, 1), got {self.beta}")
        if self.patch_sigmas <= 0:
            raise ConfigError(f"{self.name}: patch_sigmas must be positive")
        if min(self.bias_sigma, self.bias_walk, self.velocity_sigma_m_s, self.velocity_walk) < 0:
            raise ConfigError(f"{self.name}: sigmas and random walks must be >= 0")

    def _prior(self, problem: MatchProblem, position_sigma: float) -> np.ndarray:
        return initial_covariance(
            max(position_sigma, 1e-3), self.bias_sigma, self.velocity_sigma_m_s
        )

    def _predict_arrays(self, x, cov, motion: Motion, elapsed: float):
        position_var = motion.process_var
        if self.drift_in_velocity:
            position_var = position_process_var(
                position_var, elapsed, motion.dt, self.velocity_sigma_m_s, self.velocity_walk
            )
        q = process_noise(motion.dt, position_var, self.velocity_walk, self.bias_walk)
        return ekf_predict(x, cov, transition(motion.dt), q)


#: Smallest per-step position process variance, m^2 (as the motion model's floor).
MIN_POSITION_VAR = 1e-6


def position_process_var(
    prior_growth: float, elapsed: float, dt: float, velocity_sigma: float, velocity_walk: float
) -> float:
    """Per-axis position noise of one step net of the drift the velocity states carry, m^2.

    The velocity-error states (prior ``velocity_sigma`` m/s, random walk ``velocity_walk``
    m/s per sqrt(s)) give the position a variance ``V(t) = velocity_sigma^2 t^2 +
    velocity_walk^2 t^3 / 3`` after ``t`` seconds; the step from ``elapsed`` to ``elapsed
    + dt`` keeps ``prior_growth - (V(elapsed + dt) - V(elapsed))``, at least
    :data:`MIN_POSITION_VAR`.

    Parameters
    ----------
    prior_growth : float
        Position variance the prior gains over the step, m^2.
    elapsed : float
        Seconds since the first sample.
    dt : float
        Duration of the step, s.
    velocity_sigma : float
        Prior 1-sigma of the velocity errors, m/s.
    velocity_walk : float
        Their random walk, m/s per sqrt(s).
    """

    def v(t: float) -> float:
        return velocity_sigma**2 * t * t + velocity_walk**2 * t**3 / 3.0

    explained = v(elapsed + dt) - v(elapsed)
    return max(float(prior_growth) - explained, MIN_POSITION_VAR)


# ---------------------------------------------------------------------- SITAN
@dataclass(frozen=True, eq=False)
class SitanState:
    """One SITAN filter after a step.

    Attributes
    ----------
    indicated : numpy.ndarray
        ``(2,)`` indicated position at the current sample, metres.
    x : numpy.ndarray
        ``(5,)`` error state ``[dx (m), dy (m), dh (map units), dvx (m/s), dvy (m/s)]``.
    cov : numpy.ndarray
        ``(5, 5)`` its covariance.
    swrs : float
        Smoothed normalised innovation (``1`` at the start; about 1 while consistent).
    updates, skipped, evaluations : int
        Samples used, samples with no usable beam, map reads spent.
    cell_m : float
        Map cell size, metres (the unit of the posterior-spread integrity test).
    elapsed : float
        Seconds since the first sample.
    """

    indicated: np.ndarray
    x: np.ndarray
    cov: np.ndarray
    swrs: float = 1.0
    updates: int = 0
    skipped: int = 0
    evaluations: int = 0
    cell_m: float = 0.0
    elapsed: float = 0.0

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Absolute position ``indicated + [dx, dy]`` (m) and its ``(2, 2)`` covariance (m^2)."""
        return self.indicated + self.x[:2], self.cov[:2, :2].copy()

    def mode(self) -> np.ndarray:
        """The Kalman filter's mean position ``(2,)``, metres."""
        return np.asarray(self.indicated + self.x[:2], dtype=float)

    def points(self) -> None:
        """None: a Kalman filter holds no weighted posterior points."""
        return None

    def node_area(self) -> None:
        """None: no posterior points, no cells."""
        return None


@dataclass(frozen=True)
class Sitan(_EkfSettings, RecursiveFilter):
    """SITAN: one extended Kalman filter with stochastic terrain linearisation.

    Parameters
    ----------
    patch_sigmas : float
        Plane-fit half-width in position sigmas (``sqrt`` of the largest eigenvalue of the
        position covariance); at least one cell. 2 covers the 95 % region.
    fit_corr_scale : float
        Correlation length of the linearisation error between beams, in patch half-widths
        (0 treats the beams as independent); see :func:`measurement_covariance`.
    bias_sigma : float
        Prior 1-sigma of the field bias ``dh``, map units (m or mGal); 0 freezes it.
    bias_walk : float
        Random walk of ``dh``, map units per sqrt(s).
    velocity_sigma_m_s : float
        Prior 1-sigma of each velocity-error state, m/s.
    velocity_walk : float
        Random walk of the velocity error, m/s per sqrt(s).
    beta : float
        Smoothing constant of the normalised innovation (the SWRS of the bank).
    consistency_bound : float
        The fix is flagged ambiguous when the smoothed normalised innovation exceeds this
        (about 1 for a consistent filter; 3 means the innovations are ~1.7x too large).
    drift_in_velocity : bool
        The INS prior's variance growth is drift that the velocity states carry: the
        position noise is only what they leave unexplained (see the module text).
    spread_cells, spread_mass : float
        It is also flagged when its Gaussian position posterior puts more than
        ``spread_mass`` of its probability farther than ``spread_cells`` map cells from
        the estimate (:func:`posterior_too_wide`): on flat terrain the filter stays
        consistent (its innovations fit the noise) but cannot localise the vehicle.

    Notes
    -----
    The prior position sigma is ``problem.sigma_position[0]``; its per-step growth is the
    position process noise. The velocity and bias defaults (0.05 m/s, 1 map unit) are
    documented choices, not the source's (it gives none).

    References
    ----------
    .. [1] Hostetler, L. D., & Andreas, R. D. (1983). Nonlinear Kalman filtering
       techniques for terrain-aided navigation. IEEE Transactions on Automatic Control,
       28(3), 315-323.
    .. [2] Zheng, T., Wang, Z., & Bian, S. (2008). SITAN and its parallel-filter
       improvement for underwater terrain navigation. Ship Electronic Engineering, 28(7).

    Examples
    --------
    >>> import geofix
    >>> geofix.Sitan().recursive
    True
    """

    name: ClassVar[str] = "sitan"

    spread_cells: float = 3.0
    spread_mass: float = 0.05

    def initialize(self, problem: MatchProblem, rng: np.random.Generator) -> SitanState:
        """Prior at the first sample: zero correction, covariance from the problem's prior."""
        _check_problem(problem, self.name)
        cov = self._prior(problem, float(problem.sigma_position[0]))
        return SitanState(
            np.asarray(problem.indicated[0], float),
            np.zeros(STATE_SIZE),
            cov,
            cell_m=float(problem.grid.cell_size),
        )

    def predict(self, state: SitanState, motion: Motion, rng: np.random.Generator) -> SitanState:
        """Propagate the error state over one step.

        Parameters
        ----------
        state : SitanState
            The state after the last update.
        motion : Motion
            The INS motion of the step (displacement, m; duration, s; process variance, m^2).
        rng : numpy.random.Generator
            Random draws of the step.
        """
        x, cov = self._predict_arrays(state.x[None], state.cov[None], motion, state.elapsed)
        return replace(
            state,
            indicated=state.indicated + motion.displacement,
            x=x[0],
            cov=cov[0],
            elapsed=state.elapsed + motion.dt,
        )

    def update(self, state: SitanState, obs: Observation, grid: Grid, rng) -> SitanState:
        """Fold in one sample: linearise at the estimate, Kalman update, smooth the WRS.

        Parameters
        ----------
        state : SitanState
            The predicted state.
        obs : Observation
            The ping (beam offsets, m; values and variances, map units).
        grid : Grid
            The prior map.
        rng : numpy.random.Generator
            Random draws of the update.
        """
        state = replace(state, indicated=np.asarray(obs.indicated, dtype=float))
        model, lookups = linear_model(
            grid, state.x[None], state.cov[None], obs, self.patch_sigmas, self.fit_corr_scale
        )
        if not model.valid.any():
            return replace(
                state, skipped=state.skipped + 1, evaluations=state.evaluations + lookups
            )
        x, cov, wrs = ekf_update(state.x[None], state.cov[None], model)
        return replace(
            state,
            x=x[0],
            cov=cov[0],
            swrs=self.beta * state.swrs + (1.0 - self.beta) * float(wrs[0]),
            updates=state.updates + 1,
            evaluations=state.evaluations + lookups,
        )

    def estimate(self, state: SitanState) -> tuple[np.ndarray, np.ndarray]:
        """Absolute position ``indicated + [dx, dy]`` (m) and its ``(2, 2)`` covariance (m^2)."""
        return state.moments()

    def is_ambiguous(self, state: SitanState) -> bool:
        """Whether the fix is unsure.

        True when the smoothed normalised innovation exceeds ``consistency_bound``, or
        the posterior is too wide (:func:`posterior_too_wide`).
        """
        if state.swrs > self.consistency_bound or state.updates == 0:
            return True
        radius = self.spread_cells * state.cell_m
        return posterior_too_wide(state.cov[:2, :2], radius, self.spread_mass)


def posterior_too_wide(position_cov: np.ndarray, radius_m: float, mass: float) -> bool:
    """True when a Gaussian position posterior puts more than ``mass`` beyond ``radius_m``.

    Along the widest axis the share of a 2-D Gaussian beyond ``r`` is at most
    ``exp(-r^2 / (2 lambda_max))`` (exact for a circular posterior), ``lambda_max`` the
    largest eigenvalue of the covariance.

    Parameters
    ----------
    position_cov : numpy.ndarray
        ``(2, 2)`` position covariance, m^2.
    radius_m : float
        Radius, metres (a few map cells: within it the fix counts as right).
    mass : float
        Largest acceptable probability beyond ``radius_m`` (0.05 = 5 %).

    Returns
    -------
    bool
        ``exp(-radius_m^2 / (2 lambda_max)) > mass``.
    """
    lam = float(np.linalg.eigvalsh(np.asarray(position_cov, float))[-1])
    if not np.isfinite(lam):
        return True
    if lam <= 0.0:
        return False
    return bool(np.exp(-(radius_m**2) / (2.0 * lam)) > mass)


# ---------------------------------------------------------------------- the bank
@dataclass(frozen=True, eq=False)
class BankState:
    """A bank of ``M`` SITAN filters after a step.

    Attributes
    ----------
    indicated : numpy.ndarray
        ``(2,)`` indicated position at the current sample, metres.
    x : numpy.ndarray
        ``(M, 5)`` error states (see :class:`SitanState`).
    cov : numpy.ndarray
        ``(M, 5, 5)`` their covariances.
    swrs : numpy.ndarray
        ``(M,)`` smoothed weighted residual squares (1 at each (re-)initialisation).
    side : int
        Filters per side of the current lattice (``M = side^2``).
    spacing : float
        Lattice spacing of the current bank, metres.
    generation : int
        Number of re-initialisations so far.
    since_init : int
        Updates since the last (re-)initialisation.
    final : bool
        True once the bank is at its smallest (no further re-initialisation).
    updates, skipped, evaluations : int
        Samples used, samples with no usable beam, map reads spent.
    elapsed : float
        Seconds since the first sample.
    """

    indicated: np.ndarray
    x: np.ndarray
    cov: np.ndarray
    swrs: np.ndarray
    side: int
    spacing: float
    generation: int = 0
    since_init: int = 0
    final: bool = False
    updates: int = 0
    skipped: int = 0
    evaluations: int = 0
    elapsed: float = 0.0

    @property
    def best(self) -> int:
        """Index of the filter with the lowest SWRS."""
        return int(np.argmin(self.swrs))

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """The best filter's position (m) and ``(2, 2)`` covariance (m^2)."""
        best = self.best
        return self.indicated + self.x[best, :2], self.cov[best, :2, :2].copy()

    def mode(self) -> np.ndarray:
        """The best filter's mean position ``(2,)``, metres."""
        return np.asarray(self.indicated + self.x[self.best, :2], dtype=float)

    def points(self) -> None:
        """None: a Kalman filter holds no weighted posterior points."""
        return None

    def node_area(self) -> None:
        """None: no posterior points, no cells."""
        return None


def lattice_offsets(side: int, spacing: float) -> np.ndarray:
    """``(side^2, 2)`` offsets of a square lattice centred on zero, metres (row-major)."""
    half = 0.5 * (side - 1) * spacing
    ticks = np.linspace(-half, half, side)
    u, v = np.meshgrid(ticks, ticks)
    return np.column_stack([u.ravel(), v.ravel()])


def bank_states(centre: np.ndarray, base_cov: np.ndarray, side: int, spacing: float, pos_var):
    """States and covariances of a new bank around one filter.

    Parameters
    ----------
    centre : numpy.ndarray
        ``(5,)`` state of the centre filter (its bias and velocity are copied to all).
    base_cov : numpy.ndarray
        ``(5, 5)`` covariance whose bias / velocity block every filter inherits.
    side : int
        Filters per side.
    spacing : float
        Lattice spacing, metres.
    pos_var : float
        Per-axis position variance of every filter, m^2 (no position cross-terms).

    Returns
    -------
    x, cov : numpy.ndarray
        ``(side^2, 5)`` and ``(side^2, 5, 5)``.
    """
    x = np.tile(centre, (side * side, 1))
    x[:, :2] += lattice_offsets(side, spacing)
    cov = np.zeros((STATE_SIZE, STATE_SIZE))
    cov[2:, 2:] = base_cov[2:, 2:]
    cov[0, 0] = cov[1, 1] = pos_var
    return x, np.tile(cov, (side * side, 1, 1))


@dataclass(frozen=True)
class SitanBank(_EkfSettings, RecursiveFilter):
    """The parallel SITAN of source 002: N x N filters, SWRS selection, shrinking restarts.

    Every filter is a :class:`Sitan` filter (same settings); the bank is vectorised over
    filters. The estimate is the filter with the lowest SWRS.

    Parameters
    ----------
    side : int
        Largest ``N``, filters per side of the first bank (odd, so one filter sits on the
        indicated position); fewer are used when the spacing would otherwise fall below
        ``min_spacing_cells`` (see :meth:`first_side`). The spacing must stay well below
        the terrain's correlation length, or no filter starts within SITAN's capture
        range: 25 (625 filters) gives 3.1 km on the source-002 scenario (30 km error,
        12 km correlation length), where 11 and 19 diverged in 13-25 % of the trials.
    span_sigmas : float
        The first bank spans ``+-span_sigmas`` prior sigmas (``sigma_position[0]``) on each
        axis: 3 covers the 3-sigma square.
    cell_sigma : float
        Initial position 1-sigma of every filter as a fraction of the spacing: 0.5 makes
        neighbouring filters' 1-sigma regions touch.
    shrink : float
        Factor applied to the spacing and to ``N`` at each re-initialisation (``N`` kept
        odd, at least ``min_side``).
    min_side : int
        Smallest ``N``.
    min_spacing_cells : float
        Smallest spacing, map cells; once the bank has both ``min_side`` and this spacing
        it is final and never re-initialised again.
    settle_steps : int
        Updates a bank must run before it may be re-initialised (10: half the memory
        ``1 / (1 - beta)`` of the SWRS at the default ``beta = 0.95``; re-initialisation
        also waits for a clear best filter, see ``require_clear``).
    converge_ratio : float
        Re-initialise when the best filter's position sigma (largest eigenvalue) is below
        ``converge_ratio`` times the spacing: the best filter has localised the vehicle
        more finely than the bank can.
    ambiguity_ratio : float
        The fix is ambiguous when a filter farther from the best than the spacing (and
        than 3 of the best's sigmas) has an SWRS below ``ambiguity_ratio`` times the best's.
    require_clear : bool
        Re-initialise only when no such rival exists (the source re-centres "once the best
        match is obtained").
    patch_sigmas, fit_corr_scale, bias_sigma, bias_walk, velocity_sigma_m_s, velocity_walk, beta, \
consistency_bound, drift_in_velocity
        As for :class:`Sitan`; ``beta`` is the source's SWRS smoothing constant (the source
        gives no value; 0.95 is a memory of about 20 samples, which halved the divergence
        rate of 0.9 on the source-002 scenario).

    Notes
    -----
    Re-initialisation rule (the source only says "fewer, closer filters as the error
    shrinks"): after ``settle_steps`` updates, if the best filter's position sigma is below
    ``converge_ratio * spacing`` and it has no distant rival, a new bank of
    ``max(min_side, odd(N * shrink))`` filters per side, spacing
    ``max(spacing * shrink, min_spacing_cells * cell)``, is centred on the best filter;
    each inherits its bias and velocity (state and covariance), gets a position sigma
    ``max(cell_sigma * spacing, best sigma)`` and ``SWRS = 1``.

    References
    ----------
    .. [1] Zheng, T., Wang, Z., & Bian, S. (2008). SITAN and its parallel-filter
       improvement for underwater terrain navigation. Ship Electronic Engineering, 28(7).

    Examples
    --------
    >>> import geofix
    >>> geofix.SitanBank().name
    'sitan-bank'
    """

    name: ClassVar[str] = "sitan-bank"

    side: int = 25
    span_sigmas: float = 3.0
    cell_sigma: float = 0.5
    shrink: float = 0.5
    min_side: int = 3
    min_spacing_cells: float = 1.0
    settle_steps: int = 10
    converge_ratio: float = 0.5
    ambiguity_ratio: float = 1.5
    require_clear: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.side < 1 or self.side % 2 == 0 or self.min_side < 1 or self.min_side % 2 == 0:
            raise ConfigError(f"{self.name}: side and min_side must be odd and positive")
        if not 0.0 < self.shrink < 1.0 or self.span_sigmas <= 0 or self.cell_sigma <= 0:
            raise ConfigError(f"{self.name}: need 0 < shrink < 1, span_sigmas, cell_sigma > 0")

    def initialize(self, problem: MatchProblem, rng: np.random.Generator) -> BankState:
        """The first bank of filters.

        Up to ``side x side`` filters spanning ``+-span_sigmas`` prior sigmas (fewer when
        that already makes the spacing ``min_spacing_cells``).
        """
        _check_problem(problem, self.name)
        sigma0 = max(float(problem.sigma_position[0]), 1e-3)
        floor = self.min_spacing_cells * problem.grid.cell_size
        side = self.first_side(sigma0, problem.grid.cell_size)
        spacing = 2.0 * self.span_sigmas * sigma0 / max(side - 1, 1)
        base = self._prior(problem, sigma0)
        x, cov = bank_states(
            np.zeros(STATE_SIZE), base, side, spacing, (self.cell_sigma * spacing) ** 2
        )
        if side == 1:
            cov[:, :2, :2] = base[:2, :2]
        return BankState(
            indicated=np.asarray(problem.indicated[0], dtype=float),
            x=x,
            cov=cov,
            swrs=np.ones(x.shape[0]),
            side=side,
            spacing=spacing,
            final=side <= self.min_side and spacing <= floor * (1 + 1e-9),
        )

    def first_side(self, sigma0: float, cell_m: float) -> int:
        """``N`` of the first bank.

        ``side``, or the smallest odd ``N >= min_side`` whose spacing
        ``2 span_sigmas sigma0 / (N - 1)`` is at most ``min_spacing_cells`` cells.

        Parameters
        ----------
        sigma0 : float
            Prior per-axis position sigma, metres.
        cell_m : float
            Map cell size, metres.
        """
        needed = 1.0 + 2.0 * self.span_sigmas * sigma0 / (self.min_spacing_cells * cell_m)
        odd = 2 * int(np.ceil((needed - 1.0) / 2.0 - 1e-9)) + 1
        return int(min(self.side, max(self.min_side, odd)))

    def predict(self, state: BankState, motion: Motion, rng: np.random.Generator) -> BankState:
        """Propagate every filter over one step.

        Parameters
        ----------
        state : BankState
            The state after the last update.
        motion : Motion
            The INS motion of the step (displacement, m; duration, s; process variance, m^2).
        rng : numpy.random.Generator
            Random draws of the step.
        """
        x, cov = self._predict_arrays(state.x, state.cov, motion, state.elapsed)
        return replace(
            state,
            indicated=state.indicated + motion.displacement,
            x=x,
            cov=cov,
            elapsed=state.elapsed + motion.dt,
        )

    def update(self, state: BankState, obs: Observation, grid: Grid, rng) -> BankState:
        """Update every filter, smooth their WRS, and re-initialise the bank when due.

        Parameters
        ----------
        state : BankState
            The predicted state.
        obs : Observation
            The ping (beam offsets, m; values and variances, map units).
        grid : Grid
            The prior map.
        rng : numpy.random.Generator
            Random draws of the update.
        """
        state = replace(state, indicated=np.asarray(obs.indicated, dtype=float))
        model, lookups = linear_model(
            grid, state.x, state.cov, obs, self.patch_sigmas, self.fit_corr_scale
        )
        evaluations = state.evaluations + lookups
        if not model.valid.any():
            return replace(state, skipped=state.skipped + 1, evaluations=evaluations)
        x, cov, wrs = ekf_update(state.x, state.cov, model)
        wrs = np.where(np.isfinite(wrs), wrs, NO_DATA_WRS)
        state = replace(
            state,
            x=x,
            cov=cov,
            swrs=self.beta * state.swrs + (1.0 - self.beta) * wrs,
            since_init=state.since_init + 1,
            updates=state.updates + 1,
            evaluations=evaluations,
        )
        return self._reinitialise(state, grid) if self._due(state) else state

    def _due(self, state: BankState) -> bool:
        if state.final or state.since_init < self.settle_steps:
            return False
        sigma = position_sigma_max(state.cov[state.best])
        if not sigma < self.converge_ratio * state.spacing:
            return False
        return not (self.require_clear and self._rival(state))

    def _rival(self, state: BankState) -> bool:
        """True when a filter far from the best has an SWRS within ``ambiguity_ratio``."""
        best = state.best
        radius = max(state.spacing, 3.0 * float(position_sigma_max(state.cov[best])))
        far = np.hypot(*(state.x[:, :2] - state.x[best, :2]).T) > radius
        return bool(np.any(far & (state.swrs < self.ambiguity_ratio * state.swrs[best])))

    def _reinitialise(self, state: BankState, grid: Grid) -> BankState:
        best = state.best
        side = max(self.min_side, round(state.side * self.shrink) | 1)
        floor = self.min_spacing_cells * grid.cell_size
        spacing = max(state.spacing * self.shrink, floor)
        sigma_best = float(position_sigma_max(state.cov[best]))
        pos_var = max(self.cell_sigma * spacing, sigma_best) ** 2
        x, cov = bank_states(state.x[best], state.cov[best], side, spacing, pos_var)
        return replace(
            state,
            x=x,
            cov=cov,
            swrs=np.ones(x.shape[0]),
            side=side,
            spacing=spacing,
            generation=state.generation + 1,
            since_init=0,
            final=side <= self.min_side and spacing <= floor * (1 + 1e-9),
        )

    def estimate(self, state: BankState) -> tuple[np.ndarray, np.ndarray]:
        """The best filter's position (m) and ``(2, 2)`` covariance (m^2)."""
        return state.moments()

    def is_ambiguous(self, state: BankState) -> bool:
        """Whether the bank's fix is unsure.

        True if the first bank never re-initialised (not converged; a first bank that is
        already final is exempt), the best filter's SWRS exceeds ``consistency_bound``, or
        a distant filter's SWRS is within ``ambiguity_ratio`` of the best's.
        """
        unsettled = state.generation == 0 and not state.final
        if unsettled or state.swrs[state.best] > self.consistency_bound:
            return True
        return self._rival(state)
