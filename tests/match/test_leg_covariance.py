"""The INS drift inside a leg in a batch fix's covariance (geofix.match.drift)."""

import dataclasses

import numpy as np
import pytest

from geofix.evaluate.metrics import FALSE_FIX_CELLS, FALSE_FIX_SIGMAS, end_mahalanobis
from geofix.evaluate.runner import method_rng, run_trial
from geofix.maps import fractal_terrain
from geofix.match.drift import (
    increment_drift_covariance,
    information_weights,
    leg_drift_covariance,
    model_drift_covariance,
)
from geofix.match.tercom import Tercom
from geofix.nav.errstate import (
    DEG_PER_RT_H,
    MICRO_G,
    InsErrorModel,
    error_state,
    noise_factor,
)
from geofix.sim.scenario import scenario_from_dict
from geofix.sim.simulate import simulate_trial


def _relative_spread(draws: int) -> float:
    """Relative standard deviation of a sample variance of ``draws`` Gaussian values."""
    return float(np.sqrt(2.0 / (draws - 1)))


# ---------------------------------------------------------------- the formulas
@pytest.mark.parametrize("kind", ["equal", "scalar", "matrix"])
def test_increment_formula_matches_a_monte_carlo_random_walk(kind):
    rng = np.random.default_rng(11)
    n, draws = 40, 20000
    steps = rng.uniform(0.0, 9.0, n - 1)  # known increment variances, m^2 per axis
    steps[::7] = 0.0  # some steps without growth
    sigma = np.sqrt(25.0 + np.concatenate([[0.0], np.cumsum(steps)]))
    if kind == "equal":
        weights, w = None, np.broadcast_to(np.eye(2) / n, (n, 2, 2))
    elif kind == "scalar":
        weights = rng.uniform(0.1, 1.0, n)
        weights /= weights.sum()
        w = weights[:, None, None] * np.eye(2)
    else:
        a = rng.normal(size=(n, 2, 2))
        info = a @ a.transpose(0, 2, 1)
        w = np.linalg.inv(info.sum(axis=0)) @ info
        weights = w
    predicted = increment_drift_covariance(sigma, weights)
    start = 5.0 * rng.standard_normal((draws, 1, 2))  # cancels: common to every sample
    walk = np.sqrt(steps)[None, :, None] * rng.standard_normal((draws, n - 1, 2))
    e = start + np.concatenate([np.zeros((draws, 1, 2)), np.cumsum(walk, axis=1)], axis=1)
    r = e[:, -1] - np.einsum("kab,ikb->ia", w, e)
    empirical = np.cov(r.T)
    tol = 4 * _relative_spread(draws)
    np.testing.assert_allclose(np.diag(empirical), np.diag(predicted), rtol=tol)
    scale = np.sqrt(predicted[0, 0] * predicted[1, 1])
    assert abs(empirical[0, 1] - predicted[0, 1]) < 4 * scale / np.sqrt(draws)


def test_increment_formula_with_equal_weights_is_the_share_before_each_step():
    sigma = np.sqrt(np.array([4.0, 4.0, 6.0, 7.0, 7.0, 11.0]))
    n = sigma.size
    expected = sum(s * (j / n) ** 2 for j, s in enumerate(np.diff(sigma**2), start=1))
    np.testing.assert_allclose(increment_drift_covariance(sigma), expected * np.eye(2))


def test_no_growth_gives_no_drift():
    assert not increment_drift_covariance(np.full(30, 40.0)).any()
    times = 10.0 * np.arange(30)
    still = InsErrorModel(initial_offset=(300.0, -200.0), initial_std=50.0)
    track = np.column_stack([np.zeros(30), 5.0 * times])
    assert not model_drift_covariance(still, times, track).any()
    assert not model_drift_covariance(still, times + 600.0, track).any()


def test_velocity_ramp_gives_sigma_v_times_half_the_duration():
    n, dt, v = 60, 20.0, 0.04
    times = dt * np.arange(n)
    track = np.column_stack([3.0 * times, 4.0 * times])
    ramp = InsErrorModel(schuler=False, velocity_error=v)
    expected = v**2 / 2 * ((n - 1) * dt / 2) ** 2  # per-axis variance of v, times (T/2)^2
    for start in (0.0, 900.0):  # a later leg: the velocity error is the same ramp
        cov = model_drift_covariance(ramp, times + start, track)
        np.testing.assert_allclose(cov, expected * np.eye(2), rtol=1e-9, atol=1e-9)


def _simulated_errors(es, rng, draws):
    """``(draws, n, 2)`` position errors of the linear model, Gaussian draws."""
    x = rng.standard_normal((draws, es.dim)) @ noise_factor(es.prior_cov).T
    out = [x @ es.position_map.T]
    for f, q in zip(es.transitions, es.process_cov, strict=True):
        x = x @ f.T + rng.standard_normal((draws, es.dim)) @ noise_factor(q).T
        out.append(x @ es.position_map.T)
    return np.stack(out, axis=1)


