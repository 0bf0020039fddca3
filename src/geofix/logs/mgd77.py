"""Ship tracklines in NOAA's MGD77T format as logged missions: :func:`read_mgd77`.

An MGD77T file (NOAA NCEI's tab-separated marine geophysical trackline exchange format)
holds one record per time step of a survey ship: date, time, time-zone correction, the
ship's position, and where observed a corrected depth (``CORR_DEPTH``, metres positive
down), a free-air gravity anomaly (``FREEAIR``, mGal) and a residual magnetic field
(``MAG_RES``, nT), each with a quality code. A header line names the columns; blank fields
are missing values and trailing blank fields may be left out.

The ship's navigation is an absolute fix, so every mission has ``nav_source = "gnss"``
(the track is the truth, and a replay simulates an INS drift on it), whatever the era:
``meta["navigation"]`` says how good that truth is (GNSS after selective availability
ended on 2000-05-02, GNSS with it, or pre-GNSS Transit and dead reckoning before 1985).

Reading, in order (every count lands in ``meta["file"]``):

1. **Positions.** A record without a readable latitude and longitude, or whose
   ``NAV_QUALCO`` is bad, has no position and is dropped with its values. A single record
   more than ``max_jump_m`` from both neighbours while they are within ``max_jump_m`` of
   each other is a position spike and is dropped too.
2. **Values.** A channel's value is missing where its field is blank or not a number, or
   where its quality code (``BAT_QUALCO``, ``GRA_QUALCO``, ``MAG_QUALCO``) is bad.
   Records without any channel value are kept: they carry the track and its times.
3. **Times.** ``DATE`` + ``TIME`` (``HHMM.mm``) + ``TIMEZONE`` hours is UTC (the MGD77
   rule: corrections are added; a blank ``TIMEZONE`` is 0). A ``TIME`` is unreadable when
   blank, not a number, outside ``0000 .. 2359.99``, with minutes ``>= 60``, or with an
   unreadable date or time zone. Two neighbouring records with the same time and the same
   position are one record logged twice (merged: the first keeps its values, the second
   fills those it lacks); a record repeating the previous record's time at another
   position has a stale time. Readable times that run backwards are garbled: the largest
   set of records whose times increase strictly is kept (a longest increasing
   subsequence), the others lose their time. A garbled run of more than
   :data:`MAX_GARBLED_RUN` records is no longer a glitch: the track is split around it.
4. **Pieces.** The track is split where neighbouring positions are more than
   ``max_jump_m`` apart.
5. **Placing times.** Within a piece, a record without a usable time is placed by its
   order and its distance along the track: times are interpolated linearly, between the
   readable neighbours, in a coordinate that adds for each record its distance from the
   previous one plus the piece's median such distance (distance and order weigh alike;
   a ship at rest is placed by order, one under way by both); before the first and after
   the last readable time, the piece's median speed in that coordinate between readable
   neighbours extrapolates. One warning per file gives the count (``GeofixWarning``).
6. **Segments.** A piece is split where neighbouring records are more than ``max_gap_s``
   apart in time. In a segment, each field's mission holds the records with a value of
   that field (one beam at offset ``(0, 0)``), split again where its values are more than
   ``max_gap_s`` apart; missions shorter than ``min_segment_s`` are dropped.
   Read ``joint``, a segment gives one mission of every field instead: the records with
   a value of any of them (split where those are more than ``max_gap_s`` apart), the
   first field's beams the mission's own and the others' in :attr:`Mission.fields`,
   NaN where a record lacks that field.
"""

from __future__ import annotations

import warnings
from bisect import bisect_left
from dataclasses import dataclass, field, replace
from itertools import pairwise
from pathlib import Path

import numpy as np

from geofix.errors import ConfigError, GeofixWarning
from geofix.logs.mission import Mission
from geofix.memory import cells_bytes, check_allocation

MGD77T_SUFFIXES = (".m77t",)
"""File name endings :func:`geofix.logs.read_mission` reads as MGD77T."""

FIELDS = {
    "depth": ("CORR_DEPTH", "BAT_QUALCO", "m"),
    "gravity": ("FREEAIR", "GRA_QUALCO", "mGal"),
    "magnetic": ("MAG_RES", "MAG_QUALCO", "nT"),
}
"""Channels: field name -> (value column, quality column, unit of the mission's values)."""

REQUIRED_COLUMNS = ("TIMEZONE", "DATE", "TIME", "LAT", "LON")
"""Columns every MGD77T file read here must name in its header line."""

BAD_QUALITY_CODES = frozenset({4, 5, 6})
"""MGD77T quality codes that mark a value (or a position) as missing: 4 bad, 5 suspected
bad by the contributor, 6 suspected bad by the data center. Codes 1 (good), 2 (fair),
3 (poor) and blank (unspecified) keep the value."""

