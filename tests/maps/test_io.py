"""Reading maps: bundled files, netCDF, GeoTIFF, BAG, saved grids, errors."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
import xarray as xr
from pyproj import Proj

from geofix.errors import MapError
from geofix.maps import (
    BUNDLED_MAPS,
    Grid,
    builtin_path,
    bundled_maps,
    load_grid,
    save_grid,
)


# ---------------------------------------------------------------------- helpers
def write_lonlat_netcdf(path, values, lon, lat, var="z", units=None, **var_attrs):
    """A small CF-style lon/lat netCDF."""
    da = xr.DataArray(values, dims=("lat", "lon"), coords={"lon": lon, "lat": lat})
    da["lon"].attrs["units"] = "degrees_east"
    da["lat"].attrs["units"] = "degrees_north"
    if units:
        da.attrs["units"] = units
    da.attrs.update(var_attrs)
    xr.Dataset({var: da}).to_netcdf(path)
    return path


def write_metric_netcdf(path, data_vars: dict, x, y):
    ds = xr.Dataset({k: (("y", "x"), v) for k, v in data_vars.items()}, coords={"x": x, "y": y})
    ds.to_netcdf(path)
    return path


# ---------------------------------------------------------------------- bundled table
def test_bundled_table_names_packaged_files():
    assert set(bundled_maps()) == {
        "azores",
        "alaska_gravity",
        "mb_1km",
        "grav_1km",
        "navo_flat",
        "deep_nans",
    }
    for name, entry in BUNDLED_MAPS.items():
        path = builtin_path(name)
        assert path.is_file() and path.name == entry.file
        assert entry.licence and entry.source


def test_unknown_builtin_lists_known_names():
    with pytest.raises(MapError, match=r"known maps: .*azores"):
        load_grid("builtin:atlantis")


# ---------------------------------------------------------------------- bundled maps
def test_azores_is_projected_with_native_spacing():
    grid = load_grid("builtin:azores")
    native_dx, native_dy = grid.meta["native_spacing_m"]
    # 1 arc-minute: ~1852 m north-south; east-west shrinks with cos(39.25 deg).
    assert native_dy == pytest.approx(1850, abs=5)
    assert native_dx == pytest.approx(1850 * np.cos(np.radians(39.25)), rel=0.01)
    assert grid.dx == grid.dy == pytest.approx(native_dx)
    west, east, south, north = grid.extent
    assert east - west == pytest.approx(906e3, rel=0.02)  # 10 deg of longitude at 35.5 N
    assert north - south == pytest.approx(845e3, rel=0.02)  # 7.5 deg of latitude + curvature
    assert grid.kind == "depth" and grid.units == "m" and grid.name == "azores"
    assert "+proj=tmerc" in grid.meta["projection"]
    assert grid.meta["source"] == "builtin:azores" and grid.meta["variable"] == "z"
    v = grid.values
    assert -5158.4 <= np.nanmin(v) < -5000 and 1000 < np.nanmax(v) <= 1116.7
    assert np.mean(np.isnan(v)) < 0.1  # only the corners outside the lon/lat box


def test_alaska_gravity_kind_from_attributes():
    grid = load_grid("builtin:alaska_gravity", resample_m=5000)
    assert grid.kind == "gravity" and grid.units == "mGal"
    assert grid.dx == grid.dy == 5000
    assert grid.meta["native_spacing_m"][1] == pytest.approx(3710, abs=10)  # 2 arc-minutes
    assert np.nanmin(grid.values) > -107.5 and np.nanmax(grid.values) < 190


@pytest.mark.parametrize(
    ("name", "kind", "units", "low", "high"),
    [
        ("mb_1km", "depth", "m", -5021.02, -2200.42),
        ("grav_1km", "gravity", "mGal", -60.03, 33.83),
    ],
)
def test_projected_1km_grids_keep_their_cells(name, kind, units, low, high):
    grid = load_grid(f"builtin:{name}")
    assert grid.shape == (160, 160)
    assert (grid.dx, grid.dy) == (1000.0, 1000.0)
    assert (grid.x0, grid.y0) == (-84000.0, -78000.0)
    assert grid.meta["projection"] is None
    assert (grid.kind, grid.units) == (kind, units)
    assert np.nanmin(grid.values) == pytest.approx(low, abs=0.01)
    assert np.nanmax(grid.values) == pytest.approx(high, abs=0.01)


def test_bag_shape_nodata_and_geometry():
    grid = load_grid("builtin:navo_flat")
    assert grid.shape == (1478, 1707)
    assert (grid.dx, grid.dy) == (2.0, 2.0)
    assert grid.x0 == pytest.approx(620153.8729, abs=1e-3)
    assert grid.y0 == pytest.approx(7243549.9117, abs=1e-3)
    with h5py.File(builtin_path("navo_flat"), "r") as f:
        raw = f["BAG_root/elevation"][()]
    np.testing.assert_array_equal(np.isnan(grid.values), raw >= 1e6)
    assert np.mean(~np.isnan(grid.values)) == pytest.approx(0.4587, abs=1e-3)
    assert np.nanmin(grid.values) == pytest.approx(-52.957, abs=1e-3)
    assert np.nanmax(grid.values) == pytest.approx(-50.987, abs=1e-3)


def test_deep_nans_keeps_its_gaps():
    grid = load_grid("builtin:deep_nans", resample_m=500)
    nan_fraction = np.mean(np.isnan(grid.values))
    assert 0.45 < nan_fraction < 0.6
    assert np.nanmin(grid.values) > -4719.1 and np.nanmax(grid.values) < -4099.9


# ---------------------------------------------------------------------- region and projection
def test_region_is_cut_before_projection(azores_small):
    full = load_grid("builtin:azores")
    assert azores_small.meta["region"] == [-29.45, -27.15, 37.7, 39.5]
    # 1.8 deg of latitude and 2.3 deg of longitude at 1 arc-minute, before projection.
    assert azores_small.meta["original_shape"] == (109, 139)
    assert 195 <= azores_small.shape[0] <= 210 and 195 <= azores_small.shape[1] <= 210
    assert azores_small.dx == azores_small.dy == 1000.0
    small_west, small_east, _, _ = azores_small.extent
    full_west, full_east, _, _ = full.extent
    assert small_east - small_west < 0.25 * (full_east - full_west)
    # The frame is centred on the cropped grid, not on the full map.
    assert "+lat_0=38.6" in azores_small.meta["projection"]
    assert "+lon_0=-28.3" in azores_small.meta["projection"]


def test_region_on_metric_grid():
    grid = load_grid("builtin:mb_1km", region=[-10000, 10000, 0, 20000])
    assert grid.shape == (21, 21)
    assert (grid.x0, grid.y0) == (-10000.0, 0.0)


def test_projection_of_linear_lonlat_field_is_exact(tmp_path):
    # f = 100 lon + 10 lat is bilinear in lon/lat, so every metric node must read exactly
    # f at its own lon/lat; latitude is stored north-first to exercise the flip.
    lon = np.linspace(-10.0, -8.0, 41)
    lat = np.linspace(45.0, 43.5, 31)
    values = 100 * lon[None, :] + 10 * lat[:, None]
    path = write_lonlat_netcdf(tmp_path / "lin.nc", values, lon, lat)
    grid = load_grid(path, resample_m=2000)
    x, y = np.meshgrid(grid.x, grid.y)
    node_lon, node_lat = Proj(grid.meta["projection"])(x, y, inverse=True)
    ok = ~np.isnan(grid.values)
    assert ok.mean() > 0.9
    np.testing.assert_allclose(grid.values[ok], (100 * node_lon + 10 * node_lat)[ok], atol=1e-8)
    assert grid.values[0, grid.shape[1] // 2] < grid.values[-1, grid.shape[1] // 2]  # row 0 south


def test_metric_netcdf_with_decreasing_y_is_flipped(tmp_path):
    x = 100.0 * np.arange(4)
    y = 100.0 * np.arange(3)[::-1]
    values = np.arange(12.0).reshape(3, 4)  # first row is the northern one
    path = write_metric_netcdf(tmp_path / "m.nc", {"depth": values}, x, y)
    grid = load_grid(path)
    np.testing.assert_array_equal(grid.values, values[::-1])
    assert (grid.x0, grid.y0, grid.dx, grid.dy) == (0.0, 0.0, 100.0, 100.0)


# ---------------------------------------------------------------------- kinds and variables
def test_kind_detected_from_units_and_overridable(tmp_path):
    lon = np.linspace(0.0, 1.0, 11)
    lat = np.linspace(0.0, 1.0, 11)
    values = np.add.outer(lat, lon)
    path = write_lonlat_netcdf(tmp_path / "g.nc", values, lon, lat, var="faa", units="mGal")
    assert load_grid(path).kind == "gravity"
    assert load_grid(path).units == "mGal"
    assert load_grid(path, kind="depth").kind == "depth"
    path2 = write_lonlat_netcdf(tmp_path / "d.nc", values, lon, lat, var="elevation")
    assert (load_grid(path2).kind, load_grid(path2).units) == ("depth", "m")


def test_variable_choice_among_several(tmp_path):
    x = 10.0 * np.arange(5)
    data = {"depth": np.zeros((4, 5)), "quality": np.ones((4, 5))}
    path = write_metric_netcdf(tmp_path / "two.nc", data, x, 10.0 * np.arange(4))
    with pytest.raises(MapError, match="depth, quality"):
        load_grid(path)
    assert np.all(load_grid(path, variable="quality").values == 1.0)
    with pytest.raises(MapError, match=r"unknown variable 'depht'.*available: depth, quality"):
        load_grid(path, variable="depht")


# ---------------------------------------------------------------------- saved grids
def test_save_load_round_trip_is_exact(tmp_path, synthetic_grid):
    values = np.array(synthetic_grid.values)
    values[10:20, 30:35] = np.nan
    grid = synthetic_grid.with_values(
        values, x0=1234.5678, y0=-98765.4321, meta={"source": "x", "n": 3}
    )
    path = save_grid(grid, tmp_path / "saved.nc")
    back = load_grid(path)
    np.testing.assert_array_equal(back.values, grid.values)
    assert (back.x0, back.y0, back.dx, back.dy) == (grid.x0, grid.y0, grid.dx, grid.dy)
    assert (back.kind, back.units, back.name) == (grid.kind, grid.units, grid.name)
    assert back.meta == grid.meta


def test_saved_real_map_round_trip_and_region(tmp_path, azores_small):
    path = save_grid(azores_small, tmp_path / "azores.nc")
    back = load_grid(path)
    np.testing.assert_array_equal(back.values, azores_small.values)
    assert back.x0 == azores_small.x0 and back.dy == azores_small.dy
    cut = load_grid(path, region=[-20e3, 20e3, -10e3, 10e3])
    # Cell centres inside the region, up to round-off (the crop tolerates ~1e-9 of the span).
    in_x = np.abs(back.x) <= 20e3 + 1e-3
    in_y = np.abs(back.y) <= 10e3 + 1e-3
    assert cut.shape == (in_y.sum(), in_x.sum())
    assert cut.x0 == back.x[in_x][0] and cut.y0 == back.y[in_y][0]
    np.testing.assert_array_equal(cut.values, back.sample(*np.meshgrid(cut.x, cut.y)))


# ---------------------------------------------------------------------- GeoTIFF
def test_geotiff_projected(tmp_path):
    values = np.arange(30.0).reshape(5, 6)  # as stored: first row north
    values[0, 0] = -9999.0
    x = 500000.0 + 50.0 * np.arange(6)
    y = 4000000.0 + 50.0 * np.arange(5)[::-1]
    da = xr.DataArray(values, dims=("y", "x"), coords={"x": x, "y": y})
    da = da.rio.write_crs("EPSG:32630").rio.write_nodata(-9999.0)
    da.rio.to_raster(tmp_path / "map.tif")
    grid = load_grid(tmp_path / "map.tif")
    expected = values[::-1].copy()
    expected[-1, 0] = np.nan
    np.testing.assert_array_equal(grid.values, expected)
    assert (grid.x0, grid.y0, grid.dx, grid.dy) == (500000.0, 4000000.0, 50.0, 50.0)
    assert grid.meta["projection"] is None and "32630" in grid.meta["crs"]


def test_geotiff_geographic_is_projected(tmp_path):
    lon = -10.0 + 0.05 * np.arange(8)
    lat = 40.0 + 0.05 * np.arange(6)[::-1]
    values = 100 * lon[None, :] + 10 * lat[:, None]
    da = xr.DataArray(values, dims=("y", "x"), coords={"x": lon, "y": lat})
    da.rio.write_crs("EPSG:4326").rio.to_raster(tmp_path / "geo.tif")
    grid = load_grid(tmp_path / "geo.tif", resample_m=1000)
    assert grid.meta["geographic"] and "+proj=tmerc" in grid.meta["projection"]
    x, y = np.meshgrid(grid.x, grid.y)
    node_lon, node_lat = Proj(grid.meta["projection"])(x, y, inverse=True)
    ok = ~np.isnan(grid.values)
    np.testing.assert_allclose(grid.values[ok], (100 * node_lon + 10 * node_lat)[ok], atol=1e-6)


# ---------------------------------------------------------------------- errors
def test_missing_file():
    with pytest.raises(MapError, match="map file not found"):
        load_grid("no/such/map.nc")


def test_unreadable_file(tmp_path):
    path = tmp_path / "broken.nc"
    path.write_bytes(b"this is not a netCDF file")
    with pytest.raises(MapError, match=r"not a netCDF / GeoTIFF / BAG file: .*broken.nc"):
        load_grid(path)


def test_empty_region():
    with pytest.raises(MapError, match=r"region .* leaves no cells"):
        load_grid("builtin:azores", region=[10.0, 11.0, 35.6, 36.0])


def test_all_nan_map(tmp_path):
    path = write_metric_netcdf(
        tmp_path / "nan.nc", {"z": np.full((3, 3), np.nan)}, [0, 1, 2], [0, 1, 2]
    )
    with pytest.raises(MapError, match="every cell is NaN"):
        load_grid(path)


def test_bad_kind():
    with pytest.raises(MapError, match="kind must be one of"):
        load_grid("builtin:mb_1km", kind="seismic")


def test_loaded_grid_is_a_grid(azores_small):
    assert isinstance(azores_small, Grid)
    assert azores_small.name == "azores_small"
