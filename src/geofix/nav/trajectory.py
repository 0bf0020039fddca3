"""True trajectories: straight legs at constant speed joined by random turns."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class TrueTrajectory:
    """Where the vehicle really was.

    Parameters
    ----------
    times : numpy.ndarray
        ``(n,)`` sample times, seconds from the start.
    positions : numpy.ndarray
        ``(n, 2)`` true positions ``(x east, y north)``, metres.
    heading : numpy.ndarray
        ``(n,)`` true heading, radians clockwise from north.
    velocity : numpy.ndarray
        ``(n, 2)`` true velocity ``(east, north)``, m/s.
    leg_starts : tuple of int
        Index of the first sample of every leg.
    """

    times: np.ndarray
    positions: np.ndarray
    heading: np.ndarray
    velocity: np.ndarray
    leg_starts: tuple = (0,)

    @property
    def n(self) -> int:
        """Number of samples."""
        return self.times.shape[0]


def true_trajectory(
    start_xy,
    heading_deg: float,
    speed_m_s: float,
    interval_s: float,
    samples: int,
    legs: int = 1,
    turn_std_deg: float = 0.0,
    rng: np.random.Generator | None = None,
) -> TrueTrajectory:
    """A track of ``legs`` straight legs of ``samples`` samples each.

    Within a leg the vehicle runs a straight line at constant speed. At the last sample
    of a leg it turns by a random angle drawn from N(0, ``turn_std_deg``) and the next leg
    starts one interval later on the new heading, so sample ``k`` is reached from sample
    ``k - 1`` along ``heading[k]``.

    Parameters
    ----------
    start_xy : array_like
        ``(2,)`` position of the first sample ``(x, y)``, metres.
    heading_deg : float
        Heading of the first leg, degrees clockwise from north.
    speed_m_s : float
        Speed over ground, m/s (>= 0).
    interval_s : float
        Time between samples, seconds (> 0).
    samples : int
        Samples per leg (>= 1).
    legs : int
        Number of legs (>= 1).
    turn_std_deg : float
        1-sigma of the heading change between legs, degrees.
    rng : numpy.random.Generator, optional
        Needed only when there are random turns (``legs > 1`` and ``turn_std_deg > 0``).

    Returns
    -------
    TrueTrajectory
        ``n = samples * legs`` samples.
    """
    _check_track_arguments(speed_m_s, interval_s, samples, legs, turn_std_deg)
    turns = np.zeros(legs)
    if legs > 1 and turn_std_deg > 0:
        if rng is None:
            raise ValueError("random turns between legs need a numpy.random.Generator rng")
        turns[1:] = rng.normal(0.0, np.radians(turn_std_deg), legs - 1)
    leg_heading = np.radians(heading_deg) + np.cumsum(turns)
    heading = np.repeat(leg_heading, samples)
    velocity = speed_m_s * np.column_stack([np.sin(heading), np.cos(heading)])
    steps = velocity[1:] * interval_s
    positions = np.asarray(start_xy, dtype=float) + np.vstack(
        [np.zeros((1, 2)), np.cumsum(steps, axis=0)]
    )
    n = samples * legs
    return TrueTrajectory(
        times=np.arange(n) * float(interval_s),
        positions=positions,
        heading=heading,
        velocity=velocity,
        leg_starts=tuple(range(0, n, samples)),
    )


def _check_track_arguments(speed, interval, samples, legs, turn_std) -> None:
    if speed < 0:
        raise ValueError(f"speed_m_s must be >= 0, got {speed}")
    if interval <= 0:
        raise ValueError(f"interval_s must be > 0, got {interval}")
    if samples < 1 or legs < 1:
        raise ValueError(f"samples and legs must be >= 1, got {samples}, {legs}")
    if turn_std < 0:
        raise ValueError(f"turn_std_deg must be >= 0, got {turn_std}")
