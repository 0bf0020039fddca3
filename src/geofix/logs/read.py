"""One entry point for every log format: :func:`read_mission`."""

from __future__ import annotations

from pathlib import Path

from geofix.errors import ConfigError
from geofix.logs.gsf import GSF_SUFFIXES, read_gsf
from geofix.logs.mgd77 import MGD77T_SUFFIXES, longest_mission
from geofix.logs.mission import Mission
from geofix.logs.tables import read_tables

BUILTIN_LOG_PREFIX = "builtin:"
BUNDLED_LOGS = {"ex1811": "0059_20181102_212138_EX1811_MB_EM302.gsf.mb121"}
"""Logs shipped with geofix (see ``logs/data/PROVENANCE.md``)."""


def bundled_log_path(name: str) -> Path:
    """Path of a bundled log (``"ex1811"``: 50 EM302 pings of NOAA cruise EX1811).

    Raises
    ------
    ConfigError
        No bundled log of that name.
    """
    bare = name.removeprefix(BUILTIN_LOG_PREFIX)
    if bare not in BUNDLED_LOGS:
        raise ConfigError(f"no bundled log {bare!r}; bundled: {', '.join(BUNDLED_LOGS)}")
    return Path(__file__).parent / "data" / BUNDLED_LOGS[bare]


def read_mission(path: str | Path, frame: str | None = None, trial: int = 0) -> Mission:
    """Read a mission from any supported log.

    Parameters
    ----------
    path : str or pathlib.Path
        A GSF file (``.gsf``, ``.mb121``), a ``geofix export`` netCDF file, a folder of
        ``nav`` / ``soundings`` tables (:mod:`geofix.logs.tables`), an MGD77T ship
        trackline (``.m77t``: its longest depth mission, or its longest gravity mission
        when it has no depths; :func:`~geofix.logs.mgd77.read_mgd77` gives every
        segment and field), or ``builtin:ex1811``.
    frame : str, optional
        PROJ string of the metric frame for logs in lon/lat (a map's projection, so that
        the mission and the map share one frame).
    trial : int
        Trial of a ``geofix export`` file.

    Raises
    ------
    ConfigError
        Unknown format, missing file, or a reader's error.
    """
    if isinstance(path, str) and path.startswith(BUILTIN_LOG_PREFIX):
        path = bundled_log_path(path)
    path = Path(path)
    if path.is_dir():
        return read_tables(path, frame=frame)
    if not path.is_file():
        raise ConfigError(f"log not found: {path}")
    if path.suffix.lower() in GSF_SUFFIXES or ".gsf" in path.name.lower():
        return read_gsf(path, frame=frame)
    if path.suffix.lower() in MGD77T_SUFFIXES:
        return longest_mission(path, frame=frame)
    if path.suffix.lower() in (".nc", ".nc4"):
        from geofix.logs.exported import read_exported

        return read_exported(path, trial=trial)[0]
    raise ConfigError(
        f"{path}: unknown log format (expected .gsf/.mb121, a geofix export .nc, "
        "an MGD77T .m77t, or a folder of nav/soundings tables)"
    )
