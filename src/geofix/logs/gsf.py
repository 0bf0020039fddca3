"""Read multibeam pings from a Generic Sensor Format (GSF) file through ``gsfpy``.

Every swath-bathymetry ping becomes one ping of a :class:`~geofix.logs.mission.Mission`:
the ship's GNSS position (so ``nav_source = "gnss"``), heading, roll and pitch, and each
beam's ``across_track`` / ``along_track`` offsets (metres, already corrected for attitude
by the sonar's processing) with the value ``-depth`` (elevation, negative below the sea
surface, the sign of geofix depth maps). Beams with a non-zero ``beam_flags`` entry (GSF:
0 = accepted) or a zero depth are dropped (NaN). So are beams no sonar can measure, the
mark of a corrupted record: an offset beyond :data:`MAX_GSF_OFFSET_M` or a depth beyond
the physical range (:data:`geofix.conventions.PHYSICAL_LIMITS`), with one warning per
file (one such beam would otherwise stretch a gridded map over thousands of kilometres).

**Latitude and longitude.** ``gsfpy`` 2.0 declares the ping structure's two position
fields in the order ``longitude, latitude`` while the GSF C library
(``gsfSwathBathyPing`` in ``gsf.h``) stores ``latitude`` first, so ``ping.longitude``
holds the latitude and ``ping.latitude`` the longitude. The reader swaps them back
(checked on the bundled EX1811 file: 17.84 deg N, 64.59 deg W, where the NOAA Okeanos
Explorer surveyed in November 2018).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from geofix.conventions import PHYSICAL_LIMITS
from geofix.errors import ConfigError, GeofixWarning
from geofix.logs.mission import Mission

GSF_SUFFIXES = (".gsf", ".mb121")
MAX_GSF_BEAMS = 4096
"""Most beams per ping read from a GSF file (larger counts are refused as corrupt)."""
MAX_GSF_OFFSET_M = 1.0e5
"""Largest ``|across_track|`` and ``|along_track|`` of a beam kept, metres (as a replay's
``geofix.replay.MAX_BEAM_OFFSET_M``); a farther beam is a corrupted record."""


def read_gsf(path: str | Path, frame: str | None = None, max_pings: int | None = None) -> Mission:
    """Read the swath-bathymetry pings of a GSF file.

    Parameters
    ----------
    path : str or pathlib.Path
        The GSF file.
    frame : str, optional
        PROJ string of the metric frame to put the pings in (for example a map's
        ``meta["projection"]``); by default a transverse-Mercator frame centred on the
        pings (:func:`geofix.maps.project.local_tmerc`).
    max_pings : int, optional
        Read at most this many pings.

    Returns
    -------
    Mission
        ``nav_source = "gnss"``; ``meta`` holds the file, the ping and beam counts and the
        navigation's lon/lat (``"lon"``, ``"lat"``, degrees).

    Raises
    ------
    ConfigError
        The file is missing, unreadable, or holds no swath-bathymetry ping.

    Warns
    -----
    GeofixWarning
        Once, when beams with an impossible offset or depth were dropped.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"GSF file not found: {path}")
    pings = _read_pings(path, max_pings)
    if not pings:
        raise ConfigError(f"{path}: no swath bathymetry ping in the GSF file")
    _warn_corrupt_beams(pings, path)
    return _mission(pings, path, frame)


def _warn_corrupt_beams(pings: list[dict], path: Path) -> None:
    corrupt = [p["corrupt"] for p in pings]
    if not any(corrupt):
        return
    import warnings

    warnings.warn(
        f"{path.name}: {sum(corrupt)} beams in {sum(1 for c in corrupt if c)} of "
        f"{len(pings)} pings dropped as corrupt (an offset beyond {MAX_GSF_OFFSET_M:g} m "
        f"or a depth beyond {PHYSICAL_LIMITS['depth']:g} m)",
        GeofixWarning,
        stacklevel=3,
    )


