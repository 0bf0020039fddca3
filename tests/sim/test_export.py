"""Exported trials: a round trip through netCDF gives back the very same map and trials."""

import json

import numpy as np
import pytest
import xarray as xr
import yaml

from geofix.errors import GeofixError
from geofix.evaluate.runner import method_rng, run_trial
from geofix.logs.exported import read_exported
from geofix.methods import parse_method_spec
from geofix.nav.errstate import InsErrorModel
from geofix.sim.export import export_trials, load_exported
from geofix.sim.simulate import prepare_map, simulate_trial


def _scenario(factory, sensor: dict, **extra):
    track = {"samples": 8, "legs": 2, "turn_std_deg": 10}
    return factory("export-small", sensor=sensor, track=track, trials=2, **extra)


def _assert_same_trial(a, b):
    for name in ("truth", "true_heading", "indicated", "indicated_heading", "times"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    for name in ("measured", "offsets", "sigma_position"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert (a.leg_starts, a.noise_std, a.sensor, a.index) == (
        b.leg_starts,
        b.noise_std,
        b.sensor,
        b.index,
    )
    for key in ("true_velocity", "dvl_velocity", "unlagged_measured", "lag_s"):
        va, vb = getattr(a, key), getattr(b, key)
        assert (va is None) == (vb is None), key
        if va is not None:
            np.testing.assert_array_equal(va, vb, err_msg=key)


@pytest.mark.parametrize(
    ("sensor", "extra"),
    [
        (
            {"type": "multibeam", "beams": 5, "swath_width_m": 2000.0, "noise_std": 2.0},
            {"dvl": {"noise_std_m_s": 0.02}},
        ),
        (
            {"type": "gravimeter", "noise_std": 1.0, "lag_s": 30.0},
            {"map": {"path": "builtin:mb_1km", "kind": "gravity"}},
        ),
    ],
    ids=["multibeam-dvl", "gravimeter-lag"],
)
def test_round_trip_gives_the_same_map_and_trials(tmp_path, sensor, extra, small_mission):
    scen = _scenario(small_mission, sensor, **extra)
    path = export_trials(scen, tmp_path / "trials.nc", trials=3, seed=7)
    grid, trials = load_exported(path)
    ref_scen = scen.model_copy(update={"trials": 3, "seed": 7})
    ref_grid = prepare_map(ref_scen)
    np.testing.assert_array_equal(grid.values, ref_grid.values)
    assert (grid.x0, grid.y0, grid.dx, grid.dy, grid.kind, grid.units) == (
        ref_grid.x0,
        ref_grid.y0,
        ref_grid.dx,
        ref_grid.dy,
        ref_grid.kind,
        ref_grid.units,
    )
    assert len(trials) == 3
    for i, trial in enumerate(trials):
        _assert_same_trial(trial, simulate_trial(ref_scen, ref_grid, i))


def test_file_is_self_describing_and_a_method_gives_the_same_answer(tmp_path, small_mission):
    scen = _scenario(small_mission, {"type": "singlebeam", "noise_std": 2.0})
    path = export_trials(scen, tmp_path / "t.nc")
    with xr.open_dataset(path) as ds:
        assert {k: ds.sizes[k] for k in ("trial", "sample", "beam", "leg")} == {
            "trial": 2,
            "sample": 16,
            "beam": 1,
            "leg": 2,
        }
        assert ds["truth_x"].attrs["units"] == "m"
        assert "clockwise" in ds["true_heading"].attrs["units"]
        assert yaml.safe_load(ds.attrs["scenario_yaml"])["name"] == "export-small"
    grid, trials = load_exported(path)
    ref_grid = prepare_map(scen)
    tercom = parse_method_spec("tercom")
    ours = run_trial(tercom, trials[1], grid, method_rng(3, 1, "tercom"))
    ref = run_trial(tercom, simulate_trial(scen, ref_grid, 1), ref_grid, method_rng(3, 1, "tercom"))
    np.testing.assert_array_equal(ours.estimate, ref.estimate)


def test_reading_something_else_raises(tmp_path):
    with pytest.raises(GeofixError, match="cannot read"):
        load_exported(tmp_path / "missing.nc")
    xr.Dataset({"a": ("x", [1.0])}).to_netcdf(tmp_path / "other.nc")
    with pytest.raises(GeofixError, match="not a geofix trials export"):
        load_exported(tmp_path / "other.nc")


def test_cli_export(tmp_path, small_mission):
    from typer.testing import CliRunner

    from geofix.cli import app

    scen_path = tmp_path / "s.yaml"
    data = _scenario(small_mission, {"type": "singlebeam", "noise_std": 2.0}).model_dump(
        mode="json", exclude={"base_dir"}
    )
    scen_path.write_text(yaml.safe_dump(data))
    out = tmp_path / "x.nc"
    args = ["export", str(scen_path), "--trials", "2", "--seed", "5", "--out", str(out)]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    _, trials = load_exported(out)
    assert [t.index for t in trials] == [0, 1]
    bad = CliRunner().invoke(app, [*args[:2], "--trials", "0", "--out", str(out)])
    assert bad.exit_code == 2


def test_the_ins_model_round_trips_and_error_state_filters_run_on_the_file(tmp_path, small_mission):
    sensor = {"type": "multibeam", "beams": 5, "swath_width_m": 2000.0, "noise_std": 2.0}
    scen = _scenario(small_mission, sensor, dvl={"noise_std_m_s": 0.02, "bias_m_s": 0.01})
    path = export_trials(scen, tmp_path / "ins.nc")
    grid, trials = load_exported(path)
    ref_grid = prepare_map(scen)
    ref = simulate_trial(scen, ref_grid, 1)
    assert ref.ins_model is not None and ref.ins_model.dvl_aiding
    assert trials[1].ins_model == ref.ins_model
    for spec in ("mpf:particles=500", "pmf:model=errstate"):
        method = parse_method_spec(spec)
        ours = run_trial(method, trials[1], grid, method_rng(3, 1, spec))
        theirs = run_trial(method, ref, ref_grid, method_rng(3, 1, spec))
        assert not ours.failed, ours.message
        np.testing.assert_array_equal(ours.estimate, theirs.estimate)
    mission, _ = read_exported(path, trial=1)
    assert mission.meta["ins_model"] == ref.ins_model
    np.testing.assert_array_equal(mission.velocity, ref.dvl_velocity)


def test_an_export_without_the_ins_model_reads_as_before(tmp_path, small_mission):
    scen = _scenario(small_mission, {"type": "singlebeam", "noise_std": 2.0})
    path = export_trials(scen, tmp_path / "t.nc")
    with xr.open_dataset(path) as opened:
        ds = opened.load()
    assert "ins_model_json" in ds.attrs
    del ds.attrs["ins_model_json"]
    ds.to_netcdf(tmp_path / "old.nc")
    _, trials = load_exported(tmp_path / "old.nc")
    assert trials[0].ins_model is None
    mpf = parse_method_spec("mpf")
    result = run_trial(mpf, trials[0], prepare_map(scen), method_rng(0, 0, "mpf"))
    assert result.failed and "INS error model" in result.message
    ds.attrs["ins_model_json"] = '{"mode": "sideways"}'
    ds.to_netcdf(tmp_path / "bad.nc")
    with pytest.raises(GeofixError, match="ins_model_json"):
        load_exported(tmp_path / "bad.nc")


def test_ins_model_dict_round_trip():
    model = InsErrorModel(mode="dvl", initial_offset=(10.0, -5.0), dvl_bias=0.02)
    assert InsErrorModel.from_dict(json.loads(json.dumps(model.to_dict()))) == model
    assert InsErrorModel.from_dict({**model.to_dict(), "future_key": 1}) == model
