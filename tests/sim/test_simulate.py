"""Scenario -> Trial simulation on a synthetic map."""

import dataclasses
import sys
import types

import numpy as np
import pytest

from geofix.errors import ConfigError, TrackOffMapError
from geofix.evaluate.crlb import scenario_beam_variance, trial_beam_variance
from geofix.maps.grid import Grid
from geofix.nav.ins import position_sigma
from geofix.sensors import beam_noise_std, compensate_first_order_lag
from geofix.sim import (
    check_track_on_map,
    prepare_map,
    scenario_from_dict,
    simulate_trial,
    simulate_trials,
    start_position,
)
from geofix.sim.export import load_exported, trials_dataset


def smooth_field_grid(kind="gravity", hole=False):
    x = np.arange(400) * 50.0
    xx, yy = np.meshgrid(x, x)
    values = 30.0 * np.sin(xx / 1300.0) * np.cos(yy / 1700.0) + 0.002 * yy
    if hole:
        values[200:220, 200:220] = np.nan
    return Grid(values, 0.0, 0.0, 50.0, 50.0, kind=kind, units="mGal")


def scenario(**changes):
    data = {
        "name": "synthetic",
        "map": {"path": "synthetic.nc", "kind": "gravity"},
        "track": {
            "start_m": [5000.0, 5000.0],
            "heading_deg": 45.0,
            "speed_m_s": 5.0,
            "interval_s": 20.0,
            "samples": 30,
            "legs": 2,
            "turn_std_deg": 10.0,
            "start_jitter_m": 200.0,
        },
        "sensor": {"type": "gravimeter", "noise_std": 1.0, "lag_s": 40.0},
        "ins": {
            "initial_error_m": [100.0, -50.0],
            "velocity_error_m_s": 0.04,
            "heading_error_deg": 0.05,
            "accel_bias_ug": 100.0,
        },
        "trials": 3,
        "seed": 11,
    }
    for key, value in changes.items():
        block, _, field = key.partition(".")
        if field:
            data[block] = {**(data.get(block) or {}), field: value}
        else:
            data[block] = value
    return scenario_from_dict(data)


def assert_same_trial(a, b):
    for name in (
        "truth",
        "true_heading",
        "indicated",
        "indicated_heading",
        "times",
        "measured",
        "offsets",
        "sigma_position",
    ):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    for key in ("true_velocity", "dvl_velocity", "unlagged_measured"):
        assert (getattr(a, key) is None) == (getattr(b, key) is None), key


def test_trial_contents_and_shapes():
    sc = scenario()
    trial = simulate_trial(sc, smooth_field_grid(), 0)
    assert trial.n == 60 and trial.measured.shape == (60, 1)
    assert trial.leg_starts == (0, 30)
    assert trial.sensor == "gravimeter" and trial.noise_std == 1.0 and trial.index == 0
    assert np.all(np.isfinite(trial.measured))
    assert np.all(np.abs(trial.truth[0] - 5000.0) <= 200.0)
    expected_sigma = position_sigma(sc.ins, trial.times, 5.0 * trial.times)
    np.testing.assert_allclose(trial.sigma_position, expected_sigma)
    assert trial.dvl_velocity is None and trial.lag_s > 0
    unlagged = trial.unlagged_measured
    np.testing.assert_allclose(
        compensate_first_order_lag(trial.measured, trial.times, 40.0), unlagged
    )
    error = trial.indicated[0] - trial.truth[0]
    np.testing.assert_allclose(error, [100.0, -50.0])


def test_same_seed_and_index_give_the_same_trial_alone_or_in_a_batch():
    sc, grid = scenario(), smooth_field_grid()
    batch = list(simulate_trials(sc, grid))
    assert [t.index for t in batch] == [0, 1, 2]
    assert_same_trial(simulate_trial(sc, grid, 2), batch[2])
    assert_same_trial(simulate_trial(sc, grid, 1), simulate_trial(sc, grid, 1))


