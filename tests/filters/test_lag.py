"""The declared gravimeter lag: undone once, causally, by every recursive filter."""

import dataclasses

import numpy as np
import pytest

from conftest import gravity_dvl_mission_data
from geofix.errors import ConfigError
from geofix.evaluate.runner import method_rng, run_trial
from geofix.filters.base import observations
from geofix.match.abc import AbcMhd
from geofix.methods import parse_method_spec
from geofix.sim.scenario import scenario_from_dict
from geofix.sim.simulate import prepare_map, simulate_trial

LAG_S = 60.0


def _gravity_mission(lag_s: float):
    """Source 003's lagged mission (Gulf of Alaska gravity, 20 s samples), shortened."""
    data = gravity_dvl_mission_data(f"lag-{lag_s:g}", sensor={"lag_s": lag_s})
    return scenario_from_dict(data)


@pytest.fixture(scope="module")
def missions():
    lagged, unlagged = _gravity_mission(LAG_S), _gravity_mission(0.0)
    grid = prepare_map(lagged)
    pairs = [(simulate_trial(lagged, grid, i), simulate_trial(unlagged, grid, i)) for i in range(4)]
    return grid, pairs


def test_the_problem_declares_the_lag_and_the_observations_undo_it(missions):
    grid, pairs = missions
    lagged, unlagged = pairs[0]
    problem = lagged.problem(grid)
    assert problem.lag_s == LAG_S and unlagged.problem(grid).lag_s == 0.0
    values = np.array([o.values for o in observations(problem)])
    # noise and map error enter before the lag: the compensated readings are the unlagged
    np.testing.assert_allclose(values, lagged.unlagged_measured, atol=1e-9)
    np.testing.assert_allclose(values, unlagged.measured, atol=1e-9)
    assert np.abs(problem.measured - unlagged.measured).max() > 1.0  # the lag is real
    raw = dataclasses.replace(problem, lag_s=0.0)
    np.testing.assert_array_equal(np.array([o.values for o in observations(raw)]), raw.measured)


def _end_errors(spec, trials, grid, seed=3):
    method = parse_method_spec(spec)
    out = []
    for i, trial in enumerate(trials):
        result = run_trial(method, trial, grid, method_rng(seed, i, spec))
        out.append(float(np.hypot(*(result.estimate[-1] - trial.truth[-1]))))
    return np.array(out)


def _rms_and_spread(errors):
    """RMS of end errors and its 1-sigma sampling spread (delta method), metres."""
    sq = np.asarray(errors) ** 2
    rms = float(np.sqrt(sq.mean()))
    return rms, float(sq.std(ddof=1) / np.sqrt(sq.size) / (2.0 * rms))


# the exact map model: an adaptive one absorbs much of an uncompensated lag into its
# noise scale and offset, so the lag's harm is measured where nothing else hides it
@pytest.mark.parametrize("spec", ["pmf:map_model=exact", "mpf:particles=2000,map_model=exact"])
def test_compensated_filters_end_as_on_the_unlagged_mission(missions, spec):
    grid, pairs = missions
    lagged = [a for a, _ in pairs]
    clean = _end_errors(spec, [b for _, b in pairs], grid)
    comp = _end_errors(spec, lagged, grid)
    raw = _end_errors(spec, [dataclasses.replace(a, lag_s=0.0) for a in lagged], grid)
    rms_clean, spread = _rms_and_spread(clean)
    rms_comp, spread_comp = _rms_and_spread(comp)
    assert abs(rms_comp - rms_clean) < 2.0 * np.hypot(spread, spread_comp)
    # without the compensation the lagged readings pull every filter well off
    assert _rms_and_spread(raw)[0] > rms_clean + 2.0 * spread


def test_abc_mhd_keeps_its_own_lag_setting(missions):
    grid, pairs = missions
    lagged, unlagged = pairs[0]
    problem = lagged.problem(grid)
    # the problem's declared lag is not applied a second time
    np.testing.assert_allclose(AbcMhd(lag_s=LAG_S)._measured(problem), unlagged.measured)
    np.testing.assert_array_equal(AbcMhd()._measured(problem), problem.measured)


def test_a_negative_lag_is_refused(missions):
    grid, pairs = missions
    with pytest.raises(ConfigError, match="lag_s"):
        dataclasses.replace(pairs[0][0].problem(grid), lag_s=-1.0)


def test_the_navigator_undoes_the_lag_ping_by_ping_as_the_campaign_does(missions):
    from geofix.navigator import Navigator, NavigatorSettings

    grid, pairs = missions
    lagged, _ = pairs[1]
    seen = {}
    for lag in (LAG_S, 0.0):
        settings = NavigatorSettings(noise_std=1.0, lag_s=lag, max_pose_gap_s=None)
        nav = Navigator(grid, "pmf", settings, seed=1)
        values = seen.setdefault(lag, [])
        update = nav.update

        def spy(obs, t, update=update, values=values):
            values.append(obs.values.copy())  # what the filter's update is handed
            return update(obs, t)

        nav.update = spy
        nav.init(lagged.times[0], lagged.indicated[0], 300.0, lagged.indicated_heading[0])
        for k in range(12):
            if k:
                nav.motion(lagged.times[k], lagged.indicated[k], lagged.indicated_heading[k])
            nav.measure(lagged.times[k], [[0.0, 0.0, lagged.measured[k, 0]]])
    got = np.ravel(seen[LAG_S])
    np.testing.assert_allclose(got, lagged.unlagged_measured[:12, 0], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(np.ravel(seen[0.0]), lagged.measured[:12, 0])
    with pytest.raises(ConfigError, match="lag_s"):
        NavigatorSettings(lag_s=-5.0)
