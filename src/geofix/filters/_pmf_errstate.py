r"""The point-mass filter's error-state motion model (``pmf:model=errstate``).

The grid holds the (non-Gaussian) posterior of the position; a Kalman filter holds the
Gaussian ``N(mu, Sigma)`` of the whole INS error state ``x = [dp, x_l]`` of
:mod:`geofix.nav.errstate` (``dp`` = indicated - position). Between samples:

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

import numpy as np

_P = slice(0, 2)
_L = slice(2, None)


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
