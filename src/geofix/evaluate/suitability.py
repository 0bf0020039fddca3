"""Terrain suitability: where on a map a vehicle can fix its position, and how well.

Three layers, each on the map's own cells, for a mission planner to route the vehicle:

- ``std`` -- the field's standard deviation in a moving ``N x N`` window
  (:func:`geofix.maps.terrain.local_std`): the relief a matcher has to work with;
- ``roughness`` -- the mean absolute difference between adjacent cells in the window:
  the fine texture that pins a fix down;
- ``crlb`` -- the Cramér–Rao bound (RMS, metres) of a rigid fix from a standard straight
  track of ``N`` single-beam soundings one cell apart centred on the cell, for a
  measurement noise ``noise_std`` (see :mod:`geofix.evaluate.crlb`). The information of
  the track is a sum of ``g g^T`` along it, so every cell's bound comes from shifted sums
  of the three gradient products (one pass per heading and sample, vectorised over the
  whole map); the layer holds the worst of the headings (the planner does not know the
  track's heading yet), and ``crlb_mean`` the RMS over them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from geofix.errors import ConfigError, MapError
from geofix.maps.grid import Grid
from geofix.maps.terrain import local_std
from geofix.measurement import gradient_grids, inverse_trace
from geofix.memory import cells_bytes, check_allocation

#: Track headings of the standard track, degrees clockwise from north.
DEFAULT_HEADINGS_DEG = (0.0, 45.0, 90.0, 135.0)


@dataclass(frozen=True, eq=False)
class Suitability:
    """Suitability layers of a map (each a :class:`Grid` on the map's cells).

    Attributes
    ----------
    std : Grid
        Moving-window standard deviation, field units.
    roughness : Grid
        Moving-window mean absolute difference of adjacent cells, field units.
    crlb : Grid
        CRLB of the standard track, worst heading, metres (``inf`` where it says nothing
        along some direction, NaN on no-data).
    crlb_mean : Grid
        ``sqrt`` of the mean over headings of ``trace(J^-1)``, metres.
    window_cells : int
        Window side and track length, cells.
    noise_std : float
        Measurement noise assumed by the bound, field units.
    """

    std: Grid
    roughness: Grid
    crlb: Grid
    crlb_mean: Grid
    window_cells: int
    noise_std: float


def local_roughness(grid: Grid, window_cells: int) -> np.ndarray:
    """Mean absolute difference between adjacent cells in a moving window.

    Parameters
    ----------
    grid : Grid
        The map (NaN = no data; pairs touching no-data are left out).
    window_cells : int
        Side of the square window, cells.

    Returns
    -------
    numpy.ndarray
        ``(ny, nx)`` field units; NaN on no-data cells or without a valid pair.
    """
    from scipy.ndimage import uniform_filter

    z = np.asarray(grid.values, float)
    dx = np.abs(np.diff(z, axis=1))
    dy = np.abs(np.diff(z, axis=0))
    total = np.zeros(z.shape)
    count = np.zeros(z.shape)
    for diff, pad in ((dx, ((0, 0), (0, 1))), (dy, ((0, 1), (0, 0)))):
        ok = np.pad(np.isfinite(diff), pad)
        total += np.pad(np.nan_to_num(diff), pad)
        count += ok
    size = int(window_cells)
    s = uniform_filter(total, size, mode="constant")
    n = uniform_filter(count, size, mode="constant")
    with np.errstate(invalid="ignore", divide="ignore"):
        out = s / n
    return np.where(np.isfinite(z) & (n > 1e-9), out, np.nan)


def _shifted_sum(field: np.ndarray, shifts: np.ndarray) -> np.ndarray:
    """``sum_s field[r + s_row, c + s_col]`` over integer ``shifts`` ``(k, 2)``; 0 off-map."""
    ny, nx = field.shape
    pad = int(np.abs(shifts).max()) if shifts.size else 0
    padded = np.pad(field, pad)
    out = np.zeros(field.shape)
    for dr, dc in shifts:
        out += padded[pad + dr : pad + dr + ny, pad + dc : pad + dc + nx]
    return out


def track_shifts(samples: int, heading_deg: float, grid: Grid) -> np.ndarray:
    """Cell offsets ``(row, col)`` of a straight track of ``samples`` centred on a cell.

    Samples are one cell size apart (the mean of ``dx`` and ``dy``) along the heading and
    rounded to the nearest cell.

    Returns
    -------
    numpy.ndarray
        ``(samples, 2)`` integer offsets.
    """
    psi = np.radians(heading_deg)
    along = (np.arange(samples) - (samples - 1) / 2.0) * grid.cell_size
    cols = np.rint(along * np.sin(psi) / grid.dx).astype(int)
    rows = np.rint(along * np.cos(psi) / grid.dy).astype(int)
    return np.column_stack([rows, cols])


def track_crlb_traces(
    grid: Grid, samples: int, noise_std: float, headings_deg=DEFAULT_HEADINGS_DEG
) -> np.ndarray:
    """``trace(J^-1)`` of the standard track through every cell, for each heading.

    Parameters
    ----------
    grid : Grid
        The map.
    samples : int
        Soundings per track, one cell apart.
    noise_std : float
        Measurement noise 1-sigma, field units (positive).
    headings_deg : sequence of float
        Track headings, degrees clockwise from north.

    Returns
    -------
    numpy.ndarray
        ``(len(headings), ny, nx)`` variances summed over both axes, m^2 (``inf`` where
        the information is singular); gradients that cannot be formed count as none.
    """
    gxg, gyg = gradient_grids(grid)
    gx = np.nan_to_num(np.asarray(gxg.values, float))
    gy = np.nan_to_num(np.asarray(gyg.values, float))
    products = np.stack([gx * gx, gx * gy, gy * gy]) / float(noise_std) ** 2
    out = np.empty((len(headings_deg), *grid.shape))
    for h, heading in enumerate(headings_deg):
        shifts = track_shifts(samples, heading, grid)
        sxx, sxy, syy = (_shifted_sum(p, shifts) for p in products)
        info = np.stack([np.stack([sxx, sxy], -1), np.stack([sxy, syy], -1)], -2)
        out[h] = inverse_trace(info)
    return out


#: Float arrays of the map's size alive at once: gradients, their three products, the
#: shifted sums and the 2x2 information per cell, traces per heading, the layers.
_MAP_COPIES = 24


def check_suitability_size(grid: Grid, window_cells: int, headings: int) -> None:
    """Refuse a window larger than the map, or layers that would not fit in memory.

    Raises
    ------
    ConfigError
        ``window_cells`` larger than the map's larger side.
    MemoryBudgetError
        The layers' estimate (map cells times the arrays alive at once, plus the padded
        copy of ``window_cells`` around the map) against the budget.
    """
    ny, nx = grid.shape
    if window_cells > max(ny, nx):
        raise ConfigError(
            f"suitability: --window-cells {window_cells} is larger than the map "
            f"{grid.name!r} ({nx} x {ny} cells)"
        )
    pad = window_cells // 2 + 1
    estimate = cells_bytes(ny, nx, copies=_MAP_COPIES + headings) + cells_bytes(
        ny + 2 * pad, nx + 2 * pad, copies=2
    )
    check_allocation(
        estimate, f"suitability of map {grid.name!r} ({nx} x {ny} cells, window {window_cells})"
    )


def require_relief(result: Suitability) -> None:
    """Refuse a map on which no cell allows a fix (flat everywhere within the window).

    Raises
    ------
    MapError
        Every cell's CRLB is infinite or no-data.
    """
    if not np.isfinite(result.crlb.values).any():
        raise MapError(
            f"map {result.crlb.name.removesuffix('_crlb')!r} is flat within every "
            f"{result.window_cells}-cell window: no position fix is possible anywhere "
            "(the CRLB is infinite on every cell)"
        )


def suitability(
    grid: Grid,
    window_cells: int = 21,
    noise_std: float = 1.0,
    headings_deg=DEFAULT_HEADINGS_DEG,
) -> Suitability:
    """Suitability layers of a map: relief, texture and the CRLB of a standard track.

    Parameters
    ----------
    grid : Grid
        The map.
    window_cells : int
        Side of the moving window and number of soundings of the standard track, cells
        (at least 3).
    noise_std : float
        Measurement noise (sensor plus map error) 1-sigma, field units (positive).
    headings_deg : sequence of float
        Headings of the standard track, degrees clockwise from north.

    Returns
    -------
    Suitability
        The layers (see the module docstring); NaN on the map's no-data cells.

    Raises
    ------
    ConfigError
        ``window_cells`` below 3 or ``noise_std`` not positive.
    """
    if int(window_cells) < 3:
        raise ConfigError(f"suitability: window_cells must be at least 3, got {window_cells}")
    if not noise_std > 0 or not np.isfinite(noise_std):
        raise ConfigError(f"suitability: noise_std must be positive and finite, got {noise_std}")
    check_suitability_size(grid, int(window_cells), len(headings_deg))
    valid = np.isfinite(grid.values)
    traces = track_crlb_traces(grid, int(window_cells), noise_std, headings_deg)
    with np.errstate(invalid="ignore"):
        worst = np.where(valid, np.sqrt(traces.max(axis=0)), np.nan)
        mean = np.where(valid, np.sqrt(traces.mean(axis=0)), np.nan)
    meta = {"window_cells": int(window_cells), "noise_std": float(noise_std)}

    def layer(values, what: str, units: str) -> Grid:
        return grid.with_values(
            values, name=f"{grid.name}_{what}", units=units, meta={**meta, "layer": what}
        )

    return Suitability(
        std=layer(local_std(grid, int(window_cells)), "std", grid.units),
        roughness=layer(local_roughness(grid, int(window_cells)), "roughness", grid.units),
        crlb=layer(worst, "crlb", "m"),
        crlb_mean=layer(mean, "crlb_mean", "m"),
        window_cells=int(window_cells),
        noise_std=float(noise_std),
    )


def save_suitability(result: Suitability, out_dir: str | Path) -> dict[str, Path]:
    """Write the layers as grids (netCDF, :func:`geofix.maps.io.save_grid`).

    The figure is :func:`geofix.plot.suitability.suitability_figure`.

    Parameters
    ----------
    result : Suitability
        The layers.
    out_dir : str or pathlib.Path
        Output folder (created if missing).

    Returns
    -------
    dict
        ``{"std", "roughness", "crlb", "crlb_mean": netCDF path}``.
    """
    from geofix.maps.io import save_grid

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    for what in ("std", "roughness", "crlb", "crlb_mean"):
        path = out / f"suitability_{what}.nc"
        paths[what] = save_grid(getattr(result, what), path, infinite_ok=True)
    return paths
