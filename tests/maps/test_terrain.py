"""Terrain numerics: sampling and resampling on planes, gradients, plane fits, statistics."""

from __future__ import annotations

import numpy as np
import pytest

from geofix.maps import (
    gradient,
    local_std,
    planar_grid,
    plane_fit,
    resample_m,
    terrain_stats,
)
from geofix.maps.terrain import plane_stencil

SLOPE_X, SLOPE_Y, OFFSET = 0.03, -0.02, -250.0


@pytest.fixture(scope="module")
def plane():
    return planar_grid((40, 50), 10.0, SLOPE_X, SLOPE_Y, OFFSET, x0=-100.0, y0=300.0)


def plane_value(x, y):
    return OFFSET + SLOPE_X * x + SLOPE_Y * y


# ---------------------------------------------------------------------- sampling
def test_bilinear_sample_is_exact_on_a_plane(plane, rng):
    west, east, south, north = plane.extent
    x = rng.uniform(west, east, 500)
    y = rng.uniform(south, north, 500)
    np.testing.assert_allclose(plane.sample(x, y), plane_value(x, y), rtol=0, atol=1e-10)


def test_resampled_plane_stays_the_plane(plane):
    coarse = resample_m(plane, 7.3)
    assert coarse.dx == coarse.dy == 7.3
    assert (coarse.x0, coarse.y0) == (plane.x0, plane.y0)
    assert coarse.x[-1] <= plane.extent[1] and coarse.y[-1] <= plane.extent[3]
    assert coarse.shape == (int(390 / 7.3) + 1, int(490 / 7.3) + 1)
    x, y = np.meshgrid(coarse.x, coarse.y)
    np.testing.assert_allclose(coarse.values, plane_value(x, y), rtol=0, atol=1e-10)
    assert coarse.meta["resampled_from_m"] == (10.0, 10.0)


def test_resample_propagates_nan(plane):
    values = np.array(plane.values)
    values[5, 5] = np.nan
    fine = resample_m(plane.with_values(values), 5.0)
    # Nodes whose four bilinear source cells include [5, 5]: fine rows/cols 8..11 (a node
    # on cell row 4 reads rows 4 and 5; one on row 6 reads rows 6 and 7).
    assert np.all(np.isnan(fine.values[8:12, 8:12]))
    assert np.isnan(fine.values).sum() == 16


# ---------------------------------------------------------------------- gradient
def test_gradient_of_a_plane(plane):
    gx, gy = gradient(plane)
    np.testing.assert_allclose(gx, SLOPE_X, atol=1e-12)
    np.testing.assert_allclose(gy, SLOPE_Y, atol=1e-12)


def test_gradient_units_per_metre():
    grid = planar_grid((10, 12), 25.0, 0.0, 0.0, 0.0)
    quad = grid.with_values(0.5 * np.add.outer(np.zeros(10), grid.x**2))  # d/dx = x
    gx, gy = gradient(quad)
    np.testing.assert_allclose(gx[:, 1:-1], np.broadcast_to(grid.x[1:-1], (10, 10)))
    np.testing.assert_allclose(gy, 0.0)


# ---------------------------------------------------------------------- plane fit
def test_plane_fit_recovers_slopes(plane, rng):
    x = rng.uniform(0.0, 200.0, (3, 7))
    y = rng.uniform(450.0, 600.0, (3, 7))
    fit = plane_fit(plane, x, y, half_width_m=35.0)
    assert fit.slope_x.shape == (3, 7)
    np.testing.assert_allclose(fit.slope_x, SLOPE_X, atol=1e-10)
    np.testing.assert_allclose(fit.slope_y, SLOPE_Y, atol=1e-10)
    np.testing.assert_allclose(fit.value_at_centre, plane_value(x, y), atol=1e-8)
    np.testing.assert_allclose(fit.residual_std, 0.0, atol=1e-8)
    assert np.all(fit.n_valid == 81)  # 9 x 9 lattice for 35 m on 10 m cells


def test_plane_fit_off_map_and_partly_off_map(plane):
    west, _, south, _ = plane.extent
    fit = plane_fit(plane, [west - 500.0, west], [south, south + 100.0], 30.0)
    assert np.isnan(fit.slope_x[0]) and np.isnan(fit.value_at_centre[0])
    # On the west edge, only the eastern half of the 7x7 lattice (plus its centre column)
    # is on the map: 28 of 49 valid, above the default half.
    assert fit.n_valid[1] == 28
    assert fit.slope_x[1] == pytest.approx(SLOPE_X, abs=1e-10)
    strict = plane_fit(plane, [west], [south + 100.0], 30.0, min_valid_fraction=0.9)
    assert np.isnan(strict.slope_x[0])