def test_model_formula_matches_a_monte_carlo_of_the_error_state():
    rng = np.random.default_rng(5)
    model = InsErrorModel(
        velocity_error=0.04,
        accel_bias=100 * MICRO_G,
        heading_error=np.radians(0.05),
        accel_psd=(20 * MICRO_G) ** 2,
        gyro_psd=(0.002 * DEG_PER_RT_H) ** 2,
    )
    times = 20.0 * np.arange(150)
    track = 10.0 * times[:, None] * np.array([np.sin(1.2), np.cos(1.2)])
    es = error_state(model, times, track)
    leg = slice(90, 150)  # a later leg, after 1800 s of free drift
    n = leg.stop - leg.start
    weights = rng.uniform(0.2, 1.0, n)
    weights /= weights.sum()
    predicted = model_drift_covariance(model, times[leg], track[leg], weights)
    draws = 6000
    e = _simulated_errors(es, rng, draws)[:, leg]
    r = e[:, -1] - np.einsum("k,ikb->ib", weights, e)
    empirical = np.cov(r.T)
    np.testing.assert_allclose(
        np.diag(empirical), np.diag(predicted), rtol=4 * _relative_spread(draws)
    )
    # the independent-increment model of the same growth is the cruder (larger) one
    position = es.position_map @ _state_covs(es) @ es.position_map.T
    sigma = np.sqrt(np.trace(position, axis1=1, axis2=2) / 2)
    assert np.trace(increment_drift_covariance(sigma[leg], weights)) > np.trace(predicted)


def _state_covs(es):
    """``(n, d, d)`` state covariances of the free-running navigator."""
    p = es.prior_cov
    out = [p]
    for f, q in zip(es.transitions, es.process_cov, strict=True):
        p = f @ p @ f.T + q
        out.append(p)
    return np.stack(out)


# ---------------------------------------------------------------- the weights
def _synthetic_trial(grid, velocity_error=0.1, samples=120, index=0, seed=4):
    data = {
        "name": "drift-synth",
        "map": {"path": "builtin:mb_1km"},  # the scenario's own map is not used below
        "track": {
            "start_cell": [80, 60],
            "start_jitter_m": 30,
            "heading_deg": 30,
            "speed_m_s": 2,
            "interval_s": 10,
            "samples": samples,
        },
        "sensor": {"type": "multibeam", "beams": 11, "swath_width_m": 100, "noise_std": 0.5},
        "ins": {
            "initial_error_m": [60, -40],
            "initial_error_std_m": 20,
            "velocity_error_m_s": velocity_error,
        },
        "trials": 8,
        "seed": seed,
    }
    scenario = scenario_from_dict(data)
    return scenario, simulate_trial(scenario, grid, index)


@pytest.fixture(scope="module")
def rough_grid():
    """A 300 x 300 fractal seabed, 10 m cells, depth std 8 m."""
    return fractal_terrain((300, 300), 10.0, rng=np.random.default_rng(7), std=8.0)


def test_information_weights_sum_to_identity(rough_grid):
    _, trial = _synthetic_trial(rough_grid, samples=40)
    problem = trial.problem(rough_grid)
    w = information_weights(problem, trial.truth)
    assert w.shape == (problem.n, 2, 2)
    np.testing.assert_allclose(w.sum(axis=0), np.eye(2), atol=1e-12)
    flat = dataclasses.replace(rough_grid, values=np.full_like(rough_grid.values, -100.0))
    w_flat = information_weights(dataclasses.replace(problem, grid=flat), trial.truth)
    np.testing.assert_allclose(w_flat, np.broadcast_to(np.eye(2) / problem.n, w_flat.shape))


# ---------------------------------------------------------------- TERCOM
def test_tercom_covariance_is_unchanged_on_a_leg_without_drift(rough_grid):
    _, trial = _synthetic_trial(rough_grid, velocity_error=0.0, samples=60)
    problem = trial.problem(rough_grid)
    assert problem.ins_model is not None
    fix = Tercom().match(problem)
    assert not fix.diagnostics["drift_covariance"].any()
    bare = dataclasses.replace(problem, ins_model=None)
    np.testing.assert_array_equal(Tercom().match(bare).covariance, fix.covariance)


def test_tercom_is_consistent_on_legs_without_drift(rough_grid):
    """Sub-cell start errors, no drift: the NEES of TERCOM's own covariance is about 2."""
    nees = []
    for index in range(16):
        scenario, trial = _synthetic_trial(rough_grid, velocity_error=0.0, samples=40, index=index)
        result = run_trial(Tercom(), trial, rough_grid, method_rng(scenario.seed, index, "tercom"))
        e = result.estimate[-1] - trial.truth[-1]
        nees.append(end_mahalanobis(e, result.covariance) ** 2)
    # quantisation-dominated: per axis 12 u^2 with u uniform in a cell, mean 1, variance 0.8;
    # the mean of 16 sums of two lies within 2 +- 3 * sqrt(1.6 / 16)
    assert 1.0 < np.mean(nees) < 3.0


def test_tercom_on_a_drifting_leg_is_consistent_and_gives_no_false_fix(rough_grid):
    nees, own_nees, false_fixes = [], [], 0
    independent = Tercom(correlated_residuals=False)
    for index in range(8):
        scenario, trial = _synthetic_trial(rough_grid, index=index)
        rng = method_rng(scenario.seed, index, "tercom")
        result = run_trial(Tercom(), trial, rough_grid, rng)
        e = result.estimate[-1] - trial.truth[-1]
        distance = end_mahalanobis(e, result.covariance)
        bare = run_trial(independent, trial, rough_grid, rng)
        drift = leg_drift_covariance(trial.problem(rough_grid), bare.estimate)
        own_nees.append(end_mahalanobis(e, bare.covariance - drift) ** 2)
        nees.append(distance**2)
        far = np.hypot(*e) > FALSE_FIX_CELLS * rough_grid.cell_size
        false_fixes += bool(far and not result.ambiguous and distance > FALSE_FIX_SIGMAS)
    # every value taken as independent and without the drift term, the fix claims far too much
    assert np.median(own_nees) > 20
    assert np.median(nees) <= 5
    assert false_fixes == 0
