"""A replayed log's poisoned records are dropped at the door with one warning, never
ending the replay: beam values beyond the physical range of the map's kind, beams far
from the vehicle, pings whose time or position is off the mission."""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest
from typer.testing import CliRunner

from _reliability import run_cli
from geofix.cli import app
from geofix.errors import ConfigError, GeofixWarning
from geofix.logs import read_mission, write_tables
from geofix.maps import load_grid
from geofix.replay import replay, screen_mission


@pytest.fixture(scope="module")
def ex1811_map(tmp_path_factory):
    out = tmp_path_factory.mktemp("poison") / "ex1811_100m.nc"
    result = CliRunner().invoke(
        app, ["grid", "builtin:ex1811", "--cell-m", "100", "--out", str(out)]
    )
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture(scope="module")
def mission():
    return read_mission("builtin:ex1811")


def _poisoned(mission, pings: dict[int, tuple[int, int, float]]):
    """The mission with ``beams[k, beam, column] = value`` for each ``k: (beam, column, value)``."""
    beams = np.array(mission.beams, dtype=float)
    for k, (beam, column, value) in pings.items():
        beams[k, beam, column] = value
    return replace(mission, beams=beams)


POISON = {3: (0, 2, 1e308), 7: (5, 2, -1e200), 11: (2, 0, 1e160), 12: (1, 2, 1e160)}


def test_poisoned_beams_are_dropped_with_one_warning_and_the_replay_finishes(ex1811_map, mission):
    grid = load_grid(ex1811_map)
    with pytest.warns(GeofixWarning) as caught:
        result = replay(_poisoned(mission, POISON), grid, ["pmf"], initial_error_m=300, seed=1)
    messages = [str(w.message) for w in caught if issubclass(w.category, GeofixWarning)]
    assert len(messages) == 1 and "4 pings with beams dropped" in messages[0], messages
    assert "+-12000 for a depth map" in messages[0]
    estimates = result.estimates["pmf"]
    assert len(estimates) == mission.n
    track = np.array([e.position for e in estimates])
    assert np.isfinite(track).all() and np.isfinite([e.covariance for e in estimates]).all()
    assert result.summary["methods"]["pmf"]["end_error_m"] < 200.0


def test_a_clean_log_gives_no_warning(mission):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert screen_mission(mission, "depth") is mission


def test_pings_off_the_mission_in_time_or_space_are_dropped(ex1811_map, mission):
    times = np.array(mission.times, dtype=float)
    times[-1] = times[-2] + 1e12  # a clock jump of 30 000 years
    nav = np.array(mission.nav, dtype=float)
    nav[20] = 1e300
    bad = replace(mission, times=times, nav=nav)
    with pytest.warns(GeofixWarning, match="2 pings dropped"):
        result = replay(bad, load_grid(ex1811_map), ["pmf"], initial_error_m=300, seed=1)
    assert result.summary["pings"] == mission.n - 2
    assert np.isfinite([e.position for e in result.estimates["pmf"]]).all()


def test_a_log_of_only_poisoned_pings_is_one_error(mission):
    bad = replace(mission, nav=np.full_like(np.asarray(mission.nav, dtype=float), 1e300))
    with pytest.raises(ConfigError, match="every ping"):
        screen_mission(bad, "depth")


@pytest.mark.parametrize(
    ("kind", "value", "kept"),
    [
        ("depth", -11_000.0, True),
        ("depth", -12_500.0, False),
        ("gravity", 900.0, True),
        ("gravity", -1_500.0, False),
    ],
)
def test_the_physical_range_follows_the_map_kind(mission, kind, value, kept):
    beams = np.array(mission.beams, dtype=float)
    beams[..., 2] = np.where(np.isnan(beams[..., 2]), np.nan, 0.0)  # in range for both kinds
    one = _poisoned(replace(mission, beams=beams), {0: (0, 2, value)})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        screened = screen_mission(one, kind)
    assert bool(screened.beams[0, 0, 2] == value) is kept
    assert (len(caught) == 0) is kept


def test_poisoned_log_through_the_command_line(ex1811_map, mission, tmp_path):
    folder = write_tables(_poisoned(mission, POISON), tmp_path / "log")
    args = ["replay", str(folder), "--map", str(ex1811_map), "-m", "pmf", "--json"]
    outcome = run_cli("replay poisoned", [*args, "--ins-initial-error-m", "300"])
    assert outcome.exit_code == 0 and not outcome.traceback, outcome.output
    warned = [line for line in outcome.lines if line.startswith("warning:")]
    assert len(warned) == 1 and "4 pings with beams dropped" in warned[0], outcome.output


def test_pings_that_repeat_a_time_are_dropped_and_one_time_for_all_is_refused(mission):
    times = np.array(mission.times, dtype=float)
    repeated = times.copy()
    repeated[[5, 6, 20]] = repeated[[4, 4, 19]]  # logged twice (and once three times)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        screened = screen_mission(replace(mission, times=repeated), "depth")
    assert screened.n == mission.n - 3 and np.all(np.diff(screened.times) > 0)
    lines = [str(w.message) for w in caught]
    assert len(lines) == 1 and "3 pings dropped" in lines[0] and "not after" in lines[0]
    with pytest.raises(ConfigError, match=r"the 50 pings .* share one time"):
        screen_mission(replace(mission, times=np.full(mission.n, 7.0)), "depth")
