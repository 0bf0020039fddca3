"""``geofix replay`` on MGD77T tracklines: --field, --segment, --start-h, --hours.

The bundled EW0112 excerpt (40 h, one record a minute) against the bundled ETOPO1 crop at
10 arc-minutes (an independent global prior).
"""

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from typer.testing import CliRunner

from geofix.cli import app
from geofix.errors import ConfigError, GeofixWarning
from geofix.logs import read_mgd77
from geofix.logs.mgd77 import field_segments, pick_segment
from geofix.maps import load_grid
from geofix.replay import replay_log, window_mission

runner = CliRunner()
DATA = Path(__file__).parents[1] / "data" / "mgd77"
EXCERPT = DATA / "ew0112_excerpt.m77t"
ETOPO = DATA / "etopo1_10min_ew0112.nc"
ROW_KEYS = {
    "end_error_m",
    "mean_error_m",
    "max_error_m",
    "converged_at_s",
    "reinits",
    "converged_pings",
    "converged_nees",
    "ins_end_error_m",
}


def quiet(fn, *args, **kwargs):
    """Call ``fn`` with the excerpt's time-placement warning silenced."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeofixWarning)
        return fn(*args, **kwargs)


def replay_args(*extra: str) -> list[str]:
    return ["replay", str(EXCERPT), "--map", str(ETOPO), "--method", "pmf", *extra]


def without_column(tmp_path: Path, column: str, blank: bool = False) -> Path:
    """The excerpt without ``column`` (or with it blank everywhere)."""
    lines = EXCERPT.read_text(encoding="latin-1").splitlines()
    header = lines[0].split("\t")
    at = header.index(column)
    out = []
    for k, line in enumerate(lines):
        cells = line.split("\t")
        cells += [""] * (len(header) - len(cells))
        if blank:
            cells[at] = column if k == 0 else ""
        else:
            del cells[at]
        out.append("\t".join(cells))
    path = tmp_path / f"no_{column.lower()}.m77t"
    path.write_text("\n".join(out) + "\n", encoding="latin-1")
    return path


# ---------------------------------------------------------------------- the command
def test_depth_window_replays_on_etopo_with_every_json_key(tmp_path):
    args = replay_args("--field", "depth", "--hours", "2", "--seed", "3", "--json")
    result = runner.invoke(app, [*args, "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    assert set(summary) == {"pings", "methods"}
    # one depth a minute: the first 2 h hold the pings of minutes 0..120 (two lack a depth
    # later in the excerpt, none in this window)
    assert summary["pings"] == 121
    row = summary["methods"]["pmf"]
    assert set(row) >= ROW_KEYS
    assert 0 < row["mean_error_m"] <= row["max_error_m"] < 1e5
    assert row["end_error_m"] <= row["max_error_m"]
    # a free INS drifts on the GNSS track: it is off at the end of two hours
    assert row["ins_end_error_m"] > 10.0
    ds = xr.open_dataset(tmp_path / "estimates.nc")
    assert ds["x"].shape == (1, 121)
    assert float(ds["t"].values[0, -1]) == pytest.approx(7200.0)


def test_start_and_hours_pick_the_records_of_that_window():
    result, _ = quiet(
        replay_log, EXCERPT, str(ETOPO), ["pmf"], field_name="depth", start_h=10.0, hours=1.0
    )
    mission = result.mission
    # record k of the excerpt was logged at minute k (its times are whole minutes where
    # readable): the window holds records 600 .. 660, rebased on the first
    assert mission.meta["records"][0] == 600 and mission.meta["records"][-1] == 660
    assert mission.n == 61 and mission.times[0] == 0.0
    assert mission.times[-1] == pytest.approx(3600.0, abs=5.0)
    assert mission.meta["window_h"] == (10.0, 1.0)
    full = quiet(read_mgd77, EXCERPT)[0]
    assert mission.start_utc == pytest.approx(full.start_utc + 36000.0, abs=5.0)
    assert mission.meta["lon"].shape == (61,) and mission.meta["placed"].shape == (61,)
    np.testing.assert_array_equal(mission.meta["lon"], full.meta["lon"][600:661])
    # in the map's frame: the log is projected with the map's own projection
    assert mission.frame == load_grid(ETOPO).meta["projection"]


def test_segment_number_and_default_longest(tmp_path):
    name, missions = quiet(field_segments, EXCERPT, "magnetic")
    assert name == "magnetic" and len(missions) >= 1
    longest = pick_segment(missions, None)
    assert longest.duration_s == max(m.duration_s for m in missions)
    assert pick_segment(missions, 0) is missions[0]
    args = replay_args("--field", "magnetic", "--segment", "0", "--hours", "1", "--json")
    # magnetic is a map kind: a magnetic residual (nT) needs a magnetic map, not a depth one
    result = runner.invoke(app, [*args, "--out", str(tmp_path)])
    assert result.exit_code == 2, result.output
    assert "--field magnetic needs a magnetic map" in result.output
    args = replay_args("--field", "depth", "--segment", "0", "--hours", "1", "--json")
    result = runner.invoke(app, [*args, "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["pings"] > 50


def test_default_field_is_depth():
    name, missions = quiet(field_segments, EXCERPT)
    assert name == "depth" and missions[0].kind == "depth" and missions[0].n == 2398


# ---------------------------------------------------------------------- errors
@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--segment", "1"], "--segment 1 is out of range"),
        (["--segment", "-1"], "numbered 0..0 (0: 40.0 h)"),
        (["--start-h", "39", "--hours", "2"], "which is 39.98 h long"),
        (["--start-h", "45"], "lies outside"),
        (["--hours", "0"], "--hours must be a finite number of hours > 0"),
        (["--start-h", "-1"], "--start-h must be a finite number of hours >= 0"),
        (["--field", "salinity"], "unknown --field 'salinity'"),
        (["--field", "depth", "--field", "gravity"], "give one --map per --field"),
        (["--field", "gravity"], "--field gravity needs a gravity map"),
    ],
)
def test_bad_choices_end_in_one_error_line(extra, message, tmp_path):
    result = runner.invoke(app, [*replay_args(*extra), "--out", str(tmp_path)])
    assert result.exit_code == 2, result.output
    assert message in result.output
    assert "Traceback" not in result.output


def test_a_field_the_file_lacks_is_named(tmp_path):
    path = without_column(tmp_path, "MAG_RES")
    with pytest.raises(ConfigError, match=r"has no magnetic \(MAG_RES column\)"):
        field_segments(path, "magnetic")
    blank = without_column(tmp_path, "MAG_RES", blank=True)
    with pytest.raises(ConfigError, match=r"has no magnetic \(MAG_RES, nT\) segment"):
        quiet(field_segments, blank, "magnetic")
    result = runner.invoke(app, ["replay", str(path), "--map", str(ETOPO), "-m", "pmf",
                                 "--field", "magnetic", "--out", str(tmp_path / "o")])  # fmt: skip
    assert result.exit_code == 2 and "has no magnetic" in result.output


def test_field_and_segment_refused_on_other_logs(tmp_path):
    args = ["replay", "builtin:ex1811", "--map", str(ETOPO), "-m", "pmf", "--segment", "0"]
    result = runner.invoke(app, [*args, "--out", str(tmp_path)])
    assert result.exit_code == 2
    assert "--field and --segment apply to MGD77T logs" in result.output


def test_window_of_any_mission_rebases_and_refuses_outside():
    mission = quiet(read_mgd77, EXCERPT, fields=("gravity",))[0]
    assert window_mission(mission) is mission
    tail = window_mission(mission, start_h=39.0)
    assert tail.times[0] == 0.0 and tail.n == 60  # minutes 2340 .. 2399
    with pytest.raises(ConfigError, match="holds < 2 pings"):
        window_mission(mission, start_h=39.98, hours=0.001)
    with pytest.raises(ConfigError, match="lies outside"):
        window_mission(mission, start_h=0.0, hours=41.0)
