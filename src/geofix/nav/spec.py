"""Specifications of the navigation sensors: the INS datasheet and the DVL."""

from __future__ import annotations

from pydantic import Field

from geofix._strict import Strict


class InsSpec(Strict):
    """INS datasheet numbers (see :mod:`geofix.nav.ins` for how they are integrated).

    ``initial_error_m`` is a fixed ``[east, north]`` offset of the indicated start;
    ``initial_error_std_m`` adds a random per-axis Gaussian offset per trial.
    ``prior_sigma_m`` overrides the prior 1-sigma handed to the matchers.
    """

    initial_error_m: tuple[float, float] = (0.0, 0.0)
    initial_error_std_m: float = Field(default=0.0, ge=0)
    velocity_error_m_s: float = Field(default=0.0, ge=0)
    heading_error_deg: float = 0.0
    gyro_bias_deg_h: float = Field(default=0.0, ge=0)
    gyro_noise_deg_rt_h: float = Field(default=0.0, ge=0)
    accel_bias_ug: float = Field(default=0.0, ge=0)
    accel_noise_ug_rt_hz: float = Field(default=0.0, ge=0)
    schuler: bool = True
    prior_sigma_m: float | None = Field(default=None, gt=0)


class DvlSpec(Strict):
    """Doppler velocity log: per-axis white noise and a constant bias, m/s."""

    noise_std_m_s: float = Field(default=0.01, ge=0)
    bias_m_s: float = Field(default=0.0, ge=0)
