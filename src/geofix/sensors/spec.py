"""Specification of a field sensor: echosounder (single / multibeam), gravimeter or magnetometer."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from geofix._strict import Strict

SENSOR_KINDS = {
    "singlebeam": "depth",
    "multibeam": "depth",
    "gravimeter": "gravity",
    "magnetometer": "magnetic",
}
"""The map kind (:data:`geofix.maps.grid.KINDS`) each sensor type reads."""


class SensorSpec(Strict):
    """The field sensor.

    ``singlebeam``: depth under the vehicle. ``multibeam``: ``beams`` beams across a swath
    of ``swath_width_m`` metres (or ``swath_angle_deg`` with ``altitude_m``), noise growing
    to ``edge_noise_factor`` times ``noise_std`` at the outer beams. ``gravimeter``: a
    first-order lag of ``lag_s`` seconds (0 = none). ``magnetometer``: the magnetic
    anomaly under the vehicle, ``noise_std`` in nT (a towed or hull magnetometer with the
    vehicle's own field compensated).
    """

    type: Literal["singlebeam", "multibeam", "gravimeter", "magnetometer"]
    noise_std: float = Field(default=0.0, ge=0)
    beams: int = Field(default=1, ge=1)
    swath_width_m: float | None = Field(default=None, gt=0)
    swath_angle_deg: float | None = Field(default=None, gt=0, lt=180)
    altitude_m: float | None = Field(default=None, gt=0)
    edge_noise_factor: float = Field(default=2.0, ge=1)
    lag_s: float = Field(default=0.0, ge=0)
    map_error_std: float = Field(default=0.0, ge=0)

    @property
    def kind(self) -> str:
        """The map kind this sensor reads: ``depth``, ``gravity`` or ``magnetic``."""
        return SENSOR_KINDS[self.type]
