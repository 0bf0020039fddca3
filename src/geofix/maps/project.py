"""Projection of lon/lat grids to a local metric frame, and metric resampling.

A geographic grid is projected once, when it is loaded, to a local transverse-Mercator
frame centred on the grid (x east, y north, metres, scale 1 on the central meridian), and
resampled bilinearly to a regular metric grid. Bilinear reads follow :meth:`Grid.sample`:
a node whose four source cells include a NaN is NaN.
"""

from __future__ import annotations

from dataclasses import replace
from typing import NamedTuple

import numpy as np

from geofix.errors import MapError
from geofix.maps.grid import Grid, _bilinear
from geofix.memory import cells_bytes, check_allocation

# Float arrays of the output's size alive at once: node lon/lat, fractional indices,
# bilinear weights and the result (projection); indices, weights, result (resampling).
_PROJECT_COPIES = 18
"""Float64 temporaries per node of a block being projected (meshgrid, lon/lat, indices)."""

PROJECT_BLOCK_NODES = 1 << 18
"""Nodes projected at a time (whole rows): about 40 MB of temporaries."""
_RESAMPLE_COPIES = 14

# Relative slack (in cells) that keeps nodes on the very edge of the source inside it
# despite round-off in the projection.
_EDGE_SLACK_CELLS = 1e-6


class ProjectedValues(NamedTuple):
    """A lon/lat grid projected to a regular metric grid (unpacks as a 6-tuple)."""

    values: np.ndarray
    x0: float
    y0: float
    dx: float
    dy: float
    proj: str


def local_tmerc(lon0: float, lat0: float) -> str:
    """PROJ string of a transverse-Mercator frame centred on ``(lon0, lat0)`` degrees.

    Parameters
    ----------
    lon0, lat0 : float
        Centre of the frame, degrees (WGS84); it gets coordinates ``(0, 0)`` metres.

    Returns
    -------
    str
        PROJ string, x east and y north in metres, scale factor 1.
    """
    return (
        f"+proj=tmerc +lat_0={lat0:.10g} +lon_0={lon0:.10g} +k=1 +x_0=0 +y_0=0 "
        "+ellps=WGS84 +units=m +no_defs"
    )


def frame_proj(frame: str, where: str = "frame"):
    """The :class:`pyproj.Proj` of a PROJ string, or a MapError naming it.

    Parameters
    ----------
    frame : str
        PROJ string of a metric frame (e.g. :func:`local_tmerc`).
    where : str
        What the frame belongs to (a file, a map), for the message.

    Raises
    ------
    MapError
        PROJ rejects the string, or it is not a string.
    """
    from pyproj import Proj
    from pyproj.exceptions import CRSError

    if not isinstance(frame, str):
        raise MapError(f"{where}: projection must be a PROJ string, got {type(frame).__name__}")
    try:
        return Proj(frame)
    except (CRSError, ValueError, TypeError):
        shown = frame if len(frame) <= 120 else f"{frame[:120]}..."
        raise MapError(f"{where}: PROJ rejects the projection {shown!r}") from None


def project_lonlat(lon, lat, frame: str | None, where: str) -> tuple[np.ndarray, np.ndarray, str]:
    """Longitudes and latitudes (degrees) to ``(x, y, frame)`` metres in a metric frame.

    Parameters
    ----------
    lon, lat : array_like
        ``(m,)`` WGS84 degrees; NaN entries stay NaN.
    frame : str or None
        PROJ string of the frame (None: :func:`local_tmerc` centred on the points).
    where : str
        The input (a file, a table), for the messages.

    Raises
    ------
    MapError
        A latitude beyond +-90 or a longitude beyond +-360 degrees, no finite position,
        or a frame PROJ rejects.
    """
    lon = np.asarray(lon, dtype=float)
    lat = np.asarray(lat, dtype=float)
    ok = np.isfinite(lon) & np.isfinite(lat)
    if not ok.any():
        raise MapError(f"{where}: no finite longitude / latitude")
    bad = ok & ((np.abs(lat) > 90) | (np.abs(lon) > 360))
    if bad.any():
        k = int(np.argmax(bad))
        raise MapError(
            f"{where}: {int(bad.sum())} positions out of range (first: lon {lon[k]:.6g}, "
            f"lat {lat[k]:.6g}); latitude must lie within -90..90, longitude -360..360 degrees"
        )
    if frame is None:
        lon0 = 0.5 * (np.min(lon[ok]) + np.max(lon[ok]))
        frame = local_tmerc(float(lon0), 0.5 * float(np.min(lat[ok]) + np.max(lat[ok])))
    x, y = frame_proj(frame, where)(lon, lat)
    return np.asarray(x, dtype=float), np.asarray(y, dtype=float), frame


