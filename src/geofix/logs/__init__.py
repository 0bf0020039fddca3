"""Recorded missions: the :class:`Mission` value and its readers.

Readers: GSF multibeam files (:func:`read_gsf`, through ``gsfpy``), ``geofix export``
files (:func:`read_exported`), ``nav`` / ``soundings`` tables in CSV or Parquet
(:func:`read_tables`, layout documented in :mod:`geofix.logs.tables`), and NOAA MGD77T
ship tracklines of depth, gravity and magnetics (:func:`read_mgd77`);
:func:`read_mission` picks the reader from the path.
"""

from geofix.logs.exported import read_exported
from geofix.logs.gsf import read_gsf
from geofix.logs.mgd77 import read_mgd77
from geofix.logs.mission import Mission, beam_positions
from geofix.logs.read import BUNDLED_LOGS, bundled_log_path, read_mission
from geofix.logs.tables import read_tables, write_tables

__all__ = [
    "BUNDLED_LOGS",
    "Mission",
    "beam_positions",
    "bundled_log_path",
    "read_exported",
    "read_gsf",
    "read_mgd77",
    "read_mission",
    "read_tables",
    "write_tables",
]
