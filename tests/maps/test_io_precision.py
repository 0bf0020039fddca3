"""Map loading in blocks: float32 storage when the precision allows, budget refusals."""

from __future__ import annotations

import re

import numpy as np
import pytest
import xarray as xr

from geofix.errors import MemoryBudgetError
from geofix.maps import io
from geofix.maps.grid import Grid
from geofix.maps.io import float32_rounding, load_grid, save_grid


def _field(ny: int = 37, nx: int = 23, seed: int = 5) -> np.ndarray:
    """Depths of a few km with fine detail (float64 digits float32 cannot hold), one gap."""
    rng = np.random.default_rng(seed)
    values = -4000.0 + 1500.0 * rng.standard_normal((ny, nx)) + rng.uniform(0, 1e-3, (ny, nx))
    values[3, 4] = np.nan
    return values


def _descending_netcdf(path, values):
    """A plain metric netCDF with both axes descending (read flipped, block by block)."""
    ny, nx = values.shape
    x, y = 50.0 * np.arange(nx)[::-1], 50.0 * np.arange(ny)[::-1]
    ds = xr.Dataset({"depth": (("y", "x"), values)}, coords={"x": x, "y": y})
    ds.to_netcdf(path)
    return path


@pytest.fixture
def small_blocks(monkeypatch):
    """Blocks of 3 rows: every test map is read in several blocks."""
    monkeypatch.setattr(io, "READ_BLOCK_BYTES", 3 * 8 * 23)


@pytest.mark.usefixtures("small_blocks")
def test_float32_load_is_the_rounded_float64_map_within_the_stated_error(tmp_path):
    values = _field()
    path = _descending_netcdf(tmp_path / "d.nc", values)
    exact = load_grid(path)
    assert exact.values.dtype == np.float64
    np.testing.assert_array_equal(exact.values, values[::-1, ::-1])
    peak = float(np.nanmax(np.abs(values)))
    compact = load_grid(path, float32_within=float32_rounding(peak))
    assert compact.values.dtype == np.float32 and not compact.values.flags.writeable
    np.testing.assert_array_equal(compact.values, exact.values.astype(np.float32))
    error = np.nanmax(np.abs(compact.values.astype(np.float64) - exact.values))
    assert 0 < error <= float32_rounding(peak)
    assert np.isnan(compact.values[-4, -5])  # the gap, flipped with the rest


@pytest.mark.usefixtures("small_blocks")
def test_too_fine_a_tolerance_keeps_float64(tmp_path):
    values = _field()
    path = _descending_netcdf(tmp_path / "d.nc", values)
    peak = float(np.nanmax(np.abs(values)))
    grid = load_grid(path, float32_within=0.5 * float32_rounding(peak))
    assert grid.values.dtype == np.float64
    np.testing.assert_array_equal(grid.values, values[::-1, ::-1])


@pytest.mark.usefixtures("small_blocks")
def test_saved_grid_loads_in_float32_and_resampled_maps_stay_float64(tmp_path):
    values = _field()
    grid = Grid(values, 0.0, 0.0, 50.0, 50.0, name="deep")
    path = save_grid(grid, tmp_path / "g.nc")
    compact = load_grid(path, float32_within=1.0)
    assert compact.values.dtype == np.float32 and compact.name == "deep"
    np.testing.assert_array_equal(compact.values, values.astype(np.float32))
    resampled = load_grid(path, resample_m=100.0, float32_within=1.0)
    np.testing.assert_array_equal(resampled.values, load_grid(path, resample_m=100.0).values)


def test_refusal_gives_the_estimate_of_the_float32_array(tmp_path, monkeypatch, small_blocks):
    values = _field(ny=400, nx=300)
    path = _descending_netcdf(tmp_path / "d.nc", values)
    monkeypatch.setenv("GEOFIX_MEMORY_BUDGET", "100kB")
    with pytest.raises(MemoryBudgetError, match="as float32 would need") as info:
        load_grid(path, float32_within=1.0)
    kib = float(re.search(r"would need ([0-9.]+) KiB", str(info.value)).group(1))
    assert 400 * 300 * 4 <= kib * 1024 < 400 * 300 * 4.1  # the map in float32, plus one block


