"""The particle filter on the INS error state (``pf:model=errstate``, the default with an INS)."""

import dataclasses

import numpy as np
import pytest

from conftest import gravity_dvl_mission_data
from geofix.errors import MatchError
from geofix.evaluate.runner import method_rng, run_trial
from geofix.methods import parse_method_spec
from geofix.sim.scenario import scenario_from_dict
from geofix.sim.simulate import prepare_map, simulate_trial

TRIALS = 6


@pytest.fixture(scope="module")
def mission():
    """Source 003's drifting free INS aided by a DVL (Gulf of Alaska gravity), shortened."""
    scen = scenario_from_dict(gravity_dvl_mission_data("pf-errstate", trials=TRIALS))
    grid = prepare_map(scen)
    return scen, grid, [simulate_trial(scen, grid, i) for i in range(TRIALS)]


def _ends(mission, spec):
    """End errors (m) and NEES of ``spec`` over the mission's trials."""
    scen, grid, trials = mission
    method = parse_method_spec(spec)
    errors, nees = [], []
    for i, trial in enumerate(trials):
        result = run_trial(method, trial, grid, method_rng(scen.seed, i, spec))
        e = result.estimate[-1] - trial.truth[-1]
        errors.append(float(np.hypot(*e)))
        nees.append(float(e @ np.linalg.solve(result.covariance, e)))
    return np.array(errors), np.array(nees)


def test_the_default_pf_takes_the_error_state_and_agrees_with_the_point_mass_filter(mission):
    pf_errors, pf_nees = _ends(mission, "pf")
    pmf_errors, _ = _ends(mission, "pmf:model=errstate")
    rw_errors, _ = _ends(mission, "pf:model=rw")
    rms = float(np.sqrt(np.mean(pf_errors**2)))
    pmf_rms = float(np.sqrt(np.mean(pmf_errors**2)))
    # the same model on particles and on a grid: their errors agree ...
    assert abs(rms - pmf_rms) < 0.3 * pmf_rms, (rms, pmf_rms)
    # ... the random walk, which cannot follow the INS drift, ends farther off ...
    assert rms < 0.8 * float(np.sqrt(np.mean(rw_errors**2)))
    # ... and the covariance holds: a 2-dof chi-square median is 1.39; 6 trials spread it
    assert 0.2 < np.median(pf_nees) < 5.0, pf_nees


def test_the_dvl_brings_the_error_state_pf_closer(mission):
    with_dvl, _ = _ends(mission, "pf:model=errstate")
    without, _ = _ends(mission, "pf:model=errstate,use_dvl=false")
    assert np.sqrt(np.mean(with_dvl**2)) < 0.85 * np.sqrt(np.mean(without**2))


def test_the_model_setting_is_checked_and_auto_needs_no_ins(mission):
    _, grid, trials = mission
    problem = trials[0].problem(grid)
    no_ins = dataclasses.replace(problem, ins_model=None)
    rng = np.random.default_rng(0)
    assert parse_method_spec("pf").initialize(no_ins, rng).track is None
    assert parse_method_spec("pf").initialize(problem, rng).track is not None
    assert parse_method_spec("pf:model=rw").initialize(problem, rng).track is None
    with pytest.raises(MatchError, match="INS error model"):
        parse_method_spec("pf:model=errstate").initialize(no_ins, rng)
    assert parse_method_spec("pf:model=errstate").needs_ins_model
    assert not parse_method_spec("pf").needs_ins_model
    with pytest.raises(Exception, match="model must be auto, rw or errstate"):
        parse_method_spec("pf:model=kalman")


def test_a_set_collapsed_onto_one_point_still_moves(mission):
    from geofix.filters.base import motions
    from geofix.filters.particle_motion import error_state_predict

    _, grid, trials = mission
    problem = trials[0].problem(grid)
    state = parse_method_spec("pf").initialize(problem, np.random.default_rng(1))
    collapsed = np.repeat(problem.indicated[:1], 50, axis=0)
    moments = (collapsed[0].copy(), np.zeros((2, 2)))  # every particle at one point
    moved, track = error_state_predict(
        collapsed, moments, state.track, motions(problem)[0], np.random.default_rng(2)
    )
    assert np.isfinite(moved).all() and track.step == 1
    # every particle moved by about the INS displacement (the drift learnt so far is none)
    step = problem.indicated[1] - problem.indicated[0]
    assert np.allclose(moved.mean(axis=0) - collapsed[0], step, atol=0.05 * np.hypot(*step))
