"""One trial (leg logic, failures, generators) and whole campaigns (resume, pool, Dask)."""

import json
import zlib
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import pandas as pd
import pytest

from geofix import methods as registry
from geofix.console import summary_table
from geofix.errors import ConfigError, MapError, MatchError, TrackOffMapError
from geofix.evaluate import run_campaign, run_trial
from geofix.evaluate.runner import method_rng
from geofix.evaluate.store import ResultStore
from geofix.evaluate.summary import CampaignSummary
from geofix.maps.grid import Grid
from geofix.problem import Fix
from geofix.sim.scenario import scenario_from_dict
from geofix.sim.trial import Trial

# ----------------------------------------------------------------------------- one trial


def _trial(n_legs=3, per_leg=5):
    """A straight track with a growing INS drift and a growing prior sigma (metres)."""
    n = n_legs * per_leg
    t = np.arange(n) * 10.0
    truth = np.column_stack([100.0 + 5.0 * t, 200.0 + 2.0 * t])
    drift = np.column_stack([0.3 * t + 20.0, -0.2 * t - 10.0])
    return Trial(
        truth=truth,
        true_heading=np.full(n, 1.19),
        indicated=truth + drift,
        indicated_heading=np.full(n, 1.19),
        times=t,
        measured=np.zeros((n, 1)),
        offsets=np.zeros((1, 2)),
        sigma_position=30.0 + 0.5 * t,
        leg_starts=tuple(range(0, n, per_leg)),
    )


_GRID = Grid(np.zeros((4, 4)), x0=0.0, y0=0.0, dx=100.0, dy=100.0)


@dataclass
class _TruthShift:
    """Returns the true positions of the samples it is given, shifted by ``offset``."""

    trial: Trial
    offset: tuple = (30.0, -40.0)
    recursive: bool = False
    seen: list = field(default_factory=list)

    def match(self, problem, rng):
        self.seen.append(problem)
        idx = np.searchsorted(self.trial.times, problem.times)
        return Fix(track=self.trial.truth[idx] + self.offset, evaluations=3, ambiguous=False)


@dataclass
class _IndicatedShift:
    """Moves whatever indicated track it is given by ``offset``; fails on leg ``fail_leg``."""

    offset: tuple = (3.0, 4.0)
    fail_leg: int = -1
    error: type = MatchError
    calls: int = 0

    def match(self, problem, rng):
        self.calls += 1
        if self.calls - 1 == self.fail_leg:
            raise self.error("no candidate on valid map data")
        return Fix(track=problem.indicated + self.offset, ambiguous=self.calls == 2)


def test_each_leg_ends_at_the_known_offset_and_resets_to_the_fix():
    trial = _trial()
    method = _TruthShift(trial)
    result = run_trial(method, trial, _GRID, np.random.default_rng(0))
    assert not result.failed and result.n_calls == 3 and result.evaluations == 9
    assert result.leg_errors_m == pytest.approx((50.0, 50.0, 50.0))
    assert result.end_error_m == pytest.approx(50.0)
    np.testing.assert_allclose(result.error, 50.0)
    assert result.mean_track_error_m == pytest.approx(
        50.0
    ) and result.max_track_error_m == pytest.approx(50.0)
    first, second = method.seen[0], method.seen[1]
    np.testing.assert_array_equal(first.indicated, trial.indicated[:5])
    np.testing.assert_array_equal(first.sigma_position, trial.sigma_position[:5])
    fix_end = trial.truth[4] + (30.0, -40.0)
    np.testing.assert_allclose(
        second.indicated, fix_end + trial.indicated[5:10] - trial.indicated[4]
    )
    sigma = trial.sigma_position
    expected = np.sqrt(sigma[0] ** 2 + sigma[5:10] ** 2 - sigma[4] ** 2)
    np.testing.assert_allclose(second.sigma_position, expected)
    np.testing.assert_array_equal(second.measured, trial.measured[5:10])


def test_reset_compounds_the_fixes_of_earlier_legs():
    trial = _trial()
    result = run_trial(_IndicatedShift(), trial, _GRID, np.random.default_rng(0))
    for k, part in enumerate(trial.leg_slices()):  # leg k is moved by k + 1 offsets
        expected = trial.indicated[part] + (k + 1) * np.array([3.0, 4.0])
        np.testing.assert_allclose(result.estimate[part], expected)
    assert result.end_error_m == pytest.approx(np.hypot(*(expected[-1] - trial.truth[-1])))
    assert result.ambiguous  # leg 1 was flagged


def test_recursive_method_gets_the_whole_mission_once():
    trial = _trial()
    method = _TruthShift(trial, recursive=True)
    result = run_trial(method, trial, _GRID, np.random.default_rng(0))
    assert result.n_calls == 1 and len(method.seen) == 1
    np.testing.assert_array_equal(method.seen[0].indicated, trial.indicated)
    assert result.leg_errors_m == pytest.approx((50.0, 50.0, 50.0))


