"""The plain filter loop: one recursive filter, its state and its measurement model.

:class:`FilterStepper` holds a filter of the per-step protocol of
:mod:`geofix.filters.base`, its state and the measurement model's nuisance states of
:mod:`geofix.filters.nuisance` -- the common offset (measured minus map), the residual
scale and the share of the map's representation error -- and steps them together:
:meth:`~FilterStepper.start`, :meth:`~FilterStepper.predict` and
:meth:`~FilterStepper.update`. :func:`geofix.filters.base.run_filter` (every campaign
trial) drives it as it is; the online navigator (:mod:`geofix.navigator`) drives the
same pieces (:meth:`~FilterStepper.weigh`, :meth:`~FilterStepper.fold`,
:meth:`~FilterStepper.learn`) with its gating, statuses and re-initialisation around them.

Each ping is taken relative to the offset's mean with its likelihood marginalised over the
offset's variance, its variance widened by the representation error and the residual
scale; a filter that carries the offset per hypothesis (``pmf``, ``pf`` and ``mpf``, by
default on every ping) takes the readings as they are with the offset's prior. After an
accepted ping the scale and the share learn from its innovations; the hypotheses' own
offsets learn in the filter's update, and the one common offset (otherwise) from the
ping's residuals: always for a ping of fewer than three beams, for one of several only
when the caller says the position is settled (the navigator: while ``converged``; never
in a campaign trial).

**Several fields.** A problem with further fields (:attr:`MatchProblem.fields`: a
gravimeter or a magnetometer beside the echosounder) gives a filter that weighs them
(``fuses_fields``: PMF, PF, MPF) one observation per field at every sample and one set of
nuisance states per field -- its own common offset (at its map's default prior,
:func:`~geofix.maps.offset.default_offset_std`, when the settings leave the offset
to the map), residual scale and representation share, learnt from its own innovations.
The filter's update adds the fields' log-likelihoods at the same hypotheses (the product
of their likelihoods), and a filter that carries the offset per hypothesis carries one
per field, each by the rule above for its own pings. A filter that does not weigh further
fields (SITAN) uses the primary field alone.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from geofix.errors import ConfigError
from geofix.filters.convergence import posterior_points
from geofix.filters.nuisance import (
    ROUGHNESS_WINDOW_CELLS,
    WHITE_EXCESS,
    CommonOffset,
    ProfileRoughness,
    RepresentationShare,
    ResidualScale,
    SwathModes,
    correlated_share,
    default_fast_offset_walk,
    default_offset_smooth,
    read_at_points,
    representation_std,
    swath_shapes,
)
from geofix.filters.state import SteppedFilter
from geofix.maps.grid import Grid
from geofix.maps.offset import default_offset_std
from geofix.measurement import lag_compensated, map_error_variance, predict_measurements

if TYPE_CHECKING:  # annotations only: base.run_filter imports this module
    from geofix.filters.base import Motion, Observation
    from geofix.problem import MatchProblem


@dataclass(frozen=True)
class FilterSettings:
    """What a filter's update is built with: the map read, the nuisance model, its size.

    The measurement-model part of :class:`geofix.navigator.NavigatorSettings` (whose
    documentation gives each field in full); the defaults are the navigator's.

    Parameters
    ----------
    interpolation : {"bilinear", "bicubic"}
        The map read of the measurement model.
    depth_bias_std : float or None
        Prior 1-sigma of the common offset, map units (0: none; None: the map's default,
        :func:`geofix.maps.offset.default_offset_std`).
    depth_bias_walk : float
        Variance the offset gains per second, map units squared per second.
    representation_error : bool
        Add the map's representation error to every beam's variance (its layer, and the
        relief the readings show and the map lacks).
    swath_modes : bool
        Marginalise a multibeam ping over the map error's tilt and curvature across the
        swath (:class:`geofix.filters.nuisance.SwathModes`).
    adaptive_noise : bool
        Scale the measurement variance by the residual scale of the innovations.
    noise_forgetting : float
        Forgetting factor per ping of the residual scale and the representation share.
    offset_per_hypothesis : bool or None
        A filter that can carries the offset per hypothesis (None: on every ping, as
        True; False: the one common offset, marginalised per ping); a method's own
        ``offset_per_hypothesis`` is above it.
    max_update_beams : int or None
        Most valid beams of one update (None: every beam of a ping), what the filter is
        sized for (:mod:`geofix.filters.sizing`).
    max_beams : int
        Most beams a ping may carry.
    """

    interpolation: str = "bilinear"
    depth_bias_std: float | None = 0.0
    depth_bias_walk: float = 1e-3
    representation_error: bool = False
    swath_modes: bool = False
    adaptive_noise: bool = False
    noise_forgetting: float = 0.98
    offset_per_hypothesis: bool | None = None
    max_update_beams: int | None = 64
    max_beams: int = 4096

    def for_map_model(self, map_model: str) -> FilterSettings:
        """These settings for a filter of ``map_model`` ``exact``, ``adaptive`` or ``imperfect``.

        Parameters
        ----------
        map_model : str
            ``exact``: unchanged. ``adaptive``: the representation error, the swath's
            error shapes and the adaptive residual scale switched on. ``imperfect``:
            those and the common offset (at the map's default prior unless
            ``depth_bias_std`` is set).

        Returns
        -------
        FilterSettings
            The settings the filter runs with (applying them twice changes nothing).
        """
        if map_model not in ("adaptive", "imperfect"):
            return self
        adaptive = replace(self, representation_error=True, swath_modes=True, adaptive_noise=True)
        if map_model == "adaptive":
            return adaptive
        std = None if self.depth_bias_std == 0 else self.depth_bias_std
        return replace(adaptive, depth_bias_std=std)

    @classmethod
    def from_dict(cls, values: dict | None) -> FilterSettings:
        """Settings from a mapping; unknown keys are a ConfigError naming them."""
        values = dict(values or {})
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ConfigError(
                f"filter: unknown setting(s) {', '.join(unknown)} (known: {', '.join(known)})"
            )
        return cls(**values)


def offset_per_hypothesis(filt, settings: FilterSettings) -> bool:
    """Whether ``filt`` carries the common offset per hypothesis under ``settings``.

    The method's own ``offset_per_hypothesis`` is above the settings'; None in both is
    every ping.
    """
    own = getattr(filt, "offset_per_hypothesis", None)
    chosen = settings.offset_per_hypothesis if own is None else own
    return True if chosen is None else bool(chosen)


class FilterStepper:
    """One recursive filter with its state and its measurement model's nuisance states.

    Parameters
    ----------
    filt
        A filter of the per-step protocol (``initialize``, ``predict``, ``update``,
        ``estimate``), e.g. :class:`geofix.filters.pmf.Pmf`.
    grid : Grid
        The map; read with ``settings.interpolation``.
    settings : FilterSettings, optional
        The measurement model (default :class:`FilterSettings`), taken for the filter's
        ``map_model`` (:meth:`FilterSettings.for_map_model`).
    rng : numpy.random.Generator or None
        Source of every random draw of the filter (None only for deterministic filters).
    """

    def __init__(
        self, filt: SteppedFilter, grid: Grid, settings: FilterSettings | None = None, rng=None
    ):
        self.filter: Any = filt  # its steps are typed by each filter's own state
        settings = settings or FilterSettings()
        walk = getattr(filt, "offset_walk", None)  # the method's own, above the settings'
        if walk is not None:
            settings = replace(settings, depth_bias_walk=float(walk))
        per_hypothesis = getattr(filt, "offset_per_hypothesis", None)
        if per_hypothesis is not None:
            settings = replace(settings, offset_per_hypothesis=bool(per_hypothesis))
        self.settings = settings.for_map_model(filt.map_model)
        if grid.interpolation != self.settings.interpolation:
            grid = replace(grid, interpolation=self.settings.interpolation)
        self.grid = grid
        self.rng = rng
        self.state: Any = None
        self._representation: Grid | None = None  # the map's representation error, on use
        self._last_ping_at: np.ndarray | None = None  # indicated position of the last ping
        # the relief the readings show and the map lacks: of the seabed, kept on re-init
        self.roughness = ProfileRoughness.empty()
        self._value_range: tuple[float, float] | None = None  # readings the relief takes
        self.fields: tuple[FilterStepper, ...] = ()  # one per further field (start)
        self._field_index: int | None = None  # which further field this stepper is
        self._field_obs: tuple[tuple, ...] = ()  # (values, offsets, variance) per field
        self.reset_nuisance(0.0)

    # ------------------------------------------------------------------ the plain loop
    def start(self, problem: MatchProblem) -> None:
        """Initialise from a problem's prior (its first sample); the nuisance at its priors.

        A filter that weighs further fields (``fuses_fields``) gets one stepper of
        nuisance states per field of ``problem.fields`` (:attr:`fields`) and their
        observations. The state is kept when ``filter.initialize`` raises.
        """
        self.state = self.filter.initialize(problem, self.rng)
        self.reset_nuisance(float(problem.times[0]))
        self.fields, self._field_obs = (), ()
        if problem.fields and self.filter.fuses_fields:
            self._start_fields(problem)

    def _start_fields(self, problem: MatchProblem) -> None:
        """A nuisance stepper and the readings of every further field of ``problem``.

        Each field's readings with its declared lag undone and its per-beam variance,
        as :func:`geofix.filters.base.observations` gives the primary field's.
        """
        own = self.settings
        # a further field's offset prior is its own map's default (other units)
        settings = replace(own, depth_bias_std=0.0 if own.depth_bias_std == 0 else None)
        steppers, obs = [], []
        for index, field in enumerate(problem.fields):
            stepper = FilterStepper(self.filter, field.grid, settings, self.rng)
            stepper._field_index = index
            stepper.state = self.state
            stepper.reset_nuisance(float(problem.times[0]))
            steppers.append(stepper)
            alone = replace(
                problem,
                grid=field.grid,
                measured=field.measured,
                offsets=field.offsets,
                noise_std=field.noise_std,
                sensor=field.sensor,
                map_error_std=field.map_error_std,
                beam_noise_std=field.beam_noise_std,
                lag_s=field.lag_s,
                fields=(),
            )
            if alone.beam_noise_std is None:
                noise_var = max(alone.noise_std**2 + alone.map_error_std**2, 1e-12)
            else:
                noise_var = np.maximum(alone.beam_noise_var(), 1e-12)
                noise_var.setflags(write=False)
            obs.append((lag_compensated(alone), np.asarray(field.offsets), noise_var))
        self.fields, self._field_obs = tuple(steppers), tuple(obs)

    def _field_ping(self, i: int, obs: Observation) -> Observation:
        """Further field ``i``'s reading at the sample of the primary ping ``obs``."""
        values, offsets, noise_var = self._field_obs[i]
        return replace(
            obs,
            values=values[obs.index],
            offsets=offsets,
            noise_var=noise_var,
            bias_var=0.0,
            bias_walk=0.0,
            bias_per_hypothesis=False,
        )

    def predict(self, motion: Motion) -> None:
        """Apply the INS motion of one step to the posterior."""
        self.state = self.filter.predict(self.state, motion, self.rng)

    def update(self, obs: Observation, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Fold in one ping with at least one valid beam; the posterior after it.

        Parameters
        ----------
        obs : Observation
            The ping as measured.
        t : float
            Its time, seconds.

        Returns
        -------
        tuple of numpy.ndarray
            ``(mean (2,), covariance (2, 2))`` of the posterior, metres and m^2.
        """
        relative, weighed = self.weigh(obs, t)
        if self.fields:
            return self._update_fields(obs, relative, weighed, t)
        if np.isfinite(weighed.values).any():
            prior = self.filter.estimate(self.state)
            if self.fold(weighed):
                self.learn(relative, weighed, prior)
        return self.estimate()

    def _update_fields(
        self, obs: Observation, relative: Observation, weighed: Observation, t: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`update` with the further fields' pings of the same sample folded in too."""
        pings = []
        for i, stepper in enumerate(self.fields):
            stepper.state = self.state
            pings.append((stepper, *stepper.weigh(self._field_ping(i, obs), t)))
        valid = [np.isfinite(w.values).any() for _, _, w in pings]
        if np.isfinite(weighed.values).any() or any(valid):
            prior = self.filter.estimate(self.state)
            extra = tuple((stepper._for_filter(w), stepper.grid) for stepper, _, w in pings)
            if self.fold(weighed, extra):
                if np.isfinite(weighed.values).any():
                    self.learn(relative, weighed, prior)
                for (stepper, rel, w), ok in zip(pings, valid, strict=True):
                    stepper.state = self.state
                    if ok:
                        stepper.learn(rel, w, prior)
        return self.estimate()

    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """``(mean (2,), covariance (2, 2))`` of the current posterior, metres and m^2."""
        mean, cov = self.filter.estimate(self.state)
        return np.asarray(mean, dtype=float), np.asarray(cov, dtype=float)

    # ------------------------------------------------------------------ the pieces
    def reset_nuisance(self, t: float) -> None:
        """The nuisance states back at their priors: the offset ``N(0, std^2)``, scale 1.

        The offset is modelled only for a filter with weighted points (a grid or particle
        set; :func:`~geofix.filters.convergence.posterior_points`).
        """
        s = self.settings
        std = s.depth_bias_std
        if std is None:
            std = default_offset_std(self.grid)
        weighted = self.state is not None and posterior_points(self.state) is not None
        self.offset = CommonOffset.prior(std if weighted else 0.0, s.depth_bias_walk, t)
        self._offset_prior_var = self.offset.var
        self.scale = ResidualScale.prior(s.noise_forgetting)
        self._share = RepresentationShare.prior(s.noise_forgetting)
        self._modes = SwathModes.prior(s.noise_forgetting)
        self._ping_variances: tuple[np.ndarray, np.ndarray] | None = None
        # each beam's variance before the count of shared map errors, over the counted one
        self._uncounted: np.ndarray | None = None

    @property
    def noise_factor(self) -> float:
        """The residual scale's factor on the declared measurement variance (1: none)."""
        return self.scale.factor if self.settings.adaptive_noise else 1.0

    def weigh(self, obs: Observation, t: float) -> tuple[Observation, Observation]:
        """``(relative, weighed)``: the ping relative to the offset, and with the scale too.

        Both carry the map's representation error in their variance. The offset is
        predicted to ``t`` (seconds).
        """
        self.offset = self.offset.predicted(t)
        read = self._with_representation(obs)
        relative = self.offset.relative(read)
        weighed = self.scale.scaled(relative) if self.settings.adaptive_noise else relative
        if self.settings.swath_modes:
            shapes = swath_shapes(obs.offsets, np.isfinite(obs.values))
            columns = self._modes.columns(shapes)
            if columns is not None:
                relative = replace(relative, map_modes=columns)
                weighed = replace(weighed, map_modes=columns)
        return relative, weighed

    def fold(self, weighed: Observation, fields: tuple = ()) -> bool:
        """Fold the weighed ping in; a step that leaves a non-finite estimate is refused.

        The state before it is kept (a reading the input checks let through, such as
        1e160 on a map of metres, must not poison the filter). Returns whether the ping
        was folded in. ``fields`` holds ``(ping as the filter takes it, map)`` of every
        further field at the same sample (in order, a ping without a value included),
        handed to a filter that weighs them.
        """
        before = self.state
        with np.errstate(all="ignore"):
            ping = self._for_filter(weighed)
            if fields:
                self.state = self.filter.update(
                    self.state, ping, self.grid, self.rng, fields=fields
                )
            else:
                self.state = self.filter.update(self.state, ping, self.grid, self.rng)
            mean, cov = self.filter.estimate(self.state)
        if np.isfinite(mean).all() and np.isfinite(cov).all():
            return True
        self.state = before
        return False

    def learn(
        self, relative: Observation, weighed: Observation, prior, settled: bool = False
    ) -> None:
        """After a folded ping: the scale and share from its innovations, the offset too.

        Parameters
        ----------
        relative : Observation
            The ping relative to the offset (:meth:`weigh`).
        weighed : Observation
            The same with the residual scale.
        prior : tuple of numpy.ndarray
            ``(mean (2,), covariance (2, 2))`` before the ping, metres and m^2.
        settled : bool
            The position is settled (the navigator: ``converged`` at the ping before): a
            ping of three beams or more then updates the offset's mean too. A ping of
            fewer always does: alone it says nothing of the position's shape, and the
            offset is what links it to the next. Learning the offset from a multibeam
            ping while the position is uncertain along a slope lets the two trade against
            each other, so a campaign trial (no status) never does: each such ping is
            marginalised over the offset's prior.
        """
        if self.settings.adaptive_noise and self._gaussian_enough(prior[1]):
            prior_mean, prior_cov = prior
            reads = read_at_points(self.grid, prior_mean, prior_cov, relative)
            if self.settings.swath_modes:
                self._learn_modes(weighed, prior_mean, prior_cov)
            if self._ping_variances is not None:
                declared, extra = self._ping_variances
                across = correlated_share(relative.offsets, self.grid.cell_size)
                self._share = self._share.updated(reads, declared, extra, relative.bias_var, across)
            self.scale = self.scale.updated(reads, relative.bias_var)
        if not self.offset.active:
            return
        if self.carries_offset:  # the filter's own offsets, summarised for the report
            if self._field_index is None:
                moments = self.filter.offset_moments(self.state)
            else:
                moments = self.filter.offset_moments(self.state, field=self._field_index)
            if moments is not None:
                self.offset = replace(self.offset, mean=moments[0], var=moments[1])
            return
        if int(np.isfinite(relative.values).sum()) < 3 or settled:
            mean, cov = self.filter.estimate(self.state)
            reads = read_at_points(self.grid, mean, cov, weighed)
            self.offset = self.offset.updated(reads, weighed.bias_var)

    def _learn_modes(self, weighed: Observation, mean: np.ndarray, cov=None) -> None:
        """The swath shapes' variance and persistence from a ping's innovations.

        Read at the prior mean ``mean`` (metres), with the map's gradients at the beams
        by central differences half a cell either side. The residual scale and the
        representation share still see the shapes' part of the innovations (taken out
        of theirs, the scale fell on block-mean maps and the particle filter lost a
        trial in four there): a cautious double count. The shapes' coefficients are
        fitted against each beam's variance before the count of the beams and pings that
        share one map error (:func:`~geofix.filters.nuisance.correlated_share`): the count
        is how the likelihood takes each error's information once, not the scatter of
        one ping's residuals, and against the counted variance the shapes read as noise
        wherever the representation share is not near zero.
        """
        h = 0.5 * self.grid.cell_size
        points = np.asarray(mean, dtype=float) + np.array(
            [[0.0, 0.0], [h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]]
        )
        predicted = predict_measurements(self.grid, points, weighed.heading, weighed.offsets)
        used = np.isfinite(weighed.values) & np.isfinite(predicted).all(axis=0)
        shapes = swath_shapes(np.asarray(weighed.offsets, dtype=float)[used])
        if shapes is None:
            return
        p = predicted[:, used]
        gradients = np.column_stack([p[1] - p[2], p[3] - p[4]]) / (2.0 * h)
        noise = np.broadcast_to(np.asarray(weighed.noise_var, dtype=float), used.shape)
        if self._uncounted is not None:
            noise = noise * self._uncounted
        noise = noise[used]
        residual = weighed.values[used] - p[0]
        self._modes = self._modes.updated(residual, shapes, gradients, noise, weighed.index, cov)

    @property
    def carries_offset(self) -> bool:
        """The filter carries the offset per hypothesis (its own offset states).

        By default on every ping (:func:`offset_per_hypothesis`). A profile's
        offset and position only several pings separate. On a coarse or misregistered
        depth map a multibeam swath's mean level follows the relief below the map's cells
        from place to place, so each hypothesis's own offset (with a faster walk beside
        the declared one, :func:`~geofix.filters.nuisance.default_fast_offset_walk`)
        explains its own map's level where one common offset would have to be one level
        for all: on the section *Imperfect maps* and the real multibeam pings it is both
        the more accurate and the nearer to consistent. ``offset_per_hypothesis=false``
        (the settings', or the method's own) keeps the one common offset, marginalised
        per ping.
        """
        return (
            bool(self.filter.carries_offset)
            and self.offset.active
            and offset_per_hypothesis(self.filter, self.settings)
        )

    def _for_filter(self, weighed: Observation) -> Observation:
        """The ping as the filter takes it.

        A filter that carries the offset per hypothesis takes the readings as they are,
        with the offset's prior variance and walk (it starts its own offsets from them);
        any other the readings relative to the common offset (``weighed``).
        """
        if not self.carries_offset:
            return weighed
        return replace(
            weighed,
            values=weighed.values + self.offset.mean,
            bias_var=self._offset_prior_var,
            bias_walk=self.offset.walk,
            bias_per_hypothesis=True,
            bias_fast_walk=default_fast_offset_walk(self.grid, weighed.values.size),
            bias_smooth_m=default_offset_smooth(self.grid),
        )

    def _with_representation(self, obs: Observation) -> Observation:
        """``obs`` with the map's representation error added to each beam's variance.

        The layer's variance times the share the innovations support so far
        (:class:`~geofix.filters.nuisance.RepresentationShare`), and at least the relief
        the readings show along the track and the map lacks
        (:class:`~geofix.filters.nuisance.ProfileRoughness`, counted once over its
        window); each counted once for the beams and pings that share one error.
        """
        self._ping_variances = None
        self._uncounted = None
        if not self.settings.representation_error or self.state is None:
            return obs
        if self._representation is None:
            self._representation = representation_std(self.grid)
        mean, _ = self.filter.estimate(self.state)
        step = None
        if self._last_ping_at is not None:
            step = float(np.hypot(*(obs.indicated - self._last_ping_at)))
        self._last_ping_at = np.asarray(obs.indicated, dtype=float)
        self._learn_roughness(obs, mean, step)
        extra = map_error_variance(self._representation, mean, obs.heading, obs.offsets)
        floor = self.roughness.variance
        declared = np.asarray(obs.noise_var, dtype=float)
        base = self._white_floored(declared)
        if not extra.any() and floor <= 0.0:
            return obs if base is declared else replace(obs, noise_var=base)
        # the innovations measure each beam's own variance: the share is fitted to the
        # layer as it is, and the beams that share one map error are counted once after
        self._ping_variances = (declared, extra)
        counted = correlated_share(obs.offsets, self.grid.cell_size, step)
        layer = counted * self._share.value * extra
        # the relief the map lacks is measured over a window of track: shared across it
        window = ROUGHNESS_WINDOW_CELLS * self.grid.cell_size
        lacked = correlated_share(obs.offsets, window, step) * floor
        noise_var = base + np.maximum(layer, lacked)
        # each beam's own scatter, before the count: what one ping's residuals show
        self._uncounted = (base + np.maximum(self._share.value * extra, floor)) / noise_var
        return replace(obs, noise_var=noise_var)

    def _white_floored(self, declared: np.ndarray) -> np.ndarray:
        """Each beam's declared variance, raised to the readings' white scatter if larger.

        The white part of the readings' departure beyond the map's along the track
        (:attr:`~geofix.filters.nuisance.ProfileRoughness.white`: independent from ping
        to ping, so no share of it is counted across pings) is a measured noise that does
        not depend on where the filter thinks it is. Where it exceeds
        :data:`~geofix.filters.nuisance.WHITE_EXCESS` times a beam's declared variance
        (map units squared), the declared noise is too small and the beam takes the white
        scatter instead: a single beam told 2 m against a 10' grid whose readings scatter
        by 9 m would otherwise weigh each ping twenty times too sharply, and one ping can
        then empty a particle set. The representation share is still fitted against the
        declared variance (``declared`` is returned unchanged, the same object, where no
        beam is raised), so where the floor acts the share takes up part of the same
        scatter and the two overlap: the wider of the readings measured on the real
        tracks, where the floor alone left claims beyond 3 sigma.
        """
        white = self.roughness.white
        raised = white > WHITE_EXCESS * declared
        if not raised.any():
            return declared
        return np.where(raised, white, declared)

    def _learn_roughness(self, obs: Observation, mean: np.ndarray, step: float | None) -> None:
        """Fold the ping into :attr:`roughness`: its mean reading and the map's at ``mean``.

        Both over the beams that read a value, the map at the footprints seen from the
        current estimate ``mean`` (metres); ``step`` the distance since the last ping.
        """
        predicted = predict_measurements(self.grid, mean[None], obs.heading, obs.offsets)[0]
        used = np.isfinite(obs.values) & np.isfinite(predicted)
        if not used.any():
            return
        with np.errstate(all="ignore"):  # a poisoned reading (1e308) is left out below
            measured = float(obs.values[used].mean())
        if self._value_range is None:
            self._value_range = _plausible_range(self.grid)
        low, high = self._value_range
        if not low <= measured <= high:
            return
        window = ROUGHNESS_WINDOW_CELLS * self.grid.cell_size
        self.roughness = self.roughness.updated(
            step, measured, float(predicted[used].mean()), window
        )

    def _gaussian_enough(self, cov: np.ndarray) -> bool:
        """Whether the position prior is narrow enough to measure the residual scale.

        Within two map cells (largest 1-sigma) its five unscented points predict a ping's
        spread, so its innovations measure the scale; a wider, often many-moded prior
        does not.
        """
        sigma = float(np.sqrt(max(float(np.linalg.eigvalsh(cov).max()), 0.0)))
        return sigma <= 2.0 * self.grid.cell_size


def _plausible_range(grid: Grid) -> tuple[float, float]:
    """Readings the relief along the track takes in: the map's range widened by itself.

    A reading beyond it (a poisoned or garbled value that the input checks let through)
    would otherwise raise the relief floor for a whole window.
    """
    values = np.asarray(grid.values, dtype=float)
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return (-np.inf, np.inf)
    low, high = float(finite.min()), float(finite.max())
    spread = max(high - low, 1.0)
    return (low - spread, high + spread)


__all__ = ["FilterSettings", "FilterStepper", "offset_per_hypothesis"]
