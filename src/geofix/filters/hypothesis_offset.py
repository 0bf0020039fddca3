r"""A common offset carried by every hypothesis of a filter: Rao-Blackwellised.

Readings and prior map differ by an offset common to every beam of a ping (a tide, a datum
or sound-speed error, a gravimeter's offset and drift, the part of a map error correlated
over more than a swath): ``y = h(x) + beta 1 + e``. Given a hypothesised position path the
offset is linear and Gaussian, so each hypothesis (a point-mass node, a particle) carries
its own offset mean ``b_i`` -- the running, variance-weighted mean of its own residuals --
and the filter marginalises each ping over ``N(b_i, P)``
(:func:`geofix.measurement.common_bias_log_likelihood` on predictions shifted by ``b_i``).
A hypothesis on the true path sees residuals that agree with one offset; a wrong one
sees residuals that wander. One ping of a single beam tells the position nothing when
its offset is unknown, but the sequence does, as a terrain profile matched with its mean
removed does.

``P`` is common to the hypotheses: after a ping of ``n`` beams of variance ``v`` it is
``P / (1 + P sum 1/v)`` for every hypothesis that read them all, and it grows by
``walk * dt`` between pings (a random walk, so an offset that drifts is followed).

How fast the offset walks is not always known in advance: a tide or a gravimeter drifts
slowly, and a map error correlated over kilometres reads, along a track, as an offset that
moves many times faster. A filter given a second, faster rate (``fast_offset_walk``,
:func:`walk_factors`), and beside it a slower one (``slow_offset_walk``,
:data:`SLOW_OFFSET_WALK`), has each hypothesis carry one such filter per rate and each
rate's probability, multiplied at
every ping by the likelihood of its residuals under that rate: the hypothesis's
likelihood is the mixture over the rates (:meth:`HypothesisOffset.marginal`), the exact
Bayesian answer for a rate that is one of them and fixed along a hypothesis's path, with
:data:`WALK_RETURN` of the prior given back each ping so that a rate set aside can return.

A map error correlated over kilometres is smooth along the track, and a walk (whose steps
are independent) reads its slow wander as a level that stays: a filter given a length
(``offset_smooth_m``) weighs beside its walks a smooth offset, a Matern-3/2 process along
the distance travelled of that length scale whose stationary variance is the offset's
prior, carried per hypothesis as a level and its rate of change per metre
(:func:`matern_transition`); its likelihood and update are the level's, the rate
following through their covariance. On a gravity map the filters weigh one of 2 km by
default (:func:`geofix.filters.nuisance.default_offset_smooth`).

The hypotheses are moved, resampled, convolved and regridded by their filter; these
values follow them (:meth:`HypothesisOffset.take`, :meth:`HypothesisOffset.mixed`,
:meth:`HypothesisOffset.regridded`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import ndimage
from scipy.special import logsumexp

from geofix.errors import ConfigError
from geofix.filters._grid_ops import node_positions
from geofix.filters._weights import log_sum_exp_first
from geofix.filters.base import Motion, Observation
from geofix.filters.offset_sums import ResidualSums
from geofix.maps.grid import Grid
from geofix.measurement import predict_measurements
from geofix.memory import cells_bytes, check_allocation

#: How a filter's hypotheses weigh the offset's walk rates (its ``offset_rates`` setting):
#: ``own``, each by its own residuals; ``shared``, a still offset beside the declared and
#: fast walks, the steady two weighed by the posterior over every hypothesis; ``pooled``,
#: as ``shared`` and then every rate's probability pooled with the posterior's
#: (:data:`RATE_POOLING`).
OFFSET_RATES = ("own", "shared", "pooled")
#: With ``offset_rates=pooled``, the weight of the posterior's rate probabilities in each
#: hypothesis's (a geometric pool, ``log p_ik <- (1 - a) log p_ik + a log q_k``
#: normalised): 0 would leave each hypothesis its own rates, 1 make the rates the mission's.
RATE_POOLING = 0.5


def check_offset_rates(method: str, value: str) -> None:
    """Refuse an ``offset_rates`` setting that is not one of :data:`OFFSET_RATES`.

    Parameters
    ----------
    method : str
        The method's name, for the message.
    value : str
        The setting.
    """
    if value not in OFFSET_RATES:
        raise ConfigError(
            f"{method}: offset_rates must be one of {', '.join(OFFSET_RATES)}, got {value!r}"
        )


#: The slower walk rate a hypothesis weighs beside the declared one wherever it weighs a
#: faster one, as a factor on the declared walk (the filters' ``slow_offset_walk`` when
#: unset): with the default declared walk (1e-3 map units squared per second) 1e-5, about
#: 0.2 m or mGal in an hour, what a tide or a gravimeter drifts. The declared walk is
#: sized for a gravimeter drifting 2 mGal an hour, and an offset that stands still reads
#: almost as well under it; weighed beside it, the slow rate gives such an offset its
#: information back (the section *Imperfect maps*).
SLOW_OFFSET_WALK = 0.01


def walk_factors(fast: float, slow: float = 0.0) -> tuple[float, ...]:
    """The walk rates a hypothesis weighs, as factors on the declared walk.

    Parameters
    ----------
    fast : float
        A second, faster rate as a factor on the declared walk (0: the declared rate
        alone). A map error correlated over kilometres reads, along a track, as an offset
        that moves faster than a tide or a gravimeter drifts.
    slow : float
        A slower rate weighed beside the two when ``fast`` is above 0, as a factor on the
        declared walk below 1 (0: none; :data:`SLOW_OFFSET_WALK`).

    Returns
    -------
    tuple of float
        ``(1,)``, ``(1, fast)`` or ``(slow, 1, fast)``: the fastest last.
    """
    if not (np.isfinite(fast) and (fast == 0 or fast > 1)):
        raise ConfigError(f"fast_offset_walk must be 0 or a factor above 1, got {fast}")
    if not (np.isfinite(slow) and 0 <= slow < 1):
        raise ConfigError(f"slow_offset_walk must be 0 or a factor in (0, 1), got {slow}")
    if fast == 0:
        return (1.0,)
    return (1.0, float(fast)) if slow == 0 else (float(slow), 1.0, float(fast))


def check_offset_walk(method: str, walk: float | None) -> None:
    """Refuse a method's ``offset_walk`` that is not None, finite and >= 0.

    Parameters
    ----------
    method : str
        The method's name, for the message.
    walk : float or None
        Variance the common offset gains per second, map units squared per second.
    """
    if walk is not None and not (np.isfinite(walk) and walk >= 0):
        raise ConfigError(f"{method}: offset_walk must be finite and >= 0, got {walk}")


def check_offset_per_hypothesis(method: str, value) -> None:
    """Refuse an ``offset_per_hypothesis`` setting that is not None, True or False.

    Parameters
    ----------
    method : str
        The method's name, for the message.
    value : object
        The setting.
    """
    if value is not None and not isinstance(value, bool):
        raise ConfigError(
            f"{method}: offset_per_hypothesis must be true or false (unset: the default), "
            f"got {value!r}"
        )


def check_offset_smooth(method: str, value, rates: str = "own") -> None:
    """Refuse an ``offset_smooth_m`` setting that is not None or a finite length >= 0.

    Parameters
    ----------
    method : str
        The method's name, for the message.
    value : object
        The setting, metres.
    rates : str
        The method's ``offset_rates``: a smooth offset is weighed with ``own`` only.
    """
    if value is None:
        return
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{method}: offset_smooth_m must be a length in metres, got {value!r}")
    if not (np.isfinite(value) and value >= 0):
        raise ConfigError(f"{method}: offset_smooth_m must be finite and >= 0, got {value}")
    if value and rates != "own":
        raise ConfigError(f"{method}: offset_smooth_m needs offset_rates=own")


def matern_transition(scale: float, variance: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """A Matern-3/2 offset's transition and process noise over a step ``dt``.

    The state is the offset and its rate of change, ``x = (b, db/ds)``; the process is
    stationary with ``b`` of variance ``variance`` and correlation ``(1 + a) exp(-a)``,
    ``a = sqrt(3) |dt| / scale``. ``s`` is the distance travelled (metres) for a map
    error; the same in seconds would serve an offset that varies in time.

    Parameters
    ----------
    scale : float
        Length scale, in the unit of ``dt`` (> 0).
    variance : float
        Stationary variance of the offset, map units squared.
    dt : float
        Step, metres travelled (>= 0).

    Returns
    -------
    tuple of numpy.ndarray
        ``(F (2, 2), Q (2, 2))``: ``x <- F x``, ``P <- F P F' + Q``.
    """
    lam = np.sqrt(3.0) / scale
    decay = np.exp(-lam * dt)
    f = decay * np.array([[1.0 + lam * dt, dt], [-lam * lam * dt, 1.0 - lam * dt]])
    still = np.diag([variance, lam * lam * variance])
    return f, still - f @ still @ f.T


#: Share of each walk's prior probability a hypothesis gets back at every ping, so that a
#: walk it set aside can return where the map's error changes its character.
WALK_RETURN = 0.01


@dataclass(frozen=True)
class HypothesisOffset:
    """Each hypothesis's offset under each of a few walk rates, map units.

    A hypothesis carries one Kalman filter of its offset per walk rate and the
    probability of each rate given its own residuals (a multiple-model filter whose rate
    is fixed along a hypothesis's path, with :data:`WALK_RETURN` of the prior given back
    each ping). Its likelihood is the mixture over the rates.

    Parameters
    ----------
    means : numpy.ndarray
        ``(K, ...)`` offset mean of each rate and hypothesis (measured minus map), map
        units; ``...`` the shape of the filter's hypotheses (``(M,)`` particles,
        ``(N0, N1)`` nodes).
    variances : numpy.ndarray
        ``(K,)`` variance of every hypothesis's offset under each rate, map units squared.
    walks : numpy.ndarray
        ``(K,)`` variance each rate gains per second, map units squared per second.
    log_prob : numpy.ndarray
        ``(K, ...)`` log-probability of each rate for each hypothesis (summing to one
        over ``K``).
    stationary : float
        The offset's stationary variance, map units squared (inf: a random walk). Each
        rate is then a first-order Gauss-Markov process about zero that gains ``walk *
        dt`` over a short ``dt`` and never wanders beyond its prior: a fast rate follows a
        map error that comes and goes along the track without carrying the offset far
        from the level the readings and the map share.
    shared_steady : bool
        The steady rates' split is the posterior's (``offset_rates`` ``shared`` or
        ``pooled``: :meth:`shared`).
    pooling : float
        With ``offset_rates=pooled``, :data:`RATE_POOLING`; 0 otherwise.
    scales : numpy.ndarray or None
        ``(K,)`` each model's Matern-3/2 length scale along the track, metres (0: a
        walk), or None when every model walks. A smooth model's walk is 0 and its
        stationary variance :attr:`smooth_variance`.
    slopes : numpy.ndarray or None
        ``(K, ...)`` each hypothesis's rate of change of the offset under each model, map
        units per metre travelled (0 under a walk), with ``scales``.
    slope_cov : numpy.ndarray or None
        ``(K, 2)`` the covariance of level and rate and the rate's variance under each
        model (0 under a walk), with ``scales``.
    smooth_variance : float
        The smooth models' stationary variance, map units squared.
    """

    means: np.ndarray
    variances: np.ndarray
    walks: np.ndarray
    log_prob: np.ndarray
    stationary: float = float("inf")
    shared_steady: bool = False
    pooling: float = 0.0
    scales: np.ndarray | None = None
    slopes: np.ndarray | None = None
    slope_cov: np.ndarray | None = None
    smooth_variance: float = 0.0

    @classmethod
    def single(cls, mean, var: float, walk: float) -> HypothesisOffset:
        """One walk rate: each hypothesis's offset ``N(mean_i, var)``."""
        mean = np.asarray(mean, dtype=float)
        return cls(
            mean[None], np.array([float(var)]), np.array([float(walk)]), np.zeros((1, *mean.shape))
        )

    @classmethod
    def start(
        cls,
        shape,
        obs: Observation,
        fast: float | None = None,
        rates: str = "own",
        slow: float | None = None,
        smooth: float | None = None,
    ) -> HypothesisOffset | None:
        """The prior ``N(0, obs.bias_var)`` for every hypothesis, or None without one.

        Parameters
        ----------
        shape : int or tuple
            The hypotheses' shape.
        obs : Observation
            The first ping: ``bias_var`` the offset's prior variance, ``bias_walk`` its
            growth per second; None unless ``bias_per_hypothesis`` and ``bias_var > 0``.
        fast : float, optional
            A second, faster walk rate as a factor on ``bias_walk`` (the filter's
            ``fast_offset_walk``; :func:`walk_factors`), the two equally likely a priori;
            0, or a walk of 0: one rate; None: the ping's ``bias_fast_walk`` (the map
            kind's default). With two, each rate
            is a Gauss-Markov process whose stationary variance is ``bias_var``: a fast
            rate follows an error that comes and goes without carrying the offset far
            from the level the readings and the map share.
        rates : str
            ``own``, ``shared`` or ``pooled`` (:data:`OFFSET_RATES`): with ``shared`` and
            a faster rate, a still offset (walk 0) is weighed beside the others, all
            equally likely a priori, and the steady ones (all but the fastest) are
            weighed by the whole posterior (:meth:`shared`); ``pooled`` then pools every
            rate's probability with the posterior's (:data:`RATE_POOLING`).
        slow : float, optional
            A slower walk rate beside the declared one wherever a faster one is weighed,
            as a factor on ``bias_walk`` below 1 (the filter's ``slow_offset_walk``;
            :func:`walk_factors`); None: :data:`SLOW_OFFSET_WALK`; 0: none. The rates are
            equally likely a priori.
        smooth : float, optional
            A smooth offset's length scale along the track, metres (the filter's
            ``offset_smooth_m``; 0: none): a Matern-3/2 process of stationary variance
            ``bias_var`` weighed beside the walks, as likely a priori as each
            (:meth:`with_smooth`). None: the ping's ``bias_smooth_m`` (the map kind's
            default) with ``rates`` ``own``, none with ``shared`` or ``pooled``.
        """
        if not (obs.bias_per_hypothesis and obs.bias_var > 0):
            return None
        shape = (shape,) if np.ndim(shape) == 0 else tuple(shape)
        walk = float(obs.bias_walk)
        fast = obs.bias_fast_walk if fast is None else fast
        slow = SLOW_OFFSET_WALK if slow is None else slow
        if smooth is None:
            smooth = float(obs.bias_smooth_m) if rates == "own" else 0.0
        factors = np.asarray(walk_factors(fast, slow), dtype=float)
        k = 1 if walk <= 0 else factors.size
        factors = factors[:k]
        steady = rates in ("shared", "pooled") and k > 1
        if steady:
            factors, k = np.concatenate([[0.0], factors]), k + 1
        log_prior = np.full((k, *([1] * len(shape))), -np.log(k))
        walks = cls(
            np.zeros((k, *shape)),
            np.full(k, float(obs.bias_var)),
            walk * factors,
            np.broadcast_to(log_prior, (k, *shape)).copy(),
            float(obs.bias_var) if k > 1 else float("inf"),
            steady,
            RATE_POOLING if steady and rates == "pooled" else 0.0,
        )
        return walks.with_smooth(smooth, float(obs.bias_var)) if smooth > 0 else walks

    def with_smooth(self, scale: float, variance: float) -> HypothesisOffset:
        """These models and a smooth one (Matern-3/2, ``scale`` metres), at its prior.

        The smooth model starts at its stationary law (offset ``N(0, variance)``, rate
        per metre ``N(0, 3 variance / scale^2)``) and takes an equal share of the prior: every
        model's probability is scaled by ``K / (K + 1)``. It is weighed last, after the
        fastest walk, and only beside rates each hypothesis weighs by its own residuals
        (``offset_rates=own``: :meth:`shared` takes the last model for the fastest walk).

        Parameters
        ----------
        scale : float
            Length scale along the track, metres (> 0).
        variance : float
            Stationary variance of the offset, map units squared.
        """
        if self.shared_steady:
            raise ConfigError("a smooth offset is weighed with offset_rates=own only")
        k = self.models
        shape = self.means.shape[1:]
        zeros = np.zeros((1, *shape))
        log_prob = np.concatenate([self.log_prob + np.log(k / (k + 1.0)), zeros - np.log(k + 1.0)])
        scales = np.zeros(k) if self.scales is None else self.scales
        slopes = np.zeros_like(self.means) if self.slopes is None else self.slopes
        slope_cov = np.zeros((k, 2)) if self.slope_cov is None else self.slope_cov
        return replace(
            self,
            means=np.concatenate([self.means, zeros]),
            variances=np.append(self.variances, variance),
            walks=np.append(self.walks, 0.0),
            log_prob=log_prob,
            scales=np.append(scales, float(scale)),
            slopes=np.concatenate([slopes, zeros]),
            slope_cov=np.vstack([slope_cov, [0.0, 3.0 * variance / scale**2]]),
            smooth_variance=float(variance),
        )

    @property
    def models(self) -> int:
        """How many walk rates each hypothesis weighs."""
        return int(self.walks.size)

    @property
    def mean(self) -> np.ndarray:
        """Each hypothesis's offset mean over its rates, map units."""
        return np.sum(np.exp(self.log_prob) * self.means, axis=0)

    def after(self, motion: Motion) -> HypothesisOffset:
        """The offsets after an INS step (:meth:`predicted`).

        The walks move over its duration, a smooth offset over its length.
        """
        return self.predicted(motion.dt, float(np.hypot(*motion.displacement)))

    def predicted(self, dt: float, travelled: float = 0.0) -> HypothesisOffset:
        """The offsets ``dt`` seconds and ``travelled`` metres later.

        A random walk's variance grows by ``walk * dt``. With a finite
        :attr:`stationary` variance ``s`` each rate decays towards zero with the time
        constant ``2 s / walk``: ``b <- a b``, ``P <- a^2 P + s (1 - a^2)``, ``a = exp(-dt
        walk / (2 s))``. A smooth model moves over the distance ``travelled``
        (:func:`matern_transition`).
        """
        dt = max(float(dt), 0.0)
        if not np.isfinite(self.stationary):
            walked = replace(self, variances=self.variances + self.walks * dt)
        else:
            a = np.exp(-dt * self.walks / (2.0 * self.stationary))
            walked = replace(
                self,
                means=self.means * a.reshape(-1, *([1] * (self.means.ndim - 1))),
                variances=a * a * self.variances + self.stationary * (1.0 - a * a),
            )
        return walked._smoothed(max(float(travelled), 0.0))

    def _smoothed(self, dt: float) -> HypothesisOffset:
        """These offsets with each smooth model's moved over ``dt`` metres.

        A smooth model's walk is 0, so the walks' step above left it as it was.
        """
        scales, rates, rate_cov = self.scales, self.slopes, self.slope_cov
        if scales is None or rates is None or rate_cov is None:
            return self
        means, variances = self.means.copy(), self.variances.copy()
        slopes, slope_cov = rates.copy(), rate_cov.copy()
        for k in np.flatnonzero(scales > 0):
            f, q = matern_transition(float(scales[k]), self.smooth_variance, dt)
            b, r = self.means[k], rates[k]
            means[k] = f[0, 0] * b + f[0, 1] * r
            slopes[k] = f[1, 0] * b + f[1, 1] * r
            cross, rate_var = rate_cov[k]
            cov = np.array([[self.variances[k], cross], [cross, rate_var]])
            cov = f @ cov @ f.T + q
            variances[k] = cov[0, 0]
            slope_cov[k] = cov[0, 1], cov[1, 1]
        return replace(self, means=means, variances=variances, slopes=slopes, slope_cov=slope_cov)

    def take(self, index) -> HypothesisOffset:
        """The offsets of the hypotheses ``index`` (a resample's copies)."""
        slopes = None if self.slopes is None else self.slopes[:, index]
        return replace(
            self, means=self.means[:, index], log_prob=self.log_prob[:, index], slopes=slopes
        )

    def marginal(self, log_likelihood) -> np.ndarray:
        """A ping's log-likelihood of each hypothesis, marginalised over its rates.

        Parameters
        ----------
        log_likelihood : callable
            ``log_likelihood(var, mean)``: the ping's log-likelihoods (nats, the
            hypotheses' shape) marginalised over the offset ``N(mean_i, var)``.
        """
        if self.models == 1:
            return log_likelihood(float(self.variances[0]), self.means[0])
        each = np.stack(
            [log_likelihood(float(v), b) for v, b in zip(self.variances, self.means, strict=True)]
        )
        return log_sum_exp_first(each + self.log_prob)

    def moments(self, weights) -> tuple[float, float]:
        """Mean and variance of the offset over the posterior ``weights`` (summing to one).

        Returns
        -------
        tuple of float
            ``sum_i w_i sum_k p_ik b_ik`` and the mixture's variance about it (each
            rate's variance and the spread of the means), map units and squared.
        """
        w = np.asarray(weights, dtype=float).reshape(1, -1) * np.exp(self.log_prob).reshape(
            self.models, -1
        )
        b = self.means.reshape(self.models, -1)
        mean = float(np.sum(w * b))
        spread = float(np.sum(w * (b - mean) ** 2))
        return mean, float(np.sum(w.sum(axis=1) * self.variances)) + spread

    def updated(
        self, grid: Grid, positions, obs: Observation, predicted=None, sums=None
    ) -> HypothesisOffset:
        """Each hypothesis's offsets after the ping (a scalar Kalman step per rate).

        ``b_ik <- b_ik + P_k T_ik / (1 + P_k S_i)``, ``T_ik = sum (y - h_i - b_ik) / v``,
        ``S_i = sum 1 / v`` over the hypothesis's valid beams; ``P_k <- P_k / (1 + P_k S)``
        with ``S`` the most any hypothesis had (those that read the whole ping). Each
        rate's probability is multiplied by the ping's likelihood under it,
        ``exp(-(R_ik - P_k T_ik^2 / (1 + P_k S_i)) / 2) / sqrt(1 + P_k S_i)`` with
        ``R_ik = sum (y - h_i - b_ik)^2 / v``, and :data:`WALK_RETURN` of the prior is
        given back.

        Parameters
        ----------
        grid : Grid
            The prior map.
        positions : numpy.ndarray
            ``(..., 2)`` the hypotheses after the ping's weighting, metres, in the
            hypotheses' shape.
        obs : Observation
            The ping, with the variance it was weighed with.
        predicted : numpy.ndarray, optional
            ``(..., b)`` the ping's every beam read at ``positions``, map units, when the
            filter has them already (read here otherwise).
        sums : ResidualSums, optional
            The ping's residual sums of those reads when the filter has them already
            (its own shape columns are not used here).
        """
        positions = np.asarray(positions, dtype=float)
        count = int(np.prod(positions.shape[:-1]))
        beams = int(np.isfinite(obs.values).sum())
        check_allocation(cells_bytes(count * max(beams, 1), copies=4), "per-hypothesis offsets")
        use = np.isfinite(obs.values)
        if predicted is None:
            offsets = np.asarray(obs.offsets, dtype=float)[use]
            flat = positions.reshape(-1, 2)
            predicted = predict_measurements(grid, flat, obs.heading, offsets)
        else:
            predicted = np.asarray(predicted, dtype=float)[..., use]
        var = np.broadcast_to(np.asarray(obs.noise_var, dtype=float), obs.values.shape)[use]
        # each rate's residual sums from the hypothesis's own, read once for every rate
        if sums is None:
            sums = ResidualSums.of(predicted.reshape(count, -1), obs.values[use], var)
        b = self.means.reshape(self.models, count)
        s = sums.weight
        t = sums.linear - b * s
        p = self.variances.reshape(-1, 1)
        gain = 1.0 + p * s
        means = b + p * t / gain
        most = float(s.max()) if s.size else 0.0
        log_prob = self.log_prob.reshape(self.models, -1)
        if self.models > 1:
            square = sums.square - b * (2.0 * sums.linear - b * s)
            ll = -0.5 * (square - p * t * t / gain) - 0.5 * np.log(gain)
            log_prob = _returned(log_prob + ll, self._log_prior())
        shape = self.means.shape
        updated = replace(
            self,
            means=means.reshape(shape),
            variances=self.variances / (1.0 + self.variances * most),
            log_prob=log_prob.reshape(shape),
        )
        if self.slope_cov is None or self.slopes is None:
            return updated
        # the rate follows the level through their covariance: gain c / (1 + P S)
        cross, rate_var = self.slope_cov[:, 0], self.slope_cov[:, 1]
        slopes = self.slopes.reshape(self.models, count) + cross[:, None] * t / gain
        shrink = 1.0 + self.variances * most
        slope_cov = np.column_stack([cross / shrink, rate_var - cross * cross * most / shrink])
        return replace(updated, slopes=slopes.reshape(shape), slope_cov=slope_cov)

    def shared(self, log_weight) -> HypothesisOffset:
        """The steady rates' split made once, by the posterior over every hypothesis.

        With :attr:`shared_steady`, each hypothesis keeps its own probability of the fast
        (last) rate and of the steady ones together, and the split of the latter between
        the still offset and the declared walk becomes their posterior over all
        hypotheses: ``q_k = sum_i w_i p_ik / sum_i w_i (p_i0 + p_i1)``, ``k`` = 0, 1.
        With :attr:`pooling` ``a`` above 0 (``offset_rates=pooled``), every rate's
        probability is then pooled with the posterior's, ``log p_ik <- (1 - a) log p_ik
        + a log q_k`` normalised, ``q_k = sum_i w_i p_ik``: a hypothesis off the track
        weighs the fast rate partly as the posterior does instead of explaining its
        residuals by a map error it alone sees.

        Parameters
        ----------
        log_weight : numpy.ndarray
            The hypotheses' posterior log-weights after the ping, their shape.

        Returns
        -------
        HypothesisOffset
            Itself without :attr:`shared_steady`.
        """
        if not self.shared_steady:
            return self
        lp = self.log_prob.reshape(self.models, -1)
        weight = np.asarray(log_weight, dtype=float).reshape(-1)
        steady = log_sum_exp_first(lp[:-1])
        mass = weight + steady
        q = logsumexp(lp[:-1] - steady + mass, axis=1)
        q = q - logsumexp(q)
        log_prob = np.vstack([steady + q[:, None], lp[-1:]])
        if self.pooling > 0:
            log_prob = _pooled(log_prob, weight, self.pooling)
        return replace(self, log_prob=log_prob.reshape(self.log_prob.shape))

    def _log_prior(self) -> np.ndarray:
        """``(K, 1)`` the rates' prior log-probabilities (equal)."""
        return np.full((self.models, 1), -np.log(self.models))

    def mixed(self, log_weight: np.ndarray, kernels) -> HypothesisOffset:
        """The node offsets after the point-mass prediction's convolution.

        Each rate's mass at a node is the node's mass times the rate's probability; the
        rate's mean and probability where the mass arrives are moment-matched
        (:func:`mixed_offsets`).
        """
        moved = [
            _arrived(log_weight + lp, b, kernels)
            for lp, b in zip(self.log_prob, self.means, strict=True)
        ]
        means = np.stack([mean for mean, _ in moved])
        slopes = self.slopes
        if slopes is not None:
            slopes = np.stack(
                [
                    _arrived(log_weight + lp, r, kernels)[0]
                    for lp, r in zip(self.log_prob, slopes, strict=True)
                ]
            )
        if self.models == 1:
            return replace(self, means=means, slopes=slopes)
        # each rate's arrived mass on the scale of the nodes' own peak mass
        peak = np.max(log_weight)
        arrived = np.stack([mass * np.exp(top - peak) for _, (mass, top) in moved])
        total = arrived.sum(axis=0)
        ok = total > 1e-300
        log_prob = np.where(
            ok, np.log(np.maximum(arrived, 1e-300) / np.where(ok, total, 1.0)), self.log_prob
        )
        return replace(
            self, means=means, log_prob=log_prob - log_sum_exp_first(log_prob), slopes=slopes
        )

    def pooled(self, points, log_weight, width: float) -> HypothesisOffset:
        """Particle offsets averaged with their neighbours' (:func:`pooled_offsets`)."""
        if not width > 0:
            return self
        lp = self.log_prob.reshape(self.models, -1)
        means, log_prob = pooled_offsets(
            points, log_weight, self.means.reshape(self.models, -1), lp, width
        )
        slopes = self.slopes
        if slopes is not None:
            flat = slopes.reshape(self.models, -1)
            slopes = pooled_offsets(points, log_weight, flat, lp, width)[0].reshape(slopes.shape)
        return replace(
            self,
            means=means.reshape(self.means.shape),
            log_prob=log_prob.reshape(self.means.shape),
            slopes=slopes,
        )

    def regridded(self, old, new, shape) -> HypothesisOffset:
        """The node offsets moved from grid ``old`` onto ``new`` (:func:`regridded_offsets`)."""
        indices = _old_indices(old, new, shape, self.means.shape[1:])
        means = np.stack([_read_on(b, indices) for b in self.means])
        slopes = self.slopes
        if slopes is not None:
            slopes = np.stack([_read_on(r, indices) for r in slopes])
        if self.models == 1:
            return replace(self, means=means, log_prob=np.zeros_like(means), slopes=slopes)
        log_prob = np.stack([_read_on(lp, indices) for lp in self.log_prob])
        return replace(
            self, means=means, log_prob=log_prob - log_sum_exp_first(log_prob), slopes=slopes
        )


