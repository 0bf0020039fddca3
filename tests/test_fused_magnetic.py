"""Magnetic anomaly maps (nT) and the magnetometer: a map kind, a sensor, an offset prior."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

import geofix
from geofix.errors import ConfigError
from geofix.evaluate.runner import method_rng, run_trial
from geofix.maps.grid import Grid
from geofix.maps.offset import default_offset_std
from geofix.methods import parse_method_spec
from geofix.sim import scenario_from_dict, simulate_trial

CELL = 100.0


def magnetic_values(shape=(80, 80)) -> np.ndarray:
    """A smooth anomaly of a few hundred nT over ``CELL`` metre cells."""
    y, x = np.indices(shape) * CELL
    return 150.0 * np.sin(x / 900.0) * np.cos(y / 1300.0) + 0.02 * x - 0.01 * y


def write_magnetic_map(tmp_path, units="nT", name="mag_anomaly") -> str:
    values = magnetic_values()
    ny, nx = values.shape
    ds = xr.Dataset(
        {name: (("y", "x"), values)},
        coords={"x": np.arange(nx) * CELL, "y": np.arange(ny) * CELL},
    )
    ds[name].attrs["units"] = units
    ds["x"].attrs["units"] = "m"
    ds["y"].attrs["units"] = "m"
    path = tmp_path / "mag.nc"
    ds.to_netcdf(path)
    return str(path)


def magnetometer_scenario(map_path: str, sensor=None, **map_keys):
    return scenario_from_dict(
        {
            "name": "magnetic-test",
            "map": {"path": map_path, **map_keys},
            "track": {
                "start_m": [1500.0, 3000.0],
                "heading_deg": 85.0,
                "speed_m_s": 5.0,
                "interval_s": 20.0,
                "samples": 40,
            },
            "sensor": sensor or {"type": "magnetometer", "noise_std": 2.0},
            "ins": {"initial_error_m": [150.0, -100.0], "velocity_error_m_s": 0.02},
            "trials": 2,
            "seed": 3,
        }
    )


def test_a_magnetic_map_in_nt_is_detected_with_its_units(tmp_path):
    grid = geofix.load_map(write_magnetic_map(tmp_path, units="nT", name="field"))
    assert grid.kind == "magnetic"
    assert grid.units == "nT"
    np.testing.assert_allclose(grid.values, magnetic_values())


def test_a_magnetic_variable_name_is_detected_before_its_anomaly_word(tmp_path):
    # "magnetic anomaly" also holds "anomaly", a gravity word: magnetic wins
    grid = geofix.load_map(write_magnetic_map(tmp_path, units="", name="magnetic_anomaly"))
    assert grid.kind == "magnetic"


def test_a_magnetic_map_has_a_20_nt_offset_prior():
    grid = Grid(magnetic_values(), 0.0, 0.0, CELL, CELL, kind="magnetic", units="nT")
    assert default_offset_std(grid) == 20.0


def test_a_magnetometer_scenario_runs_and_a_filter_fixes_it(tmp_path):
    scen = magnetometer_scenario(write_magnetic_map(tmp_path))
    grid = geofix.prepare_map(scen)
    trial = simulate_trial(scen, grid, 0)
    assert trial.sensor == "magnetometer"
    assert trial.measured.shape == (40, 1)
    clean = grid.sample(trial.truth[:, 0], trial.truth[:, 1])
    assert np.std(trial.measured[:, 0] - clean) == pytest.approx(2.0, rel=0.4)
    result = run_trial(parse_method_spec("pmf"), trial, grid, method_rng(3, 0, "pmf"))
    free = float(np.hypot(*(trial.indicated[-1] - trial.truth[-1])))
    assert result.end_error_m < 0.5 * free


def test_a_magnetometer_on_a_depth_map_is_refused(tmp_path):
    scen = magnetometer_scenario(write_magnetic_map(tmp_path), kind="depth")
    grid = geofix.prepare_map(scen)
    with pytest.raises(ConfigError, match="magnetometer needs a magnetic map"):
        simulate_trial(scen, grid, 0)
