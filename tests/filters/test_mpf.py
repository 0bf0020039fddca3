"""Marginalised particle filter: the INS error state carried, consistency, DVL, errors."""

import numpy as np
import pytest

from conftest import small_mission_data
from geofix.errors import ConfigError, MatchError
from geofix.evaluate.crlb import scenario_beam_variance, trial_crlb
from geofix.evaluate.metrics import end_mahalanobis
from geofix.evaluate.runner import method_rng, run_trial
from geofix.methods import parse_method_spec
from geofix.sim.scenario import scenario_from_dict
from geofix.sim.simulate import prepare_map, simulate_trial

DRIFT_INS = {"initial_error_std_m": 300.0, "velocity_error_m_s": 0.05, "accel_bias_ug": 150.0}


def _drift_scenario(**changes):
    data = small_mission_data(
        "mpf-drift",
        track={"samples": 50, "interval_s": 40, "start_cell": [40, 40], "speed_m_s": 8},
        ins=DRIFT_INS,
        trials=8,
        **changes,
    )
    return scenario_from_dict(data)


def _run(scen, specs, trials):
    grid = prepare_map(scen)
    out = {s: [] for s in specs}
    bounds = []
    for i in range(trials):
        trial = simulate_trial(scen, grid, i)
        bounds.append(trial_crlb(trial, grid, scenario_beam_variance(scen, trial.offsets)))
        for spec in specs:
            result = run_trial(parse_method_spec(spec), trial, grid, method_rng(scen.seed, i, spec))
            e = result.estimate[-1] - trial.truth[-1]
            out[spec].append((e, end_mahalanobis(e, result.covariance)))
    crlb = np.sqrt(np.mean([b.recursive_var_m2 for b in bounds]))
    return out, crlb


def _rms(rows):
    return float(np.sqrt(np.mean([e @ e for e, _ in rows])))


def test_error_state_filters_follow_a_drifting_ins_far_better_than_the_random_walk_ones():
    scen = _drift_scenario()
    specs = ["pf:particles=2000", "mpf:particles=2000", "pmf:model=errstate"]
    out, crlb = _run(scen, specs, 8)
    pf, mpf, pmf = (_rms(out[s]) for s in specs)
    # the bound on this mission is about 35 m; the random-walk PF ends near 5x that
    assert mpf < 0.7 * pf and pmf < 0.7 * pf
    assert mpf < 1.6 * crlb and pmf < 1.6 * crlb
    nees = np.mean([d**2 for _, d in out["mpf:particles=2000"]])
    # 8 trials of a chi-square(2) mean: 2 +- 0.7 (1 sigma); allow the filter's own slack
    assert 0.5 < nees < 5.0


def test_mpf_needs_the_ins_model_and_checks_its_settings(small_mission):
    scen = small_mission("mpf-bad")
    grid = prepare_map(scen)
    trial = simulate_trial(scen, grid, 0)
    problem = trial.problem(grid)
    stripped = type(problem)(**{**problem.__dict__, "ins_model": None, "dvl_velocity": None})
    with pytest.raises(MatchError, match="INS error model"):
        parse_method_spec("mpf").match(stripped, np.random.default_rng(0))
    with pytest.raises(ConfigError, match="particles"):
        parse_method_spec("mpf:particles=5")


def test_mpf_seeded_runs_repeat(small_mission):
    scen = small_mission("mpf-seed")
    grid = prepare_map(scen)
    problem = simulate_trial(scen, grid, 1).problem(grid)
    m = parse_method_spec("mpf:particles=500")
    a = m.match(problem, np.random.default_rng(2)).track
    b = m.match(problem, np.random.default_rng(2)).track
    np.testing.assert_array_equal(a, b)


def test_marginal_replacement_and_conditional_motion_of_a_gaussian():
    from geofix.filters._pmf_errstate import conditional_motion, replace_marginal

    rng = np.random.default_rng(0)
    a = rng.normal(size=(5, 5))
    sigma = a @ a.T + np.eye(5)
    mu = rng.normal(size=5)
    # the same marginal gives back the same Gaussian
    same_mu, same_sigma = replace_marginal(mu, sigma, mu[:2], sigma[:2, :2])
    np.testing.assert_allclose(same_mu, mu)
    np.testing.assert_allclose(same_sigma, sigma)
    # a Gaussian measurement of dp: the marginal replacement is the Kalman update
    r = np.diag([0.5, 2.0])
    z = np.array([0.3, -1.0])
    h = np.zeros((2, 5))
    h[0, 0] = h[1, 1] = 1.0
    gain = sigma @ h.T @ np.linalg.inv(h @ sigma @ h.T + r)
    kf_mu, kf_sigma = mu + gain @ (z - h @ mu), (np.eye(5) - gain @ h) @ sigma
    new_mu, new_sigma = replace_marginal(mu, sigma, kf_mu[:2], kf_sigma[:2, :2])
    np.testing.assert_allclose(new_mu, kf_mu)
    np.testing.assert_allclose(new_sigma, kf_sigma, atol=1e-12)
    # E[dp' | dp] and Cov[dp' | dp] of x' = F x + w, checked on the joint Gaussian
    f = np.eye(5) + 0.1 * rng.normal(size=(5, 5))
    q = 0.01 * np.eye(5)
    g, shift, k = conditional_motion(mu, sigma, f, q)
    joint_mu = np.concatenate([mu[:2], f[:2] @ mu])
    cross = sigma[:2] @ f[:2].T
    joint = np.block([[sigma[:2, :2], cross], [cross.T, f[:2] @ sigma @ f[:2].T + q[:2, :2]]])
    reg = np.linalg.solve(joint[:2, :2], joint[:2, 2:]).T
    np.testing.assert_allclose(g, reg)
    np.testing.assert_allclose(shift, joint_mu[2:] - reg @ joint_mu[:2])
    np.testing.assert_allclose(k, joint[2:, 2:] - reg @ joint[:2, 2:])