def shared_offsets(state):
    """A filter state with every hypothesis offset's steady rates shared (:meth:`shared`).

    Parameters
    ----------
    state
        A filter state with ``log_weight`` (the posterior after the ping), ``offset``
        and ``field_offsets``.
    """
    offset = state.offset
    fields = state.field_offsets
    if not (
        (offset is not None and offset.shared_steady)
        or any(o is not None and o.shared_steady for o in fields)
    ):
        return state
    log_weight = state.log_weight
    return replace(
        state,
        offset=None if offset is None else offset.shared(log_weight),
        field_offsets=tuple(None if o is None else o.shared(log_weight) for o in fields),
    )


def _pooled(log_prob: np.ndarray, log_weight: np.ndarray, pooling: float) -> np.ndarray:
    """Each hypothesis's rate log-probabilities pooled with the posterior's.

    ``log p_ik <- (1 - a) log p_ik + a log q_k``, normalised over ``k``, with
    ``q_k = sum_i w_i p_ik`` (``w`` the posterior weights).

    Parameters
    ----------
    log_prob : numpy.ndarray
        ``(K, m)`` every hypothesis's rate log-probabilities.
    log_weight : numpy.ndarray
        ``(m,)`` the hypotheses' posterior log-weights (normalised or not).
    pooling : float
        ``a`` in ``(0, 1]``.
    """
    q = logsumexp(log_prob + log_weight, axis=1)
    q = q - logsumexp(q)
    pooled = (1.0 - pooling) * log_prob + pooling * q[:, None]
    return pooled - log_sum_exp_first(pooled)


