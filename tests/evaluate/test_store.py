"""Results store: round trip, resume keys, persistence, export, scenario fingerprint."""

import json

import numpy as np
import pandas as pd
import pytest

from geofix.errors import GeofixError, MapError
from geofix.evaluate.runner import TrialResult
from geofix.evaluate.store import ResultStore, scenario_hash
from geofix.sim.scenario import scenario_from_dict

NAN = float("nan")


def _result(shift, failed=False, n=4):
    estimate = np.column_stack([np.arange(n) * 10.0 + shift, np.full(n, -5.0)])
    error = np.full(n, shift)
    if failed:
        estimate[2:] = NAN
        error[2:] = NAN
    return TrialResult(
        estimate=estimate,
        error=error,
        end_error_m=NAN if failed else float(shift),
        mean_track_error_m=NAN if failed else float(shift),
        max_track_error_m=NAN if failed else float(shift),
        leg_errors_m=(float(shift), NAN if failed else float(shift)),
        time_s=0.25,
        n_calls=2,
        ambiguous=not failed,
        covariance=None if failed else np.array([[4.0, 1.0], [1.0, 9.0]]),
        evaluations=123,
        failed=failed,
        message="tercom: window off the map" if failed else "",
    )


def _scenario(**changes):
    data = {
        "name": "tiny",
        "map": {"path": "builtin:mb_1km"},
        "track": {"start_cell": [40, 40], "speed_m_s": 10, "interval_s": 100, "samples": 10},
        "sensor": {"type": "singlebeam", "noise_std": 5.0},
        "trials": 5,
        "seed": 3,
    }
    data.update(changes)
    return scenario_from_dict(data)


def test_round_trip_keeps_values_arrays_and_nans(tmp_path):
    with ResultStore(tmp_path) as store:
        store.record("tiny", "h1", "tercom", 0, _result(7.0))
        store.record("tiny", "h1", "tercom", 1, _result(3.0, failed=True))
        frame = store.to_frame("h1", arrays=True)
    assert list(frame["trial"]) == [0, 1]
    ok, bad = frame.iloc[0], frame.iloc[1]
    assert ok["end_error_m"] == 7.0 and ok["n_calls"] == 2 and ok["evaluations"] == 123
    assert bool(ok["ambiguous"]) and not bool(ok["failed"])
    assert ok["leg_errors_m"] == [7.0, 7.0]
    np.testing.assert_array_equal(ok["estimate"], _result(7.0).estimate)
    np.testing.assert_array_equal(ok["covariance"], [[4.0, 1.0], [1.0, 9.0]])
    assert bool(bad["failed"]) and bad["message"] == "tercom: window off the map"
    assert np.isnan(bad["end_error_m"]) and bad["covariance"] is None
    assert bad["leg_errors_m"][0] == 3.0 and np.isnan(bad["leg_errors_m"][1])
    np.testing.assert_array_equal(np.isnan(bad["error"]), [False, False, True, True])


def test_done_keys_per_scenario_hash_and_replace(tmp_path):
    with ResultStore(tmp_path) as store:
        store.record("tiny", "h1", "tercom", 0, _result(1.0))
        store.record("tiny", "h1", "pmf", 2, _result(1.0))
        store.record("tiny", "h2", "tercom", 0, _result(1.0))
        store.record("tiny", "h1", "tercom", 0, _result(9.0))  # same key: replaced
        assert store.done_keys("h1") == {("tercom", 0), ("pmf", 2)}
        assert store.done_keys("h3") == set()
        assert list(store.to_frame("h1")["end_error_m"]) == [1.0, 9.0]  # pmf, tercom
        assert len(store.to_frame()) == 3


def test_rows_survive_reopening(tmp_path):
    store = ResultStore(tmp_path)
    store.record("tiny", "h1", "tercom", 4, _result(2.0))
    store.close()
    with ResultStore(tmp_path) as again:
        assert again.done_keys("h1") == {("tercom", 4)}