DEFAULT_MIN_SEGMENT_S = 3600.0
"""Shortest mission kept, seconds. An hour at the 5-6 m/s these ships steam is 18-22 km
of track, about ten cells of a 1-arc-minute gravity grid: less is too short a profile for
a map fix."""

DEFAULT_MAX_GAP_S = 900.0
"""Largest time between neighbouring records (and between neighbouring values of one
field) inside a mission, seconds. Cruises of 1973-2001 log a record every 1-3 minutes
and a field's values every 1-5 minutes (99 % of the gaps between the depths of a 1979
cruise, digitised at irregular times, are under 12 minutes); 15 minutes is above those
intervals and below the hour-long stops that mark an instrument or a navigation break."""

DEFAULT_MAX_JUMP_M = 5000.0
"""Largest distance between neighbouring positions inside a piece, metres. A ship at the
files' typical 5.5 m/s covers 5 km in ``DEFAULT_MAX_GAP_S``; neighbouring records a minute
apart are at most 0.5 km apart in the GNSS-era files, while breaks between legs (and a
position spike) in older files are kilometres to hundreds of kilometres."""

MAX_GARBLED_RUN = 30
"""Most consecutive readable times dropped as garbled before the track is split around
them instead (a leg logged out of order is not a glitch)."""

ORDER_STEP_M = 1.0
"""Least distance credited to each record when placing times, metres (keeps the placed
times of a track that never moves increasing)."""

EARTH_RADIUS_M = 6371008.8
"""Mean Earth radius, metres (great-circle distances between records)."""

MIN_COURSE_STEP_M = 5.0
"""Smallest displacement over two records that gives a course, metres; below it (a ship
at rest, GNSS jitter) the last course is held."""

_SAME_POSITION_DEG = 1e-7
"""Positions closer than this in latitude and longitude, degrees, are the same (1 cm)."""

_BYTES_PER_CELL = 96
"""Memory per table cell while parsing (a Python string and its numeric copy), bytes."""

_MIN_RECORD_BYTES = 24
"""Shortest plausible MGD77T data line, bytes (sizes the parse before it runs)."""


@dataclass
class _Track:
    """The records that have a position, in file order."""

    record: np.ndarray  # (m,) 0-based data record numbers in the file
    lon: np.ndarray
    lat: np.ndarray
    t: np.ndarray  # UTC seconds since 1970, NaN where unreadable
    values: dict[str, np.ndarray]
    survey: str
    source: str
    counts: dict = field(default_factory=dict)


@dataclass
class _Segment:
    """A continuous stretch of the track, times placed."""

    rows: np.ndarray  # indices into the _Track
    t: np.ndarray  # UTC seconds, strictly increasing
    placed: np.ndarray  # bool: time placed by distance