def test_different_index_or_seed_gives_a_different_trial():
    sc, grid = scenario(), smooth_field_grid()
    a, b = simulate_trial(sc, grid, 0), simulate_trial(sc, grid, 1)
    assert not np.allclose(a.truth, b.truth)
    assert not np.allclose(a.indicated - a.truth, b.indicated - b.truth)
    c = simulate_trial(scenario(seed=12), grid, 0)
    assert not np.allclose(a.measured, c.measured)


def test_adding_a_dvl_keeps_track_ins_and_measurements():
    grid = smooth_field_grid()
    plain = simulate_trial(scenario(), grid, 4)
    aided = simulate_trial(scenario(dvl={"noise_std_m_s": 0.01, "bias_m_s": 0.02}), grid, 4)
    for name in ("truth", "indicated", "measured"):
        np.testing.assert_array_equal(getattr(plain, name), getattr(aided, name))
    dvl = aided.dvl_velocity
    assert dvl.shape == (60, 2)
    assert 0.0 < np.abs(dvl - aided.true_velocity).max() < 0.1
    assert aided.problem(grid, slice(0, 30)).dvl_velocity.shape == (30, 2)


def test_multibeam_trial_reads_every_beam():
    grid = smooth_field_grid(kind="depth")
    sc = scenario(
        sensor={
            "type": "multibeam",
            "beams": 9,
            "swath_width_m": 400.0,
            "noise_std": 0.0,
            "map_error_std": 0.0,
        }
    )
    trial = simulate_trial(sc, grid, 0)
    assert trial.measured.shape == (60, 9) and trial.offsets.shape == (9, 2)
    problem = trial.problem(grid)
    x, y = problem.footprint(trial.truth, trial.true_heading)
    np.testing.assert_array_equal(trial.measured, grid.sample(x, y))
    assert trial.unlagged_measured is None


def test_start_cell_is_converted_with_the_grid():
    grid = smooth_field_grid()
    sc = scenario(
        **{"track.start_m": None, "track.start_cell": [100, 120], "track.start_jitter_m": 0.0}
    )
    assert start_position(sc, grid) == (5000.0, 6000.0)
    np.testing.assert_array_equal(simulate_trial(sc, grid, 0).truth[0], [5000.0, 6000.0])


def test_start_needs_exactly_one_of_cell_and_metres():
    grid = smooth_field_grid()
    with pytest.raises(ConfigError, match=r"track\.start_cell"):
        start_position(scenario(**{"track.start_m": None}), grid)
    with pytest.raises(ConfigError, match=r"track\.start_m"):
        start_position(scenario(**{"track.start_cell": [1, 2]}), grid)


def test_true_track_leaving_the_map_raises_with_the_sample():
    sc = scenario(
        **{
            "track.start_m": [19000.0, 19000.0],
            "track.start_jitter_m": 0.0,
            "track.legs": 1,
            "track.heading_deg": 90.0,
        }
    )
    with pytest.raises(TrackOffMapError, match=r"true track leaves the map .* sample 10 of 30"):
        simulate_trial(sc, smooth_field_grid(), 0)


def test_true_track_over_no_data_raises():
    sc = scenario(
        **{
            "track.start_m": [9000.0, 10500.0],
            "track.start_jitter_m": 0.0,
            "track.legs": 1,
            "track.heading_deg": 90.0,
        }
    )
    # the hole starts at x = 10000 m, reached by sample 10
    with pytest.raises(TrackOffMapError, match=r"sample 10 of 30, \(10000\.0, 10500\.0\)"):
        simulate_trial(sc, smooth_field_grid(hole=True), 0)


def test_check_track_on_map_names_the_beam():
    grid = smooth_field_grid()
    footprints = np.array([[[100.0, 100.0], [150.0, 100.0]], [[100.0, 200.0], [-10.0, 200.0]]])
    with pytest.raises(TrackOffMapError, match=r"sample 1 of 2 beam 1, \(-10\.0, 200\.0\)"):
        check_track_on_map(grid, footprints, "true track")
    check_track_on_map(grid, footprints[:1], "true track")


