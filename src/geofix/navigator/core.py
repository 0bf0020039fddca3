"""``geofix.Navigator``: an online terrain-aided navigator around any recursive filter.

Usage (``grid`` a :class:`~geofix.maps.grid.Grid`; positions in metres, headings in
radians)::

    nav = Navigator(grid, method="pmf", settings={"noise_std": 2.0}, seed=1)
    nav.init(t=0.0, position=(x0, y0), sigma_m=500.0)
    nav.motion(t, position=(x, y), heading=psi)       # the INS pose
    est = nav.measure(t, beams)                       # (b, 3) across_m, along_m, value
    est.position, est.covariance, est.mle, est.status, est.nis

**Several fields.** A vehicle with a gravimeter (or a magnetometer) beside its
echosounder gives the navigator the further fields' maps, ``field_grids`` (the
``grid`` is the primary field's), and each ping the further fields' readings,
``measure(..., fields=[{"kind": "gravity", "beams": [[0, 0, 12.5]], "noise_var": 1.0}])``.
The filter folds every field of a ping in one update (the product of the fields'
likelihoods, :class:`geofix.filters.loop.FilterStepper`), each field with its own
common offset, residual scale and representation share; a field missing from a ping is
not weighed at it. The NIS of the gate and of the health rules is the primary field's
alone (NaN for a ping with no valid primary beam). Only a filter that weighs several
fields (``pmf``, ``pf``, ``mpf``) takes ``field_grids``; without them every number is
the one-field navigator's.

The method is any registered recursive filter by name or spec (``"pmf"``, ``"pf"``,
``"sitan"``, ``"pmf:points=41"``, and every filter added to the registry later on the
same per-step protocol). The filters on the INS error state (``"mpf"``,
``"pmf:model=errstate"``) also need the INS error model, ``ins_model`` (an
:class:`~geofix.nav.errstate.InsErrorModel`, e.g. ``InsErrorModel.from_specs(spec)`` of
a scenario's ``ins:`` block); its position prior is replaced by ``init``'s sigma.

The navigator drives the filter loop of the filters layer
(:class:`geofix.filters.loop.FilterStepper`: the filter, its state and the measurement
model's nuisance states, as every campaign trial runs it) and adds around it:

- **the two steps** -- :meth:`Navigator.predict` (a :class:`~geofix.filters.base.Motion`)
  and :meth:`Navigator.update` (an :class:`~geofix.filters.base.Observation`, returns an
  :class:`~geofix.navigator.estimate.Estimate`); a replay or a server connection calls
  them through the raw-input methods :meth:`~Navigator.motion` and
  :meth:`~Navigator.measure`, whose inputs are checked first
  (:mod:`geofix.navigator.intake`);
- **gating** -- a ping whose per-beam NIS exceeds ``gate_nis`` (after the first accepted
  ping) is rejected as an outlier and not folded in;
- **status** -- ``initialising`` until a ping is accepted, then ``converging``, then
  ``converged`` once the posterior is small, its mean and mode agree, it is close to a
  Gaussian (the KL divergence of the grid's or particles' posterior to the Gaussian of
  the same mean and covariance below ``converge_kl_nats``, the convergence test of
  MBARI's TRN, Meduna 2011; :mod:`geofix.filters.convergence`) and the filter's claim is
  consistent with its pings (:meth:`Navigator.consistency`,
  :mod:`geofix.navigator.health`);
- **lost and re-initialisation** (TRN's rules, :mod:`geofix.navigator.health`) -- while
  lost (from the loss until the filter is ``converged`` again) the reported estimate is
  the INS fallback (:meth:`Navigator.fallback`), the navigation plus the last good offset
  with the covariance grown since; with ``reinit`` the filter is re-initialised around
  it with its largest 1-sigma (at least the init sigma);
- **the common offset** -- learnt from multibeam pings only while converged
  (:mod:`geofix.navigator.offset`).

All randomness goes through the one generator of the seed.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from geofix.errors import ConfigError, InputError, MatchError
from geofix.filters.base import Motion, Observation, RecursiveFilter
from geofix.filters.convergence import posterior_kl
from geofix.filters.loop import FilterSettings, FilterStepper
from geofix.filters.sizing import FilterSize, check_filter_budget, filter_size
from geofix.filters.state import mode_position
from geofix.maps.grid import Grid
from geofix.measurement import map_error_variance
from geofix.navigator.estimate import Estimate, estimate_fields
from geofix.navigator.health import Health, innovation_nis
from geofix.navigator.intake import (
    PingIntake,
    check_start_box,
    finite,
    min_beams,
    motion_between,
    point,
)
from geofix.navigator.offset import OffsetEstimator
from geofix.navigator.settings import NavigatorSettings
from geofix.problem import Matcher, MatchField, MatchProblem, registered_covariance

FIELD_SENSORS = {"depth": "singlebeam", "gravity": "gravimeter", "magnetic": "magnetometer"}
"""The sensor type of a further field of each map kind (its placeholder start reading)."""
FIELD_PING_KEYS = ("kind", "beams", "noise_var")
"""The keys of one further field's reading of a ping (:meth:`Navigator.measure`)."""


