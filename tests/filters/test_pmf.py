"""Point-mass filter: the Kalman posterior on a plane, log-space robustness, a real map."""

from importlib import resources

import numpy as np
import pytest

from geofix.errors import ConfigError, MatchError
from geofix.filters import _grid_ops as ops
from geofix.filters.base import motions, observations, run_filter
from geofix.filters.pmf import Pmf, node_field_variance
from geofix.maps.synthetic import fractal_terrain, planar_grid
from geofix.match.base import MatchProblem, footprint_xy
from geofix.match.registry import parse_method_spec

SLOPE = np.array([0.04, -0.015])  # mGal per metre: a strong, gravity-like plane
OFFSETS = np.array([[-60.0, 0.0], [0.0, 0.0], [60.0, 0.0]])  # three beams across track


def _plane_problem(rng, n=6, sigma0=30.0, q=4.0, noise=1.0, offsets=OFFSETS):
    """A mission over a tilted plane: truth, INS offset, beams, Gaussian noise."""
    grid = planar_grid((120, 120), 10.0, *SLOPE, offset=20.0, kind="gravity")
    heading = np.full(n, np.radians(35.0))
    truth = np.array([500.0, 450.0]) + np.arange(n)[:, None] * 25.0 * np.array(
        [np.sin(heading[0]), np.cos(heading[0])]
    )
    indicated = truth + np.array([18.0, -12.0])
    x, y = footprint_xy(truth, heading, offsets)
    measured = grid.sample(x, y) + rng.normal(0.0, noise, x.shape)
    return MatchProblem(
        grid=grid,
        indicated=indicated,
        heading=heading,
        offsets=offsets,
        measured=measured,
        sigma_position=np.sqrt(sigma0**2 + q * np.arange(n)),
        times=np.arange(n) * 10.0,
        noise_std=noise,
        sensor="gravimeter",
    )


def _kalman(problem):
    """The exact posterior of the linear-Gaussian case, hand-written, at every sample."""
    grid = problem.grid
    mean = problem.indicated[0].astype(float)
    cov = problem.sigma_position[0] ** 2 * np.eye(2)
    obs, steps = observations(problem), motions(problem)
    means, covs = [], []
    for k in range(problem.n):
        if k:
            mean = mean + steps[k - 1].displacement
            cov = cov + steps[k - 1].process_var * np.eye(2)
        x, y = footprint_xy(mean[None], problem.heading[k : k + 1], problem.offsets)
        predicted = grid.sample(x, y)[0]
        h = np.tile(SLOPE, (problem.beams, 1))
        s = h @ cov @ h.T + obs[k].noise_var * np.eye(problem.beams)
        gain = cov @ h.T @ np.linalg.inv(s)
        mean = mean + gain @ (problem.measured[k] - predicted)
        cov = (np.eye(2) - gain @ h) @ cov
        means.append(mean)
        covs.append(cov)
    return np.array(means), np.array(covs)


@pytest.mark.parametrize(("discretisation_noise", "tol"), [(False, 0.01), (True, 0.03)])
def test_posterior_equals_kalman_on_a_plane(discretisation_noise, tol):
    # tol: whitened error of the mean and of the covariance; with the node-field variance
    # the likelihood is slightly flattened (a 1 % wider posterior on this grid)
    problem = _plane_problem(np.random.default_rng(3))
    fix = run_filter(Pmf(discretisation_noise=discretisation_noise), problem, None)
    means, covs = _kalman(problem)
    covs_pmf = fix.diagnostics["covariances"]
    # along the gradient the posterior is ~6 m wide, across it ~30 m: both resolved
    sd = np.sqrt(np.linalg.eigvalsh(covs))
    assert sd[-1, 0] < 8.0 and sd[-1, 1] > 25.0
    for k in range(problem.n):
        whiten = np.linalg.inv(np.linalg.cholesky(covs[k]))
        assert np.max(np.abs(whiten @ (fix.track[k] - means[k]))) < tol
        rel = whiten @ covs_pmf[k] @ whiten.T
        np.testing.assert_allclose(rel, np.eye(2), atol=tol)


def test_log_space_survives_a_needle_likelihood():
    rng = np.random.default_rng(5)
    grid = fractal_terrain((128, 128), 10.0, rng=rng, std=20.0)
    truth = np.array([[600.0, 600.0], [620.0, 600.0], [640.0, 600.0], [660.0, 600.0]])
    offsets = np.array([[-40.0, 0.0], [0.0, 0.0], [40.0, 0.0]])
    heading = np.full(4, np.pi / 2)
    x, y = footprint_xy(truth, heading, offsets)
    problem = MatchProblem(
        grid=grid,
        indicated=truth + 35.0,
        heading=heading,
        offsets=offsets,
        measured=grid.sample(x, y) + rng.normal(0, 1e-6, x.shape),
        sigma_position=np.full(4, 40.0),
        times=np.arange(4.0),
        noise_std=1e-6,
    )
    fix = Pmf(discretisation_noise=False).match(problem, rng)
    covs = fix.diagnostics["covariances"]
    assert np.all(np.isfinite(fix.track)) and np.all(np.isfinite(covs))
    assert np.all(np.linalg.eigvalsh(covs) > 0)


