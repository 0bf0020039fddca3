"""Sensors: single-beam and multibeam echosounders, gravimeter (noise, lag)."""

from geofix.sensors.echosounder import (
    beam_noise_std,
    measure,
    measure_with_unlagged,
    sensor_offsets,
)
from geofix.sensors.gravimeter import apply_first_order_lag, compensate_first_order_lag

__all__ = [
    "apply_first_order_lag",
    "beam_noise_std",
    "compensate_first_order_lag",
    "measure",
    "measure_with_unlagged",
    "sensor_offsets",
]
