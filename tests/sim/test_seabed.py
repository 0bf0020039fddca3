"""The seabed block: the field the sensor reads differs from the prior map the methods get."""

import numpy as np
import pytest
import xarray as xr

from geofix.errors import ConfigError, MemoryBudgetError, TrackOffMapError
from geofix.evaluate.campaign import run_campaign
from geofix.evaluate.store import ResultStore, scenario_hash
from geofix.maps.grid import Grid
from geofix.maps.io import save_grid
from geofix.maps.synthetic import fractal_terrain
from geofix.nav.dvl import simulate_dvl
from geofix.nav.ins import simulate_ins
from geofix.sensors.echosounder import sensor_offsets
from geofix.sim import SeabedSpec, scenario_from_dict, simulate_trial
from geofix.sim.export import export_trials, load_exported
from geofix.sim.seabed import (
    HolesSpec,
    block_mean_grid,
    cut_and_fill_holes,
    gaussian_field,
    seabed_streams,
    shifted_values,
)
from geofix.sim.sensing import measure_with_unlagged
from geofix.sim.simulate import _true_track

CELL = 50.0


def ramp_grid(shape=(120, 120), a=0.02, b=-0.03, kind="gravity"):
    """A plane ``1 + a x + b y`` (map units), ``CELL`` metre cells, cell [0, 0] at (0, 0)."""
    y, x = np.indices(shape) * CELL
    return Grid(1.0 + a * x + b * y, 0.0, 0.0, CELL, CELL, kind=kind, units="mGal")


def wavy_grid(shape=(120, 120), kind="gravity"):
    """A smooth non-planar field on ``CELL`` metre cells (a tilted egg-box)."""
    y, x = np.indices(shape) * CELL
    values = 20.0 * np.sin(x / 700.0) * np.cos(y / 900.0) + 0.003 * x
    return Grid(values, 0.0, 0.0, CELL, CELL, kind=kind, units="mGal")


def scenario(seabed=None, sensor=None, **changes):
    """A gravimeter mission of 25 samples across the middle of a 120 x 120 cell map."""
    data = {
        "name": "seabed-test",
        "map": {"path": "synthetic.nc", "kind": "gravity"},
        "track": {
            "start_m": [2000.0, 2500.0],
            "heading_deg": 80.0,
            "speed_m_s": 5.0,
            "interval_s": 20.0,
            "samples": 25,
            "start_jitter_m": 100.0,
        },
        "sensor": sensor or {"type": "gravimeter", "noise_std": 0.5},
        "ins": {"initial_error_m": [60.0, -40.0], "velocity_error_m_s": 0.03},
        "trials": 2,
        "seed": 5,
        **changes,
    }
    if seabed is not None:
        data["seabed"] = seabed
    return scenario_from_dict(data)


# ----------------------------------------------------------------------------- unchanged default
def test_without_seabed_a_trial_is_bitwise_the_four_stream_trial():
    """spawn(5)'s first four children are spawn(4)'s: every draw of a plain trial stays."""
    scen = scenario(
        sensor={"type": "gravimeter", "noise_std": 0.7, "lag_s": 30.0, "map_error_std": 0.2},
        dvl={"noise_std_m_s": 0.02},
    )
    grid = wavy_grid()
    trial = simulate_trial(scen, grid, 3)
    track_rng, ins_rng, dvl_rng, sensor_rng = np.random.default_rng([scen.seed, 3]).spawn(4)
    true = _true_track(scen, grid, track_rng)
    ins = simulate_ins(true, scen.ins, ins_rng, scen.dvl)
    assert scen.dvl is not None
    dvl = simulate_dvl(true, scen.dvl, dvl_rng)
    offsets = sensor_offsets(scen.sensor)
    measured, unlagged = measure_with_unlagged(
        grid, true.positions, true.heading, offsets, scen.sensor, sensor_rng, true.times
    )
    np.testing.assert_array_equal(trial.truth, true.positions)
    np.testing.assert_array_equal(trial.indicated, ins.indicated)
    np.testing.assert_array_equal(trial.indicated_heading, ins.heading)
    np.testing.assert_array_equal(trial.measured, measured)
    np.testing.assert_array_equal(trial.unlagged_measured, unlagged)
    np.testing.assert_array_equal(trial.dvl_velocity, dvl)
    assert trial.prior_map is None and trial.prior_shift_m is None
    problem = trial.problem(grid)
    assert problem.grid is grid


