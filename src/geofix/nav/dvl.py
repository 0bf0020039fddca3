"""Doppler velocity log (DVL): velocity over ground with a constant bias and white noise."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from geofix.nav.spec import DvlSpec
    from geofix.nav.trajectory import TrueTrajectory


def simulate_dvl(true: TrueTrajectory, spec: DvlSpec, rng: np.random.Generator) -> np.ndarray:
    """DVL velocities along a true trajectory, in the local frame.

    ``true velocity + bias + noise``: the bias is constant over the trial, of magnitude
    ``spec.bias_m_s`` in a uniformly random direction; the noise is white, N(0,
    ``spec.noise_std_m_s``) per axis and sample.

    Parameters
    ----------
    true : TrueTrajectory
        The true track (its ``velocity`` is used), m/s.
    spec : DvlSpec
        Noise and bias, m/s.
    rng : numpy.random.Generator
        Source of the random draws (the bias direction first, then the noise).

    Returns
    -------
    numpy.ndarray
        ``(n, 2)`` measured velocities ``(east, north)``, m/s.
    """
    angle = rng.uniform(0.0, 2.0 * np.pi)
    bias = spec.bias_m_s * np.array([np.cos(angle), np.sin(angle)])
    velocity = np.asarray(true.velocity, dtype=float)
    noise = rng.normal(0.0, 1.0, velocity.shape) * spec.noise_std_m_s
    return velocity + bias + noise
