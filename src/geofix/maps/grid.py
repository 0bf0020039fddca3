"""The :class:`Grid`: an immutable regular map of a geophysical field."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from geofix.errors import MapError

KINDS = ("depth", "gravity")


@dataclass(frozen=True, eq=False)
class Grid:
    """A regular grid of a field (bathymetry or gravity anomaly) in a metric frame.

    Parameters
    ----------
    values : numpy.ndarray
        ``(ny, nx)`` field values; NaN marks no data. Row 0 is the southern edge.
    x0, y0 : float
        Easting and northing of the centre of cell ``[0, 0]``, metres.
    dx, dy : float
        Cell size along x (east) and y (north), metres; both positive.
    kind : str
        ``"depth"`` (elevation, metres, negative below sea level) or ``"gravity"`` (mGal).
    units : str
        Unit of ``values``.
    name : str
        Short name for tables and figures.
    meta : dict
        Free-form provenance (source file, projection, region), never used by numerics.
    """

    values: np.ndarray
    x0: float
    y0: float
    dx: float
    dy: float
    kind: str = "depth"
    units: str = "m"
    name: str = "map"
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        values = np.asarray(self.values, dtype=float)
        if values.ndim != 2 or min(values.shape) < 2:
            raise MapError(f"map {self.name!r}: values must be a 2-D array of at least 2x2")
        if not (self.dx > 0 and self.dy > 0):
            raise MapError(
                f"map {self.name!r}: cell size must be positive, got {self.dx}, {self.dy}"
            )
        if self.kind not in KINDS:
            raise MapError(f"map {self.name!r}: kind must be one of {KINDS}, got {self.kind!r}")
        if np.all(np.isnan(values)):
            raise MapError(f"map {self.name!r}: every cell is NaN (no data)")
        values = values.copy()
        values.flags.writeable = False
        object.__setattr__(self, "values", values)

    # ------------------------------------------------------------------ geometry
    @property
    def shape(self) -> tuple[int, int]:
        """``(ny, nx)``."""
        return self.values.shape

    @property
    def cell_size(self) -> float:
        """Mean cell size, metres (the ``C`` of the sources)."""
        return 0.5 * (self.dx + self.dy)

    @property
    def x(self) -> np.ndarray:
        """Cell-centre eastings, metres, shape ``(nx,)``."""
        return self.x0 + self.dx * np.arange(self.shape[1])

    @property
    def y(self) -> np.ndarray:
        """Cell-centre northings, metres, shape ``(ny,)``."""
        return self.y0 + self.dy * np.arange(self.shape[0])

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(west, east, south, north)`` of the cell centres, metres."""
        ny, nx = self.shape
        return (self.x0, self.x0 + (nx - 1) * self.dx, self.y0, self.y0 + (ny - 1) * self.dy)

    def cell_to_xy(self, col, row) -> tuple[np.ndarray, np.ndarray]:
        """Metric position of (fractional) cell indices ``col``, ``row``."""
        return self.x0 + np.asarray(col) * self.dx, self.y0 + np.asarray(row) * self.dy

    def xy_to_cell(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Fractional ``(col, row)`` of metric positions."""
        return (np.asarray(x) - self.x0) / self.dx, (np.asarray(y) - self.y0) / self.dy

    def contains(self, x, y) -> np.ndarray:
        """True where ``(x, y)`` lies inside the grid and on valid (non-NaN) data."""
        return ~np.isnan(self.sample(x, y))

    # ------------------------------------------------------------------ sampling
    def sample(self, x, y, method: str = "bilinear") -> np.ndarray:
        """Read the field at metric positions.

        Parameters
        ----------
        x, y : array_like
            Eastings and northings, metres; any (broadcastable) shape.
        method : {"bilinear", "nearest"}
            Interpolation. Bilinear uses the four surrounding cell centres; a NaN in any of
            them gives NaN.

        Returns
        -------
        numpy.ndarray
            Field values, broadcast shape of ``x`` and ``y``; NaN off the map and in
            no-data cells.
        """
        col, row = self.xy_to_cell(x, y)
        if method == "bilinear":
            return _bilinear(self.values, col, row)
        if method == "nearest":
            return _nearest(self.values, col, row)
        raise ValueError(f"unknown sampling method {method!r}; use 'bilinear' or 'nearest'")

    def sample_gradient(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Exact gradient of the bilinear interpolant read by :meth:`sample`.

        Parameters
        ----------
        x, y : array_like
            Eastings and northings, metres; any (broadcastable) shape.

        Returns
        -------
        tuple of numpy.ndarray
            ``(d/dx, d/dy)`` in field units per metre, NaN where :meth:`sample` is NaN.
            Inside a cell the interpolant is ``a + b u + c v + d u v``; on a cell edge the
            derivative of the cell :meth:`sample` reads from (the one at or above-right).
        """
        col, row = self.xy_to_cell(x, y)
        gc, gr = bilinear_gradient(self.values, col, row)
        return gc / self.dx, gr / self.dy

    # ------------------------------------------------------------------ derived grids
    def with_values(self, values: np.ndarray, **changes) -> Grid:
        """A copy with new ``values`` (same shape) and optionally other fields changed."""
        return replace(self, values=values, **changes)

    def crop_cells(self, col0: int, col1: int, row0: int, row1: int) -> Grid:
        """The sub-grid of columns ``col0:col1`` and rows ``row0:row1``."""
        sub = self.values[row0:row1, col0:col1]
        x0, y0 = self.cell_to_xy(col0, row0)
        return replace(self, values=sub, x0=float(x0), y0=float(y0))

    def __repr__(self) -> str:
        ny, nx = self.shape
        return (
            f"Grid(name={self.name!r}, kind={self.kind!r}, shape=({ny}, {nx}), "
            f"cell=({self.dx:g}, {self.dy:g}) m, units={self.units!r})"
        )


def _bilinear(values: np.ndarray, col, row) -> np.ndarray:
    col = np.asarray(col, dtype=float)
    row = np.asarray(row, dtype=float)
    col, row = np.broadcast_arrays(col, row)
    ny, nx = values.shape
    inside = (col >= 0) & (col <= nx - 1) & (row >= 0) & (row <= ny - 1)
    c = np.where(inside, col, 0.0)
    r = np.where(inside, row, 0.0)
    c0 = np.minimum(np.floor(c).astype(np.intp), nx - 2)
    r0 = np.minimum(np.floor(r).astype(np.intp), ny - 2)
    fc = c - c0
    fr = r - r0
    v00 = values[r0, c0]
    v01 = values[r0, c0 + 1]
    v10 = values[r0 + 1, c0]
    v11 = values[r0 + 1, c0 + 1]
    out = (v00 * (1 - fc) + v01 * fc) * (1 - fr) + (v10 * (1 - fc) + v11 * fc) * fr
    return np.where(inside, out, np.nan)


def bilinear_gradient(values: np.ndarray, col, row) -> tuple[np.ndarray, np.ndarray]:
    """Derivatives of :func:`_bilinear` along the column and row index (field per cell).

    The same cell and the same NaN rule as the bilinear read: ``d/dcol = (v01 - v00)(1 -
    fr) + (v11 - v10) fr`` and ``d/drow = (v10 - v00)(1 - fc) + (v11 - v01) fc``.
    """
    col = np.asarray(col, dtype=float)
    row = np.asarray(row, dtype=float)
    col, row = np.broadcast_arrays(col, row)
    ny, nx = values.shape
    inside = (col >= 0) & (col <= nx - 1) & (row >= 0) & (row <= ny - 1)
    c = np.where(inside, col, 0.0)
    r = np.where(inside, row, 0.0)
    c0 = np.minimum(np.floor(c).astype(np.intp), nx - 2)
    r0 = np.minimum(np.floor(r).astype(np.intp), ny - 2)
    fc = c - c0
    fr = r - r0
    v00 = values[r0, c0]
    v01 = values[r0, c0 + 1]
    v10 = values[r0 + 1, c0]
    v11 = values[r0 + 1, c0 + 1]
    d_col = (v01 - v00) * (1 - fr) + (v11 - v10) * fr
    d_row = (v10 - v00) * (1 - fc) + (v11 - v01) * fc
    return np.where(inside, d_col, np.nan), np.where(inside, d_row, np.nan)


def _nearest(values: np.ndarray, col, row) -> np.ndarray:
    col = np.asarray(col, dtype=float)
    row = np.asarray(row, dtype=float)
    col, row = np.broadcast_arrays(col, row)
    ny, nx = values.shape
    ic = np.rint(col)
    ir = np.rint(row)
    inside = (ic >= 0) & (ic <= nx - 1) & (ir >= 0) & (ir <= ny - 1)
    ic = np.where(inside, ic, 0).astype(np.intp)
    ir = np.where(inside, ir, 0).astype(np.intp)
    return np.where(inside, values[ir, ic], np.nan)