def test_without_seabed_the_scenario_dumps_and_hashes_as_before(tmp_path):
    path = save_grid(wavy_grid(), tmp_path / "synthetic.nc")
    plain = scenario(map={"path": str(path), "kind": "gravity"})
    assert "seabed" not in plain.model_dump(mode="json")
    with_block = plain.model_copy(update={"seabed": SeabedSpec(cell_factor=2)})
    assert with_block.model_dump(mode="json")["seabed"]["cell_factor"] == 2
    assert scenario_hash(plain) != scenario_hash(with_block)


def test_an_empty_seabed_block_reads_the_seabed_and_hands_it_on():
    grid = wavy_grid()
    plain = simulate_trial(scenario(), grid, 1)
    trial = simulate_trial(scenario(seabed={}), grid, 1)
    np.testing.assert_array_equal(trial.truth, plain.truth)
    np.testing.assert_array_equal(trial.measured, plain.measured)
    np.testing.assert_array_equal(trial.prior_map.values, grid.values)
    np.testing.assert_array_equal(trial.prior_shift_m, [0.0, 0.0])
    assert trial.problem(grid).grid is trial.prior_map


# ----------------------------------------------------------------------------- block means
def test_block_means_keep_a_plane_and_average_constant_blocks():
    plane = ramp_grid((60, 45))
    coarse = block_mean_grid(plane, 4)
    xx, yy = np.meshgrid(coarse.x, coarse.y)
    np.testing.assert_allclose(coarse.values, 1.0 + 0.02 * xx - 0.03 * yy, atol=1e-12)
    blocks = np.kron(np.arange(12.0).reshape(3, 4), np.ones((3, 3)))
    blocks[0, 0] = np.nan  # one no-data cell: the mean of the other eight
    blocks[3:6, 3:6] = np.nan  # a whole block of no-data: no data
    means = block_mean_grid(Grid(blocks, 0.0, 0.0, 10.0, 10.0), 3).values
    expected = np.arange(12.0).reshape(3, 4)
    expected[1, 1] = np.nan
    np.testing.assert_array_equal(means, expected)


def test_cell_factor_gives_a_grid_k_times_coarser_over_the_same_area():
    fine = ramp_grid((61, 47))  # ragged: 61 = 5 * 12 + 1, 47 = 5 * 9 + 2
    coarse = block_mean_grid(fine, 5)
    assert coarse.shape == (12, 9)
    assert (coarse.dx, coarse.dy) == (5 * fine.dx, 5 * fine.dy)
    # west and south cell edges coincide; the east / north edge loses the ragged cells only
    assert coarse.x0 - coarse.dx / 2 == pytest.approx(fine.x0 - fine.dx / 2)
    assert coarse.y0 - coarse.dy / 2 == pytest.approx(fine.y0 - fine.dy / 2)
    fine_east = fine.extent[1] + fine.dx / 2
    assert coarse.extent[1] + coarse.dx / 2 == pytest.approx(fine_east - 2 * fine.dx)
    fine_north = fine.extent[3] + fine.dy / 2
    assert coarse.extent[3] + coarse.dy / 2 == pytest.approx(fine_north - 1 * fine.dy)


# ----------------------------------------------------------------------------- random fields
def test_gaussian_field_has_its_rms_and_correlation_length():
    """Covariance rms^2 exp(-d^2 / (2 L^2)): correlation exp(-1/2) at lag L.

    Over 8 fields of 128 x 128 cells with L = 4 cells, the rms and the lag-L correlation
    scatter by about 0.08 rms and 0.03 per field (measured over 50 fields), so by about
    a third of that for the mean of 8: the bounds are four of those spreads.
    """
    rms, corr_x, corr_y, corr_half = [], [], [], []
    for seed in range(8):
        f = gaussian_field((128, 128), 10.0, 10.0, 2.0, 40.0, np.random.default_rng(seed))
        var = np.mean(f**2)
        rms.append(np.sqrt(var))
        corr_x.append(np.mean(f[:, :-4] * f[:, 4:]) / var)
        corr_y.append(np.mean(f[:-4] * f[4:]) / var)
        corr_half.append(np.mean(f[:, :-2] * f[:, 2:]) / var)
    assert abs(np.mean(rms) - 2.0) < 4 * 0.08 / np.sqrt(8)
    assert abs(np.mean(corr_x) - np.exp(-0.5)) < 4 * 0.03 / np.sqrt(8)
    assert abs(np.mean(corr_y) - np.exp(-0.5)) < 4 * 0.03 / np.sqrt(8)
    assert abs(np.mean(corr_half) - np.exp(-0.125)) < 4 * 0.03 / np.sqrt(8)


