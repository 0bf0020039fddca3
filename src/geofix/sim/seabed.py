"""An imperfect prior map: the seabed the sensor reads differs from the map the methods get.

Without a ``seabed:`` block a scenario's readings are simulated from the very map the
methods match against. With one, the scenario's ``map`` is the SEABED (the field the
sensor reads, prepared by :func:`geofix.sim.simulate.prepare_map` as always) and every
trial derives its own PRIOR map from it, the map every method of the campaign is handed
(``Trial.prior_map``, used by :meth:`geofix.sim.trial.Trial.problem`)::

    seabed:
      cell_factor: 4             # prior = block means of 4 x 4 seabed cells (int >= 1)
      relief_rms: 1.5            # sub-cell relief added to the seabed only, map units
      relief_corr_m: 30          #   its correlation length, metres
      error_rms: 2.0             # correlated map error added to the prior only, map units
      error_corr_m: 400          #   its correlation length, metres
      offset: 0.5                # added to every reading, map units
      offset_std: 0.0            # and an offset drawn per trial from N(0, offset_std^2)
      tide_amplitude: 1.2        # A sin(2 pi t / T + phase) added to the readings, map units
      tide_period_s: 44712       #   T, seconds (default: the M2 tide); phase drawn per trial
      drift_per_h: 0.1           # a gravimeter's drift, map units per hour of mission
      misregistration_m: 150     # the prior's content moved by 150 m in a drawn direction
      # misregistration_xy_m: [100, -50]   # ... or by this fixed (east, north) vector
      registration_std_m: 100    # how well the map states it is registered (metadata)
      holes: {count: 3, radius_m: 800}    # discs cut from the prior, filled like a gridder

Every key is optional; ``seabed: {}`` makes a prior equal to the seabed.

Definitions
-----------
- The prior's cells are the seabed's block means over ``cell_factor`` x ``cell_factor``
  cells (:func:`block_mean_grid`): the prior cell ``[i, j]`` is centred on the mean of its
  block's cell centres, its cells ``cell_factor`` times larger; a ragged east or north
  edge (fewer than ``cell_factor`` columns or rows left over) is dropped. A block mean is
  the mean of the block's valid cells (NaN only when all of them are no-data).
- ``relief`` and ``error`` are zero-mean Gaussian random fields (:func:`gaussian_field`)
  with covariance ``rms**2 * exp(-d**2 / (2 L**2))`` at distance ``d`` metres, ``L`` the
  correlation length: the correlation at lag ``L`` is ``exp(-1/2) = 0.61``. They are
  white noise filtered by a Gaussian kernel of standard deviation ``L / sqrt(2)``. The
  relief is drawn at the seabed's cells (around the true track only: the sensor reads
  nowhere else) and never seen by the prior; the error is drawn at the prior's cells.
- The readings are ``seabed + relief`` read along the true track (bilinear), plus the
  sensor's noise, map error and lag as without the block, plus
  ``offset + drawn + tide_amplitude sin(2 pi t / tide_period_s + phase) + drift_per_h t
  / 3600`` with ``t`` the sample time (seconds from the start), ``phase`` uniform on
  ``[0, 2 pi)`` and ``drawn`` normal of 1-sigma ``offset_std`` per trial
  (:func:`reading_offsets`): a trial's offset drawn from a stated spread, against which
  a filter's covariance, averaged over the trials, can be held.
- Misregistration moves the prior's content by ``(dx, dy)`` metres: the prior keeps its
  cells and takes the value ``prior(x - dx, y - dy)`` (bilinear, positions past an edge
  clamped to it) (:func:`shifted_values`). ``misregistration_m`` draws the direction
  uniformly per trial; ``Trial.prior_shift_m`` holds the drawn vector (truth, never
  handed to a method). ``registration_std_m`` is what the map states about its own
  registration, carried in the prior's ``meta["registration_std_m"]``.
- ``holes`` cuts ``count`` discs of ``radius_m`` metres centred uniformly over the prior's
  extent, and fills each as a gridder would (:func:`cut_and_fill_holes`): linear
  interpolation from the valid cells on the hole's rim, nearest rim value where the rim
  does not surround the cell (a hole at the map's edge). The true track may cross them.

Order on the prior: block means, then the error field, then the holes, then the shift.

Random draws come from the fifth child of the trial's generator
(``default_rng([seed, index]).spawn(5)[4]``), split again into one stream per part
(:func:`seabed_streams`), so the track, INS, DVL and sensor draws of a trial are those of
the same scenario without the block, and switching one part on leaves the others' draws
unchanged.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass

import numpy as np
from pydantic import Field, model_validator

from geofix._strict import Strict
from geofix.errors import ConfigError
from geofix.maps import mapread
from geofix.maps.grid import Grid
from geofix.memory import cells_bytes, check_allocation

__all__ = [
    "HolesSpec",
    "SeabedDraw",
    "SeabedSpec",
    "SeabedStreams",
    "block_mean_grid",
    "cut_and_fill_holes",
    "draw_seabed",
    "gaussian_field",
    "misregistration_vector",
    "prior_map",
    "prior_shape",
    "reading_offsets",
    "seabed_streams",
    "sensed_seabed",
    "shifted_values",
]

#: The M2 (principal lunar semidiurnal) tide's period, seconds.
M2_PERIOD_S = 44712.0
#: Cells of margin kept around the true track's footprints for the relief (bilinear reads).
_TRACK_MARGIN_CELLS = 2
#: Cells of the rim a hole is filled from.
_RIM_CELLS = 2


class HolesSpec(Strict):
    """Discs cut from the prior map: ``count`` of ``radius_m`` metres each."""

    count: int = Field(ge=1)
    radius_m: float = Field(gt=0)


class SeabedSpec(Strict):
    """The ``seabed:`` block: how the prior map and the readings differ from the seabed.

    See the module docstring for every key, its units and its definition.
    """

    cell_factor: int = Field(default=1, ge=1)
    relief_rms: float = Field(default=0.0, ge=0)
    relief_corr_m: float = Field(default=0.0, ge=0)
    error_rms: float = Field(default=0.0, ge=0)
    error_corr_m: float = Field(default=0.0, ge=0)
    offset: float = 0.0
    offset_std: float = Field(default=0.0, ge=0)
    tide_amplitude: float = Field(default=0.0, ge=0)
    tide_period_s: float = Field(default=M2_PERIOD_S, gt=0)
    drift_per_h: float = 0.0
    misregistration_m: float = Field(default=0.0, ge=0)
    misregistration_xy_m: tuple[float, float] | None = None
    registration_std_m: float | None = Field(default=None, ge=0)
    holes: HolesSpec | None = None

    @model_validator(mode="after")
    def _consistent(self) -> SeabedSpec:
        for part in ("relief", "error"):
            rms, corr = getattr(self, f"{part}_rms"), getattr(self, f"{part}_corr_m")
            if rms > 0 and not corr > 0:
                raise ValueError(
                    f"{part}_corr_m must be greater than 0 when {part}_rms is {rms:g} "
                    f"(the field's correlation length, metres)"
                )
        if self.misregistration_m > 0 and self.misregistration_xy_m is not None:
            raise ValueError(
                "give misregistration_m (a drawn direction) or misregistration_xy_m "
                "(a fixed vector), not both"
            )
        return self


@dataclass(frozen=True)
class SeabedStreams:
    """Independent generators for each random part of a seabed block."""

    relief: np.random.Generator
    error: np.random.Generator
    holes: np.random.Generator
    shift: np.random.Generator
    readings: np.random.Generator


def seabed_streams(rng: np.random.Generator) -> SeabedStreams:
    """Split a trial's seabed generator into one stream per part.

    Parameters
    ----------
    rng : numpy.random.Generator
        The trial's seabed stream (the fifth child of ``default_rng([seed, index])``).

    Returns
    -------
    SeabedStreams
        ``relief, error, holes, shift, readings``, children of ``rng`` in that order.
    """
    return SeabedStreams(*rng.spawn(5))


@dataclass(frozen=True, eq=False)
class SeabedDraw:
    """One trial's draw of a seabed block.

    Parameters
    ----------
    sensed : Grid
        The field the sensor reads: the seabed plus relief (cut around the true track
        when there is relief; the seabed itself otherwise).
    prior : Grid
        The prior map the methods get.
    shift_m : numpy.ndarray
        ``(2,)`` the prior's misregistration ``(east, north)``, metres (truth).
    reading_offsets : numpy.ndarray
        ``(n,)`` offset (stated and drawn) + tide + drift added to every beam's reading,
        map units.
    """

    sensed: Grid
    prior: Grid
    shift_m: np.ndarray
    reading_offsets: np.ndarray


def draw_seabed(
    seabed: Grid, spec: SeabedSpec, rng: np.random.Generator, footprints, times
) -> SeabedDraw:
    """Draw one trial's sensed seabed, prior map and reading offsets.

    Parameters
    ----------
    seabed : Grid
        The prepared scenario map (the seabed).
    spec : SeabedSpec
        The scenario's ``seabed`` block.
    rng : numpy.random.Generator
        The trial's seabed stream (split by :func:`seabed_streams`).
    footprints : array_like
        ``(n, b, 2)`` (or ``(n, 2)``) true beam footprints, metres; the relief is drawn
        around them.
    times : array_like
        ``(n,)`` sample times, seconds from the start.

    Returns
    -------
    SeabedDraw
        The sensed seabed, the prior, the drawn misregistration and the reading offsets.

    Raises
    ------
    ConfigError
        ``seabed.cell_factor`` leaves fewer than 2 x 2 prior cells, or holes leave no data.
    MemoryBudgetError
        A field would not fit the memory budget.
    """
    streams = seabed_streams(rng)
    prior, shift = prior_map(seabed, spec, streams)
    return SeabedDraw(
        sensed=sensed_seabed(seabed, spec, streams.relief, footprints),
        prior=prior,
        shift_m=shift,
        reading_offsets=reading_offsets(times, spec, streams.readings),
    )


# ----------------------------------------------------------------------------- fields
def _kernel(sigma_cells: float) -> np.ndarray:
    """A Gaussian kernel of ``sigma_cells``, cut at 4 sigma, scaled to unit sum of squares."""
    radius = max(1, math.ceil(4.0 * sigma_cells))
    i = np.arange(-radius, radius + 1, dtype=float)
    weights = np.exp(-0.5 * (i / sigma_cells) ** 2)
    return weights / np.sqrt(np.sum(weights**2))


def gaussian_field(
    shape: tuple[int, int],
    dx: float,
    dy: float,
    rms: float,
    corr_m: float,
    rng: np.random.Generator,
    what: str = "random field",
) -> np.ndarray:
    """A zero-mean Gaussian random field with a Gaussian covariance, on a regular grid.

    The covariance at distance ``d`` metres is ``rms**2 * exp(-d**2 / (2 corr_m**2))``,
    so the correlation at lag ``corr_m`` is ``exp(-1/2)``: white noise on a canvas padded
    by the kernel's reach, filtered (FFT convolution, one axis at a time) by a Gaussian
    kernel of standard deviation ``corr_m / sqrt(2)`` cut at four of them and scaled to a
    unit sum of squares, then cropped (no wrap-around at the edges).

    Parameters
    ----------
    shape : (int, int)
        ``(ny, nx)`` cells.
    dx, dy : float
        Cell size along x and y, metres.
    rms : float
        Standard deviation of the field, field units (0 gives zeros, no draw).
    corr_m : float
        Correlation length, metres (> 0 when ``rms`` > 0).
    rng : numpy.random.Generator
        Source of the white noise.
    what : str
        What the field is, for a memory-budget message (e.g. ``"seabed.error_rms field"``).

    Returns
    -------
    numpy.ndarray
        ``(ny, nx)`` float64 field values.

    Raises
    ------
    ConfigError
        ``rms`` > 0 with ``corr_m`` not > 0.
    MemoryBudgetError
        The padded canvas and its transforms would not fit the memory budget.
    """
    from scipy.signal import fftconvolve

    ny, nx = int(shape[0]), int(shape[1])
    if rms == 0:
        return np.zeros((ny, nx))
    if not corr_m > 0:
        raise ConfigError(f"{what}: correlation length must be > 0 m, got {corr_m}")
    ky = _kernel(corr_m / (math.sqrt(2.0) * dy))
    kx = _kernel(corr_m / (math.sqrt(2.0) * dx))
    ry, rx = ky.size // 2, kx.size // 2
    check_allocation(
        cells_bytes(ny + 4 * ry + 1, nx + 4 * rx + 1, copies=6),
        f"{what} ({ny} x {nx} cells, correlation {corr_m:g} m = kernel reach {ry} x {rx} cells)",
    )
    white = rng.standard_normal((ny + 2 * ry, nx + 2 * rx))
    field = fftconvolve(white, ky[:, None], mode="valid", axes=0)
    field = fftconvolve(field, kx[None, :], mode="valid", axes=1)
    return rms * field


def sensed_seabed(
    seabed: Grid, spec: SeabedSpec, rng: np.random.Generator, footprints=None
) -> Grid:
    """The field the sensor reads: the seabed plus the block's relief.

    Parameters
    ----------
    seabed : Grid
        The seabed (the prepared scenario map).
    spec : SeabedSpec
        ``relief_rms`` (map units) and ``relief_corr_m`` (metres).
    rng : numpy.random.Generator
        Source of the relief.
    footprints : array_like, optional
        ``(..., 2)`` positions the sensor reads, metres; the relief is then drawn on the
        seabed's cells around them only (plus a margin of two cells), which is all the
        sensor sees. Default: the whole seabed.

    Returns
    -------
    Grid
        The seabed itself without relief; else the (cut) seabed with the relief added at
        its own cells (no-data cells stay no-data).

    Raises
    ------
    MemoryBudgetError
        The relief field would not fit the memory budget.
    """
    if spec.relief_rms == 0:
        return seabed
    window = seabed if footprints is None else _window_around(seabed, footprints)
    relief = gaussian_field(
        window.shape,
        window.dx,
        window.dy,
        spec.relief_rms,
        spec.relief_corr_m,
        rng,
        "seabed.relief_rms field",
    )
    return window.with_values(np.asarray(window.values, dtype=float) + relief)


def _window_around(grid: Grid, positions) -> Grid:
    """The sub-grid holding every finite position, with a margin of a few cells."""
    pos = np.asarray(positions, dtype=float).reshape(-1, 2)
    pos = pos[np.isfinite(pos).all(axis=1)]
    if pos.size == 0:
        return grid
    col, row = grid.xy_to_cell(pos[:, 0], pos[:, 1])
    ny, nx = grid.shape
    m = _TRACK_MARGIN_CELLS
    col0 = int(np.clip(np.floor(col.min()) - m, 0, nx - 2))
    row0 = int(np.clip(np.floor(row.min()) - m, 0, ny - 2))
    col1 = int(np.clip(np.ceil(col.max()) + m + 1, col0 + 2, nx))
    row1 = int(np.clip(np.ceil(row.max()) + m + 1, row0 + 2, ny))
    return grid.crop_cells(col0, col1, row0, row1)


# ----------------------------------------------------------------------------- the prior
def prior_shape(shape: tuple[int, int], cell_factor: int) -> tuple[int, int]:
    """The shape of the prior made from a seabed of ``shape`` (ragged edges dropped).

    Parameters
    ----------
    shape : (int, int)
        ``(ny, nx)`` cells of the seabed.
    cell_factor : int
        Seabed cells per prior cell along each axis.

    Returns
    -------
    tuple of int
        ``(ny // cell_factor, nx // cell_factor)`` prior cells.
    """
    return int(shape[0]) // int(cell_factor), int(shape[1]) // int(cell_factor)


def block_mean_grid(grid: Grid, cell_factor: int) -> Grid:
    """The grid's block means over ``cell_factor`` x ``cell_factor`` cells.

    Parameters
    ----------
    grid : Grid
        The fine grid.
    cell_factor : int
        Cells per block along each axis (1 returns ``grid`` itself).

    Returns
    -------
    Grid
        Cells ``cell_factor`` times larger; cell ``[0, 0]`` centred on the mean of the
        centres of the fine cells ``[0:k, 0:k]`` (``x0 + (k - 1) dx / 2``); the last
        ``nx % k`` columns and ``ny % k`` rows (a ragged edge) dropped. Each value is the
        mean of its block's valid cells, NaN where all of them are no-data.

    Raises
    ------
    ConfigError
        ``cell_factor`` leaves fewer than 2 x 2 cells.
    MemoryBudgetError
        The block sums would not fit the memory budget.
    """
    k = int(cell_factor)
    if k == 1:
        return grid
    ny, nx = prior_shape(grid.shape, k)
    if ny < 2 or nx < 2:
        raise ConfigError(
            f"seabed.cell_factor {k} leaves {ny} x {nx} prior cells of map {grid.name!r} "
            f"({grid.shape[0]} x {grid.shape[1]} cells); at least 2 x 2 are needed"
        )
    check_allocation(
        cells_bytes(ny * k, nx * k, copies=2.5),
        f"block means of map {grid.name!r} (seabed.cell_factor {k})",
    )
    fine = np.asarray(grid.values[: ny * k, : nx * k], dtype=float)
    valid = np.isfinite(fine)
    total = np.where(valid, fine, 0.0).reshape(ny, k, nx, k).sum(axis=(1, 3))
    count = valid.reshape(ny, k, nx, k).sum(axis=(1, 3))
    means = np.full((ny, nx), np.nan)
    np.divide(total, count, out=means, where=count > 0)
    return grid.with_values(
        means,
        x0=float(grid.x0 + 0.5 * (k - 1) * grid.dx),
        y0=float(grid.y0 + 0.5 * (k - 1) * grid.dy),
        dx=float(k * grid.dx),
        dy=float(k * grid.dy),
    )


def misregistration_vector(spec: SeabedSpec, rng: np.random.Generator) -> np.ndarray:
    """The prior's misregistration ``(east, north)``, metres.

    Parameters
    ----------
    spec : SeabedSpec
        ``misregistration_xy_m`` (a fixed vector, metres) or ``misregistration_m`` (a
        distance, metres).
    rng : numpy.random.Generator
        Source of the bearing (one uniform draw on ``[0, 2 pi)`` whatever the distance,
        none with a fixed vector).

    Returns
    -------
    numpy.ndarray
        ``(2,)`` ``misregistration_xy_m`` when given, else ``misregistration_m`` times
        ``(sin b, cos b)`` for the drawn bearing ``b`` clockwise from north.
    """
    if spec.misregistration_xy_m is not None:
        return np.asarray(spec.misregistration_xy_m, dtype=float)
    bearing = rng.uniform(0.0, 2.0 * np.pi)
    return spec.misregistration_m * np.array([np.sin(bearing), np.cos(bearing)])


def shifted_values(grid: Grid, shift_m) -> np.ndarray:
    """The grid's content moved by ``shift_m``: ``values(x - dx, y - dy)`` at every cell.

    Parameters
    ----------
    grid : Grid
        The map.
    shift_m : array_like
        ``(east, north)`` shift, metres.

    Returns
    -------
    numpy.ndarray
        ``(ny, nx)`` bilinear reads at the shifted positions, clamped to the grid's
        extent (the edge values extend outwards); NaN next to no-data cells.

    Raises
    ------
    MemoryBudgetError
        The read would not fit the memory budget.
    """
    ny, nx = grid.shape
    check_allocation(cells_bytes(ny, nx, copies=3), f"misregistered prior of map {grid.name!r}")
    sx, sy = (float(s) for s in np.asarray(shift_m, dtype=float))
    col = np.clip(np.arange(nx) - sx / grid.dx, 0.0, nx - 1.0)
    row = np.clip(np.arange(ny) - sy / grid.dy, 0.0, ny - 1.0)
    return mapread.bilinear_cells(grid.values, col[None, :], row[:, None])


def cut_and_fill_holes(grid: Grid, holes: HolesSpec, rng: np.random.Generator) -> np.ndarray:
    """Cut discs from a map and fill them as a gridder would.

    ``holes.count`` centres are drawn uniformly over the grid's extent (eastings first,
    then northings). The valid cells whose centre lies within ``holes.radius_m`` of one
    are replaced by a linear interpolation (Delaunay) of the valid cells within two cells
    of the hole (its rim), and by the nearest rim value where the rim does not surround
    them; overlapping discs form one hole. No-data cells stay no-data.

    Parameters
    ----------
    grid : Grid
        The map.
    holes : HolesSpec
        ``count`` and ``radius_m`` (metres).
    rng : numpy.random.Generator
        Source of the centres.

    Returns
    -------
    numpy.ndarray
        ``(ny, nx)`` filled values.

    Raises
    ------
    ConfigError
        A hole has no valid cell around it to be filled from (the holes cover the map).
    MemoryBudgetError
        The hole masks would not fit the memory budget.
    """
    ny, nx = grid.shape
    check_allocation(cells_bytes(ny, nx, copies=3), f"seabed.holes on map {grid.name!r}")
    west, east, south, north = grid.extent
    centres = np.column_stack(
        [rng.uniform(west, east, holes.count), rng.uniform(south, north, holes.count)]
    )
    values = np.array(grid.values, dtype=float)
    mask = _discs(grid, centres, holes.radius_m)
    cut = mask & np.isfinite(values)
    if cut.any():
        _fill(values, cut, mask, grid.dx, grid.dy, holes)
    return values


def _discs(grid: Grid, centres: np.ndarray, radius_m: float) -> np.ndarray:
    """Boolean ``(ny, nx)``: cells whose centre lies within ``radius_m`` of a centre."""
    ny, nx = grid.shape
    mask = np.zeros((ny, nx), dtype=bool)
    for cx, cy in centres:
        c0, c1 = _index_range(cx, radius_m, grid.x0, grid.dx, nx)
        r0, r1 = _index_range(cy, radius_m, grid.y0, grid.dy, ny)
        if c0 >= c1 or r0 >= r1:
            continue
        xs = grid.x0 + grid.dx * np.arange(c0, c1) - cx
        ys = grid.y0 + grid.dy * np.arange(r0, r1) - cy
        mask[r0:r1, c0:c1] |= ys[:, None] ** 2 + xs[None, :] ** 2 <= radius_m**2
    return mask


def _index_range(centre: float, radius: float, origin: float, step: float, n: int):
    """Cell indices ``[i0, i1)`` along one axis whose centres may lie within ``radius``."""
    i0 = max(0, math.floor((centre - radius - origin) / step))
    i1 = min(n, math.ceil((centre + radius - origin) / step) + 1)
    return i0, i1


def _fill(values, cut, mask, dx: float, dy: float, holes: HolesSpec) -> None:
    """Fill every connected hole of ``cut`` in place from its rim."""
    from scipy import ndimage

    labels, _ = ndimage.label(cut)
    valid = np.isfinite(values) & ~mask
    ny, nx = values.shape
    for k, box in enumerate(ndimage.find_objects(labels), start=1):
        rows = slice(max(0, box[0].start - _RIM_CELLS), min(ny, box[0].stop + _RIM_CELLS))
        cols = slice(max(0, box[1].start - _RIM_CELLS), min(nx, box[1].stop + _RIM_CELLS))
        hole = labels[rows, cols] == k
        rim = ndimage.binary_dilation(hole, iterations=_RIM_CELLS) & valid[rows, cols]
        if not rim.any():
            raise ConfigError(
                f"seabed.holes: a hole of radius_m {holes.radius_m:g} leaves no valid map "
                f"cell around it to be filled from; use fewer or smaller holes"
            )
        r_rim, c_rim = np.nonzero(rim)
        r_hole, c_hole = np.nonzero(hole)
        sub = values[rows, cols]
        sub[r_hole, c_hole] = _interpolate(
            np.column_stack([c_rim * dx, r_rim * dy]),
            sub[r_rim, c_rim],
            np.column_stack([c_hole * dx, r_hole * dy]),
        )


def _interpolate(points: np.ndarray, data: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Linear (Delaunay) interpolation, the nearest point's value outside the hull."""
    from scipy.interpolate import griddata
    from scipy.spatial import QhullError

    out = np.full(targets.shape[0], np.nan)
    if points.shape[0] >= 3:
        with contextlib.suppress(QhullError):  # collinear rim points: nearest values only
            out = griddata(points, data, targets, method="linear")
    missing = np.isnan(out)
    if missing.any():
        out[missing] = griddata(points, data, targets[missing], method="nearest")
    return out


