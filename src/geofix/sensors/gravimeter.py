"""Gravimeter dynamics: the first-order lag of a strongly damped sensor, and its inverse.

A damped gravimeter behaves as a first-order low-pass filter of time constant ``lag_s``.
Between samples ``t_{k-1}`` and ``t_k`` (input held over the interval) the exact discrete
filter is ``y_k = a_k y_{k-1} + (1 - a_k) x_k`` with ``a_k = exp(-(t_k - t_{k-1}) /
lag_s)``, started at ``y_0 = x_0``; :func:`compensate_first_order_lag` inverts it exactly.
"""

from __future__ import annotations

import numpy as np


def _lag_coefficients(times, lag_s: float) -> np.ndarray:
    dt = np.diff(np.asarray(times, dtype=float))
    if np.any(dt <= 0):
        raise ValueError("times must be strictly increasing")
    return np.exp(-dt / lag_s)


def apply_first_order_lag(values, times, lag_s: float) -> np.ndarray:
    """Pass a series through the gravimeter's first-order lag.

    Parameters
    ----------
    values : array_like
        ``(n,)`` or ``(n, b)`` input series (map units), sample axis first.
    times : array_like
        ``(n,)`` sample times, seconds, strictly increasing.
    lag_s : float
        Time constant, seconds; 0 returns a copy of ``values``.

    Returns
    -------
    numpy.ndarray
        The lagged series, same shape as ``values``.
    """
    x = np.array(values, dtype=float)
    if lag_s <= 0 or x.shape[0] < 2:
        return x
    a = _lag_coefficients(times, lag_s)
    y = np.empty_like(x)
    y[0] = x[0]
    for k in range(1, x.shape[0]):
        y[k] = a[k - 1] * y[k - 1] + (1.0 - a[k - 1]) * x[k]
    return y


def compensate_first_order_lag(values, times, lag_s: float) -> np.ndarray:
    """Undo :func:`apply_first_order_lag` exactly.

    ``x_k = (y_k - a_k y_{k-1}) / (1 - a_k)``, ``x_0 = y_0``. Noise added after the lag
    is amplified by up to ``(1 + a) / (1 - a)``; noise added before it is recovered as is.

    Parameters
    ----------
    values : array_like
        ``(n,)`` or ``(n, b)`` lagged series (map units), sample axis first.
    times : array_like
        ``(n,)`` sample times, seconds, strictly increasing.
    lag_s : float
        Time constant, seconds; 0 returns a copy of ``values``.

    Returns
    -------
    numpy.ndarray
        The input series that the lag turned into ``values``.
    """
    y = np.array(values, dtype=float)
    if lag_s <= 0 or y.shape[0] < 2:
        return y
    a = _lag_coefficients(times, lag_s).reshape((-1,) + (1,) * (y.ndim - 1))
    x = np.empty_like(y)
    x[0] = y[0]
    x[1:] = undo_lag_step(y[1:], y[:-1], a)
    return x


def undo_lag_step(lagged, previous, a):
    """One step of the exact inverse: ``x_k = (y_k - a y_{k-1}) / (1 - a)``.

    Parameters
    ----------
    lagged, previous : array_like
        ``y_k`` and ``y_{k-1}``, the lagged readings now and one sample before (map units).
    a : float or array_like
        ``exp(-(t_k - t_{k-1}) / lag_s)`` (dimensionless, broadcast against the readings).

    Returns
    -------
    numpy.ndarray
        The unlagged reading ``x_k``, map units.
    """
    return (lagged - a * previous) / (1.0 - a)
