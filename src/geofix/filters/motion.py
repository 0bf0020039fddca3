r"""Motion models of the point-mass filter: how the grid moves between two samples.

:class:`Pmf <geofix.filters.pmf.Pmf>` calls the motion model its ``model`` setting
selects (:data:`MOTION_MODELS`):

- ``rw``, :class:`RandomWalk`: the INS error as a white random walk of per-axis variance
  ``Motion.process_var``. The grid follows the posterior (regridded when it is off the
  ideal frame), the log-density is convolved with the isotropic motion kernel and the
  grid moves by the INS displacement;
- ``errstate``, :class:`InsErrorState`: the INS error state of :mod:`geofix.nav.errstate`,
  with an aiding DVL's velocity folded in.

**The error-state model.** The grid holds the (non-Gaussian) posterior of the position; a
Kalman filter holds the Gaussian ``N(mu, Sigma)`` of the whole INS error state
``x = [dp, x_l]`` of :mod:`geofix.nav.errstate` (``dp`` = indicated - position). Between
samples:

1. the Kalman filter takes the grid's posterior moments as the new marginal of ``dp``
   (:func:`replace_marginal`: the linear states move along their regression on ``dp``);
2. given ``dp``, the next ``dp`` is Gaussian, with a mean *affine* in ``dp``
   (``G dp + h``, :func:`conditional_motion`) and a covariance ``K`` shared by all
   nodes: the linear states marginalised with their conditional mean linear in ``dp``
   (exact when the posterior is Gaussian). The grid is carried through that affine map
   exactly (resampled onto a grid fitted to the moved posterior) and convolved with
   ``K``;
3. the Kalman filter predicts ``mu <- F mu``, ``Sigma <- F Sigma F^T + Q``.

With an aiding DVL, its velocity ``y = v_INS - v_DVL = C x + noise`` (``C`` the error
state's velocity map, noise variance ``r`` per axis) is, given ``dp``, Gaussian with mean
``C_p dp + C_l E[x_l | dp]`` (affine in ``dp``) and a covariance shared by all nodes: it
weighs the nodes by that likelihood and updates the Kalman filter (:func:`dvl_update`),
whose conditional of ``x_l`` given ``dp`` then holds the velocity's information for the
next step's regression.

Why this form rather than a PMF feeding a separate error-state filter that resets the
INS: the affine map carries the correlation between where the vehicle is and how fast
the INS drifts there, which a single correction applied to every node cannot; it costs
one grid interpolation per step.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from geofix.errors import ConfigError, MatchError
from geofix.filters import _grid_ops as ops
from geofix.filters.base import Motion, Observation
from geofix.measurement import predict_measurements
from geofix.nav.errstate import ErrorState, error_state, step_matrices, step_velocities
from geofix.problem import MatchProblem

if TYPE_CHECKING:
    from geofix.filters.pmf import Pmf, PmfState

_P = slice(0, 2)
_L = slice(2, None)

#: ``(normalised log-weights (N0, N1), centre (2,) m, spacing (2,) m, the model's own
#: PmfState fields by name)`` of a prior grid (its axes are x and y).
PriorGrid = tuple[np.ndarray, np.ndarray, np.ndarray, dict]


def _prior_grid_on_map(problem: MatchProblem, xy: np.ndarray) -> None:
    """Refuse (MatchError) a prior grid whose nodes all lie off the map."""
    if not np.isfinite(predict_measurements(problem.grid, xy, 0.0, np.zeros((1, 2)))).any():
        raise MatchError("pmf: the prior grid lies entirely off the map")


@dataclass(frozen=True, eq=False)
class ErrorStateTrack:
    """The error-state motion model's part of a point-mass state.

    Parameters
    ----------
    kf : tuple
        ``(mu (d,), Sigma (d, d))`` of the INS error state (Kalman filter).
    errstate : ErrorState
        The error model along the indicated track.
    indicated : numpy.ndarray
        ``(2,)`` indicated position at the current sample, metres.
    step : int
        Current sample index.
    dvl : numpy.ndarray or None
        ``(n, 2)`` ``v_INS - v_DVL`` at every sample, m/s, when a DVL aids.
    """

    kf: tuple[np.ndarray, np.ndarray]
    errstate: ErrorState
    indicated: np.ndarray
    step: int = 0
    dvl: np.ndarray | None = None


@dataclass(frozen=True)
class RandomWalk:
    """The INS error as a white random walk of per-axis variance ``Motion.process_var``."""

    #: The model needs no INS error model.
    needs_ins_model: ClassVar[bool] = False

    def prior(self, pmf: Pmf, problem: MatchProblem) -> PriorGrid:
        """Gaussian prior ``N(indicated[0], sigma_position[0]^2 I)`` on a square grid.

        Raises
        ------
        MatchError
            No node of the prior grid lies on valid map data.
        """
        cell = problem.grid.cell_size
        floor = pmf.min_spacing_cells * cell * (pmf.points - 1) / (2 * pmf.extent_sigmas)
        sigma = max(float(problem.sigma_position[0]), floor)
        centre = np.asarray(problem.indicated[0], dtype=float)
        spacing, shape = pmf.grid_layout(np.full(2, pmf.extent_sigmas * sigma), cell)
        xy = ops.node_positions(centre, np.eye(2), spacing, shape)
        _prior_grid_on_map(problem, xy)
        log_weight = ops.gaussian_log_density(xy, centre, sigma**2 * np.eye(2))
        return ops.normalise(log_weight), centre, spacing, {}

    def predict(self, pmf: Pmf, state: PmfState, motion: Motion) -> PmfState:
        """Follow the posterior with the grid, convolve with the motion kernel, shift.

        Parameters
        ----------
        pmf : Pmf
            The filter (its grid layout).
        state : PmfState
            The state after the last update.
        motion : Motion
            The INS motion of the step (displacement, m; duration, s; process variance, m^2).
        rng : numpy.random.Generator
            Random draws of the step.
        """
        state = self.follow(pmf, state, motion.process_var)
        sd = np.sqrt(motion.process_var)
        k0, k1 = (
            ops.motion_kernel(sd / h, n - 1)
            for h, n in zip(state.spacing, state.shape, strict=True)
        )
        kernels = (k0, k1)
        log_weight = ops.convolve_log(state.log_weight, kernels)
        centre = state.centre + np.asarray(motion.displacement, dtype=float)

        def mixed(offset):
            if offset is None:
                return None
            return offset.mixed(state.log_weight, kernels).after(motion)

        return replace(
            state,
            log_weight=log_weight,
            centre=centre,
            offset=mixed(state.offset),
            field_offsets=tuple(mixed(o) for o in state.field_offsets),
        )

    def follow(self, pmf: Pmf, state: PmfState, process_var: float) -> PmfState:
        """Move the log-density onto the ideal grid for the coming prediction if needed.

        Parameters
        ----------
        pmf : Pmf
            The filter (its grid layout: :meth:`~geofix.filters.pmf.Pmf.ideal_frame`).
        state : PmfState
            The posterior after the last update.
        process_var : float
            Per-axis variance of the coming prediction, m^2.
        """
        mean, cov = state.moments()
        frame, shape = pmf.ideal_frame(state, mean, cov + process_var * np.eye(2))
        if not pmf.off_frame(state, frame, shape):
            return state
        ops.check_regrid(shape)
        log_weight = ops.resample_grid(state.log_weight, state.frame, frame, (mean, cov), shape)

        def moved(offset):
            if offset is None:
                return None
            return offset.regridded(state.frame, frame, log_weight.shape)

        centre, axes, spacing = frame
        return replace(
            state,
            offset=moved(state.offset),
            field_offsets=tuple(moved(o) for o in state.field_offsets),
            log_weight=log_weight,
            centre=centre,
            axes=axes,
            spacing=spacing,
            regrids=state.regrids + 1,
        )

    def aid(self, state: PmfState, obs: Observation) -> PmfState:
        """No velocity state to aid: ``state`` unchanged."""
        return state


@dataclass(frozen=True)
class InsErrorState:
    """The INS error state of :mod:`geofix.nav.errstate`, a DVL's velocity folded in.

    Parameters
    ----------
    use_dvl : bool
        Fold in an aiding DVL's velocity when the problem has one.
    """

    #: The model needs the INS error model (``problem.ins_model``).
    needs_ins_model: ClassVar[bool] = True

    use_dvl: bool = True

    def prior(self, pmf: Pmf, problem: MatchProblem) -> PriorGrid:
        """The error state's position prior on a square grid, the Kalman filter at its prior.

        Raises
        ------
        MatchError
            The problem has no INS error model, or no node lies on valid map data.
        """
        model = problem.ins_model
        if model is None:
            raise MatchError("pmf: model=errstate needs the INS error model (problem.ins_model)")
        es = error_state(model, problem.times, problem.indicated)
        cell = problem.grid.cell_size
        floor = pmf.min_spacing_cells * cell * (pmf.points - 1) / (2 * pmf.extent_sigmas)
        sigma = es.prior_cov
        sigma[:2, :2] += floor**2 * np.eye(2)
        centre = np.asarray(problem.indicated[0], dtype=float)
        half = pmf.extent_sigmas * np.sqrt(np.diag(sigma[:2, :2]))
        spacing, shape = pmf.grid_layout(half, cell)
        xy = ops.node_positions(centre, np.eye(2), spacing, shape)
        _prior_grid_on_map(problem, xy)
        # position = indicated - dp: the position prior is N(indicated, Sigma_pp)
        log_weight = ops.gaussian_log_density(xy, centre, sigma[:2, :2])
        track = ErrorStateTrack(
            (np.zeros(es.dim), sigma), es, centre, dvl=self.dvl_innovations(problem, es)
        )
        return ops.normalise(log_weight), centre, spacing, {"track": track}

    def dvl_innovations(self, problem: MatchProblem, es: ErrorState) -> np.ndarray | None:
        """``v_INS - v_DVL`` ``(n, 2)`` m/s (``v_INS`` the indicated step velocity)."""
        dvl = problem.dvl_velocity
        if not self.use_dvl or dvl is None or es.velocity_map is None:
            return None
        return step_velocities(problem.times, problem.indicated) - np.asarray(dvl, float)

    def aid(self, state: PmfState, obs: Observation) -> PmfState:
        """The DVL's velocity at ``obs``'s sample, when it aids and is finite there."""
        track = state.track
        assert track is not None
        if track.dvl is not None and np.isfinite(track.dvl[obs.index]).all():
            return self.dvl_update(state, track.dvl[obs.index])
        return state

    def dvl_update(self, state: PmfState, y: np.ndarray) -> PmfState:
        """The DVL's velocity: node log-likelihoods and the Kalman update of the error state."""
        track = state.track
        assert track is not None and track.errstate.velocity_map is not None
        es = track.errstate
        dp = track.indicated - ops.node_positions(*state.frame, state.shape)
        log_like, kf = dvl_update(*track.kf, es.velocity_map, es.velocity_noise_var, y, dp)
        log_weight = ops.normalise(state.log_weight + log_like.reshape(state.shape))
        return replace(state, log_weight=log_weight, track=replace(track, kf=kf))

    def predict(self, pmf: Pmf, state: PmfState, motion: Motion) -> PmfState:
        """Carry the grid through the affine motion given ``dp``, convolve with ``K``.

        Parameters
        ----------
        pmf : Pmf
            The filter (its grid layout).
        state : PmfState
            The state after the last update.
        motion : Motion
            The INS motion of the step (displacement, m; duration, s; process variance, m^2).
        rng : numpy.random.Generator
            Random draws of the step.
        """
        track = state.track
        assert track is not None
        k = track.step
        mean, cov = state.moments()
        mu, sigma = replace_marginal(track.kf[0], track.kf[1], track.indicated - mean, cov)
        es, f, q = step_matrices(
            track.errstate, k, motion.displacement, motion.dt, motion.process_var
        )
        g, h, kernel = conditional_motion(mu, sigma, f, q)
        indicated = track.indicated + np.asarray(motion.displacement, dtype=float)
        shift = indicated - g @ track.indicated - h  # position' = G position + shift
        moved_mean = g @ mean + shift
        moved_cov = g @ cov @ g.T + kernel
        moved = replace(state, centre=g @ state.centre + shift, axes=g @ state.axes)
        (centre, axes, spacing), shape = pmf.ideal_frame(moved, moved_mean, moved_cov)
        ops.check_regrid(shape)
        g_inv = np.linalg.inv(g)
        pulled = (g_inv @ (centre - shift), g_inv @ axes, spacing)
        fallback = (mean, g_inv @ moved_cov @ g_inv.T)
        log_weight = ops.resample_grid(state.log_weight, state.frame, pulled, fallback, shape)
        along = np.einsum("ij,ik,kj->j", axes, kernel, axes)  # K along the new grid axes
        k0, k1 = (  # a kernel wider than the grid keeps its central taps
            ops.motion_kernel(np.sqrt(max(v, 0.0)) / s, n - 1)
            for v, s, n in zip(along, spacing, shape, strict=True)
        )
        kernels = (k0, k1)
        mu_next = f @ mu
        sigma_next = f @ sigma @ f.T + q

        def carried(offset):
            if offset is None:
                return None
            moved = offset.regridded(state.frame, pulled, shape)
            return moved.mixed(log_weight, kernels).after(motion)

        return replace(
            state,
            offset=carried(state.offset),
            field_offsets=tuple(carried(o) for o in state.field_offsets),
            log_weight=ops.convolve_log(log_weight, kernels),
            centre=centre,
            axes=axes,
            spacing=spacing,
            track=ErrorStateTrack(
                (mu_next, 0.5 * (sigma_next + sigma_next.T)), es, indicated, k + 1, track.dvl
            ),
            regrids=state.regrids + 1,
        )