def read_mgd77(
    path: str | Path,
    fields: tuple[str, ...] | list[str] = ("depth",),
    min_segment_s: float = DEFAULT_MIN_SEGMENT_S,
    max_gap_s: float = DEFAULT_MAX_GAP_S,
    max_jump_m: float = DEFAULT_MAX_JUMP_M,
    frame: str | None = None,
    joint: bool = False,
) -> list[Mission]:
    """Read an MGD77T trackline file as missions, one per continuous segment and field.

    The module text states every rule (quality codes, time repairs, splits).

    Parameters
    ----------
    path : str or pathlib.Path
        The ``.m77t`` file (tab-separated, with its header line).
    fields : sequence of {"depth", "gravity", "magnetic"}
        Channels to read: ``depth`` (``CORR_DEPTH``, stored as elevation ``-depth``,
        metres, negative below sea level like geofix depth maps), ``gravity``
        (``FREEAIR``, mGal), ``magnetic`` (``MAG_RES``, nT).
    min_segment_s : float
        Shortest mission kept, seconds (:data:`DEFAULT_MIN_SEGMENT_S`).
    max_gap_s : float
        Largest time between neighbouring records or values in a mission, seconds
        (:data:`DEFAULT_MAX_GAP_S`).
    max_jump_m : float
        Largest distance between neighbouring positions in a mission, metres
        (:data:`DEFAULT_MAX_JUMP_M`).
    frame : str, optional
        PROJ string of the metric frame (a map's projection); by default each segment
        gets a transverse-Mercator frame centred on it
        (:func:`geofix.maps.project.local_tmerc`), shared by its fields' missions.
    joint : bool
        One mission per segment holding every field of ``fields`` (the first its
        ``kind`` and ``beams``, the others in ``Mission.fields``, NaN where a record
        lacks one), over the records with a value of any of them; ``meta["fields"]``
        names them and ``meta["field_pings"]`` counts each one's values.

    Returns
    -------
    list of Mission
        In time order, and by ``fields`` order within a segment. Each has
        ``nav_source = "gnss"``, ``truth`` equal to ``nav``, ``heading`` the course over
        ground, one beam ``(0, 0, value)`` per ping and ``kind`` the field name.
        ``meta`` holds ``source``, ``reader`` (``"mgd77"``), ``survey_id``, ``field``,
        ``column``, ``units``, ``segment`` (index of the continuous segment),
        ``records`` (0-based data record numbers of the pings), ``lon`` / ``lat``
        (degrees), ``placed`` (bool per ping: time placed by distance),
        ``placed_by_distance`` (their count), ``navigation`` (``"gnss"``, ``"gnss-sa"``
        or ``"pre-gnss"``), ``nav_error_m`` (its order of magnitude: 10, 100, 500 m)
        and ``file`` (the file's counts).

    Raises
    ------
    ConfigError
        A missing file, a file that is not MGD77T (no tab-separated header line naming
        ``TIMEZONE``, ``DATE``, ``TIME``, ``LAT``, ``LON``), a missing value column, an
        unknown field, bad limits, or no record with a position and a usable time, or
        no mission as long as ``min_segment_s``.

    Warns
    -----
    GeofixWarning
        Once per file, when record times were placed by distance (with their count).
    """
    path = Path(path)
    fields = _check_arguments(path, fields, min_segment_s, max_gap_s, max_jump_m)
    table = _read_table(path, fields)
    track = _track(table, fields, path, max_jump_m)
    segments = _segments(track, max_jump_m, max_gap_s)
    placed = sum(int(s.placed.sum()) for s in segments)
    track.counts["placed_by_distance"] = placed
    if placed:
        warnings.warn(
            f"{path}: {placed} of {track.record.size} record times were blank or garbled "
            "and were placed by distance along the track",
            GeofixWarning,
            stacklevel=2,
        )
    missions = []
    for index, segment in enumerate(segments):
        missions += _segment_missions(
            track, segment, index, fields, frame, (min_segment_s, max_gap_s), joint
        )
    if not missions:
        raise ConfigError(
            f"{path}: no {'/'.join(fields)} segment of at least {min_segment_s:g} s "
            f"(records with a position and a time: {track.record.size})"
        )
    return [
        replace(m, name=f"{path.stem}-{'+'.join([m.kind, *m.fields])}-{k}")
        for k, m in enumerate(missions)
    ]


