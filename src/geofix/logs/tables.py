"""A mission as two tables, ``nav`` and ``soundings`` (CSV or Parquet), for any logger.

A folder holds ``nav.csv`` and ``soundings.csv`` (or ``nav.parquet`` and
``soundings.parquet``). Column names are fixed; units are in the names.

``nav`` -- one row per navigation record, ``t`` ascending:

=================  ========  ==========================================================
column             required  meaning
=================  ========  ==========================================================
``t``              yes       time, seconds (any origin, the same as the soundings')
``x``, ``y``       one pair  position east / north in the map's metric frame, metres
``lon``, ``lat``   one pair  ... or WGS84 longitude / latitude, degrees
``heading_deg``    yes       heading, degrees clockwise from north
``roll_deg``       no        roll, degrees
``pitch_deg``      no        pitch, degrees
``vx``, ``vy``     no        velocity east / north, m/s
``sigma_m``        no        per-axis 1-sigma of the navigation error, metres
``truth_x/_y``     no        independent true position, metres (or ``truth_lon/_lat``)
=================  ========  ==========================================================

``soundings`` -- one row per beam; the rows of one ping share its ``t``:

================  ========  ===========================================================
column            required  meaning
================  ========  ===========================================================
``t``             yes       ping time, seconds
``across_m``      yes       beam offset to starboard from the vehicle, metres
``along_m``       yes       beam offset forward, metres
``value``         one       measured value in map units, with the map's sign
``depth_m``       one       ... or depth, metres, positive down (stored as ``-depth_m``)
================  ========  ===========================================================

The navigation is interpolated linearly (heading on the unwrapped angle) to every ping
time; a ping more than :data:`MAX_POSE_GAP_S` from the nearest navigation record is an
error, as is a ping outside the navigation's time span.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from geofix.errors import ConfigError
from geofix.logs.mission import Mission

MAX_POSE_GAP_S = 5.0
"""Largest time, seconds, between a ping and the navigation record nearest to it."""
TABLE_SUFFIXES = (".csv", ".parquet")


def read_tables(
    folder: str | Path, frame: str | None = None, nav_source: str | None = None
) -> Mission:
    """Read ``nav`` and ``soundings`` tables from a folder.

    Parameters
    ----------
    folder : str or pathlib.Path
        Folder holding ``nav.csv`` + ``soundings.csv`` or ``nav.parquet`` +
        ``soundings.parquet``.
    frame : str, optional
        PROJ string of the metric frame for ``lon``/``lat`` tables (default: a
        transverse-Mercator frame centred on the navigation).
    nav_source : {"gnss", "ins"}, optional
        What the navigation is; default ``"ins"`` when the table has truth columns,
        else ``"gnss"``.

    Raises
    ------
    ConfigError
        A missing file or column, a ping without navigation near it, bad values.
    """
    folder = Path(folder)
    nav = _read_table(folder, "nav")
    sound = _read_table(folder, "soundings")
    _require(nav, ("t", "heading_deg"), folder / "nav")
    _require(sound, ("t", "across_m", "along_m"), folder / "soundings")
    xy, frame = _positions(nav, "", frame, folder / "nav")
    truth = _truth(nav, frame, folder / "nav")
    if nav_source is None:
        nav_source = "ins" if truth is not None else "gnss"
    ping_t, beams = _pings(sound, folder / "soundings")
    t_nav = nav["t"].to_numpy(float)
    _check_pose_gaps(t_nav, ping_t, folder)

    def at(v):
        return np.interp(ping_t, t_nav, np.asarray(v, dtype=float))

    def opt(col):
        return np.deg2rad(at(nav[col])) if col in nav else None

    def pair(a, b):
        return np.column_stack([at(nav[a]), at(nav[b])]) if a in nav and b in nav else None

    return Mission(
        times=ping_t - ping_t[0],
        nav=np.column_stack([at(xy[:, 0]), at(xy[:, 1])]),
        heading=np.mod(at(np.unwrap(np.deg2rad(nav["heading_deg"].to_numpy(float)))), 2 * np.pi),
        beams=beams,
        nav_source=nav_source,
        truth=None if truth is None else np.column_stack([at(truth[:, 0]), at(truth[:, 1])]),
        roll=opt("roll_deg"),
        pitch=opt("pitch_deg"),
        velocity=pair("vx", "vy"),
        sigma_position=at(nav["sigma_m"]) if "sigma_m" in nav else None,
        frame=frame,
        start_utc=float(ping_t[0]),
        name=folder.name,
        meta={"source": folder.name, "reader": "tables", "pings": int(ping_t.size)},
    )


def write_tables(mission: Mission, folder: str | Path, fmt: str = "csv") -> Path:
    """Write a mission as ``nav`` and ``soundings`` tables (metric ``x``/``y``).

    Times are written as ``start_utc + times`` when the mission has a start time.

    Parameters
    ----------
    mission : Mission
        The mission to write; beams with a non-finite offset or value are left out.
    folder : str or pathlib.Path
        Folder of the two tables (created); ``nav.<fmt>`` and ``soundings.<fmt>``.
    fmt : {"csv", "parquet"}
        Table format.

    Returns
    -------
    pathlib.Path
        ``folder``.

    Raises
    ------
    ConfigError
        An unknown ``fmt``.
    """
    import pandas as pd

    if fmt not in ("csv", "parquet"):
        raise ConfigError(f"table format must be 'csv' or 'parquet', got {fmt!r}")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    t = np.asarray(mission.times, float) + (mission.start_utc or 0.0)
    nav = {"t": t, "x": mission.nav[:, 0], "y": mission.nav[:, 1]}
    nav["heading_deg"] = np.rad2deg(mission.heading)
    for col, value in (("roll_deg", mission.roll), ("pitch_deg", mission.pitch)):
        if value is not None:
            nav[col] = np.rad2deg(value)
    if mission.velocity is not None:
        nav["vx"], nav["vy"] = mission.velocity[:, 0], mission.velocity[:, 1]
    if mission.sigma_position is not None:
        nav["sigma_m"] = mission.sigma_position
    if mission.truth is not None:
        nav["truth_x"], nav["truth_y"] = mission.truth[:, 0], mission.truth[:, 1]
    valid = np.isfinite(mission.beams).all(axis=2)
    k, j = np.nonzero(valid)
    sound = {
        "t": t[k],
        "across_m": mission.beams[k, j, 0],
        "along_m": mission.beams[k, j, 1],
        "value": mission.beams[k, j, 2],
    }
    for name, table in (("nav", nav), ("soundings", sound)):
        frame = pd.DataFrame(table)
        path = folder / f"{name}.{fmt}"
        if fmt == "csv":
            frame.to_csv(path, index=False, float_format="%.17g")
        else:
            frame.to_parquet(path, index=False)
    return folder


def _read_table(folder: Path, stem: str):
    import pandas as pd

    for suffix in TABLE_SUFFIXES:
        path = folder / f"{stem}{suffix}"
        if path.is_file():
            try:
                table = pd.read_csv(path) if suffix == ".csv" else pd.read_parquet(path)
            except Exception as exc:
                raise ConfigError(f"cannot read {path}: {str(exc).splitlines()[0]}") from None
            return numeric_columns(table, path)
    raise ConfigError(f"{folder}: no {stem}.csv or {stem}.parquet")


NUMERIC_COLUMNS = frozenset(
    {
        *("t", "x", "y", "lon", "lat", "heading_deg", "roll_deg", "pitch_deg", "vx", "vy"),
        *("sigma_m", "truth_x", "truth_y", "truth_lon", "truth_lat"),
        *("across_m", "along_m", "value", "depth_m"),
    }
)
"""Columns of the nav, soundings and gridding tables that must hold numbers."""


def numeric_columns(table, path: Path):
    """The table with every column of :data:`NUMERIC_COLUMNS` as float (else ConfigError).

    Empty cells are NaN; text, dates or other objects in such a column are refused with a
    message naming the file, the column, the first bad row (1-based, header excluded)
    and its value.
    """
    import pandas as pd

    for col in [c for c in table.columns if c in NUMERIC_COLUMNS]:
        series = table[col]
        if pd.api.types.is_bool_dtype(series) or not pd.api.types.is_numeric_dtype(series):
            numbers = pd.to_numeric(series, errors="coerce")
            bad = numbers.isna() & series.notna()
            if pd.api.types.is_bool_dtype(series) or bad.any():
                row = int(np.argmax(bad.to_numpy())) if bad.any() else 0
                shown = str(series.iloc[row])[:40] if len(series) else ""
                raise ConfigError(
                    f"{path}: column {col!r} must hold numbers; row {row + 1} holds {shown!r}"
                )
            table[col] = numbers.astype(float)
    return table


def _require(table, columns, where: Path) -> None:
    missing = [c for c in columns if c not in table]
    if missing:
        raise ConfigError(f"{where}: missing column(s) {', '.join(missing)}")


def _positions(nav, prefix: str, frame: str | None, where: Path):
    """``((m, 2) metres, frame)`` from ``x``/``y`` or ``lon``/``lat`` columns."""
    from geofix.maps.project import local_tmerc, project_lonlat

    if f"{prefix}x" in nav and f"{prefix}y" in nav:
        return np.column_stack([nav[f"{prefix}x"], nav[f"{prefix}y"]]).astype(float), frame
    if f"{prefix}lon" in nav and f"{prefix}lat" in nav:
        lon = nav[f"{prefix}lon"].to_numpy(float)
        lat = nav[f"{prefix}lat"].to_numpy(float)
        if frame is None and np.all(np.abs(lat) <= 90):
            frame = local_tmerc(float(np.mean(lon)), float(np.mean(lat)))
        x, y, frame = project_lonlat(lon, lat, frame, str(where))
        return np.column_stack([x, y]), frame
    raise ConfigError(f"{where}: needs columns {prefix}x, {prefix}y or {prefix}lon, {prefix}lat")


def _truth(nav, frame, where: Path):
    if not any(c.startswith("truth_") for c in nav.columns):
        return None
    return _positions(nav, "truth_", frame, where)[0]


def _pings(sound, where: Path) -> tuple[np.ndarray, np.ndarray]:
    """Ping times ``(n,)`` and beams ``(n, b, 3)`` (NaN-padded) from the soundings rows."""
    if "value" in sound:
        value = sound["value"].to_numpy(float)
    elif "depth_m" in sound:
        value = -sound["depth_m"].to_numpy(float)
    else:
        raise ConfigError(f"{where}: needs a value or a depth_m column")
    t = sound["t"].to_numpy(float)
    if t.size == 0 or not np.isfinite(t).all():
        raise ConfigError(f"{where}: no rows, or a time that is NaN")
    ping_t, index, counts = np.unique(t, return_inverse=True, return_counts=True)
    slot = np.zeros(t.size, dtype=int)
    order = np.argsort(index, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    slot[order] = np.arange(t.size) - np.repeat(starts, counts)
    beams = np.full((ping_t.size, int(counts.max()), 3), np.nan)
    beams[index, slot] = np.column_stack([sound["across_m"], sound["along_m"], value])
    return ping_t, beams


def _check_pose_gaps(t_nav: np.ndarray, ping_t: np.ndarray, folder: Path) -> None:
    if t_nav.size == 0 or np.any(np.diff(t_nav) <= 0):
        raise ConfigError(f"{folder / 'nav'}: t must be strictly ascending")
    if ping_t[0] < t_nav[0] or ping_t[-1] > t_nav[-1]:
        raise ConfigError(
            f"{folder}: pings span t {ping_t[0]:g} .. {ping_t[-1]:g} s, "
            f"outside the navigation's {t_nav[0]:g} .. {t_nav[-1]:g} s"
        )
    right = np.clip(np.searchsorted(t_nav, ping_t), 0, t_nav.size - 1)
    left = np.clip(right - 1, 0, t_nav.size - 1)
    gap = np.minimum(np.abs(t_nav[right] - ping_t), np.abs(ping_t - t_nav[left]))
    worst = int(np.argmax(gap))
    if gap[worst] > MAX_POSE_GAP_S:
        raise ConfigError(
            f"{folder}: ping at t = {ping_t[worst]:g} s is {gap[worst]:.3g} s from the nearest "
            f"navigation record (at most {MAX_POSE_GAP_S:g} s)"
        )