def _returned(log_prob: np.ndarray, log_prior: np.ndarray) -> np.ndarray:
    """``(K, N)`` normalised rate probabilities with :data:`WALK_RETURN` of the prior back."""
    post = log_prob - log_sum_exp_first(log_prob)
    return np.logaddexp(np.log1p(-WALK_RETURN) + post, np.log(WALK_RETURN) + log_prior)


def mixed_offsets(log_weight: np.ndarray, mean: np.ndarray, kernels) -> np.ndarray:
    """Node offsets after the point-mass prediction's convolution, moment-matched.

    The mass arriving at a node comes from its neighbours with the motion kernel's
    weights; its offset mean is the mass-weighted mean of theirs
    (``conv(p b) / conv(p)``). Where no mass arrives (below 1e-300 of the peak) the
    node keeps its own.

    Parameters
    ----------
    log_weight : numpy.ndarray
        ``(N0, N1)`` log-weights before the convolution.
    mean : numpy.ndarray
        ``(N0, N1)`` offset means before it, map units.
    kernels : tuple of numpy.ndarray
        The 1-D motion kernels along each grid axis.

    Returns
    -------
    numpy.ndarray
        ``(N0, N1)`` offset means after it.
    """
    return _arrived(log_weight, mean, kernels)[0]


def _arrived(log_weight: np.ndarray, mean: np.ndarray, kernels):
    """:func:`mixed_offsets` and the mass that arrives at each node.

    Returns
    -------
    tuple
        ``(means (N0, N1), (conv(p) (N0, N1), max of log_weight))``: the mass relative
        to ``exp`` of the peak log-weight.
    """
    top = np.max(log_weight)
    p = np.exp(log_weight - top)
    num, den = p * mean, p
    for axis, kernel in enumerate(kernels):
        num = ndimage.convolve1d(num, kernel, axis=axis, mode="constant")
        den = ndimage.convolve1d(den, kernel, axis=axis, mode="constant")
    arrived = den > 1e-300
    return np.where(arrived, num / np.where(arrived, den, 1.0), mean), (den, top)


