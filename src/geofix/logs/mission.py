"""The :class:`Mission`: one recorded mission, whatever logger wrote it.

A mission is a sequence of pings. Each ping has a time, the vehicle's navigation at that
time (position in a metric frame, heading, and roll, pitch and velocity where the log has
them) and the ping's beams as body-frame offsets ``(across, along)`` plus the measured
value, in map units and with the map's sign (elevation: negative below sea level). Where
the log has an independent truth (a simulated mission, a post-processed track) it is kept
beside the navigation; where the navigation itself comes from GNSS (a surface ship) the
navigation *is* the truth (``nav_source == "gnss"``). A mission of several fields (a
ship's depths and gravity anomalies) keeps the further fields' beams beside the primary
field's (:attr:`Mission.fields`), NaN where a ping has no reading of a field.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from geofix.errors import ConfigError

NAV_SOURCES = ("gnss", "ins")


@dataclass(frozen=True, eq=False)
class Mission:
    """A recorded mission in a local metric frame (x east, y north, metres).

    Parameters
    ----------
    times : numpy.ndarray
        ``(n,)`` ping times, seconds from ``start_utc``, non-decreasing.
    nav : numpy.ndarray
        ``(n, 2)`` the vehicle's logged navigation position at every ping, metres.
    heading : numpy.ndarray
        ``(n,)`` logged heading, radians clockwise from north.
    beams : numpy.ndarray
        ``(n, b, 3)`` every ping's beams ``(across_m, along_m, value)``: body-frame offsets
        (across positive to starboard, along positive forward) and the measured value in
        map units; rows of NaN pad pings with fewer beams.
    nav_source : {"gnss", "ins"}
        ``"gnss"``: the navigation is an absolute fix (it is the truth, an INS drift may be
        simulated on it); ``"ins"``: it is dead-reckoned (it is the INS to be corrected).
    truth : numpy.ndarray or None
        ``(n, 2)`` independent true positions, metres, when the log has them.
    roll, pitch : numpy.ndarray or None
        ``(n,)`` attitude, radians, when logged.
    velocity : numpy.ndarray or None
        ``(n, 2)`` velocity (east, north), m/s, when logged.
    sigma_position : numpy.ndarray or None
        ``(n,)`` per-axis 1-sigma of the navigation error, metres, when the log states it.
    frame : str or None
        PROJ string of the metric frame (None: the frame of the map it came with).
    start_utc : float or None
        UTC time of ``times == 0``, seconds since 1970-01-01.
    kind : str
        Field measured: ``"depth"``, ``"gravity"`` or ``"magnetic"`` (the primary field,
        whose beams are ``beams``).
    name : str
        Short name for tables and figures.
    meta : dict
        Provenance (source file, reader, counts).
    fields : dict
        The further fields measured at the same pings: kind (other than ``kind``) ->
        ``(n, b_k, 3)`` beams ``(across_m, along_m, value)`` as ``beams``, in that field's
        units (NaN rows: no reading). ``{}``: the one field.
    """

    times: np.ndarray
    nav: np.ndarray
    heading: np.ndarray
    beams: np.ndarray
    nav_source: str = "ins"
    truth: np.ndarray | None = None
    roll: np.ndarray | None = None
    pitch: np.ndarray | None = None
    velocity: np.ndarray | None = None
    sigma_position: np.ndarray | None = None
    frame: str | None = None
    start_utc: float | None = None
    kind: str = "depth"
    name: str = "mission"
    meta: dict = field(default_factory=dict)
    fields: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = np.asarray(self.times).shape[0] if np.ndim(self.times) == 1 else -1
        who = f"mission {self.name!r}"
        if n < 1:
            raise ConfigError(f"{who}: times must be a non-empty 1-D array")
        if self.nav_source not in NAV_SOURCES:
            raise ConfigError(f"{who}: nav_source must be one of {NAV_SOURCES}")
        _check(who, "nav", self.nav, (n, 2))
        _check(who, "heading", self.heading, (n,))
        beams = np.asarray(self.beams, dtype=float)
        if beams.ndim != 3 or beams.shape[0] != n or beams.shape[2] != 3:
            raise ConfigError(f"{who}: beams has shape {beams.shape}, expected ({n}, b, 3)")
        for name, shape in (("truth", (n, 2)), ("roll", (n,)), ("pitch", (n,))):
            if getattr(self, name) is not None:
                _check(who, name, getattr(self, name), shape)
        if self.velocity is not None:
            _check(who, "velocity", self.velocity, (n, 2), finite=False)
        if self.sigma_position is not None:
            _check(who, "sigma_position", self.sigma_position, (n,))
        for kind, extra in self.fields.items():
            extra = np.asarray(extra, dtype=float)
            if kind == self.kind:
                raise ConfigError(f"{who}: further field {kind!r} is the primary field")
            if extra.ndim != 3 or extra.shape[0] != n or extra.shape[2] != 3:
                raise ConfigError(
                    f"{who}: field {kind!r} has shape {extra.shape}, expected ({n}, b, 3)"
                )
        times = np.asarray(self.times, dtype=float)
        if not np.isfinite(times).all() or np.any(np.diff(times) < 0):
            raise ConfigError(f"{who}: times must be finite and non-decreasing")

    # ------------------------------------------------------------------ sizes
    @property
    def n(self) -> int:
        """Number of pings."""
        return int(np.asarray(self.times).shape[0])

    @property
    def beam_count(self) -> int:
        """Beams per ping ``b`` (padded)."""
        return int(self.beams.shape[1])

    @property
    def duration_s(self) -> float:
        """Time from the first to the last ping, seconds."""
        return float(self.times[-1] - self.times[0])

    @property
    def reference(self) -> np.ndarray | None:
        """The ``(n, 2)`` positions errors are judged against.

        The truth, the GNSS navigation, or None when the log has neither.
        """
        if self.truth is not None:
            return np.asarray(self.truth, dtype=float)
        return np.asarray(self.nav, dtype=float) if self.nav_source == "gnss" else None

    # ------------------------------------------------------------------ geometry
    def ping(self, k: int) -> np.ndarray:
        """``(b_k, 3)`` the valid beams of ping ``k`` (rows with any NaN dropped)."""
        rows = np.asarray(self.beams[k], dtype=float)
        return rows[np.isfinite(rows).all(axis=1)]

    def soundings(self) -> np.ndarray:
        """``(m, 3)`` georeferenced soundings ``(x, y, value)`` of every valid beam, metres.

        Each beam's offsets are turned by the ping's heading and added to its navigation
        position (:func:`beam_positions`).
        """
        x, y = beam_positions(self.nav, self.heading, self.beams)
        pts = np.stack([x, y, self.beams[..., 2]], axis=-1).reshape(-1, 3)
        return pts[np.isfinite(pts).all(axis=1)]

    def subset(self, part: slice) -> Mission:
        """The pings ``part`` of the mission (times keep their origin)."""

        def cut(values: np.ndarray) -> np.ndarray:
            return np.asarray(values)[part]

        def cut_optional(values: np.ndarray | None) -> np.ndarray | None:
            return None if values is None else cut(values)

        return replace(
            self,
            times=cut(self.times),
            nav=cut(self.nav),
            heading=cut(self.heading),
            beams=cut(self.beams),
            truth=cut_optional(self.truth),
            roll=cut_optional(self.roll),
            pitch=cut_optional(self.pitch),
            velocity=cut_optional(self.velocity),
            sigma_position=cut_optional(self.sigma_position),
            fields={kind: cut(extra) for kind, extra in self.fields.items()},
        )


def _check(who: str, name: str, value, shape: tuple, finite: bool = True) -> None:
    arr = np.asarray(value, dtype=float)
    if arr.shape != shape:
        raise ConfigError(f"{who}: {name} has shape {arr.shape}, expected {shape}")
    if finite and not np.isfinite(arr).all():
        raise ConfigError(f"{who}: {name} has NaN or infinite values")


def beam_positions(nav, heading, beams) -> tuple[np.ndarray, np.ndarray]:
    """Map positions of every beam of every ping, with per-ping offsets.

    Parameters
    ----------
    nav : numpy.ndarray
        ``(n, 2)`` vehicle positions, metres.
    heading : numpy.ndarray
        ``(n,)`` headings, radians clockwise from north.
    beams : numpy.ndarray
        ``(n, b, 2+)`` offsets ``(across, along, ...)``, metres (across to starboard).

    Returns
    -------
    tuple of numpy.ndarray
        ``(x, y)`` each ``(n, b)``, metres (the convention of
        :func:`geofix.problem.footprint_xy`: starboard is ``(cos psi, -sin psi)``).
    """
    nav = np.asarray(nav, dtype=float)
    s = np.sin(np.asarray(heading, dtype=float))[:, None]
    c = np.cos(np.asarray(heading, dtype=float))[:, None]
    across = np.asarray(beams, dtype=float)[..., 0]
    along = np.asarray(beams, dtype=float)[..., 1]
    return nav[:, 0:1] + across * c + along * s, nav[:, 1:2] - across * s + along * c
