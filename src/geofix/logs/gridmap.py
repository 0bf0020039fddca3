"""``geofix grid``: a netCDF map with an uncertainty layer from a log's soundings."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from geofix.errors import ConfigError, MapError
from geofix.maps.gridding import GriddedMap, grid_soundings, save_gridded
from geofix.maps.io import stated_numbers


def _read_soundings(path: str | Path) -> tuple[np.ndarray, str | None, str]:
    """Georeferenced soundings ``(m, 3)`` ``(x, y, value)``, their frame and a name.

    Parameters
    ----------
    path : str or pathlib.Path
        Any log :func:`geofix.logs.read_mission` reads (its beams are placed with the
        navigation), or one CSV / Parquet table of georeferenced soundings with columns
        ``x, y`` (metres) or ``lon, lat`` (degrees, projected to a transverse-Mercator
        frame centred on them, as lon/lat maps are) and ``value`` (map units) or
        ``depth_m`` (positive down).
    """
    from geofix.logs.read import read_mission

    p = Path(path) if not str(path).startswith("builtin:") else None
    if p is not None and p.is_file() and p.suffix.lower() in (".csv", ".parquet"):
        return _table_soundings(p)
    mission = read_mission(path)
    return mission.soundings(), mission.frame, mission.name


def _table_soundings(path: Path) -> tuple[np.ndarray, str | None, str]:
    import pandas as pd

    from geofix.logs.tables import numeric_columns
    from geofix.maps.project import project_lonlat

    try:
        table = pd.read_csv(path) if path.suffix.lower() == ".csv" else pd.read_parquet(path)
    except Exception as exc:
        raise ConfigError(f"cannot read {path}: {str(exc).splitlines()[0]}") from None
    table = numeric_columns(table, path)
    if "value" in table:
        value = table["value"].to_numpy(float)
    elif "depth_m" in table:
        value = -table["depth_m"].to_numpy(float)
    else:
        raise ConfigError(f"{path}: needs a value or a depth_m column")
    frame = None
    if "x" in table and "y" in table:
        x, y = table["x"].to_numpy(float), table["y"].to_numpy(float)
    elif "lon" in table and "lat" in table:
        lon, lat = table["lon"].to_numpy(float), table["lat"].to_numpy(float)
        x, y, frame = project_lonlat(lon, lat, None, str(path))
    else:
        raise ConfigError(f"{path}: needs columns x, y or lon, lat")
    return np.column_stack([x, y, value]), frame, path.stem


def grid_log(
    path: str | Path,
    cell_m: float,
    out: str | Path,
    max_gap_cells: float = 2.0,
    registration_std_m: float | None = None,
) -> tuple[GriddedMap, Path]:
    """Grid the soundings of ``path`` to ``cell_m`` cells and write ``out`` (netCDF).

    The file is a :func:`geofix.maps.save_grid` map (``z``, read back by
    :func:`geofix.maps.load_grid`) with ``z_std`` and ``z_count`` beside it; its
    ``meta["projection"]`` is the soundings' frame, so a replay of the same log lands in
    the same frame.

    Parameters
    ----------
    path : str or pathlib.Path
        Any log :func:`geofix.logs.read_mission` reads, or one CSV / Parquet table of
        georeferenced soundings (columns ``x, y`` in metres or ``lon, lat`` in degrees,
        and ``value`` in map units or ``depth_m`` positive down).
    cell_m : float
        Cell size, metres.
    out : str or pathlib.Path
        The netCDF file to write; its folder is created.
    max_gap_cells : float
        Cells farther than this (in cells) from any cell with soundings stay NaN.
    registration_std_m : float, optional
        How well the soundings' positions register the map, metres (1-sigma per axis),
        kept in its ``meta`` (:attr:`geofix.maps.grid.Grid.registration_var`); None:
        not stated.

    Returns
    -------
    tuple of (GriddedMap, pathlib.Path)
        The gridded map and the path written.

    Raises
    ------
    ConfigError
        An unreadable input or an output folder that cannot be created.
    MapError
        Soundings that cannot be gridded (the message names ``path``).
    """
    pts, frame, name = _read_soundings(path)
    try:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"cannot create the folder of {out}: {exc}") from None
    meta = {"source": Path(str(path)).name, "projection": frame, "format": "soundings"}
    if registration_std_m is not None:
        meta.update(stated_numbers({"registration_std_m": registration_std_m}, "grid"))
    try:
        gridded = grid_soundings(
            pts[:, 0], pts[:, 1], pts[:, 2], cell_m, max_gap_cells, name=name, meta=meta
        )
    except MapError as exc:  # name the input: the soundings come from it
        raise MapError(f"{path}: {exc}") from None
    return gridded, save_gridded(gridded, out)
