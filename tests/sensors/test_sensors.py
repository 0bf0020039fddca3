"""Sensor geometry, measurement model and the gravimeter lag."""

import numpy as np
import pytest

from geofix.errors import ConfigError
from geofix.maps.grid import Grid
from geofix.problem import footprint_xy
from geofix.sensors import (
    apply_first_order_lag,
    beam_noise_std,
    compensate_first_order_lag,
    sensor_offsets,
)
from geofix.sensors.spec import SensorSpec
from geofix.sim.sensing import measure, measure_with_unlagged


def smooth_grid(kind="depth"):
    x = np.arange(200) * 10.0
    y = np.arange(150) * 10.0
    xx, yy = np.meshgrid(x, y)
    values = -50.0 + 8.0 * np.sin(xx / 170.0) * np.cos(yy / 230.0) + 0.01 * xx
    return Grid(values, 0.0, 0.0, 10.0, 10.0, kind=kind)


def track(n=40):
    t = np.arange(n)
    positions = np.column_stack([400.0 + 15.0 * t, 300.0 + 10.0 * t])
    heading = np.radians(40.0 + 2.0 * t)
    return positions, heading, 5.0 * t


@pytest.mark.parametrize("kind", ["singlebeam", "gravimeter"])
def test_single_footprint_sensors_have_one_nadir_offset(kind):
    np.testing.assert_array_equal(sensor_offsets(SensorSpec(type=kind, beams=5)), [[0.0, 0.0]])


def test_multibeam_offsets_over_swath_width():
    offsets = sensor_offsets(SensorSpec(type="multibeam", beams=11, swath_width_m=100.0))
    assert offsets.shape == (11, 2)
    np.testing.assert_allclose(offsets[:, 0], np.linspace(-50.0, 50.0, 11))
    np.testing.assert_allclose(offsets[:, 0], -offsets[::-1, 0])
    np.testing.assert_array_equal(offsets[:, 1], 0.0)
    assert offsets[5, 0] == 0.0


def test_multibeam_offsets_from_swath_angle_and_altitude():
    spec = SensorSpec(
        type="multibeam", beams=16, swath_angle_deg=44.0, altitude_m=50.0, swath_width_m=1.0
    )
    offsets = sensor_offsets(spec)
    assert offsets.shape == (16, 2)
    assert offsets[-1, 0] == pytest.approx(50.0 * np.tan(np.radians(22.0)))
    np.testing.assert_allclose(offsets[:, 0], -offsets[::-1, 0], atol=1e-12)
    angles = np.degrees(np.arctan(offsets[:, 0] / 50.0))
    np.testing.assert_allclose(np.diff(angles), 44.0 / 15.0)


def test_multibeam_without_swath_is_a_config_error():
    with pytest.raises(ConfigError, match="swath_width_m"):
        sensor_offsets(SensorSpec(type="multibeam", beams=5, altitude_m=30.0))


def test_beam_noise_grows_linearly_to_the_edge():
    spec = SensorSpec(type="multibeam", beams=5, swath_width_m=40.0, noise_std=0.3)
    std = beam_noise_std(sensor_offsets(spec), spec)
    np.testing.assert_allclose(std, [0.6, 0.45, 0.3, 0.45, 0.6])


@pytest.mark.parametrize(
    "spec",
    [
        SensorSpec(type="singlebeam"),
        SensorSpec(type="multibeam", beams=7, swath_width_m=120.0),
        SensorSpec(type="gravimeter"),
    ],
)
def test_noiseless_measurement_is_the_map_at_the_footprints(spec):
    grid = smooth_grid()
    positions, heading, times = track()
    offsets = sensor_offsets(spec)
    measured = measure(grid, positions, heading, offsets, spec, np.random.default_rng(0), times)
    x, y = footprint_xy(positions, heading, offsets)
    assert measured.shape == (40, offsets.shape[0])
    np.testing.assert_array_equal(measured, grid.sample(x, y))
    assert np.all(np.isfinite(measured))


def test_measurement_noise_per_beam_and_map_error():
    grid = smooth_grid()
    positions = np.tile([800.0, 700.0], (4000, 1))
    heading = np.zeros(4000)
    spec = SensorSpec(
        type="multibeam", beams=3, swath_width_m=40.0, noise_std=0.3, map_error_std=0.4
    )
    offsets = sensor_offsets(spec)
    rng = np.random.default_rng(1)
    measured = measure(grid, positions, heading, offsets, spec, rng)
    clean = grid.sample(*footprint_xy(positions, heading, offsets))
    expected = np.hypot([0.6, 0.3, 0.6], 0.4)
    np.testing.assert_allclose((measured - clean).std(axis=0), expected, rtol=0.05)


def test_lag_of_a_step_and_its_exact_inverse():
    times = np.arange(6) * 10.0
    step = np.array([0.0, 1.0, 1.0, 1.0, 1.0, 1.0])
    lagged = apply_first_order_lag(step, times, 20.0)
    a = np.exp(-0.5)
    np.testing.assert_allclose(lagged, 1.0 - np.r_[1.0, a ** np.arange(1, 6)])
    np.testing.assert_allclose(compensate_first_order_lag(lagged, times, 20.0), step, atol=1e-12)


def test_lag_then_compensate_returns_the_input_with_uneven_times():
    rng = np.random.default_rng(2)
    times = np.cumsum(rng.uniform(5.0, 30.0, 50))
    values = rng.normal(20.0, 5.0, (50, 2))
    lagged = apply_first_order_lag(values, times, 120.0)
    assert np.abs(lagged - values).max() > 1.0
    np.testing.assert_allclose(compensate_first_order_lag(lagged, times, 120.0), values, atol=1e-9)
    np.testing.assert_array_equal(apply_first_order_lag(values, times, 0.0), values)


def test_gravimeter_lag_is_applied_after_the_noise():
    grid = smooth_grid(kind="gravity")
    positions, heading, times = track()
    spec = SensorSpec(type="gravimeter", noise_std=1.0, lag_s=60.0)
    offsets = sensor_offsets(spec)
    measured, unlagged = measure_with_unlagged(
        grid, positions, heading, offsets, spec, np.random.default_rng(3), times
    )
    clean = grid.sample(*footprint_xy(positions, heading, offsets))
    assert 0.4 < np.std(unlagged - clean) < 1.6
    np.testing.assert_allclose(measured, apply_first_order_lag(unlagged, times, 60.0))
    np.testing.assert_allclose(compensate_first_order_lag(measured, times, 60.0), unlagged)
    with pytest.raises(ValueError, match="times"):
        measure(grid, positions, heading, offsets, spec, np.random.default_rng(3))


def test_footprint_off_the_map_reads_nan():
    grid = smooth_grid()
    spec = SensorSpec(type="singlebeam")
    positions = np.array([[100.0, 100.0], [5000.0, 100.0]])
    measured = measure(
        grid, positions, np.zeros(2), sensor_offsets(spec), spec, np.random.default_rng(0)
    )
    assert np.isfinite(measured[0, 0]) and np.isnan(measured[1, 0])