def test_geofix_error_marks_the_trial_failed_and_keeps_earlier_legs():
    trial = _trial()
    result = run_trial(_IndicatedShift(fail_leg=2), trial, _GRID, np.random.default_rng(0))
    assert result.failed and "no candidate" in result.message
    assert result.n_calls == 3
    assert np.isfinite(result.leg_errors_m[:2]).all() and np.isnan(result.leg_errors_m[2])
    assert np.isnan(result.end_error_m) and np.isnan(result.mean_track_error_m)
    assert np.isnan(result.estimate[10:]).all()


def test_other_exceptions_propagate():
    with pytest.raises(ZeroDivisionError):
        run_trial(_IndicatedShift(fail_leg=0, error=ZeroDivisionError), _trial(), _GRID, None)


def test_method_rng_is_stable_and_depends_on_the_spec():
    a = method_rng(5, 2, "tercom:metric=mad").random(3)
    expected = np.random.default_rng([5, 2, zlib.crc32(b"tercom:metric=mad")]).random(3)
    np.testing.assert_array_equal(a, expected)
    assert not np.array_equal(a, method_rng(5, 2, "tercom").random(3))
    assert not np.array_equal(a, method_rng(5, 3, "tercom:metric=mad").random(3))


# ----------------------------------------------------------------------------- campaigns


@dataclass(frozen=True)
class JitterMethod:
    """A cheap random method: the indicated track moved by a random offset (metres)."""

    name: ClassVar[str] = "test_jitter"
    recursive: ClassVar[bool] = False
    scale: float = 200.0

    def match(self, problem, rng):
        return Fix(track=problem.indicated + rng.normal(0.0, self.scale, 2), evaluations=1)


_INTERRUPT = {"calls": 0, "stop_at": -1}


@dataclass(frozen=True)
class InterruptMethod(JitterMethod):
    """Like ``test_jitter``, but raises KeyboardInterrupt at call number ``stop_at``."""

    name: ClassVar[str] = "test_interrupt"

    def match(self, problem, rng):
        _INTERRUPT["calls"] += 1
        if _INTERRUPT["calls"] == _INTERRUPT["stop_at"]:
            raise KeyboardInterrupt
        return super().match(problem, rng)


@pytest.fixture(scope="module", autouse=True)
def _test_methods():
    """Register the two test methods for this module only (the registry is global)."""
    with pytest.MonkeyPatch.context() as mp:
        for cls in (JitterMethod, InterruptMethod):
            mp.setitem(registry._REGISTRY, cls.name, cls)
        yield


def _scenario(**track):
    spec = {"start_cell": [40, 40], "heading_deg": 45, "speed_m_s": 10.0, "interval_s": 100.0}
    spec.update({"samples": 8, "legs": 2, "turn_std_deg": 20.0, **track})
    return scenario_from_dict(
        {
            "name": "tiny",
            "map": {"path": "builtin:mb_1km"},
            "track": spec,
            "sensor": {"type": "singlebeam", "noise_std": 5.0},
            "ins": {"initial_error_std_m": 1500.0, "velocity_error_m_s": 0.1},
            "trials": 6,
            "seed": 7,
        }
    )


