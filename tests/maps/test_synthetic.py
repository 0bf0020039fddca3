"""Synthetic maps: fractal terrain and tilted planes."""

from __future__ import annotations

import numpy as np
import pytest

from geofix.errors import ConfigError
from geofix.maps import fractal_terrain, planar_grid, terrain_stats


def test_fractal_std_and_mean_are_exact(rng):
    grid = fractal_terrain((96, 80), 5.0, rng, std=3.32, mean=-42.0)
    assert grid.shape == (96, 80)
    assert grid.dx == grid.dy == 5.0
    assert (grid.x0, grid.y0) == (0.0, 0.0)
    assert np.std(grid.values) == pytest.approx(3.32, rel=1e-12)
    assert np.mean(grid.values) == pytest.approx(-42.0, rel=1e-12)
    assert grid.kind == "depth" and grid.units == "m" and grid.name == "fractal"


def test_fractal_same_seed_same_grid_other_seed_differs():
    a = fractal_terrain((64, 64), 10.0, np.random.default_rng(7))
    b = fractal_terrain((64, 64), 10.0, rng=np.random.default_rng(7))
    c = fractal_terrain((64, 64), 10.0, np.random.default_rng(8))
    np.testing.assert_array_equal(a.values, b.values)
    assert np.max(np.abs(a.values - c.values)) > 1.0


def test_fractal_is_spatially_correlated_and_not_periodic(rng):
    grid = fractal_terrain((128, 128), 10.0, rng, hurst=0.8, std=5.0)
    stats = terrain_stats(grid)
    # Neighbours differ by far less than the overall spread (white noise: ~1.13 std).
    assert stats.roughness < 0.3 * stats.std
    assert stats.correlation_length_m > 30.0
    # Synthesised on a larger canvas: opposite edges are not continuous with each other.
    wrap = np.mean(np.abs(grid.values[:, 0] - grid.values[:, -1]))
    assert wrap > 3 * stats.roughness


def test_fractal_gravity_kind(rng):
    grid = fractal_terrain((32, 32), 100.0, rng, std=10.0, mean=0.0, kind="gravity")
    assert (grid.kind, grid.units) == ("gravity", "mGal")


def test_fractal_rejects_bad_arguments(rng):
    with pytest.raises(TypeError, match="Generator"):
        fractal_terrain((32, 32), 10.0)
    with pytest.raises(ConfigError, match="hurst"):
        fractal_terrain((32, 32), 10.0, rng, hurst=1.5)


def test_planar_grid_values():
    grid = planar_grid((4, 5), 2.0, slope_x=0.5, slope_y=-1.0, offset=10.0, x0=1.0, y0=-3.0)
    x, y = np.meshgrid(1.0 + 2.0 * np.arange(5), -3.0 + 2.0 * np.arange(4))
    np.testing.assert_allclose(grid.values, 10.0 + 0.5 * x - 1.0 * y)
    assert grid.values[1, 0] - grid.values[0, 0] == pytest.approx(-2.0)  # row 1 is north
    gravity = planar_grid((3, 3), 1.0, kind="gravity")
    assert gravity.units == "mGal"