def test_relief_reaches_the_readings_only_and_error_the_prior_only():
    grid = wavy_grid()
    noise_free = {"type": "gravimeter", "noise_std": 0.0}
    plain = simulate_trial(scenario(sensor=noise_free), grid, 0)
    relief = simulate_trial(
        scenario({"relief_rms": 1.5, "relief_corr_m": 100.0}, sensor=noise_free), grid, 0
    )
    np.testing.assert_array_equal(relief.prior_map.values, grid.values)
    diff = relief.measured - plain.measured
    assert 0.3 < np.sqrt(np.mean(diff**2)) < 4.0  # 25 correlated reads of a 1.5 rms field
    error = simulate_trial(
        scenario({"error_rms": 2.0, "error_corr_m": 200.0}, sensor=noise_free), grid, 0
    )
    np.testing.assert_array_equal(error.measured, plain.measured)
    prior_error = error.prior_map.values - grid.values
    # 120 x 120 cells, L = 4 cells: the rms of one field scatters by about 0.08 (see above)
    assert abs(np.sqrt(np.mean(prior_error**2)) - 2.0) < 0.4
    lag = np.mean(prior_error[:, :-4] * prior_error[:, 4:]) / np.mean(prior_error**2)
    assert abs(lag - np.exp(-0.5)) < 0.15


def test_relief_is_drawn_at_the_seabed_cells_around_the_track():
    from geofix.sim.seabed import sensed_seabed

    grid = wavy_grid()
    spec = SeabedSpec(relief_rms=1.0, relief_corr_m=100.0)
    footprints = np.array([[1000.0, 1200.0], [2000.0, 1500.0]])
    sensed = sensed_seabed(grid, spec, np.random.default_rng(0), footprints)
    assert (sensed.dx, sensed.dy) == (grid.dx, grid.dy)
    west, east, south, north = sensed.extent
    assert west <= 1000.0 - 2 * CELL and east >= 2000.0 + 2 * CELL
    assert south <= 1200.0 - 2 * CELL and north >= 1500.0 + 2 * CELL
    assert sensed.shape[1] < grid.shape[1]
    whole = sensed_seabed(grid, spec, np.random.default_rng(0))
    assert whole.shape == grid.shape


# ----------------------------------------------------------------------------- readings
def test_offset_tide_and_drift_appear_exactly_in_noise_free_readings():
    grid = wavy_grid()
    sensor = {"type": "gravimeter", "noise_std": 0.0}
    block = {"offset": 2.5, "tide_amplitude": 1.5, "tide_period_s": 600.0, "drift_per_h": 3.6}
    plain = simulate_trial(scenario(sensor=sensor), grid, 4)
    trial = simulate_trial(scenario(block, sensor=sensor), grid, 4)
    readings = seabed_streams(np.random.default_rng([5, 4]).spawn(5)[4]).readings
    phase = readings.uniform(0.0, 2.0 * np.pi)
    t = trial.times
    expected = 2.5 + 1.5 * np.sin(2 * np.pi * t / 600.0 + phase) + 3.6 * t / 3600.0
    np.testing.assert_allclose(trial.measured - plain.measured, expected[:, None], atol=1e-12)
    other = simulate_trial(scenario(block, sensor=sensor), grid, 5)
    plain_other = simulate_trial(scenario(sensor=sensor), grid, 5)
    assert not np.allclose(other.measured - plain_other.measured, expected[:, None])