def test_convolution_of_log_density_is_exact_and_finite():
    log_w = np.full((31, 31), -1e9)
    log_w[15, 15] = 0.0  # a point mass: every other node far below underflow
    kernel = ops.motion_kernel(2.0)
    out = ops.convolve_log(log_w, (kernel, kernel))
    assert np.all(np.isfinite(out))
    w = np.exp(out)
    half = kernel.size // 2
    np.testing.assert_allclose(w[15, 15 - half : 16 + half], kernel[half] * kernel, rtol=1e-12)
    u = np.arange(31) - 15.0
    assert w.sum(axis=1) @ u**2 == pytest.approx(4.0, rel=1e-6)


@pytest.mark.parametrize("sigma", [0.05, 0.5, 0.8, 1.5, 6.0])
def test_motion_kernel_has_the_exact_variance(sigma):
    k = ops.motion_kernel(sigma)
    u = np.arange(k.size) - k.size // 2
    assert k.sum() == pytest.approx(1.0)
    assert k @ u**2 == pytest.approx(sigma**2, rel=1e-5)


def test_regridding_keeps_the_moments_of_a_gaussian():
    mean, cov = np.array([3.0, -2.0]), np.array([[40.0, 12.0], [12.0, 9.0]])
    old = (np.zeros(2), np.eye(2), np.array([1.0, 1.0]))
    xy = ops.node_positions(*old, 61)
    log_w = ops.normalise(ops.gaussian_log_density(xy, mean, cov))
    values, axes = np.linalg.eigh(cov)
    new = (mean, axes, 10.0 * np.sqrt(values) / 60.0)
    moved = ops.resample_grid(log_w, old, new, (mean, cov))
    got_mean, got_cov = ops.moments(moved, *new)
    np.testing.assert_allclose(got_mean, mean, atol=0.01)
    resolution = axes @ np.diag(new[2] ** 2 / 12.0) @ axes.T
    np.testing.assert_allclose(got_cov - resolution, cov, rtol=0.01)


def test_node_field_variance_is_that_of_a_uniform_cell():
    # a plane read at nodes 2 m apart along both axes: differences 2*0.5 and 2*0.25
    u = np.arange(5) * 2.0
    predicted = (0.5 * u[:, None] + 0.25 * u[None, :])[..., None]
    expected = (1.0**2 + 0.5**2) / 12.0
    assert node_field_variance(predicted, np.array([1.0])) == pytest.approx(expected)


def test_converges_on_the_bundled_azores_scenario():
    from geofix.sim.scenario import load_scenario
    from geofix.sim.simulate import prepare_map, simulate_trial

    path = resources.files("geofix") / "scenarios" / "azores_demo.yaml"
    scen = load_scenario(path)
    grid = prepare_map(scen)
    errors, ins_errors = [], []
    for index in range(3):
        trial = simulate_trial(scen, grid, index)
        fix = Pmf().match(trial.problem(grid), np.random.default_rng(index))
        errors.append(np.hypot(*(fix.track[-1] - trial.truth[-1])))
        ins_errors.append(np.hypot(*(trial.indicated[-1] - trial.truth[-1])))
        assert not fix.ambiguous
    assert max(errors) < 0.5 * grid.cell_size
    assert np.mean(errors) < 0.3 * np.mean(ins_errors)


def test_flat_map_is_flagged_ambiguous():
    grid = planar_grid((80, 80), 10.0, 0.0, 0.0, offset=-50.0)
    n = 8
    truth = np.array([400.0, 400.0]) + np.arange(n)[:, None] * np.array([10.0, 0.0])
    problem = MatchProblem(
        grid=grid,
        indicated=truth + 20.0,
        heading=np.full(n, np.pi / 2),
        offsets=np.zeros((1, 2)),
        measured=np.full((n, 1), -50.0),
        sigma_position=np.full(n, 40.0),
        times=np.arange(float(n)),
        noise_std=0.5,
    )
    assert Pmf().match(problem, None).ambiguous


def test_settings_and_errors():
    assert parse_method_spec("pmf:points=41").points == 41
    with pytest.raises(ConfigError):
        Pmf(points=40)
    problem = _plane_problem(np.random.default_rng(0))
    far = MatchProblem(
        **{**problem.__dict__, "indicated": problem.indicated + 1e6}  # off the map
    )
    with pytest.raises(MatchError):
        Pmf().match(far, None)
