"""A map that states the 1-sigma of its level: the prior of the filters' common offset."""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from geofix.errors import GeofixWarning, MapError
from geofix.logs.mgd77 import field_segments, pick_segment
from geofix.maps import Grid, load_grid
from geofix.maps import offset as offset_module
from geofix.maps.offset import default_offset_std
from geofix.replay import nees, replay, window_mission


def _stated(grid: Grid, std) -> Grid:
    return dataclasses.replace(grid, meta={**grid.meta, "offset_std": std})


def test_the_stated_level_replaces_the_map_kind_s_offset_prior():
    depth = Grid(np.full((3, 3), -1000.0), 0.0, 0.0, 10.0, 10.0)
    gravity = dataclasses.replace(depth, values=np.zeros((3, 3)), kind="gravity")
    assert depth.stated_offset_std is None
    assert default_offset_std(depth) == pytest.approx(5.0 + 0.002 * 1000.0)
    assert default_offset_std(gravity) == 5.0
    assert default_offset_std(_stated(gravity, 25.0)) == 25.0
    assert default_offset_std(_stated(depth, 0.0)) == 0.0
    for bad in (-1.0, float("nan"), "level"):
        with pytest.raises(MapError, match="offset_std"):
            default_offset_std(_stated(gravity, bad))


def test_a_depth_map_s_median_is_read_once_and_kept_per_map(monkeypatch):
    # a matcher asks for the prior at every fix: the median over a large map is taken
    # once per map, and a second map (other depths) gets its own
    values = np.full((4, 5), -2000.0)
    values[0, 0], values[1, 1] = np.nan, -10.0
    deep, shallow = Grid(values, 0.0, 0.0, 10.0, 10.0), Grid(values / 10, 0.0, 0.0, 10.0, 10.0)
    calls = []
    median = np.median
    monkeypatch.setattr(offset_module.np, "median", lambda a: calls.append(1) or median(a))
    assert default_offset_std(deep) == pytest.approx(5.0 + 0.002 * 2000.0)
    assert default_offset_std(deep) == pytest.approx(5.0 + 0.002 * 2000.0)
    assert len(calls) == 1
    assert default_offset_std(shallow) == pytest.approx(5.0 + 0.002 * 200.0)
    assert len(calls) == 2


def test_a_map_file_states_its_level_in_an_attribute(tmp_path):
    y, x = np.arange(5) * 100.0, np.arange(6) * 100.0
    z = xr.DataArray(np.add.outer(y, x) * 0.01, coords={"y": y, "x": x}, dims=("y", "x"))
    z.attrs["units"] = "mGal"
    path = tmp_path / "stated.nc"
    xr.Dataset({"z": z}, attrs={"offset_std": 25.0}).to_netcdf(path)
    assert load_grid(path).stated_offset_std == 25.0
    z.attrs["offset_std"] = 12.0  # the variable's attribute wins over the file's
    xr.Dataset({"z": z}, attrs={"offset_std": 25.0}).to_netcdf(path)
    assert load_grid(path).stated_offset_std == 12.0
    del z.attrs["offset_std"]
    xr.Dataset({"z": z}).to_netcdf(path)
    assert load_grid(path).stated_offset_std is None
    xr.Dataset({"z": z}, attrs={"offset_std": -5.0}).to_netcdf(path)
    with pytest.raises(MapError, match="offset_std must be a number >= 0"):
        load_grid(path)


#: The real-tracks benchmark's data: a 36 h excerpt of EW0112 (GNSS truth, a free-air anomaly
#: a minute) and EIGEN-6C4's anomaly at 10 km height over it, stating a 25 mGal level.
TRACKS = Path(__file__).parents[1] / "benchmarks" / "data" / "mgd77"
#: The 2-D 3-sigma: ``e^T C^-1 e`` within the covariance's 99.73 % ellipse.
NEES_3SIGMA = 11.83


def test_a_real_gravity_track_holds_on_a_model_that_states_its_level():
    # the ship's anomaly sits about 32 mGal above the model's along this track, six times
    # the gravity default's 5 mGal: with the map's stated 25 mGal as the offset's prior
    # pmf ends better than the INS alone
    grid = load_grid(TRACKS / "eigen6c4_10min_ew0112.nc")
    assert grid.kind == "gravity" and grid.stated_offset_std == 25.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeofixWarning)  # the excerpt's placed times
        _, missions = field_segments(
            TRACKS / "ew0112_excerpt.m77t", "gravity", frame=grid.meta["projection"]
        )
    mission = window_mission(pick_segment(missions, None), 24.0, 12.0)
    result = replay(mission, grid, ["pmf"], seed=1)
    ests, inputs = result.estimates["pmf"], result.inputs
    error = np.hypot(*(np.array([e.position for e in ests]) - inputs.truth).T)
    ins = np.hypot(*(inputs.indicated - inputs.truth).T)
    assert error[-1] < ins[-1]
    assert np.mean(nees(ests, inputs.truth) <= NEES_3SIGMA) >= 0.99


def test_a_replay_states_the_level_it_is_told():
    from typer.testing import CliRunner

    from geofix.cli import app
    from geofix.replay import replay_log

    def first_offset(offset_std):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", GeofixWarning)  # the excerpt's placed times
            result, _ = replay_log(
                str(TRACKS / "ew0112_excerpt.m77t"),
                [str(TRACKS / "eigen6c4_10min_ew0112.nc")],
                ["pmf"],
                field_name=["gravity"],
                hours=0.25,
                offset_std=offset_std,
            )
        return result.estimates["pmf"][0].depth_bias

    # the ship reads about 33 mGal above the model here: the first ping's offset is that
    # residual shrunk by the prior, prior / (prior + noise); a 5 mGal prior shrinks it more
    assert first_offset([5.0]) < first_offset(None) - 1.0
    args = ["replay", str(TRACKS / "ew0112_excerpt.m77t"), "--method", "pmf", "--field"]
    args += ["gravity", "--map", str(TRACKS / "eigen6c4_10min_ew0112.nc")]
    result = CliRunner().invoke(app, [*args, "--offset-std", "5", "--offset-std", "5"])
    assert result.exit_code != 0 and "2 --offset-std values for 1 maps" in result.output
    serve = ["serve", "--map", "builtin:grav_1km", "--port", "0"]
    result = CliRunner().invoke(app, [*serve, "--offset-std", "5", "--offset-std", "5"])
    assert result.exit_code != 0
    assert "serve: 2 --offset-std values for 1 maps" in result.output
    result = CliRunner().invoke(app, [*serve, "--offset-std", "-3"])
    assert result.exit_code != 0 and "offset_std must be >= 0" in result.output
