"""The valid bound of a campaign, its trial bounds in the store, and one simulation per trial."""

import json
import sqlite3

import numpy as np
import pytest

from geofix.evaluate import bounds, campaign, run_campaign
from geofix.evaluate.bounds import TrialInfo
from geofix.evaluate.store import ResultStore, read_summary, scenario_hash

SHORT = {"samples": 8}


def test_valid_bound_of_a_campaign_is_the_bound_of_its_trials(small_mission, tmp_path):
    scen = small_mission("valid", track=SHORT, trials=2)
    result = run_campaign(scen, ["tercom"], jobs=1, out_dir=tmp_path, valid_bound=True)
    terms = bounds.scenario_bound_tracks(scen, 2, genie=("_simulator",))
    summary = result.summary
    assert summary.valid_bound_m == bounds.end_bound_rms(terms, "_simulator")
    assert summary.valid_bound_track_m == bounds.track_bound_rms(terms, "_simulator")
    written = read_summary(tmp_path)
    assert written["valid_bound_m"] == summary.valid_bound_m
    assert written["crlb_m"] == summary.crlb_m  # the earlier keys stay
    with ResultStore(tmp_path) as store:
        stored = store.trial_bounds(scenario_hash(scen))
    assert sorted(stored) == [0, 1] and all(i.has_valid_bound for i in stored.values())
    expected = np.maximum(terms["crlb_simulator"][1], terms["zzb_simulator"][1])
    np.testing.assert_array_equal(stored[1].valid_track_m2, expected)


def test_valid_bound_is_added_to_a_store_without_it_and_only_when_asked(small_mission, tmp_path):
    scen = small_mission("valid-later", track=SHORT, trials=2)
    plain = run_campaign(scen, ["tercom"], jobs=1, out_dir=tmp_path)
    assert "valid_bound_m" not in json.loads((tmp_path / "summary.json").read_text())
    assert plain.summary.valid_bound_m is None
    later = run_campaign(scen, ["tercom"], jobs=1, out_dir=tmp_path, valid_bound=True)
    assert later.computed == 0 and later.summary.valid_bound_m > 0
    assert later.summary.crlb_m == plain.summary.crlb_m
    again = run_campaign(scen, ["tercom", "tercom:metric=mad"], jobs=1, out_dir=tmp_path)
    with ResultStore(tmp_path) as store:  # a later campaign without it keeps the terms
        assert all(i.has_valid_bound for i in store.trial_bounds(again.scenario_hash).values())


def test_each_trial_is_simulated_once(small_mission, tmp_path, monkeypatch):
    calls = []
    simulate = campaign.simulate_trial

    def counted(scenario, grid, index):
        calls.append(index)
        return simulate(scenario, grid, index)

    monkeypatch.setattr(campaign, "simulate_trial", counted)
    run_campaign(small_mission("once", trials=3), ["tercom", "pf"], jobs=1, out_dir=tmp_path)
    assert calls == [0, 1, 2]


def test_store_reads_bounds_of_earlier_versions(tmp_path):
    with ResultStore(tmp_path) as store:
        assert store.trial_bounds("h") == {}  # no side table yet
        db = store.connection
        db.execute(
            "CREATE TABLE trial_bounds (scenario_hash TEXT NOT NULL, trial INTEGER NOT NULL, "
            "crlb_var_m2 REAL, crlb_batch_var_m2 REAL, truth_end_x REAL NOT NULL, "
            "truth_end_y REAL NOT NULL, PRIMARY KEY (scenario_hash, trial))"
        )
        db.execute("INSERT INTO trial_bounds VALUES ('h', 3, 4.0, NULL, 1.0, 2.0)")
        db.commit()
        (old,) = store.trial_bounds("h").values()
        assert (old.index, old.crlb_var_m2, old.truth_end) == (3, 4.0, (1.0, 2.0))
        assert np.isnan(old.crlb_batch_var_m2) and np.isnan(old.crlb_rw_var_m2)
        assert old.valid_track_m2 is None
        store.open_bounds()
        info = TrialInfo(3, 5.0, 6.0, (1.0, 2.0), 7.0, 8.0, np.arange(3.0), np.ones(3))
        store.record_bounds("h", info)
        store.record_bounds("h", TrialInfo(3, 9.0, 6.0, (1.0, 2.0), 7.0, 8.0))
        (new,) = store.trial_bounds("h").values()
    assert new.crlb_var_m2 == 9.0
    np.testing.assert_array_equal(new.valid_track_m2, np.arange(3.0))
    with sqlite3.connect(tmp_path / "results.sqlite") as db:
        columns = [row[1] for row in db.execute("PRAGMA table_info(trial_bounds)")]
    assert columns[:8] == [
        *("scenario_hash", "trial", "crlb_var_m2", "crlb_batch_var_m2", "truth_end_x"),
        *("truth_end_y", "crlb_track_var_m2", "crlb_rw_var_m2"),
    ]


def test_valid_bound_needs_every_trial():
    full = TrialInfo(0, 1.0, 1.0, (0.0, 0.0), valid_track_m2=np.ones(2), genie_track_m2=np.ones(2))
    assert bounds.valid_bound([full, TrialInfo(1, 1.0, 1.0, (0.0, 0.0))]) == (None, None)
    genie = np.array([np.nan, 9.0])
    info = TrialInfo(0, 1.0, 1.0, (0.0, 0.0), valid_track_m2=np.ones(2), genie_track_m2=genie)
    end, track = bounds.valid_bound([info])
    assert end == pytest.approx(3.0) and track == pytest.approx(np.sqrt(5.0))


def test_bounds_of_trials_in_two_processes_are_those_of_one(small_mission):
    """Each trial's bound is the same whichever process computes it."""
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    from geofix.evaluate._pool import worker_start_method

    scen = small_mission("parallel", track=SHORT, trials=3)
    serial = bounds.scenario_bound_tracks(scen, 3, genie=("_simulator",))
    with ProcessPoolExecutor(2, mp_context=get_context(worker_start_method())) as pool:
        parallel = bounds.scenario_bound_tracks(scen, 3, genie=("_simulator",), mapper=pool.map)
    assert sorted(serial) == sorted(parallel)
    for key, value in serial.items():
        np.testing.assert_array_equal(parallel[key], value)