def native_spacing_m(lon: np.ndarray, lat: np.ndarray, proj: str) -> tuple[float, float]:
    """Size of one source cell at the grid centre, metres east and north.

    Parameters
    ----------
    lon, lat : numpy.ndarray
        1-D ascending cell-centre longitudes and latitudes, degrees.
    proj : str
        PROJ string of the metric frame.

    Returns
    -------
    (float, float)
        East-west and north-south extent of one median cell at the centre, metres.
    """
    from pyproj import Proj

    dlon = float(np.median(np.diff(lon)))
    dlat = float(np.median(np.diff(lat)))
    lon_c, lat_c = 0.5 * (lon[0] + lon[-1]), 0.5 * (lat[0] + lat[-1])
    p = Proj(proj)
    ex, ey = p([lon_c - dlon / 2, lon_c + dlon / 2], [lat_c, lat_c])
    nx, ny = p([lon_c, lon_c], [lat_c - dlat / 2, lat_c + dlat / 2])
    return float(np.hypot(ex[1] - ex[0], ey[1] - ey[0])), float(
        np.hypot(nx[1] - nx[0], ny[1] - ny[0])
    )


def _footprint(lon: np.ndarray, lat: np.ndarray, proj) -> tuple[float, float, float, float]:
    """Metric bounding box ``(xmin, xmax, ymin, ymax)`` of the lon/lat box's boundary."""
    blon = np.concatenate([lon, lon, np.full(lat.size, lon[0]), np.full(lat.size, lon[-1])])
    blat = np.concatenate([np.full(lon.size, lat[0]), np.full(lon.size, lat[-1]), lat, lat])
    bx, by = proj(blon, blat)
    return float(bx.min()), float(bx.max()), float(by.min()), float(by.max())


def _axis_nodes(lo: float, hi: float, cell: float) -> np.ndarray:
    """Regular nodes ``cell`` apart covering ``[lo, hi]``, centred in that interval."""
    n = int(np.floor((hi - lo) / cell + 1e-9)) + 1
    start = lo + 0.5 * ((hi - lo) - (n - 1) * cell)
    return start + cell * np.arange(n)