def start_problem(
    grid: Grid,
    t: float,
    position,
    sigma_m: float,
    heading: float,
    ins_model=None,
    field_grids: tuple[Grid, ...] = (),
) -> MatchProblem:
    """A one-sample :class:`MatchProblem` carrying a prior for ``filter.initialize``.

    ``measured`` holds one placeholder reading of 0 (filters check that a problem has
    some finite reading; :meth:`Navigator.init` never updates with it). An
    ``ins_model`` (:class:`~geofix.nav.errstate.InsErrorModel`) is carried with its
    position prior replaced by the start's: no fixed offset, per-axis ``sigma_m``; its
    velocity, tilt, bias and heading-error prior are kept. A filter on it builds each
    later step from the motion (:func:`geofix.nav.errstate.step_matrices`).

    Parameters
    ----------
    grid : Grid
        The map.
    t : float
        Start time, seconds.
    position : array_like
        ``(2,)`` start position, metres.
    sigma_m : float
        Per-axis 1-sigma of the start, metres.
    heading : float
        Heading, radians clockwise from north.
    ins_model : InsErrorModel, optional
        The INS error model of a filter on the INS error state.
    field_grids : tuple of Grid
        The further fields' maps: each a :class:`~geofix.problem.MatchField` of one
        placeholder reading, so that the filter loop keeps one set of nuisance states
        per field.

    Returns
    -------
    MatchProblem
        One sample at ``t``.
    """
    fields = tuple(
        MatchField(
            grid=g,
            measured=np.zeros((1, 1)),
            offsets=np.zeros((1, 2)),
            sensor=FIELD_SENSORS.get(g.kind, "gravimeter"),
        )
        for g in field_grids
    )
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
        fields=fields,
    )


