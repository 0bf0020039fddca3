"""``geofix grid`` on the bundled EX1811 pings: a map with its uncertainty layer."""

import numpy as np
from typer.testing import CliRunner

from geofix.cli import app
from geofix.logs import read_mission
from geofix.maps import load_grid
from geofix.maps.gridding import load_map_error

runner = CliRunner()


def test_grid_writes_a_map_in_the_log_frame_with_std_and_count(tmp_path):
    out = tmp_path / "ex1811.nc"
    result = runner.invoke(app, ["grid", "builtin:ex1811", "--cell-m", "100", "--out", str(out)])
    assert result.exit_code == 0, result.output
    grid = load_grid(out)
    assert grid.dx == grid.dy == 100.0
    mission = read_mission("builtin:ex1811")
    assert grid.meta["projection"] == mission.frame
    # every sounding lies on a cell with data, and reads the map within the depth spread
    x, y, v = mission.soundings().T
    read = grid.sample(x, y, method="nearest")
    assert np.isfinite(read).all()
    assert np.median(np.abs(read - v)) < 20.0
    std = load_map_error(out)
    assert np.nanmax(std.values) > 0 and np.isfinite(std.values).sum() > 100


def test_grid_bad_cell_is_one_line_exit_2(tmp_path):
    result = runner.invoke(
        app, ["grid", "builtin:ex1811", "--cell-m", "-5", "--out", str(tmp_path / "m.nc")]
    )
    assert result.exit_code == 2
    assert "cell size must be positive" in result.output
    assert "Traceback" not in result.output


def test_grid_states_the_registration_it_is_told(tmp_path):
    out = tmp_path / "stated.nc"
    args = ["grid", "builtin:ex1811", "--cell-m", "200", "--out", str(out)]
    result = runner.invoke(app, [*args, "--registration-std", "15"])
    assert result.exit_code == 0, result.output
    assert load_grid(out).registration_var == 225.0
    result = runner.invoke(app, [*args, "--registration-std", "-1"])
    assert result.exit_code == 2
    assert "registration_std_m must be a number >= 0" in result.output
