"""A simulated (or replayed) mission: truth, INS indication and measurements."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from geofix.maps.grid import Grid
from geofix.nav.errstate import InsErrorModel
from geofix.problem import MatchProblem, check_beam_noise_std

_TRUTH_PREFIXES = ("true_", "unlagged_")


@dataclass(frozen=True, eq=False)
class Trial:
    """One mission.

    Parameters
    ----------
    truth : numpy.ndarray
        ``(n, 2)`` true positions, metres.
    true_heading : numpy.ndarray
        ``(n,)`` true heading, radians clockwise from north.
    indicated : numpy.ndarray
        ``(n, 2)`` free-running INS positions (never reset), metres.
    indicated_heading : numpy.ndarray
        ``(n,)`` INS heading, radians.
    times : numpy.ndarray
        ``(n,)`` sample times, seconds from the start.
    measured : numpy.ndarray
        ``(n, b)`` sensor readings (map units), NaN = missing.
    offsets : numpy.ndarray
        ``(b, 2)`` body-frame beam offsets ``(across, along)``, metres.
    sigma_position : numpy.ndarray
        ``(n,)`` prior per-axis 1-sigma of the INS position error, metres.
    leg_starts : tuple of int
        Index of the first sample of every leg (``(0,)`` for a single leg).
    noise_std : float
        Sensor noise 1-sigma, map units (the nadir value for a multibeam).
    sensor : str
        Sensor type.
    map_error_std : float
        1-sigma of the map error, map units.
    index : int
        Trial number within its scenario.
    extras : dict
        Aiding data (``"dvl_velocity"`` ``(n, 2)`` m/s, ``"unlagged_measured"`` before the
        gravimeter lag, ``"lag_s"``) and truth kept for diagnostics (keys starting with
        ``"true_"`` or ``"unlagged_"``, never handed to a method).
    beam_noise_std : numpy.ndarray or None
        ``(b,)`` noise 1-sigma of every beam, map units, on the same footing as
        ``noise_std`` (None: ``noise_std`` for every beam). Handed on to every problem.
    ins_model : InsErrorModel or None
        The navigator's datasheet error model (:mod:`geofix.nav.errstate`), for the
        Cramér–Rao bound and the error-state filters; handed to every problem as
        ``extras["ins_model"]`` (None for a replayed mission without one).
    """

    truth: np.ndarray
    true_heading: np.ndarray
    indicated: np.ndarray
    indicated_heading: np.ndarray
    times: np.ndarray
    measured: np.ndarray
    offsets: np.ndarray
    sigma_position: np.ndarray
    leg_starts: tuple = (0,)
    noise_std: float = 0.0
    sensor: str = "singlebeam"
    map_error_std: float = 0.0
    index: int = 0
    extras: dict = field(default_factory=dict)
    beam_noise_std: np.ndarray | None = None
    ins_model: InsErrorModel | None = None

    def __post_init__(self) -> None:
        if self.beam_noise_std is not None:
            check_beam_noise_std(self.beam_noise_std, self.offsets.shape[0], "Trial")

    @property
    def n(self) -> int:
        """Number of samples."""
        return self.truth.shape[0]

    def leg_slices(self) -> list[slice]:
        """One slice per leg over the sample axis."""
        bounds = [*self.leg_starts, self.n]
        return [slice(a, b) for a, b in itertools.pairwise(bounds)]

    def problem(self, grid: Grid, part: slice = slice(None), indicated=None) -> MatchProblem:
        """The :class:`MatchProblem` for samples ``part``.

        ``indicated`` replaces the free INS track for that part (after a reset to an
        earlier fix, say); by default the free INS track is used.
        """
        ind = self.indicated[part] if indicated is None else np.asarray(indicated, dtype=float)
        extras = {
            k: (v[part] if isinstance(v, np.ndarray) and v.shape[:1] == (self.n,) else v)
            for k, v in self.extras.items()
            if not k.startswith(_TRUTH_PREFIXES)
        }
        if self.ins_model is not None:
            extras["ins_model"] = self.ins_model
        return MatchProblem(
            grid=grid,
            indicated=ind,
            heading=self.indicated_heading[part],
            offsets=self.offsets,
            measured=self.measured[part],
            sigma_position=self.sigma_position[part],
            times=self.times[part],
            noise_std=self.noise_std,
            sensor=self.sensor,
            map_error_std=self.map_error_std,
            extras=extras,
            beam_noise_std=self.beam_noise_std,
        )
