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