def regridded_offsets(mean: np.ndarray, old, new, shape) -> np.ndarray:
    """Node offsets moved from grid ``old`` onto grid ``new`` by linear interpolation.

    Parameters
    ----------
    mean : numpy.ndarray
        ``(N0, N1)`` offset means on ``old``, map units.
    old, new : tuple
        ``(centre (2,), axes (2, 2), spacing (2,))`` of each grid, metres.
    shape : tuple
        ``(M0, M1)`` nodes of the new grid.

    Returns
    -------
    numpy.ndarray
        ``(M0, M1)`` offset means (a new node beyond the old grid takes its nearest
        old node's).
    """
    return _read_on(mean, _old_indices(old, new, shape, mean.shape))


def _old_indices(old, new, shape, old_shape) -> list[np.ndarray]:
    """``[rows, cols]``: the fractional indices on grid ``old`` of every node of ``new``."""
    centre, axes, spacing = new
    xy = node_positions(centre, axes, spacing, shape) - np.asarray(old[0], dtype=float)
    along = xy @ np.asarray(old[1], dtype=float)  # coordinates along the old axes
    n0, n1 = old_shape
    rows = along[..., 0] / old[2][0] + 0.5 * (n0 - 1)
    cols = along[..., 1] / old[2][1] + 0.5 * (n1 - 1)
    return [rows, cols]