@pytest.mark.parametrize("suffix", [".parquet", ".csv"])
def test_export_by_suffix(tmp_path, suffix):
    with ResultStore(tmp_path) as store:
        store.record("tiny", "h1", "tercom", 0, _result(7.0))
        store.record("tiny", "h1", "tercom", 1, _result(3.0, failed=True))
        path = store.export(tmp_path / f"table{suffix}")
    if suffix == ".parquet":
        back = pd.read_parquet(path)
        xs = list(back["estimate_x"][0])
    else:
        back = pd.read_csv(path)
        xs = json.loads(back["estimate_x"][0])
        assert json.loads(back["error"][1])[2] is None  # NaN written as JSON null
    assert list(back["end_error_m"][:1]) == [7.0]
    assert xs == [7.0, 17.0, 27.0, 37.0]
    with ResultStore(tmp_path) as store, pytest.raises(GeofixError, match="xlsx"):
        store.export(tmp_path / "table.xlsx")


def test_scenario_hash_tracks_what_decides_the_trials():
    base = _scenario()
    assert scenario_hash(base) == scenario_hash(_scenario())
    assert scenario_hash(base) == scenario_hash(_scenario(trials=50))  # more trials extend
    assert scenario_hash(base) != scenario_hash(_scenario(seed=4))
    assert scenario_hash(base) != scenario_hash(_scenario(map={"path": "builtin:grav_1km"}))
    noisier = _scenario(sensor={"type": "singlebeam", "noise_std": 6.0})
    assert scenario_hash(base) != scenario_hash(noisier)


def test_scenario_hash_of_missing_map_file_raises(tmp_path):
    missing = scenario_from_dict(
        {
            "name": "x",
            "map": {"path": "nowhere.nc"},
            "track": {"speed_m_s": 1, "interval_s": 1, "samples": 2},
            "sensor": {"type": "singlebeam"},
        },
        base_dir=tmp_path,
    )
    with pytest.raises(MapError, match=r"nowhere\.nc"):
        scenario_hash(missing)


def test_uncommitted_rows_reach_other_readers_only_after_commit(tmp_path):
    store = ResultStore(tmp_path)
    store.record("tiny", "h1", "tercom", 0, _result(7.0), commit=False)
    with ResultStore(tmp_path) as reader:
        assert reader.done_keys("h1") == set()
    store.commit()
    with ResultStore(tmp_path) as reader:
        assert reader.done_keys("h1") == {("tercom", 0)}
    store.close()


def test_a_batch_interrupted_by_ctrl_c_is_still_committed(tmp_path):
    from geofix.evaluate.store import Batches

    store = ResultStore(tmp_path)
    with pytest.raises(KeyboardInterrupt), Batches(store) as batches:
        for trial in range(3):
            store.record("tiny", "h1", "tercom", trial, _result(1.0), commit=False)
            batches.recorded()
        raise KeyboardInterrupt
    with ResultStore(tmp_path) as reader:
        assert reader.done_keys("h1") == {("tercom", t) for t in range(3)}
    store.close()


def test_scenario_hash_changes_with_the_code_that_runs_the_trials(monkeypatch):
    """A store written by other code is not read as this code's."""
    import geofix.evaluate.store as store_module

    base = scenario_hash(_scenario())
    digest = store_module.code_digest()
    assert len(digest) == 64 and digest == store_module.code_digest()
    monkeypatch.setattr(store_module, "code_digest", lambda: "0" * 64)
    assert scenario_hash(_scenario()) != base


def test_the_code_digest_reads_every_source_file(tmp_path, monkeypatch):
    import geofix.evaluate.store as store_module

    package = tmp_path / "geofix"
    (package / "evaluate").mkdir(parents=True)
    (package / "a.py").write_text("x = 1\n")
    fake = package / "evaluate" / "store.py"
    fake.write_text("")
    monkeypatch.setattr(store_module, "__file__", str(fake))
    store_module.code_digest.cache_clear()
    try:
        first = store_module.code_digest()
        store_module.code_digest.cache_clear()
        (package / "a.py").write_text("x = 2\n")
        assert store_module.code_digest() != first
    finally:
        store_module.code_digest.cache_clear()
