"""Measurement model with per-beam noise: likelihood, problem variances, filters weighing beams."""

import numpy as np
import pytest

from geofix.errors import ConfigError
from geofix.filters.base import observations, run_filter
from geofix.filters.pmf import Pmf
from geofix.filters.sitan import measurement_covariance
from geofix.maps.synthetic import planar_grid
from geofix.measurement import OFF_MAP_LOG_LIKELIHOOD, log_likelihood
from geofix.problem import MatchProblem, footprint_xy

SLOPE = np.array([0.04, -0.015])  # mGal per metre
OFFSETS = np.array([[-60.0, 0.0], [0.0, 0.0], [60.0, 0.0]])
BEAM_STD = np.array([3.0, 0.5, 1.0])  # noisy port beam, good nadir, middling starboard


def _problem(rng, n=6, beam_std=BEAM_STD, map_error_std=0.0):
    grid = planar_grid((120, 120), 10.0, *SLOPE, offset=20.0, kind="gravity")
    heading = np.full(n, np.radians(35.0))
    step = 25.0 * np.array([np.sin(heading[0]), np.cos(heading[0])])
    truth = np.array([500.0, 450.0]) + np.arange(n)[:, None] * step
    x, y = footprint_xy(truth, heading, OFFSETS)
    measured = grid.sample(x, y) + rng.normal(0.0, 1.0, x.shape) * beam_std
    return MatchProblem(
        grid=grid,
        indicated=truth + np.array([18.0, -12.0]),
        heading=heading,
        offsets=OFFSETS,
        measured=measured,
        sigma_position=np.sqrt(30.0**2 + 4.0 * np.arange(n)),
        times=np.arange(n) * 10.0,
        noise_std=0.5,
        sensor="gravimeter",
        map_error_std=map_error_std,
        beam_noise_std=beam_std,
    )


# ---------------------------------------------------------------------- log_likelihood
def test_per_beam_log_likelihood_known_answer():
    predicted = np.array([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]])
    measured = np.array([2.0, 2.0, 1.0])
    var = np.array([4.0, 1.0, 0.5])
    # hypothesis 0: residuals (-1, 0, 2) -> -0.5 * (1/4 + 0 + 4/0.5) = -4.125
    # hypothesis 1: residuals (-2, -2, -1) -> -0.5 * (4/4 + 4/1 + 1/0.5) = -3.5
    np.testing.assert_allclose(log_likelihood(predicted, measured, var), [-4.125, -3.5])


def test_scalar_and_uniform_array_variances_agree():
    rng = np.random.default_rng(0)
    predicted = rng.normal(size=(4, 5, 3))
    measured = rng.normal(size=3)
    np.testing.assert_allclose(
        log_likelihood(predicted, measured, 2.5),
        log_likelihood(predicted, measured, np.full(3, 2.5)),
    )


def test_missing_beam_masks_its_variance_too():
    predicted = np.array([[1.0, 5.0, 3.0]])
    measured = np.array([2.0, np.nan, 1.0])
    # the missing beam's variance (0 here) must be dropped with it: no inf, no NaN
    var = np.array([4.0, 0.0, 0.5])
    np.testing.assert_allclose(log_likelihood(predicted, measured, var), [-0.5 * (0.25 + 8.0)])


def test_off_map_beam_costs_the_penalty_with_per_beam_variance():
    predicted = np.array([[2.0, np.nan, 1.0]])
    measured = np.array([2.0, 2.0, 1.0])
    ll = log_likelihood(predicted, measured, np.array([1.0, 9.0, 0.25]))
    np.testing.assert_allclose(ll, [OFF_MAP_LOG_LIKELIHOOD])


# ---------------------------------------------------------------------- problem variances
def test_beam_noise_var_adds_the_map_error_per_beam():
    problem = _problem(np.random.default_rng(1), map_error_std=2.0)
    np.testing.assert_allclose(problem.beam_noise_var(), BEAM_STD**2 + 4.0)
    uniform = MatchProblem(**{**problem.__dict__, "beam_noise_std": None})
    np.testing.assert_allclose(uniform.beam_noise_var(), np.full(3, 0.25 + 4.0))


@pytest.mark.parametrize("bad", [np.ones(2), np.array([1.0, -1.0, 1.0]), np.full(3, np.nan)])
def test_bad_beam_noise_std_raises_when_used(bad):
    # building the problem stays cheap and lenient (callers subset beams with replace)
    problem = MatchProblem(**{**_problem(np.random.default_rng(1)).__dict__, "beam_noise_std": bad})
    with pytest.raises(ConfigError, match="beam_noise_std"):
        problem.beam_noise_var()
    with pytest.raises(ConfigError, match="beam_noise_std"):
        observations(problem)