def _fractional_index(axis: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Fractional index of positions ``q`` along an ascending (possibly irregular) axis.

    Parameters
    ----------
    axis : numpy.ndarray
        1-D strictly ascending coordinates.
    q : numpy.ndarray
        Positions, same unit as ``axis``; any shape.

    Returns
    -------
    numpy.ndarray
        Fractional indices (linear between nodes); NaN outside the axis beyond a tiny
        round-off slack.
    """
    n = axis.size
    idx = np.interp(q, axis, np.arange(n, dtype=float))
    slack = _EDGE_SLACK_CELLS * (axis[-1] - axis[0]) / max(n - 1, 1)
    outside = (q < axis[0] - slack) | (q > axis[-1] + slack)
    return np.where(outside, np.nan, idx)


def project_lonlat_grid(
    values: np.ndarray,
    lon: np.ndarray,
    lat: np.ndarray,
    cell_m: float | None = None,
    float32_within: float | None = None,
) -> ProjectedValues:
    """Project a lon/lat grid to a local transverse-Mercator frame and resample it.

    The metric grid covers the bounding box of the projected lon/lat box (nodes outside
    the source are NaN) with square cells of ``cell_m``; each node reads the source
    bilinearly at its own lon/lat. The nodes are projected and read a block of rows at a
    time, straight into the output array.

    Parameters
    ----------
    values : numpy.ndarray
        ``(ny, nx)`` field, row 0 at the south, column 0 at the west (float32 or float64;
        read as it is).
    lon, lat : numpy.ndarray
        ``(nx,)`` and ``(ny,)`` strictly ascending cell-centre coordinates, degrees.
    cell_m : float, optional
        Metric cell size, metres; default the smaller native spacing at the grid centre.
    float32_within : float, optional
        Store the projected values in float32 when rounding their largest magnitude
        changes it by at most this, map units (each bilinear read, computed in float64,
        rounded once when stored: the very numbers of a float64 projection converted
        afterwards); otherwise, or None, float64.

    Returns
    -------
    ProjectedValues
        ``(values, x0, y0, dx, dy, proj)``: metric values (row 0 south), centre of cell
        ``[0, 0]`` and cell size in metres, and the PROJ string of the frame.
    """
    from pyproj import Proj

    lon = np.asarray(lon, dtype=float)
    lat = np.asarray(lat, dtype=float)
    proj = local_tmerc(0.5 * (lon[0] + lon[-1]), 0.5 * (lat[0] + lat[-1]))
    if cell_m is None:
        cell_m = min(native_spacing_m(lon, lat, proj))
    if not cell_m > 0:
        raise MapError(f"cell size must be positive, got {cell_m}")
    p = Proj(proj)
    xmin, xmax, ymin, ymax = _footprint(lon, lat, p)
    nx, ny = (xmax - xmin) / cell_m + 1, (ymax - ymin) / cell_m + 1
    dtype = np.dtype(np.float64 if float32_within is None else np.float32)
    rows = max(1, int(PROJECT_BLOCK_NODES // max(nx, 1.0)))
    check_allocation(
        cells_bytes(nx, ny, itemsize=dtype.itemsize)
        + cells_bytes(nx, min(rows, ny), copies=_PROJECT_COPIES),
        f"map projected at {cell_m:g} m cells ({nx:.0f} x {ny:.0f})",
    )
    x = _axis_nodes(xmin, xmax, cell_m)
    y = _axis_nodes(ymin, ymax, cell_m)
    out = np.empty((y.size, x.size), dtype)
    source = values if values.dtype in (np.float32, np.float64) else values.astype(float)
    peak = 0.0
    for r0 in range(0, y.size, rows):
        node_x, node_y = np.meshgrid(x, y[r0 : r0 + rows])
        node_lon, node_lat = p(node_x, node_y, inverse=True)
        col = _fractional_index(lon, node_lon)
        row = _fractional_index(lat, node_lat)
        block = _bilinear(source, col, row)
        out[r0 : r0 + rows] = block
        low, high = np.fmin.reduce(block, axis=None), np.fmax.reduce(block, axis=None)
        peak = max(peak, abs(float(low)), abs(float(high))) if high == high else peak
    if float32_within is not None and not peak * 2.0**-24 <= float32_within:
        del out
        return project_lonlat_grid(values, lon, lat, cell_m)
    return ProjectedValues(out, float(x[0]), float(y[0]), float(cell_m), float(cell_m), proj)


def resample_m(grid: Grid, cell_m: float) -> Grid:
    """Resample a metric grid bilinearly to square cells of ``cell_m`` metres.

    The new grid starts at the old grid's first cell centre and covers its extent.

    Parameters
    ----------
    grid : Grid
        A metric grid.
    cell_m : float
        New cell size along x and y, metres.

    Returns
    -------
    Grid
        The resampled grid (same kind, units and name; ``meta["resampled_from_m"]`` holds
        the old ``(dx, dy)``).
    """
    if not cell_m > 0:
        raise MapError(f"map {grid.name!r}: resampling cell size must be positive, got {cell_m}")
    ny, nx = grid.shape
    fx, fy = (nx - 1) * grid.dx / cell_m + 1, (ny - 1) * grid.dy / cell_m + 1
    check_allocation(
        cells_bytes(fx, fy, copies=_RESAMPLE_COPIES),
        f"map {grid.name!r} at resample_m {cell_m:g} ({fx:.0f} x {fy:.0f} cells)",
    )
    new_nx = int(np.floor((nx - 1) * grid.dx / cell_m + 1e-9)) + 1
    new_ny = int(np.floor((ny - 1) * grid.dy / cell_m + 1e-9)) + 1
    if new_nx < 2 or new_ny < 2:
        raise MapError(f"map {grid.name!r}: cell size {cell_m} m leaves fewer than 2x2 cells")
    col = np.minimum(np.arange(new_nx) * (cell_m / grid.dx), nx - 1)
    row = np.minimum(np.arange(new_ny) * (cell_m / grid.dy), ny - 1)
    values = _bilinear(grid.values, col[None, :], row[:, None])
    meta = {**grid.meta, "resampled_from_m": (grid.dx, grid.dy)}
    return replace(grid, values=values, dx=float(cell_m), dy=float(cell_m), meta=meta)
