"""Campaign statistics on a hand-made results table with known answers."""

import math

import numpy as np
import pandas as pd
import pytest

from geofix.evaluate.metrics import summarize

NAN = float("nan")


def _rows(method, ends, tracks, max_tracks, legs, ambiguous, failed, times, calls):
    return pd.DataFrame(
        {
            "method": method,
            "trial": range(len(ends)),
            "end_error_m": ends,
            "mean_track_error_m": tracks,
            "max_track_error_m": max_tracks,
            "leg_errors_m": legs,
            "time_s": times,
            "n_calls": calls,
            "evaluations": [100] * len(ends),
            "ambiguous": ambiguous,
            "failed": failed,
        }
    )


@pytest.fixture
def table():
    a = _rows(
        "tercom:metric=mad",
        ends=[10.0, 30.0, 50.0, 90.0, 250.0, NAN],
        tracks=[5.0, 15.0, 25.0, 45.0, 100.0, 1e9],  # the failed row must be ignored
        max_tracks=[20.0, 40.0, 60.0, 100.0, 300.0, 1e9],
        legs=[[1.0, 10.0], [3.0, 30.0], [5.0, 50.0], [9.0, 90.0], [25.0, 250.0], [NAN, NAN]],
        ambiguous=[False, False, False, True, False, False],
        failed=[False] * 5 + [True],
        times=[1.0, 1.0, 1.0, 1.0, 1.0, 0.5],
        calls=[2, 2, 2, 2, 2, 1],
    )
    b = _rows(
        "b",
        ends=[NAN, NAN],
        tracks=[NAN, NAN],
        max_tracks=[NAN, NAN],
        legs=[[NAN], [NAN]],
        ambiguous=[False, False],
        failed=[True, True],
        times=[0.1, 0.3],
        calls=[1, 1],
    )
    return pd.concat([a, b], ignore_index=True)


def test_error_statistics_over_successful_trials(table):
    s = summarize(table, cell_m=40.0)["tercom:metric=mad"]
    assert s.trials == 6
    assert s.failures == 1
    assert s.mean_error_m == pytest.approx(86.0)
    assert s.std_error_m == pytest.approx(math.sqrt(7424.0))  # population std
    assert s.median_error_m == pytest.approx(50.0)
    assert s.max_error_m == pytest.approx(250.0)
    assert s.mean_track_error_m == pytest.approx(38.0)
    assert s.max_track_error_m == pytest.approx(300.0)
    assert s.mean_time_s == pytest.approx(5.5 / 11)
    assert s.leg_mean_errors_m == pytest.approx([8.6, 86.0])


def test_success_rates_in_metres_and_cells_count_failures_as_misses(table):
    rates = summarize(table, cell_m=40.0)["tercom:metric=mad"].success_rate
    expected = {"20": 1, "40": 2, "60": 3, "80": 3, "100": 4}
    expected.update({"0.5c": 1, "1c": 2, "2c": 3, "3c": 4})  # 20, 40, 80, 120 m
    assert list(rates) == list(expected)
    for key, hits in expected.items():
        assert rates[key] == pytest.approx(hits / 6), key


def test_false_fixes_are_far_and_unflagged(table):
    s = summarize(table, cell_m=40.0)["tercom:metric=mad"]
    assert s.false_fix_rate == pytest.approx(1 / 6)  # 250 m > 3 cells, not flagged
    flagged = table.copy()
    flagged.loc[4, "ambiguous"] = True
    assert summarize(flagged, cell_m=40.0)["tercom:metric=mad"].false_fix_rate == 0.0
    # with 100 m cells, 250 m is within 3 cells: no false fix
    assert summarize(table, cell_m=100.0)["tercom:metric=mad"].false_fix_rate == 0.0


def test_all_failed_method_gives_none_not_nan(table):
    s = summarize(table, cell_m=40.0)["b"]
    assert s.trials == 2 and s.failures == 2
    for key in ("mean_error_m", "std_error_m", "median_error_m", "max_error_m"):
        assert getattr(s, key) is None
    assert s.mean_track_error_m is None
    assert set(s.success_rate.values()) == {0.0}
    assert s.mean_time_s == pytest.approx(0.2)
    assert s.leg_mean_errors_m == []


def test_methods_keep_their_order_and_values_are_plain_python(table):
    summary = summarize(table.iloc[::-1], cell_m=40.0)
    assert list(summary) == ["b", "tercom:metric=mad"]
    s = summary["tercom:metric=mad"]
    for key, value in s.to_json().items():
        if key not in ("success_rate", "leg_mean_errors_m"):
            assert type(value) in (int, float, type(None)), key
            assert not isinstance(value, np.generic), key
