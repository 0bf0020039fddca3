"""The online navigator's settings, its statuses and the constants of its rules.

:class:`NavigatorSettings` holds every rule of :class:`geofix.navigator.Navigator`; its
measurement-model part (map read, common offset, representation error, residual scale,
beams per update) is what the filter loop of the filters layer takes
(:meth:`NavigatorSettings.filter_settings`, :class:`geofix.filters.loop.FilterSettings`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from geofix.errors import ConfigError
from geofix.filters.loop import FilterSettings

STATUSES = ("initialising", "converging", "converged", "lost")
"""The statuses of an estimate, in the order a run passes them."""

NIS_QUANTILE = 0.999
"""Chi-square point of the ``converged`` NIS term for a run of many beams."""

SHIFT_FLOOR = 0.1
"""Share of the predicted covariance a mean may always move by in the shift term."""


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
        data for :meth:`~geofix.navigator.Navigator.init` (start-up gating).
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
        :func:`geofix.maps.offset.default_offset_std` of the map (5 m plus 0.2 % of
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
        independent error across the ping (:func:`geofix.filters.nuisance.correlated_share`),
        and at least the relief the readings show along the track and the map lacks
        (:class:`geofix.filters.nuisance.ProfileRoughness`). Default off; on for a filter
        whose ``map_model`` is ``adaptive`` or ``imperfect`` (:meth:`for_map_model`).
    swath_modes : bool
        Marginalise each multibeam ping over the map error's tilt and curvature across
        its swath, at the variance and persistence the innovations show
        (:class:`geofix.filters.nuisance.SwathModes`; pings of fewer than
        :data:`~geofix.filters.nuisance.MIN_SWATH_BEAMS` beams have none). Default off;
        on for a filter whose ``map_model`` is ``adaptive`` or ``imperfect``.
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
        carries it per hypothesis; None (default): on every ping, as True; False: the
        navigator's one offset, marginalised per ping. A method's own
        ``offset_per_hypothesis`` (``pmf:offset_per_hypothesis=false``) is above this one.
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
        (:func:`~geofix.navigator.health.normalised_move`), for every such ``j``. Default
        7.38, the 97.5 % point of a chi-square of two degrees of freedom: a grid walking
        back a metre a ping to where the map pulls it, with a covariance of a metre,
        fails it. None: no shift term.
    converge_ins_max : float or None
        Largest ``d^T (P_f + P)^-1 d`` of the fix against what the INS alone tells for
        ``converged``: ``d`` the estimate minus the INS fallback
        (:meth:`~geofix.navigator.Navigator.fallback`, the navigation plus the last good
        offset), ``P_f`` the fallback's covariance (the
        last good one grown by the INS since), ``P`` the estimate's. Default 13.8, the
        99.9 % point of a chi-square of two degrees of freedom: a restarted filter that
        locks onto a place its INS prior all but rules out (single-beam depths match
        some contour almost anywhere) is not a good fix, and its offset is not taken.
        None: no such term.
    converge_scale_max : float or None
        Largest residual scale (:attr:`~geofix.navigator.Navigator.noise_factor`, the
        factor the innovations put on the declared noise variance) for ``converged``.
        Default 25: a map whose residuals run five times the declared noise or more
        cannot vouch for a fix, whatever the NIS of the scaled noise says (the scale
        follows the residuals, so the NIS of a wrong fix is as good as a right one's).
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
    swath_modes: bool = False
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
        (``report_status=False``; the KL term would cost a binning). A campaign trial
        runs the plain filter loop (:class:`geofix.filters.loop.FilterStepper`), which
        steps exactly what a navigator with these settings steps.
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

        The rule of :meth:`geofix.filters.loop.FilterSettings.for_map_model`.

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
        model = self.filter_settings().for_map_model(map_model)
        return replace(self, **{name: getattr(model, name) for name in _FILTER_FIELDS})

    def filter_settings(self) -> FilterSettings:
        """The measurement-model part, as the filter loop takes it."""
        return FilterSettings(**{name: getattr(self, name) for name in _FILTER_FIELDS})

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


_FILTER_FIELDS = tuple(f.name for f in fields(FilterSettings))


__all__ = ["NIS_QUANTILE", "SHIFT_FLOOR", "STATUSES", "NavigatorSettings"]
