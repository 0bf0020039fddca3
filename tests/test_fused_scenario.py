"""Scenarios with several field sensors (``sensors:``): validation, simulation, export."""

from __future__ import annotations

import numpy as np
import pytest

from geofix.errors import ConfigError
from geofix.sim import prepare_map, scenario_from_dict, simulate_trial
from geofix.sim.export import export_trials, load_exported

DEPTH = {"map": {"path": "builtin:mb_1km"}, "sensor": {"type": "singlebeam", "noise_std": 10.0}}
GRAVITY = {
    "map": {"path": "builtin:grav_1km"},
    "sensor": {"type": "gravimeter", "noise_std": 1.0},
}


def fused(**changes) -> dict:
    data = {
        "name": "fused-test",
        "sensors": [DEPTH, GRAVITY],
        "track": {
            "start_cell": [130, 60],
            "heading_deg": 280,
            "speed_m_s": 8,
            "interval_s": 30,
            "samples": 30,
        },
        "ins": {"initial_error_m": [0, 0], "initial_error_std_m": 800, "velocity_error_m_s": 0.05},
        "trials": 2,
        "seed": 4,
    }
    return {**data, **changes}


def single(**changes) -> dict:
    data = fused(**changes)
    data.pop("sensors")
    return {**data, "map": DEPTH["map"], "sensor": DEPTH["sensor"]}


def test_the_first_entry_is_the_primary_field_and_the_others_follow():
    scen = scenario_from_dict(fused())
    assert scen.map.path == "builtin:mb_1km" and scen.sensor.type == "singlebeam"
    assert [f.sensor.kind for f in scen.fields] == ["depth", "gravity"]
    again = scenario_from_dict(scen.model_dump(exclude={"base_dir"}))
    assert again == scen


def test_a_scenario_without_sensors_dumps_as_before():
    dumped = scenario_from_dict(single()).model_dump()
    assert "sensors" not in dumped and dumped["sensor"]["type"] == "singlebeam"


def test_top_level_blocks_equal_to_the_first_entry_are_accepted():
    scen = scenario_from_dict(fused(map=DEPTH["map"], sensor=DEPTH["sensor"]))
    assert len(scen.fields) == 2


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"map": {"path": "builtin:grav_1km"}}, r"map: conflicts with sensors\[0\]\.map"),
        ({"sensor": {"type": "multibeam", "beams": 3}}, r"sensor: conflicts with sensors\[0\]"),
        ({"sensors": []}, "sensors: the list is empty"),
        ({"sensors": [DEPTH, GRAVITY, {**GRAVITY, "sensor": {"type": "gravimeter"}}]},
         r"sensors\[2\]: a second gravity sensor \(sensors\[1\] is one\)"),
        ({"sensors": [DEPTH, {**GRAVITY, "map": {"path": "x.nc", "kind": "depth"}}]},
         r"sensors\[1\]: sensor.type gravimeter needs a gravity map"),
    ],
)  # fmt: skip
def test_bad_sensors_lists_are_refused_in_one_line(changes, message):
    with pytest.raises(ConfigError, match=message):
        scenario_from_dict(fused(**changes))


def test_neither_map_nor_sensors_is_refused():
    data = single()
    data.pop("map")
    with pytest.raises(ConfigError, match="map required"):
        scenario_from_dict(data)


def test_a_further_map_off_the_track_is_refused():
    far = {
        **GRAVITY,
        "map": {"path": "builtin:grav_1km", "region": [-84000, -70000, -78000, -60000]},
    }
    scen = scenario_from_dict(fused(sensors=[DEPTH, far]))
    with pytest.raises(ConfigError, match=r"sensors\[1\]: map .* does not overlap the true track"):
        simulate_trial(scen, prepare_map(scen), 0)


def test_a_further_field_leaves_the_primary_numbers_bit_identical():
    one, two = scenario_from_dict(single()), scenario_from_dict(fused())
    grid = prepare_map(one)
    a, b = simulate_trial(one, grid, 1), simulate_trial(two, grid, 1)
    for key in ("truth", "indicated", "measured", "sigma_position", "beam_noise_std"):
        assert np.array_equal(getattr(a, key), getattr(b, key)), key
    assert a.fields == () and len(b.fields) == 1


def test_a_further_field_reads_its_own_map_with_its_own_noise():
    scen = scenario_from_dict(fused(track={**fused()["track"], "samples": 400}))
    grid = prepare_map(scen)
    trial = simulate_trial(scen, grid, 0)
    (gravity,) = trial.fields
    assert gravity.kind == "gravity" and gravity.sensor == "gravimeter"
    clean = gravity.grid.sample(trial.truth[:, 0], trial.truth[:, 1])
    residual = gravity.measured[:, 0] - clean
    assert abs(np.std(residual) - 1.0) < 0.12 and abs(np.mean(residual)) < 0.2
    problem = trial.problem(grid, slice(5, 25))
    assert len(problem.fields) == 1 and problem.fields[0].measured.shape == (20, 1)
    assert problem.fields[0].grid is gravity.grid and problem.fields[0].kind == "gravity"


def test_export_writes_and_reads_back_the_further_fields(tmp_path):
    scen = scenario_from_dict(fused())
    path = export_trials(scen, tmp_path / "fused.nc")
    _, trials = load_exported(path)
    again = simulate_trial(scen, prepare_map(scen), 1)
    assert np.array_equal(trials[1].measured, again.measured)
    (field,) = trials[1].fields
    assert np.array_equal(field.measured, again.fields[0].measured)
    assert np.array_equal(field.grid.values, again.fields[0].grid.values)
    assert field.kind == "gravity" and field.sensor == "gravimeter"
    assert field.grid.units == "mGal" and field.noise_std == 1.0


def test_a_further_field_may_have_a_seabed_block_of_its_own(tmp_path):
    offset = {**GRAVITY, "seabed": {"offset": 3.0, "cell_factor": 2}}
    scen = scenario_from_dict(fused(sensors=[DEPTH, offset]))
    assert scen.seabed is None and scen.fields[1].seabed.offset == 3.0
    grid = prepare_map(scen)
    trial = simulate_trial(scen, grid, 0)
    (field,) = trial.fields
    assert field.sensed is not None and field.grid.cell_size == 2 * field.sensed.cell_size
    clean = field.sensed.sample(trial.truth[:, 0], trial.truth[:, 1])
    assert abs(np.mean(field.measured[:, 0] - clean) - 3.0) < 0.5
    assert trial.prior_map is None  # the primary field keeps its map
    _, back = load_exported(export_trials(scen, tmp_path / "seabed.nc", trials=1))
    assert np.array_equal(back[0].fields[0].grid.values, field.grid.values)
    assert np.array_equal(back[0].fields[0].measured, field.measured)
