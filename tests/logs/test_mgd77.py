"""MGD77T trackline reader: the bundled EW0112 excerpt, one hand-made file per quirk, the
five full cruises (from the folder ``GEOFIX_MGD77_DIR`` names; skipped without it), and
bad input."""

import os
import warnings
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest
from pyproj import Proj

from geofix.errors import ConfigError, GeofixWarning
from geofix.logs import read_mgd77, read_mission
from geofix.logs.mgd77 import course_over_ground, increasing_subsequence

DATA = Path(__file__).parents[1] / "data" / "mgd77"
EXCERPT = DATA / "ew0112_excerpt.m77t"
#: Folder of the full cruise files, outside the project (they are not bundled).
FULL_CRUISES = Path(os.environ["GEOFIX_MGD77_DIR"]) if os.environ.get("GEOFIX_MGD77_DIR") else None
ALL_FIELDS = ("depth", "gravity", "magnetic")


def utc(*args) -> float:
    return datetime(*args, tzinfo=UTC).timestamp()


def read_quiet(path, **kwargs):
    """read_mgd77 with its placement warning silenced."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeofixWarning)
        return read_mgd77(path, **kwargs)


def quirk(name: str, **kwargs):
    """The missions of a hand-made file, every field, any length."""
    kwargs = {"fields": ALL_FIELDS, "min_segment_s": 0, **kwargs}
    return read_quiet(DATA / f"quirk_{name}.m77t", **kwargs)


def by_kind(missions, kind):
    return [m for m in missions if m.kind == kind]


# ---------------------------------------------------------------------- the real excerpt
@pytest.fixture(scope="module")
def excerpt():
    return read_quiet(EXCERPT, fields=ALL_FIELDS)


def test_excerpt_is_one_mission_per_field_over_40_hours(excerpt):
    assert [m.kind for m in excerpt] == list(ALL_FIELDS)
    depth, gravity, magnetic = excerpt
    assert (depth.n, gravity.n, magnetic.n) == (2398, 2400, 2298)
    assert gravity.duration_s == pytest.approx(2399 * 60, abs=1e-6)
    assert all(np.all(np.diff(m.times) > 0) for m in excerpt)
    assert {m.meta["segment"] for m in excerpt} == {0}


def test_excerpt_first_record_has_its_known_values_and_utc_time(excerpt):
    depth, gravity, _ = excerpt
    # EW0112 20011013 0517, TIMEZONE -12: 2001-10-12 17:17 UTC; CORR_DEPTH 5067, FREEAIR 21.6
    assert depth.meta["records"][0] == 0 and gravity.meta["records"][0] == 0
    assert depth.beams[0, 0].tolist() == [0.0, 0.0, -5067.0]  # elevation, negative down
    assert gravity.beams[0, 0, 2] == pytest.approx(21.6)
    assert depth.start_utc == utc(2001, 10, 12, 17, 17)
    assert (depth.meta["lat"][0], depth.meta["lon"][0]) == (-17.69138, 76.43695)
    assert np.all(depth.beams[..., 2] < 0), "depths are stored as elevation"
    assert depth.meta["units"] == "m" and gravity.meta["units"] == "mGal"


def test_excerpt_track_is_gnss_truth_in_its_frame(excerpt):
    depth = excerpt[0]
    assert depth.nav_source == "gnss" and depth.meta["navigation"] == "gnss"
    np.testing.assert_array_equal(depth.truth, depth.nav)
    np.testing.assert_array_equal(depth.reference, depth.nav)
    x, y = Proj(depth.frame)(depth.meta["lon"], depth.meta["lat"])
    np.testing.assert_allclose(depth.nav, np.column_stack([x, y]))
    steps = np.hypot(*np.diff(depth.nav, axis=0).T) / np.diff(depth.times)
    assert steps.max() < 8.0, "a research ship, not faster than 16 kn"


def test_excerpt_garbled_hours_are_placed_within_seconds_of_one_record_a_minute(excerpt):
    gravity = excerpt[1]  # a value at every record: record k was logged at minute k
    placed = gravity.meta["placed"]
    assert gravity.meta["placed_by_distance"] == int(placed.sum()) == 360
    counts = gravity.meta["file"]
    assert (counts["blank_time"], counts["time_out_of_order"]) == (160, 200)
    error = gravity.times - 60.0 * gravity.meta["records"]
    assert np.all(error[~placed] == 0)
    assert np.median(np.abs(error[placed])) < 1.0  # 0.32 s
    assert np.abs(error[placed]).max() < 5.0  # 2.6 s


def test_excerpt_warns_once_with_the_count():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        read_mgd77(EXCERPT, fields=ALL_FIELDS)
    ours = [w for w in caught if issubclass(w.category, GeofixWarning)]
    assert len(ours) == 1
    assert "360 of 2400 record times" in str(ours[0].message)
    assert "ew0112_excerpt.m77t" in str(ours[0].message)


def test_a_given_frame_is_used_for_every_mission():
    frame = "+proj=utm +zone=44 +south +ellps=WGS84 +units=m +no_defs"
    missions = read_quiet(EXCERPT, fields=("depth", "gravity"), frame=frame)
    for m in missions:
        assert m.frame == frame
        x, y = Proj(frame)(m.meta["lon"], m.meta["lat"])
        np.testing.assert_allclose(m.nav, np.column_stack([x, y]))


def test_read_mission_gives_the_longest_depth_mission():
    with pytest.warns(GeofixWarning, match="placed by distance"):
        mission = read_mission(EXCERPT)
    assert mission.kind == "depth" and mission.n == 2398
    assert mission.meta["reader"] == "mgd77"


def test_read_mission_falls_back_to_gravity_without_depths(tmp_path):
    lines = EXCERPT.read_text(encoding="latin-1").splitlines()
    header = lines[0].split("\t")
    depth_at = header.index("CORR_DEPTH")
    out = ["\t".join(c for c in header if c != "CORR_DEPTH")]
    for line in lines[1:]:
        fields = line.split("\t")
        out.append("\t".join(f for k, f in enumerate(fields) if k != depth_at))
    path = tmp_path / "no_depth.m77t"
    path.write_text("\n".join(out) + "\n")
    with pytest.warns(GeofixWarning):
        mission = read_mission(path)
    assert mission.kind == "gravity" and mission.n == 2400


def test_replay_simulates_an_ins_on_the_track(excerpt):
    from geofix.replay import replay_inputs

    part = excerpt[1].subset(slice(0, 120))
    inputs = replay_inputs(part, seed=0)
    assert np.isfinite(inputs.indicated).all() and np.isfinite(inputs.sigma).all()
    np.testing.assert_array_equal(inputs.truth, part.nav)


# ---------------------------------------------------------------------- quirks
def test_blank_times_are_placed_by_distance_between_readable_neighbours():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        missions = read_mgd77(DATA / "quirk_blank_time.m77t", fields=ALL_FIELDS, min_segment_s=0)
    assert len([w for w in caught if issubclass(w.category, GeofixWarning)]) == 1
    assert "3 of 12 record times" in str(caught[0].message)
    depth = by_kind(missions, "depth")[0]
    np.testing.assert_allclose(depth.times, 60.0 * np.arange(12), atol=1e-6)
    assert np.flatnonzero(depth.meta["placed"]).tolist() == [4, 5, 6]
    assert depth.meta["file"]["blank_time"] == 3


def test_garbled_times_out_of_range_bad_minutes_backwards_or_text_are_placed():
    depth = by_kind(quirk("garbled_time"), "depth")[0]
    counts = depth.meta["file"]
    assert (counts["garbled_time"], counts["time_out_of_order"]) == (3, 1)
    assert np.flatnonzero(depth.meta["placed"]).tolist() == [3, 5, 8, 11]
    np.testing.assert_allclose(depth.times, 60.0 * np.arange(15), atol=1e-6)


def test_a_record_logged_twice_is_merged_and_a_stale_time_is_placed():
    depth = by_kind(quirk("duplicates"), "depth")[0]
    assert depth.n == 12
    assert 5 not in depth.meta["records"].tolist(), "the second copy is merged into the first"
    assert depth.beams[4, 0, 2] == -1004.0, "the copy's depth fills the first's blank"
    np.testing.assert_allclose(depth.times, 60.0 * np.arange(12), atol=1e-6)
    assert np.flatnonzero(depth.meta["placed"]).tolist() == [8]
    counts = depth.meta["file"]
    assert (counts["duplicates_merged"], counts["stale_time"]) == (1, 1)


def test_records_without_a_position_are_dropped_with_their_values():
    missions = quirk("no_position")
    kept = [0, 1, 2, 4, 5, 7, 8, 10, 12, 14, 15]
    for m in missions:
        assert m.meta["records"].tolist() == kept
        np.testing.assert_allclose(m.times, 60.0 * np.array(kept), atol=1e-6)
    counts = missions[0].meta["file"]
    assert (counts["no_position"], counts["bad_nav_quality"], counts["position_spikes"]) == (
        3,
        1,
        1,
    )


def test_bad_quality_codes_drop_values_and_poor_or_good_keep_them():
    missions = quirk("quality")
    records = {m.kind: m.meta["records"].tolist() for m in missions}
    assert records["depth"] == [0, 1, 5, 6, 7, 8, 9, 10, 11]  # 4, 5, 6 dropped; 3, 1 kept
    assert 7 not in records["gravity"] and len(records["gravity"]) == 11
    assert 9 not in records["magnetic"] and len(records["magnetic"]) == 11


def test_timezone_is_added_per_record_to_give_utc():
    missions = quirk("timezone")
    depth = by_kind(missions, "depth")[0]
    assert depth.start_utc == utc(2020, 1, 2, 4, 55)
    np.testing.assert_allclose(depth.times, 60.0 * np.arange(12), atol=1e-6)
    assert not depth.meta["placed"].any(), "the local step back is no garbled time"


def test_records_without_a_value_carry_the_track_but_are_no_pings():
    depth = by_kind(quirk("no_value"), "depth")[0]
    assert depth.meta["records"].tolist() == [0, 1, 2, 6, 7, 8, 9, 10, 11]
    np.testing.assert_allclose(depth.times[3], 360.0)
    assert np.rad2deg(depth.heading) == pytest.approx(90.0, abs=0.5)


def test_time_gaps_and_position_jumps_split_segments():
    depth = by_kind(quirk("gaps"), "depth")
    assert [m.n for m in depth] == [20, 20, 20]
    assert [m.start_utc for m in depth] == [
        utc(2020, 1, 1, 0, 0),
        utc(2020, 1, 1, 2, 20),
        utc(2020, 1, 1, 2, 40),
    ]
    assert [m.meta["segment"] for m in depth] == [0, 1, 2]
    # the silence also moved the ship 40 km; the jump after the second leg is 49 km
    no_gap_split = by_kind(quirk("gaps", max_gap_s=3 * 3600, max_jump_m=45e3), "depth")
    assert [m.n for m in no_gap_split] == [40, 20]
    no_jump_split = by_kind(quirk("gaps", max_jump_m=100e3), "depth")
    assert [m.n for m in no_jump_split] == [20, 40]


def test_min_segment_drops_short_missions():
    assert len(quirk("gaps", fields=("depth",), min_segment_s=19 * 60)) == 3
    with pytest.raises(ConfigError, match=r"quirk_gaps\.m77t: no depth segment of at least 1200"):
        quirk("gaps", fields=("depth",), min_segment_s=20 * 60)


def test_a_leg_logged_out_of_order_is_split_not_retimed():
    depth = by_kind(quirk("out_of_order"), "depth")
    assert [m.meta["records"][0] for m in depth] == [40, 0]
    assert [m.start_utc for m in depth] == [utc(2020, 1, 1, 0, 0), utc(2020, 1, 1, 1, 0)]
    assert not any(m.meta["placed"].any() for m in depth)


def test_increasing_subsequence_and_course_over_ground():
    assert increasing_subsequence(np.array([1, 5, 2, 3, 0, 4])).tolist() == [0, 2, 3, 5]
    assert increasing_subsequence(np.array([])).tolist() == []
    # at rest (GNSS jitter of a metre) for three records, then north-east
    xy = np.array([[0, 0], [1, 0], [0, 1], [0, 0], [100, 100], [200, 200]], dtype=float)
    course = np.rad2deg(course_over_ground(xy))
    assert course[4:] == pytest.approx([45.0, 45.0])
    assert course[3] == pytest.approx(np.rad2deg(np.arctan2(100, 99)))
    assert np.all(course[:3] == course[3]), "the first course is held back over the rest"
    assert np.rad2deg(course_over_ground(xy[:, ::-1] * [1, -1])[5]) == pytest.approx(135.0)


def test_a_record_with_extra_fields_does_not_shift_the_columns(tmp_path):
    path = tmp_path / "extra.m77t"
    rows = [f"X\t0\t20200101\t00{k:02d}\t10\t{20 + 0.003 * k:.3f}\t{1000 + k}" for k in range(3)]
    rows[1] += "\t7\t8"
    path.write_text("\n".join([header_line(), *rows]) + "\n")
    depth = read_mgd77(path, min_segment_s=0)[0]
    assert depth.beams[:, 0, 2].tolist() == [-1000.0, -1001.0, -1002.0]
    assert depth.meta["lat"].tolist() == [10.0, 10.0, 10.0]


# ---------------------------------------------------------------------- bad input
def header_line(without=()):
    return "\t".join(
        c
        for c in ("SURVEY_ID", "TIMEZONE", "DATE", "TIME", "LAT", "LON", "CORR_DEPTH")
        if c not in without
    )


@pytest.mark.parametrize(
    ("content", "match"),
    [
        (b"", "not an MGD77T file"),
        (b"lat,lon,depth\n10,20,1000\n", "not an MGD77T file"),
        (b"\x89HDF\r\n\x1a\n\0\0\0\0", "not an MGD77T file"),
        (header_line(without=("LAT",)).encode() + b"\n", "lacks column.*LAT"),
        (header_line(without=("CORR_DEPTH",)).encode() + b"\n", "lacks column.*CORR_DEPTH"),
        (header_line().encode() + b"\nX\t0\t20200101\t0000\t\t\t1000\n", "no MGD77T record"),
        (header_line().encode() + b"\n", "no MGD77T record"),
    ],
)
def test_bad_files_are_clear_errors_naming_the_path(tmp_path, content, match):
    path = tmp_path / "bad.m77t"
    path.write_bytes(content)
    with pytest.raises(ConfigError, match=match) as info:
        read_mgd77(path)
    assert "bad.m77t" in str(info.value)


def test_bad_arguments_and_missing_files_are_clear_errors(tmp_path):
    with pytest.raises(ConfigError, match=r"unknown MGD77T field.*bathy"):
        read_mgd77(EXCERPT, fields=("bathy",))
    with pytest.raises(ConfigError, match="max_gap_s"):
        read_mgd77(EXCERPT, max_gap_s=float("nan"))
    with pytest.raises(ConfigError, match="MGD77T file not found"):
        read_mgd77(tmp_path / "none.m77t")
    with pytest.raises(ConfigError, match="log not found"):
        read_mission(tmp_path / "none.m77t")


# ---------------------------------------------------------------------- full cruises
CRUISES = {
    # file: (records, depths, free-air, magnetics kept, navigation, one segment)
    "ew0007.m77t": (49006, 43646, 48986, 32520, "gnss", True),
    "ew0102.m77t": (38436, 37426, 37769, 5654, "gnss", True),
    "ew0112.m77t": (23838, 23710, 23719, 5515, "gnss", True),
    "78123006.m77t": (44713, 11988, 7620, 30207, "pre-gnss", False),
    "wi933014.m77t": (49299, 47640, 0, 43928, "pre-gnss", False),
}


@pytest.mark.skipif(
    FULL_CRUISES is None or not FULL_CRUISES.is_dir(),
    reason="GEOFIX_MGD77_DIR does not name a folder of the full cruise files",
)
@pytest.mark.parametrize("name", sorted(CRUISES))
def test_every_shared_cruise_reads_into_sane_missions(name):
    records, depths, gravity, magnetics, era, one_segment = CRUISES[name]
    assert FULL_CRUISES is not None
    missions = read_quiet(FULL_CRUISES / name, fields=ALL_FIELDS)
    counts = missions[0].meta["file"]
    assert counts["records"] == records
    assert (counts["depth_values"], counts["gravity_values"], counts["magnetic_values"]) == (
        depths,
        gravity,
        magnetics,
    )
    for m in missions:
        assert m.duration_s >= 3600 and m.meta["navigation"] == era
        assert np.all(np.diff(m.times) > 0) and np.diff(m.times).max() <= 900
        speed = np.hypot(*np.diff(m.nav, axis=0).T) / np.diff(m.times)
        assert speed.max() < 15.0, f"{m.name}: a ship at {speed.max():.1f} m/s"
        assert m.meta["records"].size == m.n and np.all(np.diff(m.meta["records"]) > 0)
    depth = by_kind(missions, "depth")
    assert depth and all(np.all(m.beams[..., 2] < 0) for m in depth)
    assert sum(m.n for m in depth) > 0.97 * depths
    assert ({m.meta["segment"] for m in missions} == {0}) == one_segment
    longest = max(m.duration_s for m in depth) / 3600
    assert 24 < longest < 1000
