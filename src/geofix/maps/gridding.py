"""A map from soundings: block statistics plus a linear gridder, with an uncertainty layer.

Scattered soundings ``(x, y, value)`` in a metric frame are reduced to one value per map
cell with :class:`verde.BlockReduce` (the cell mean, placed at the mean position of the
cell's soundings; the per-cell standard deviation and sounding count form the
uncertainty layer). :class:`verde.Linear` (Delaunay linear interpolation) carries the
means to the cell centres, filling cells without soundings within ``max_gap_cells`` of
a cell with some; farther cells stay NaN (no data), so the map never claims terrain
nobody measured.

The standard deviation layer is the spread of the soundings inside each cell: the error
of reading that cell's mean at a point inside it (terrain within the cell plus sounding
noise). Filters use it as per-cell map error (see
:func:`geofix.measurement.map_error_variance`); cells with fewer than two
soundings have no value (NaN) there.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from geofix.errors import MapError
from geofix.maps.grid import Grid
from geofix.memory import cells_bytes, check_allocation

GRID_CELL_BYTES = 96
"""Peak bytes per map cell while gridding (measured with tracemalloc: about 80)."""
GRID_SOUNDING_BYTES = 400
"""Peak bytes per sounding while gridding (measured: about 330)."""
MAX_COORDINATE_M = 4.0e7
"""Largest sounding coordinate accepted, metres (the Earth's circumference)."""
STD_VARIABLE = "z_std"
COUNT_VARIABLE = "z_count"


@dataclass(frozen=True, eq=False)
class GriddedMap:
    """A map gridded from soundings and its uncertainty layer.

    Parameters
    ----------
    grid : Grid
        Cell means (and linearly filled gaps), map units.
    std : numpy.ndarray
        ``(ny, nx)`` standard deviation of the soundings in each cell, map units; NaN where
        a cell holds fewer than two.
    count : numpy.ndarray
        ``(ny, nx)`` number of soundings in each cell.
    """

    grid: Grid
    std: np.ndarray
    count: np.ndarray

    def error_grid(self) -> Grid | None:
        """The ``std`` layer as a :class:`Grid` on the map's geometry (for the filters).

        None when no cell holds two soundings (``std`` all NaN).
        """
        return _error_layer_grid(self.grid, self.std)


def grid_soundings(
    x,
    y,
    value,
    cell_m: float,
    max_gap_cells: float = 2.0,
    kind: str = "depth",
    name: str = "soundings",
    meta: dict | None = None,
) -> GriddedMap:
    """Grid scattered soundings to square cells of ``cell_m`` metres.

    Parameters
    ----------
    x, y : array_like
        ``(m,)`` sounding positions east / north in a metric frame, metres.
    value : array_like
        ``(m,)`` sounding values, map units (NaN rows are dropped).
    cell_m : float
        Cell size, metres.
    max_gap_cells : float
        Cells farther than this (in cells) from any cell with soundings stay NaN.
    kind, name : str
        Labels of the :class:`Grid`.
    meta : dict, optional
        Provenance stored in the grid's ``meta`` (projection, source, ...).

    Returns
    -------
    GriddedMap

    Raises
    ------
    MapError
        A non-positive or infinite cell size, fewer than 3 valid soundings, or soundings
        beyond :data:`MAX_COORDINATE_M` of the frame's origin.
    MemoryBudgetError
        A grid whose gridding would exceed the memory budget (the message gives the
        estimate; :mod:`geofix.memory`).
    """
    import verde as vd  # type: ignore[import-untyped]  # verde ships no type information

    pts = np.column_stack([np.ravel(x), np.ravel(y), np.ravel(value)]).astype(float)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if not (cell_m > 0 and np.isfinite(cell_m)):
        raise MapError(f"gridding: cell size must be positive and finite, got {cell_m}")
    if pts.shape[0] < 3:
        raise MapError(f"gridding: need at least 3 valid soundings, got {pts.shape[0]}")
    _check_coordinates(pts)
    x0, y0, nx, ny = _layout(pts, float(cell_m))
    region = (x0 - cell_m / 2, x0 + (nx - 0.5) * cell_m, y0 - cell_m / 2, y0 + (ny - 0.5) * cell_m)
    stats, located = {}, {}
    for label, reduction in (("mean", np.mean), ("std", np.std), ("count", np.size)):
        blocks = vd.BlockReduce(
            reduction, spacing=cell_m, region=region, center_coordinates=True, adjust="region"
        )
        (bx, by), stats[label] = blocks.filter((pts[:, 0], pts[:, 1]), pts[:, 2])
    for axis in (0, 1):  # where each cell's soundings are on average
        blocks = vd.BlockReduce(np.mean, spacing=cell_m, region=region, adjust="region")
        _, located[axis] = blocks.filter((pts[:, 0], pts[:, 1]), pts[:, axis])
    col = np.clip(np.rint((bx - x0) / cell_m).astype(int), 0, nx - 1)
    row = np.clip(np.rint((by - y0) / cell_m).astype(int), 0, ny - 1)
    std = np.full((ny, nx), np.nan)
    count = np.zeros((ny, nx), dtype=np.int64)
    count[row, col] = stats["count"].astype(np.int64)
    std[row, col] = np.where(stats["count"] >= 2, stats["std"], np.nan)
    centroids = (located[0], located[1])
    mean = _interpolate(centroids, stats["mean"], (bx, by), x0, y0, nx, ny, cell_m, max_gap_cells)
    info = {"gridded_from": "soundings", "soundings": int(pts.shape[0]), "cell_m": cell_m}
    grid = Grid(mean, x0, y0, cell_m, cell_m, kind=kind, name=name, meta={**(meta or {}), **info})
    return GriddedMap(grid, std, count)


def _check_coordinates(pts: np.ndarray) -> None:
    """Refuse sounding positions beyond :data:`MAX_COORDINATE_M` of the frame's origin."""
    far = np.abs(pts[:, :2]) > MAX_COORDINATE_M
    if far.any():
        row = int(np.argmax(far.any(axis=1)))
        raise MapError(
            f"gridding: {int(far.any(axis=1).sum())} soundings lie beyond "
            f"{MAX_COORDINATE_M:g} m of the frame's origin (first: x {pts[row, 0]:.6g}, "
            f"y {pts[row, 1]:.6g}); positions must be metres on the Earth"
        )


def _layout(pts: np.ndarray, cell: float) -> tuple[float, float, int, int]:
    """First cell centre and cell counts covering the soundings; refuse a huge grid.

    The grid's peak (:data:`GRID_CELL_BYTES` per cell, :data:`GRID_SOUNDING_BYTES` per
    sounding) is checked against the memory budget before anything is allocated.

    Raises
    ------
    MemoryBudgetError
        The gridding would exceed the budget (the message gives the estimate).
    """
    lo = np.floor(pts[:, :2].min(axis=0) / cell + 0.5) * cell  # centres on multiples of cell
    hi = pts[:, :2].max(axis=0)
    counts = np.maximum(np.floor((hi - lo) / cell + 0.5) + 1.0, 2.0)  # floats: never overflow
    fx, fy = (float(c) for c in counts)
    check_allocation(
        cells_bytes(fx, fy, itemsize=GRID_CELL_BYTES)
        + cells_bytes(pts.shape[0], itemsize=GRID_SOUNDING_BYTES),
        f"gridding {fx:.0f} x {fy:.0f} cells of {cell:g} m (use a larger --cell-m)",
    )
    return float(lo[0]), float(lo[1]), int(fx), int(fy)


def _interpolate(centroids, block_mean, centres, x0, y0, nx, ny, cell, max_gap_cells):
    """Cell-centre values from the cell means placed where their soundings lie.

    A cell mean is the field at its soundings' mean position, not at the cell centre (at
    a survey's edge the two can be half a cell apart, on a slope a sizeable bias), so the
    means are interpolated linearly (:class:`verde.Linear`) from those positions to the
    centres; centres outside the hull of those positions (the survey's rim) take the
    nearest cell mean (:class:`verde.KNeighbors`), so that a bilinear read is defined up to
    the last sounding. Centres farther than ``max_gap_cells`` from every cell with
    soundings stay NaN.
    """
    import verde as vd  # type: ignore[import-untyped]  # verde ships no type information

    gx, gy = np.meshgrid(x0 + cell * np.arange(nx), y0 + cell * np.arange(ny))
    near = vd.distance_mask(centres, maxdist=max_gap_cells * cell, coordinates=(gx, gy))
    mean = np.full((ny, nx), np.nan)
    if block_mean.size < 3:
        raise MapError("gridding: the soundings fill fewer than 3 cells; use a smaller cell")
    try:
        fitted = vd.Linear().fit(centroids, block_mean)
        mean[near] = fitted.predict((gx[near], gy[near]))
    except Exception as exc:  # a degenerate (collinear) set of cells
        raise MapError(_interpolation_error(exc)) from None
    rim = near & np.isnan(mean)
    if rim.any():  # outside the hull of the means: the nearest cell mean
        nearest = vd.KNeighbors(k=1).fit(centroids, block_mean)
        mean[rim] = nearest.predict((gx[rim], gy[rim]))
    return mean


def _interpolation_error(exc: Exception) -> str:
    """One short line for a failed interpolation (Qhull's own text runs to 60 lines)."""
    from scipy.spatial import QhullError

    if isinstance(exc, QhullError):
        return (
            "gridding: the cells with soundings lie on one line, so no map can be "
            "interpolated between them (soundings spread across the track, or a smaller "
            "--cell-m, are needed)"
        )
    first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    return f"gridding: cannot interpolate the cell means: {first[:160]}"


def _error_layer_grid(grid: Grid, std: np.ndarray) -> Grid | None:
    """The per-cell standard deviation on the geometry of ``grid``; None if all NaN."""
    std = np.asarray(std, dtype=float)
    if std.shape != grid.shape or not np.isfinite(std).any():
        return None
    return Grid(std, grid.x0, grid.y0, grid.dx, grid.dy, kind=grid.kind, name=f"{grid.name}_std")


def save_gridded(gridded: GriddedMap, path: str | Path) -> Path:
    """Write the map (:func:`geofix.maps.io.save_grid`) plus ``z_std`` and ``z_count``.

    The three variables are written to a temporary file renamed into place when complete
    (:mod:`geofix._atomic`): a killed or failed write leaves no map without its layers.

    Raises
    ------
    MapError
        The map holds infinite cells (values too large to grid).
    OutputError
        The file cannot be written (disk full, permission denied, not a file).
    """
    import xarray as xr

    from geofix._atomic import write_atomic
    from geofix.maps.io import _require_finite, _write_grid_file

    path = Path(path)
    _require_finite(gridded.grid.values, f"gridded map {gridded.grid.name!r} (not written)")
    layers = xr.Dataset(
        {
            STD_VARIABLE: (("y", "x"), gridded.std, {"units": gridded.grid.units}),
            COUNT_VARIABLE: (("y", "x"), gridded.count, {"units": "1"}),
        },
        coords={"x": gridded.grid.x, "y": gridded.grid.y},
    )
    layers[STD_VARIABLE].attrs["long_name"] = "standard deviation of the soundings in the cell"
    layers[COUNT_VARIABLE].attrs["long_name"] = "number of soundings in the cell"
    return write_atomic(path, lambda part: _write_grid_file(gridded.grid, part, layers=layers))


def load_map_error(path: str | Path) -> Grid | None:
    """The ``z_std`` layer of a map file as a :class:`Grid`, or None when it has none.

    The layer keeps the geometry stored in the file (so it is read at metric positions,
    whatever cropping or resampling was applied to the map itself).
    """
    import xarray as xr

    path = Path(path)
    if path.suffix.lower() not in (".nc", ".nc4") or not path.is_file():
        return None
    try:
        with xr.open_dataset(path) as ds:
            if STD_VARIABLE not in ds or int(ds.attrs.get("geofix_grid", 0)) != 1:
                return None
            a = ds.attrs
            std = ds[STD_VARIABLE].values.astype(float)
    except (OSError, ValueError) as exc:
        raise MapError(f"cannot read the uncertainty layer of {path}: {exc}") from None
    if not np.isfinite(std).any():
        return None
    return Grid(std, float(a["x0"]), float(a["y0"]), float(a["dx"]), float(a["dy"]), name="std")
