"""Field sensors: echosounder beam geometry and the error model of every sensor.

The map value at each beam's footprint (predicted by :mod:`geofix.measurement`) becomes a
reading by :func:`add_sensor_errors`, which adds white noise:

- ``singlebeam``: one beam under the vehicle, noise ``noise_std``;
- ``multibeam``: ``beams`` beams across track; the noise 1-sigma grows linearly with the
  across-track distance, from ``noise_std`` at nadir to ``edge_noise_factor * noise_std``
  at the outermost beam;
- ``gravimeter``: one reading under the vehicle, noise ``noise_std``, then the first-order
  lag of :mod:`geofix.sensors.gravimeter`.

``map_error_std`` adds a further white error per sample and beam, standing for the
difference between the prior map and the real field (a spatially smooth error field
would be more realistic; white is the simple, documented choice). Order: map value +
map error + sensor noise, then (gravimeter only) the lag.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from geofix.errors import ConfigError
from geofix.sensors.gravimeter import apply_first_order_lag

if TYPE_CHECKING:
    from geofix.sensors.spec import SensorSpec


def sensor_offsets(spec: SensorSpec) -> np.ndarray:
    """Body-frame footprint offsets of the sensor's beams.

    Single-beam, gravimeter and magnetometer: ``[[0, 0]]``. Multibeam: ``spec.beams`` beams with
    ``along = 0``; if ``swath_angle_deg`` and ``altitude_m`` are both given, the beam
    angles are equally spaced over the swath and ``across = altitude * tan(angle)``;
    otherwise the beams are equally spaced over ``swath_width_m``. With an odd beam count
    the middle beam sits at nadir.

    Parameters
    ----------
    spec : SensorSpec
        The sensor.

    Returns
    -------
    numpy.ndarray
        ``(b, 2)`` offsets ``(across, along)``, metres (across positive to starboard).

    Raises
    ------
    ConfigError
        A multibeam without a swath width (or swath angle and altitude).
    """
    if spec.type != "multibeam":
        return np.zeros((1, 2))
    unit = np.linspace(-0.5, 0.5, spec.beams) if spec.beams > 1 else np.zeros(1)
    if spec.swath_angle_deg is not None and spec.altitude_m is not None:
        across = spec.altitude_m * np.tan(np.radians(spec.swath_angle_deg) * unit)
    elif spec.swath_width_m is not None:
        across = spec.swath_width_m * unit
    else:
        raise ConfigError(
            "sensor: a multibeam needs sensor.swath_width_m, or sensor.swath_angle_deg "
            "with sensor.altitude_m"
        )
    return np.column_stack([across, np.zeros_like(across)])


def beam_noise_std(offsets: np.ndarray, spec: SensorSpec) -> np.ndarray:
    """Sensor noise 1-sigma of each beam, map units.

    Parameters
    ----------
    offsets : numpy.ndarray
        ``(b, 2)`` body-frame offsets, metres.
    spec : SensorSpec
        The sensor.

    Returns
    -------
    numpy.ndarray
        ``(b,)``: ``noise_std`` for single-beam and gravimeter; for a multibeam
        ``noise_std * (1 + (edge_noise_factor - 1) * |across| / max|across|)``.
    """
    across = np.abs(np.asarray(offsets, dtype=float)[:, 0])
    std = np.full(across.shape, float(spec.noise_std))
    if spec.type != "multibeam" or across.max() == 0:
        return std
    return std * (1.0 + (spec.edge_noise_factor - 1.0) * across / across.max())


def add_sensor_errors(
    clean, offsets, spec: SensorSpec, rng: np.random.Generator, times=None
) -> tuple[np.ndarray, np.ndarray]:
    """Turn noise-free field values into sensor readings (see the module docstring).

    Parameters
    ----------
    clean : array_like
        ``(n, b)`` map values at the true footprints, map units.
    offsets : numpy.ndarray
        ``(b, 2)`` body-frame beam offsets ``(across, along)``, metres (they set each
        beam's noise).
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

    Raises
    ------
    ValueError
        A gravimeter with a lag and no sample times.
    """
    clean = np.asarray(clean, dtype=float)
    noise = rng.standard_normal(clean.shape) * beam_noise_std(offsets, spec)
    map_error = rng.standard_normal(clean.shape) * spec.map_error_std
    unlagged = clean + map_error + noise
    if spec.type != "gravimeter" or spec.lag_s <= 0:
        return unlagged, unlagged.copy()
    if times is None:
        raise ValueError("a gravimeter with a lag needs the sample times")
    return apply_first_order_lag(unlagged, times, spec.lag_s), unlagged