def test_an_offset_drawn_per_trial_has_its_spread_and_leaves_the_rest_as_it_was():
    grid = wavy_grid()
    sensor = {"type": "gravimeter", "noise_std": 0.0}
    plain = scenario({"tide_amplitude": 1.0}, sensor=sensor)
    drawn = scenario({"tide_amplitude": 1.0, "offset_std": 4.0}, sensor=sensor)
    offsets = []
    for index in range(40):
        a = simulate_trial(plain, grid, index)
        b = simulate_trial(drawn, grid, index)
        step = (b.measured - a.measured)[:, 0]
        np.testing.assert_allclose(step, step[0], atol=1e-12)  # one offset, the tide as it was
        readings = seabed_streams(np.random.default_rng([5, index]).spawn(5)[4]).readings
        readings.uniform(0.0, 2.0 * np.pi)  # the tide's phase first
        assert step[0] == pytest.approx(readings.normal(0.0, 4.0), abs=1e-12)
        offsets.append(step[0])
    # 40 draws of N(0, 16): the sample sd within about 3 of its standard errors (4 / sqrt(80))
    assert abs(np.std(offsets) - 4.0) < 3 * 4.0 / np.sqrt(80)
    with pytest.raises(ConfigError, match="offset_std"):
        scenario({"offset_std": -1.0})


# ----------------------------------------------------------------------------- misregistration
def test_a_fixed_misregistration_moves_a_ramp_by_the_stated_vector():
    grid = ramp_grid()
    trial = simulate_trial(scenario({"misregistration_xy_m": [120.0, -75.0]}), grid, 0)
    np.testing.assert_array_equal(trial.prior_shift_m, [120.0, -75.0])
    diff = trial.prior_map.values - grid.values
    inner = diff[5:-5, 5:-5]  # away from the edges, where the read is clamped
    np.testing.assert_allclose(inner, -(0.02 * 120.0 - 0.03 * -75.0), atol=1e-9)
    assert np.isfinite(trial.prior_map.values).all()


def test_a_drawn_misregistration_has_its_length_and_a_drawn_direction():
    grid = ramp_grid()
    scen = scenario({"misregistration_m": 90.0, "registration_std_m": 40.0})
    shifts = [simulate_trial(scen, grid, i).prior_shift_m for i in range(3)]
    for shift in shifts:
        assert np.hypot(*shift) == pytest.approx(90.0)
    assert not np.allclose(shifts[0], shifts[1])
    trial = simulate_trial(scen, grid, 2)
    dx, dy = trial.prior_shift_m
    diff = (trial.prior_map.values - grid.values)[5:-5, 5:-5]
    np.testing.assert_allclose(diff, -(0.02 * dx - 0.03 * dy), atol=1e-9)
    assert trial.prior_map.meta["registration_std_m"] == 40.0


def test_shifted_values_read_the_content_at_the_shifted_cells():
    grid = ramp_grid((10, 12))
    moved = shifted_values(grid, (CELL, 0.0))  # one cell east: column j takes column j - 1
    np.testing.assert_array_equal(moved[:, 1:], grid.values[:, :-1])
    np.testing.assert_array_equal(moved[:, 0], grid.values[:, 0])  # clamped at the edge


# ----------------------------------------------------------------------------- holes
def test_holes_are_filled_with_finite_values_and_a_plane_is_filled_exactly():
    plane = ramp_grid((60, 80))
    for seed in range(3):
        filled = cut_and_fill_holes(
            plane, HolesSpec(count=4, radius_m=300.0), np.random.default_rng(seed)
        )
        assert np.isfinite(filled).all()
        np.testing.assert_allclose(filled, plane.values, atol=1e-9)  # linear fill of a plane
    wavy = wavy_grid((60, 80))
    filled = cut_and_fill_holes(wavy, HolesSpec(count=4, radius_m=300.0), np.random.default_rng(0))
    changed = filled != wavy.values
    assert np.isfinite(filled).all()
    assert 4 * 20 < changed.sum() <= 4 * np.pi * (300.0 / CELL + 1) ** 2  # about 4 discs of 6 cells


def test_holes_leave_no_data_alone_and_refuse_a_map_with_nothing_to_fill_from():
    wavy = wavy_grid((40, 40))
    values = np.array(wavy.values)
    values[:, :5] = np.nan
    with_gap = wavy.with_values(values)
    filled = cut_and_fill_holes(
        with_gap, HolesSpec(count=6, radius_m=400.0), np.random.default_rng(2)
    )
    np.testing.assert_array_equal(np.isnan(filled), np.isnan(values))
    with pytest.raises(ConfigError, match=r"seabed\.holes"):
        cut_and_fill_holes(wavy, HolesSpec(count=3, radius_m=1e5), np.random.default_rng(0))