#: The point-mass filter's motion models by their ``model`` setting.
MOTION_MODELS = {"rw": RandomWalk, "errstate": InsErrorState}


def check_motion_model(name: str, model: str) -> None:
    """Refuse (ConfigError) a ``model`` setting other than ``auto``, ``rw`` or ``errstate``."""
    if model not in MOTION_MODELS and model != "auto":
        raise ConfigError(f"{name}: model must be auto, rw or errstate, got {model!r}")


def takes_error_state(model: str, problem: MatchProblem) -> bool:
    """Whether a ``model`` setting runs on the INS error state for ``problem``.

    ``errstate``, or ``auto`` on a problem with an INS error model (``problem.ins_model``).
    """
    return model == "errstate" or (model == "auto" and problem.ins_model is not None)


def replace_marginal(mu, sigma, dp_mean, dp_cov):
    """``N(mu, Sigma)`` with the ``dp`` marginal replaced by ``N(dp_mean, dp_cov)``.

    Parameters
    ----------
    mu, sigma : numpy.ndarray
        ``(d,)`` mean and ``(d, d)`` covariance of the predicted error state.
    dp_mean, dp_cov : numpy.ndarray
        ``(2,)`` and ``(2, 2)`` new moments of ``dp``, metres and m^2.

    Returns
    -------
    tuple of numpy.ndarray
        The updated ``(mu, Sigma)``: ``x_l`` keeps its conditional given ``dp``.
    """
    s_pp = sigma[_P, _P]
    reg = np.linalg.solve(s_pp, sigma[_P, _L]).T  # (d_l, 2)
    cond = sigma[_L, _L] - reg @ sigma[_P, _L]
    mu = mu.copy()
    mu[_L] = mu[_L] + reg @ (dp_mean - mu[_P])
    mu[_P] = dp_mean
    out = np.empty_like(sigma)
    out[_P, _P] = dp_cov
    out[_L, _P] = reg @ dp_cov
    out[_P, _L] = out[_L, _P].T
    out[_L, _L] = cond + reg @ dp_cov @ reg.T
    return mu, 0.5 * (out + out.T)


