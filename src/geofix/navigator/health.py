"""The navigator's health rules: NIS, the consistency of ``converged``, lost, INS fallback.

- **NIS** -- the normalised innovation squared of every ping, per beam, against the
  predicted measurement spread of the current posterior (unscented sigma points of its
  mean and covariance): ``mean_b r_b^2 / (R_b + S_b)``, about 1 for a consistent filter
  (:func:`innovation_nis`).
- **converged** -- the posterior's largest 1-sigma below ``converge_sigma_m``, the MMSE
  (mean) and MLE (mode) positions within ``converge_mle_m`` (:meth:`Health.converged`),
  and the filter's claim consistent with its pings (:meth:`Health.consistency`), judged on
  the run of the latest accepted pings (of the last ``max(nis_window,
  converge_min_pings)``, since the filter was (re)started) that came to a posterior
  already small and resolved:

  - at least ``converge_min_pings`` such pings (one ping never converges);
  - their mean per-beam NIS within its expected range: at most ``converge_nis_max`` or
    the 99.9 % point of its chi-square (:func:`nis_limit`), at least
    ``converge_nis_min``;
  - the navigation offset (estimate minus navigation) steady within what the filter
    says it learnt: for a consistent Bayesian filter the move ``d`` of its mean since
    ping ``j`` has covariance ``P_j + Q_j I - P_k`` (``Q_j`` the process variance of the
    motions since), so ``d^T (P_j + Q_j I - P_k)^-1 d`` is a chi-square of two degrees
    of freedom (:func:`normalised_move`) and must stay within ``converge_shift_max``;
  - the posterior carried by at least ``converge_min_points`` effective nodes or
    particles;
  - the residual scale the innovations put on the declared noise at most
    ``converge_scale_max``;
  - the fix within ``converge_ins_max`` of the INS fallback, in the metric of their two
    covariances.

- **lost** (TRN's rules, :meth:`Health.lost_reason`) -- the mean NIS over the last
  ``nis_window`` pings above ``nis_limit``, no accepted ping for ``outage_s``, or a
  posterior grown beyond ``max_sigma_factor`` times what the INS alone would give since
  the filter was (re)started; for ``reinit_grace_pings`` pings after a
  re-initialisation no rule can lose it again.
- **the INS fallback** (:meth:`Health.fallback`) -- the navigation plus the last good
  offset (estimate minus navigation at the last converged ping), with the last good
  covariance (the init prior before the first) grown by the process variance of every
  motion since. A loss by the NIS window drops the good fixes made while the window
  filled (:meth:`Health.forget_good_fix`): the fallback goes back to the last one before.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import numpy as np

from geofix.filters.base import Observation
from geofix.filters.convergence import posterior_points
from geofix.filters.nuisance import unscented_points
from geofix.maps.grid import Grid
from geofix.measurement import predict_measurements
from geofix.navigator.settings import NIS_QUANTILE, SHIFT_FLOOR, NavigatorSettings


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
    ``(sum r^2 / v - P T^2 / (1 + P S)) / b`` (``S = sum 1 / v``, ``T = sum r / v``);
    with the swath's map-error shapes ``obs.map_modes`` (``Z``) the covariance is
    ``diag(v) + P 1 1^T + Z Z^T``, its quadratic form by Woodbury's identity.

    Parameters
    ----------
    grid : Grid
        The map.
    mean : array_like
        ``(2,)`` posterior mean, metres.
    cov : array_like
        ``(2, 2)`` posterior covariance, m^2.
    obs : Observation
        The ping (values in map units, variances in map units squared).

    Returns
    -------
    float
        The per-beam NIS (dimensionless).
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
        columns = [] if obs.map_modes is None else [np.asarray(obs.map_modes)[use]]
        if obs.bias_var > 0:
            columns.insert(0, np.full((residual.size, 1), np.sqrt(obs.bias_var)))
        if columns:  # Woodbury: r^T (V + Z Z^T)^-1 r
            z = np.concatenate(columns, axis=1)
            u = z.T @ (residual / var)
            inner = np.eye(z.shape[1]) + (z / var[:, None]).T @ z
            quad -= float(u @ np.linalg.solve(inner, u))
    return quad / residual.size


class Health:
    """The rules' memory of one navigator: NIS window, accepted pings, the last good fix.

    Parameters
    ----------
    settings : NavigatorSettings
        The navigator's rules.
    grid : Grid
        The map (its cell size sets the default spread limits).
    """

    def __init__(self, settings: NavigatorSettings, grid: Grid) -> None:
        self.settings = settings
        self.grid = grid
        self.nis: deque[float] = deque(maxlen=max(settings.nis_window, 1))
        # the accepted pings since the filter was (re)started, for the consistency of
        # ``converged``: (NIS, beams, offset (2,) m, covariance (2, 2) m^2, process var
        # m^2, whether the ping came to a small and resolved posterior)
        self.window: deque[tuple[float, int, np.ndarray, np.ndarray, float, bool]] = deque(
            maxlen=max(settings.nis_window, settings.converge_min_pings)
        )
        self.process_var = 0.0  # per-axis process variance of every motion so far, m^2
        self.prior_sigma = 0.0  # the init sigma, metres
        self.start_sigma = 0.0  # sigma the filter was (re)started with, metres
        self.start_var = 0.0  # self.process_var at that (re)start
        self.grace = 0  # pings before a rule may lose a re-initialised filter again
        self.lost = False
        self.good_offset = np.zeros(2)  # estimate minus navigation at the last good fix
        self.good_cov = np.zeros((2, 2))  # its covariance (the init prior before one)
        self.good_var = 0.0  # self.process_var at the last good fix
        self.nis_count = 0  # NIS values taken into the window since the start
        # the good fixes remembered while the latest NIS window filled and the last one
        # before it: (nis_count when remembered, offset (2,) m, covariance (2, 2) m^2,
        # process var m^2); at most a few windows' worth of pings without a NIS
        self.good_fixes: deque[tuple[int, np.ndarray, np.ndarray, float]] = deque(
            maxlen=4 * max(settings.nis_window, 1) + 1
        )

    # ------------------------------------------------------------------ restarts
    def restart(self, sigma_m: float) -> None:
        """Fresh rules after an init or a start: no loss, no good fix yet (sigma, metres)."""
        self.prior_sigma = self.start_sigma = float(sigma_m)
        self.process_var = self.start_var = self.good_var = 0.0
        self.good_offset = np.zeros(2)
        self.good_cov = float(sigma_m) ** 2 * np.eye(2)
        self.good_fixes.clear()
        self.lost = False
        self.grace = 0
        self.nis.clear()
        self.window.clear()

    def reinitialised(self, sigma_m: float) -> None:
        """The filter was re-initialised with ``sigma_m`` (metres): a fresh run, a grace."""
        self.nis.clear()
        self.window.clear()
        self.start_sigma, self.start_var = sigma_m, self.process_var
        self.grace = self.settings.reinit_grace_pings

    def moved(self, process_var: float) -> None:
        """A motion added ``process_var`` (m^2 per axis) to the INS error."""
        self.process_var += float(process_var)

    def add_nis(self, nis: float) -> None:
        """A ping's NIS into the window of the NIS rule."""
        self.nis.append(float(nis))
        self.nis_count += 1

    def pinged(self) -> None:
        """One ping less of grace."""
        self.grace = max(self.grace - 1, 0)

    # ------------------------------------------------------------------ converged
    def converged(self, mean, cov, mle) -> bool:
        """Small (:meth:`small`) and the mean within ``converge_mle_m`` of the MLE.

        Parameters
        ----------
        mean : numpy.ndarray
            ``(2,)`` posterior mean, metres.
        cov : numpy.ndarray
            ``(2, 2)`` posterior covariance, m^2.
        mle : numpy.ndarray
            ``(2,)`` posterior mode, metres.

        Returns
        -------
        bool
            The posterior's spread and mean-to-mode distance pass.
        """
        cell = self.grid.cell_size
        s = self.settings
        mle_max = s.converge_mle_m if s.converge_mle_m is not None else max(10.0, cell)
        return self.small(cov) and float(np.hypot(*(mean - mle))) <= mle_max

    def small(self, cov) -> bool:
        """The covariance's largest 1-sigma is within ``converge_sigma_m`` (default 2 cells)."""
        s = self.settings
        sigma_max = (
            s.converge_sigma_m if s.converge_sigma_m is not None else 2.0 * self.grid.cell_size
        )
        return bool(np.sqrt(max(float(np.linalg.eigvalsh(cov).max()), 0.0)) <= sigma_max)

    def consistency(
        self,
        mean,
        cov,
        navigation,
        state,
        noise_factor: float,
        nis: float = float("nan"),
        judged: bool = False,
        beams: int = 1,
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
        navigation : numpy.ndarray
            ``(2,)`` the current navigation (INS) position, metres.
        state
            The filter's state (its weighted points, for the ``points`` term).
        noise_factor : float
            The residual scale's factor on the declared noise (1: none).
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
        for entry in reversed(self.window):
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
            offset = np.asarray(mean, dtype=float) - navigation
            for *_, earlier, earlier_cov, var, _ in run:
                predicted = earlier_cov + max(self.process_var - var, 0.0) * np.eye(2)
                if normalised_move(offset - earlier, predicted, cov) > s.converge_shift_max:
                    return "shift"
        if not self.resolved(state):
            return "points"
        if s.converge_scale_max is not None and noise_factor > s.converge_scale_max:
            return "scale"
        if s.converge_ins_max is not None:
            position, spread = self.fallback(navigation)
            move = np.asarray(mean, dtype=float) - position
            if normalised_move(move, spread + cov, np.zeros((2, 2)), 0.0) > s.converge_ins_max:
                return "ins"
        return None

    def resolved(self, state) -> bool:
        """The posterior is carried by at least ``converge_min_points`` effective points.

        ``1 / sum w_i^2`` over the nodes of a grid or the particles of a set; always True
        for a filter without weighted points (an EKF) or without the setting.
        """
        if self.settings.converge_min_points is None:
            return True
        found = posterior_points(state)
        if found is None:
            return True
        weights = found[1] / found[1].sum()
        return 1.0 / float(np.sum(weights**2)) >= self.settings.converge_min_points

    # ------------------------------------------------------------------ lost
    def lost_reason(
        self, t: float, t_accepted: float, covariance: Callable[[], np.ndarray]
    ) -> str | None:
        """Which rule loses the filter now (``nis``, ``outage``, ``information``), or None.

        Parameters
        ----------
        t : float
            Now, seconds.
        t_accepted : float
            Time of the last accepted ping, seconds.
        covariance : callable
            Returns the posterior's ``(2, 2)`` covariance, m^2 (asked only when needed).

        Returns
        -------
        str or None
            The rule, or None while none loses the filter.
        """
        s = self.settings
        if self.grace > 0:
            return None
        window = s.nis_window > 0 and len(self.nis) == s.nis_window
        if window and float(np.mean(self.nis)) > s.nis_limit:
            return "nis"
        if self.outage(t, t_accepted):
            return "outage"
        if s.max_sigma_factor is not None:
            cov = covariance()
            sigma = float(np.sqrt(max(np.linalg.eigvalsh(cov).max(), 0.0)))
            if sigma > s.max_sigma_factor * self.ins_sigma():
                return "information"
        return None

    def outage(self, t: float, t_accepted: float) -> bool:
        """No ping accepted for longer than ``outage_s`` (times in seconds)."""
        s = self.settings
        return s.outage_s is not None and t - t_accepted > s.outage_s

    def ins_sigma(self) -> float:
        """Per-axis sigma of the INS alone since the filter was (re)started, metres.

        The start sigma grown by the process variance of every motion since, at least one
        map cell.
        """
        grown = self.start_sigma**2 + max(self.process_var - self.start_var, 0.0)
        return max(float(np.sqrt(grown)), self.grid.cell_size)

    # ------------------------------------------------------------------ the INS fallback
    def fallback(self, navigation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(position (2,), cov (2, 2))``: what the INS alone tells since the last good fix.

        ``navigation`` (metres) plus the last good offset, and the last good covariance
        grown by the process variance of every motion since (m^2).
        """
        grown = self.process_var - self.good_var
        return navigation + self.good_offset, self.good_cov + grown * np.eye(2)

    def forget_good_fix(self) -> None:
        """Drop the good fixes the window of inconsistent pings speaks against.

        A window of inconsistent pings after a ``converged`` claim says the claims made
        while it filled may have been wrong: the INS fallback goes back to the last good
        fix remembered before the window's first ping, and to the INS alone (the init
        prior grown by every motion since) when there is none.
        """
        first = self.nis_count - len(self.nis)  # NIS values before the window's first
        before = [fix for fix in self.good_fixes if fix[0] <= first]
        self.good_fixes.clear()
        if before:
            _, self.good_offset, self.good_cov, self.good_var = before[-1]
            self.good_fixes.append(before[-1])
            return
        self.good_offset = np.zeros(2)
        self.good_cov = self.prior_sigma**2 * np.eye(2)
        self.good_var = 0.0

    def remember_good(self, position: np.ndarray, cov: np.ndarray, navigation) -> None:
        """A converged estimate at ``navigation``: the INS fallback's new start.

        Parameters
        ----------
        position : numpy.ndarray
            ``(2,)`` the estimate, metres.
        cov : numpy.ndarray
            ``(2, 2)`` its covariance, m^2.
        navigation : numpy.ndarray
            ``(2,)`` the navigation (INS) position at the ping, metres.
        """
        self.lost = False
        self.good_offset = position - navigation
        self.good_cov = np.array(cov, dtype=float)
        self.good_var = self.process_var
        fix = (self.nis_count, self.good_offset, self.good_cov, self.good_var)
        self.good_fixes.append(fix)
        first = self.nis_count - self.settings.nis_window  # where a full window starts
        while len(self.good_fixes) > 1 and self.good_fixes[1][0] <= first:
            self.good_fixes.popleft()  # superseded by a later fix before the window


__all__ = ["Health", "innovation_nis", "nis_limit", "normalised_move"]
