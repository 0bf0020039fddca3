"""Simulated sensor readings: the one measurement model plus each sensor's errors.

A reading is the map predicted at every beam's footprint along the *true* track
(:func:`geofix.measurement.predict_track` with :data:`TRUTH_READ`, bilinear whatever the
grid's ``interpolation``) with the sensor's noise, map error and lag added
(:func:`geofix.sensors.echosounder.add_sensor_errors`).
"""

from __future__ import annotations

import numpy as np

from geofix.maps.grid import Grid
from geofix.measurement import predict_track
from geofix.sensors.echosounder import add_sensor_errors
from geofix.sensors.spec import SensorSpec

TRUTH_READ = "bilinear"
"""The map read that makes the simulated readings (and so the one the bounds of
:mod:`geofix.evaluate.crlb` differentiate): the true field is the bilinear interpolant of
the grid, whichever read a filter's measurement model takes."""


def measure_with_unlagged(
    grid: Grid, truth, heading, offsets, spec: SensorSpec, rng: np.random.Generator, times=None
) -> tuple[np.ndarray, np.ndarray]:
    """Sensor readings along a true track, and the same readings before the lag.

    Parameters
    ----------
    grid : Grid
        The field the sensor sees (read with :data:`TRUTH_READ`, bilinear).
    truth : array_like
        ``(n, 2)`` true positions, metres.
    heading : array_like
        ``(n,)`` true heading, radians clockwise from north.
    offsets : numpy.ndarray
        ``(b, 2)`` body-frame beam offsets ``(across, along)``, metres.
    spec : SensorSpec
        Noise, map error and (gravimeter) lag.
    rng : numpy.random.Generator
        Source of the noise (sensor noise first, then map error).
    times : array_like, optional
        ``(n,)`` sample times, seconds; needed by a gravimeter with ``lag_s > 0``.

    Returns
    -------
    tuple of numpy.ndarray
        ``(measured, unlagged)``, each ``(n, b)`` map units; they are equal except for a
        gravimeter with ``lag_s > 0``.
    """
    clean = predict_track(grid, truth, heading, offsets, method=TRUTH_READ)
    return add_sensor_errors(clean, offsets, spec, rng, times)


def measure(
    grid: Grid, truth, heading, offsets, spec: SensorSpec, rng: np.random.Generator, times=None
) -> np.ndarray:
    """Sensor readings along a true track.

    Parameters
    ----------
    grid : Grid
        The field the sensor sees (read with :data:`TRUTH_READ`, bilinear).
    truth : array_like
        ``(n, 2)`` true positions, metres.
    heading : array_like
        ``(n,)`` true heading, radians clockwise from north.
    offsets : numpy.ndarray
        ``(b, 2)`` body-frame beam offsets ``(across, along)``, metres.
    spec : SensorSpec
        Noise, map error and (gravimeter) lag.
    rng : numpy.random.Generator
        Source of the noise (sensor noise first, then map error).
    times : array_like, optional
        ``(n,)`` sample times, seconds; needed by a gravimeter with ``lag_s > 0``.

    Returns
    -------
    numpy.ndarray
        ``(n, b)`` readings in map units; NaN where a footprint is off the map.
    """
    return measure_with_unlagged(grid, truth, heading, offsets, spec, rng, times)[0]
