"""The online navigator core: one recursive filter driven one input at a time.

:class:`OnlineFilter` wraps any filter of the per-step protocol of
:mod:`geofix.filters.base` (``initialize`` / ``predict`` / ``update`` / ``estimate``) and
owns everything a navigator adds around it:

- **the two steps** -- :meth:`OnlineFilter.predict` (a :class:`Motion`) and
  :meth:`OnlineFilter.update` (an :class:`Observation`, returns an :class:`Estimate`).
  :func:`geofix.filters.base.run_filter` (every campaign trial) and a replay or a server
  connection (through the raw-input methods :meth:`~OnlineFilter.motion` and
  :meth:`~OnlineFilter.measure`) all call these two, so there is one time step in geofix;
- **input validation** -- times in order, finite positions, a velocity limit between
  navigation records, a ping within ``max_pose_gap_s`` of the pose it is placed with,
  bounded beam counts; a bad input raises :class:`~geofix.errors.InputError` and leaves
  the state untouched;
- **start-up gating** -- the start box (``+-2 sigma``) must lie mostly on valid map data;
- **NIS** -- the normalised innovation squared of every ping, per beam, against the
  predicted measurement spread of the current posterior (unscented sigma points of its
  mean and covariance): ``mean_b r_b^2 / (R_b + S_b)``, about 1 for a consistent filter;
- **gating** -- a ping whose NIS exceeds ``gate_nis`` (after the first accepted ping) is
  rejected as an outlier and not folded in;
- **status** -- ``initialising`` until a ping is accepted, then ``converging``, then
  ``converged`` once the posterior's largest 1-sigma is below ``converge_sigma_m`` and the
  MMSE (mean) and MLE (mode) positions are within ``converge_mle_m`` of each other and
  the posterior is close to a Gaussian: the KL divergence of the grid's or particles'
  posterior to the Gaussian of the same mean and covariance is below
  ``converge_kl_nats`` (the convergence test of MBARI's TRN, Meduna 2011; the estimators
  are those of :mod:`geofix.filters.convergence`; a filter without weighted points, an
  EKF, skips the KL term). A small covariance is only the filter's own claim, so
  ``converged`` also needs the claim to be consistent with the pings
  (:meth:`OnlineFilter.consistency`), judged on the run of the latest accepted pings
  (of the last ``max(nis_window, converge_min_pings)``, since the filter was
  (re)started) that came to a posterior already small and resolved:

  - at least ``converge_min_pings`` such pings (one ping never converges);
  - their mean per-beam NIS within its expected range: at most ``converge_nis_max`` or
    the 99.9 % point of its chi-square (:func:`nis_limit`), at least
    ``converge_nis_min``;
  - the navigation offset (estimate minus navigation) steady within what the filter
    says it learnt: for a consistent Bayesian filter the move ``d`` of its mean since
    ping ``j`` has covariance ``P_j + Q_j I - P_k`` (``Q_j`` the process variance of the
    motions since), so ``d^T (P_j + Q_j I - P_k)^-1 d`` is a chi-square of two degrees
    of freedom (:func:`normalised_move`) and must stay within ``converge_shift_max``. A
    posterior that claims a metre and then walks ten -- a grid collapsed below its node
    spacing, a fix pulled by a map error that the NIS cannot see because the position
    absorbs it -- fails it;
  - the posterior carried by at least ``converge_min_points`` effective nodes or
    particles (a posterior on a handful of grid nodes has the grid's covariance, not the
    data's);
  - the residual scale the innovations put on the declared noise at most
    ``converge_scale_max`` (a map that disagrees with the readings by many times their
    noise cannot vouch for a fix);
  - the fix within ``converge_ins_max`` of the INS fallback below, in the metric of
    their two covariances (a restarted filter locking onto a place its INS prior all
    but rules out is no good fix);

- **lost and re-initialisation** (TRN's rules) -- when the mean NIS over the last
  ``nis_window`` pings exceeds ``nis_limit``, when no ping has been accepted for
  ``outage_s`` (a measurement or bottom-lock outage), or when the posterior grows beyond
  ``max_sigma_factor`` times what the INS alone would give since the filter was
  (re)started (its start sigma grown by the motions' process variance: low information),
  the status is ``lost``;
- **the INS fallback** -- while lost (from the loss until the filter is ``converged``
  again) the reported estimate is the navigation plus the last good offset (estimate
  minus navigation at the last converged ping; none before the first, and none after a
  loss by the NIS window of accepted pings, which says that fix may have been wrong),
  with the last good covariance (the init prior before the first) grown by the process
  variance of every motion since: what the INS alone tells, never the filter's own collapsed
  covariance. With ``reinit`` the filter is re-initialised around that estimate with its
  largest 1-sigma (at least the init sigma), and for ``reinit_grace_pings`` pings after a
  re-initialisation no rule can lose it again (a restarted filter is given the pings it
  needs to settle before it is judged).

All randomness goes through the one generator handed in.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, fields, replace

import numpy as np

from geofix.errors import ConfigError, InputError, MatchError
from geofix.filters.base import Motion, Observation
from geofix.filters.convergence import posterior_kl, posterior_points
from geofix.filters.nuisance import (
    CommonOffset,
    RepresentationShare,
    ResidualScale,
    correlated_share,
    default_offset_std,
    read_at_points,
    representation_std,
    unscented_points,
)
from geofix.maps.grid import Grid
from geofix.measurement import map_error_variance, predict_measurements
from geofix.problem import MatchProblem
from geofix.sensors.attitude import level_offsets
from geofix.sensors.gravimeter import undo_lag_step

STATUSES = ("initialising", "converging", "converged", "lost")


@dataclass(frozen=True)
class NavigatorSettings:
    """Rules of the online navigator (defaults are documented choices).

    Parameters
    ----------
    noise_std : float
        Measurement noise 1-sigma per beam, map units, when a ping brings none.
    process_noise_m2_s : float
        Per-axis variance the navigation error gains per second, m^2/s, when a motion
        brings no ``process_var``.
    gate_nis : float or None
        Reject a ping whose per-beam NIS exceeds this (None: no gating).
    nis_window : int
        Pings in the NIS window (0: no NIS-window rule).
    nis_limit : float
        Lost when the window's mean NIS exceeds this.
    outage_s : float or None
        Lost after this long without an accepted ping, seconds (None: never).
    max_sigma_factor : float or None
        Lost when the posterior's largest 1-sigma exceeds this times the sigma of the INS
        alone since the filter was (re)started: the sigma it was started with, grown by
        the process variance of every motion since (at least one map cell).
    reinit : bool
        Re-initialise when lost (False: only report ``lost``).
    min_beams : int or None
        A ping with fewer valid beams is not used (it counts towards an outage). None
        (default): 1 for a ping of one beam (a single-beam echosounder, a gravimeter),
        3 for a ping of several (a multibeam ping needs three valid beams).
    max_update_beams : int or None
        Use at most this many valid beams of a ping, evenly spread across the swath
        (None: all of them).
    converge_sigma_m : float or None
        Largest posterior 1-sigma for ``converged``, metres (None: 2 map cells).
    converge_mle_m : float or None
        Largest MMSE-to-MLE distance for ``converged``, metres (None: ``max(10 m, 1 cell)``).
    converge_kl_nats : float or None
        Largest KL divergence of the posterior to its moment-matched Gaussian for
        ``converged``, nats (:mod:`geofix.filters.convergence`; None: no KL term). The
        default 0.2 nats passes a Gaussian and refuses two equal modes six standard
        deviations (of one mode) apart (about 0.47 nats).
    min_start_share : float
        Share of a 9 x 9 lattice over the ``+-2 sigma`` start box that must read valid map
        data for :meth:`OnlineFilter.init` (start-up gating).
    max_pose_gap_s : float or None
        Largest time between a ping and the navigation record it is placed with, seconds.
    max_speed_m_s : float or None
        Largest speed implied by two navigation records, m/s.
    max_beams : int
        Most beams a ping may carry.
    interpolation : {"bilinear", "bicubic"}
        The map read of the measurement model (:mod:`geofix.maps.mapread`): bilinear
        (default) or Keys bicubic (smoother, exact for quadratic terrain; same NaN rules).
    depth_bias_std : float or None
        Prior 1-sigma of an unknown offset common to every beam of a ping, measured minus
        map (tide, sound speed, map datum, a gravimeter's offset), map units. 0
        (default): no offset for a filter of ``map_model`` ``exact`` or ``adaptive``, the
        map's default for one of ``imperfect`` (:meth:`for_map_model`); None:
        :func:`geofix.filters.nuisance.default_offset_std` of the map (5 m plus 0.2 % of
        the median depth on a depth map, 5 mGal on a gravity map).
        The offset is a random-walk state ``N(b, P)`` estimated with the position
        (:class:`geofix.filters.nuisance.CommonOffset`): every ping's values are taken
        relative to ``b``, each hypothesis's likelihood is marginalised over ``P`` in
        closed form (:func:`geofix.measurement.common_bias_log_likelihood`), and after
        every accepted ping the state is updated from the residuals at the posterior's
        unscented points; a filter that carries it per hypothesis
        (``offset_per_hypothesis``) starts its own offsets from ``N(0, std^2)``. The
        estimate reports ``b``. Only a grid or particle filter takes it (an EKF such as
        ``sitan`` carries its own field bias).
    depth_bias_walk : float
        Variance the offset gains per second, map units squared per second (default
        1e-3: about 1 m over 15 minutes, a tide's rate).
    representation_error : bool
        Add the prior map's representation error at its own resolution to every beam's
        variance: :func:`geofix.filters.nuisance.representation_std` read at the beam's
        footprint from the current estimate, times the share the innovations support
        (:class:`geofix.filters.nuisance.RepresentationShare`) and the beams per
        independent error across the ping (:func:`geofix.filters.nuisance.correlated_share`).
        Default off; on for a filter whose ``map_model`` is ``adaptive`` or
        ``imperfect`` (:meth:`for_map_model`).
    adaptive_noise : bool
        Estimate a factor on the measurement variance from the innovations
        (:class:`geofix.filters.nuisance.ResidualScale`): a map coarser than
        the seabed or wrong in correlated ways, or a noise declared too small, widens the
        likelihood to the residuals actually seen. The factor is never below 1. Default
        off; on for a filter whose ``map_model`` is ``adaptive`` or ``imperfect``
        (:meth:`for_map_model`).
    noise_forgetting : float
        The residual scale's forgetting factor per ping, in ``(0, 1]`` (0.98: a memory of
        about 50 pings).
    offset_per_hypothesis : bool or None
        With a common offset, whether a filter that can (``pmf``, ``pf``, ``mpf``)
        carries it per hypothesis; None (default): for pings of fewer
        than three beams (a profile), and the navigator's one offset for multibeam pings.
    lag_s : float
        The sensor's first-order lag time constant, seconds (a damped gravimeter's
        datasheet number; 0, the default: none). Each ping's values are compensated
        causally before the update, ``x_k = (y_k - a y_{k-1}) / (1 - a)`` with
        ``a = exp(-(t_k - t_{k-1}) / lag_s)`` and the first ping taken as settled, as a
        campaign's filters do (:func:`geofix.measurement.lag_compensated`); a ping whose
        beam count differs from the one before restarts the compensation.
    converge_min_pings : int
        Accepted pings since the filter was (re)started before it may be ``converged``
        (default 5, at least 2: one ping never converges; with single-beam pings five
        keep the NIS term's false refusals near 1 %).
    converge_nis_max : float or None
        Largest mean per-beam NIS of the accepted pings in the window (the last
        ``max(nis_window, converge_min_pings)`` accepted pings; their NIS weighted by
        their beams) for ``converged``: this, or the 99.9 % point of a chi-square of
        ``N`` degrees of freedom over ``N`` (``N`` the beams of those pings) when that is
        smaller. About 1 for a consistent filter; default 3, where the mean of five
        single-beam NIS lands about 1 % of the time; five 21-beam pings must stay below
        1.48, a residual spread twice the declared one (an unmodelled offset, a wrong
        map) is caught. None: no NIS term.
    converge_nis_min : float or None
        Smallest mean per-beam NIS of the same pings for ``converged`` (default 0.1: a
        declared noise variance ten times what the residuals show, where the NIS can no
        longer tell a wrong posterior from a right one -- the pings are all but ignored
        -- so they cannot vouch for it; five single-beam NIS average below 0.1 about
        1 % of the time). None: no lower bound.
    converge_shift_max : float or None
        Largest normalised move of the navigation offset for ``converged``:
        ``d^T C^-1 d`` with ``d`` the move since an earlier ping ``j`` of the run and
        ``C = P_j + Q_j I - P_k`` what the filter says it learnt since
        (:func:`normalised_move`; module text), for every such ``j``. Default 7.38, the
        97.5 % point of a chi-square of two degrees of freedom: a grid walking back a
        metre a ping to where the map pulls it, with a covariance of a metre, fails it
        (the EX1811 replay: 9.21, the 99 % point, let three such pings through at
        NEES 23-45). None: no shift term.
    converge_ins_max : float or None
        Largest ``d^T (P_f + P)^-1 d`` of the fix against what the INS alone tells for
        ``converged``: ``d`` the estimate minus the INS fallback (:meth:`OnlineFilter.fallback`,
        the navigation plus the last good offset), ``P_f`` the fallback's covariance (the
        last good one grown by the INS since), ``P`` the estimate's. Default 13.8, the
        99.9 % point of a chi-square of two degrees of freedom: a restarted filter that
        locks onto a place its INS prior all but rules out (single-beam depths match
        some contour almost anywhere) is not a good fix, and its offset is not taken.
        None: no such term.
    converge_scale_max : float or None
        Largest residual scale (:attr:`OnlineFilter.noise_factor`, the factor the
        innovations put on the declared noise variance) for ``converged``. Default 25: a
        map whose residuals run five times the declared noise or more cannot vouch for a
        fix, whatever the NIS of the scaled noise says (the scale follows the residuals,
        so the NIS of a wrong fix is as good as a right one's). Measured on a 40-hour
        single-beam ship track against a 10' grid: factors of 100 to 6000 and hundreds of
        ``converged`` pings beyond 3 sigma; on the simulated imperfect maps, at most 5.
        None: no such term.
    converge_min_points : float or None
        Fewest effective points ``1 / sum w_i^2`` (nodes of a grid, particles of a set)
        that must carry the posterior for ``converged`` (default 30: a Gaussian spread
        over about 1.5 node spacings per sigma on a square grid). A posterior on a
        handful of nodes is not resolved: its covariance is the grid's, not the data's.
        Filters without weighted points (an EKF) skip it. None: no such term.
    reinit_grace_pings : int
        Pings after a re-initialisation during which no rule (NIS window, outage,
        information) can lose the filter again (default 8, one NIS window): a restarted
        filter is not re-initialised on every record. 0: none.
    report_status : bool
        Work out the MLE and the convergence status of every estimate (default). False
        (:meth:`passive`, a campaign trial's filter, where nothing reads them): the
        estimate's ``mle`` is its mean and its status stays ``initialising`` /
        ``converging``; the mean and covariance are the same either way.
    mount_offset_m : tuple of float
        The sensor's mounting offset from the navigation reference point, ``(across,
        along)`` or ``(across, along, down)`` metres in the body frame (starboard,
        forward, down), added to every beam's offsets; with a ping's roll and pitch it is
        levelled with the beams first (:mod:`geofix.sensors.attitude`), so a sensor
        mounted below the reference point moves across under a roll.
    """

    noise_std: float = 2.0
    process_noise_m2_s: float = 0.5
    gate_nis: float | None = 25.0
    nis_window: int = 8
    nis_limit: float = 9.0
    outage_s: float | None = 120.0
    max_sigma_factor: float | None = 3.0
    reinit: bool = True
    min_beams: int | None = None
    max_update_beams: int | None = 64
    converge_sigma_m: float | None = None
    converge_mle_m: float | None = None
    converge_kl_nats: float | None = 0.2
    min_start_share: float = 0.2
    max_pose_gap_s: float | None = 5.0
    max_speed_m_s: float | None = 30.0
    max_beams: int = 4096
    interpolation: str = "bilinear"
    depth_bias_std: float | None = 0.0
    depth_bias_walk: float = 1e-3
    representation_error: bool = False
    adaptive_noise: bool = False
    noise_forgetting: float = 0.98
    offset_per_hypothesis: bool | None = None
    lag_s: float = 0.0
    mount_offset_m: tuple[float, ...] = (0.0, 0.0)
    report_status: bool = True
    converge_min_pings: int = 5
    converge_nis_max: float | None = 3.0
    converge_nis_min: float | None = 0.1
    converge_shift_max: float | None = 7.38
    converge_min_points: float | None = 30.0
    converge_ins_max: float | None = 13.8
    converge_scale_max: float | None = 25.0
    reinit_grace_pings: int = 8

    def __post_init__(self) -> None:
        positive = ("noise_std", "nis_limit", "max_beams")
        for name in positive:
            if not getattr(self, name) > 0:
                raise ConfigError(f"navigator: {name} must be positive, got {getattr(self, name)}")
        if self.min_beams is not None and not self.min_beams > 0:
            raise ConfigError(
                f"navigator: min_beams must be positive or None, got {self.min_beams}"
            )
        optional = (
            "gate_nis",
            "outage_s",
            "max_sigma_factor",
            "max_update_beams",
            "converge_sigma_m",
            "converge_mle_m",
            "converge_kl_nats",
            "converge_nis_max",
            "converge_nis_min",
            "converge_shift_max",
            "converge_min_points",
            "converge_ins_max",
            "converge_scale_max",
            "max_pose_gap_s",
            "max_speed_m_s",
        )
        for name in optional:
            value = getattr(self, name)
            if value is not None and not value > 0:
                raise ConfigError(f"navigator: {name} must be positive or None, got {value}")
        if self.nis_window < 0 or self.process_noise_m2_s < 0:
            raise ConfigError("navigator: nis_window and process_noise_m2_s must be >= 0")
        if not (isinstance(self.converge_min_pings, int) and self.converge_min_pings >= 2):
            raise ConfigError(
                "navigator: converge_min_pings must be an integer >= 2 (one ping never "
                f"converges), got {self.converge_min_pings!r}"
            )
        if not (isinstance(self.reinit_grace_pings, int) and self.reinit_grace_pings >= 0):
            raise ConfigError(
                f"navigator: reinit_grace_pings must be an integer >= 0, "
                f"got {self.reinit_grace_pings!r}"
            )
        if self.interpolation not in ("bilinear", "bicubic"):
            raise ConfigError(
                f"navigator: interpolation must be bilinear or bicubic, got {self.interpolation!r}"
            )
        for name in ("depth_bias_std", "depth_bias_walk", "lag_s"):
            value = getattr(self, name)
            if value is None and name == "depth_bias_std":
                continue
            if not (np.isfinite(value) and value >= 0):
                raise ConfigError(f"navigator: {name} must be finite and >= 0, got {value}")
        if not 0.0 < self.noise_forgetting <= 1.0:
            raise ConfigError(
                f"navigator: noise_forgetting must be in (0, 1], got {self.noise_forgetting}"
            )
        if not 0.0 <= self.min_start_share <= 1.0:
            raise ConfigError("navigator: min_start_share must be in [0, 1]")
        mount = np.asarray(self.mount_offset_m, dtype=float)
        if mount.shape not in ((2,), (3,)) or not np.isfinite(mount).all():
            raise ConfigError(
                "navigator: mount_offset_m must be two or three finite numbers "
                "(across, along[, down])"
            )

    @classmethod
    def passive(cls) -> NavigatorSettings:
        """No gating, no re-initialisation, no input limits: a campaign trial's filter.

        Nothing reads a trial's status, so neither it nor the MLE is worked out
        (``report_status=False``; the KL term would cost a binning).
        """
        return cls(
            report_status=False,
            converge_kl_nats=None,
            gate_nis=None,
            nis_window=0,
            outage_s=None,
            max_sigma_factor=None,
            reinit=False,
            min_beams=1,
            min_start_share=0.0,
            max_pose_gap_s=None,
            max_speed_m_s=None,
            max_beams=10**9,
            max_update_beams=None,
        )

    def for_map_model(self, map_model: str) -> NavigatorSettings:
        """These settings for a filter of ``map_model`` ``exact``, ``adaptive`` or ``imperfect``.

        Parameters
        ----------
        map_model : str
            ``exact``: unchanged. ``adaptive``: the representation error and the adaptive
            residual scale switched on. ``imperfect``: those and the common offset (at the
            map's default prior unless ``depth_bias_std`` is set).

        Returns
        -------
        NavigatorSettings
            The settings the navigator runs with.
        """
        if map_model not in ("adaptive", "imperfect"):
            return self
        adaptive = replace(self, representation_error=True, adaptive_noise=True)
        if map_model == "adaptive":
            return adaptive
        std = None if self.depth_bias_std == 0 else self.depth_bias_std
        return replace(adaptive, depth_bias_std=std)

    @classmethod
    def from_dict(cls, values: dict | None) -> NavigatorSettings:
        """Settings from a mapping; unknown keys are a ConfigError naming them."""
        values = dict(values or {})
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ConfigError(
                f"navigator: unknown setting(s) {', '.join(unknown)} (known: {', '.join(known)})"
            )
        return cls(**values)


@dataclass(frozen=True, eq=False)
class Estimate:
    """The navigator's answer after an input.

    Parameters
    ----------
    t : float
        Time of the last input, seconds.
    position : numpy.ndarray
        ``(2,)`` MMSE (posterior mean) position, metres.
    covariance : numpy.ndarray
        ``(2, 2)`` posterior covariance, m^2.
    mle : numpy.ndarray
        ``(2,)`` MLE (posterior mode) position, metres.
    status : str
        One of :data:`STATUSES`.
    nis : float
        Per-beam NIS of the last ping (NaN when not computed).
    accepted : bool
        The last ping was folded in (False: gated out, too few beams, or no ping yet).
    pings, rejected, reinits : int
        Pings seen, pings gated out, re-initialisations so far.
    kl_nats : float
        KL divergence of the posterior to its Gaussian, nats (NaN: not computed -- the
        spread or MLE test failed first -- or a filter without weighted points).
    depth_bias, depth_bias_std : float
        The common-offset state's mean and 1-sigma, map units (measured minus map; NaN
        when ``depth_bias_std`` is 0).
    """

    t: float
    position: np.ndarray
    covariance: np.ndarray
    mle: np.ndarray
    status: str
    nis: float = float("nan")
    accepted: bool = False
    pings: int = 0
    rejected: int = 0
    reinits: int = 0
    kl_nats: float = float("nan")
    depth_bias: float = float("nan")
    depth_bias_std: float = float("nan")

    @property
    def sigma_m(self) -> float:
        """Largest 1-sigma of the covariance, metres."""
        return float(np.sqrt(max(np.linalg.eigvalsh(self.covariance).max(), 0.0)))

    def to_dict(self) -> dict:
        """JSON-ready mapping of the estimate.

        Keys ``t, x, y, cov, status, mle, nis, accepted, pings, rejected, reinits,
        kl_nats, depth_bias`` (``nis``, ``kl_nats``, ``depth_bias`` null when not
        computed).
        """
        return {
            "t": float(self.t),
            "x": float(self.position[0]),
            "y": float(self.position[1]),
            "cov": [[float(v) for v in row] for row in self.covariance],
            "status": self.status,
            "mle": [float(self.mle[0]), float(self.mle[1])],
            "nis": None if not np.isfinite(self.nis) else float(self.nis),
            "accepted": bool(self.accepted),
            "pings": int(self.pings),
            "rejected": int(self.rejected),
            "reinits": int(self.reinits),
            "kl_nats": None if not np.isfinite(self.kl_nats) else float(self.kl_nats),
            "depth_bias": None if not np.isfinite(self.depth_bias) else float(self.depth_bias),
        }


def start_problem(
    grid: Grid, t: float, position, sigma_m: float, heading: float, ins_model=None
) -> MatchProblem:
    """A one-sample :class:`MatchProblem` carrying a prior for ``filter.initialize``.

    ``measured`` holds one placeholder reading of 0 (filters check that a problem has
    some finite reading; :meth:`OnlineFilter.init` never updates with it). An
    ``ins_model`` (:class:`~geofix.nav.errstate.InsErrorModel`) is carried with its
    position prior replaced by the start's: no fixed offset, per-axis ``sigma_m``; its
    velocity, tilt, bias and heading-error prior are kept. A filter on it builds each
    later step from the motion (:func:`geofix.nav.errstate.step_matrices`).
    """
    if ins_model is not None:
        ins_model = replace(ins_model, initial_offset=(0.0, 0.0), initial_std=float(sigma_m))
    return MatchProblem(
        grid=grid,
        indicated=np.asarray(position, dtype=float).reshape(1, 2),
        heading=np.array([float(heading)]),
        offsets=np.zeros((1, 2)),
        measured=np.zeros((1, 1)),
        sigma_position=np.array([float(sigma_m)]),
        times=np.array([float(t)]),
        ins_model=ins_model,
    )


def mode_position(filt, state) -> np.ndarray:
    """MLE position ``(2,)`` of a filter state, metres.

    The filter's own ``mode(state)`` when it has one; else the highest-weight particle
    (states with ``particles`` and ``log_weight``) or node (states with a point-mass
    ``frame`` and ``log_weight``); else the mean.
    """
    mode = getattr(filt, "mode", None)
    if callable(mode):
        return np.asarray(mode(state), dtype=float)
    log_weight = getattr(state, "log_weight", None)
    if log_weight is not None and hasattr(state, "particles"):
        return np.asarray(state.particles[int(np.argmax(log_weight))], dtype=float)
    if log_weight is not None and hasattr(state, "frame"):
        i, j = np.unravel_index(int(np.argmax(log_weight)), log_weight.shape)
        u = np.array([i, j]) - 0.5 * (np.array(log_weight.shape) - 1)
        centre, axes, spacing = state.frame
        return np.asarray(centre + axes @ (u * spacing), dtype=float)
    return np.asarray(filt.estimate(state)[0], dtype=float)


NIS_QUANTILE = 0.999
"""Chi-square point of the ``converged`` NIS term for a run of many beams."""


def nis_limit(cap: float, beams: float, quantile: float = NIS_QUANTILE) -> float:
    """Largest mean per-beam NIS of ``beams`` residuals a consistent filter shows.

    The ``quantile`` point of a chi-square of ``beams`` degrees of freedom over ``beams``
    (the mean of that many squared standard normals), at most ``cap``: 3.0 for five
    single beams at the default cap, 1.48 for 105 beams, 1.26 for 320.

    Parameters
    ----------
    cap : float
        The fixed limit (``converge_nis_max``).
    beams : float
        Beams (degrees of freedom) in the mean.
    quantile : float
        The chi-square point taken.

    Returns
    -------
    float
        The limit (dimensionless).
    """
    from scipy.stats import chi2

    dof = max(float(beams), 1.0)
    return float(min(cap, chi2.ppf(quantile, dof) / dof))


SHIFT_FLOOR = 0.1
"""Share of the predicted covariance a mean may always move by in the shift term."""


def normalised_move(move, predicted, posterior, floor: float = SHIFT_FLOOR) -> float:
    """``d^T C^-1 d`` of a posterior mean's move ``d`` against what the filter learnt.

    For a Bayesian filter the move of its mean between two times, ``d = m_k - m_{k|j}``,
    has covariance ``predicted - posterior`` (``P_{k|j} - P_k``, by the orthogonality of
    the error to the data): a filter that claims to have learnt little in a direction
    should hardly move in it. ``C`` is that difference with its eigenvalues, in the
    metric of ``predicted``, floored at ``floor`` (a grid or particle posterior is not
    exactly Gaussian, and a covariance that grew beyond the prediction would leave none).

    Parameters
    ----------
    move : array_like
        ``(2,)`` the move ``d``, metres.
    predicted : array_like
        ``(2, 2)`` the earlier covariance grown by the process noise since, m^2.
    posterior : array_like
        ``(2, 2)`` the current covariance, m^2.
    floor : float
        Least share of ``predicted`` in ``C`` along any direction.

    Returns
    -------
    float
        ``d^T C^-1 d`` (chi-square of two degrees of freedom for a consistent filter).
    """
    a = np.asarray(predicted, dtype=float)
    a = 0.5 * (a + a.T) + (1e-9 * abs(float(np.trace(a))) + 1e-12) * np.eye(2)
    values, vectors = np.linalg.eigh(a)
    values = np.maximum(values, 1e-12)
    whiten = vectors @ np.diag(values**-0.5) @ vectors.T  # a^(-1/2)
    gained = whiten @ (a - np.asarray(posterior, dtype=float)) @ whiten
    shares, axes = np.linalg.eigh(0.5 * (gained + gained.T))
    z = axes.T @ (whiten @ np.asarray(move, dtype=float))
    return float(np.sum(z**2 / np.maximum(shares, floor)))


def innovation_nis(grid: Grid, mean, cov, obs: Observation) -> float:
    """Per-beam NIS of ``obs`` against the posterior ``N(mean, cov)`` (NaN if no beam).

    The predicted reading and its spread over the posterior come from the five
    unscented sigma points ``mean``, ``mean +- sqrt(3) L_i`` (``L L^T = cov``, weights
    1/3 and 1/6): ``mean_b (y_b - yhat_b)^2 / (R_b + S_b)``. With a common-offset
    variance ``obs.bias_var = P`` the residual's covariance is ``diag(v) + P 1 1^T``
    (``v_b = R_b + S_b``) and the NIS is its quadratic form per beam,
    ``(sum r^2 / v - P T^2 / (1 + P S)) / b`` (``S = sum 1 / v``, ``T = sum r / v``).
    """
    points, weights = unscented_points(mean, cov)
    pred = predict_measurements(grid, points, obs.heading, obs.offsets)
    use = np.isfinite(obs.values) & np.isfinite(pred).all(axis=0)
    if not use.any():
        return float("nan")
    p = pred[:, use]
    yhat = weights @ p
    s = weights @ (p - yhat) ** 2
    r = np.broadcast_to(np.asarray(obs.noise_var, dtype=float), obs.values.shape)[use]
    residual, var = obs.values[use] - yhat, r + s
    with np.errstate(over="ignore", invalid="ignore"):  # a poisoned ping: an infinite NIS
        quad = float(np.sum(residual**2 / var))
        if obs.bias_var > 0:
            t, total = float(np.sum(residual / var)), float(np.sum(1.0 / var))
            quad -= obs.bias_var * t * t / (1.0 + obs.bias_var * total)
    return quad / residual.size


class OnlineFilter:
    """A recursive filter run one input at a time, with a navigator's rules.

    Parameters
    ----------
    filt
        A filter of the per-step protocol (``initialize``, ``predict``, ``update``,
        ``estimate``), e.g. :class:`geofix.filters.pmf.Pmf`.
    grid : Grid
        The map.
    settings : NavigatorSettings, optional
        The navigator's rules (default :class:`NavigatorSettings`).
    rng : numpy.random.Generator or None
        Source of every random draw of the filter (None only for deterministic filters,
        as :func:`~geofix.filters.base.run_filter` allows).
    map_error : Grid, optional
        The map's per-cell standard deviation layer (added as map-error variance to the
        measurement variance at each beam's footprint).
    ins_model : InsErrorModel, optional
        The INS error model (:mod:`geofix.nav.errstate`) of a filter that needs one
        (``mpf``, ``pmf:model=errstate``); see :func:`start_problem` for its prior.
    """

    def __init__(
        self, filt, grid: Grid, settings=None, rng=None, map_error=None, ins_model=None
    ) -> None:
        self.filter = filt
        settings = settings or NavigatorSettings()
        self.settings = settings.for_map_model(getattr(filt, "map_model", "exact"))
        if grid.interpolation != self.settings.interpolation:
            grid = replace(grid, interpolation=self.settings.interpolation)
        self.grid = grid
        self.rng = rng
        self.map_error = map_error
        self.ins_model = ins_model
        self.state = None
        self._nis: deque[float] = deque(maxlen=max(self.settings.nis_window, 1))
        self._pose: tuple[float, np.ndarray, float] | None = None  # (t, position (2,), heading)
        self._t_last: float | None = None
        self._t_accepted = 0.0
        self._prior_sigma = 0.0
        self._pings = self._rejected = self._reinits = self._accepted_count = 0
        self._last: Estimate | None = None
        # the accepted pings since the filter was (re)started, for the consistency of
        # ``converged``: (NIS, beams, offset (2,) m, covariance (2, 2) m^2, process var
        # m^2, whether the ping came to a small and resolved posterior)
        self._window: deque[tuple[float, int, np.ndarray, np.ndarray, float, bool]] = deque(
            maxlen=max(self.settings.nis_window, self.settings.converge_min_pings)
        )
        self._process_var = 0.0  # per-axis process variance of every motion so far, m^2
        self._start_sigma = 0.0  # sigma the filter was (re)started with, metres
        self._start_var = 0.0  # self._process_var at that (re)start
        self._grace = 0  # pings before a rule may lose a re-initialised filter again
        self._lost = False
        self._good_offset = np.zeros(2)  # estimate minus navigation at the last good fix
        self._good_cov = np.zeros((2, 2))  # its covariance (the init prior before one)
        self._good_var = 0.0  # self._process_var at the last good fix
        self._lagged: tuple[float, np.ndarray] | None = None  # the last raw ping (t, values)
        self._representation: Grid | None = None  # the map's representation error, on use
        self._was_converged = False  # the last ping's status was converged
        self._last_ping_at: np.ndarray | None = None  # indicated position of the last ping
        self._reset_bias(0.0)

    def _min_beams(self, obs: Observation) -> int:
        """Valid beams a ping needs: the setting, or 1 for a one-beam ping and 3 otherwise."""
        if self.settings.min_beams is not None:
            return int(self.settings.min_beams)
        return 1 if obs.values.size == 1 else 3

    def _unlagged(self, t: float, values: np.ndarray) -> np.ndarray:
        """A ping's values with the sensor's first-order lag undone (``lag_s``)."""
        lag = float(self.settings.lag_s)
        if lag <= 0:
            return values
        previous = self._lagged
        self._lagged = (t, values.copy())
        if previous is None or previous[1].shape != values.shape or t <= previous[0]:
            return values
        return undo_lag_step(values, previous[1], np.exp(-(t - previous[0]) / lag))

    def _reset_bias(self, t: float) -> None:
        """The nuisance states back at their priors: the offset ``N(0, std^2)``, scale 1.

        The offset is modelled only for a filter with weighted points (a grid or particle
        set; :func:`~geofix.filters.convergence.posterior_points`).
        """
        s = self.settings
        std = s.depth_bias_std
        if std is None:
            std = default_offset_std(self.grid)
        weighted = self.state is not None and posterior_points(self.state) is not None
        self._offset = CommonOffset.prior(std if weighted else 0.0, s.depth_bias_walk, t)
        self._offset_prior_var = self._offset.var
        self._profile_offset: bool | None = None  # offsets per hypothesis (first ping)
        self._scale = ResidualScale.prior(s.noise_forgetting)
        self._share = RepresentationShare.prior(s.noise_forgetting)
        self._ping_variances: tuple[np.ndarray, np.ndarray] | None = None

    def _with_nuisance(self, obs: Observation, t: float) -> tuple[Observation, Observation]:
        """``(relative, weighed)``: the ping relative to the offset, and with the scale too.

        Both carry the map's representation error in their variance.
        """
        self._offset = self._offset.predicted(t)
        if self._profile_offset is None:
            chosen = self.settings.offset_per_hypothesis
            self._profile_offset = obs.values.size < 3 if chosen is None else bool(chosen)
        read = self._with_representation(obs)
        relative = self._offset.relative(read)
        weighed = self._scale.scaled(relative) if self.settings.adaptive_noise else relative
        return relative, weighed

    @property
    def _carries_offset(self) -> bool:
        """The filter carries the offset per hypothesis (its own offset states).

        For pings of fewer than three beams, whose offset and position only a profile of
        several pings separates (decided at the first ping after a reset). A multibeam
        ping's shape tells the position whatever the offset, and an offset per hypothesis
        fitted to each ping lets a shift along a slope trade against it on a map whose
        errors are not one offset (measured on the EX1811 replay: the converged NEES 4 ->
        17-39), so those pings use the navigator's one offset, learnt while converged.
        """
        return (
            bool(getattr(self.filter, "carries_offset", False))
            and self._offset.active
            and bool(self._profile_offset)
        )

    def _for_filter(self, weighed: Observation) -> Observation:
        """The ping as the filter takes it.

        A filter that carries the offset per hypothesis takes the readings as they are,
        with the offset's prior variance and walk (it starts its own offsets from them);
        any other the readings relative to the navigator's offset (``weighed``).
        """
        if not self._carries_offset:
            return weighed
        return replace(
            weighed,
            values=weighed.values + self._offset.mean,
            bias_var=self._offset_prior_var,
            bias_walk=self._offset.walk,
            bias_per_hypothesis=True,
        )

    def _learns_offset(self, obs: Observation) -> bool:
        """Whether a ping's residuals update the offset's mean.

        A ping of fewer than three beams always does: alone it says nothing of the
        position's shape, and the offset is what links it to the next. A ping of several
        beams tells the position by its shape whatever the offset (its likelihood is
        marginalised over the offset's variance); it updates the offset only while the
        navigator reports ``converged`` (at the ping before): learning the offset from it
        while the position is uncertain along a slope lets the two trade against each
        other and the covariance claim what neither has (measured: ``mpf`` on a 10 m
        multibeam map, end error 1.2 -> 3.5 m and NEES 2 -> 21 when every ping updated it).
        Where no status is reported (a campaign trial) such pings never update it: each
        is marginalised over the offset's prior (measured on the ``imperfect_depth``
        scenario, 6 trials: learning it whenever the posterior was within two cells and
        resolved took ``mpf`` from 2.5 m and NEES 2.2 to 3.6 m and NEES 21).
        """
        return int(np.isfinite(obs.values).sum()) < 3 or self._was_converged

    def _with_representation(self, obs: Observation) -> Observation:
        """``obs`` with the map's representation error added to each beam's variance.

        The layer's variance times the share the innovations support so far
        (:class:`~geofix.filters.nuisance.RepresentationShare`).
        """
        self._ping_variances = None
        if not self.settings.representation_error or self.state is None:
            return obs
        if self._representation is None:
            self._representation = representation_std(self.grid)
        mean, _ = self.filter.estimate(self.state)
        extra = map_error_variance(self._representation, mean, obs.heading, obs.offsets)
        if not extra.any():
            return obs
        step = None
        if self._last_ping_at is not None:
            step = float(np.hypot(*(obs.indicated - self._last_ping_at)))
        self._last_ping_at = np.asarray(obs.indicated, dtype=float)
        # the innovations measure each beam's own variance: the share is fitted to the
        # layer as it is, and the beams that share one map error are counted once after
        declared = np.asarray(obs.noise_var, dtype=float)
        self._ping_variances = (declared, extra)
        counted = correlated_share(obs.offsets, self.grid.cell_size, step)
        return replace(obs, noise_var=declared + self._share.value * counted * extra)

    def _gaussian_enough(self, cov: np.ndarray) -> bool:
        """Whether the position prior is narrow enough to measure the residual scale.

        Within two map cells (largest 1-sigma) its five unscented points predict a ping's
        spread, so its innovations measure the scale; a wider, often many-moded prior
        does not.
        """
        sigma = float(np.sqrt(max(float(np.linalg.eigvalsh(cov).max()), 0.0)))
        return sigma <= 2.0 * self.grid.cell_size

    def _nuisance_update(self, relative: Observation, weighed: Observation, prior) -> None:
        """After an accepted ping: the scale from its innovations, the offset from its residuals."""
        if self.settings.adaptive_noise and self._gaussian_enough(prior[1]):
            prior_mean, prior_cov = prior
            reads = read_at_points(self.grid, prior_mean, prior_cov, relative)
            if self._ping_variances is not None:
                declared, extra = self._ping_variances
                self._share = self._share.updated(reads, declared, extra, relative.bias_var)
            self._scale = self._scale.updated(reads, relative.bias_var)
        if not self._offset.active:
            return
        if self._carries_offset:  # the filter's own offsets, summarised for the report
            moments = self.filter.offset_moments(self.state)
            if moments is not None:
                self._offset = replace(self._offset, mean=moments[0], var=moments[1])
            return
        if self._learns_offset(relative):
            mean, cov = self.filter.estimate(self.state)
            reads = read_at_points(self.grid, mean, cov, weighed)
            self._offset = self._offset.updated(reads, weighed.bias_var)

    # ------------------------------------------------------------------ the two steps
    def start(self, problem: MatchProblem) -> None:
        """Initialise from a problem's prior (its first sample), as a campaign trial does."""
        self.state = self.filter.initialize(problem, self.rng)
        t0 = float(problem.times[0])
        self._pose = (t0, np.asarray(problem.indicated[0], float), float(problem.heading[0]))
        self._t_last = self._t_accepted = t0
        self._restart_rules(float(problem.sigma_position[0]))
        self._last = None
        self._reset_bias(t0)

    def predict(self, motion: Motion) -> None:
        """Apply the INS motion of one step to the posterior."""
        self._require_started()
        self.state = self.filter.predict(self.state, motion, self.rng)
        self._process_var += float(motion.process_var)
        self._last = None

    def update(self, obs: Observation, t: float | None = None) -> Estimate:
        """Fold in one ping (gated by its NIS), update the status, re-initialise if lost."""
        pose = self._require_started()
        t = pose[0] if t is None else float(t)
        self._pings += 1
        s = self.settings
        nis = float("nan")
        relative, obs = self._with_nuisance(obs, t)
        accepted = int(np.isfinite(obs.values).sum()) >= self._min_beams(obs)
        prior = self.filter.estimate(self.state) if accepted else None
        judges_nis = s.converge_nis_max is not None or s.converge_nis_min is not None
        wants_nis = s.gate_nis is not None or s.nis_window > 0
        if prior is not None and (wants_nis or (s.report_status and judges_nis)):
            mean, cov = prior
            nis = innovation_nis(self.grid, mean, cov, obs)
            gated = self._accepted_count > 0
            if s.gate_nis is not None and gated and np.isfinite(nis) and nis > s.gate_nis:
                accepted = False
                self._rejected += 1
            if np.isfinite(nis) and s.nis_window > 0:
                self._nis.append(nis)
        # the ping judges the filter's claim when it came to a posterior already small
        # and resolved (the NIS against a wide or unresolved one is no test of the claim)
        judged = (
            accepted
            and s.report_status
            and prior is not None
            and self._small(prior[1])
            and self._resolved()
        )
        if accepted:
            accepted = self._guarded_update(obs)
        if accepted:
            self._accepted_count += 1
            self._t_accepted = t
            self._nuisance_update(relative, obs, prior)
        beams = int(np.isfinite(obs.values).sum())
        estimate = self._describe(t, nis, accepted, judged, beams)
        self._was_converged = estimate.status == "converged"
        if accepted and s.report_status:
            offset = estimate.position - pose[1]
            entry = (nis, beams, offset, estimate.covariance, self._process_var, judged)
            self._window.append(entry)
        self._grace = max(self._grace - 1, 0)
        reason = self._lost_reason(t)
        if reason is not None:
            if reason == "nis" and accepted:  # not an outlier the gate already refused
                self._forget_good_fix()
            estimate = self._lose(estimate, t)  # a ping that loses the filter is no good fix
        elif estimate.status == "converged":
            self._remember_good(estimate, pose[1])
        elif self._lost:
            estimate = self._fallback(estimate)
        self._last = estimate
        return estimate

    # ------------------------------------------------------------------ raw inputs
    def init(self, t: float, position, sigma_m: float, heading: float = 0.0) -> Estimate:
        """Start (or restart) at ``position`` (metres) with a per-axis prior ``sigma_m``.

        Raises
        ------
        InputError
            Non-finite values, a non-positive sigma, or a start box mostly off valid map
            data (start-up gating).
        """
        t, heading = _finite(t, "t"), _finite(heading, "heading")
        position = _point(position, "position")
        sigma_m = _finite(sigma_m, "sigma_m")
        if sigma_m <= 0:
            raise InputError(f"init: sigma_m must be positive, got {sigma_m:g}")
        self._check_start_box(position, sigma_m)
        try:
            state = self.filter.initialize(
                start_problem(self.grid, t, position, sigma_m, heading, self.ins_model), self.rng
            )
        except MatchError as exc:
            raise InputError(f"init: {exc}") from None
        self.state = state
        self._pose = (t, position, heading)
        self._t_last = self._t_accepted = t
        self._restart_rules(sigma_m)
        self._pings = self._rejected = self._reinits = self._accepted_count = 0
        self._last = None
        self._reset_bias(t)
        return self.estimate()

    def motion(self, t: float, position, heading: float, process_var: float | None = None):
        """A navigation record: the INS-indicated position (metres) and heading (radians).

        The posterior moves by the change of the indicated position since the previous
        record; its per-axis variance grows by ``process_var`` (m^2; default
        ``process_noise_m2_s`` times the elapsed time).

        Raises
        ------
        InputError
            Before :meth:`init`, out of time order, non-finite, or faster than
            ``max_speed_m_s``.
        """
        t_prev, pos_prev, _ = self._require_started()
        t, heading = _finite(t, "t"), _finite(heading, "heading")
        position = _point(position, "position")
        dt = t - t_prev
        if dt < 0 or (self._t_last is not None and t < self._t_last):
            raise InputError(f"nav at t = {t:g} s is before the previous input ({self._t_last:g})")
        displacement = position - pos_prev
        step = float(np.hypot(*displacement))
        vmax = self.settings.max_speed_m_s
        if vmax is not None and step > vmax * dt + 1e-6:
            raise InputError(
                f"nav at t = {t:g} s moves {step:.4g} m in {dt:.4g} s (limit {vmax:g} m/s)"
            )
        if process_var is None:
            process_var = max(self.settings.process_noise_m2_s * dt, 1e-6)
        elif not (np.isfinite(process_var) and process_var >= 0):
            raise InputError(f"nav: process_var must be finite and >= 0, got {process_var}")
        self.predict(Motion(displacement, float(dt), float(process_var)))
        self._pose = (t, position, heading)
        self._t_last = t
        if self._grace == 0 and self._outage(t):
            self._last = self._lose(self._describe(t, float("nan"), False), t)
        return self.estimate()

    def measure(self, t: float, beams, noise_var=None, roll=None, pitch=None) -> Estimate:
        """A ping: rows ``(across_m, along_m, value)`` or ``(across_m, along_m, down_m, value)``.

        Values may be NaN (missing beam); offsets must be finite. The ping is placed with
        the last navigation record, which must be within ``max_pose_gap_s``.

        Parameters
        ----------
        t : float
            Ping time, seconds (not before the previous input).
        beams : array_like
            ``(b, 3)``: level-frame across / along footprint offsets (metres, as a sonar
            that corrects for attitude reports them) and measured values (map units);
            ``(b, 4)``: body-frame beam vectors ``(across, along, down)`` from the sensor
            (metres), levelled by ``roll`` and ``pitch``, and the values.
        noise_var : float or array_like, optional
            Measurement variance, map units squared, scalar or ``(b,)``; default
            ``noise_std^2``. The map's per-cell error variance is added to it.
        roll, pitch : float, optional
            Vehicle attitude at the ping, radians (roll positive starboard down, pitch
            positive bow up; :mod:`geofix.conventions`); None is 0 for body-frame beams.
            They level the body-frame beams and the mounting offset.

        Raises
        ------
        InputError
            Before :meth:`init`, out of order, far from the last pose, malformed beams,
            or a roll / pitch not finite or beyond +-90 degrees.
        """
        t_pose, position, heading = self._require_started()
        t = _finite(t, "t")
        if self._t_last is not None and t < self._t_last:
            raise InputError(f"ping at t = {t:g} s is before the previous input ({self._t_last:g})")
        gap = self.settings.max_pose_gap_s
        if gap is not None and abs(t - t_pose) > gap:
            raise InputError(
                f"ping at t = {t:g} s is {abs(t - t_pose):.3g} s from the last nav "
                f"(at most {gap:g} s)"
            )
        beams = self._beams(beams)
        offsets, values = self._level(beams, roll, pitch)
        values = self._unlagged(t, values)
        var = self._noise_var(noise_var, values.shape[0])
        offsets, values, var = self._thin(offsets, values, var)
        if self.map_error is not None:
            mean, _ = self.filter.estimate(self.state)
            var = var + map_error_variance(self.map_error, mean, heading, offsets)
        obs = Observation(values, position, heading, offsets, var, self._pings)
        self._t_last = t
        return self.update(obs, t)

    def estimate(self) -> Estimate:
        """The current estimate (the last one returned, or one of the current state)."""
        t_pose = self._require_started()[0]
        if self._last is None:
            t = self._t_last if self._t_last is not None else t_pose  # both set by init/start
            described = self._describe(t, float("nan"), False)
            self._last = self._fallback(described) if self._lost else described
        return self._last

    def fallback(self) -> tuple[np.ndarray, np.ndarray]:
        """What the INS alone tells since the last good fix: ``(position (2,), cov (2, 2))``.

        The current navigation plus the last good offset (estimate minus navigation at the
        last ``converged`` ping; zero before the first), and the last good covariance
        (the init prior before the first) grown by the process variance of every motion
        since, metres and m^2. It is the estimate reported while ``lost``.

        Raises
        ------
        InputError
            Before :meth:`init`.
        """
        position = self._require_started()[1]
        grown = self._process_var - self._good_var
        return position + self._good_offset, self._good_cov + grown * np.eye(2)

    # ------------------------------------------------------------------ rules
    def _describe(
        self, t: float, nis: float, accepted: bool, judged: bool = False, beams: int = 1
    ) -> Estimate:
        mean, cov = self.filter.estimate(self.state)
        mean, cov = np.asarray(mean, dtype=float), np.asarray(cov, dtype=float)
        report = self.settings.report_status
        mle = mode_position(self.filter, self.state) if report else mean.copy()
        status = "initialising" if self._accepted_count == 0 else "converging"
        kl = float("nan")
        if (
            report
            and status == "converging"
            and self._converged(mean, cov, mle)
            and self.consistency(mean, cov, nis, judged, beams) is None
        ):
            status = "converged"
            if self.settings.converge_kl_nats is not None:
                kl = posterior_kl(self.state)
                if np.isfinite(kl) and kl > self.settings.converge_kl_nats:
                    status = "converging"
        return Estimate(
            t=float(t),
            position=mean,
            covariance=cov,
            mle=mle,
            status=status,
            nis=nis,
            accepted=accepted,
            pings=self._pings,
            rejected=self._rejected,
            reinits=self._reinits,
            kl_nats=kl,
            **self._bias_fields(),
        )

    def _bias_fields(self) -> dict:
        if not self._offset.active:
            return {}
        return {"depth_bias": self._offset.mean, "depth_bias_std": self._offset.std}

    @property
    def noise_factor(self) -> float:
        """The residual scale's factor on the declared measurement variance (1: none)."""
        return self._scale.factor if self.settings.adaptive_noise else 1.0

    def _converged(self, mean, cov, mle) -> bool:
        cell = self.grid.cell_size
        s = self.settings
        mle_max = s.converge_mle_m if s.converge_mle_m is not None else max(10.0, cell)
        return self._small(cov) and float(np.hypot(*(mean - mle))) <= mle_max

    def _small(self, cov) -> bool:
        """The covariance's largest 1-sigma is within ``converge_sigma_m`` (default 2 cells)."""
        s = self.settings
        sigma_max = (
            s.converge_sigma_m if s.converge_sigma_m is not None else 2.0 * self.grid.cell_size
        )
        return bool(np.sqrt(max(float(np.linalg.eigvalsh(cov).max()), 0.0)) <= sigma_max)

    def consistency(
        self, mean, cov, nis: float = float("nan"), judged: bool = False, beams: int = 1
    ) -> str | None:
        """Why the filter's claim is not (yet) consistent with its pings, or None.

        The claim is judged on the run of the latest accepted pings of the window (since
        the filter was (re)started) that came to a posterior already within
        ``converge_sigma_m`` and resolved (``converge_min_points``): the NIS of a ping
        against such a posterior is a sharp test of it, one against a wide prior is not.
        ``"pings"``: that run (with the current ping when it is one of them) is shorter
        than ``converge_min_pings``; ``"nis"``: its mean per-beam NIS (weighted by the
        pings' beams) is above ``converge_nis_max`` (or the chi-square point of its beams,
        :func:`nis_limit`) or below ``converge_nis_min``; ``"shift"``: the navigation
        offset (``mean`` minus the navigation) moved since a ping of the run by more than
        ``converge_shift_max`` in the metric of what the filter says it learnt since
        (:func:`normalised_move`: that ping's covariance grown by the process variance
        since, minus the current covariance); ``"points"``: the posterior is carried by
        fewer than ``converge_min_points`` effective nodes or particles; ``"ins"``: the
        fix lies beyond ``converge_ins_max`` of the INS fallback (its covariance plus the
        fix's); ``"scale"``: the residual scale is beyond ``converge_scale_max``.

        Parameters
        ----------
        mean : array_like
            ``(2,)`` the current posterior mean, metres.
        cov : array_like
            ``(2, 2)`` the current posterior covariance, m^2.
        nis : float
            Per-beam NIS of the current ping (NaN: none).
        judged : bool
            The current ping was folded in and came to a small, resolved posterior (it
            then counts; it is not in the window yet).
        beams : int
            Valid beams of the current ping.

        Returns
        -------
        str or None
            The first failed term, or None when all pass.
        """
        s = self.settings
        run = []
        for entry in reversed(self._window):
            if not entry[-1]:
                break
            run.append(entry)
        if len(run) + int(judged) < s.converge_min_pings:
            return "pings"
        pairs = [(entry[0], entry[1]) for entry in run] + ([(nis, beams)] if judged else [])
        scored = np.array([(v, max(b, 1)) for v, b in pairs if np.isfinite(v)], dtype=float)
        if s.converge_nis_max is not None or s.converge_nis_min is not None:
            if scored.shape[0] < s.converge_min_pings:
                return "nis"
            total = float(scored[:, 1].sum())
            mean_nis = float(scored[:, 0] @ scored[:, 1]) / total
            too_high = s.converge_nis_max is not None and mean_nis > nis_limit(
                s.converge_nis_max, total
            )
            too_low = s.converge_nis_min is not None and mean_nis < s.converge_nis_min
            if too_high or too_low:
                return "nis"
        if s.converge_shift_max is not None:
            offset = np.asarray(mean, dtype=float) - self._require_started()[1]
            for *_, earlier, earlier_cov, var, _ in run:
                predicted = earlier_cov + max(self._process_var - var, 0.0) * np.eye(2)
                if normalised_move(offset - earlier, predicted, cov) > s.converge_shift_max:
                    return "shift"
        if not self._resolved():
            return "points"
        if s.converge_scale_max is not None and self.noise_factor > s.converge_scale_max:
            return "scale"
        if s.converge_ins_max is not None:
            position, spread = self.fallback()
            move = np.asarray(mean, dtype=float) - position
            if normalised_move(move, spread + cov, np.zeros((2, 2)), 0.0) > s.converge_ins_max:
                return "ins"
        return None

    def _resolved(self) -> bool:
        """The posterior is carried by at least ``converge_min_points`` effective points.

        ``1 / sum w_i^2`` over the nodes of a grid or the particles of a set; always True
        for a filter without weighted points (an EKF) or without the setting.
        """
        if self.settings.converge_min_points is None:
            return True
        found = posterior_points(self.state)
        if found is None:
            return True
        weights = found[1] / found[1].sum()
        return 1.0 / float(np.sum(weights**2)) >= self.settings.converge_min_points

    def _lost_reason(self, t: float) -> str | None:
        """Which rule loses the filter now (``nis``, ``outage``, ``information``), or None."""
        s = self.settings
        if self._grace > 0:
            return None
        window = s.nis_window > 0 and len(self._nis) == s.nis_window
        if window and float(np.mean(self._nis)) > s.nis_limit:
            return "nis"
        if self._outage(t):
            return "outage"
        if s.max_sigma_factor is not None:
            cov = self.filter.estimate(self.state)[1]
            sigma = float(np.sqrt(max(np.linalg.eigvalsh(cov).max(), 0.0)))
            if sigma > s.max_sigma_factor * self._ins_sigma():
                return "information"
        return None

    def _ins_sigma(self) -> float:
        """Per-axis sigma of the INS alone since the filter was (re)started, metres.

        The start sigma grown by the process variance of every motion since, at least one
        map cell.
        """
        grown = self._start_sigma**2 + max(self._process_var - self._start_var, 0.0)
        return max(float(np.sqrt(grown)), self.grid.cell_size)

    def _restart_rules(self, sigma_m: float) -> None:
        """Fresh rules after :meth:`init` or :meth:`start`: no loss, no good fix yet."""
        self._prior_sigma = self._start_sigma = float(sigma_m)
        self._process_var = self._start_var = self._good_var = 0.0
        self._good_offset = np.zeros(2)
        self._good_cov = float(sigma_m) ** 2 * np.eye(2)
        self._lost = False
        self._grace = 0
        self._nis.clear()
        self._window.clear()

    def _guarded_update(self, obs: Observation) -> bool:
        """Fold the ping in; a step that leaves a non-finite estimate is refused.

        The state before it is kept and the ping counts as rejected (a reading the input
        checks let through, such as 1e160 on a map of metres, must not poison the
        navigator). Returns whether the ping was folded in.
        """
        before = self.state
        with np.errstate(all="ignore"):
            self.state = self.filter.update(self.state, self._for_filter(obs), self.grid, self.rng)
            mean, cov = self.filter.estimate(self.state)
        if np.isfinite(mean).all() and np.isfinite(cov).all():
            return True
        self.state = before
        self._rejected += 1
        return False

    def _forget_good_fix(self) -> None:
        """The INS alone again: no offset, the init prior grown by every motion since.

        A window of inconsistent pings after a ``converged`` claim says the claim may have
        been wrong; the INS fallback then carries no correction from it. (Measured on a
        40-hour single-beam ship track against a 10' grid: a fallback that kept a wrong
        correction ended 155 km off where the INS alone ended 64 km off.)
        """
        self._good_offset = np.zeros(2)
        self._good_cov = self._prior_sigma**2 * np.eye(2)
        self._good_var = 0.0

    def _remember_good(self, estimate: Estimate, position: np.ndarray) -> None:
        """A converged estimate: the offset and covariance the INS fallback starts from."""
        self._lost = False
        self._good_offset = estimate.position - position
        self._good_cov = np.array(estimate.covariance, dtype=float)
        self._good_var = self._process_var

    def _fallback(self, estimate: Estimate) -> Estimate:
        """``estimate`` with the INS fallback's position and covariance, status ``lost``."""
        position, cov = self.fallback()
        return Estimate(
            **{
                **_fields(estimate),
                "position": position,
                "covariance": cov,
                "mle": position.copy(),
                "status": "lost",
                "kl_nats": float("nan"),
            }
        )

    def _outage(self, t: float) -> bool:
        s = self.settings
        return s.outage_s is not None and t - self._t_accepted > s.outage_s

    def _lose(self, estimate: Estimate, t: float) -> Estimate:
        """Report ``lost`` (the INS fallback); re-initialise the filter around it.

        The restart sigma is the fallback's largest 1-sigma, at least the init sigma.
        """
        self._lost = True
        lost = self._fallback(estimate)
        if not self.settings.reinit:
            return lost
        heading = self._require_started()[2]
        sigma = max(lost.sigma_m, self._prior_sigma)
        try:
            self.state = self.filter.initialize(
                start_problem(self.grid, t, lost.position, sigma, heading, self.ins_model),
                self.rng,
            )
        except MatchError:
            return lost  # the restart box is off the map: keep the old posterior, stay lost
        self._reinits += 1
        self._reset_bias(t)
        self._accepted_count = 0
        self._t_accepted = t
        self._nis.clear()
        self._window.clear()
        self._start_sigma, self._start_var = sigma, self._process_var
        self._grace = self.settings.reinit_grace_pings
        return Estimate(**{**_fields(lost), "reinits": self._reinits})

    # ------------------------------------------------------------------ checks
    def _require_started(self) -> tuple[float, np.ndarray, float]:
        """The last pose ``(t, position (2,), heading)``; InputError before any init."""
        if self.state is None or self._pose is None:
            raise InputError("no init yet: send init (t, x, y, sigma_m) first")
        return self._pose

    def _check_start_box(self, position: np.ndarray, sigma_m: float) -> None:
        share_needed = self.settings.min_start_share
        if share_needed <= 0:
            return
        u = np.linspace(-2.0 * sigma_m, 2.0 * sigma_m, 9)
        gx, gy = np.meshgrid(position[0] + u, position[1] + u)
        share = float(np.isfinite(self.grid.sample(gx, gy)).mean())
        if share < share_needed:
            raise InputError(
                f"init: only {share:.0%} of the +-2 sigma start box around "
                f"({position[0]:.1f}, {position[1]:.1f}) m lies on valid map data "
                f"(need {share_needed:.0%})"
            )

    def _level(self, beams: np.ndarray, roll, pitch) -> tuple[np.ndarray, np.ndarray]:
        """``(offsets (b, 2), values (b,))``: level footprint offsets and the readings."""
        values = beams[:, -1]
        mount = np.asarray(self.settings.mount_offset_m, dtype=float)
        if beams.shape[1] == 3 and roll is None and pitch is None:
            return (beams[:, :2] + mount[:2] if mount.any() else beams[:, :2]), values
        attitude = []
        for name, angle in (("roll", roll), ("pitch", pitch)):
            angle = 0.0 if angle is None else _finite(angle, name)
            if abs(angle) >= 0.5 * np.pi:
                raise InputError(f"ping: {name} must be within +-90 degrees, got {angle:g} rad")
            attitude.append(angle)
        roll_rad, pitch_rad = attitude
        if beams.shape[1] == 4:
            return level_offsets(beams[:, :3], roll_rad, pitch_rad, mount)[:, :2], values
        lever = level_offsets(np.zeros((1, 3)), roll_rad, pitch_rad, mount)[0, :2]
        return beams[:, :2] + lever, values

    def _beams(self, beams) -> np.ndarray:
        try:
            arr = np.asarray(beams, dtype=float)
        except (TypeError, ValueError):
            raise InputError("ping: beams must be a list of [across_m, along_m, value]") from None
        if arr.ndim != 2 or arr.shape[1] not in (3, 4) or arr.shape[0] < 1:
            raise InputError(f"ping: beams must have shape (b, 3) or (b, 4), got {arr.shape}")
        if arr.shape[0] > self.settings.max_beams:
            raise InputError(
                f"ping: {arr.shape[0]} beams, more than max_beams = {self.settings.max_beams}"
            )
        if not np.isfinite(arr[:, :-1]).all() or np.isinf(arr[:, -1]).any():
            raise InputError("ping: beam offsets must be finite and values finite or NaN")
        return arr

    def _noise_var(self, noise_var, beams: int):
        if noise_var is None:
            return self.settings.noise_std**2
        var = np.asarray(noise_var, dtype=float)
        if var.shape not in ((), (beams,)) or not (np.isfinite(var).all() and (var >= 0).all()):
            raise InputError(f"ping: noise_var must be a number or ({beams},) values >= 0")
        return np.maximum(var, 1e-12) if var.ndim else max(float(var), 1e-12)

    def _thin(self, offsets, values, var):
        limit = self.settings.max_update_beams
        valid = np.flatnonzero(np.isfinite(values))
        if limit is None or valid.size <= limit:
            return offsets, values, var
        keep = valid[np.linspace(0, valid.size - 1, limit).round().astype(int)]
        var = var[keep] if np.ndim(var) else var
        return offsets[keep], values[keep], var


def _fields(estimate: Estimate) -> dict:
    return {f.name: getattr(estimate, f.name) for f in fields(estimate)}


def _finite(value, name: str) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {type(value).__name__}") from None
    if not np.isfinite(out):
        raise InputError(f"{name} must be finite, got {out}")
    return out


def _point(value, name: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be two numbers (x, y)") from None
    if arr.shape != (2,) or not np.isfinite(arr).all():
        raise InputError(f"{name} must be two finite numbers (x, y), got {value!r}")
    return arr


__all__ = [
    "STATUSES",
    "Estimate",
    "NavigatorSettings",
    "OnlineFilter",
    "innovation_nis",
    "mode_position",
    "nis_limit",
    "normalised_move",
    "start_problem",
    "unscented_points",
]
