"""A simulated (or replayed) mission: truth, INS indication and measurements."""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from geofix.maps.grid import Grid
from geofix.nav.errstate import InsErrorModel
from geofix.problem import MatchField, MatchProblem, check_beam_noise_std


@dataclass(frozen=True, eq=False)
class TrialField:
    """One more field of a mission with several sensors (a scenario's ``sensors:`` list).

    Parameters
    ----------
    kind : str
        The field's kind (``depth``, ``gravity`` or ``magnetic``).
    sensor : str
        The sensor type.
    measured : numpy.ndarray
        ``(n, b)`` readings along the true track, map units, NaN = missing.
    offsets : numpy.ndarray
        ``(b, 2)`` body-frame beam offsets ``(across, along)``, metres.
    noise_std : float
        ``hypot(sensor.noise_std, sensor.map_error_std)``, map units (nadir for a
        multibeam), as the trial's own ``noise_std``.
    beam_noise_std : numpy.ndarray
        ``(b,)`` every beam's noise 1-sigma on the same footing, map units.
    grid : Grid
        The map the methods get for this field: the prepared map, or the trial's prior
        map of this field with a ``seabed`` block in its entry.
    lag_s : float
        The sensor's declared lag time constant, seconds (0: none).
    unlagged_measured : numpy.ndarray or None
        ``(n, b)`` the readings before the lag (truth: never handed to a method).
    sensed : Grid or None
        The field the sensor read when it differs from ``grid`` (a ``seabed`` block; truth:
        never handed to a method).
    prior_shift_m : numpy.ndarray or None
        ``(2,)`` the prior map's drawn misregistration, metres (truth); None without one.
    """

    kind: str
    sensor: str
    measured: np.ndarray
    offsets: np.ndarray
    noise_std: float
    beam_noise_std: np.ndarray
    grid: Grid
    lag_s: float = 0.0
    unlagged_measured: np.ndarray | None = None
    sensed: Grid | None = None
    prior_shift_m: np.ndarray | None = None

    def match_field(self, part: slice = slice(None)) -> MatchField:
        """What a method is handed of this field over samples ``part``."""
        return MatchField(
            grid=self.grid,
            measured=self.measured[part],
            offsets=self.offsets,
            noise_std=float(self.noise_std),
            sensor=self.sensor,
            beam_noise_std=self.beam_noise_std,
            lag_s=float(self.lag_s),
        )


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
    beam_noise_std : numpy.ndarray or None
        ``(b,)`` noise 1-sigma of every beam, map units, on the same footing as
        ``noise_std`` (None: ``noise_std`` for every beam). Handed on to every problem.
    ins_model : InsErrorModel or None
        The navigator's datasheet error model (:mod:`geofix.nav.errstate`), for the
        Cramér–Rao bound and the error-state filters; handed to every problem (None for a
        replayed mission without one).
    dvl_velocity : numpy.ndarray or None
        ``(n, 2)`` DVL velocity over ground, m/s, when the vehicle has a DVL (aiding data,
        handed to every problem).
    true_velocity : numpy.ndarray or None
        ``(n, 2)`` true velocity, m/s (truth: never handed to a method).
    unlagged_measured : numpy.ndarray or None
        ``(n, b)`` the readings before a gravimeter's lag, map units (truth: never handed
        to a method); None without a lag.
    lag_s : float
        The gravimeter's declared lag time constant, seconds (0 without one): the
        scenario's sensor datasheet number, handed to every problem.
    prior_map : Grid or None
        The prior map of this trial when it differs from the field the sensor read (a
        scenario's ``seabed`` block, :mod:`geofix.sim.seabed`): :meth:`problem` hands it
        to the method instead of the grid it is given. Its ``meta`` may hold
        ``registration_std_m``, how well the map states it is registered, metres.
    prior_shift_m : numpy.ndarray or None
        ``(2,)`` the prior map's drawn misregistration ``(east, north)``, metres (truth:
        never handed to a method); None without a prior map.
    fields : tuple of TrialField
        The other fields of a scenario's ``sensors:`` list, in its order after the first
        (``()``: one field). Handed to every problem (:attr:`MatchProblem.fields`).
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
    beam_noise_std: np.ndarray | None = None
    ins_model: InsErrorModel | None = None
    dvl_velocity: np.ndarray | None = None
    true_velocity: np.ndarray | None = None
    unlagged_measured: np.ndarray | None = None
    lag_s: float = 0.0
    prior_map: Grid | None = None
    prior_shift_m: np.ndarray | None = None
    fields: tuple[TrialField, ...] = ()

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

        Parameters
        ----------
        grid : Grid
            The map the method matches against; the trial's ``prior_map`` replaces it
            when the trial has one.
        part : slice
            The samples of the problem (default: all).
        indicated : array_like, optional
            ``(m, 2)`` positions, metres, replacing the free INS track over ``part``
            (after a reset to an earlier fix, say); by default the free INS track.

        Returns
        -------
        MatchProblem
            What a method is handed: never the truth.
        """
        ind = self.indicated[part] if indicated is None else np.asarray(indicated, dtype=float)
        dvl = None if self.dvl_velocity is None else np.asarray(self.dvl_velocity)[part]
        return MatchProblem(
            grid=grid if self.prior_map is None else self.prior_map,
            indicated=ind,
            heading=self.indicated_heading[part],
            offsets=self.offsets,
            measured=self.measured[part],
            sigma_position=self.sigma_position[part],
            times=self.times[part],
            noise_std=self.noise_std,
            sensor=self.sensor,
            map_error_std=self.map_error_std,
            beam_noise_std=self.beam_noise_std,
            dvl_velocity=dvl,
            ins_model=self.ins_model,
            lag_s=float(self.lag_s),
            fields=tuple(f.match_field(part) for f in self.fields),
        )
