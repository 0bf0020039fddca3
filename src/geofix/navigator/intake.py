"""The navigator's intake: raw inputs checked and turned into the filter loop's steps.

- **input validation** -- times in order, finite positions, a velocity limit between
  navigation records, a ping within ``max_pose_gap_s`` of the pose it is placed with,
  bounded beam counts; a bad input raises :class:`~geofix.errors.InputError` and leaves
  the navigator's state untouched;
- **start-up gating** -- the start box (``+-2 sigma``) must lie mostly on valid map data
  (:func:`check_start_box`);
- **a ping's beams** (:class:`PingIntake`) -- levelled with the attitude and the mounting
  offset (:mod:`geofix.sensors.attitude`), the sensor's lag undone, the variance checked
  and the valid beams thinned to ``max_update_beams``.
"""

from __future__ import annotations

import numpy as np

from geofix.errors import InputError
from geofix.filters.base import Motion
from geofix.maps.grid import Grid
from geofix.navigator.settings import NavigatorSettings
from geofix.sensors.attitude import level_offsets
from geofix.sensors.gravimeter import undo_lag_step


def finite(value, name: str) -> float:
    """``value`` as a finite float; InputError naming ``name`` otherwise."""
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {type(value).__name__}") from None
    if not np.isfinite(out):
        raise InputError(f"{name} must be finite, got {out}")
    return out