def _read_on(values: np.ndarray, indices: list[np.ndarray]) -> np.ndarray:
    """``values`` on the old grid read at ``indices`` (:func:`_old_indices`), linearly."""
    return ndimage.map_coordinates(values, indices, order=1, mode="nearest")


__all__ = [
    "OFFSET_RATES",
    "RATE_POOLING",
    "SLOW_OFFSET_WALK",
    "WALK_RETURN",
    "HypothesisOffset",
    "check_offset_rates",
    "check_offset_smooth",
    "check_offset_walk",
    "matern_transition",
    "mixed_offsets",
    "regridded_offsets",
    "shared_offsets",
    "walk_factors",
]


def _cloud_in_cell(points: np.ndarray, width: float):
    """Bilinear (cloud-in-cell) weights of each point on a lattice of ``width`` metres.

    Only the lattice nodes some point touches are kept (numbered densely), so a few
    outlying points do not size a lattice over the whole span.

    Returns
    -------
    tuple
        ``(index (4, M) int, weight (4, M), nodes)``: the number of each of a point's
        four corner nodes, its bilinear weight there, and the count of nodes.
    """
    scaled = (points - points.min(axis=0)) / width
    base = np.floor(scaled).astype(np.int64)
    frac = scaled - base
    stride = int(base[:, 1].max()) + 2
    keys, weight = [], []
    for di in (0, 1):
        for dj in (0, 1):
            keys.append((base[:, 0] + di) * stride + base[:, 1] + dj)
            wi = frac[:, 0] if di else 1.0 - frac[:, 0]
            wj = frac[:, 1] if dj else 1.0 - frac[:, 1]
            weight.append(wi * wj)
    nodes, index = np.unique(np.stack(keys), return_inverse=True)
    return index.reshape(4, -1), np.stack(weight), int(nodes.size)


