"""The error-state point-mass filter folds in an aiding DVL (``pmf:model=errstate``)."""

import numpy as np

from conftest import gravity_dvl_mission_data
from geofix.evaluate.runner import method_rng, run_trial
from geofix.filters.motion import dvl_update
from geofix.methods import parse_method_spec
from geofix.sim.scenario import scenario_from_dict
from geofix.sim.simulate import prepare_map, simulate_trial


def test_dvl_node_likelihood_and_kalman_update_agree():
    rng = np.random.default_rng(3)
    a = rng.standard_normal((5, 5))
    sigma = a @ a.T + 0.5 * np.eye(5)
    mu = rng.standard_normal(5)
    c = rng.standard_normal((2, 5))
    c[:, :2] *= 0.1  # a velocity that sees the position error only weakly
    y = c @ mu + np.array([0.7, -0.4])
    # the dp posterior on a fine grid: Gaussian prior times the nodes' DVL likelihood
    sd = np.sqrt(np.diag(sigma)[:2])
    axes = [np.linspace(m - 6 * s, m + 6 * s, 301) for m, s in zip(mu[:2], sd, strict=True)]
    dp = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    log_like, (mu_post, sigma_post) = dvl_update(mu, sigma, c, 0.2, y, dp)
    d = dp - mu[:2]
    log_prior = -0.5 * np.einsum("...i,ij,...j->...", d, np.linalg.inv(sigma[:2, :2]), d)
    w = np.exp(log_prior + log_like - (log_prior + log_like).max())
    w /= w.sum()
    mean = np.einsum("ij,ijk->k", w, dp)
    e = dp - mean
    cov = np.einsum("ij,ijk,ijl->kl", w, e, e)
    # ... is the dp marginal of the Kalman update of the joint
    np.testing.assert_allclose(mean, mu_post[:2], atol=1e-3 * sd.max())
    np.testing.assert_allclose(cov, sigma_post[:2, :2], rtol=2e-3, atol=1e-6)


def _gravity_dvl_mission():
    """Source 003's mission (Gulf of Alaska gravity, a free INS aided by a DVL), shortened."""
    return scenario_from_dict(gravity_dvl_mission_data("pmf-dvl", trials=5))


def test_errstate_pmf_with_the_dvl_ends_closer_and_as_mpf():
    scen = _gravity_dvl_mission()
    grid = prepare_map(scen)
    trials = [simulate_trial(scen, grid, i) for i in range(5)]
    assert trials[0].dvl_velocity is not None

    def end_rms(spec):
        method = parse_method_spec(spec)
        sq = []
        for i, trial in enumerate(trials):
            result = run_trial(method, trial, grid, method_rng(scen.seed, i, spec))
            sq.append(np.sum((result.estimate[-1] - trial.truth[-1]) ** 2))
        return float(np.sqrt(np.mean(sq)))

    with_dvl = end_rms("pmf:model=errstate,map_model=exact")  # the map is the seabed
    without = end_rms("pmf:model=errstate,use_dvl=false,map_model=exact")
    mpf = end_rms("mpf:particles=2000,map_model=exact")
    assert with_dvl < 0.85 * without
    # the grid and the particles carry the same model: their errors agree
    assert abs(with_dvl - mpf) < 0.25 * mpf