def point(value, name: str) -> np.ndarray:
    """``value`` as two finite numbers ``(x, y)``; InputError naming ``name`` otherwise."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be two numbers (x, y)") from None
    if arr.shape != (2,) or not np.isfinite(arr).all():
        raise InputError(f"{name} must be two finite numbers (x, y), got {value!r}")
    return arr


def check_start_box(grid: Grid, position: np.ndarray, sigma_m: float, share_needed: float) -> None:
    """Refuse a start whose ``+-2 sigma`` box lies mostly off valid map data.

    Parameters
    ----------
    grid : Grid
        The map.
    position : numpy.ndarray
        ``(2,)`` start position, metres.
    sigma_m : float
        Per-axis start sigma, metres.
    share_needed : float
        Share of a 9 x 9 lattice over the box that must read valid data (0: no check).

    Raises
    ------
    InputError
        Too little of the box on valid data.
    """
    if share_needed <= 0:
        return
    u = np.linspace(-2.0 * sigma_m, 2.0 * sigma_m, 9)
    gx, gy = np.meshgrid(position[0] + u, position[1] + u)
    share = float(np.isfinite(grid.sample(gx, gy)).mean())
    if share < share_needed:
        raise InputError(
            f"init: only {share:.0%} of the +-2 sigma start box around "
            f"({position[0]:.1f}, {position[1]:.1f}) m lies on valid map data "
            f"(need {share_needed:.0%})"
        )


def motion_between(
    settings: NavigatorSettings,
    previous: tuple[float, np.ndarray],
    t: float,
    position: np.ndarray,
    process_var: float | None,
) -> Motion:
    """The motion from the previous navigation record to this one, checked.

    Parameters
    ----------
    settings : NavigatorSettings
        ``max_speed_m_s`` and ``process_noise_m2_s``.
    previous : tuple
        ``(t, position (2,))`` of the previous record, seconds and metres.
    t : float
        Time of this record, seconds (not before the previous one).
    position : numpy.ndarray
        ``(2,)`` its indicated position, metres.
    process_var : float or None
        Per-axis variance gained, m^2 (None: ``process_noise_m2_s`` times the elapsed
        time, at least ``1e-6``).

    Returns
    -------
    Motion
        The displacement, the elapsed time and the process variance.

    Raises
    ------
    InputError
        Faster than ``max_speed_m_s``, or a process variance not finite and >= 0.
    """
    dt = t - previous[0]
    displacement = position - previous[1]
    step = float(np.hypot(*displacement))
    vmax = settings.max_speed_m_s
    if vmax is not None and step > vmax * dt + 1e-6:
        raise InputError(
            f"nav at t = {t:g} s moves {step:.4g} m in {dt:.4g} s (limit {vmax:g} m/s)"
        )
    if process_var is None:
        process_var = max(settings.process_noise_m2_s * dt, 1e-6)
    elif not (np.isfinite(process_var) and process_var >= 0):
        raise InputError(f"nav: process_var must be finite and >= 0, got {process_var}")
    return Motion(displacement, float(dt), float(process_var))


def min_beams(settings: NavigatorSettings, beams: int) -> int:
    """Valid beams a ping of ``beams`` needs: the setting, or 1 for one beam, 3 for more."""
    if settings.min_beams is not None:
        return int(settings.min_beams)
    return 1 if beams == 1 else 3


class PingIntake:
    """A ping's raw beams turned into offsets, values and variances (with the lag memory).

    Parameters
    ----------
    settings : NavigatorSettings
        ``max_beams``, ``mount_offset_m``, ``lag_s``, ``noise_std`` and
        ``max_update_beams``.
    """

    def __init__(self, settings: NavigatorSettings) -> None:
        self.settings = settings
        self._lagged: tuple[float, np.ndarray] | None = None  # the last raw ping (t, values)

    def read(self, t: float, beams, noise_var, roll, pitch):
        """``(offsets (b, 2), values (b,), var)`` of a ping at ``t`` (seconds), checked.

        Parameters
        ----------
        t : float
            Ping time, seconds.
        beams : array_like
            ``(b, 3)`` level offsets and values or ``(b, 4)`` body-frame vectors and values.
        noise_var : float or array_like or None
            Measurement variance, map units squared (None: ``noise_std^2``).
        roll, pitch : float or None
            Attitude, radians.

        Returns
        -------
        tuple
            Level footprint offsets (metres), the values with the lag undone (map units)
            and their variance (a float or ``(b,)``), thinned to ``max_update_beams``.

        Raises
        ------
        InputError
            Malformed beams, attitude or variance.
        """
        rows = self.beams(beams)
        offsets, values = self.level(rows, roll, pitch)
        values = self.unlagged(t, values)
        var = self.noise_var(noise_var, values.shape[0])
        return self.thin(offsets, values, var)

    def unlagged(self, t: float, values: np.ndarray) -> np.ndarray:
        """A ping's values with the sensor's first-order lag undone (``lag_s``)."""
        lag = float(self.settings.lag_s)
        if lag <= 0:
            return values
        previous = self._lagged
        self._lagged = (t, values.copy())
        if previous is None or previous[1].shape != values.shape or t <= previous[0]:
            return values
        return undo_lag_step(values, previous[1], np.exp(-(t - previous[0]) / lag))

    def level(self, beams: np.ndarray, roll, pitch) -> tuple[np.ndarray, np.ndarray]:
        """``(offsets (b, 2), values (b,))``: level footprint offsets and the readings.

        Parameters
        ----------
        beams : numpy.ndarray
            ``(b, 3)`` level offsets (metres) and values, or ``(b, 4)`` body-frame beam
            vectors (metres) and values.
        roll, pitch : float or None
            Attitude, radians (None: 0, and level beams are taken as they are).

        Returns
        -------
        tuple of numpy.ndarray
            Offsets with the levelled mounting offset, metres, and the values.
        """
        values = beams[:, -1]
        mount = np.asarray(self.settings.mount_offset_m, dtype=float)
        if beams.shape[1] == 3 and roll is None and pitch is None:
            return (beams[:, :2] + mount[:2] if mount.any() else beams[:, :2]), values
        attitude = []
        for name, angle in (("roll", roll), ("pitch", pitch)):
            angle = 0.0 if angle is None else finite(angle, name)
            if abs(angle) >= 0.5 * np.pi:
                raise InputError(f"ping: {name} must be within +-90 degrees, got {angle:g} rad")
            attitude.append(angle)
        roll_rad, pitch_rad = attitude
        if beams.shape[1] == 4:
            return level_offsets(beams[:, :3], roll_rad, pitch_rad, mount)[:, :2], values
        lever = level_offsets(np.zeros((1, 3)), roll_rad, pitch_rad, mount)[0, :2]
        return beams[:, :2] + lever, values

    def beams(self, beams) -> np.ndarray:
        """The ping's rows as a ``(b, 3)`` or ``(b, 4)`` float array; InputError if malformed."""
        try:
            arr = np.asarray(beams, dtype=float)
        except (TypeError, ValueError):
            raise InputError("ping: beams must be a list of [across_m, along_m, value]") from None
        if arr.ndim != 2 or arr.shape[1] not in (3, 4) or arr.shape[0] < 1:
            raise InputError(f"ping: beams must have shape (b, 3) or (b, 4), got {arr.shape}")
        if arr.shape[0] > self.settings.max_beams:
            raise InputError(
                f"ping: {arr.shape[0]} beams, more than max_beams = {self.settings.max_beams}"
            )
        if not np.isfinite(arr[:, :-1]).all() or np.isinf(arr[:, -1]).any():
            raise InputError("ping: beam offsets must be finite and values finite or NaN")
        return arr

    def noise_var(self, noise_var, beams: int):
        """The ping's measurement variance: ``noise_std^2`` by default, else checked (units^2)."""
        if noise_var is None:
            return self.settings.noise_std**2
        var = np.asarray(noise_var, dtype=float)
        if var.shape not in ((), (beams,)) or not (np.isfinite(var).all() and (var >= 0).all()):
            raise InputError(f"ping: noise_var must be a number or ({beams},) values >= 0")
        return np.maximum(var, 1e-12) if var.ndim else max(float(var), 1e-12)

    def thin(self, offsets, values, var):
        """At most ``max_update_beams`` valid beams, evenly spread across the swath.

        Parameters
        ----------
        offsets : numpy.ndarray
            ``(b, 2)`` footprint offsets, metres.
        values : numpy.ndarray
            ``(b,)`` readings, map units (NaN: missing).
        var : float or numpy.ndarray
            Measurement variance, map units squared (one, or ``(b,)``).

        Returns
        -------
        tuple
            The kept offsets, values and variances.
        """
        limit = self.settings.max_update_beams
        valid = np.flatnonzero(np.isfinite(values))
        if limit is None or valid.size <= limit:
            return offsets, values, var
        keep = valid[np.linspace(0, valid.size - 1, limit).round().astype(int)]
        var = var[keep] if np.ndim(var) else var
        return offsets[keep], values[keep], var


__all__ = ["PingIntake", "check_start_box", "finite", "min_beams", "motion_between", "point"]