def conditional_motion(mu, sigma, f, q):
    """``E[dp' | dp] = G dp + h`` and ``Cov[dp' | dp] = K`` over one step.

    Parameters
    ----------
    mu, sigma : numpy.ndarray
        ``(d,)``, ``(d, d)`` error state at the current sample.
    f, q : numpy.ndarray
        ``(d, d)`` transition and process noise of the step.

    Returns
    -------
    tuple of numpy.ndarray
        ``G`` ``(2, 2)``, ``h`` ``(2,)`` metres, ``K`` ``(2, 2)`` m^2.
    """
    reg = np.linalg.solve(sigma[_P, _P], sigma[_P, _L]).T
    cond = sigma[_L, _L] - reg @ sigma[_P, _L]
    a_p, a_l = f[_P, _P], f[_P, _L]
    g = a_p + a_l @ reg
    h = a_l @ (mu[_L] - reg @ mu[_P])
    k = a_l @ cond @ a_l.T + q[_P, _P]
    return g, h, 0.5 * (k + k.T)


def dvl_update(mu, sigma, velocity_map, noise_var: float, y, dp):
    """A DVL velocity ``y = C x + v``: node log-likelihoods and the Kalman update.

    Parameters
    ----------
    mu, sigma : numpy.ndarray
        ``(d,)``, ``(d, d)`` error state at the current sample.
    velocity_map : numpy.ndarray
        ``(2, d)`` ``C``, m/s per state unit.
    noise_var : float
        Per-axis variance of the DVL noise ``v``, m^2/s^2.
    y : numpy.ndarray
        ``(2,)`` ``v_INS - v_DVL``, m/s.
    dp : numpy.ndarray
        ``(..., 2)`` position error of every node (indicated - node), metres.

    Returns
    -------
    tuple
        ``log p(y | dp)`` ``(...)`` up to a constant, and the updated ``(mu, Sigma)``.
    """
    c = np.asarray(velocity_map, dtype=float)
    reg = np.linalg.solve(sigma[_P, _P], sigma[_P, _L]).T
    cond = sigma[_L, _L] - reg @ sigma[_P, _L]
    c_p, c_l = c[:, _P], c[:, _L]
    gain_dp = c_p + c_l @ reg  # d E[y | dp] / d dp
    offset = c_l @ (mu[_L] - reg @ mu[_P])
    s = c_l @ cond @ c_l.T + noise_var * np.eye(2)
    r = np.asarray(y, dtype=float) - (np.asarray(dp, dtype=float) @ gain_dp.T + offset)
    log_like = -0.5 * np.einsum("...i,ij,...j->...", r, np.linalg.inv(s), r)
    total = c @ sigma @ c.T + noise_var * np.eye(2)
    gain = np.linalg.solve(total, c @ sigma).T
    mu = mu + gain @ (np.asarray(y, dtype=float) - c @ mu)
    sigma = sigma - gain @ c @ sigma
    return log_like, (mu, 0.5 * (sigma + sigma.T))


__all__ = [
    "MOTION_MODELS",
    "ErrorStateTrack",
    "InsErrorState",
    "RandomWalk",
    "check_motion_model",
    "conditional_motion",
    "dvl_update",
    "replace_marginal",
    "takes_error_state",
]
