"""Sensors: single-beam and multibeam echosounders, gravimeter (noise, lag), magnetometer."""

from geofix.sensors.echosounder import (
    add_sensor_errors,
    beam_noise_std,
    sensor_offsets,
)
from geofix.sensors.gravimeter import apply_first_order_lag, compensate_first_order_lag

__all__ = [
    "add_sensor_errors",
    "apply_first_order_lag",
    "beam_noise_std",
    "compensate_first_order_lag",
    "sensor_offsets",
]