def test_prepare_map_passes_the_map_block_to_the_loader(monkeypatch):
    calls = []

    def load_grid(path, variable, kind, region, resample_m):
        calls.append((path, variable, kind, region, resample_m))
        return smooth_field_grid()

    monkeypatch.setitem(sys.modules, "geofix.maps.io", types.SimpleNamespace(load_grid=load_grid))
    sc = scenario(
        map={
            "path": "builtin:x",
            "variable": "z",
            "kind": "gravity",
            "region": [-146, -144, 54, 56],
            "resample_m": 100,
        }
    )
    assert isinstance(prepare_map(sc), Grid)
    assert calls == [("builtin:x", "z", "gravity", (-146.0, -144.0, 54.0, 56.0), 100.0)]


def multibeam_scenario(map_error_std=0.0):
    return scenario(
        sensor={
            "type": "multibeam",
            "beams": 9,
            "swath_width_m": 400.0,
            "noise_std": 0.5,
            "edge_noise_factor": 3.0,
            "map_error_std": map_error_std,
        }
    )


def test_multibeam_trial_carries_the_per_beam_noise_of_its_sensor():
    grid = smooth_field_grid(kind="depth")
    sc = multibeam_scenario()
    trial = simulate_trial(sc, grid, 0)
    expected = beam_noise_std(trial.offsets, sc.sensor)
    np.testing.assert_array_equal(trial.beam_noise_std, expected)
    # nadir 0.5, edges three times as noisy, growing linearly with |across| (+-200 m)
    np.testing.assert_allclose(trial.beam_noise_std[[0, 4, 8]], [1.5, 0.5, 1.5])
    np.testing.assert_allclose(trial.beam_noise_std[[2, 6]], [1.0, 1.0])
    assert trial.noise_std == 0.5
    problem = trial.problem(grid, slice(5, 20))
    np.testing.assert_array_equal(problem.beam_noise_std, expected)
    np.testing.assert_allclose(problem.beam_noise_var(), expected**2)
    np.testing.assert_allclose(
        trial_beam_variance(trial), scenario_beam_variance(sc, trial.offsets)
    )


def test_per_beam_noise_holds_the_map_error_like_the_scalar():
    grid = smooth_field_grid(kind="depth")
    sc = multibeam_scenario(map_error_std=1.2)
    trial = simulate_trial(sc, grid, 0)
    expected = np.hypot(beam_noise_std(trial.offsets, sc.sensor), 1.2)
    np.testing.assert_allclose(trial.beam_noise_std, expected)
    assert trial.beam_noise_std[4] == pytest.approx(trial.noise_std)
    np.testing.assert_allclose(
        trial.problem(grid).beam_noise_var(),
        0.5**2 * (1 + 2 * np.abs(np.linspace(-1, 1, 9))) ** 2 + 1.2**2,
    )
    np.testing.assert_allclose(
        trial_beam_variance(trial), scenario_beam_variance(sc, trial.offsets)
    )


def test_single_sensor_trial_has_one_beam_noise():
    trial = simulate_trial(scenario(), smooth_field_grid(), 1)
    np.testing.assert_array_equal(trial.beam_noise_std, [1.0])


def test_per_beam_noise_survives_export_and_is_absent_when_never_set(tmp_path):
    grid = smooth_field_grid(kind="depth")
    sc = multibeam_scenario(map_error_std=0.3)
    with_noise = simulate_trial(sc, grid, 0)
    without = dataclasses.replace(simulate_trial(sc, grid, 1), beam_noise_std=None)
    trials_dataset(grid, [with_noise, without]).to_netcdf(tmp_path / "both.nc")
    _, back = load_exported(tmp_path / "both.nc")
    np.testing.assert_array_equal(back[0].beam_noise_std, with_noise.beam_noise_std)
    assert back[1].beam_noise_std is None
    trials_dataset(grid, [without]).to_netcdf(tmp_path / "none.nc")
    _, back = load_exported(tmp_path / "none.nc")
    assert back[0].beam_noise_std is None


def test_trial_rejects_a_beam_noise_of_the_wrong_length():
    trial = simulate_trial(multibeam_scenario(), smooth_field_grid(kind="depth"), 0)
    with pytest.raises(ConfigError, match="beam_noise_std"):
        dataclasses.replace(trial, beam_noise_std=np.ones(3))
