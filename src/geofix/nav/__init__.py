"""Navigation: true trajectories, the INS error model and the DVL."""

from geofix.nav.dvl import simulate_dvl
from geofix.nav.ins import (
    InsTrack,
    position_sigma,
    schuler_bias_error,
    schuler_gyro_error,
    simulate_ins,
)
from geofix.nav.trajectory import TrueTrajectory, true_trajectory

__all__ = [
    "InsTrack",
    "TrueTrajectory",
    "position_sigma",
    "schuler_bias_error",
    "schuler_gyro_error",
    "simulate_dvl",
    "simulate_ins",
    "true_trajectory",
]