def test_infinite_cells_are_found_block_by_block(tmp_path, small_blocks):
    values = _field()
    values[20, 7] = np.inf
    path = _descending_netcdf(tmp_path / "d.nc", values)
    with pytest.raises(Exception, match=r"1 cells are infinite \(first at row 16, column 15\)"):
        load_grid(path)


def test_saved_grid_read_with_netcdf4_alone_equals_the_xarray_read(tmp_path, monkeypatch):
    values = _field()
    meta = {"source": "test", "shape": [37, 23]}
    grid = Grid(values, 10.0, -5.0, 50.0, 25.0, kind="gravity", units="mGal", meta=meta)
    path = save_grid(grid, tmp_path / "g.nc")
    direct = load_grid(path, float32_within=1.0)
    monkeypatch.setattr(io, "_read_saved_netcdf4", lambda *args: None)
    through_xarray = load_grid(path, float32_within=1.0)
    np.testing.assert_array_equal(direct.values, through_xarray.values)
    assert direct.values.dtype == through_xarray.values.dtype == np.float32
    fields = ("x0", "y0", "dx", "dy", "kind", "units", "name", "meta")
    assert [getattr(direct, f) for f in fields] == [getattr(through_xarray, f) for f in fields]


def test_packed_saved_grid_is_left_to_xarray(tmp_path):
    grid = Grid(_field(), 0.0, 0.0, 50.0, 50.0)
    path = save_grid(grid, tmp_path / "g.nc")
    with xr.open_dataset(path) as ds:
        packed = ds.load()
    packed["z"].encoding.update(dtype="int32", scale_factor=0.01, _FillValue=-(2**31))
    packed.to_netcdf(tmp_path / "p.nc")
    assert io._read_saved_netcdf4(tmp_path / "p.nc", "p", None) is None
    np.testing.assert_allclose(load_grid(tmp_path / "p.nc").values, grid.values, atol=0.006)


def _lonlat_files(tmp_path, values):
    """The same lon/lat field as a netCDF (latitudes descending) and as a GeoTIFF."""
    ny, nx = values.shape
    lon = -20.0 + 0.01 * np.arange(nx)
    lat = 38.0 + 0.01 * np.arange(ny)[::-1]
    ds = xr.Dataset({"elevation": (("lat", "lon"), values)}, coords={"lon": lon, "lat": lat})
    ds["lon"].attrs["units"] = "degrees_east"
    ds["lat"].attrs["units"] = "degrees_north"
    ds.to_netcdf(tmp_path / "geo.nc")
    da = xr.DataArray(values, dims=("y", "x"), coords={"x": lon, "y": lat})
    da.rio.write_crs("EPSG:4326").rio.to_raster(tmp_path / "geo.tif")
    return tmp_path / "geo.nc", tmp_path / "geo.tif"


@pytest.mark.usefixtures("small_blocks")
def test_lonlat_maps_project_in_row_blocks_straight_into_float32(tmp_path, monkeypatch):
    # Projected a few rows at a time (the same numbers as in one block) and stored in
    # float32 when rounding the projected values' largest magnitude fits: exactly the
    # float64 projection rounded afterwards (what a campaign's storage did); a tighter
    # allowance keeps float64, bit for bit. GeoTIFF and netCDF alike.
    import rioxarray  # noqa: F401 - registers the .rio accessor

    from geofix.maps import project

    for path in _lonlat_files(tmp_path, _field()):
        exact = load_grid(path, resample_m=300.0)
        peak = float(np.nanmax(np.abs(exact.values)))
        monkeypatch.setattr(project, "PROJECT_BLOCK_NODES", 10)
        blocked = load_grid(path, resample_m=300.0)
        np.testing.assert_array_equal(blocked.values, exact.values)
        compact = load_grid(path, resample_m=300.0, float32_within=float32_rounding(peak))
        monkeypatch.undo()
        assert exact.values.dtype == np.float64 and compact.values.dtype == np.float32
        np.testing.assert_array_equal(compact.values, exact.values.astype(np.float32))
        tight = load_grid(path, resample_m=300.0, float32_within=0.99 * float32_rounding(peak))
        assert tight.values.dtype == np.float64
        np.testing.assert_array_equal(tight.values, exact.values)
