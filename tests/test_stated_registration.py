"""A map that states how well it is registered: its variance in every reported covariance."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import xarray as xr

from conftest import northward_trial
from geofix import Navigator
from geofix.errors import MapError
from geofix.maps import Grid, load_grid
from geofix.methods import parse_method_spec
from geofix.problem import registered_covariance
from test_navigator import pings, run

STATED_M = 20.0


def _stated(grid: Grid, std=STATED_M) -> Grid:
    return dataclasses.replace(grid, meta={**grid.meta, "registration_std_m": std})


def test_the_stated_registration_is_a_variance_per_axis():
    grid = Grid(np.zeros((3, 3)), 0.0, 0.0, 10.0, 10.0)
    assert grid.registration_var == 0.0
    assert _stated(grid).registration_var == STATED_M**2
    cov = np.stack([np.eye(2), 4.0 * np.eye(2)])
    np.testing.assert_allclose(registered_covariance(_stated(grid), cov)[1], 404.0 * np.eye(2))
    assert registered_covariance(grid, cov) is cov
    assert registered_covariance(_stated(grid), None) is None
    for bad in (-1.0, float("nan"), "far"):
        with pytest.raises(MapError, match="registration_std_m"):
            _ = _stated(grid, bad).registration_var


def test_a_map_file_states_its_registration_in_an_attribute(tmp_path):
    y, x = np.arange(5) * 100.0, np.arange(6) * 100.0
    z = xr.DataArray(np.add.outer(y, x) * 0.01 - 1000.0, coords={"y": y, "x": x}, dims=("y", "x"))
    path = tmp_path / "stated.nc"
    xr.Dataset({"z": z}, attrs={"registration_std_m": 35.0}).to_netcdf(path)
    assert load_grid(path).registration_var == 35.0**2
    xr.Dataset({"z": z}).to_netcdf(path)
    assert load_grid(path).registration_var == 0.0
    xr.Dataset({"z": z}, attrs={"registration_std_m": -5.0}).to_netcdf(path)
    with pytest.raises(MapError, match="registration_std_m must be a number >= 0"):
        load_grid(path)


@pytest.mark.parametrize("spec", ["pmf", "pf", "tercom"])
def test_a_method_reports_its_fix_with_the_stated_registration(spec, synthetic_grid):
    """The estimate is the same; only the reported covariance grows by the stated variance."""
    trial = northward_trial(synthetic_grid, 40, 60.0, (40.0, -30.0), 0.5, np.random.default_rng(3))
    method = parse_method_spec(spec)
    plain = method.match(trial.problem(synthetic_grid), np.random.default_rng(5))
    stated = method.match(trial.problem(_stated(synthetic_grid)), np.random.default_rng(5))
    np.testing.assert_array_equal(stated.track, plain.track)
    np.testing.assert_allclose(stated.covariance, plain.covariance + STATED_M**2 * np.eye(2))


def test_the_navigator_reports_the_stated_registration(synthetic_grid):
    """Its rules of convergence work in the map's frame: the same statuses, every ping."""
    t, truth, beams = pings(synthetic_grid, np.random.default_rng(2))
    offset = np.array([30.0, -25.0])
    runs = []
    for grid in (synthetic_grid, _stated(synthetic_grid)):
        nav = Navigator(grid, "pmf", {"noise_std": 0.3}, seed=1)
        runs.append(run(nav, t, truth + offset, beams))
    assert runs[0][-1].status == "converged"
    for plain, stated in zip(*runs, strict=True):
        assert stated.status == plain.status
        np.testing.assert_array_equal(stated.position, plain.position)
        np.testing.assert_allclose(stated.covariance, plain.covariance + STATED_M**2 * np.eye(2))


def test_a_replay_states_the_registration_it_is_told(small_mission, tmp_path):
    from typer.testing import CliRunner

    from geofix.cli import app
    from geofix.replay import replay_log
    from geofix.sim.export import export_trials

    sensor = {"type": "multibeam", "beams": 7, "swath_width_m": 3000.0, "noise_std": 2.0}
    path = export_trials(small_mission("stated-replay", sensor=sensor, trials=1), tmp_path / "e.nc")
    plain = replay_log(path, None, ["pmf"])[0].estimates["pmf"]
    stated = replay_log(path, None, ["pmf"], registration_std_m=STATED_M)[0].estimates["pmf"]
    for a, b in zip(plain, stated, strict=True):
        assert a.status == b.status
        np.testing.assert_allclose(b.covariance, a.covariance + STATED_M**2 * np.eye(2))
    runner = CliRunner()
    for args in (
        ["replay", str(path), "--method", "pmf", "--registration-std", "-3"],
        ["serve", "--map", "builtin:mb_1km", "--port", "0", "--registration-std", "-3"],
    ):
        result = runner.invoke(app, args)
        assert result.exit_code == 2, result.output
        assert "registration_std_m must be >= 0" in result.output
