r"""The field beneath a prior map whose error is added to it: the map's posterior.

A prior map is the field plus an error, ``m = g + e``: a survey gridded, an altimetry
model, a chart. When the error ``e`` is a Gaussian random field correlated over a length
``L`` (standard deviation ``s``) and independent of the field, the map does not say
that the field is ``m`` up to an error independent of the map. Part of what the map shows
is its error: at the wavelengths where the error's power is comparable to the field's,
a feature of the map is as likely the error's as the field's. The field given the map is
Gaussian (a Wiener filter, per wavenumber ``f``):

    E[g | m](f) = m(f) P_g(f) / (P_g(f) + P_e(f)),
    Cov[g | m](f) = P_g(f) P_e(f) / (P_g(f) + P_e(f)),

with ``P_g`` and ``P_e`` the power spectra of the field and of the error. ``P_e`` is the
error's (the Gaussian covariance ``s^2 exp(-d^2 / (2 L^2))`` of
:func:`geofix.sim.seabed.gaussian_field`); ``P_g`` is read from the map itself, its
isotropic power less the error's (``E|m(f)|^2 = P_g + P_e``; empirical Bayes, no truth
needed). A vehicle that reads the field then predicts its readings with the posterior mean
and counts the posterior covariance between every two of them, not the error's own: the
posterior mean's gradient is the information the map really carries.

The spectra are taken over the map beside its mirror images (twice its size along each
axis, periodic without a jump at the edges), so the posterior covariance is that of a
periodic field on that grid; a covariance between points is read at their nearest nodes'
lag, which keeps every covariance matrix positive semi-definite.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from geofix.maps.grid import Grid
from geofix.memory import cells_bytes, check_allocation

__all__ = ["MapPosterior", "gaussian_error_power", "map_posterior", "radial_power"]


@dataclass(frozen=True, eq=False)
class MapPosterior:
    """The field beneath a prior map, given the map: mean and covariance.

    Parameters
    ----------
    mean : Grid
        ``E[g | m]`` on the prior map's grid (NaN where the map is NaN), map units.
    lag_covariance : numpy.ndarray
        ``(My, Mx)`` covariance of ``g - E[g | m]`` between two nodes ``(i, j)`` rows and
        columns apart, periodic over the padded grid, map units squared.
    """

    mean: Grid
    lag_covariance: np.ndarray

    @property
    def variance(self) -> float:
        """The posterior variance at a node, map units squared."""
        return float(self.lag_covariance[0, 0])

    def covariance(self, points) -> np.ndarray:
        """Posterior covariance between points, at their nearest nodes' lag.

        Parameters
        ----------
        points : array_like
            ``(k, 2)`` easting and northing, metres.

        Returns
        -------
        numpy.ndarray
            ``(k, k)`` covariance, map units squared.
        """
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        k = points.shape[0]
        check_allocation(
            cells_bytes(k, k, copies=3), f"the map posterior's covariance of {k} points"
        )
        col = np.rint((points[:, 0] - self.mean.x0) / self.mean.dx).astype(np.int64)
        row = np.rint((points[:, 1] - self.mean.y0) / self.mean.dy).astype(np.int64)
        my, mx = self.lag_covariance.shape
        return self.lag_covariance[
            (row[:, None] - row[None, :]) % my, (col[:, None] - col[None, :]) % mx
        ]


def gaussian_error_power(shape: tuple[int, int], dx: float, dy: float, rms: float, corr_m: float):
    """Expected periodogram ``|FFT(e)|^2 / N`` of a Gaussian-covariance error on a grid.

    Parameters
    ----------
    shape : (int, int)
        ``(ny, nx)`` nodes.
    dx, dy : float
        Node spacing, metres.
    rms : float
        The error's standard deviation, map units.
    corr_m : float
        Its correlation length ``L`` (covariance ``rms^2 exp(-d^2 / (2 L^2))``), metres.

    Returns
    -------
    numpy.ndarray
        ``(ny, nx)`` power per wavenumber of :func:`numpy.fft.fft2`'s layout, its mean
        ``rms^2`` (the variance, by Parseval).
    """
    fy = np.fft.fftfreq(shape[0], dy)[:, None]
    fx = np.fft.fftfreq(shape[1], dx)[None, :]
    shape_of = np.exp(-2.0 * math.pi**2 * (fx**2 + fy**2) * corr_m**2)
    return rms**2 * shape_of / shape_of.mean()


def radial_power(values: np.ndarray, dx: float, dy: float, bins: int = 256) -> np.ndarray:
    """A field's periodogram averaged over rings of equal wavenumber.

    Parameters
    ----------
    values : numpy.ndarray
        ``(ny, nx)`` field, finite, mean removed.
    dx, dy : float
        Node spacing, metres.
    bins : int
        Rings between wavenumber 0 and the largest.

    Returns
    -------
    numpy.ndarray
        ``(ny, nx)`` the ring's mean of ``|FFT(values)|^2 / N`` at every wavenumber.
    """
    ny, nx = values.shape
    power = np.abs(np.fft.fft2(values)) ** 2 / values.size
    radius = np.hypot(np.fft.fftfreq(nx, dx)[None, :], np.fft.fftfreq(ny, dy)[:, None])
    ring = np.minimum((radius / radius.max() * bins).astype(np.int64), bins - 1)
    total = np.bincount(ring.ravel(), power.ravel(), minlength=bins)
    count = np.bincount(ring.ravel(), minlength=bins)
    return (total / np.maximum(count, 1))[ring]


def map_posterior(prior: Grid, error_rms: float, error_corr_m: float) -> MapPosterior:
    """The field beneath ``prior`` given it, its error Gaussian-correlated and added.

    Parameters
    ----------
    prior : Grid
        The prior map (NaN cells are taken at the map's mean for the spectra and stay
        NaN in the mean).
    error_rms : float
        The map error's standard deviation, map units (0: the map is the field).
    error_corr_m : float
        Its correlation length, metres (> 0 when ``error_rms`` > 0).

    Returns
    -------
    MapPosterior
        The posterior mean and covariance (with ``error_rms`` 0, the map itself and a
        zero covariance).

    Raises
    ------
    ValueError
        A negative rms, or an rms without a positive length.
    MemoryBudgetError
        The padded spectra would not fit the memory budget.
    """
    if error_rms < 0 or (error_rms > 0 and not error_corr_m > 0):
        raise ValueError(
            "map error: rms must be >= 0 with a positive length, got "
            f"{error_rms} and {error_corr_m}"
        )
    values = np.asarray(prior.values, dtype=float)
    finite = np.isfinite(values)
    if error_rms == 0:
        return MapPosterior(prior, np.zeros(values.shape))
    ny, nx = values.shape
    check_allocation(
        cells_bytes(2 * ny, 2 * nx, copies=12),
        f"the map posterior's spectra ({2 * ny} x {2 * nx} nodes, the map and its mirror)",
    )
    level = float(values[finite].mean())
    filled = np.where(finite, values - level, 0.0)
    # the map beside its mirror images: periodic without a jump at the edges, whose
    # leakage would read as field power at every wavenumber
    padded = np.pad(filled, ((0, ny), (0, nx)), mode="symmetric")
    error = gaussian_error_power(padded.shape, prior.dx, prior.dy, error_rms, error_corr_m)
    field = np.maximum(radial_power(padded, prior.dx, prior.dy) - error, 0.0)
    total = field + error
    gain = np.divide(field, total, out=np.ones_like(total), where=total > 0)
    mean = np.real(np.fft.ifft2(gain * np.fft.fft2(padded)))[:ny, :nx]
    residual = np.divide(field * error, total, out=np.zeros_like(total), where=total > 0)
    lag = np.real(np.fft.ifft2(residual))
    mean_values = np.where(finite, mean + level, np.nan)
    return MapPosterior(prior.with_values(mean_values, name=f"{prior.name}-posterior"), lag)
