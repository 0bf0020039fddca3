"""A lower bound that sees ambiguity: the MMSE of the initial offset, the drift given.

The posterior Cramér–Rao bound (:mod:`geofix.evaluate.crlb`) is local: it adds up the
map's gradients along the true track, and while the likelihood still has far modes (a
wide prior over self-similar terrain, the first pings of a 30 km error) it lies far below
what any estimator reaches. This module gives a bound that holds there.

**The genie-aided problem.** Give the estimator more than it has: the INS drift after the
start, ``d_k = e_k - e_0`` with ``e_k`` the trial's true position error at sample ``k``
(indicated minus true position), so that only the initial offset ``e_0`` is unknown.
Extra information cannot make the best estimator worse, so the genie's minimum
mean-square error at sample ``k``, ``E[trace Var(e_0 | y_0..k)]``, bounds the mean-square
position error of any estimator that holds the same prior. It is the exact Bayesian limit
of that easier problem, whatever the number of modes, and needs no Gaussian
approximation of the likelihood. The prior is, by default, the one the error-state CRLB
and the filters take (zero mean, the simulator's second moments: the position block of
the error state's prior; ``sigma_position[0]^2`` per axis without an INS model), so that
the two bounds and the filters share their prior information. With
``simulator_prior=True`` it is the very distribution the simulator draws ``e_0`` from
(``N(initial_error_m, initial_error_std_m^2)`` per axis): then the bound holds for any
estimator on these trials whatever prior it assumes, and is much lower where the
simulator draws a fixed bias that the filters' zero-mean prior does not know
(``source002_bank``: a 3 km spread about a 30 km bias against a 12.4 km prior sigma).

**Computation.** The posterior of ``e_0`` is two-dimensional: it is evaluated on a grid
over ``+-extent_sigmas`` prior sigmas along the prior's principal axes (at most
``max_nodes`` per axis), from every beam's Gaussian likelihood with the trial's per-beam
variance (sensor noise plus map error), the reading at hypothesis ``e`` being the map's
bilinear read (the simulator's, :data:`geofix.sim.sensing.TRUTH_READ`) at
``truth_k + e_0 - e`` (the unlagged readings of a lagged gravimeter: the lag is a known
invertible map, the information is the same). The grid is trusted while the posterior
spans many nodes (its standard deviation at least ``min_sd_nodes`` node steps along both
principal axes) and while it samples the likelihood finely enough: each mode of the
posterior is about as wide as the likelihood at the truth, ``w_k = lambda_max(J_0..k)^-1/2``
with ``J`` the Fisher information of the readings so far (the CRLB's, without the prior),
and a Gaussian mode of standard deviation ``w`` sampled at nodes ``h`` apart carries the
mass of its integral to within ``2 exp(-2 pi^2 w^2 / h^2)`` (Poisson summation: 1.4 % at
``w = h / 2``, ``min_width_steps``). Below that the sampled posterior aliases -- its modes'
weights, so its mean, change with the node step (on ``source002_bank`` with the
filters' prior, 16 beams make the modes narrower than the nodes from the first ping) --
and it says nothing. From the first sample where either fails, :func:`genie_track`
reports NaN and stops (the posterior only narrows, and a narrow posterior is the CRLB's
domain).
Per trial it gives the posterior variance and the squared error of the posterior mean;
either, averaged over trials, estimates the genie's MMSE. The squared error is the one to
hold a filter's errors against: on the same trials both follow the same draws of the
start error, so their ratio is not blurred by those draws (in a weak-information phase
both errors are about the drawn offset itself).

:func:`track_bound` combines the two bounds sample by sample: the larger of the
error-state CRLB and the genie's MMSE, each averaged over trials (a trial whose posterior
the grid no longer resolves counting 0 for the genie).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from geofix.errors import ConfigError
from geofix.evaluate.crlb import trial_error_state, trial_information
from geofix.filters._grid_ops import grid_moments
from geofix.maps.grid import Grid
from geofix.measurement import node_grid_log_likelihood
from geofix.memory import cells_bytes, check_allocation


@dataclass(frozen=True)
class AmbiguityGrid:
    """Settings of the genie's grid.

    Parameters
    ----------
    extent_sigmas : float
        Half-width of the grid, prior standard deviations along each principal axis.
    max_nodes : int
        Most nodes per axis (odd).
    min_sd_nodes : float
        Least posterior standard deviation, in node steps along both principal axes, for
        the grid's variance to be reported.
    min_width_steps : float
        Least width of the likelihood at the truth (``lambda_max(J)^-1/2``, the
        information of the readings so far), in node steps, for the grid to be trusted:
        below it the sampled posterior aliases (see the module text).
    """

    extent_sigmas: float = 5.0
    max_nodes: int = 801
    min_sd_nodes: float = 4.0
    min_width_steps: float = 0.5

    def __post_init__(self) -> None:
        if not (np.isfinite(self.extent_sigmas) and self.extent_sigmas > 0):
            raise ConfigError(
                f"ambiguity grid: extent_sigmas must be > 0, got {self.extent_sigmas}"
            )
        if self.max_nodes < 3:
            raise ConfigError(f"ambiguity grid: max_nodes must be at least 3, got {self.max_nodes}")
        if not (np.isfinite(self.min_sd_nodes) and self.min_sd_nodes >= 0):
            raise ConfigError(f"ambiguity grid: min_sd_nodes must be >= 0, got {self.min_sd_nodes}")
        if not (np.isfinite(self.min_width_steps) and self.min_width_steps >= 0):
            raise ConfigError(
                f"ambiguity grid: min_width_steps must be >= 0, got {self.min_width_steps}"
            )


def initial_offset_prior(trial, simulator_prior: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """``(mean (2,), cov (2, 2))`` of the initial position error's prior, m and m^2.

    Zero mean and the error state's position prior (the simulator's second moments, the
    CRLB's and the filters' prior), or ``sigma_position[0]^2 I`` without an INS model;
    with ``simulator_prior``, ``N(initial_offset, initial_std^2 I)`` of the trial's INS
    error model (indicated minus true position at the start).
    """
    model = getattr(trial, "ins_model", None)
    if model is None:
        return np.zeros(2), float(trial.sigma_position[0]) ** 2 * np.eye(2)
    if simulator_prior:
        return np.asarray(model.initial_offset, float), float(model.initial_std) ** 2 * np.eye(2)
    es = trial_error_state(trial)
    return np.zeros(2), es.position_cov(es.prior_cov)


class GenieTrack(NamedTuple):
    """The genie's posterior at every sample of one trial (NaN once unresolved), m^2.

    Attributes
    ----------
    variance : numpy.ndarray
        ``(n,)`` ``trace Var(e_0 | y_0..k)``.
    squared_error : numpy.ndarray
        ``(n,)`` squared distance of the posterior mean from the true ``e_0``.
    """

    variance: np.ndarray
    squared_error: np.ndarray


def genie_track(
    trial,
    grid: Grid,
    beam_var,
    settings: AmbiguityGrid | None = None,
    simulator_prior: bool = False,
) -> GenieTrack:
    """The genie's posterior of the initial offset at every sample.

    Parameters
    ----------
    trial : Trial
        The mission: true track and headings, indicated track, beam offsets, readings
        (``unlagged_measured`` when present), INS error model.
    grid : Grid
        The map the readings were drawn from.
    beam_var : float or array_like
        Measurement variance per beam (sensor noise plus map error), field units squared.
    settings : AmbiguityGrid, optional
        The grid (defaults of :class:`AmbiguityGrid`).
    simulator_prior : bool
        Take the simulator's own distribution of the start error as the prior (see the
        module text) instead of the CRLB's.

    Returns
    -------
    GenieTrack
        Posterior variance and squared error, m^2; NaN from the first sample whose
        posterior the grid no longer resolves (all NaN when the start error is known).
    """
    settings = settings or AmbiguityGrid()
    variance = np.full(trial.truth.shape[0], np.nan)
    squared = variance.copy()
    mean, prior = initial_offset_prior(trial, simulator_prior)
    values, axes = np.linalg.eigh(prior)
    if not values.min() > 0:  # the start error is known: the genie knows everything
        return GenieTrack(variance, squared)
    sd = np.sqrt(values)
    half = max(settings.max_nodes // 2, 1)
    nodes = 2 * half + 1
    # the log-posterior, its weights and the likelihood of one sample, plus temporaries
    check_allocation(cells_bytes(nodes, nodes, copies=6), f"genie grid of {nodes} x {nodes} nodes")
    steps = np.maximum(settings.extent_sigmas * sd / half, 1e-9)
    u, v = (np.arange(-half, half + 1) * s for s in steps)
    # prior log-density over the nodes (principal coordinates about the prior's mean)
    log_post = -0.5 * ((u[:, None] / sd[0]) ** 2 + (v[None, :] / sd[1]) ** 2)
    readings = trial.unlagged_measured if trial.unlagged_measured is not None else trial.measured
    readings = np.asarray(readings, float)
    start_error = np.asarray(trial.indicated[0], float) - np.asarray(trial.truth[0], float)
    truth_offset = axes.T @ (start_error - mean)  # the true e_0 in the grid's coordinates
    var = np.broadcast_to(np.asarray(beam_var, float), (trial.offsets.shape[0],))
    resolvable = likelihood_width(trial, grid, var) >= settings.min_width_steps * steps.max()
    for k in range(trial.truth.shape[0]):
        if not resolvable[k]:
            break
        if np.isfinite(readings[k]).any():
            # node [i, j] is e_0 = mean + (u_i, v_j) along the prior's axes, at
            # truth_k + (true e_0) - e_0
            centre = np.asarray(trial.truth[k], float) + start_error - mean
            frame = (centre, -axes, u, v)
            ll, _ = node_grid_log_likelihood(
                grid, frame, float(trial.true_heading[k]), trial.offsets, readings[k], var, False
            )
            log_post = log_post + ll
        centre_uv, cov = _grid_moments(log_post, u, v)
        spread = np.sqrt(np.clip(np.linalg.eigvalsh(cov), 0.0, None))
        if spread.min() < settings.min_sd_nodes * steps.max():
            break
        variance[k] = float(np.trace(cov))
        squared[k] = float(np.sum((centre_uv - truth_offset) ** 2))
    return GenieTrack(variance, squared)


def _grid_moments(log_post: np.ndarray, u: np.ndarray, v: np.ndarray) -> tuple:
    """``(mean (2,), cov (2, 2))`` of the normalised grid density, grid coordinates."""
    mu_u, mu_v, c_uu, c_uv, c_vv = grid_moments(log_post, u, v)
    return np.array([mu_u, mu_v]), np.array([[c_uu, c_uv], [c_uv, c_vv]])


def likelihood_width(trial, grid: Grid, beam_var) -> np.ndarray:
    """``(n,)`` width of the likelihood of the readings ``0..k`` at the truth, metres.

    ``lambda_max(J_0 + ... + J_k)^-1/2`` with ``J`` the per-sample Fisher information of
    the initial offset given the drift (:func:`geofix.evaluate.crlb.trial_information`:
    map gradients at the true footprints, per-beam variance ``beam_var``); ``inf`` while
    no reading carries information.
    """
    info = np.cumsum(trial_information(trial, grid, beam_var), axis=0)
    largest = np.linalg.eigvalsh(0.5 * (info + np.swapaxes(info, 1, 2)))[:, -1]
    with np.errstate(divide="ignore"):
        return np.where(largest > 0, 1.0 / np.sqrt(np.maximum(largest, 0.0)), np.inf)


def track_bound(crlb_var, genie) -> np.ndarray:
    """Sample by sample, the larger of the CRLB and the genie's MMSE over trials, m^2.

    Parameters
    ----------
    crlb_var : array_like
        ``(trials, n)`` traces of the error-state CRLB at every sample.
    genie : array_like
        ``(trials, n)`` the genie's posterior variance or squared error
        (:class:`GenieTrack`; NaN where its grid no longer resolves the posterior).

    Returns
    -------
    numpy.ndarray
        ``(n,)`` the larger of the mean over trials of the CRLB and of the genie's, a
        trial whose grid no longer resolves its (narrow) posterior counting 0 there: the
        genie's mean is then an underestimate of its MMSE, so still a bound, m^2.
    """
    crlb_var = np.atleast_2d(np.asarray(crlb_var, float))
    genie = np.atleast_2d(np.asarray(genie, float))
    return np.maximum(crlb_var.mean(axis=0), np.nan_to_num(genie, nan=0.0).mean(axis=0))