def test_observations_carry_the_read_only_per_beam_variance():
    problem = _problem(np.random.default_rng(1), map_error_std=1.0)
    obs = observations(problem)
    for o in obs:
        np.testing.assert_allclose(o.noise_var, BEAM_STD**2 + 1.0)
    with pytest.raises(ValueError):
        obs[0].noise_var[0] = 0.0


def test_observations_without_per_beam_noise_keep_the_scalar_variance():
    problem = _problem(np.random.default_rng(1), map_error_std=1.0)
    uniform = MatchProblem(**{**problem.__dict__, "beam_noise_std": None})
    assert all(o.noise_var == pytest.approx(0.25 + 1.0) for o in observations(uniform))


def test_sitan_measurement_covariance_has_the_per_beam_variance_on_its_diagonal():
    obs = observations(_problem(np.random.default_rng(1)))[0]
    valid = np.array([[True, True, True], [True, False, True]])
    r = measurement_covariance(obs, np.zeros((2, 3)), np.zeros(2), valid)
    np.testing.assert_allclose(np.diagonal(r, axis1=1, axis2=2), [BEAM_STD**2, [9.0, 1.0, 1.0]])


# ---------------------------------------------------------------------- filters
def _kalman(problem, beam_var):
    """Exact linear-Gaussian posterior with a diagonal per-beam measurement covariance."""
    mean = problem.indicated[0].astype(float)
    cov = problem.sigma_position[0] ** 2 * np.eye(2)
    h = np.tile(SLOPE, (problem.beams, 1))
    means, covs = [], []
    for k in range(problem.n):
        if k:
            mean = mean + problem.indicated[k] - problem.indicated[k - 1]
            q = problem.sigma_position[k] ** 2 - problem.sigma_position[k - 1] ** 2
            cov = cov + q * np.eye(2)
        x, y = footprint_xy(mean[None], problem.heading[k : k + 1], problem.offsets)
        gain = cov @ h.T @ np.linalg.inv(h @ cov @ h.T + np.diag(beam_var))
        mean = mean + gain @ (problem.measured[k] - problem.grid.sample(x, y)[0])
        cov = (np.eye(2) - gain @ h) @ cov
        means.append(mean)
        covs.append(cov)
    return np.array(means), np.array(covs)


def test_pmf_weighs_every_beam_by_its_own_noise():
    problem = _problem(np.random.default_rng(3))
    fix = run_filter(Pmf(discretisation_noise=False, map_model="exact"), problem, None)
    means, covs = _kalman(problem, BEAM_STD**2)
    _, wrong_covs = _kalman(problem, np.full(3, 0.25))  # nadir noise everywhere
    for k in range(problem.n):
        whiten = np.linalg.inv(np.linalg.cholesky(covs[k]))
        assert np.max(np.abs(whiten @ (fix.track[k] - means[k]))) < 0.01
        rel = whiten @ fix.diagnostics["covariances"][k] @ whiten.T
        np.testing.assert_allclose(rel, np.eye(2), atol=0.02)  # first grid: 1.3 % wide
    # the uniform-noise posterior is far narrower along the gradient: the test can tell
    along = SLOPE / np.linalg.norm(SLOPE)
    assert along @ wrong_covs[-1] @ along < 0.6 * (along @ covs[-1] @ along)


def test_linearisation_reads_the_grid_interpolation():
    from dataclasses import replace

    from geofix.maps.grid import Grid
    from geofix.measurement import linearise

    yy, xx = np.mgrid[0:60, 0:70]
    x, y = 8.0 * xx, 12.0 * yy

    def surface(x, y):
        return 5.0 + 0.03 * x - 0.02 * y + 1e-4 * x * x - 2e-4 * x * y + 3e-4 * y * y

    linear = Grid(surface(x, y), 0.0, 0.0, 8.0, 12.0)
    cubic = replace(linear, interpolation="bicubic")
    position, heading = np.array([263.7, 351.2]), np.radians(35.0)
    fx, fy = footprint_xy(position, heading, OFFSETS)
    lin = linearise(cubic, position, heading, OFFSETS, half_width_m=40.0)
    # bicubic reads a quadratic exactly, so does the prediction; on the symmetric patch the
    # plane's slopes are the quadratic's gradient at each footprint
    np.testing.assert_allclose(lin.predicted, surface(fx, fy), atol=1e-9)
    np.testing.assert_allclose(lin.slopes[:, 0], 0.03 + 2e-4 * fx - 2e-4 * fy, atol=1e-9)
    np.testing.assert_allclose(lin.slopes[:, 1], -0.02 - 2e-4 * fx + 6e-4 * fy, atol=1e-9)
    # the bilinear grid's linearisation reads its own (inexact) interpolant
    bilinear = linearise(linear, position, heading, OFFSETS, half_width_m=40.0)
    np.testing.assert_array_equal(bilinear.predicted, linear.sample(fx, fy))
    assert np.abs(bilinear.predicted - surface(fx, fy)).max() > 1e-3
