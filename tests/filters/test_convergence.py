"""The KL term of the convergence test: known Gaussian, known bimodal, and the navigator's use."""

from dataclasses import replace

import numpy as np
import pytest
from scipy import integrate, stats
from scipy.special import logsumexp

from geofix import Navigator
from geofix.filters.convergence import kl_grid, kl_to_gaussian, posterior_kl

SX, SY = 30.0, 10.0  # one mode's standard deviations, metres


def lattice(half_sigmas=8.0, nodes=81):
    u = np.linspace(-half_sigmas, half_sigmas, nodes)
    gx, gy = np.meshgrid(u * SX, u * SY, indexing="ij")
    area = (u[1] - u[0]) ** 2 * SX * SY
    return np.column_stack([gx.ravel(), gy.ravel()]), area


def bimodal_density(points, d):
    """Two equal modes at ``(+-d SX, 0)``, each ``N(., diag(SX^2, SY^2))``."""
    zx, zy = points[:, 0] / SX, points[:, 1] / SY
    return np.exp(-0.5 * ((zx - d) ** 2 + zy**2)) + np.exp(-0.5 * ((zx + d) ** 2 + zy**2))


def bimodal_kl(d):
    """Exact ``KL`` (nats) of the mixture to its moment-matched Gaussian: only the x axis
    differs from a Gaussian, so it is the 1-D ``KL`` of ``0.5 N(-d, 1) + 0.5 N(d, 1)`` to
    ``N(0, 1 + d^2)``."""

    def p(x):
        return 0.5 * (stats.norm.pdf(x, -d) + stats.norm.pdf(x, d))

    q = stats.norm(0.0, np.sqrt(1.0 + d * d))
    value, _ = integrate.quad(lambda x: p(x) * (np.log(p(x)) - q.logpdf(x)), -d - 12, d + 12)
    return value


def test_a_gaussian_grid_and_sample_have_no_divergence(rng):
    points, area = lattice()
    cov = np.array([[SX**2, 0.5 * SX * SY], [0.5 * SX * SY, SY**2]])
    w = stats.multivariate_normal([0.0, 0.0], cov).pdf(points)
    assert kl_grid(points, w, area) < 1e-6
    sample = rng.multivariate_normal([100.0, -50.0], cov, 5000)
    # plug-in bias removed: what is left is of the order of the sampling spread (~0.01)
    assert kl_to_gaussian(sample, np.ones(5000), sample=True) < 0.02
    assert kl_to_gaussian(sample, np.ones(5000), sample=False) > 0.01  # the bias it removes


@pytest.mark.parametrize("d", [2.0, 3.0])
def test_a_bimodal_grid_gives_the_exact_divergence(d):
    points, area = lattice()
    exact = bimodal_kl(d)
    assert kl_grid(points, bimodal_density(points, d), area) == pytest.approx(exact, abs=2e-3)


def test_a_bimodal_sample_gives_a_binned_lower_bound(rng):
    d, m = 3.0, 20000
    exact = bimodal_kl(d)
    centres = np.where(rng.random(m) < 0.5, -d, d) * SX
    sample = np.column_stack([centres + SX * rng.standard_normal(m), SY * rng.standard_normal(m)])
    estimate = kl_to_gaussian(sample, np.ones(m), sample=True)
    # binning can only lower it (data processing); 0.5-sigma bins keep most of it
    assert 0.8 * exact < estimate < exact + 0.01
    assert estimate > 0.2  # the default converge_kl_nats refuses it


def test_the_navigator_refuses_convergence_on_a_bimodal_posterior(synthetic_grid):
    loose = {"converge_sigma_m": 1e6, "converge_mle_m": 1e6}
    nav = Navigator(synthetic_grid, "pmf", loose)
    nav.init(0.0, (600.0, 500.0), 40.0)
    state = nav.state
    _, axes, spacing = state.frame
    n0, n1 = state.shape
    i, j = np.meshgrid(np.arange(n0), np.arange(n1), indexing="ij")
    u = np.stack([i.ravel(), j.ravel()], axis=1) - 0.5 * (np.array([n0, n1]) - 1)
    rel = (u * spacing) @ axes.T
    sd = 0.5 * (min(n0, n1) - 1) * spacing.min() / 12.0  # one mode's sigma: well inside
    zx, zy = rel[:, 0] / sd, rel[:, 1] / sd
    log_dens = np.logaddexp(-0.5 * ((zx - 3) ** 2 + zy**2), -0.5 * ((zx + 3) ** 2 + zy**2))
    log_weight = (log_dens - logsumexp(log_dens)).reshape(n0, n1)
    nav.state = replace(state, log_weight=log_weight)
    nav._accepted_count = 1  # as after one accepted ping
    nav.consistency = lambda *args, **kwargs: None  # only the KL term here (the others:
    # tests/filters/test_navigator_honesty.py)
    est = nav._describe(0.0, float("nan"), True)
    assert est.status == "converging" and est.kl_nats > 0.3
    assert posterior_kl(nav.state) == pytest.approx(est.kl_nats)
    unimodal = -0.5 * (zx**2 + zy**2)
    nav.state = replace(state, log_weight=(unimodal - logsumexp(unimodal)).reshape(n0, n1))
    est = nav._describe(0.0, float("nan"), True)
    assert est.status == "converged" and est.kl_nats < 0.01
    assert est.to_dict()["kl_nats"] == pytest.approx(est.kl_nats)
