"""The Ziv–Zakai bound along the true track: a lower bound that sees ambiguity.

The posterior Cramér–Rao bound (:mod:`geofix.evaluate.crlb`) adds up the map's gradients
at the true footprints; while the likelihood still has far modes (a wide prior over
self-similar terrain, the first pings of a 30 km error) it lies far below what any
estimator reaches. The genie's exact posterior (:mod:`geofix.evaluate.ambiguity`) sees
those modes, but only while its grid samples every mode finely, which a multibeam
likelihood under a wide prior defeats from the first ping. The Ziv–Zakai bound (ZZB)
needs no such grid: it bounds the mean-square error through the error probability of
binary tests between pairs of positions, and a bound computed from *any* subset of the
pairs is still a bound, only a looser one. A coarse grid of shifts loses tightness, never
validity.

**The problem bounded.** As for the genie, the estimator is told the INS drift after the
start, so that only the initial offset ``e_0`` (indicated minus true position) is unknown;
extra information cannot make the best estimator worse, so a bound of this problem bounds
the position error of any estimator at every sample. ``e_0`` has a Gaussian prior of
covariance ``P`` (:func:`geofix.evaluate.ambiguity.initial_offset_prior`: the CRLB's and
the filters' second moments, or the simulator's own spread with ``simulator_prior``); the
readings are the map's bilinear read (the simulator's,
:data:`geofix.sim.sensing.TRUTH_READ`) plus white Gaussian noise of the per-beam variance
(sensor noise plus map error), the unlagged ones of a lagged gravimeter.

**The bound** (Bell, Steinberg, Ephraim & Van Trees 1997, the extended ZZB for a vector):
for a unit direction ``a``,

``a^T R a >= int_0^inf h/2 V{ max_{delta: a^T delta = h} A(delta) } dh``,

``A(delta) = int (p(theta) + p(theta + delta)) Pmin(theta, theta + delta) dtheta``, with
``Pmin`` the least error probability of deciding between the two offsets from the
readings (equal-cost test, prior weights ``p``) and ``V`` valley filling
(``V f(h) = max_{eta >= 0} f(h + eta)``). The trace is the sum over the prior's two
principal axes. For Gaussian noise the two hypotheses are Gaussian readings whose means
differ by ``d(delta)``, the noise-weighted distance between the map read at the true
footprints and at the footprints shifted by ``-delta``,
``d^2 = sum_k sum_beams (m(x_kb) - m(x_kb - delta))^2 / sigma_b^2``; taking ``d`` at the
trial's true footprints (the convention of the CRLB, which evaluates the map's gradients
there) and averaging the prior weights over ``theta`` in closed form gives

``A(delta) = 2 Q(sqrt(d(delta)^2 + delta^T P^-1 delta) / 2)``

(the prior acts as one more Gaussian reading; ``Q`` the normal tail). The pair
``(x, x - delta)`` and the pair ``(x + delta, x)`` both hold the truth, so the mean of
``A`` at ``delta`` and ``-delta`` is taken (the full integral over ``theta`` is symmetric).
On a plane ``d^2 = delta^T J delta`` and the bound is the Kalman covariance
``(P^-1 + J)^-1`` exactly; on a comb of ridges it keeps the modes' spread that the CRLB
does not see.

**Which prior.** With the simulator's own spread of the start error the bound holds for
any estimator on the trials; where the simulator starts every trial at one fixed offset
that spread is 0 and so is the bound (an estimator told the offset would be exact), and
only the CRLB is left. With the CRLB's prior (zero mean, the simulator's second moments)
it is the limit of the Bayesian problem the filters solve, start errors drawn from that
prior; on fixed-offset trials a filter can lie below it.

**Computation.** ``d^2`` accumulates sample by sample on a ladder of square grids of
shifts along the prior's principal axes: an outer grid over ``+-extent_sigmas`` prior
sigmas (``outer_nodes`` per axis), then finer grids of ``inner_nodes`` per axis, each
``ratio`` times finer, down to a quarter of the narrowest likelihood width of the track
(:func:`geofix.evaluate.ambiguity.likelihood_width`). ``max_delta A`` at ``a^T delta = h``
is taken over the grid points of every level, the integral as a lower Riemann sum of the
non-increasing ``V`` (both only lower the bound). A shifted footprint off the map or on
no-data would read nothing where the sensor read a value: that pair is told apart
(``A = 0``, :data:`geofix.measurement.OFF_MAP_LOG_LIKELIHOOD` per beam). ``d^2`` only
grows, so a level's shifts outside the next finer level, once their ``A`` is below
``drop_below`` everywhere, are dropped for the rest of the track.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import erfc

from geofix.errors import ConfigError
from geofix.evaluate.ambiguity import initial_offset_prior, likelihood_width
from geofix.maps.grid import Grid
from geofix.measurement import node_grid_log_likelihood, predict_track
from geofix.memory import cells_bytes, check_allocation
from geofix.sim.sensing import TRUTH_READ


@dataclass(frozen=True)
class ShiftLadder:
    """The grids of shifts the bound is evaluated on.

    Parameters
    ----------
    extent_sigmas : float
        Half-width of the outer grid, prior standard deviations along each principal axis.
    outer_nodes : int
        Nodes per axis of the outer grid (odd).
    inner_nodes : int
        Nodes per axis of every finer grid (odd).
    ratio : float
        Step of one grid over the next finer one.
    max_levels : int
        Most grids, the outer one included.
    finest_width_fraction : float
        The finest step, as a fraction of the narrowest likelihood width of the track.
    drop_below : float
        A level's shifts outside the next finer level are dropped once their ``A`` is
        below this everywhere (it can only fall).
    """

    extent_sigmas: float = 5.0
    outer_nodes: int = 301
    inner_nodes: int = 41
    ratio: float = 4.0
    max_levels: int = 10
    finest_width_fraction: float = 0.25
    drop_below: float = 1e-9

    def __post_init__(self) -> None:
        checks = (
            ("extent_sigmas", self.extent_sigmas > 0),
            ("outer_nodes", self.outer_nodes >= 3),
            ("inner_nodes", self.inner_nodes >= 3),
            ("ratio", self.ratio > 1),
            ("max_levels", self.max_levels >= 1),
            ("finest_width_fraction", self.finest_width_fraction > 0),
            ("drop_below", self.drop_below >= 0),
        )
        for name, ok in checks:
            value = getattr(self, name)
            if not (np.isfinite(value) and ok):
                raise ConfigError(f"Ziv-Zakai shift ladder: {name} out of range, got {value}")


def ziv_zakai_integral(h, f) -> float:
    """``int_0^inf h/2 V{f}(h) dh`` from samples, as a lower Riemann sum, ``h`` units^2.

    Parameters
    ----------
    h : array_like
        Shifts along one direction, ``>= 0`` (any order, repeats allowed).
    f : array_like
        ``max A`` at each shift, in ``[0, 1]``.

    Returns
    -------
    float
        The integral with ``V{f}(h) = max over sampled h' >= h of f(h')`` held on each
        interval at its right end and 0 beyond the largest shift: a lower bound of the
        integral of any ``f`` that passes through the samples.
    """
    h = np.asarray(h, float).ravel()
    f = np.asarray(f, float).ravel()
    order = np.argsort(h, kind="stable")
    h, f = h[order], f[order]
    filled = np.maximum.accumulate(f[::-1])[::-1]
    previous = np.concatenate([[0.0], h[:-1]])
    return float(np.sum(0.25 * (h**2 - previous**2) * filled))


def pair_term(d2: np.ndarray, u: np.ndarray, v: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """``A(delta) = 2 Q(sqrt(d^2 + delta^T P^-1 delta) / 2)``, symmetrised in ``delta``.

    Parameters
    ----------
    d2 : numpy.ndarray
        ``(N0, N1)`` noise-weighted squared distance of the readings at shift ``(u_i, v_j)``.
    u, v : numpy.ndarray
        Shifts along the prior's principal axes, symmetric about 0, metres.
    sd : numpy.ndarray
        ``(2,)`` prior standard deviations along those axes, metres.
    """
    rho2 = (u[:, None] / sd[0]) ** 2 + (v[None, :] / sd[1]) ** 2
    a = erfc(np.sqrt(d2 + rho2) / (2.0 * np.sqrt(2.0)))
    return 0.5 * (a + a[::-1, ::-1])


def zzb_track(
    trial,
    grid: Grid,
    beam_var,
    ladder: ShiftLadder | None = None,
    simulator_prior: bool = False,
) -> np.ndarray:
    """The Ziv–Zakai bound on the mean-square position error at every sample, m^2.

    Parameters
    ----------
    trial : Trial
        The mission: true track and headings, beam offsets, readings (which beams read
        at each sample), INS error model (the prior of the start error).
    grid : Grid
        The map the readings were drawn from.
    beam_var : float or array_like
        Measurement variance per beam (sensor noise plus map error), field units squared.
    ladder : ShiftLadder, optional
        The grids of shifts (defaults of :class:`ShiftLadder`).
    simulator_prior : bool
        Take the simulator's own spread of the start error as the prior (see
        :func:`geofix.evaluate.ambiguity.initial_offset_prior`).

    Returns
    -------
    numpy.ndarray
        ``(n,)`` lower bound on ``E|e_0_hat - e_0|^2`` after the readings ``0..k``, m^2
        (0 when the start error is known).
    """
    ladder = ladder or ShiftLadder()
    n = trial.truth.shape[0]
    _, prior = initial_offset_prior(trial, simulator_prior)
    values, axes = np.linalg.eigh(prior)
    if not values.min() > 0:
        return np.zeros(n)
    sd = np.sqrt(values)
    readings = trial.unlagged_measured if trial.unlagged_measured is not None else trial.measured
    truth = np.asarray(trial.truth, float)
    heading = np.asarray(trial.true_heading, float)
    clean = predict_track(grid, truth, heading, trial.offsets, method=TRUTH_READ)
    valid = np.isfinite(np.asarray(readings, float)) & np.isfinite(clean)
    var = np.broadcast_to(np.asarray(beam_var, float), (trial.offsets.shape[0],))
    width = float(np.min(likelihood_width(trial, grid, var)))
    levels = shift_levels(sd, width, ladder)
    d2 = [np.zeros((u.size, v.size)) for u, v in levels]
    alive = [True] * len(levels)
    out = np.empty(n)
    bound = float(np.sum(values))
    for k in range(n):
        if valid[k].any():
            y = np.where(valid[k], clean[k], np.nan)
            for i, (u, v) in enumerate(levels):
                if alive[i]:  # the finest level is never dropped
                    frame = (truth[k], -axes, u, v)
                    ll, _ = node_grid_log_likelihood(
                        grid, frame, heading[k], trial.offsets, y, var, False
                    )
                    d2[i] -= 2.0 * ll
            bound = _bound(levels, d2, alive, sd, ladder.drop_below)
        out[k] = bound
    return out


def shift_levels(sd: np.ndarray, width: float, ladder: ShiftLadder) -> list:
    """``[(u, v), ...]``: node coordinates of each grid of shifts, outer first, metres.

    Parameters
    ----------
    sd : numpy.ndarray
        ``(2,)`` prior standard deviations along its principal axes, metres.
    width : float
        The narrowest likelihood width, metres: the finest grid's step is
        ``ladder.finest_width_fraction`` of it.
    ladder : ShiftLadder
        The grids.
    """
    half = ladder.outer_nodes // 2
    inner = ladder.inner_nodes // 2
    check_allocation(
        cells_bytes(2 * half + 1, 2 * half + 1, copies=6),
        f"Ziv-Zakai shifts of {2 * half + 1} x {2 * half + 1} nodes",
    )
    steps = ladder.extent_sigmas * sd / half
    levels = [tuple(np.arange(-half, half + 1) * s for s in steps)]
    step = float(steps.max())
    finest = ladder.finest_width_fraction * width
    while len(levels) < ladder.max_levels and step > finest:
        step /= ladder.ratio
        nodes = np.arange(-inner, inner + 1) * step
        levels.append((nodes, nodes))
    return levels


def _bound(levels: list, d2: list, alive: list, sd: np.ndarray, drop_below: float) -> float:
    """The bound on the trace from the shifts of every live level (updates ``alive``)."""
    h: list[list] = [[], []]
    f: list[list] = [[], []]
    for i, (u, v) in enumerate(levels):
        if not alive[i]:
            continue
        a = pair_term(d2[i], u, v, sd)
        if i < len(levels) - 1:
            reach = levels[i + 1][0][-1]
            outside = (np.abs(u)[:, None] > reach) | (np.abs(v)[None, :] > reach)
            alive[i] = bool(a[outside].max(initial=0.0) >= drop_below)
        iu, iv = u.size // 2, v.size // 2
        h[0].append(u[iu:])
        f[0].append(a[iu:, :].max(axis=1))
        h[1].append(v[iv:])
        f[1].append(a[:, iv:].max(axis=0))
    return sum(ziv_zakai_integral(np.concatenate(h[j]), np.concatenate(f[j])) for j in (0, 1))


def bound_of_levels(levels: list, d2: list, sd: np.ndarray) -> float:
    """The bound on the trace from every grid of shifts and its final ``d^2``, m^2.

    Parameters
    ----------
    levels : list
        :func:`shift_levels`.
    d2 : list of numpy.ndarray
        ``(u.size, v.size)`` squared distance of the readings at each level's shifts.
    sd : numpy.ndarray
        ``(2,)`` prior standard deviations along the principal axes, metres.
    """
    return _bound(levels, d2, [True] * len(levels), sd, 0.0)


def combined_track_bound(crlb_var, zzb) -> np.ndarray:
    """Sample by sample, the mean over trials of the larger of the CRLB and the ZZB, m^2.

    Parameters
    ----------
    crlb_var : array_like
        ``(trials, n)`` traces of the error-state CRLB at every sample.
    zzb : array_like
        ``(trials, n)`` :func:`zzb_track` of the same trials.

    Returns
    -------
    numpy.ndarray
        ``(n,)`` ``mean over trials of max(CRLB, ZZB)``: each a lower bound of the trial's
        mean-square error, so their larger one is too, m^2.
    """
    crlb_var = np.atleast_2d(np.asarray(crlb_var, float))
    zzb = np.atleast_2d(np.asarray(zzb, float))
    return np.maximum(crlb_var, zzb).mean(axis=0)