def test_plane_fit_matches_lstsq_with_gaps(synthetic_grid, rng):
    values = np.array(synthetic_grid.values)
    values[40:60, 40:50] = np.nan
    grid = synthetic_grid.with_values(values)
    x = rng.uniform(300.0, 700.0, 12)
    y = rng.uniform(300.0, 700.0, 12)
    fit = plane_fit(grid, x, y, half_width_m=50.0)
    offsets = plane_stencil(grid, 50.0)
    for i in range(x.size):
        z = grid.sample(x[i] + offsets[:, 0], y[i] + offsets[:, 1])
        ok = ~np.isnan(z)
        design = np.column_stack([np.ones(ok.sum()), offsets[ok]])
        coef, *_ = np.linalg.lstsq(design, z[ok], rcond=None)
        resid = z[ok] - design @ coef
        assert fit.n_valid[i] == ok.sum()
        if ok.sum() < 0.5 * ok.size:
            assert np.isnan(fit.slope_x[i])
            continue
        np.testing.assert_allclose(
            [fit.value_at_centre[i], fit.slope_x[i], fit.slope_y[i]], coef, rtol=1e-8, atol=1e-10
        )
        assert fit.residual_std[i] == pytest.approx(np.sqrt(resid @ resid / (ok.sum() - 3)))


def test_plane_stencil_size():
    grid = planar_grid((10, 10), 10.0)
    assert plane_stencil(grid, 2.0).shape == (9, 2)  # at least 3 x 3
    assert plane_stencil(grid, 50.0).shape == (121, 2)  # one cell apart
    wide = plane_stencil(grid, 1000.0, max_side=31)
    assert wide.shape == (31 * 31, 2)
    assert wide.min() == -1000.0 and wide.max() == 1000.0


# ---------------------------------------------------------------------- statistics
def test_terrain_stats_known_array():
    z = np.array([[0.0, 1.0, 3.0], [2.0, 4.0, 8.0], [np.nan, 5.0, 6.0]])
    stats = terrain_stats(z, cell_m=2.0)
    # valid: 0 1 3 2 4 8 5 6 -> mean 3.625, sum of squared deviations 49.875.
    assert stats.mean == pytest.approx(3.625)
    assert stats.std == pytest.approx(np.sqrt(49.875 / 8))
    assert stats.range == 8.0
    # |diffs| along x: 1 2 2 4 1, along y: 2 3 1 5 2 (pairs with the NaN skipped).
    assert stats.roughness == pytest.approx(23 / 10)
    assert stats.valid_fraction == pytest.approx(8 / 9)


def test_terrain_stats_slope_and_correlation_lengths():
    plane = planar_grid((20, 30), 5.0, 3e-3, 4e-3, -50.0)
    assert terrain_stats(plane).mean_slope == pytest.approx(5e-3)
    # A cosine of wavelength 64 cells along x, constant along y: the autocorrelation is
    # cos(2 pi lag / 64), which reaches 1/e at lag = 64 acos(1/e) / (2 pi) cells.
    nx, wavelength = 512, 64
    z = np.tile(np.cos(2 * np.pi * np.arange(nx) / wavelength), (16, 1))
    stats = terrain_stats(z, cell_m=(2.0, 3.0))
    expected = 2.0 * wavelength * np.arccos(np.exp(-1)) / (2 * np.pi)
    assert stats.correlation_length_x_m == pytest.approx(expected, rel=0.02)
    assert stats.correlation_length_y_m == np.inf


def test_correlation_length_grows_with_hurst(rng_factory):
    from geofix.maps import fractal_terrain

    rough = fractal_terrain((128, 128), 10.0, rng_factory(3), hurst=0.2)
    smooth = fractal_terrain((128, 128), 10.0, rng_factory(3), hurst=0.9)
    assert terrain_stats(smooth).correlation_length_m > terrain_stats(rough).correlation_length_m
    assert terrain_stats(smooth).roughness < terrain_stats(rough).roughness


def test_terrain_stats_on_real_map(azores_small):
    stats = terrain_stats(azores_small)
    assert 0.9 < stats.valid_fraction <= 1.0
    assert 300 < stats.std < 2000
    assert 1e3 < stats.correlation_length_m < 1e5


def test_local_std_matches_brute_force(rng):
    z = rng.normal(size=(12, 15))
    z[3, 4] = z[7, 10] = np.nan
    out = local_std(z, 3)
    for r in range(12):
        for c in range(15):
            window = z[max(r - 1, 0) : r + 2, max(c - 1, 0) : c + 2]
            expected = np.nan if np.isnan(z[r, c]) else np.nanstd(window)
            np.testing.assert_allclose(out[r, c], expected, atol=1e-10)


def test_local_std_checkerboard_and_constant(plane):
    board = np.indices((9, 9)).sum(axis=0) % 2 * 2.0 - 1.0  # +-1
    out = local_std(board, 3)
    np.testing.assert_allclose(out[1:-1, 1:-1], np.sqrt(80 / 81))
    flat = plane.with_values(np.full(plane.shape, -40.0))
    np.testing.assert_allclose(local_std(flat, 5), 0.0, atol=1e-12)