def _read_pings(path: Path, max_pings: int | None) -> list[dict]:
    try:
        # gsfpy ships no type information
        from gsfpy import open_gsf  # type: ignore[import-untyped]
        from gsfpy.enums import RecordType  # type: ignore[import-untyped]
    except ImportError as exc:  # pragma: no cover - gsfpy is a dependency
        raise ConfigError(f"reading GSF needs the gsfpy package: {exc}") from None
    pings: list[dict] = []
    try:
        with open_gsf(str(path)) as gsf:
            while max_pings is None or len(pings) < max_pings:
                try:
                    _, record = gsf.read(RecordType.GSF_RECORD_SWATH_BATHYMETRY_PING)
                except Exception as exc:  # gsfpy raises GsfException at the end of file
                    if "End of File" in str(exc):
                        break
                    raise
                pings.append(_ping_values(record.mb_ping, path))
    except ConfigError:
        raise
    except Exception as exc:
        raise ConfigError(f"cannot read GSF file {path}: {exc}") from None
    return pings


def _ping_values(ping, path: Path) -> dict:
    nb = int(ping.number_beams)
    if not 0 < nb <= MAX_GSF_BEAMS:
        raise ConfigError(f"{path}: a ping has {nb} beams (expected 1..{MAX_GSF_BEAMS})")

    def beams(name: str) -> np.ndarray:
        return np.ctypeslib.as_array(getattr(ping, name), (nb,)).astype(float)

    depth = beams("depth")
    flags = beams("beam_flags") if ping.beam_flags else np.zeros(nb)
    across, along = beams("across_track"), beams("along_track")
    with np.errstate(invalid="ignore"):
        corrupt = (np.abs(across) > MAX_GSF_OFFSET_M) | (np.abs(along) > MAX_GSF_OFFSET_M)
        corrupt |= np.abs(depth) > PHYSICAL_LIMITS["depth"]
    value = np.where((flags == 0) & (depth != 0) & ~corrupt, -depth, np.nan)
    across[corrupt] = np.nan
    along[corrupt] = np.nan
    return {
        "t": float(ping.ping_time.tv_sec) + 1e-9 * float(ping.ping_time.tv_nsec),
        "lat": float(ping.longitude),  # gsfpy's field order is swapped: see the module text
        "lon": float(ping.latitude),
        "heading": float(ping.heading),
        "roll": float(ping.roll),
        "pitch": float(ping.pitch),
        "beams": np.column_stack([across, along, value]),
        "corrupt": int(corrupt.sum()),
    }


def _mission(pings: list[dict], path: Path, frame: str | None) -> Mission:
    from geofix.maps.project import local_tmerc, project_lonlat

    lon = np.array([p["lon"] for p in pings])
    lat = np.array([p["lat"] for p in pings])
    if frame is None and np.all(np.abs(lat) <= 90):
        frame = local_tmerc(float(lon.mean()), float(lat.mean()))
    x, y, frame = project_lonlat(lon, lat, frame, str(path))
    width = max(p["beams"].shape[0] for p in pings)
    beams = np.full((len(pings), width, 3), np.nan)
    for k, p in enumerate(pings):
        beams[k, : p["beams"].shape[0]] = p["beams"]
    stamps = np.array([p["t"] for p in pings])
    return Mission(
        times=stamps - stamps[0],
        nav=np.column_stack([x, y]),
        heading=np.deg2rad([p["heading"] for p in pings]),
        beams=beams,
        nav_source="gnss",
        roll=np.deg2rad([p["roll"] for p in pings]),
        pitch=np.deg2rad([p["pitch"] for p in pings]),
        frame=frame,
        start_utc=float(stamps[0]),
        kind="depth",
        name=path.name.split(".")[0],
        meta={
            "source": str(path.name),
            "reader": "gsf",
            "pings": len(pings),
            "beams": width,
            "lon": lon,
            "lat": lat,
        },
    )
