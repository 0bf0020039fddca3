"""The prior of a common offset between what a sensor reads and what a map holds.

A tide, a datum, a sound-speed error or a gravimeter's bias moves every reading of a ping
by the same amount against the map. The filters estimate that offset with the position
(:mod:`geofix.filters.nuisance`) and TERCOM weighs it in its fix's covariance
(:class:`geofix.match.tercom.Tercom`); both start from the prior 1-sigma below when the
settings leave it open.
"""

from __future__ import annotations

import weakref

import numpy as np

from geofix.maps.grid import Grid

#: Default prior 1-sigma of the common offset for a depth map: metres plus a share of the
#: water depth (a sound-speed error of 0.2 % scales every depth).
DEPTH_OFFSET_STD_M = 5.0
DEPTH_OFFSET_SHARE = 0.002
#: Default prior 1-sigma of the common offset for a gravity map, mGal.
GRAVITY_OFFSET_STD_MGAL = 5.0


def default_offset_std(grid: Grid) -> float:
    """Prior 1-sigma of the common offset when the settings leave it open, map units.

    Parameters
    ----------
    grid : Grid
        The prior map: its kind and its median field value.

    Returns
    -------
    float
        What the map states (:attr:`geofix.maps.grid.Grid.stated_offset_std`, a file's
        ``offset_std`` attribute) when it states it; else a depth map: ``5 m + 0.2 %`` of
        the median water depth (a tide, a datum, a sound-speed error); a gravity map:
        5 mGal; a magnetic map: 20 nT (the diurnal variation left after a base-station
        correction, and the offset between the map's crustal model and the vehicle's
        reference field).
    """
    stated = grid.stated_offset_std
    if stated is not None:
        return stated
    if grid.kind == "gravity":
        return GRAVITY_OFFSET_STD_MGAL
    if grid.kind == "magnetic":
        return 20.0  # nT
    return DEPTH_OFFSET_STD_M + DEPTH_OFFSET_SHARE * median_depth(grid)


_MEDIAN_DEPTHS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def median_depth(grid: Grid) -> float:
    """Median absolute value of the map's valid cells (0 when none), map units.

    Read once per map and remembered while the map lives (its values are read-only): a
    matcher asks at every fix, and on a large map the median costs more than the search.
    """
    known = _MEDIAN_DEPTHS.get(grid)
    if known is None:
        values = np.asarray(grid.values, dtype=float)
        finite = values[np.isfinite(values)]
        known = float(np.median(np.abs(finite))) if finite.size else 0.0
        _MEDIAN_DEPTHS[grid] = known
    return known