def pooled_offsets(points, log_weight, means, log_prob, width: float):
    """Each hypothesis's offsets averaged with its neighbours', moment-matched per rate.

    The particle filters' counterpart of the point-mass convolution's
    :func:`mixed_offsets`: mass ``w_j p_kj`` and mass times offset are spread onto a
    lattice of ``width`` metres by bilinear weights and read back the same way, so that
    ``b_ki = sum_j K_ij w_j p_kj b_kj / sum_j K_ij w_j p_kj`` with ``K`` the tent kernel
    (support two lattice cells per axis). A map error correlated over a cell or more is
    then estimated by every hypothesis there together, not by each path alone.

    Parameters
    ----------
    points : numpy.ndarray
        ``(M, 2)`` hypotheses, metres.
    log_weight : numpy.ndarray
        ``(M,)`` their log-weights.
    means, log_prob : numpy.ndarray
        ``(K, M)`` offsets (map units) and rate log-probabilities.
    width : float
        Lattice spacing, metres (> 0).

    Returns
    -------
    tuple of numpy.ndarray
        ``(means, log_prob)`` after pooling, ``(K, M)`` each.
    """
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    index, weight, cells = _cloud_in_cell(points, width)
    mass = np.exp(log_weight - np.max(log_weight))[None] * np.exp(log_prob)  # (K, M)
    out_means, arrived = np.empty_like(means), np.empty_like(means)
    flat_index = index.ravel()
    for k in range(means.shape[0]):
        num = np.bincount(flat_index, (weight * (mass[k] * means[k])).ravel(), cells)
        den = np.bincount(flat_index, (weight * mass[k]).ravel(), cells)
        got_num = np.sum(weight * num[index], axis=0)
        got_den = np.sum(weight * den[index], axis=0)
        ok = got_den > 1e-300
        out_means[k] = np.where(ok, got_num / np.where(ok, got_den, 1.0), means[k])
        arrived[k] = got_den
    if means.shape[0] == 1:
        return out_means, log_prob
    total = arrived.sum(axis=0)
    ok = total > 1e-300
    share = np.log(np.maximum(arrived, 1e-300) / np.where(ok, total, 1.0))
    new_prob = np.where(ok, share, log_prob)
    return out_means, new_prob - log_sum_exp_first(new_prob)
