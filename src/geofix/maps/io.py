"""Reading maps into :class:`Grid` values, and saving them.

:func:`load_grid` reads netCDF (any variable, lon/lat or projected metres), GeoTIFF, BAG
and grids saved by :func:`save_grid`; it crops a region in the file's own coordinates,
projects lon/lat grids to a local transverse-Mercator frame (see
:mod:`geofix.maps.project`) and resamples. Heavy readers (xarray, rioxarray, h5py) are
imported only when a file of their format is read; netCDF is opened with xarray's
netCDF4 backend named directly, so xarray does not import every installed backend
(rioxarray, and dask through it, cost seconds) to guess the engine.

Memory: a netCDF map is read in blocks of rows (about :data:`READ_BLOCK_BYTES` each)
into one array allocated, after a budget check (:func:`geofix.memory.check_allocation`),
at its final size, orientation and precision. With ``float32_within`` a metric map that
is neither projected nor resampled is stored in float32 when that rounds no value by
more than the given amount; the values are then exactly ``float32(value)`` of the file's
float64 values, as a conversion of the whole map would give, but without a full float64
copy ever existing (peak: 4 bytes a cell plus one block). The no-data and infinity
checks run block by block too, so no full-map mask is made.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from geofix._atomic import write_atomic
from geofix.errors import MapError
from geofix.maps import project
from geofix.maps.bundled import BUILTIN_PREFIX, BUNDLED_MAPS, builtin_name, builtin_path
from geofix.maps.grid import KINDS, Grid, registration_std_value
from geofix.memory import cells_bytes, check_allocation

NETCDF_SUFFIXES = (".nc", ".nc4", ".cdf", ".grd", ".netcdf")
GEOTIFF_SUFFIXES = (".tif", ".tiff", ".gtiff")
BAG_SUFFIXES = (".bag",)
BAG_NODATA = 1e6
DEFAULT_UNITS = {"depth": "m", "gravity": "mGal", "magnetic": "nT"}
_GRAVITY_WORDS = ("grav", "mgal", "free-air", "free air", "freeair", "anomaly")
_MAGNETIC_WORDS = ("magnetic", "nanotesla", "total field")
_MAGNETIC_TOKENS = ("nt", "tmi")
_X_NAMES = ("x", "lon", "longitude", "long", "easting", "east")
_Y_NAMES = ("y", "lat", "latitude", "northing", "north")
#: Attribute of a saved grid whose infinite cells are meaningful (see :func:`save_grid`).
INFINITE_ATTR = "infinite_cells"
_SAVED_LABELS = {"kind": "depth", "units": "m", "name": "map"}
#: Bytes of float64 read from a file at a time (a block of whole rows).
READ_BLOCK_BYTES = 8 * 2**20


@dataclass
class _Raw:
    """A grid as read from a file: ascending axes, row 0 at the south."""

    values: np.ndarray
    x: np.ndarray
    y: np.ndarray
    geographic: bool
    fmt: str
    variable: str | None = None
    units: str | None = None
    text: str = ""
    spacing: tuple[float, float] | None = None
    saved: dict | None = None
    extra: dict = field(default_factory=dict)


# ---------------------------------------------------------------------- public API
def load_grid(
    path: str | Path,
    variable: str | None = None,
    kind: str | None = None,
    region=None,
    resample_m: float | None = None,
    name: str | None = None,
    float32_within: float | None = None,
) -> Grid:
    """Read a map file into a metric :class:`Grid`.

    Parameters
    ----------
    path : str or pathlib.Path
        A file (netCDF, GeoTIFF, BAG, or a grid saved by :func:`save_grid`) or
        ``"builtin:NAME"`` for a bundled map (see :func:`geofix.maps.bundled_maps`).
    variable : str, optional
        netCDF variable (default: the only 2-D variable, else ``z``); GeoTIFF band number.
    kind : {"depth", "gravity", "magnetic"}, optional
        Field kind; by default "magnetic" when the variable name, units or long name
        mention magnetic, nanotesla, total field or TMI (or the units are nT), else
        "gravity" when they mention gravity, mGal, free-air or anomaly, else "depth".
    region : sequence of 4 floats, optional
        ``[west, east, south, north]`` in the file's own coordinates (degrees or metres),
        cut before projection and resampling.
    resample_m : float, optional
        Output cell size, metres. Lon/lat grids default to their native spacing at the
        centre (the smaller axis); metric grids keep theirs.
    name : str, optional
        Map name (default: the builtin name or the file's stem).
    float32_within : float, optional
        Largest rounding error allowed for float32 storage, map units: a netCDF or
        GeoTIFF map that is used as read (metric, no ``resample_m``) is read straight
        into float32, and a lon/lat map's projection is stored in float32, when
        :func:`float32_rounding` of the largest magnitude is within it, else in float64
        (the default, None: float64). The values are then exactly the float64 ones
        rounded to float32, as a conversion afterwards would give them.

    Returns
    -------
    Grid
        Row 0 at the south; ``meta`` holds the provenance (source, variable, region,
        projection, original spacing).

    Raises
    ------
    MapError
        Missing or unreadable file, unknown variable, a region without cells, no data.

    Examples
    --------
    >>> import geofix
    >>> grid = geofix.load_map("builtin:mb_1km")
    >>> grid.shape, grid.cell_size, grid.units
    ((160, 160), 1000.0, 'm')
    >>> azores = geofix.load_map("builtin:azores", region=[-30, -29, 38, 39], resample_m=2000)
    >>> azores.meta["projection"].startswith("+proj=tmerc")
    True
    """
    if kind is not None and kind not in KINDS:
        raise MapError(f"map kind must be one of {KINDS}, got {kind!r}")
    source, file_path, default_kind = _resolve(path)
    raw = _read(file_path, variable, source, float32_within, resample_m is not None)
    if raw.saved is None or not raw.saved.get("infinite_ok"):  # a CRLB layer may hold inf
        _require_finite(raw.values, source)
    raw = _crop(raw, region, source)
    if raw.saved is not None:
        return _finish_saved(raw, region, resample_m, kind, name)
    kind = kind or _detect_kind(raw.text, default_kind)
    units = raw.units or DEFAULT_UNITS[kind]
    name = name or (source.removeprefix(BUILTIN_PREFIX) if _is_builtin(path) else file_path.stem)
    labels = {"kind": kind, "units": units, "name": name}
    meta = _provenance(raw, source, region)
    return _to_metric(raw, resample_m, meta, source, labels, float32_within)


def save_grid(grid: Grid, path: str | Path, infinite_ok: bool = False) -> Path:
    """Write a :class:`Grid` to netCDF so that :func:`load_grid` restores it exactly.

    The file is written to a temporary name and renamed when complete
    (:mod:`geofix._atomic`): it is whole or absent.

    Parameters
    ----------
    grid : Grid
        The map to save.
    path : str or pathlib.Path
        Output file (netCDF-4).
    infinite_ok : bool
        Allow ``+-inf`` cells (a layer such as an unbounded CRLB, marked
        ``infinite_cells = "allowed"``); a map with infinite cells is refused otherwise,
        and :func:`load_grid` refuses to read one without that mark.

    Returns
    -------
    pathlib.Path
        The path written. The file holds variable ``z`` on metric ``x``/``y`` coordinates
        and the attributes ``x0, y0, dx, dy, kind, units, name, meta_json`` and
        ``geofix_grid = 1``. ``meta`` is stored as JSON: values and geometry come back
        exactly, tuples in ``meta`` come back as lists.
    """
    path = Path(path)
    if not infinite_ok:
        _require_finite(grid.values, f"map {grid.name!r} (not written to {path})")
    return write_atomic(path, lambda part: _write_grid_file(grid, part, infinite_ok))


def _write_grid_file(grid: Grid, path: Path, infinite_ok: bool = False, layers=None) -> None:
    """Write ``grid`` (and the extra variables of the dataset ``layers``) to ``path``."""
    import xarray as xr

    attrs = {
        "geofix_grid": 1,
        "x0": float(grid.x0),
        "y0": float(grid.y0),
        "dx": float(grid.dx),
        "dy": float(grid.dy),
        "kind": grid.kind,
        "units": grid.units,
        "name": grid.name,
        "meta_json": json.dumps(grid.meta, default=str),
    }
    if infinite_ok:
        attrs[INFINITE_ATTR] = "allowed"
    values = xr.DataArray(np.asarray(grid.values, dtype=float), dims=("y", "x"))
    values.attrs = {"units": grid.units, "long_name": grid.kind}
    ds = xr.Dataset({"z": values}, coords={"x": grid.x, "y": grid.y}, attrs=attrs)
    ds["x"].attrs["units"] = "m"
    ds["y"].attrs["units"] = "m"
    if layers is not None:
        ds = ds.merge(layers)
    ds.to_netcdf(path)


# ---------------------------------------------------------------------- resolution
def _is_builtin(path) -> bool:
    return isinstance(path, str) and path.startswith(BUILTIN_PREFIX)


def _resolve(path) -> tuple[str, Path, str | None]:
    """``(source label, file path, default kind)``; MapError if the file is missing."""
    if _is_builtin(path):
        bare = builtin_name(path)
        return f"{BUILTIN_PREFIX}{bare}", builtin_path(bare), BUNDLED_MAPS[bare].kind
    file_path = Path(path)
    if not file_path.is_file():
        raise MapError(f"map file not found: {file_path}")
    return str(file_path), file_path, None


_SIGNATURES = {
    b"CDF\x01": "netCDF",
    b"CDF\x02": "netCDF",
    b"CDF\x05": "netCDF",
    b"\x89HDF\r\n\x1a\n": "HDF5",
    b"II*\x00": "TIFF",
    b"MM\x00*": "TIFF",
    b"II+\x00": "TIFF",
    b"MM\x00+": "TIFF",
}


def _sniff(path: Path, source: str) -> str:
    """The container a file's first bytes announce: ``netCDF``, ``HDF5`` or ``TIFF``.

    Raises
    ------
    MapError
        The file is empty or is none of them (``not a netCDF / GeoTIFF / BAG file``).
    """
    try:
        with open(path, "rb") as f:
            head = f.read(8)
            f.seek(512)
            at512 = f.read(8)  # HDF5 may start its superblock at 512, 1024, ...
    except OSError as exc:
        raise MapError(f"cannot read map file {source}: {exc.strerror or exc}") from None
    if not head:
        raise MapError(f"map file {source} is empty (0 bytes)")
    for magic, kind in _SIGNATURES.items():
        if head.startswith(magic) or at512.startswith(magic):
            return kind
    raise MapError(f"not a netCDF / GeoTIFF / BAG file: {source}")


def _read(
    path: Path, variable: str | None, source: str, float32_within=None, resampled=False
) -> _Raw:
    """Dispatch on the file suffix (unknown suffixes try netCDF, then GeoTIFF).

    ``float32_within`` / ``resampled``: see :func:`_storage_within`.
    """
    _sniff(path, source)
    suffix = path.suffix.lower()
    precision = (float32_within, resampled)
    if suffix in BAG_SUFFIXES:
        return _read_bag(path, source)
    if suffix in GEOTIFF_SUFFIXES:
        return _read_geotiff(path, variable, source, precision)
    if suffix in NETCDF_SUFFIXES:
        return _read_netcdf(path, variable, source, precision)
    try:
        return _read_netcdf(path, variable, source, precision)
    except MapError:
        try:
            return _read_geotiff(path, variable, source, precision)
        except MapError:
            raise MapError(f"unrecognised map format: {source}") from None


def _one_line(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__


# ---------------------------------------------------------------------- netCDF
def _open_netcdf(path: Path, source: str):
    """The file as a lazily read xarray Dataset (netCDF4 backend, else xarray's guess)."""
    import xarray as xr

    try:
        from xarray.backends import NetCDF4BackendEntrypoint

        return xr.open_dataset(path, engine=NetCDF4BackendEntrypoint)
    except Exception:  # not readable by netCDF4: let xarray try its other backends
        pass
    try:
        return xr.open_dataset(path)
    except Exception as exc:  # xarray raises many types for a bad file
        raise MapError(f"cannot read {source} as netCDF: {_one_line(exc)}") from exc


def _storage_within(precision: tuple, geographic: bool) -> float | None:
    """Rounding allowed when reading the values in float32, map units (None: float64).

    ``precision`` is ``(float32_within, resampled)``. A metric map used as read may round
    by ``float32_within``; a lon/lat map is read in float64 and its projection stored in
    float32 instead (:func:`geofix.maps.project.project_lonlat_grid`); a resampled metric
    map stays float64.
    """
    within, resampled = precision
    if geographic or resampled:
        return None
    return within


def _read_netcdf(path: Path, variable: str | None, source: str, precision=(None, False)) -> _Raw:
    saved_within = _storage_within(precision, False)
    saved = _read_saved_netcdf4(path, source, saved_within)
    if saved is not None:
        return saved
    ds = _open_netcdf(path, source)
    with ds:
        if _is_saved(ds.attrs, source):
            if "z" not in ds:
                raise MapError(f"{source}: a geofix map without its variable 'z'")
            return _saved_raw(ds.attrs, ds["z"], source, saved_within)
        var = _pick_variable(ds, variable, source)
        da = _as_yx(ds[var], source)
        xname, yname = da.dims[1], da.dims[0]
        for dim in (xname, yname):
            if dim not in da.coords:
                raise MapError(f"{source}: variable {var!r} has no coordinate for {dim!r}")
        x = _numbers(da[xname], f"coordinate {xname!r}", source)
        y = _numbers(da[yname], f"coordinate {yname!r}", source)
        xa, ya = dict(da[xname].attrs), dict(da[yname].attrs)
        attrs = dict(da.attrs)
        extra = stated_numbers({**ds.attrs, **attrs}, source)
        geographic = _is_geographic(str(xname), str(yname), xa, ya, x, y)
        x, y, flips = _ascending_axes(x, y, source)
        within = _storage_within(precision, geographic)
        values = _numbers(da, f"variable {var!r}", source, flips, within)
    text = " ".join([var, str(attrs.get("long_name", "")), str(attrs.get("standard_name", ""))])
    units = attrs.get("units") or None
    return _Raw(
        values, x, y, geographic, "netcdf", var, units, f"{text} {units or ''}", extra=extra
    )


#: The numbers a map file may state about itself, as attributes on the file or its variable:
#: how well it is registered (metres, :attr:`geofix.maps.grid.Grid.registration_var`) and
#: the 1-sigma of its level against a sensor's (map units,
#: :attr:`geofix.maps.grid.Grid.stated_offset_std`).
STATED_ATTRIBUTES = ("registration_std_m", "offset_std")


def stated_numbers(attrs: dict, source: str, names=STATED_ATTRIBUTES) -> dict:
    """``{name: value}`` of each of :data:`STATED_ATTRIBUTES` a map file states.

    Parameters
    ----------
    attrs : dict
        The file's and the variable's attributes (the variable's win).
    source : str
        For messages.
    names : sequence of str
        The attributes to read.

    Returns
    -------
    dict
        Each given attribute's value (a 1-sigma: metres for ``registration_std_m``, map
        units for ``offset_std``); empty when none is given.

    Raises
    ------
    MapError
        An attribute is not a finite number at least 0.
    """
    out = {}
    for name in names:
        if name not in attrs:
            continue
        raw = attrs[name]
        value = registration_std_value(raw)
        if np.isnan(value):
            raise MapError(f"{source}: {name} must be a number >= 0, got {raw!r}")
        out[name] = value
    return out


def _pick_variable(ds, variable: str | None, source: str) -> str:
    """The requested variable, or the only 2-D one, or ``z``."""
    names = [str(v) for v in ds.data_vars]
    if variable is not None:
        if variable not in names:
            raise MapError(
                f"unknown variable {variable!r} in {source}; available: {', '.join(names)}"
            )
        return variable
    grids = [v for v in names if ds[v].squeeze().ndim == 2]
    if len(grids) == 1:
        return grids[0]
    if "z" in grids:
        return "z"
    shapes = ", ".join(f"{v} {_shape(ds[v])}" for v in names) or "none"
    if not grids:
        raise MapError(
            f"{source}: no 2-D variable of at least 2 x 2 cells to read as a map "
            f"(variables: {shapes})"
        )
    raise MapError(
        f"{source}: several 2-D variables ({', '.join(grids)}); choose one with "
        "map.variable / --variable"
    )


def _shape(da) -> str:
    return "(" + " x ".join(f"{d}={n}" for d, n in da.sizes.items()) + ")"


def _as_yx(da, source: str):
    """The DataArray squeezed to dims ``(y, x)`` (transposed if it comes as x, y)."""
    full = _shape(da)
    da = da.squeeze(drop=True)
    if da.ndim != 2:
        raise MapError(
            f"{source}: variable {da.name!r} {full} is not a 2-D grid of at least 2 x 2 "
            "cells (extra dimensions must have length 1)"
        )
    first, second = (str(d).lower() for d in da.dims)
    if first in _X_NAMES and second in _Y_NAMES:
        return da.transpose()
    return da


def float32_rounding(peak: float) -> float:
    """Largest error of rounding values of magnitude up to ``peak`` to float32.

    float32 has a 24-bit significand: a value rounds by at most ``2**-24`` of itself
    (``inf`` for a ``peak`` that is not finite or beyond the float32 range).
    """
    peak = abs(float(peak))
    if not peak <= float(np.finfo(np.float32).max):
        return float("inf")
    return peak * 2.0**-24


def _numbers(
    da, what: str, source: str, flips=(False, False), float32_within: float | None = None
) -> np.ndarray:
    """The values of a DataArray, read in blocks of rows into their final array.

    Parameters
    ----------
    da : xarray.DataArray
        A lazily loaded variable; 2-D for a map (1-D coordinates are read whole).
    what, source : str
        For messages.
    flips : tuple of bool
        ``(flip_x, flip_y)``: reverse the columns / rows while reading (2-D only).
    float32_within : float, optional
        Store float32 when rounding the largest magnitude read changes it by at most
        this (map units); otherwise (or None) float64. A variable that turns out too
        large for it is read again into float64.

    Raises
    ------
    MapError
        Text values. MemoryBudgetError: the array (plus one block) would not fit.
    """
    if da.dtype.kind not in "biuf":
        raise MapError(f"{source}: {what} holds {da.dtype} values, not numbers")
    if da.ndim != 2:
        check_allocation(cells_bytes(da.size, copies=2), f"{source}: reading {what} {_shape(da)}")
        return np.asarray(da.values, dtype=float)
    dtype = np.dtype(np.float32 if float32_within is not None else np.float64)
    ny, nx = (int(n) for n in da.shape)
    step = max(1, READ_BLOCK_BYTES // (8 * max(nx, 1)))
    block_bytes = 3.0 * 8 * min(step, ny) * nx  # the block read, its float64 copy, |block|
    need = cells_bytes(ny, nx, itemsize=dtype.itemsize) + block_bytes
    check_allocation(need, f"{source}: reading {what} {_shape(da)} as {dtype.name}")
    out = np.empty((ny, nx), dtype)
    peak = 0.0
    for r0 in range(0, ny, step):
        r1 = min(r0 + step, ny)
        block = da[r0:r1]
        block = np.asarray(getattr(block, "values", block), dtype=float)
        if flips[0]:
            block = block[:, ::-1]
        if flips[1]:
            out[ny - r1 : ny - r0] = block[::-1]
        else:
            out[r0:r1] = block
        if dtype == np.float32:
            largest = np.fmax.reduce(np.abs(block), axis=None)  # NaN only if all NaN
            peak = max(peak, float(largest)) if largest == largest else peak
    if dtype == np.float32 and not float32_rounding(peak) <= (float32_within or 0.0):
        del out
        return _numbers(da, what, source, flips, None)
    return out


def _is_geographic(xname: str, yname: str, xattrs: dict, yattrs: dict, x, y) -> bool:
    """Whether the axes are lon/lat degrees (units, names, then value ranges)."""
    units = f"{xattrs.get('units', '')} {yattrs.get('units', '')}".lower()
    if "degree" in units:
        return True
    if xname.lower() in ("lon", "longitude") or yname.lower() in ("lat", "latitude"):
        return True
    if units.strip():
        return False
    in_range = np.all(np.abs(x) <= 180) and np.all(np.abs(y) <= 90)
    fine = np.median(np.abs(np.diff(x))) < 1 and np.median(np.abs(np.diff(y))) < 1
    return bool(in_range and fine)


def _read_saved_netcdf4(path: Path, source: str, float32_within=None) -> _Raw | None:
    """A grid written by :func:`save_grid`, read with netCDF4 alone; None if it is not one.

    Importing xarray (and dask, which xarray looks for) takes longer than reading a map
    of a few million cells; geofix's own files have a known layout (variable ``z`` of
    floats, unpacked, NaN or no fill value), read here as xarray would decode them.
    """
    try:
        import netCDF4
    except ImportError:  # pragma: no cover - a dependency of the netCDF reader
        return None
    try:
        ds = netCDF4.Dataset(path, "r")
    except OSError:
        return None
    with ds:
        attrs = {name: ds.getncattr(name) for name in ds.ncattrs()}
        var = ds.variables.get("z")
        if not _is_saved(attrs, source) or var is None or not _plain_floats(var):
            return None
        var.set_auto_maskandscale(False)
        return _saved_raw(attrs, _Rows(var), source, float32_within)


def _plain_floats(var) -> bool:
    """A 2-D float variable stored as it is decoded: no packing, no fill value but NaN."""
    names = set(var.ncattrs())
    if names & {"scale_factor", "add_offset", "missing_value", "valid_min", "valid_max"}:
        return False
    if "valid_range" in names or var.dtype.kind != "f" or var.ndim != 2:
        return False
    return "_FillValue" not in names or bool(np.isnan(var.getncattr("_FillValue")))


class _Rows:
    """A netCDF4 variable as :func:`_numbers` reads it: dtype, shape, blocks of rows."""

    def __init__(self, var) -> None:
        self._var = var
        self.dtype = var.dtype
        self.shape = tuple(int(n) for n in var.shape)
        self.ndim = len(self.shape)
        self.size = int(np.prod(self.shape))
        self.sizes = dict(zip(var.dimensions, self.shape, strict=True))

    def __getitem__(self, rows) -> np.ndarray:
        return np.asarray(self._var[rows])


def _saved_raw(a: dict, z, source: str, float32_within: float | None = None) -> _Raw:
    """A grid written by :func:`save_grid`: its attributes ``a`` and its variable ``z``."""
    geometry = _saved_geometry(a, source)
    saved = _saved_labels(a, source)
    values = _numbers(z, "variable 'z'", source, (False, False), float32_within)
    if values.ndim != 2:
        raise MapError(f"{source}: variable 'z' has {values.ndim} dimensions, expected 2")
    ny, nx = values.shape
    x0, y0, dx, dy = geometry
    x = x0 + dx * np.arange(nx)
    y = y0 + dy * np.arange(ny)
    spacing = (dx, dy)
    return _Raw(values, x, y, False, "geofix", "z", saved["units"], spacing=spacing, saved=saved)


def _is_saved(attrs, source: str) -> bool:
    """Whether the attributes mark a grid written by :func:`save_grid` (MapError if garbled)."""
    marker = attrs.get("geofix_grid", 0)
    try:
        return int(np.asarray(marker).item()) == 1
    except (TypeError, ValueError, OverflowError):
        raise MapError(f"{source}: attribute geofix_grid is not a number") from None


def _saved_geometry(a, source: str) -> tuple[float, float, float, float]:
    """``(x0, y0, dx, dy)`` of a saved grid: finite metres, positive steps (else MapError)."""
    out = []
    for key in ("x0", "y0", "dx", "dy"):
        try:
            value = float(np.asarray(a[key]).item())
        except KeyError:
            raise MapError(f"{source}: a geofix map without its attribute {key}") from None
        except (TypeError, ValueError, OverflowError):
            raise MapError(f"{source}: attribute {key} is not a number") from None
        if not np.isfinite(value) or (key in ("dx", "dy") and value <= 0):
            raise MapError(f"{source}: attribute {key} = {value:g} is not a valid map geometry")
        out.append(value)
    return out[0], out[1], out[2], out[3]


def _saved_labels(a, source: str) -> dict:
    """Kind, units, name and meta of a saved grid (MapError if garbled)."""
    saved: dict = {k: str(a.get(k, default)) for k, default in _SAVED_LABELS.items()}
    if saved["kind"] not in KINDS:
        raise MapError(f"{source}: attribute kind = {saved['kind'][:40]!r}, not one of {KINDS}")
    try:
        meta = json.loads(str(a.get("meta_json", "{}")))
    except (ValueError, RecursionError):
        raise MapError(f"{source}: attribute meta_json is not valid JSON") from None
    if not isinstance(meta, dict):
        raise MapError(f"{source}: attribute meta_json is not a JSON object")
    projection = meta.get("projection")
    if projection is not None and not isinstance(projection, str):
        raise MapError(f"{source}: meta_json projection is not a PROJ string")
    saved["meta"] = meta
    saved["infinite_ok"] = str(a.get(INFINITE_ATTR, "")) == "allowed"
    return saved


# ---------------------------------------------------------------------- GeoTIFF
def _read_geotiff(path: Path, variable: str | None, source: str, precision=(None, False)) -> _Raw:
    import rioxarray

    try:
        da = rioxarray.open_rasterio(path, masked=True)
    except Exception as exc:  # rasterio raises its own error types
        raise MapError(f"cannot read {source} as GeoTIFF: {_one_line(exc)}") from exc
    if isinstance(da, list):  # several subdatasets: not a single-grid GeoTIFF
        raise MapError(f"{source}: a GeoTIFF of {len(da)} subdatasets; give one of them")
    with da:
        band = _pick_band(da, variable, source)
        crs = da.rio.crs
        x, y = da["x"].values.astype(float), da["y"].values.astype(float)
        data = da.isel(band=band) if "band" in da.dims else da
        attrs = dict(da.attrs)
        if crs is not None:
            geographic = bool(crs.is_geographic)
        else:
            geographic = _is_geographic("x", "y", {}, {}, x, y)
        x, y, flips = _ascending_axes(x, y, source)
        within = _storage_within(precision, geographic)
        values = _numbers(data, f"band {band + 1}", source, flips, within)
    units = attrs.get("units") or None
    text = f"{attrs.get('long_name', '')} {units or ''} {path.stem}"
    extra = {"crs": crs.to_string() if crs is not None else None}
    return _Raw(values, x, y, geographic, "geotiff", f"band {band + 1}", units, text, extra=extra)


def _pick_band(da, variable: str | None, source: str) -> int:
    """Zero-based band index from ``variable`` (a 1-based band number), default band 1."""
    count = da.sizes.get("band", 1)
    if variable is None:
        return 0
    try:
        band = int(str(variable).lower().removeprefix("band").strip())
    except ValueError:
        band = 0
    if not 1 <= band <= count:
        raise MapError(f"unknown band {variable!r} in {source}; available: 1..{count}")
    return band - 1


# ---------------------------------------------------------------------- BAG
def _read_bag(path: Path, source: str) -> _Raw:
    import h5py

    try:
        with h5py.File(path, "r") as f:
            values = np.asarray(f["BAG_root/elevation"][()], dtype=float)
            xml = np.asarray(f["BAG_root/metadata"][()]).tobytes()
    except (OSError, KeyError) as exc:
        raise MapError(f"cannot read {source} as BAG: {_one_line(exc)}") from exc
    dx, dy, llx, lly = _bag_geometry(xml, source)
    values[values >= BAG_NODATA] = np.nan
    ny, nx = values.shape
    x = llx + dx * np.arange(nx)
    y = lly + dy * np.arange(ny)
    return _Raw(values, x, y, False, "bag", "elevation", "m", "elevation", spacing=(dx, dy))


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _bag_geometry(xml: bytes, source: str) -> tuple[float, float, float, float]:
    """``(dx, dy, x_sw, y_sw)`` from BAG ISO metadata: resolutions and the SW corner."""
    try:
        root = ET.fromstring(xml.replace(b"\x00", b"").strip())
        resolution = {}
        for dim in (e for e in root.iter() if _local(e.tag) == "MD_Dimension"):
            named = [e for e in dim.iter() if _local(e.tag) == "dimensionName"]
            res = [e for e in dim.iter() if _local(e.tag) == "resolution"]
            key = "".join(named[0].itertext()).strip() or named[0].attrib.get("codeListValue")
            resolution[key] = float("".join(res[0].itertext()).strip())
        coords = next(e for e in root.iter() if _local(e.tag) == "coordinates")
        sw = (coords.text or "").split()[0].split(",")
        return resolution["column"], resolution["row"], float(sw[0]), float(sw[1])
    except (ET.ParseError, KeyError, IndexError, ValueError, StopIteration, AttributeError) as e:
        raise MapError(f"{source}: cannot find grid spacing and corners in BAG metadata") from e


# ---------------------------------------------------------------------- shared steps
def _ascending_axes(x: np.ndarray, y: np.ndarray, source: str):
    """``(x, y, (flip_x, flip_y))``: both axes ascending, and which ones were reversed."""
    for axis, coord in ((1, x), (0, y)):
        step = np.diff(coord)
        if not (np.all(step > 0) or np.all(step < 0)):
            raise MapError(f"{source}: coordinates along axis {axis} are not monotonic")
    flips = (bool(x[-1] < x[0]), bool(y[-1] < y[0]))
    return (x[::-1] if flips[0] else x), (y[::-1] if flips[1] else y), flips


def _row_blocks(values: np.ndarray):
    """Views of ``values`` by blocks of whole rows (about ``READ_BLOCK_BYTES`` each)."""
    rows = max(1, READ_BLOCK_BYTES // max(values.itemsize * values.shape[-1], 1))
    for r0 in range(0, values.shape[0], rows):
        yield r0, values[r0 : r0 + rows]


def _frozen(values: np.ndarray) -> np.ndarray:
    """``values`` C-contiguous (copied only if not) and read-only: a Grid keeps it as is."""
    values = np.ascontiguousarray(values)
    if values.dtype not in (np.float32, np.float64):
        values = values.astype(np.float64)
    values.flags.writeable = False
    return values


def _crop(raw: _Raw, region, source: str) -> _Raw:
    """Keep the cells whose centres lie in ``[west, east, south, north]``."""
    if region is None:
        return raw
    try:
        west, east, south, north = (float(v) for v in region)
    except (TypeError, ValueError):
        raise MapError(f"region must be [west, east, south, north], got {region!r}") from None
    tol_x = 1e-9 * (abs(raw.x[-1] - raw.x[0]) + 1.0)
    tol_y = 1e-9 * (abs(raw.y[-1] - raw.y[0]) + 1.0)
    cols = np.flatnonzero((raw.x >= west - tol_x) & (raw.x <= east + tol_x))
    rows = np.flatnonzero((raw.y >= south - tol_y) & (raw.y <= north + tol_y))
    if cols.size < 2 or rows.size < 2:
        cover = f"{raw.x[0]:g}..{raw.x[-1]:g}, {raw.y[0]:g}..{raw.y[-1]:g}"
        raise MapError(f"region {list(region)} leaves no cells of {source} (it covers {cover})")
    values = raw.values[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1]
    x, y = raw.x[cols[0] : cols[-1] + 1], raw.y[rows[0] : rows[-1] + 1]
    return replace(raw, values=values, x=x, y=y)


def _detect_kind(text: str, default_kind: str | None) -> str:
    lowered = text.lower()
    tokens = set(lowered.replace("_", " ").replace("(", " ").replace(")", " ").split())
    if any(w in lowered for w in _MAGNETIC_WORDS) or tokens & set(_MAGNETIC_TOKENS):
        return "magnetic"
    if any(word in lowered for word in _GRAVITY_WORDS):
        return "gravity"
    return default_kind or "depth"


def _require_finite(values: np.ndarray, source: str) -> None:
    """Refuse ``+inf`` / ``-inf`` cells: no-data must be NaN (or the file's fill value).

    Checked a block of rows at a time: no full-map mask is made.
    """
    count, first = 0, None
    for r0, block in _row_blocks(np.atleast_2d(values)):
        bad = np.isinf(block)
        n = int(np.count_nonzero(bad))
        if n and first is None:
            row, col = np.unravel_index(int(np.argmax(bad)), block.shape)
            first = (r0 + int(row), int(col))
        count += n
    if first is not None:
        raise MapError(
            f"{source}: {count} cells are infinite (first at row {first[0]}, column "
            f"{first[1]}); mark no-data as NaN or with _FillValue"
        )


def _require_data(values: np.ndarray, source: str) -> None:
    if np.isnan(np.fmax.reduce(values, axis=None)):  # all NaN, without a full-map mask
        raise MapError(f"{source}: every cell is NaN (no data) in the selected area")


def _spacing(raw: _Raw) -> tuple[float, float]:
    """Native cell size in file units (regularity checked for metric axes)."""
    if raw.spacing is not None:
        return raw.spacing
    dx = (raw.x[-1] - raw.x[0]) / (raw.x.size - 1)
    dy = (raw.y[-1] - raw.y[0]) / (raw.y.size - 1)
    return float(dx), float(dy)


def _check_regular(raw: _Raw, dx: float, dy: float, source: str) -> None:
    for coord, step in ((raw.x, dx), (raw.y, dy)):
        if np.max(np.abs(np.diff(coord) - step)) > 1e-3 * step:
            raise MapError(f"{source}: projected grid coordinates are not regularly spaced")


def _provenance(raw: _Raw, source: str, region) -> dict:
    meta = {
        "source": source,
        "format": raw.fmt,
        "variable": raw.variable,
        "region": None if region is None else [float(v) for v in region],
        "original_spacing": _spacing(raw),
        "original_shape": tuple(raw.values.shape),
        "geographic": raw.geographic,
    }
    meta.update(raw.extra)
    return meta


def _to_metric(
    raw: _Raw, cell_m: float | None, meta: dict, source: str, labels: dict, float32_within=None
) -> Grid:
    """Project (lon/lat) or keep (metric) the raw grid, then resample if asked.

    ``float32_within``: the rounding a lon/lat map's projection may take to be stored in
    float32 (see :func:`geofix.maps.project.project_lonlat_grid`).
    """
    _require_data(raw.values, source)
    if raw.geographic:
        _check_lonlat(raw, source)
        pv = project.project_lonlat_grid(raw.values, raw.x, raw.y, cell_m, float32_within)
        _require_data(pv.values, source)
        meta["projection"] = pv.proj
        meta["native_spacing_m"] = project.native_spacing_m(raw.x, raw.y, pv.proj)
        return Grid(_frozen(pv.values), pv.x0, pv.y0, pv.dx, pv.dy, meta=meta, **labels)
    dx, dy = _spacing(raw)
    _check_regular(raw, dx, dy, source)
    meta["projection"] = None
    values = _frozen(raw.values)
    grid = Grid(values, float(raw.x[0]), float(raw.y[0]), dx, dy, meta=meta, **labels)
    if cell_m is not None:
        grid = project.resample_m(grid, cell_m)
        _require_data(grid.values, source)
    return grid


def _check_lonlat(raw: _Raw, source: str) -> None:
    """Refuse lon/lat axes outside the globe (latitude beyond +-90, longitude beyond 360)."""
    if not (np.all(np.abs(raw.y) <= 90) and np.all(np.abs(raw.x) <= 360)):
        raise MapError(
            f"{source}: degree coordinates out of range (longitude {raw.x[0]:g}..{raw.x[-1]:g},"
            f" latitude {raw.y[0]:g}..{raw.y[-1]:g}); latitudes must lie within -90..90"
        )
    if raw.x[-1] - raw.x[0] > 360:
        raise MapError(f"{source}: longitudes span more than 360 degrees")


def _finish_saved(raw: _Raw, region, cell_m, kind: str | None, name: str | None) -> Grid:
    """A grid written by :func:`save_grid`: restore it, cropping/resampling if asked."""
    saved = raw.saved
    assert saved is not None and raw.spacing is not None  # a grid written by save_grid
    _require_data(raw.values, str(saved["name"]))
    meta = dict(saved["meta"])
    if region is not None:
        meta["region"] = [float(v) for v in region]
    dx, dy = raw.spacing
    grid = Grid(
        _frozen(raw.values),
        float(raw.x[0]),
        float(raw.y[0]),
        dx,
        dy,
        kind=kind or str(saved["kind"]),
        units=str(saved["units"]),
        name=name or str(saved["name"]),
        meta=meta,
    )
    return grid if cell_m is None else project.resample_m(grid, cell_m)