def prior_map(seabed: Grid, spec: SeabedSpec, streams: SeabedStreams) -> tuple[Grid, np.ndarray]:
    """The prior map a trial's methods get, made from the seabed.

    Parameters
    ----------
    seabed : Grid
        The seabed (the prepared scenario map).
    spec : SeabedSpec
        The scenario's ``seabed`` block.
    streams : SeabedStreams
        The trial's seabed streams (``error``, ``holes`` and ``shift`` are used).

    Returns
    -------
    tuple
        ``(prior, shift_m)``: the prior :class:`Grid` (block means, plus the error field,
        holes cut and filled, content moved by the misregistration; the seabed itself
        when the block changes none of them), named ``"<seabed>-prior"``, its ``meta`` the
        seabed's plus ``prior_of``, ``cell_factor`` and (when given)
        ``registration_std_m``; and the ``(2,)`` misregistration ``(east, north)``, metres.

    Raises
    ------
    ConfigError
        ``cell_factor`` leaves fewer than 2 x 2 cells, or the holes leave no data.
    MemoryBudgetError
        A step would not fit the memory budget.
    """
    shift = misregistration_vector(spec, streams.shift)
    prior = block_mean_grid(seabed, spec.cell_factor)
    if spec.error_rms > 0:
        error = gaussian_field(
            prior.shape,
            prior.dx,
            prior.dy,
            spec.error_rms,
            spec.error_corr_m,
            streams.error,
            "seabed.error_rms field",
        )
        prior = prior.with_values(np.asarray(prior.values, dtype=float) + error)
    if spec.holes is not None:
        prior = prior.with_values(cut_and_fill_holes(prior, spec.holes, streams.holes))
    if np.any(shift != 0):
        prior = prior.with_values(shifted_values(prior, shift))
    meta = {**seabed.meta, "prior_of": seabed.name, "cell_factor": int(spec.cell_factor)}
    if spec.registration_std_m is not None:
        meta["registration_std_m"] = float(spec.registration_std_m)
    return prior.with_values(prior.values, name=f"{seabed.name}-prior", meta=meta), shift


