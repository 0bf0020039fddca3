"""The relief the readings show along the track and the map lacks (ProfileRoughness)."""

from __future__ import annotations

import numpy as np
import pytest

from geofix.filters.nuisance import MIN_ROUGHNESS_PINGS, ProfileRoughness
from geofix.maps.grid import Grid

CELL = 100.0  # m
STEP = 10.0  # m between pings
WINDOW = 4 * CELL
RELIEF_STD = 5.0  # m, the seabed's relief below the map
NOISE_STD = 1.0  # m, the sensor's white noise
PINGS = 1000


def _smooth_map() -> Grid:
    """A smooth map: a slope and a gentle curvature, 100 m cells."""
    y, x = np.mgrid[0:60, 0:60] * CELL
    values = 3000.0 + 0.02 * x - 0.01 * y + 2e-6 * (x - 3000.0) ** 2
    return Grid(values=values, x0=0.0, y0=0.0, dx=CELL, dy=CELL, kind="depth", units="m")


def _relief(rng, n: int, corr_m: float) -> np.ndarray:
    """Stationary AR(1) relief of ``RELIEF_STD`` correlated over ``corr_m`` along the track."""
    rho = np.exp(-STEP / corr_m)
    out = np.empty(n)
    out[0] = rng.normal(0.0, RELIEF_STD)
    shocks = rng.normal(0.0, RELIEF_STD * np.sqrt(1 - rho**2), n)
    for i in range(1, n):
        out[i] = rho * out[i - 1] + shocks[i]
    return out


def _floor(measured: np.ndarray, mapped: np.ndarray) -> ProfileRoughness:
    state = ProfileRoughness.empty()
    for i, (m, p) in enumerate(zip(measured, mapped, strict=True)):
        state = state.updated(None if i == 0 else STEP, m, p, WINDOW)
    return state


def _track(n: int) -> np.ndarray:
    return np.column_stack([500.0 + STEP * np.arange(n), np.full(n, 2000.0)])


def test_the_relief_a_map_lacks_is_measured_wherever_the_estimate_is(rng):
    grid = _smooth_map()
    truth = _track(PINGS)
    relief = _relief(rng, PINGS, 30.0)
    measured = grid.sample(*truth.T) + relief + rng.normal(0, NOISE_STD, PINGS)
    here = _floor(measured, grid.sample(*truth.T))
    shifted = _floor(measured, grid.sample(*(truth + np.array([700.0, -900.0])).T))
    # correlated over 30 m with 10 m steps: the white part takes (1 - rho) of the relief and
    # the sensor's noise, the rest is the floor; over 20 seeds it fell within 0.57-1.21 of
    # rho * RELIEF_STD^2 (the windows overlap, and the memory is 500 pings)
    rho = np.exp(-STEP / 30.0)
    assert 0.45 * rho * RELIEF_STD**2 < here.variance < 1.35 * rho * RELIEF_STD**2
    # the map's bilinear kinks differ between the two tracks, and so the windows in which
    # the map is taken to show the relief: 6 % apart here
    assert shifted.variance == pytest.approx(here.variance, rel=0.1)
    assert here.white == pytest.approx((1 - rho) * RELIEF_STD**2 + NOISE_STD**2, rel=0.5)


def test_a_map_that_is_the_seabed_lacks_nothing_and_white_noise_is_not_relief(rng):
    grid = _smooth_map()
    truth = _track(PINGS)
    on_map = grid.sample(*truth.T)
    noisy = on_map + rng.normal(0, 3.0, PINGS)
    assert _floor(noisy, on_map).variance < 0.05 * 3.0**2
    # a seabed with relief that the map has too: nothing lacked
    rough = grid.with_values(grid.values + rng.normal(0, 20.0, grid.values.shape))
    on_rough = rough.sample(*truth.T)
    assert _floor(on_rough + rng.normal(0, 1.0, PINGS), on_rough).variance < 0.05 * 20.0**2


def test_a_short_window_or_missing_values_give_no_floor(rng):
    few = _floor(np.arange(MIN_ROUGHNESS_PINGS - 1.0) ** 2, np.zeros(MIN_ROUGHNESS_PINGS - 1))
    assert few.variance == 0.0 and few.den == 0.0
    state = ProfileRoughness.empty().updated(None, np.nan, 1.0, WINDOW)
    assert state.distance.size == 0