def _table(result):
    return result.frame.drop(columns=["time_s"])


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted in-process campaign."""
    out = tmp_path_factory.mktemp("reference")
    return run_campaign(_scenario(), ["tercom", "test_jitter"], jobs=1, out_dir=out, progress=None)


def test_summary_contract_and_files(reference):
    summary = reference.summary
    assert summary.scenario == "tiny" and summary.trials == 6
    assert list(summary.methods) == ["tercom", "test_jitter"]
    keys = {"trials", "mean_error_m", "std_error_m", "median_error_m", "max_error_m"}
    keys |= {"mean_track_error_m", "max_track_error_m", "success_rate", "mean_time_s"}
    keys |= {"failures"}
    stats = summary.methods["tercom"]
    assert keys <= set(stats.to_json())
    assert stats.trials == 6 and stats.failures == 0
    assert list(stats.success_rate) == ["20", "40", "60", "80", "100", "0.5c", "1c", "2c", "3c"]
    assert stats.mean_error_m < summary.methods["test_jitter"].mean_error_m
    assert json.loads(reference.paths["summary"].read_text()) == summary.to_json()
    assert CampaignSummary.from_json(summary.to_json()) == summary
    assert list(reference.frame["trial"]) == [*range(6), *range(6)]
    assert summary_table(summary).row_count == 2
    with ResultStore(reference.paths["store"].parent) as store:
        arrays = store.to_frame(reference.scenario_hash, arrays=True)
    assert arrays["estimate"][0].shape == (16, 2) and arrays["error"][0].shape == (16,)


def test_resume_after_interrupt_gives_the_uninterrupted_table(tmp_path, reference):
    methods = ["tercom", "test_interrupt"]
    full = run_campaign(_scenario(), methods, jobs=1, out_dir=tmp_path / "a", progress=None)
    _INTERRUPT.update(calls=0, stop_at=7)  # 2 legs a trial: first leg of trial 3
    with pytest.raises(KeyboardInterrupt):
        run_campaign(_scenario(), methods, jobs=1, out_dir=tmp_path / "b", progress=None)
    resumed = run_campaign(_scenario(), methods, jobs=1, out_dir=tmp_path / "b", progress=None)
    assert resumed.computed == 6  # trials 3..5 of both methods; 0..2 came from the store
    pd.testing.assert_frame_equal(_table(resumed), _table(full))
    # test_interrupt draws like test_jitter under its own spec: different numbers
    assert not np.allclose(full.frame["end_error_m"][6:], reference.frame["end_error_m"][6:])


def test_more_trials_extend_a_shorter_campaign(tmp_path, reference):
    methods = ["tercom", "test_jitter"]
    short = run_campaign(_scenario(), methods, trials=3, jobs=1, out_dir=tmp_path, progress=None)
    assert short.computed == 6 and short.trials == 3 and len(short.frame) == 6
    longer = run_campaign(_scenario(), methods, trials=6, jobs=1, out_dir=tmp_path, progress=None)
    assert longer.computed == 6
    pd.testing.assert_frame_equal(_table(longer), _table(reference))
    again = run_campaign(_scenario(), methods, jobs=1, out_dir=tmp_path, progress=None)
    assert again.computed == 0


def test_process_pool_gives_the_same_table(tmp_path, reference):
    pooled = run_campaign(
        _scenario(), ["tercom", "test_jitter"], jobs=2, out_dir=tmp_path, progress=None
    )
    assert pooled.computed == 12
    pd.testing.assert_frame_equal(_table(pooled), _table(reference))


def test_dask_cluster_gives_the_same_table(tmp_path, reference):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=1,
        threads_per_worker=1,
        processes=False,  # in-process ("inproc://" transport: no host to give)
        dashboard_address=None,
    ) as cluster:
        result = run_campaign(
            _scenario(),
            ["tercom", "test_jitter"],
            out_dir=tmp_path,
            scheduler=cluster,
            progress=None,
        )
    pd.testing.assert_frame_equal(_table(result), _table(reference))


def test_other_seed_gives_other_results(tmp_path, reference):
    other = run_campaign(
        _scenario(), ["test_jitter"], trials=2, seed=8, jobs=1, out_dir=tmp_path, progress=None
    )
    assert not np.allclose(other.frame["end_error_m"], reference.frame["end_error_m"][6:8])


@pytest.mark.parametrize(
    ("scenario", "methods", "error"),
    [
        (_scenario(), ["nonexistent_method"], ConfigError),
        (_scenario(), ["tercom:metric=bogus"], ConfigError),
        (_scenario(), [], ConfigError),
        (_scenario(start_cell=[150, 150]), ["tercom"], TrackOffMapError),
        (
            _scenario().model_copy(
                update={"map": _scenario().map.model_copy(update={"path": "no.nc"})}
            ),
            ["tercom"],
            MapError,
        ),
    ],
)
def test_errors_before_any_trial_create_no_store(tmp_path, scenario, methods, error):
    with pytest.raises(error):
        run_campaign(scenario, methods, jobs=1, out_dir=tmp_path / "out", progress=None)
    assert not (tmp_path / "out").exists()


@dataclass
class _ConfidentShift(_TruthShift):
    """As :class:`_TruthShift`, with a fix covariance."""

    covariance: tuple = ((900.0, 300.0), (300.0, 400.0))

    def match(self, problem, rng):
        fix = super().match(problem, rng)
        return Fix(track=fix.track, covariance=np.array(self.covariance), ambiguous=False)


def test_each_leg_starts_from_the_previous_fix_covariance_grown_by_the_ins():
    from geofix.evaluate.runner import fix_variance

    trial = _trial()
    sigma = trial.sigma_position
    method = _ConfidentShift(trial)
    fine = Grid(np.zeros((4, 4)), x0=0.0, y0=0.0, dx=10.0, dy=10.0)
    run_trial(method, trial, fine, np.random.default_rng(0))
    largest = np.linalg.eigvalsh(np.array(method.covariance))[-1]
    assert 25.0 < largest < sigma[4] ** 2  # inside the cell floor and the free-INS cap
    expected = np.sqrt(largest + sigma[5:10] ** 2 - sigma[4] ** 2)
    np.testing.assert_allclose(method.seen[1].sigma_position, expected)
    # a tiny covariance is floored at a quarter cell squared, a huge one capped by the INS
    assert fix_variance(np.eye(2), 100.0, 300.0, 80.0) == pytest.approx(2500.0)
    assert fix_variance(1e9 * np.eye(2), 100.0, 300.0, 80.0) == pytest.approx(9e4)
    assert fix_variance(None, 100.0, 300.0, 80.0) == pytest.approx(6400.0)