def test_holes_in_a_scenario_change_the_prior_and_never_the_readings():
    grid = wavy_grid()
    plain = simulate_trial(scenario(), grid, 0)
    trial = simulate_trial(scenario({"holes": {"count": 5, "radius_m": 400.0}}), grid, 0)
    np.testing.assert_array_equal(trial.measured, plain.measured)
    assert np.isfinite(trial.prior_map.values).all()
    assert (trial.prior_map.values != grid.values).sum() > 100


# ----------------------------------------------------------------------------- reproducibility
def test_a_trial_is_reproducible_per_seed_and_differs_per_trial():
    block = {
        "cell_factor": 2,
        "relief_rms": 0.5,
        "relief_corr_m": 150.0,
        "error_rms": 1.0,
        "error_corr_m": 300.0,
        "tide_amplitude": 0.8,
        "misregistration_m": 60.0,
        "holes": {"count": 2, "radius_m": 300.0},
    }
    grid = wavy_grid()
    a, b = (simulate_trial(scenario(block), grid, 1) for _ in range(2))
    np.testing.assert_array_equal(a.prior_map.values, b.prior_map.values)
    np.testing.assert_array_equal(a.measured, b.measured)
    c = simulate_trial(scenario(block), grid, 0)
    assert not np.allclose(a.prior_map.values, c.prior_map.values)
    d = simulate_trial(scenario(block, seed=6), grid, 1)
    assert not np.allclose(a.prior_map.values, d.prior_map.values)
    assert a.prior_map.shape == (60, 60) and a.prior_map.dx == 2 * CELL


# ----------------------------------------------------------------------------- bad settings
@pytest.mark.parametrize(
    ("block", "match"),
    [
        ({"relief_rms": 1.0}, r"seabed.*relief_corr_m must be greater than 0"),
        ({"error_rms": 1.0, "error_corr_m": 0}, r"seabed.*error_corr_m must be greater than 0"),
        ({"error_rms": -1.0, "error_corr_m": 10}, r"seabed\.error_rms"),
        ({"cell_factor": 0}, r"seabed\.cell_factor"),
        ({"cell_factor": 1.5}, r"seabed\.cell_factor"),
        ({"tide_period_s": 0}, r"seabed\.tide_period_s"),
        ({"misregistration_m": 5, "misregistration_xy_m": [1, 2]}, r"not both"),
        ({"holes": {"count": 0, "radius_m": 10}}, r"seabed\.holes\.count"),
        ({"holes": {"count": 2}}, r"seabed\.holes\.radius_m"),
        ({"registration_std_m": -3}, r"seabed\.registration_std_m"),
        ({"relief": 1.0}, r"seabed\.relief: unknown key"),
        ({"offset": float("nan")}, r"seabed\.offset"),
    ],
)
def test_bad_settings_are_refused_naming_the_key(block, match):
    with pytest.raises(ConfigError, match=match):
        scenario(block)


def test_a_cell_factor_too_large_for_the_map_is_refused():
    with pytest.raises(ConfigError, match=r"seabed\.cell_factor 70 leaves 1 x 1 prior cells"):
        simulate_trial(scenario({"cell_factor": 70}), wavy_grid(), 0)


def test_a_track_off_the_prior_is_refused_clearly():
    # the seabed holds the track up to its last column; the prior of 7 x 7 blocks drops it
    scen = scenario(
        {"cell_factor": 7},
        track={
            "start_m": [5000.0, 3000.0],
            "heading_deg": 90.0,
            "speed_m_s": 5.0,
            "interval_s": 20.0,
            "samples": 9,
        },
    )
    with pytest.raises(TrackOffMapError, match=r"prior map.*seabed\.cell_factor 7"):
        simulate_trial(scen, wavy_grid(), 0)
    simulate_trial(scenario(track=scen.track.model_dump()), wavy_grid(), 0)  # fits the seabed


def test_fields_are_sized_against_the_memory_budget(monkeypatch):
    monkeypatch.setenv("GEOFIX_MEMORY_BUDGET", "200kB")
    with pytest.raises(MemoryBudgetError, match=r"seabed\.error_rms field"):
        simulate_trial(scenario({"error_rms": 1.0, "error_corr_m": 300.0}), wavy_grid(), 0)