def longest_mission(path: str | Path, frame: str | None = None) -> Mission:
    """The longest depth mission of an MGD77T file (its longest gravity one without depths).

    What :func:`geofix.logs.read_mission` returns for a ``.m77t`` file: one mission,
    read with the default limits of :func:`read_mgd77`.

    Parameters
    ----------
    path : str or pathlib.Path
        The ``.m77t`` file.
    frame : str, optional
        PROJ string of the metric frame (default: one centred on the mission's segment).

    Returns
    -------
    Mission
        The longest (in time) mission of the first of ``depth``, ``gravity`` that has
        one; ties go to the earlier.

    Raises
    ------
    ConfigError
        As :func:`read_mgd77`.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"MGD77T file not found: {path}")
    header = _header(path)
    fields = tuple(f for f in ("depth", "gravity") if FIELDS[f][0] in header) or ("depth",)
    missions = read_mgd77(path, fields=fields, frame=frame)
    kind = next(f for f in fields if any(m.kind == f for m in missions))
    return max((m for m in missions if m.kind == kind), key=lambda m: m.duration_s)


# ---------------------------------------------------------------------- reading
def _check_arguments(path: Path, fields, min_segment_s, max_gap_s, max_jump_m) -> tuple:
    if isinstance(fields, str):
        fields = (fields,)
    fields = tuple(dict.fromkeys(fields))
    unknown = [f for f in fields if f not in FIELDS]
    if not fields or unknown:
        raise ConfigError(
            f"{path}: unknown MGD77T field(s) {unknown or 'none given'}; "
            f"choose from {', '.join(FIELDS)}"
        )
    for name, value in (
        ("min_segment_s", min_segment_s),
        ("max_gap_s", max_gap_s),
        ("max_jump_m", max_jump_m),
    ):
        if not (np.isfinite(value) and value >= 0):
            raise ConfigError(f"{path}: {name} must be a finite number >= 0, got {value!r}")
    if max_gap_s <= 0 or max_jump_m <= 0:
        raise ConfigError(f"{path}: max_gap_s and max_jump_m must be > 0")
    if not path.is_file():
        raise ConfigError(f"MGD77T file not found: {path}")
    return fields


def _read_table(path: Path, fields: tuple[str, ...]):
    """The needed columns of the file as strings (blank where missing)."""
    import pandas as pd

    header = _header(path)
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    missing += [FIELDS[f][0] for f in fields if FIELDS[f][0] not in header]
    if missing:
        raise ConfigError(f"{path}: MGD77T header lacks column(s) {', '.join(missing)}")
    wanted = [*REQUIRED_COLUMNS, "SURVEY_ID", "NAV_QUALCO"]
    wanted += [c for f in fields for c in FIELDS[f][:2]]
    usecols = [c for c in dict.fromkeys(wanted) if c in header]
    lines = path.stat().st_size / _MIN_RECORD_BYTES
    check_allocation(
        cells_bytes(lines, len(usecols), itemsize=_BYTES_PER_CELL), f"reading MGD77T {path}"
    )
    try:
        table = pd.read_csv(
            path,
            sep="\t",
            dtype=str,
            keep_default_na=False,
            usecols=usecols,
            index_col=False,  # a record with extra fields must not shift the columns
            encoding="latin-1",
        )
    except Exception as exc:
        raise ConfigError(f"cannot read MGD77T file {path}: {str(exc).splitlines()[0]}") from None
    return table


def _header(path: Path) -> list[str]:
    with path.open("rb") as handle:
        first = handle.readline(65536)
    text = first.decode("latin-1").strip()
    columns = [c.strip() for c in text.split("\t")]
    if b"\0" in first or not set(columns) & set(REQUIRED_COLUMNS):
        raise ConfigError(
            f"{path}: not an MGD77T file (its first line must be the tab-separated header "
            f"naming {', '.join(REQUIRED_COLUMNS)}, ...)"
        )
    return columns


def _column(table, name: str) -> np.ndarray:
    """A column as stripped strings (blank where the file has none)."""
    if name not in table:
        return np.full(len(table), "", dtype=object)
    return table[name].astype(str).str.strip().to_numpy(dtype=object)


def _numbers(text: np.ndarray) -> np.ndarray:
    import pandas as pd

    numbers = pd.to_numeric(pd.Series(text, dtype=object), errors="coerce")
    return np.array(numbers, dtype=float)  # a writable copy


def _bad_quality(table, column: str) -> np.ndarray:
    codes = _numbers(_column(table, column))
    return np.isin(codes, sorted(BAD_QUALITY_CODES))


def _track(table, fields: tuple[str, ...], path: Path, max_jump_m: float) -> _Track:
    """Positions, UTC times and channel values of the records that have a position."""
    n = len(table)
    counts: dict = {"records": n}
    lon = _numbers(_column(table, "LON"))
    lat = _numbers(_column(table, "LAT"))
    bad_nav = _bad_quality(table, "NAV_QUALCO")
    has_position = np.isfinite(lon) & np.isfinite(lat) & (np.abs(lat) <= 90) & (np.abs(lon) <= 180)
    counts["no_position"] = int(np.count_nonzero(~has_position))
    counts["bad_nav_quality"] = int(np.count_nonzero(has_position & bad_nav))
    t, blank, garbled = _utc_times(table)
    values = {}
    for name in fields:
        column, quality, _ = FIELDS[name]
        v = _numbers(_column(table, column))
        bad = _bad_quality(table, quality) & np.isfinite(v)
        v[bad] = np.nan
        counts[f"{name}_bad_quality"] = int(np.count_nonzero(bad))
        values[name] = v
    keep = np.flatnonzero(has_position & ~bad_nav)
    survey = next((s for s in _column(table, "SURVEY_ID") if s), path.stem)
    track = _Track(
        record=keep,
        lon=lon[keep],
        lat=lat[keep],
        t=t[keep],
        values={k: v[keep] for k, v in values.items()},
        survey=str(survey),
        source=path.name,
        counts=counts,
    )
    counts["blank_time"] = int(np.count_nonzero(blank[keep]))
    counts["garbled_time"] = int(np.count_nonzero(garbled[keep]))
    _drop_spikes(track, max_jump_m)
    _merge_duplicates(track)
    if track.record.size == 0 or not np.isfinite(track.t).any():
        raise ConfigError(f"{path}: no MGD77T record with a position and a readable time")
    for name in fields:
        counts[f"{name}_values"] = int(np.count_nonzero(np.isfinite(track.values[name])))
    return track


def _utc_times(table) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """UTC seconds since 1970 (NaN unreadable), and the blank and garbled masks."""
    import pandas as pd

    text = _column(table, "TIME")
    blank = text == ""
    clock = _numbers(text)
    hours = np.floor(clock / 100.0)
    minutes = clock - 100.0 * hours
    clock_ok = np.isfinite(clock) & (clock >= 0) & (clock < 2400) & (minutes < 60)
    date = pd.to_datetime(
        pd.Series(_column(table, "DATE"), dtype=object), format="%Y%m%d", errors="coerce"
    )
    day_s = (date - pd.Timestamp("1970-01-01")).dt.total_seconds().to_numpy(float)
    zone_text = _column(table, "TIMEZONE")
    zone = np.where(zone_text == "", 0.0, _numbers(zone_text))
    zone_ok = np.isfinite(zone) & (np.abs(zone) <= 13)
    ok = clock_ok & np.isfinite(day_s) & zone_ok
    t = np.where(ok, day_s + 3600.0 * hours + 60.0 * minutes + 3600.0 * zone, np.nan)
    return t, blank, ~blank & ~ok


def _distance_m(lon1, lat1, lon2, lat2) -> np.ndarray:
    """Great-circle distance, metres (haversine on the mean sphere)."""
    p1, p2 = np.radians(lat1), np.radians(lat2)
    dl = np.radians(np.asarray(lon2) - np.asarray(lon1))
    a = np.sin((p2 - p1) / 2) ** 2 + np.cos(p1) * np.cos(p2) * np.sin(dl / 2) ** 2
    return 2.0 * EARTH_RADIUS_M * np.arcsin(np.sqrt(np.clip(a, 0.0, 1.0)))


def _steps_m(track: _Track) -> np.ndarray:
    """``(m - 1,)`` distance between neighbouring records, metres."""
    return _distance_m(track.lon[:-1], track.lat[:-1], track.lon[1:], track.lat[1:])


def _take(track: _Track, keep: np.ndarray) -> None:
    track.record, track.lon, track.lat, track.t = (
        track.record[keep],
        track.lon[keep],
        track.lat[keep],
        track.t[keep],
    )
    track.values = {k: v[keep] for k, v in track.values.items()}


def _drop_spikes(track: _Track, max_jump_m: float) -> None:
    """Drop single records far from both neighbours that are close to each other."""
    spikes = np.zeros(track.record.size, dtype=bool)
    if track.record.size >= 3:
        step = _steps_m(track)
        skip = _distance_m(track.lon[:-2], track.lat[:-2], track.lon[2:], track.lat[2:])
        spikes[1:-1] = (step[:-1] > max_jump_m) & (step[1:] > max_jump_m) & (skip <= max_jump_m)
    track.counts["position_spikes"] = int(np.count_nonzero(spikes))
    _take(track, ~spikes)


def _merge_duplicates(track: _Track) -> None:
    """Merge neighbours logged twice; a repeated time at a new position becomes unreadable."""
    m = track.record.size
    same_time = np.zeros(m, dtype=bool)
    same_time[1:] = np.isfinite(track.t[1:]) & (track.t[1:] == track.t[:-1])
    same_place = np.zeros(m, dtype=bool)
    same_place[1:] = (np.abs(np.diff(track.lon)) < _SAME_POSITION_DEG) & (
        np.abs(np.diff(track.lat)) < _SAME_POSITION_DEG
    )
    duplicate = same_time & same_place
    keep = np.ones(m, dtype=bool)
    for k in np.flatnonzero(duplicate):
        first = k - 1
        while not keep[first]:
            first -= 1
        for v in track.values.values():
            if not np.isfinite(v[first]):
                v[first] = v[k]
        keep[k] = False
    stale = same_time & ~same_place
    track.t[stale] = np.nan
    track.counts["duplicates_merged"] = int(np.count_nonzero(duplicate))
    track.counts["stale_time"] = int(np.count_nonzero(stale))
    _take(track, keep)


# ---------------------------------------------------------------------- times
def increasing_subsequence(values: np.ndarray) -> np.ndarray:
    """Indices of a longest strictly increasing subsequence of ``values``.

    Parameters
    ----------
    values : numpy.ndarray
        ``(n,)`` finite numbers.

    Returns
    -------
    numpy.ndarray
        Increasing indices into ``values`` (patience sorting, ``O(n log n)``; among equally
        long answers, the one ending on the latest elements).
    """
    tails: list[float] = []
    tail_index: list[int] = []
    parent = np.full(len(values), -1, dtype=int)
    for i, v in enumerate(np.asarray(values, dtype=float)):
        j = bisect_left(tails, v)
        if j == len(tails):
            tails.append(v)
            tail_index.append(i)
        else:
            tails[j], tail_index[j] = v, i
        parent[i] = tail_index[j - 1] if j > 0 else -1
    out = []
    i = tail_index[-1] if tail_index else -1
    while i >= 0:
        out.append(i)
        i = parent[i]
    return np.array(out[::-1], dtype=int)


def _pieces(track: _Track, max_jump_m: float) -> list[tuple[int, int]]:
    """``[start, stop)`` row ranges without a jump larger than ``max_jump_m``."""
    cuts = np.flatnonzero(_steps_m(track) > max_jump_m) + 1
    bounds = [0, *cuts.tolist(), track.record.size]
    return [(a, b) for a, b in pairwise(bounds) if b > a]


def _anchored(t: np.ndarray, start: int, stop: int) -> list[tuple[int, int, np.ndarray]]:
    """Split ``[start, stop)`` around long garbled runs; each part with its anchor rows."""
    rows = start + np.flatnonzero(np.isfinite(t[start:stop]))
    if rows.size == 0:
        return [(start, stop, rows)]
    kept = np.zeros(rows.size, dtype=bool)
    kept[increasing_subsequence(t[rows])] = True
    dropped = np.flatnonzero(~kept)
    if dropped.size:
        runs = np.split(dropped, np.flatnonzero(np.diff(dropped) > 1) + 1)
        long = [r for r in runs if r.size > MAX_GARBLED_RUN]
        if long:
            run = long[0]
            lo, hi = int(rows[run[0]]), int(rows[run[-1]]) + 1
            parts = [(start, lo), (lo, hi), (hi, stop)]
            return [p for a, b in parts if b > a for p in _anchored(t, a, b)]
    return [(start, stop, rows[kept])]


def _segments(track: _Track, max_jump_m: float, max_gap_s: float) -> list[_Segment]:
    """Continuous segments with every record's time placed."""
    parts = [p for a, b in _pieces(track, max_jump_m) for p in _anchored(track.t, a, b)]
    readable = int(np.count_nonzero(np.isfinite(track.t)))
    anchors = sum(p[2].size for p in parts)
    track.counts["time_out_of_order"] = readable - anchors
    step = np.concatenate([[0.0], _steps_m(track)])
    rates = [_rates(step, a, b, rows, track.t) for a, b, rows in parts]
    every = np.concatenate(rates) if rates else np.array([])
    file_rate = float(np.median(every)) if every.size else np.nan
    segments: list[_Segment] = []
    unplaced = 0
    for (a, b, rows), rate in zip(parts, rates, strict=True):
        own = float(np.median(rate)) if rate.size else file_rate
        placed = _place(step, a, b, rows, track.t, own)
        if placed is None:
            unplaced += b - a
            continue
        t, was_placed = placed
        cuts = np.flatnonzero(np.diff(t) > max_gap_s) + 1
        for lo, hi in zip([0, *cuts.tolist()], [*cuts.tolist(), t.size], strict=True):
            segments.append(_Segment(np.arange(a + lo, a + hi), t[lo:hi], was_placed[lo:hi]))
    track.counts["unplaceable"] = unplaced
    segments.sort(key=lambda s: s.t[0])
    return segments


