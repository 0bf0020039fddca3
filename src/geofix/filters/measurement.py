"""One measurement model for every recursive filter: prediction, likelihood, linearisation.

The field predicted at a position is the map read (bilinear) at every beam's footprint.
The point-mass and particle filters use :func:`log_likelihood` on many hypotheses at
once; SITAN uses :func:`linearise` (stochastic terrain linearisation: slopes of a
least-squares plane fitted over a patch the size of the position uncertainty).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geofix.maps._reads import bilinear_reads, gaussian_log_likelihood
from geofix.maps.grid import Grid
from geofix.match.base import footprint_xy

OFF_MAP_LOG_LIKELIHOOD = -1e6
"""Log-likelihood per beam of a hypothesis whose footprint is off the map (finite, so a
filter whose every hypothesis is off the map stays defined)."""


def predict_measurements(grid: Grid, positions: np.ndarray, heading: float, offsets) -> np.ndarray:
    """Field values every beam would read from ``positions``.

    Parameters
    ----------
    grid : Grid
        The map.
    positions : numpy.ndarray
        ``(..., 2)`` hypothesised vehicle positions, metres.
    heading : float
        Heading, radians clockwise from north.
    offsets : numpy.ndarray
        ``(b, 2)`` body-frame beam offsets, metres.

    Returns
    -------
    numpy.ndarray
        ``(..., b)`` predicted values; NaN off the map and wherever a cell of the bilinear
        stencil is NaN (as :meth:`Grid.sample`), read in one compiled loop
        (:func:`geofix.maps._reads.bilinear_reads`) for speed on large hypothesis sets.
    """
    positions = np.asarray(positions, dtype=float)
    offsets = np.asarray(offsets, dtype=float)
    # The beam offsets in metres are the same for every hypothesis: add them in cells.
    ox, oy = footprint_xy(np.zeros(2), np.asarray(heading, dtype=float), offsets)
    col, row = grid.xy_to_cell(positions[..., 0].ravel(), positions[..., 1].ravel())
    out = bilinear_reads(grid.values, row, col, oy / grid.dy, ox / grid.dx)
    return out.reshape(*positions.shape[:-1], offsets.shape[0])


def log_likelihood(predicted: np.ndarray, measured: np.ndarray, noise_var) -> np.ndarray:
    """Gaussian log-likelihood of the measured beams for every hypothesis.

    Parameters
    ----------
    predicted : numpy.ndarray
        ``(..., b)`` predicted values (NaN off the map).
    measured : numpy.ndarray
        ``(b,)`` measured values (NaN = missing beam, ignored).
    noise_var : float or numpy.ndarray
        Measurement variance (sensor + map error), map units squared: one value for
        every beam or ``(b,)`` per beam (each beam's squared residual is divided by its
        own variance).

    Returns
    -------
    numpy.ndarray
        ``(...)`` log-likelihoods up to a constant; off-map beams cost
        :data:`OFF_MAP_LOG_LIKELIHOOD` each.
    """
    measured = np.asarray(measured, dtype=float)
    flat = np.asarray(predicted, dtype=float).reshape(-1, measured.shape[0])
    ll = gaussian_log_likelihood(flat, measured, noise_var, OFF_MAP_LOG_LIKELIHOOD)
    return ll.reshape(predicted.shape[:-1])


def map_error_variance(error_std: Grid | None, position, heading: float, offsets) -> np.ndarray:
    """Per-cell map-error variance at every beam's footprint, map units squared.

    Parameters
    ----------
    error_std : Grid or None
        The map's uncertainty layer (per-cell standard deviation, e.g.
        :class:`geofix.maps.gridding.GriddedMap`); None gives zeros.
    position : array_like
        ``(2,)`` vehicle position the footprints are taken from (the current estimate),
        metres.
    heading : float
        Heading, radians clockwise from north.
    offsets : numpy.ndarray
        ``(b, 2)`` body-frame beam offsets, metres.

    Returns
    -------
    numpy.ndarray
        ``(b,)`` ``std^2`` of the cell under each beam (nearest cell), 0 where the layer
        has no value; added to the measurement variance of that beam.
    """
    offsets = np.asarray(offsets, dtype=float)
    if error_std is None:
        return np.zeros(offsets.shape[0])
    x, y = footprint_xy(np.asarray(position, dtype=float), np.asarray(heading, float), offsets)
    std = error_std.sample(x, y, method="nearest")
    return np.where(np.isfinite(std), std**2, 0.0)


@dataclass(frozen=True)
class Linearisation:
    """Local linear model of the field around an estimate, one row per beam.

    ``predicted`` ``(b,)`` values read at the estimate; ``slopes`` ``(b, 2)`` field units
    per metre along x and y; ``fit_var`` ``(b,)`` residual variance of the plane fits
    (added to the measurement noise as linearisation error).
    """

    predicted: np.ndarray
    slopes: np.ndarray
    fit_var: np.ndarray


def linearise(grid: Grid, position, heading: float, offsets, half_width_m: float) -> Linearisation:
    """Stochastic terrain linearisation at every beam's footprint.

    A least-squares plane is fitted to the map over a square patch of half-width
    ``half_width_m`` (the position uncertainty, metres; at least one cell) around each
    footprint; its slopes form the rows of the measurement Jacobian.

    ``position`` is ``(2,)`` (one estimate: arrays ``(b,)`` / ``(b, 2)``) or ``(..., 2)``
    (several estimates at once, same heading and patch: arrays ``(..., b)`` / ``(..., b, 2)``).
    """
    from geofix.maps.terrain import plane_fit

    pos = np.asarray(position, dtype=float)[..., None, :]
    x, y = footprint_xy(pos, np.full(pos.shape[:-1], heading), np.asarray(offsets, dtype=float))
    x, y = x[..., 0, :], y[..., 0, :]
    fit = plane_fit(grid, x, y, max(half_width_m, grid.cell_size))
    slopes = np.stack([fit.slope_x, fit.slope_y], axis=-1)
    return Linearisation(
        predicted=grid.sample(x, y),
        slopes=slopes,
        fit_var=np.asarray(fit.residual_std, dtype=float) ** 2,
    )