# ----------------------------------------------------------------------------- export, campaign
def test_export_carries_the_prior_maps_beside_the_seabed(tmp_path):
    grid = fractal_terrain((100, 100), CELL, rng=np.random.default_rng(1), std=10.0, kind="gravity")
    path = save_grid(grid, tmp_path / "synthetic.nc")
    where = {"map": {"path": str(path), "kind": "gravity"}}
    same = export_trials(scenario({"cell_factor": 2}, **where), tmp_path / "same.nc")
    with xr.open_dataset(same) as ds:
        assert ds["prior_z"].dims == ("prior_y", "prior_x") and ds["z"].shape == (100, 100)
        assert ds["prior_z"].shape == (50, 50) and ds.attrs["prior_grid_dx"] == 2 * CELL
    _, same_trials = load_exported(same)
    coarse = block_mean_grid(grid, 2)
    for trial in same_trials:
        np.testing.assert_array_equal(trial.prior_map.values, coarse.values)
        assert (trial.prior_map.x0, trial.prior_map.dx) == (coarse.x0, coarse.dx)
    block = {
        "error_rms": 1.0,
        "error_corr_m": 200.0,
        "misregistration_m": 80.0,
        "registration_std_m": 50.0,
    }
    scen = scenario(block, **where)
    per_trial = export_trials(scen, tmp_path / "per_trial.nc")
    with xr.open_dataset(per_trial) as ds:
        assert ds["prior_z"].dims == ("trial", "prior_y", "prior_x")
    seabed, trials = load_exported(per_trial)
    np.testing.assert_array_equal(seabed.values, grid.values)
    for trial in trials:
        ref = simulate_trial(scen, grid, trial.index)
        np.testing.assert_array_equal(trial.prior_map.values, ref.prior_map.values)
        np.testing.assert_array_equal(trial.prior_shift_m, ref.prior_shift_m)
        np.testing.assert_array_equal(trial.measured, ref.measured)
        assert trial.prior_map.meta["registration_std_m"] == 50.0
        assert trial.problem(seabed).grid is trial.prior_map
    plain = export_trials(scenario(**where), tmp_path / "plain.nc")
    with xr.open_dataset(plain) as ds:
        assert not any(name.startswith("prior_") for name in [*ds.variables, *ds.attrs])


def test_a_campaign_runs_on_the_imperfect_prior_and_tercom_lands_on_the_shift(tmp_path):
    """A prior misregistered by 400 m east: the readings match it 400 m east of the truth."""
    grid = fractal_terrain((140, 140), CELL, rng=np.random.default_rng(3), std=15.0, kind="gravity")
    path = save_grid(grid, tmp_path / "synthetic.nc")
    scen = scenario(
        {"misregistration_xy_m": [400.0, 0.0], "offset": 0.2, "cell_factor": 1},
        sensor={"type": "gravimeter", "noise_std": 0.2},
        map={"path": str(path), "kind": "gravity"},
        ins={"initial_error_m": [60.0, -40.0], "initial_error_std_m": 300.0},
        track={
            "start_m": [2500.0, 3000.0],
            "heading_deg": 70.0,
            "speed_m_s": 5.0,
            "interval_s": 20.0,
            "samples": 30,
        },
    )
    result = run_campaign(
        scen, ["pmf", "tercom"], trials=2, jobs=1, out_dir=tmp_path / "out", progress=None
    )
    assert result.summary.trials == 2 and set(result.summary.methods) == {"pmf", "tercom"}
    assert result.summary.trials == 2 and list(result.summary.methods) == ["pmf", "tercom"]
    assert not result.frame["failed"].any() and np.isfinite(result.frame["end_error_m"]).all()
    with ResultStore(tmp_path / "out") as store:
        frame = store.to_frame(arrays=True).set_index(["method", "trial"])
    for index in range(2):
        truth = simulate_trial(scen, grid, index).truth
        estimate = np.asarray(frame.loc[("tercom", index), "estimate"], dtype=float)
        np.testing.assert_allclose(estimate[-1] - truth[-1], [400.0, 0.0], atol=1.5 * CELL)
