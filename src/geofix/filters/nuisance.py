r"""The measurement model's nuisance states: a common offset and the residual scale.

A prior map is not the seabed. Two of its departures matter to every filter whatever its
algorithm, and both are estimated here on line, beside the position, from the pings
themselves:

- :class:`CommonOffset` -- an offset common to every beam of a ping, measured minus map
  (a tide, a datum or sound-speed error, a gravimeter's offset and drift, the slowly
  varying part of a map error correlated over more than a swath). It is a random walk
  ``beta_k = beta_{k-1} + w``, ``Var w = walk * dt``, with a Gaussian prior. Each ping is
  weighed with its values taken relative to the offset's mean and its likelihood
  marginalised over the offset's variance ``P`` in closed form
  (:func:`geofix.measurement.common_bias_log_likelihood`), so a ping's shape tells the
  position whatever the offset; after the update the offset's posterior is taken at the
  five unscented points of the position posterior and moment-matched (its variance is the
  mean posterior variance plus the spread of the points' means), so an uncertain position
  on a slope leaves the offset uncertain too.
- :class:`ResidualScale` -- a factor ``s`` on the declared measurement variance, the
  residual scale, estimated from the innovations (Mehra 1972; Sage and Husa 1969): before
  each update the residuals ``r_b`` of the ping against the prediction at the five
  unscented points of the prior give ``u = sum_b (r_b^2 - S_b - P) / R_b`` over the ``n``
  beams (``S_b`` the predicted spread of beam ``b`` over the position posterior, ``P``
  the offset's variance, ``R_b`` the declared variance), whose expectation is
  ``s n`` when the map's departures add ``(s - 1) R_b``. ``s`` is the mean ``beta / alpha``
  of an inverse-gamma posterior with exponential forgetting (``alpha <- lambda alpha +
  n / 2``, ``beta <- lambda beta + max(u, 0) / 2``), floored at 1: a filter
  told too small a noise (a map coarser than the seabed, an offset, a correlated error)
  moves to the residuals it sees and reports the covariance they support; a filter told
  the right noise keeps it.

Both are immutable values; :class:`geofix.filters.loop.FilterStepper` carries them for
every filter with weighted points (the point-mass, particle and marginalised particle
filters), in a campaign trial as on line.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage

from geofix.errors import ConfigError
from geofix.maps.grid import Grid
from geofix.maps.offset import default_offset_std
from geofix.measurement import common_bias_posterior, predict_measurements
from geofix.memory import cells_bytes, check_allocation

if TYPE_CHECKING:  # annotations only: the filter loop below base.run_filter imports this
    from geofix.filters.base import Observation

#: The second, faster walk rate a gravity map's per-hypothesis offset weighs by default, as
#: a factor on the declared walk (:func:`default_fast_offset_walk`).
GRAVITY_FAST_OFFSET_WALK = 10.0
#: The same for a depth map's per-hypothesis offset on pings of three beams or more
#: (the default ``offset_per_hypothesis``): across a swath the error of a coarse map is relief below
#: its cells, which moves the swath's mean level from ping to ping.
SWATH_FAST_OFFSET_WALK = 10.0
#: The shortest length scale, metres along the track, of the smooth offset a gravity map's
#: per-hypothesis offset weighs beside its walks by default (:func:`default_offset_smooth`).
GRAVITY_OFFSET_SMOOTH_M = 2000.0
#: On a map coarser than half that, the default length in the map's cells.
SMOOTH_OFFSET_CELLS = 2.0


MAP_MODELS = ("exact", "adaptive", "imperfect")
"""What a filter's likelihood assumes of the prior map (its ``map_model`` setting).

