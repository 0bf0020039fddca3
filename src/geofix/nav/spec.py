"""Specifications of the navigation sensors: the INS datasheet and the DVL."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from geofix._strict import Strict

#: No position error on Earth is larger than half its circumference, metres.
EARTH_HALF_CIRCUMFERENCE_M = 2.0e7
#: Largest INS or DVL error rate or noise accepted (in each key's own units): far beyond
#: any real sensor, small enough that the error-state arithmetic stays finite.
MAX_RATE = 1.0e9


class InsSpec(Strict):
    """INS datasheet numbers (see :mod:`geofix.nav.ins` for how they are integrated).

    ``initial_error_m`` is a fixed ``[east, north]`` offset of the indicated start;
    ``initial_error_std_m`` adds a random per-axis Gaussian offset per trial.
    ``prior_sigma_m`` overrides the prior 1-sigma handed to the matchers.
    ``mode`` is ``free`` (a free inertial navigator, the default: every other key as
    above) or ``dvl`` (DVL-aided dead reckoning: the position integrates the ``dvl``
    block's velocity, with its bias, noise and ``scale_error``, rotated by a heading of
    error ``heading_error_deg`` drifting at ``gyro_bias_deg_h`` with noise
    ``gyro_noise_deg_rt_h``; the accelerometer, velocity-error and Schuler keys are then
    unused). ``latitude_deg`` (degrees, optional) switches on the Earth-rate coupling of
    the heading error of a free INS (see :mod:`geofix.nav.errstate`).
    """

    initial_error_m: tuple[float, float] = (0.0, 0.0)
    initial_error_std_m: float = Field(default=0.0, ge=0, le=EARTH_HALF_CIRCUMFERENCE_M)
    velocity_error_m_s: float = Field(default=0.0, ge=0, le=MAX_RATE)
    heading_error_deg: float = Field(default=0.0, ge=-MAX_RATE, le=MAX_RATE)
    gyro_bias_deg_h: float = Field(default=0.0, ge=0, le=MAX_RATE)
    gyro_noise_deg_rt_h: float = Field(default=0.0, ge=0, le=MAX_RATE)
    accel_bias_ug: float = Field(default=0.0, ge=0, le=MAX_RATE)
    accel_noise_ug_rt_hz: float = Field(default=0.0, ge=0, le=MAX_RATE)
    schuler: bool = True
    prior_sigma_m: float | None = Field(default=None, gt=0, le=EARTH_HALF_CIRCUMFERENCE_M)
    mode: Literal["free", "dvl"] = "free"
    latitude_deg: float | None = Field(default=None, ge=-90, le=90)

    @field_validator("initial_error_m")
    @classmethod
    def _on_earth(cls, v: tuple[float, float]) -> tuple[float, float]:
        if max(abs(v[0]), abs(v[1])) > EARTH_HALF_CIRCUMFERENCE_M:
            raise ValueError(f"must be at most {EARTH_HALF_CIRCUMFERENCE_M:g} m per axis")
        return v


class DvlSpec(Strict):
    """Doppler velocity log: per-axis white noise and a constant bias, m/s.

    ``scale_error`` (dimensionless, e.g. 0.002 for 0.2 %) is the magnitude of a scale-factor
    error of random sign; it is used by ``ins.mode: dvl`` (dead reckoning on the DVL).
    """

    noise_std_m_s: float = Field(default=0.01, ge=0, le=MAX_RATE)
    bias_m_s: float = Field(default=0.0, ge=0, le=MAX_RATE)
    scale_error: float = Field(default=0.0, ge=0, le=MAX_RATE)