def _along(step: np.ndarray, a: int, b: int) -> np.ndarray:
    """Placing coordinate of rows ``a .. b-1``, metres: distance and order weighed alike.

    Each record adds its distance from the previous one plus the piece's median distance
    between neighbours (at least :data:`ORDER_STEP_M`), so a record is placed by how far
    the ship went and by how many records it logged meanwhile.
    """
    inner = step[a + 1 : b]
    per_record = max(float(np.median(inner)) if inner.size else 0.0, ORDER_STEP_M)
    return np.concatenate([[0.0], np.cumsum(inner + per_record)])


def _rates(step, a: int, b: int, rows: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Along-track speeds (m/s, see :func:`_along`) between neighbouring anchors."""
    if rows.size < 2:
        return np.array([])
    u = _along(step, a, b)[rows - a]
    return np.diff(u) / np.diff(t[rows])


def _place(step, a: int, b: int, rows: np.ndarray, t: np.ndarray, rate: float):
    """Times of rows ``a .. b-1`` (anchors kept, the others placed), or None."""
    if rows.size == 0 or (rows.size < b - a and not (np.isfinite(rate) and rate > 0)):
        return None
    u = _along(step, a, b)
    ua, ta = u[rows - a], t[rows]
    placed_t = np.interp(u, ua, ta)
    before, after = u < ua[0], u > ua[-1]
    placed_t[before] = ta[0] - (ua[0] - u[before]) / rate
    placed_t[after] = ta[-1] + (u[after] - ua[-1]) / rate
    was_placed = np.ones(b - a, dtype=bool)
    was_placed[rows - a] = False
    placed_t[rows - a] = ta
    return placed_t, was_placed


# ---------------------------------------------------------------------- missions
def _navigation_era(utc_s: float) -> tuple[str, float]:
    """``(label, order of the position error in metres)`` of a cruise's navigation."""
    if utc_s < 473385600.0:  # 1985-01-01: Transit and dead reckoning before
        return "pre-gnss", 500.0
    if utc_s < 957225600.0:  # 2000-05-02: GPS selective availability switched off
        return "gnss-sa", 100.0
    return "gnss", 10.0


def _frame_of(lon: np.ndarray, lat: np.ndarray) -> str:
    from geofix.maps.project import local_tmerc

    angle = np.radians(lon)
    lon0 = float(np.degrees(np.arctan2(np.sin(angle).mean(), np.cos(angle).mean())))
    return local_tmerc(lon0, float(np.mean(lat)))


def course_over_ground(xy: np.ndarray) -> np.ndarray:
    """Heading along a track from its positions, radians clockwise from north.

    Parameters
    ----------
    xy : numpy.ndarray
        ``(n, 2)`` positions east / north, metres.

    Returns
    -------
    numpy.ndarray
        ``(n,)`` course in ``[0, 2 pi)`` from the displacement between each record's
        neighbours; where it is under :data:`MIN_COURSE_STEP_M` (a ship at rest) the
        previous course is held (the first course for the leading records, 0 when the
        track never moves).
    """
    xy = np.asarray(xy, dtype=float)
    if xy.shape[0] < 2:
        return np.zeros(xy.shape[0])
    d = np.gradient(xy, axis=0) * 2.0
    heading = np.mod(np.arctan2(d[:, 0], d[:, 1]), 2.0 * np.pi)
    moving = np.hypot(d[:, 0], d[:, 1]) >= MIN_COURSE_STEP_M
    if not moving.any():
        return np.zeros(xy.shape[0])
    last = np.maximum.accumulate(np.where(moving, np.arange(moving.size), -1))
    last[last < 0] = int(np.argmax(moving))
    return heading[last]


def _segment_missions(
    track: _Track,
    segment: _Segment,
    index: int,
    fields: tuple[str, ...],
    frame: str | None,
    limits: tuple[float, float],
    joint: bool = False,
) -> list[Mission]:
    """The missions of one segment: per field (or for all ``joint``), split where they pause."""
    from geofix.maps.project import frame_proj

    min_segment_s, max_gap_s = limits
    rows = segment.rows
    lon, lat = track.lon[rows], track.lat[rows]
    seg_frame = frame or _frame_of(lon, lat)
    x, y = frame_proj(seg_frame, "MGD77 segment frame")(lon, lat)
    xy = np.column_stack([x, y])
    heading = course_over_ground(xy)
    era, error_m = _navigation_era(float(segment.t[0]))
    missions = []
    groups = [fields] if joint else [(name,) for name in fields]
    for names in groups:
        values = {name: track.values[name][rows] for name in names}
        found = np.zeros(rows.size, dtype=bool)
        for value in values.values():
            found |= np.isfinite(value)
        has = np.flatnonzero(found)
        cuts = np.flatnonzero(np.diff(segment.t[has]) > max_gap_s) + 1
        for part in np.split(has, cuts) if has.size else []:
            t = segment.t[part]
            if t[-1] - t[0] < min_segment_s or (min_segment_s > 0 and part.size < 2):
                continue
            name = names[0]
            column, _, units = FIELDS[name]
            beams = {
                kind: np.column_stack(
                    [np.zeros((part.size, 2)), -value[part] if kind == "depth" else value[part]]
                )[:, None, :]
                for kind, value in values.items()
            }
            extra = {}
            if joint:
                extra = {
                    "fields": list(names),
                    "field_pings": {
                        kind: int(np.isfinite(value[part]).sum()) for kind, value in values.items()
                    },
                }
            missions.append(
                Mission(
                    times=t - t[0],
                    nav=xy[part],
                    heading=heading[part],
                    beams=beams[name],
                    fields={kind: beams[kind] for kind in names[1:]},
                    nav_source="gnss",
                    truth=xy[part].copy(),
                    frame=seg_frame,
                    start_utc=float(t[0]),
                    kind=name,
                    meta={
                        "source": track.source,
                        "reader": "mgd77",
                        "survey_id": track.survey,
                        "field": name,
                        "column": column,
                        "units": units,
                        "segment": index,
                        "records": track.record[rows[part]],
                        "lon": lon[part],
                        "lat": lat[part],
                        "placed": segment.placed[part],
                        "placed_by_distance": int(np.count_nonzero(segment.placed[part])),
                        "navigation": era,
                        "nav_error_m": error_m,
                        "file": track.counts,
                        **extra,
                    },
                )
            )
    return missions


# ---------------------------------------------------------------------- one segment
def field_segments(
    path: str | Path, field_name: str | None = None, frame: str | None = None
) -> tuple[str, list[Mission]]:
    """The field a replay of an MGD77T file uses and its missions (segments) in time order.

    Parameters
    ----------
    path : str or pathlib.Path
        The ``.m77t`` file.
    field_name : {"depth", "gravity", "magnetic"}, optional
        The channel; by default ``depth``, or ``gravity`` for a file without depths (as
        :func:`longest_mission`).
    frame : str, optional
        PROJ string of the metric frame (a map's projection).

    Returns
    -------
    tuple
        ``(field, missions)``: the missions of that field read with the default limits of
        :func:`read_mgd77`, in time order; segment ``N`` of ``geofix replay --segment N``
        is ``missions[N]``.

    Raises
    ------
    ConfigError
        An unknown field, a file without that field's column or without one segment of
        it as long as :data:`DEFAULT_MIN_SEGMENT_S`, or a reader's error.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"MGD77T file not found: {path}")
    if field_name is None:
        header = _header(path)
        field_name = next((f for f in ("depth", "gravity") if FIELDS[f][0] in header), "depth")
    if field_name not in FIELDS:
        raise ConfigError(f"unknown --field {field_name!r}; choose from {', '.join(FIELDS)}")
    column, _, units = FIELDS[field_name]
    if column not in _header(path):
        raise ConfigError(f"{path.name} has no {field_name} ({column} column): try another --field")
    try:
        missions = read_mgd77(path, fields=(field_name,), frame=frame)
    except ConfigError as exc:
        if "no " in str(exc) and "segment of at least" in str(exc):
            raise ConfigError(
                f"{path.name} has no {field_name} ({column}, {units}) segment of at least "
                f"{DEFAULT_MIN_SEGMENT_S / 3600:g} h: try another --field"
            ) from None
        raise
    return field_name, missions


def joint_segments(
    path: str | Path, field_names, frame: str | None = None
) -> tuple[str, list[Mission]]:
    """The missions of several fields of an MGD77T file together, segments in time order.

    What ``geofix replay --field depth --field gravity`` replays: :func:`read_mgd77`
    with ``joint`` (the first field the primary, every record with a value of any field;
    a field missing at a record is NaN there) and the default limits.

    Parameters
    ----------
    path : str or pathlib.Path
        The ``.m77t`` file.
    field_names : sequence of {"depth", "gravity", "magnetic"}
        The channels, the primary first, each once.
    frame : str, optional
        PROJ string of the metric frame (a map's projection).

    Returns
    -------
    tuple
        ``("depth+gravity", missions)``: the label of the fields and their missions;
        segment ``N`` of ``geofix replay --segment N`` is ``missions[N]``.

    Raises
    ------
    ConfigError
        An unknown or repeated field, a file without a field's column, no segment of the
        fields as long as :data:`DEFAULT_MIN_SEGMENT_S`, or a reader's error.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"MGD77T file not found: {path}")
    names = tuple(field_names)
    unknown = [f for f in names if f not in FIELDS]
    if not names or unknown:
        raise ConfigError(
            f"unknown --field {', '.join(map(repr, unknown)) or '(none)'}; "
            f"choose from {', '.join(FIELDS)}"
        )
    if len(set(names)) != len(names):
        raise ConfigError(f"--field names a channel twice: {', '.join(names)}")
    header = _header(path)
    for name in names:
        column = FIELDS[name][0]
        if column not in header:
            raise ConfigError(f"{path.name} has no {name} ({column} column): try another --field")
    label = "+".join(names)
    try:
        missions = read_mgd77(path, fields=names, frame=frame, joint=True)
    except ConfigError as exc:
        if "segment of at least" in str(exc):
            raise ConfigError(
                f"{path.name} has no {label} segment of at least "
                f"{DEFAULT_MIN_SEGMENT_S / 3600:g} h: try other --field channels"
            ) from None
        raise
    return label, missions


def pick_segment(missions: list[Mission], segment: int | None, label: str = "") -> Mission:
    """Segment ``segment`` of a field's missions, or the longest (ties: the earlier).

    Parameters
    ----------
    missions : list of Mission
        One field's missions in time order (:func:`field_segments`).
    segment : int, optional
        0-based segment number; None picks the longest.
    label : str
        The file and field named in an error.

    Raises
    ------
    ConfigError
        ``segment`` is out of range (the message lists every segment's length, hours).
    """
    if not missions:
        raise ConfigError(f"{label}: no segment")
    if segment is None:
        return max(missions, key=lambda m: m.duration_s)
    if isinstance(segment, bool) or not 0 <= int(segment) < len(missions):
        lengths = ", ".join(f"{k}: {m.duration_s / 3600:.1f} h" for k, m in enumerate(missions))
        raise ConfigError(
            f"--segment {segment} is out of range: {label} has {len(missions)} segment(s) "
            f"numbered 0..{len(missions) - 1} ({lengths})"
        )
    return missions[int(segment)]
