"""The :class:`Grid`: an immutable regular map of a geophysical field."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from geofix.errors import MapError
from geofix.maps import mapread

KINDS = ("depth", "gravity", "magnetic")


@dataclass(frozen=True, eq=False)
class Grid:
    """A regular grid of a field (bathymetry, gravity or magnetic anomaly) in a metric frame.

    Parameters
    ----------
    values : numpy.ndarray
        ``(ny, nx)`` field values; NaN marks no data. Row 0 is the southern edge. Stored
        as a read-only float64 copy; an array that is already read-only, C-contiguous
        and float64 or float32 (a shared or compact map) is kept as it is, not copied.
    x0, y0 : float
        Easting and northing of the centre of cell ``[0, 0]``, metres.
    dx, dy : float
        Cell size along x (east) and y (north), metres; both positive.
    kind : str
        ``"depth"`` (elevation, metres, negative below sea level), ``"gravity"`` (mGal)
        or ``"magnetic"`` (magnetic anomaly, nT).
    units : str
        Unit of ``values``.
    name : str
        Short name for tables and figures.
    meta : dict
        Free-form provenance (source file, projection, region), never used by numerics
        save ``registration_std_m``: how well the map states it is registered, metres
        (:attr:`registration_var`).
    interpolation : {"bilinear", "bicubic"}
        The read the map's users take by default (:meth:`sample` and
        :meth:`sample_gradient` without a method, the measurement model of
        :func:`geofix.measurement.predict_measurements`).
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
    interpolation: str = "bilinear"

    def __post_init__(self) -> None:
        values = _stored_values(self.values)
        if values.ndim != 2 or min(values.shape) < 2:
            raise MapError(f"map {self.name!r}: values must be a 2-D array of at least 2x2")
        if not (self.dx > 0 and self.dy > 0):
            raise MapError(
                f"map {self.name!r}: cell size must be positive, got {self.dx}, {self.dy}"
            )
        if self.interpolation not in mapread.READS:
            raise MapError(
                f"map {self.name!r}: interpolation must be one of {mapread.READS}, "
                f"got {self.interpolation!r}"
            )
        if self.kind not in KINDS:
            raise MapError(f"map {self.name!r}: kind must be one of {KINDS}, got {self.kind!r}")
        if np.isnan(np.fmax.reduce(values, axis=None)):  # all NaN, without a temporary
            raise MapError(f"map {self.name!r}: every cell is NaN (no data)")
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
    def registration_var(self) -> float:
        """Variance of the map's stated registration error along each axis, m^2.

        ``meta["registration_std_m"]`` squared; 0 when the map states none. A
        misregistration moves every feature of the map alike, so no reading can show it:
        a position matched on the map is uncertain by it besides its own covariance.
        """
        std = self._stated_std("registration_std_m")
        return 0.0 if std is None else std * std

    @property
    def stated_offset_std(self) -> float | None:
        """The 1-sigma the map states for its level against what a sensor reads, map units.

        ``meta["offset_std"]``: how far the map's level may sit from the readings' (a
        datum, a reference field or formula, a reduction to another height), the prior of
        the filters' common offset in place of the map kind's default
        (:func:`geofix.maps.offset.default_offset_std`); None when the map states
        none.

        Raises
        ------
        MapError
            The stated value is not a number at least 0.
        """
        return self._stated_std("offset_std")

    def _stated_std(self, key: str) -> float | None:
        """``meta[key]``, a stated 1-sigma, as a float; None when absent (MapError if < 0)."""
        raw = self.meta.get(key)
        if raw is None:
            return None
        value = registration_std_value(raw)
        if np.isnan(value):
            raise MapError(f"map {self.name!r}: {key} must be >= 0, got {raw!r}")
        return value

    def with_offset_std(self, std: float) -> Grid:
        """The map stating its level to ``std`` map units (1-sigma; :attr:`stated_offset_std`).

        Raises
        ------
        MapError
            ``std`` is not a number at least 0.
        """
        return self._stating("offset_std", std)

    def with_registration(self, std_m: float) -> Grid:
        """The map stating that it is registered to ``std_m`` metres (1-sigma per axis).

        Raises
        ------
        MapError
            ``std_m`` is not a number at least 0.
        """
        return self._stating("registration_std_m", std_m)

    def _stating(self, key: str, std: float) -> Grid:
        """The map with ``meta[key] = std``, refused (MapError) unless a number >= 0."""
        stated = replace(self, meta={**self.meta, key: std})
        stated._stated_std(key)
        return stated

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
    def sample(self, x, y, method: str | None = None) -> np.ndarray:
        """Read the field at metric positions.

        Parameters
        ----------
        x, y : array_like
            Eastings and northings, metres; any (broadcastable) shape.
        method : {"bilinear", "bicubic", "nearest"}, optional
            Interpolation (default: the grid's ``interpolation``, bilinear unless set).
            Bilinear uses the four surrounding cell centres, bicubic (Keys, a = -0.5) the
            sixteen; a NaN in any of them gives NaN (:mod:`geofix.maps.mapread`).

        Returns
        -------
        numpy.ndarray
            Field values, broadcast shape of ``x`` and ``y``; NaN off the map and in
            no-data cells.
        """
        method = self.interpolation if method is None else method
        return mapread.read_xy(self.values, self.x0, self.y0, self.dx, self.dy, x, y, method)

    def sample_gradient(
        self, x, y, method: str | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Value and exact gradient of the field's interpolant at metric positions.

        Parameters
        ----------
        x, y : array_like
            Eastings and northings, metres; any (broadcastable) shape.
        method : {"bilinear", "bicubic"}, optional
            Interpolant (default: the grid's ``interpolation``, as :meth:`sample`).

        Returns
        -------
        tuple of numpy.ndarray
            ``(value, d/dx, d/dy)``: the value of :meth:`sample` with the same method, field
            units, and the gradient of that interpolant (:mod:`geofix.maps.mapread`),
            field units per metre; all NaN off the map and wherever a stencil cell is NaN.
        """
        method = self.interpolation if method is None else method
        return mapread.gradient_xy(self.values, self.x0, self.y0, self.dx, self.dy, x, y, method)

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


def registration_std_value(raw) -> float:
    """A stated 1-sigma (a registration's, metres; a level's) as a float; NaN unless >= 0.

    ``raw`` may be a number, a numeric string or an array (its first element: a netCDF
    attribute reads as one).
    """
    try:
        value = float(np.asarray(raw).reshape(-1)[0])
    except (TypeError, ValueError, IndexError):
        return float("nan")
    return value if np.isfinite(value) and value >= 0 else float("nan")


def _stored_values(values) -> np.ndarray:
    """Read-only C-contiguous float values: kept if already so (float32/64), else copied."""
    array = np.asarray(values)
    keep = (
        array.dtype in (np.float32, np.float64)
        and not array.flags.writeable
        and array.flags.c_contiguous
    )
    if keep:
        return array
    array = np.array(array, dtype=float, order="C")
    array.flags.writeable = False
    return array


def _bilinear(values: np.ndarray, col, row) -> np.ndarray:
    """Bilinear values at fractional cells (the compiled read of :mod:`geofix.maps.mapread`)."""
    return mapread.bilinear_cells(values, col, row)