``imperfect`` (the default of ``pmf``, ``pf`` and ``mpf``): the map's representation error
per beam at the share the innovations support, the noise scaled to the innovations, and a
common offset (measured minus map) estimated with the position, per hypothesis
(:mod:`geofix.filters.hypothesis_offset`; ``offset_per_hypothesis=false``: the
navigator's one :class:`CommonOffset`). ``adaptive``: the same without the
offset. ``exact``: the map is the seabed up to white noise per beam. The navigator's
settings per model: :meth:`geofix.filters.loop.FilterSettings.for_map_model`.
"""


def check_map_model(name: str, value: str) -> None:
    """Raise a ConfigError naming the filter unless ``value`` is one of :data:`MAP_MODELS`.

    Parameters
    ----------
    name : str
        The filter's name, for the message.
    value : str
        The ``map_model`` setting.
    """
    if value not in MAP_MODELS:
        raise ConfigError(f"{name}: map_model must be exact, adaptive or imperfect, got {value!r}")


def default_fast_offset_walk(grid: Grid, beams: int = 1) -> float:
    """The faster offset walk a filter weighs when its settings leave it open.

    A factor on the declared walk (:func:`geofix.filters.hypothesis_offset.walk_factors`)
    for the per-hypothesis offset.

    Parameters
    ----------
    grid : Grid
        The prior map: its kind.
    beams : int
        Beams of the ping (1: a profile).

    Returns
    -------
    float
        A gravity map: :data:`GRAVITY_FAST_OFFSET_WALK`. A gravity map's error is smooth
        over kilometres (an altimetry grid's), so along a track it reads as an offset
        moving faster than a gravimeter drifts, and the field is smooth enough that the
        position is read from how the readings change rather than their level. A depth
        map: for pings of three beams or more :data:`SWATH_FAST_OFFSET_WALK` (a swath's
        shape tells the position, and its mean level follows the relief below the map's
        cells from ping to ping), for fewer 0 (the declared rate alone): a profile's error
        is mostly relief below the map's cells (:class:`ProfileRoughness`), which a
        faster offset would absorb with the relief that tells positions apart. A magnetic
        map: 0, not yet measured on an imperfect magnetic map.
    """
    if grid.kind == "gravity":
        return GRAVITY_FAST_OFFSET_WALK
    if grid.kind == "depth" and beams >= 3:
        return SWATH_FAST_OFFSET_WALK
    return 0.0


def default_offset_smooth(grid: Grid) -> float:
    """The smooth offset's length a filter weighs when its settings leave it open, metres.

    The per-hypothesis offset's ``offset_smooth_m`` when unset
    (:meth:`geofix.filters.hypothesis_offset.HypothesisOffset.with_smooth`).

    Parameters
    ----------
    grid : Grid
        The prior map: its kind.

    Returns
    -------
    float
        A gravity map: :data:`GRAVITY_OFFSET_SMOOTH_M`, or :data:`SMOOTH_OFFSET_CELLS`
        of its cells where that is longer. A gravity map's error is correlated over
        kilometres (an altimetry grid's, an interpolated gap's); read along a track it
        varies smoothly with the distance travelled, which independent walk steps read
        as a level that holds and a smooth (Matern-3/2) offset weighs as it is. On the
        section *Imperfect maps* and on held-out gravity maps 2 km removes the false
        fixes of errors correlated over 1-1.5 km and is within a few per cent of the
        walks alone where the error's length is 2.5 km or more. A length shorter than
        the error's is the one to avoid (the error then seems to forget itself, and
        stretches of track count as independent evidence), and a grid holds no error
        structure finer than its cells: on a coarse grid (a 10' global model) the
        length is the cells'. A depth map: 0
        (none): a single-beam profile against a coarse grid reads the relief below the
        grid's cells, which a smooth offset would absorb (on the real ship tracks it
        claimed ``converged`` beyond 3 sigma). A magnetic map: 0, not yet measured.
    """
    if grid.kind != "gravity":
        return 0.0
    return max(GRAVITY_OFFSET_SMOOTH_M, SMOOTH_OFFSET_CELLS * grid.cell_size)


def unscented_points(mean, cov) -> tuple[np.ndarray, np.ndarray]:
    """The five sigma points ``mean``, ``mean +- sqrt(3) L_i`` (``L L^T = cov``) and weights.

    Parameters
    ----------
    mean : array_like
        ``(2,)`` position, metres.
    cov : array_like
        ``(2, 2)`` covariance, m^2.

    Returns
    -------
    tuple of numpy.ndarray
        ``(5, 2)`` points (metres) and ``(5,)`` weights ``1/3, 1/6, 1/6, 1/6, 1/6``.
    """
    mean = np.asarray(mean, dtype=float)
    cov = np.asarray(cov, dtype=float)
    cov = 0.5 * (cov + cov.T) + 1e-9 * np.eye(2)
    try:
        chol = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        chol = np.sqrt(np.clip(np.diag(cov), 0.0, None)) * np.eye(2)
    spread = np.sqrt(3.0) * chol.T
    points = np.vstack([mean, mean + spread, mean - spread])
    return points, np.array([1 / 3, 1 / 6, 1 / 6, 1 / 6, 1 / 6])


@dataclass(frozen=True)
class PointReads:
    """A ping read from the unscented points of a position posterior.

    Parameters
    ----------
    predicted : numpy.ndarray
        ``(5, k)`` field each used beam reads from each point, map units.
    weights : numpy.ndarray
        ``(5,)`` the points' weights.
    values : numpy.ndarray
        ``(k,)`` the used beams' readings (relative to the offset's mean), map units.
    noise_var : numpy.ndarray
        ``(k,)`` the used beams' declared variance, map units squared.
    used : numpy.ndarray or None
        ``(b,)`` which of the ping's beams were used.
    """

    predicted: np.ndarray
    weights: np.ndarray
    values: np.ndarray
    noise_var: np.ndarray
    used: np.ndarray | None = None

    @property
    def beams(self) -> int:
        """Beams read (finite reading, on the map at every point)."""
        return int(self.values.size)


def read_at_points(grid: Grid, mean, cov, obs: Observation) -> PointReads | None:
    """The ping's beams read at the unscented points of ``N(mean, cov)``.

    Parameters
    ----------
    grid : Grid
        The prior map.
    mean, cov : array_like
        Position posterior ``(2,)`` metres and ``(2, 2)`` m^2.
    obs : Observation
        The ping.

    Returns
    -------
    PointReads or None
        None when no beam has a finite reading on the map at every point.
    """
    points, weights = unscented_points(mean, cov)
    predicted = predict_measurements(grid, points, obs.heading, obs.offsets)
    use = np.isfinite(obs.values) & np.isfinite(predicted).all(axis=0)
    if not use.any():
        return None
    noise = np.broadcast_to(np.asarray(obs.noise_var, dtype=float), obs.values.shape)
    return PointReads(predicted[:, use], weights, obs.values[use], noise[use], use)


@dataclass(frozen=True)
class CommonOffset:
    """A random-walk offset common to every beam, measured minus map (map units).

    Parameters
    ----------
    mean : float
        Posterior mean, map units.
    var : float
        Posterior variance, map units squared (0: no offset is modelled).
    walk : float
        Variance gained per second, map units squared per second.
    t : float or None
        Time of the last prediction, seconds (None: not yet predicted).
    """

    mean: float = 0.0
    var: float = 0.0
    walk: float = 1e-3
    t: float | None = None

    @classmethod
    def prior(cls, std: float, walk: float, t: float) -> CommonOffset:
        """``N(0, std^2)`` at time ``t`` with the walk rate.

        Parameters
        ----------
        std : float
            Prior 1-sigma, map units (0: no offset is modelled).
        walk : float
            Variance gained per second, map units squared per second.
        t : float
            Time of the prior, seconds.

        Returns
        -------
        CommonOffset
            The prior.

        Raises
        ------
        ConfigError
            ``std`` or ``walk`` not finite and >= 0.
        """
        for name, value in (("std", std), ("walk", walk)):
            if not (np.isfinite(value) and value >= 0):
                raise ConfigError(f"common offset: {name} must be finite and >= 0, got {value}")
        return cls(0.0, float(std) ** 2, float(walk), float(t))

    @property
    def active(self) -> bool:
        """An offset is modelled (its prior variance was positive)."""
        return self.var > 0

    @property
    def std(self) -> float:
        """Posterior 1-sigma, map units."""
        return float(np.sqrt(self.var))

    def predicted(self, t: float) -> CommonOffset:
        """The offset at time ``t`` (seconds): the variance grows by ``walk`` per second."""
        if not self.active:
            return self
        dt = 0.0 if self.t is None else max(float(t) - self.t, 0.0)
        return replace(self, var=self.var + self.walk * dt, t=float(t))

    def relative(self, obs: Observation) -> Observation:
        """``obs`` with its values relative to the offset's mean and its variance to marginalise.

        Parameters
        ----------
        obs : Observation
            The ping as read (map units).

        Returns
        -------
        Observation
            ``values - mean`` and ``bias_var = var`` (unchanged when inactive).
        """
        if not self.active:
            return obs
        return replace(obs, values=obs.values - self.mean, bias_var=self.var)

    def updated(self, reads: PointReads | None, bias_var: float) -> CommonOffset:
        """The offset's posterior after a ping, moment-matched over the unscented points.

        Parameters
        ----------
        reads : PointReads or None
            The ping read at the posterior's unscented points (values relative to the
            offset's mean); None leaves the offset as it is.
        bias_var : float
            The offset's variance the ping was weighed with, map units squared.

        Returns
        -------
        CommonOffset
            Mean ``mean + sum_i w_i d_i`` and variance ``v + sum_i w_i (d_i - dbar)^2``,
            ``d_i, v`` the offset's posterior given the ping at point ``i``
            (:func:`geofix.measurement.common_bias_posterior`).
        """
        if not self.active or reads is None:
            return self
        shifts = np.empty(reads.weights.size)
        var = bias_var
        for i in range(reads.weights.size):
            shifts[i], var = common_bias_posterior(
                reads.values - reads.predicted[i], reads.noise_var, bias_var
            )
        shift = float(reads.weights @ shifts)
        spread = float(reads.weights @ (shifts - shift) ** 2)
        return replace(self, mean=self.mean + shift, var=var + spread)


@dataclass(frozen=True)
class ResidualScale:
    """A factor on the declared measurement variance, estimated from the innovations.

    Parameters
    ----------
    alpha, beta : float
        Shape and scale of the inverse-gamma posterior of the factor (pseudo-counts of
        half-beams).
    forgetting : float
        ``lambda`` in ``(0, 1]``: the weight a ping keeps at the next one (memory of about
        ``1 / (1 - lambda)`` pings).
    floor : float
        Smallest factor reported.
    """

    alpha: float = 5.0
    beta: float = 5.0
    forgetting: float = 0.98
    floor: float = 1.0

    @classmethod
    def prior(cls, forgetting: float, pseudo_beams: float = 10.0) -> ResidualScale:
        """A factor of 1 worth ``pseudo_beams`` beams, forgetting ``forgetting`` per ping.

        Raises
        ------
        ConfigError
            ``forgetting`` outside ``(0, 1]`` or ``pseudo_beams`` not positive.
        """
        if not 0.0 < forgetting <= 1.0:
            raise ConfigError(f"residual scale: forgetting must be in (0, 1], got {forgetting}")
        if not pseudo_beams > 0:
            raise ConfigError(f"residual scale: pseudo_beams must be positive, got {pseudo_beams}")
        half = 0.5 * float(pseudo_beams)
        return cls(half, half, float(forgetting))

    @property
    def factor(self) -> float:
        """The factor on the declared variance, at least ``floor``."""
        return max(self.beta / self.alpha, self.floor)

    def scaled(self, obs: Observation) -> Observation:
        """``obs`` with its measurement variance times :attr:`factor`."""
        factor = self.factor
        if factor == 1.0:
            return obs
        return replace(obs, noise_var=np.asarray(obs.noise_var, dtype=float) * factor)

    def updated(self, reads: PointReads | None, bias_var: float) -> ResidualScale:
        """Fold in a ping's innovations (read before its update).

        Parameters
        ----------
        reads : PointReads or None
            The ping read at the prior's unscented points, with the declared (unscaled)
            variances; None leaves the scale as it is.
        bias_var : float
            Variance of the common offset the values are relative to, map units squared.

        Returns
        -------
        ResidualScale
            ``alpha <- l alpha + sum_b w_b / 2``, ``beta <- l beta + u / 2`` with
            ``u = sum_b w_b (r_b^2 - S_b - P) / R_b``: the squared innovations less
            what the position's and the offset's spread explain, in units of the
            declared variance (``sum_b w_b`` on average when it is right). Each beam
            counts by ``w_b = (s R_b / (s R_b + S_b + P))^2`` (``s`` the factor so
            far), the share of its innovation's variance the noise makes, and the ping
            forgets ``l = lambda^(sum_b w_b / n)`` (``n`` beams): a ping a wide
            posterior explains says little of the noise and leaves the factor as it
            was. (Counted at full weight, or with ``u`` clipped at zero per ping, such
            pings' large, noisy excess drove the factor tens of times too high.)
        """
        found = None if reads is None else _innovations(reads, bias_var)
        if reads is None or found is None:
            return self
        excess, explained = found
        declared = self.factor * reads.noise_var
        weight = (declared / (declared + explained)) ** 2
        total = float(np.sum(weight * excess / reads.noise_var))
        if not np.isfinite(total):
            return self
        counted = float(np.sum(weight))
        lam = self.forgetting ** (counted / reads.beams)  # forget as much as is learnt
        return replace(
            self,
            alpha=lam * self.alpha + 0.5 * counted,
            beta=lam * self.beta + 0.5 * total,
        )


def _innovations(reads: PointReads, bias_var: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Each used beam's squared innovation less what is explained, and what is explained.

    ``(r_b^2 - S_b - P, S_b + P)`` in map units squared: the excess less the position's
    spread (``S_b`` over the unscented points) and the common offset's variance ``P``. A
    ping of three beams or more is taken relative to its own mean first (predictions and
    readings alike, the squares times ``k / (k - 1)``): a common offset then drops out
    whatever it is, where ``P`` is only its prior spread (an offset not yet learnt, ``P``
    large, would otherwise explain away every excess). None when not all are finite.
    """
    predicted, values, bias = reads.predicted, reads.values, bias_var
    factor = 1.0
    if values.size >= 3:
        predicted = predicted - predicted.mean(axis=1, keepdims=True)
        values = values - values.mean()
        factor, bias = values.size / (values.size - 1.0), 0.0
    if not np.isfinite(predicted).all():
        return None
    yhat = reads.weights @ predicted
    spread = reads.weights @ (predicted - yhat) ** 2
    explained = spread + bias
    excess = factor * (values - yhat) ** 2 - explained
    return (excess, explained) if np.isfinite(excess).all() else None


#: Least share at which :class:`RepresentationShare` weighs a multibeam ping's innovations
#: (the prior's).
SHARE_WEIGHT_FLOOR = 1.0
#: Fewest beams of a ping whose innovations the share weighs at least at the floor.
SHARE_FLOOR_BEAMS = 3


@dataclass(frozen=True)
class RepresentationShare:
    """The share ``c`` of the representation-error layer the innovations support.

    The representation layer (:func:`representation_std`) says how much a map read
    between its nodes may miss where the seabed is rougher than the map; a map that *is*
    the seabed misses nothing, a map of block means about what the layer says. Each beam's
    variance is ``R_b + c Q_b`` (``R_b`` the declared variance, ``Q_b`` the layer's
    variance at the beam's footprint), and ``c`` is the weighted least-squares fit of
    the innovations' excess ``e_b = r_b^2 - S_b - P - R_b`` to ``c Q_b`` (weights
    ``1 / V_b^2``, ``V_b = R_b + c Q_b + S_b + P``: a beam whose innovation a wide
    posterior explains is a noisy measure of ``c``), with exponential forgetting and a prior of
    ``c = 1`` worth ``pseudo`` beams whose variance is all representation:
    ``num <- lambda num + sum Q_b e_b / V_b^2``, ``den <- lambda den + sum Q_b^2 / V_b^2``,
    ``c = num / den`` clipped to ``[0, ceiling]``. A filter starts as cautious as the layer
    and keeps the information a map that matches the seabed better gives. (The likelihood
    then counts the beams that share one map error once: ``c Q_b`` times
    :func:`correlated_share`.) The innovations' weights use the share so far, but for a
    ping of :data:`SHARE_FLOOR_BEAMS` beams or more never below
    :data:`SHARE_WEIGHT_FLOOR`: at a share near zero ``V_b`` is the sensor's variance
    alone, and the few multibeam pings that took it there (one ping of many beams can
    take it from 1 to near 0) would weigh thousands of times the rest for as long as the
    running sums remember them. A ping of one or two beams is not floored: floored, the
    single-beam Azores demo's filters (the map the seabed) ended farther off (``pmf``
    271.6 m against 257.7 m over 60 trials, NEES 6.11 against 5.16). A ping's sums are
    divided by the beams that share one map error across its swath (``counted``), as its
    likelihood counts them: its beams' excesses are not independent measures of ``c``.
    The per-beam excess is a noisy measure, so the share moves over tens of pings, not
    one.

    Parameters
    ----------
    num, den : float
        The running sums (dimensionless).
    forgetting : float
        ``lambda`` in ``(0, 1]``.
    ceiling : float
        Largest share reported.
    """

    num: float = 5.0
    den: float = 5.0
    forgetting: float = 0.98
    ceiling: float = 4.0

    @classmethod
    def prior(cls, forgetting: float, pseudo: float = 5.0) -> RepresentationShare:
        """``c = 1`` worth ``pseudo`` beams, forgetting ``forgetting`` per ping."""
        return cls(float(pseudo), float(pseudo), float(forgetting))

    @property
    def value(self) -> float:
        """The share ``c`` in ``[0, ceiling]``."""
        return float(np.clip(self.num / self.den, 0.0, self.ceiling)) if self.den > 0 else 1.0

    def updated(
        self,
        reads: PointReads | None,
        declared,
        extra,
        bias_var: float,
        counted: float = 1.0,
    ) -> RepresentationShare:
        """Fold in a ping's innovations (read before its update).

        Parameters
        ----------
        reads : PointReads or None
            The ping read at the prior's unscented points; None leaves the share.
        declared, extra : numpy.ndarray
            ``(b,)`` every beam's declared variance ``R_b`` and representation variance
            ``Q_b`` (before the share), map units squared.
        bias_var : float
            Variance of the common offset the values are relative to.
        counted : float
            Beams per independent map error across the ping (:func:`correlated_share`
            without the track's part; at least 1): the ping's sums are divided by it.
        """
        if reads is None or reads.used is None:
            return self
        found = _innovations(reads, bias_var)
        if found is None:
            return self
        excess, explained = found
        r = np.broadcast_to(np.asarray(declared, dtype=float), reads.used.shape)[reads.used]
        q = np.broadcast_to(np.asarray(extra, dtype=float), reads.used.shape)[reads.used]
        if not q.any():
            return self
        share = self.value
        if q.size >= SHARE_FLOOR_BEAMS:
            share = max(share, SHARE_WEIGHT_FLOOR)
        v2 = (r + share * q + explained) ** 2
        lam, per = self.forgetting, 1.0 / max(float(counted), 1.0)
        num = lam * self.num + per * float(np.sum(q * (excess - r) / v2))
        den = lam * self.den + per * float(np.sum(q * q / v2))
        if not (np.isfinite(num) and np.isfinite(den)):
            return self
        return replace(self, num=num, den=den)


#: Fewest beams of a ping whose map error is given shapes across its swath.
MIN_SWATH_BEAMS = 8
#: Added to the position's prior variance in the swath shapes' fit, m^2 (a collapsed
#: particle set would otherwise pin the shift at exactly zero).
POSITION_FLOOR_M2 = 1e-2


def swath_shapes(offsets, used=None) -> np.ndarray | None:
    """Orthonormal tilt and curvature across a ping's footprints, orthogonal to their mean.

    The footprints' coordinate ``a`` along their widest direction (the principal axis of
    the used offsets, pointed to positive first component so that a shape keeps its sign
    from ping to ping), scaled to ``[-1, 1]``; the shapes are ``a`` and ``a^2``
    orthogonalised (Gram-Schmidt) against the constant and each other, each of unit
    norm over the used beams.

    Parameters
    ----------
    offsets : array_like
        ``(b, 2)`` footprint offsets, metres.
    used : array_like of bool, optional
        ``(b,)`` the beams that count (default all).

    Returns
    -------
    numpy.ndarray or None
        ``(b, 2)`` the two shapes (0 on unused beams); None for fewer than
        :data:`MIN_SWATH_BEAMS` used beams or footprints that do not spread.
    """
    offsets = np.asarray(offsets, dtype=float).reshape(-1, 2)
    used = np.ones(offsets.shape[0], bool) if used is None else np.asarray(used, bool)
    if int(used.sum()) < MIN_SWATH_BEAMS:
        return None
    d = offsets[used] - offsets[used].mean(axis=0)
    axis = np.linalg.svd(d, full_matrices=False)[2][0]
    if axis[0] < 0 or (axis[0] == 0 and axis[1] < 0):
        axis = -axis
    a = d @ axis
    half = 0.5 * float(np.ptp(a))
    if not half > 0:
        return None
    a = (a - 0.5 * (a.max() + a.min())) / half
    ones = np.full(a.size, 1.0 / np.sqrt(a.size))
    shapes: list[np.ndarray] = []
    for raw in (a, a * a):
        v = raw - ones * (ones @ raw)
        for done in shapes:
            v = v - done * (done @ v)
        norm = float(np.linalg.norm(v))
        if not norm > 1e-9:
            return None
        shapes.append(v / norm)
    out = np.zeros((offsets.shape[0], 2))
    out[used] = np.stack(shapes, axis=1)
    return out


@dataclass(frozen=True)
class SwathModes:
    r"""The map error's tilt and curvature across a swath: their variance and persistence.

    A map error correlated over more than a swath (an old survey's gridding, a
    sound-speed error in the map's soundings) reads, across one multibeam ping, as an
    offset (:class:`CommonOffset`) plus a tilt and a curvature, and consecutive pings
    see nearly the same ones. Taken as white noise per beam, they pull the position
    along whatever slope mimics them, with the confidence of every beam of every ping
    (measured: end errors of 60-200 m at a reported 1-sigma under a metre on a 2 m, 300 m
    correlated error). Here their shapes ``u_k`` (:func:`swath_shapes`) are marginalised
    over in the likelihood, ``R + sum_k m_k s_k u_k u_k^T``, with

    - ``s_k`` the variance of the shape's coefficient ``t_k`` beyond what the noise
      explains, learnt from the innovations before each update (:meth:`updated`: the
      residual at the prior mean fitted with the constant, the shapes and the map's
      gradients): ``e_k = t_k^2 - N_k``, a running weighted mean with forgetting,
      floored at 0 (0 on a map that is the seabed, whose innovations are noise);
    - ``m_k = (1 + rho_k) / (1 - rho_k)`` the pings that see one such error, ``rho_k``
      the lag-one correlation of the coefficients of consecutive pings,
      ``mean(w t_n t_{n-1}) / (s_k + mean(w N_k))`` (at most
      :data:`MAX_PINGS_PER_ERROR` pings): each ping then carries ``1 / m_k`` of an
      error's information, as the representation error's along-track count does
      (:func:`correlated_share`). The correlation of the whole coefficient, noise
      included, is lower than the error's own where the noise dominates, and then
      ``s_k`` is small: the ratio to ``s_k`` alone multiplied a small, noisy ``s_k`` by
      up to 100 on a map that is the seabed.

    Parameters
    ----------
    excess, weight, lagged, noise : numpy.ndarray
        ``(2,)`` forgetting sums of ``w e``, ``w``, ``w t_n t_{n-1}`` and ``w N``
        (map units^2; ``w`` dimensionless).
    last : numpy.ndarray or None
        ``(2,)`` the previous learnt ping's coefficients, map units.
    last_index : int
        That ping's index (a lag is counted only between consecutive pings).
    forgetting : float
        ``lambda`` in ``(0, 1]`` per ping.
    """

    excess: np.ndarray
    weight: np.ndarray
    lagged: np.ndarray
    noise: np.ndarray
    last: np.ndarray | None = None
    last_index: int = -2
    forgetting: float = 0.98

    @classmethod
    def prior(cls, forgetting: float, pseudo: float = 5.0) -> SwathModes:
        """No shape error, worth ``pseudo`` pings, forgetting ``forgetting`` per ping."""
        zero = np.zeros(2)
        return cls(zero, np.full(2, float(pseudo)), zero, zero, None, -2, float(forgetting))

    @property
    def variance(self) -> np.ndarray:
        """``(2,)`` ``s_k``, the shapes' variance per ping, map units squared."""
        with np.errstate(divide="ignore", invalid="ignore"):
            value = np.where(self.weight > 0, self.excess / self.weight, 0.0)
        return np.clip(value, 0.0, None)

    @property
    def pings_per_error(self) -> np.ndarray:
        """``(2,)`` ``m_k``: consecutive pings that see one shape error (at least 1)."""
        var = self.variance
        total = self.weight * var + self.noise
        with np.errstate(divide="ignore", invalid="ignore"):
            rho = np.where(var > 0, self.lagged / total, 0.0)
        top = (MAX_PINGS_PER_ERROR - 1.0) / (MAX_PINGS_PER_ERROR + 1.0)
        rho = np.clip(np.nan_to_num(rho), 0.0, top)
        return (1.0 + rho) / (1.0 - rho)

    def columns(self, shapes: np.ndarray | None) -> np.ndarray | None:
        """``(b, 2)`` the likelihood's columns ``sqrt(m_k s_k) u_k`` (None when all 0)."""
        if shapes is None:
            return None
        scale = np.sqrt(self.pings_per_error * self.variance)
        if not scale.any():
            return None
        return shapes * scale

    def updated(
        self, residual, shapes, gradients, noise_var, index: int, position_cov=None
    ) -> SwathModes:
        """Fold in a ping's innovations (before its update).

        The residual at the prior mean is fitted by weighted least squares with the
        constant, the two shapes and the map's gradients at the beams times a shift of
        the position ``d``, with the prior ``d ~ N(0, P)`` (``P`` the position's prior
        covariance; a Bayesian regression), so that the shapes' coefficients ``t_k`` are
        what neither an offset nor a shift the filter allows explains. Their noise part
        ``N_k`` is the fit's variance of ``t_k``; where the terrain's gradients mimic a
        shape it is large and the ping counts little, ``w_k = ((U_k + s_k) / (N_k +
        s_k))^2`` (``U_k = 1 / u_k^T W u_k``, the shape's noise alone). Measured on the
        ``imperfect_depth`` benchmark: with the shift left free (no prior) the shapes'
        part that a shift mimics, the part that misleads, went unseen (the particle
        filter 6-8 m off at NEES 60-300 on a correlated map error); taken only as the
        spread of the prior's unscented points, a particle filter that had drifted 4 m
        on a map that is the seabed read its own error as the map's and drifted to 13 m.

        Parameters
        ----------
        residual : numpy.ndarray
            ``(k,)`` the used beams' readings less their prediction at the prior mean,
            map units.
        shapes : numpy.ndarray or None
            ``(k, 2)`` the used beams' shapes (:func:`swath_shapes`); None leaves the
            modes.
        gradients : numpy.ndarray or None
            ``(k, 2)`` the map's gradient at each used beam's footprint, map units per
            metre (None: no position term).
        noise_var : numpy.ndarray
            ``(k,)`` the used beams' variance as the likelihood takes it before the
            shapes (declared, scaled, with the representation error), map units squared.
        index : int
            The ping's index.
        position_cov : numpy.ndarray, optional
            ``(2, 2)`` the position's prior covariance, m^2 (None: the shift is free).
        """
        if shapes is None:
            return self
        residual = np.asarray(residual, dtype=float)
        weight = 1.0 / np.broadcast_to(np.asarray(noise_var, dtype=float), residual.shape)
        columns = [np.ones((residual.size, 1)), shapes]
        if gradients is not None:
            columns.append(np.asarray(gradients, dtype=float))
        x = np.concatenate(columns, axis=1)
        if not (np.isfinite(x).all() and np.isfinite(residual).all() and residual.size > 5):
            return self
        info = (x * weight[:, None]).T @ x
        if gradients is not None and position_cov is not None:  # the shift's prior
            prior = np.asarray(position_cov, dtype=float) + POSITION_FLOOR_M2 * np.eye(2)
            info[3:, 3:] += np.linalg.inv(prior)
        try:
            cov = np.linalg.inv(info)
        except np.linalg.LinAlgError:
            return self
        t = (cov @ ((x * weight[:, None]).T @ residual))[1:3]
        noise = np.diag(cov)[1:3]
        alone = 1.0 / ((shapes * shapes).T @ weight)
        if not (np.isfinite(t).all() and np.all(noise > 0)):
            return self
        var = self.variance
        w = ((alone + var) / (noise + var)) ** 2
        lam = self.forgetting
        lagged = lam * self.lagged
        if self.last is not None and index == self.last_index + 1:
            lagged = lagged + w * t * self.last
        return replace(
            self,
            excess=lam * self.excess + w * (t * t - noise),
            weight=lam * self.weight + w,
            lagged=lagged,
            noise=lam * self.noise + w * noise,
            last=t,
            last_index=int(index),
        )


#: Share of the 3 x 3 plane-fit residual that the map's representation error is taken to be:
#: a quadratic surface's bilinear interpolation error has 0.39 of the rms of that residual,
#: and relief below the cell adds to it. Measured on block means of the bundled real grids
#: (their error against the seabed over the layer), 0.5 left the layer 1.4-4.0 times too
#: small; at 1.2 the ratio is 0.6-0.96. The filters' representation share
#: (:class:`RepresentationShare`) takes it down where the innovations show less, slowly
#: on single-beam pings: on a map that is the seabed the default then pays for the caution
#: (the marginalised particle filter 2.7x its bound on a drifting single-beam mission).
REPRESENTATION_SHARE = 1.2


def representation_std(grid: Grid) -> Grid:
    """The map's representation error at its own resolution, per cell (map units).

    A map read between its nodes (bilinear) misses the field's curvature and the relief
    below its cell. Both scale with the field's departure from a plane at the scale of a
    cell, the rms residual ``rho`` of a least-squares plane fitted to each 3 x 3 block of
    cells; the layer is ``REPRESENTATION_SHARE * rho``. A plane reads exactly (0); a
    rough map at a coarse cell gets the most.

    Parameters
    ----------
    grid : Grid
        The prior map.

    Returns
    -------
    Grid
        The same geometry, per-cell standard deviation (the outer ring takes its inner
        neighbour's value; 0 next to no-data).
    """
    z = np.asarray(grid.values, dtype=float)
    check_allocation(cells_bytes(z.size, copies=6), "representation-error layer of the map")
    finite = np.isfinite(z)
    z = z - (float(np.mean(z[finite])) if finite.any() else 0.0)  # less cancellation below
    ones = np.ones((3, 3)) / 9.0
    u = np.array([[-1.0, 0.0, 1.0]] * 3) / 6.0  # sum u^2 over the block = 6
    mean = ndimage.correlate(z, ones, mode="nearest")
    slope_u = ndimage.correlate(z, u, mode="nearest")
    slope_v = ndimage.correlate(z, u.T, mode="nearest")
    mean_sq = ndimage.correlate(z * z, ones, mode="nearest")
    # residual variance of the plane fit: mean z^2 - a^2 - (2/3)(b^2 + c^2)
    resid = mean_sq - mean**2 - (2.0 / 3.0) * (slope_u**2 + slope_v**2)
    std = REPRESENTATION_SHARE * np.sqrt(np.clip(resid, 0.0, None))
    std = np.where(np.isfinite(std), std, 0.0)
    if min(std.shape) >= 3:  # the outer ring has no full block: its neighbour's value
        std[0], std[-1] = std[1], std[-2]
        std[:, 0], std[:, -1] = std[:, 1], std[:, -2]
    return grid.with_values(std)


#: Length of the along-track window over which :class:`ProfileRoughness` measures the relief
#: the readings show and the map lacks, in map cells. On three ship tracks against a 10'
#: global grid, 1, 2 and 4 cells caught 0.3-0.6, 0.5-0.7 and 0.6-0.8 of the map's rms error
#: at the true track; a wider window lets the map's own relief at the track into it.
ROUGHNESS_WINDOW_CELLS = 4.0
#: Fewest pings over a window for its relief to be measured.
MIN_ROUGHNESS_PINGS = 12
#: Most pings kept in the window (a vehicle at rest, or pinging far faster than it moves
#: across a cell, keeps the newest).
MAX_ROUGHNESS_PINGS = 512
#: Largest lag-one correlation of a window's departures taken in its variance's correction.
MAX_ROUGHNESS_RHO = 0.95
#: A window counts the relief its map lacks only where the map shows less than this share of
#: the readings' relief. A map that shows more (block means of the seabed, the seabed itself)
#: has its error described by its own layer (:func:`representation_std`); two samples of the
#: same relief differ by chance by tens of percent over a window, which would otherwise raise
#: a floor on a map that lacks nothing.
LACKING_SHARE = 0.5
#: A beam's declared variance is raised to the readings' white scatter beyond the map's
#: (:attr:`ProfileRoughness.white`) only where that scatter exceeds this many times it: on
#: a map that is the seabed the white part is the declared noise itself, up to its sampling
#: spread, and is left alone.
WHITE_EXCESS = 4.0
#: Weight kept per ping by :class:`ProfileRoughness`'s running sums.
ROUGHNESS_FORGETTING = 0.998


@dataclass(frozen=True)
class ProfileRoughness:
    """The relief the readings show along the track and the map does not: a map-error floor.

    A map gridded coarser than the seabed's relief, or smoothed, lacks the relief below
    its resolution, and its own layer (:func:`representation_std`, from the map's
    curvature) cannot see what was never in it. The readings can: over the last
    :data:`ROUGHNESS_WINDOW_CELLS` cells of track, the ping means' departure from a
    quadratic in along-track distance is the seabed's relief at scales below the window;
    the same departure of the map read at the estimate along the same pings is the map's.
    Each is taken without its white part (half the mean square of consecutive
    departures' differences: sensor noise, uncorrelated from ping to ping), and their
    difference ``V`` is the correlated relief the map lacks, counted where the map shows
    less than :data:`LACKING_SHARE` of it. A window still filling (from its first
    :data:`MIN_ROUGHNESS_PINGS` pings) gives a first ``V``: the relief below the track run
    so far, scaled to the window as a Brownian profile's grows (in proportion to the span)
    and weighed by its share of the window. A shift of the track changes
    which relief the map shows, not how much, so ``V`` does not depend on where the filter
    thinks it is; it is averaged over windows with forgetting, and the filters take each
    beam's map-error variance as at least ``V``.

    Parameters
    ----------
    distance, measured, mapped : numpy.ndarray
        ``(k,)`` the window's pings: along-track distance (metres), mean reading and the
        map's mean reading at the estimate over the same beams (map units).
    num, white_num, den : float
        Running sums of the windows' ``V`` and white parts (map units squared) and of
        their weights.
    forgetting : float
        Weight of the sums kept per ping, in ``(0, 1]``.
    """

    distance: np.ndarray
    measured: np.ndarray
    mapped: np.ndarray
    num: float = 0.0
    white_num: float = 0.0
    den: float = 0.0
    forgetting: float = ROUGHNESS_FORGETTING

    @classmethod
    def empty(cls, forgetting: float = ROUGHNESS_FORGETTING) -> ProfileRoughness:
        """No pings yet: a floor of 0."""
        none = np.empty(0)
        return cls(none, none, none, forgetting=float(forgetting))

    @property
    def variance(self) -> float:
        """The floor ``V`` under each beam's map-error variance, map units squared."""
        return max(self.num / self.den, 0.0) if self.den > 0 else 0.0

    @property
    def white(self) -> float:
        """The readings' white departure beyond the map's, per ping, map units squared."""
        return max(self.white_num / self.den, 0.0) if self.den > 0 else 0.0

    def updated(
        self, step_m: float | None, measured: float, mapped: float, window_m: float
    ) -> ProfileRoughness:
        """Add a ping and fold in its window's relief when the window is full.

        Parameters
        ----------
        step_m : float or None
            Distance along the track since the previous ping, metres (None: the first).
        measured, mapped : float
            The ping's mean reading and the map's mean at the estimate over the same
            beams, map units; a non-finite one leaves the state.
        window_m : float
            The window's length, metres.
        """
        if not (np.isfinite(measured) and np.isfinite(mapped)):
            return self
        step = float(step_m) if step_m is not None and np.isfinite(step_m) else 0.0
        last = float(self.distance[-1]) if self.distance.size else 0.0
        distance = np.append(self.distance, last + max(step, 0.0))[-MAX_ROUGHNESS_PINGS:]
        keep = distance >= distance[-1] - window_m
        state = replace(
            self,
            distance=distance[keep],
            measured=np.append(self.measured, measured)[-MAX_ROUGHNESS_PINGS:][keep],
            mapped=np.append(self.mapped, mapped)[-MAX_ROUGHNESS_PINGS:][keep],
        )
        span = float(state.distance[-1] - state.distance[0])
        if state.distance.size < MIN_ROUGHNESS_PINGS or span <= 0.0:
            return state
        s = (state.distance - state.distance.mean()) / max(span, 1e-9)
        seen, seen_white = _relief(s, state.measured)
        shown, shown_white = _relief(s, state.mapped)
        seen_relief, shown_relief = seen - seen_white, shown - shown_white
        lacked = seen_relief - shown_relief
        if seen_relief > 0.0 and shown_relief >= LACKING_SHARE * seen_relief:
            lacked = 0.0  # the map has the relief: its own layer describes its error
        white = seen_white - shown_white
        if not (np.isfinite(lacked) and np.isfinite(white)):
            return state
        # a window still filling holds the relief below its span: taken as growing in
        # proportion to the span up to the window's (a Brownian profile), at the weight
        # of its share of the window, so the first full windows soon outweigh it
        share = min(span / window_m, 1.0)
        lam = self.forgetting
        return replace(
            state,
            num=lam * self.num + lacked,
            white_num=lam * self.white_num + share * white,
            den=lam * self.den + share,
        )


def _relief(s: np.ndarray, values: np.ndarray) -> tuple[float, float]:
    """Variance of ``values``' departure from a quadratic in ``s``, and its white part.

    The variance is corrected for what the quadratic takes of correlated departures (an
    AR(1) of the residuals' lag-one correlation, at most :data:`MAX_ROUGHNESS_RHO`, and
    never more than half the window). The white part is half the mean square of
    consecutive departures' differences (what an error independent from one value to the
    next adds), map units squared.
    """
    design = np.column_stack([np.ones_like(s), s, s * s])
    coef, _, rank, _ = np.linalg.lstsq(design, values, rcond=None)
    resid = values - design @ coef
    square = float(resid @ resid)
    # a quadratic fitted to correlated departures takes more than its rank of their
    # variance: about rank (1 + rho) / (1 - rho) for a lag-one correlation rho
    rho = float(resid[1:] @ resid[:-1]) / square if square > 0 else 0.0
    rho = min(max(rho, 0.0), MAX_ROUGHNESS_RHO)
    taken = min(int(rank) * (1.0 + rho) / (1.0 - rho), 0.5 * values.size)
    total = square / max(values.size - taken, 1.0)
    return total, 0.5 * float(np.mean(np.diff(resid) ** 2))


#: Most pings that one map error is counted across (a vehicle at rest would otherwise
#: discount its readings without end). A ship's single beam against a 10' grid reads one
#: map cell about 40 times; a cap of 10 counted each map error 4 times over.
MAX_PINGS_PER_ERROR = 100.0


def correlated_share(offsets, cell: float, step_m: float | None = None) -> float:
    """Readings per independent map error: across a ping's footprints and along the track.

    The representation error is correlated over about a cell. The ``b`` footprints of a
    ping spanning ``extent`` metres see about ``n = 1 + extent / cell`` independent errors
    (at most ``b``); consecutive pings ``step_m`` apart see the same error about
    ``m = cell / step_m`` times (at least 1, at most :data:`MAX_PINGS_PER_ERROR`). Each
    beam's map-error variance is multiplied by ``m b / n`` so that the likelihood carries
    each map error's information once, not ``m b / n`` times (a diagonal approximation of
    the correlated covariance of the beams and the pings).

    Parameters
    ----------
    offsets : array_like
        ``(b, 2)`` footprint offsets, metres.
    cell : float
        The map's cell size, metres.
    step_m : float or None
        Distance moved since the previous ping, metres (None: pings counted alone).

    Returns
    -------
    float
        ``m b / n``, at least 1.
    """
    offsets = np.asarray(offsets, dtype=float)
    beams = offsets.shape[0]
    cell = max(float(cell), 1e-9)
    along = 1.0
    if step_m is not None and np.isfinite(step_m):
        along = float(np.clip(cell / max(float(step_m), 1e-9), 1.0, MAX_PINGS_PER_ERROR))
    if beams < 2:
        return along
    extent = float(np.ptp(offsets, axis=0).max())
    independent = min(1.0 + extent / cell, float(beams))
    return along * beams / independent


__all__ = [
    "GRAVITY_FAST_OFFSET_WALK",
    "GRAVITY_OFFSET_SMOOTH_M",
    "MAP_MODELS",
    "SHARE_FLOOR_BEAMS",
    "SHARE_WEIGHT_FLOOR",
    "SMOOTH_OFFSET_CELLS",
    "SWATH_FAST_OFFSET_WALK",
    "WHITE_EXCESS",
    "CommonOffset",
    "PointReads",
    "ProfileRoughness",
    "RepresentationShare",
    "ResidualScale",
    "SwathModes",
    "check_map_model",
    "correlated_share",
    "default_fast_offset_walk",
    "default_offset_smooth",
    "default_offset_std",
    "read_at_points",
    "representation_std",
    "swath_shapes",
    "unscented_points",
]