# ----------------------------------------------------------------------------- the readings
def reading_offsets(times, spec: SeabedSpec, rng: np.random.Generator) -> np.ndarray:
    """Offset, tide and drift added to every reading of a trial.

    Parameters
    ----------
    times : array_like
        ``(n,)`` sample times, seconds from the start.
    spec : SeabedSpec
        ``offset`` and ``offset_std`` (the 1-sigma of an offset drawn per trial),
        ``tide_amplitude`` (map units), ``tide_period_s`` (seconds), ``drift_per_h``
        (map units per hour).
    rng : numpy.random.Generator
        Source of the tide's phase (one uniform draw on ``[0, 2 pi)``), then of the
        drawn offset (one normal draw, only when ``offset_std`` is positive: a block
        without it draws as before).

    Returns
    -------
    numpy.ndarray
        ``(n,)`` ``offset + drawn + tide_amplitude sin(2 pi t / tide_period_s + phase)
        + drift_per_h t / 3600``, map units.
    """
    t = np.asarray(times, dtype=float)
    phase = rng.uniform(0.0, 2.0 * np.pi)
    drawn = rng.normal(0.0, spec.offset_std) if spec.offset_std > 0 else 0.0
    tide = spec.tide_amplitude * np.sin(2.0 * np.pi * t / spec.tide_period_s + phase)
    return spec.offset + drawn + tide + spec.drift_per_h * t / 3600.0
