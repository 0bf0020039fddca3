"""Mission readers: the bundled EX1811 GSF file, geofix exports, nav/soundings tables."""

import numpy as np
import pytest
from pyproj import Proj

from geofix.errors import ConfigError
from geofix.logs import Mission, read_exported, read_mission, read_tables, write_tables
from geofix.sim.export import export_trials


@pytest.fixture(scope="module")
def ex1811() -> Mission:
    return read_mission("builtin:ex1811")


def test_gsf_has_50_pings_of_432_beams_over_298_s(ex1811):
    assert (ex1811.n, ex1811.beam_count) == (50, 432)
    assert ex1811.nav_source == "gnss"
    assert ex1811.duration_s == pytest.approx(298.5, abs=0.01)
    # 2018-11-02 21:21:44 UTC
    assert ex1811.start_utc == pytest.approx(1541193704.56, abs=0.01)


def test_gsf_position_is_the_cruise_area_with_lat_lon_swapped_back(ex1811):
    lon, lat = ex1811.meta["lon"], ex1811.meta["lat"]
    assert np.all((lat > 17.8) & (lat < 17.9)), "latitude must be about 17.84 N"
    assert np.all((lon > -64.65) & (lon < -64.55)), "longitude must be about 64.59 W"
    x, y = Proj(ex1811.frame)(lon, lat)
    np.testing.assert_allclose(ex1811.nav, np.column_stack([x, y]))


def test_gsf_values_are_elevations_within_the_file_depth_range(ex1811):
    v = ex1811.beams[..., 2]
    good = v[np.isfinite(v)]
    assert good.min() == pytest.approx(-2316.674, abs=0.01)
    assert good.max() == pytest.approx(-1165.564, abs=0.01)
    heading = np.rad2deg(ex1811.heading)
    assert heading.min() > 132 and heading.max() < 145


def test_starboard_beams_land_south_west_of_a_ship_heading_south_east(ex1811):
    ping = ex1811.ping(0)
    far_beam = int(np.argmax(ping[:, 0]))
    assert ping[far_beam, 0] > 1000
    # the first ping's soundings come first in soundings()
    far = ex1811.soundings()[far_beam]
    assert far[0] < ex1811.nav[0, 0] - 500 and far[1] < ex1811.nav[0, 1] - 500
    assert np.hypot(*(far[:2] - ex1811.nav[0])) == pytest.approx(
        np.hypot(ping[far_beam, 0], ping[far_beam, 1]), rel=1e-9
    )


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_tables_round_trip_gives_the_same_mission(ex1811, tmp_path, fmt):
    part = ex1811.subset(slice(0, 6))
    write_tables(part, tmp_path / "m", fmt=fmt)
    back = read_tables(tmp_path / "m", frame=part.frame)
    assert back.nav_source == "gnss" and back.n == 6
    np.testing.assert_allclose(back.times, part.times, atol=1e-6)
    np.testing.assert_allclose(back.nav, part.nav, atol=1e-6)
    np.testing.assert_allclose(back.heading, part.heading, atol=1e-9)
    np.testing.assert_allclose(back.soundings(), part.soundings(), atol=1e-5)


def test_tables_refuse_a_ping_far_from_any_navigation_record(tmp_path):
    import pandas as pd

    pd.DataFrame(
        {"t": [0.0, 100.0], "x": [0, 100.0], "y": [0, 0.0], "heading_deg": [90, 90]}
    ).to_csv(tmp_path / "nav.csv", index=False)
    pd.DataFrame({"t": [50.0], "across_m": [0.0], "along_m": [0.0], "depth_m": [10.0]}).to_csv(
        tmp_path / "soundings.csv", index=False
    )
    with pytest.raises(ConfigError, match="50 s from the nearest navigation"):
        read_tables(tmp_path)


def test_tables_name_a_missing_column(tmp_path):
    import pandas as pd

    pd.DataFrame({"t": [0.0], "x": [0.0], "y": [0.0]}).to_csv(tmp_path / "nav.csv", index=False)
    pd.DataFrame({"t": [0.0], "across_m": [0.0], "along_m": [0.0]}).to_csv(
        tmp_path / "soundings.csv", index=False
    )
    with pytest.raises(ConfigError, match="heading_deg"):
        read_tables(tmp_path)


def test_export_reader_gives_the_trial_as_an_ins_mission(small_mission, tmp_path):
    scen = small_mission("logs-export", trials=2)
    path = export_trials(scen, tmp_path / "trials.nc")
    mission, grid = read_exported(path, trial=1)
    from geofix.sim.export import load_exported

    _, trials = load_exported(path)
    t = trials[1]
    assert mission.nav_source == "ins"
    np.testing.assert_array_equal(mission.nav, t.indicated)
    np.testing.assert_array_equal(mission.truth, t.truth)
    np.testing.assert_array_equal(mission.beams[..., 2], t.measured)
    np.testing.assert_array_equal(mission.reference, t.truth)
    assert grid.shape == (160, 160)
    with pytest.raises(ConfigError, match="trial 5 not in the file"):
        read_exported(path, trial=5)


def test_unknown_log_format_is_a_clear_error(tmp_path):
    (tmp_path / "log.txt").write_text("x")
    with pytest.raises(ConfigError, match="unknown log format"):
        read_mission(tmp_path / "log.txt")
    with pytest.raises(ConfigError, match="no bundled log"):
        read_mission("builtin:nope")