class Navigator:
    """An online navigator on ``grid`` with a named recursive filter.

    Feed it navigation records (:meth:`motion`) and pings (:meth:`measure`) after a
    start (:meth:`init`); each returns an :class:`~geofix.navigator.estimate.Estimate`
    (:meth:`estimate` gives the current one, :meth:`fallback` what the INS alone tells).
    :meth:`predict` and :meth:`update` are the two steps underneath, on a
    :class:`~geofix.filters.base.Motion` and an :class:`~geofix.filters.base.Observation`.

    Parameters
    ----------
    grid : Grid
        The map (metric frame).
    method : str or filter
        A registered recursive method name or spec (``"pmf"``, ``"pf:particles=2000"``,
        ``"sitan"``, ...), or a filter instance.
    settings : NavigatorSettings or dict, optional
        The navigator's rules (:class:`~geofix.navigator.settings.NavigatorSettings`).
    seed : int or numpy.random.Generator
        Seed of the generator behind every random draw (same seed, same inputs: the
        same estimates, bit for bit).
    map_error : Grid, optional
        Per-cell map standard deviation (the ``z_std`` layer of ``geofix grid``), added
        as map-error variance to the measurement variance at each beam's footprint.
    ins_model : InsErrorModel, optional
        The INS error model (:mod:`geofix.nav.errstate`): required by a filter on the INS
        error state (``mpf``, ``pmf:model=errstate``), ignored by the others; see
        :func:`start_problem` for its prior.
    field_grids : sequence of Grid, optional
        The further fields' maps (a gravity anomaly, a magnetic anomaly beside a depth
        map), each of a kind of its own other than ``grid``'s, in the same metric frame
        (their cells need not match). Each ping may then carry their readings
        (:meth:`measure`'s ``fields``). Their readings are taken as given (no lag undone,
        no per-cell map error added); the filter must weigh several fields (``pmf``,
        ``pf``, ``mpf``).

    Raises
    ------
    ConfigError
        Unknown method or setting, a batch matcher instead of a recursive filter, a
        filter that needs an INS error model without one, or further maps a filter does
        not weigh, of a repeated kind or not maps.
    MemoryBudgetError
        The filter would exceed the memory budget (:mod:`geofix.filters.sizing`).
    """

    def __init__(
        self,
        grid: Grid,
        method="pmf",
        settings=None,
        seed=0,
        map_error=None,
        ins_model=None,
        field_grids=None,
    ) -> None:
        filt = _recursive_filter(method)
        field_grids = _field_grids(grid, field_grids, filt, method)
        if filt.needs_ins_model and ins_model is None:
            raise ConfigError(
                f"navigator: method {method if isinstance(method, str) else filt.name!r} "
                "needs an INS error model (ins_model; for geofix replay / serve: "
                "--ins SCENARIO.yaml with an ins: block)"
            )
        if not isinstance(settings, NavigatorSettings):
            settings = NavigatorSettings.from_dict(settings)
        check_filter_budget(filt, settings.filter_settings(), grid)  # before it holds a point
        rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        self.method = method if isinstance(method, str) else filt.name
        self.settings = settings.for_map_model(filt.map_model)
        self._stepper = FilterStepper(filt, grid, self.settings.filter_settings(), rng)
        self.map_error = map_error
        self.ins_model = ins_model
        self._intake = PingIntake(self.settings)
        self.field_grids: tuple[Grid, ...] = field_grids
        # a further field's readings: levelled as the primary's, no lag undone
        self._field_intake = PingIntake(replace(self.settings, lag_s=0.0))
        self._health = Health(self.settings, self._stepper.grid)
        self._offset = OffsetEstimator(self._stepper)
        self._pose: tuple[float, np.ndarray, float] | None = None  # (t, position (2,), heading)
        self._t_last: float | None = None
        self._t_accepted = 0.0
        self._pings = self._rejected = self._reinits = self._accepted_count = 0
        self._last: Estimate | None = None
        self._map_cov = np.zeros((2, 2))  # the last posterior's, without the registration

    # ------------------------------------------------------------------ the filter
    @property
    def filter(self):
        """The recursive filter (a filter of the per-step protocol)."""
        return self._stepper.filter

    @property
    def grid(self) -> Grid:
        """The map, read with the settings' ``interpolation``."""
        return self._stepper.grid

    @property
    def rng(self):
        """The generator behind every random draw."""
        return self._stepper.rng

    @property
    def state(self):
        """The filter's current state (None before :meth:`init` or :meth:`start`)."""
        return self._stepper.state

    @state.setter
    def state(self, state) -> None:
        self._stepper.state = state

    @property
    def noise_factor(self) -> float:
        """The residual scale's factor on the declared measurement variance (1: none)."""
        return self._stepper.noise_factor

    @property
    def field_kinds(self) -> tuple[str, ...]:
        """The kinds of the further fields' maps, in order (``()``: the one field)."""
        return tuple(g.kind for g in self.field_grids)

    # ------------------------------------------------------------------ the two steps
    def start(self, problem: MatchProblem) -> None:
        """Initialise from a problem's prior (its first sample), as a campaign trial does.

        Parameters
        ----------
        problem : MatchProblem
            Its first sample's indicated position, heading, time and ``sigma_position``
            make the prior.
        """
        self._stepper.start(problem)
        t0 = float(problem.times[0])
        self._pose = (t0, np.asarray(problem.indicated[0], float), float(problem.heading[0]))
        self._t_last = self._t_accepted = t0
        self._health.restart(float(problem.sigma_position[0]))
        self._last = None

    def predict(self, motion: Motion) -> None:
        """Apply the INS motion of one step to the posterior.

        Parameters
        ----------
        motion : Motion
            The displacement (metres), its duration (seconds) and process variance (m^2).

        Raises
        ------
        InputError
            Before :meth:`init`.
        """
        self._require_started()
        self._stepper.predict(motion)
        self._health.moved(motion.process_var)
        self._last = None

    def update(self, obs: Observation, t: float | None = None, fields=()) -> Estimate:
        """Fold in one ping (gated by its NIS), update the status, re-initialise if lost.

        Parameters
        ----------
        obs : Observation
            The ping, placed at the current pose (the primary field's).
        t : float, optional
            Its time, seconds (default: the time of the last pose).
        fields : sequence of Observation or None
            One per further field (:attr:`field_grids`, in order): its reading at the
            same pose, or None where the ping has none (``()``: none at all). The ping is
            taken when the primary or a further field has its minimum of valid beams; a
            primary short of it is left out of the update. The gate judges the
            primary's NIS alone and refuses the whole ping.

        Returns
        -------
        Estimate
            The estimate after the ping (the INS fallback while lost).

        Raises
        ------
        InputError
            Before :meth:`init`.
        """
        pose = self._require_started()
        t = pose[0] if t is None else float(t)
        self._pings += 1
        s = self.settings
        nis = float("nan")
        further = self._weigh_fields(fields, t) if self.field_grids else []
        relative, obs = self._stepper.weigh(obs, t)
        accepted = int(np.isfinite(obs.values).sum()) >= min_beams(s, obs.values.size)
        primary = accepted
        if any(ok for *_, ok in further):
            accepted = True
        prior = self.filter.estimate(self.state) if accepted else None
        judges_nis = s.converge_nis_max is not None or s.converge_nis_min is not None
        wants_nis = s.gate_nis is not None or s.nis_window > 0
        if primary and prior is not None and (wants_nis or (s.report_status and judges_nis)):
            mean, cov = prior
            nis = innovation_nis(self.grid, mean, cov, obs)
            gated = self._accepted_count > 0
            if s.gate_nis is not None and gated and np.isfinite(nis) and nis > s.gate_nis:
                accepted = False
                self._rejected += 1
            if np.isfinite(nis) and s.nis_window > 0:
                self._health.add_nis(nis)
        # the ping judges the filter's claim when it came to a posterior already small
        # and resolved (the NIS against a wide or unresolved one is no test of the claim)
        judged = (
            accepted
            and s.report_status
            and prior is not None
            and self._health.small(prior[1])
            and self._health.resolved(self.state)
        )
        if accepted and any(ok for *_, ok in further):
            accepted = self._fold_fields(obs if primary else _blank(obs), further)
            self._rejected += int(not accepted)
        elif accepted:
            accepted = self._stepper.fold(obs)
            self._rejected += int(not accepted)  # a step that left a non-finite estimate
        if accepted:
            self._accepted_count += 1
            self._t_accepted = t
            if primary:
                self._offset.learn(relative, obs, prior)
            for stepper, rel, weighed, ok in further:
                stepper.state = self.state
                if ok:
                    stepper.learn(rel, weighed, prior, settled=self._offset.settled)
        beams = int(np.isfinite(obs.values).sum()) if primary else 0
        estimate = self._describe(t, nis, accepted, judged, beams)
        self._offset.judged(estimate.status)
        if accepted and s.report_status:
            offset = estimate.position - pose[1]
            entry = (nis, beams, offset, self._map_cov, self._health.process_var, judged)
            self._health.window.append(entry)
        self._health.pinged()
        reason = self._health.lost_reason(t, self._t_accepted, self._covariance)
        if reason is not None:
            if reason == "nis" and accepted:  # not an outlier the gate already refused
                self._health.forget_good_fix()
            estimate = self._lose(estimate, t)  # a ping that loses the filter is no good fix
        elif estimate.status == "converged":
            self._health.remember_good(estimate.position, self._map_cov, pose[1])
        elif self._health.lost:
            estimate = self._fallback(estimate)
        self._last = estimate
        return estimate

    def _weigh_fields(self, fields, t: float) -> list[tuple]:
        """``(stepper, relative, weighed, usable)`` of every further field of a ping.

        A field the ping has no reading of gets a one-beam placeholder of NaN (not weighed
        by the filter, its nuisance states untouched).
        """
        fields = tuple(fields) if fields is not None else ()
        if len(fields) not in (0, len(self.field_grids)):
            raise InputError(
                f"ping: {len(fields)} further field readings, the navigator has "
                f"{len(self.field_grids)} further maps"
            )
        out: list[tuple] = []
        steppers = self._stepper.fields
        for i, stepper in enumerate(steppers):
            obs = fields[i] if fields else None
            if obs is None:
                out.append((stepper, None, None, False))
                continue
            stepper.state = self.state
            relative, weighed = stepper.weigh(obs, t)
            valid = int(np.isfinite(weighed.values).sum())
            usable = valid >= min_beams(self.settings, weighed.values.size)
            out.append((stepper, relative, weighed, usable))
        return out

    def _fold_fields(self, obs: Observation, further: list[tuple]) -> bool:
        """Fold the primary ping and every further field's in one update; folded or not."""
        extra = []
        for stepper, _, weighed, usable in further:
            if usable:
                extra.append((stepper._for_filter(weighed), stepper.grid))
            else:
                extra.append((_placeholder(obs), stepper.grid))
        return self._stepper.fold(obs, tuple(extra))

    # ------------------------------------------------------------------ raw inputs
    def init(self, t: float, position, sigma_m: float, heading: float = 0.0) -> Estimate:
        """Start (or restart) at ``position`` with a per-axis prior ``sigma_m``.

        Parameters
        ----------
        t : float
            Time, seconds.
        position : array_like
            ``(2,)`` start position ``(x, y)``, metres.
        sigma_m : float
            Per-axis 1-sigma of the start, metres (positive).
        heading : float
            Heading, radians clockwise from north.

        Returns
        -------
        Estimate
            The estimate of the fresh prior (status ``initialising``).

        Raises
        ------
        InputError
            Non-finite values, a non-positive sigma, or a start box mostly off valid map
            data (start-up gating).
        """
        t, heading = finite(t, "t"), finite(heading, "heading")
        position = point(position, "position")
        sigma_m = finite(sigma_m, "sigma_m")
        if sigma_m <= 0:
            raise InputError(f"init: sigma_m must be positive, got {sigma_m:g}")
        check_start_box(self.grid, position, sigma_m, self.settings.min_start_share)
        prior = start_problem(
            self.grid, t, position, sigma_m, heading, self.ins_model, self.field_grids
        )
        try:
            self._stepper.start(prior)
        except MatchError as exc:
            raise InputError(f"init: {exc}") from None
        self._pose = (t, position, heading)
        self._t_last = self._t_accepted = t
        self._health.restart(sigma_m)
        self._pings = self._rejected = self._reinits = self._accepted_count = 0
        self._last = None
        return self.estimate()

    def motion(
        self, t: float, position, heading: float, process_var: float | None = None
    ) -> Estimate:
        """A navigation record: the INS-indicated position and heading.

        The posterior moves by the change of the indicated position since the previous
        record.

        Parameters
        ----------
        t : float
            Time, seconds (not before the previous input).
        position : array_like
            ``(2,)`` indicated position ``(x, y)``, metres.
        heading : float
            Indicated heading, radians clockwise from north.
        process_var : float, optional
            Per-axis variance the position error gains since the previous record, m^2
            (default ``process_noise_m2_s`` times the elapsed time).

        Returns
        -------
        Estimate
            The estimate after the motion (``lost`` after an outage).

        Raises
        ------
        InputError
            Before :meth:`init`, out of time order, non-finite, or faster than
            ``max_speed_m_s``.
        """
        t_prev, pos_prev, _ = self._require_started()
        t, heading = finite(t, "t"), finite(heading, "heading")
        position = point(position, "position")
        if t < t_prev or (self._t_last is not None and t < self._t_last):
            raise InputError(f"nav at t = {t:g} s is before the previous input ({self._t_last:g})")
        step = motion_between(self.settings, (t_prev, pos_prev), t, position, process_var)
        self.predict(step)
        self._pose = (t, position, heading)
        self._t_last = t
        if self._health.grace == 0 and self._health.outage(t, self._t_accepted):
            self._last = self._lose(self._describe(t, float("nan"), False), t)
        return self.estimate()

    def measure(
        self, t: float, beams, noise_var=None, roll=None, pitch=None, fields=None
    ) -> Estimate:
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
        fields : sequence of mapping, optional
            The further fields' readings of the ping, each ``{"kind": KIND, "beams":
            rows, "noise_var": var}``: ``KIND`` one of :attr:`field_kinds` (each at most
            once), ``rows`` as ``beams`` (in that map's units, NaN: missing) and ``var``
            the reading's measurement variance, that map's units squared (a number or
            one per beam). A further field left out is not weighed at this ping. The
            primary ``beams`` may then be all NaN (a ping of the further fields alone).

        Returns
        -------
        Estimate
            The estimate after the ping.

        Raises
        ------
        InputError
            Before :meth:`init`, out of order, far from the last pose, malformed beams,
            a roll / pitch not finite or beyond +-90 degrees, or a malformed further
            field (an unknown or repeated kind, an unknown key, no ``noise_var``).
        """
        t_pose, position, heading = self._require_started()
        t = finite(t, "t")
        if self._t_last is not None and t < self._t_last:
            raise InputError(f"ping at t = {t:g} s is before the previous input ({self._t_last:g})")
        gap = self.settings.max_pose_gap_s
        if gap is not None and abs(t - t_pose) > gap:
            raise InputError(
                f"ping at t = {t:g} s is {abs(t - t_pose):.3g} s from the last nav "
                f"(at most {gap:g} s)"
            )
        further = self._field_readings(t, fields, roll, pitch, position, heading)
        offsets, values, var = self._intake.read(t, beams, noise_var, roll, pitch)
        if self.map_error is not None:
            mean, _ = self.filter.estimate(self.state)
            var = var + map_error_variance(self.map_error, mean, heading, offsets)
        obs = Observation(values, position, heading, offsets, var, self._pings)
        self._t_last = t
        if further is None:
            return self.update(obs, t)
        return self.update(obs, t, further)

    def _field_readings(self, t: float, fields, roll, pitch, position, heading):
        """One Observation (or None) per further field of a ping's ``fields``, checked.

        None when the ping carries no ``fields`` at all.
        """
        if fields is None:
            return None
        if isinstance(fields, dict | str | bytes) or not hasattr(fields, "__iter__"):
            raise InputError("ping: fields must be a list of {kind, beams, noise_var}")
        readings: list[Observation | None] = [None] * len(self.field_grids)
        kinds = self.field_kinds
        for entry in fields:
            if not isinstance(entry, dict):
                raise InputError("ping: each of fields must be an object {kind, beams, noise_var}")
            unknown = sorted(set(entry) - set(FIELD_PING_KEYS))
            if unknown:
                shown = ", ".join(str(k) for k in unknown)[:80]
                raise InputError(f"ping: a field has unknown key(s) {shown}")
            kind = entry.get("kind")
            if kind not in kinds:
                known = ", ".join(kinds) if kinds else "none: one map"
                raise InputError(f"ping: field kind {str(kind)[:40]!r} has no map ({known})")
            i = kinds.index(kind)
            if readings[i] is not None:
                raise InputError(f"ping: field {kind} given twice")
            if entry.get("noise_var") is None:
                raise InputError(f"ping: field {kind} needs its noise_var ({kind} map units^2)")
            try:
                offsets, values, var = self._field_intake.read(
                    t, entry.get("beams"), entry["noise_var"], roll, pitch
                )
            except InputError as exc:
                raise InputError(f"{kind} field {exc}") from None
            readings[i] = Observation(values, position, heading, offsets, var, self._pings)
        return readings

    def estimate(self) -> Estimate:
        """The current estimate (the last one returned, or one of the current state).

        Returns
        -------
        Estimate
            The estimate (the INS fallback while lost).

        Raises
        ------
        InputError
            Before :meth:`init`.
        """
        t_pose = self._require_started()[0]
        if self._last is None:
            t = self._t_last if self._t_last is not None else t_pose  # both set by init/start
            described = self._describe(t, float("nan"), False)
            self._last = self._fallback(described) if self._health.lost else described
        return self._last

    def fallback(self) -> tuple[np.ndarray, np.ndarray]:
        """What the INS alone tells since the last good fix.

        The current navigation plus the last good offset (estimate minus navigation at the
        last ``converged`` ping; zero before the first), and the last good covariance
        (the init prior before the first) grown by the process variance of every motion
        since. It is the estimate reported while ``lost``.

        Returns
        -------
        tuple of numpy.ndarray
            ``(position (2,), covariance (2, 2))``, metres and m^2.

        Raises
        ------
        InputError
            Before :meth:`init`.
        """
        return self._health.fallback(self._require_started()[1])

    def consistency(
        self, mean, cov, nis: float = float("nan"), judged: bool = False, beams: int = 1
    ) -> str | None:
        """Why the filter's claim is not (yet) consistent with its pings, or None.

        The terms of :meth:`geofix.navigator.health.Health.consistency` (``"pings"``,
        ``"nis"``, ``"shift"``, ``"points"``, ``"scale"``, ``"ins"``) against the current
        navigation, state and residual scale.

        Parameters
        ----------
        mean : array_like
            ``(2,)`` the current posterior mean, metres.
        cov : array_like
            ``(2, 2)`` the current posterior covariance, m^2.
        nis : float
            Per-beam NIS of the current ping (NaN: none).
        judged : bool
            The current ping was folded in and came to a small, resolved posterior.
        beams : int
            Valid beams of the current ping.

        Returns
        -------
        str or None
            The first failed term, or None when all pass.

        Raises
        ------
        InputError
            Before :meth:`init`.
        """
        navigation = self._require_started()[1]
        return self._health.consistency(
            mean, cov, navigation, self.state, self.noise_factor, nis, judged, beams
        )

    # ------------------------------------------------------------------ rules
    def _describe(
        self, t: float, nis: float, accepted: bool, judged: bool = False, beams: int = 1
    ) -> Estimate:
        """The estimate of the current state: status, MLE and KL as the settings ask."""
        mean, cov = self._stepper.estimate()
        self._map_cov = cov  # the health rules work in the map's frame
        report = self.settings.report_status
        mle = mode_position(self.filter, self.state) if report else mean.copy()
        status = "initialising" if self._accepted_count == 0 else "converging"
        kl = float("nan")
        if (
            report
            and status == "converging"
            and self._health.converged(mean, cov, mle)
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
            covariance=registered_covariance(self.grid, cov),
            mle=mle,
            status=status,
            nis=nis,
            accepted=accepted,
            pings=self._pings,
            rejected=self._rejected,
            reinits=self._reinits,
            kl_nats=kl,
            **self._offset.fields(),
        )

    def _covariance(self) -> np.ndarray:
        """The posterior's ``(2, 2)`` covariance, m^2."""
        return self.filter.estimate(self.state)[1]

    def _fallback(self, estimate: Estimate) -> Estimate:
        """``estimate`` with the INS fallback's position and covariance, status ``lost``."""
        position, cov = self.fallback()
        if self._health.good_fixes:  # from a fix on the map: its registration too
            cov = registered_covariance(self.grid, cov)
        return Estimate(
            **{
                **estimate_fields(estimate),
                "position": position,
                "covariance": cov,
                "mle": position.copy(),
                "status": "lost",
                "kl_nats": float("nan"),
            }
        )

    def _lose(self, estimate: Estimate, t: float) -> Estimate:
        """Report ``lost`` (the INS fallback); re-initialise the filter around it.

        The restart sigma is the fallback's largest 1-sigma, at least the init sigma.
        """
        self._health.lost = True
        lost = self._fallback(estimate)
        if not self.settings.reinit:
            return lost
        heading = self._require_started()[2]
        sigma = max(lost.sigma_m, self._health.prior_sigma)
        try:
            self._stepper.start(
                start_problem(
                    self.grid,
                    t,
                    lost.position,
                    sigma,
                    heading,
                    self.ins_model,
                    self.field_grids,
                )
            )
        except MatchError:
            return lost  # the restart box is off the map: keep the old posterior, stay lost
        self._reinits += 1
        self._accepted_count = 0
        self._t_accepted = t
        self._health.reinitialised(sigma)
        return Estimate(**{**estimate_fields(lost), "reinits": self._reinits})

    def _require_started(self) -> tuple[float, np.ndarray, float]:
        """The last pose ``(t, position (2,), heading)``; InputError before any init."""
        if self.state is None or self._pose is None:
            raise InputError("no init yet: send init (t, x, y, sigma_m) first")
        return self._pose


def _field_grids(grid: Grid, field_grids, filt, method) -> tuple[Grid, ...]:
    """The further fields' maps, checked (ConfigError naming the problem)."""
    if field_grids is None:
        return ()
    if isinstance(field_grids, Grid):
        field_grids = (field_grids,)
    field_grids = tuple(field_grids)
    if not field_grids:
        return ()
    if not all(isinstance(g, Grid) for g in field_grids):
        raise ConfigError("navigator: field_grids must be maps (Grid)")
    kinds = [grid.kind, *(g.kind for g in field_grids)]
    repeated = sorted({k for k in kinds if kinds.count(k) > 1})
    if repeated:
        raise ConfigError(
            f"navigator: one map per field kind; {', '.join(repeated)} is given twice "
            f"(maps of kinds {', '.join(kinds)})"
        )
    if not filt.fuses_fields:
        label = method if isinstance(method, str) else filt.name
        raise ConfigError(
            f"navigator: method {label!r} weighs one field only; several fields need a "
            "filter that fuses them (pmf, pf, mpf)"
        )
    return field_grids


def _blank(obs: Observation) -> Observation:
    """``obs`` with every value missing (a primary short of its minimum of beams)."""
    return replace(obs, values=np.full_like(np.asarray(obs.values, dtype=float), np.nan))


def _placeholder(obs: Observation) -> Observation:
    """A one-beam reading of NaN at ``obs``'s pose: a field the ping has no value of."""
    return Observation(
        np.full(1, np.nan), obs.indicated, obs.heading, np.zeros((1, 2)), 1.0, obs.index
    )


def _parse_method(method):
    """The filter of a method spec, or ``method`` itself when it is a filter instance."""
    from geofix.methods import parse_method_spec

    return parse_method_spec(method) if isinstance(method, str) else method


def _recursive_filter(method) -> RecursiveFilter:
    """The filter of a method spec or instance, refused unless it steps ping by ping.

    Raises
    ------
    ConfigError
        A batch matcher, or a method without the per-ping steps (the free INS ``ins``).
    """
    filt = _parse_method(method)
    if isinstance(filt, RecursiveFilter):
        return filt
    label = method if isinstance(method, str) else type(method).__name__
    stepped = isinstance(filt, Matcher) and filt.recursive
    what = "cannot run ping by ping" if stepped else "is a batch matcher"
    raise ConfigError(
        f"navigator: method {label!r} {what}; use a recursive filter (pmf, pf, sitan, ...)"
    )


def _filter_settings(settings) -> FilterSettings:
    """The measurement-model part of navigator settings (a mapping or None: checked)."""
    if not isinstance(settings, NavigatorSettings):
        settings = NavigatorSettings.from_dict(settings)
    return settings.filter_settings()


def method_size(method, settings=None, grid: Grid | None = None, beams=None) -> FilterSize | None:
    """:func:`geofix.filters.sizing.filter_size` of a method spec or filter instance.

    Parameters
    ----------
    method : str or filter
        ``"pf:particles=2000"``, or a filter.
    settings : NavigatorSettings or dict, optional
        The navigator's settings.
    grid : Grid, optional
        The map (for the representation-error layer of ``map_model`` other than exact).
    beams : int, optional
        Most beams of a ping.

    Returns
    -------
    FilterSize or None
        None for a filter that is not sized (``sitan``, ``sitan-bank``).

    Raises
    ------
    ConfigError
        An unknown method or setting.
    """
    return filter_size(_parse_method(method), _filter_settings(settings), grid, beams)


def check_method_budget(
    method, settings=None, grid: Grid | None = None, beams=None
) -> FilterSize | None:
    """:func:`geofix.filters.sizing.check_filter_budget` of a method spec or filter.

    Parameters
    ----------
    method : str or filter
        ``"pf:particles=2000"``, or a filter.
    settings : NavigatorSettings or dict, optional
        The navigator's settings.
    grid : Grid, optional
        The map.
    beams : int, optional
        Most beams of a ping.

    Returns
    -------
    FilterSize or None
        The size, None for a filter that is not sized.

    Raises
    ------
    ConfigError
        An unknown method or setting.
    MemoryBudgetError
        The filter would exceed the memory budget (the message gives the estimate).
    """
    return check_filter_budget(_parse_method(method), _filter_settings(settings), grid, beams)


__all__ = ["Navigator", "check_method_budget", "method_size", "start_problem"]
