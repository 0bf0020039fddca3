"""Point-mass filter: the Kalman posterior on a plane, log-space robustness, a real map."""

from dataclasses import replace
from importlib import resources

import numpy as np
import pytest

from geofix.errors import ConfigError, MatchError
from geofix.filters import _grid_ops as ops
from geofix.filters.base import motions, observations, run_filter
from geofix.filters.pmf import Pmf, PmfState, node_field_variance
from geofix.maps.synthetic import fractal_terrain, planar_grid
from geofix.methods import parse_method_spec
from geofix.problem import MatchProblem, footprint_xy

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
    # the exact map model: on a plane a common offset is a shift along the slope
    fix = run_filter(
        Pmf(discretisation_noise=discretisation_noise, map_model="exact"), problem, None
    )
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


def _wide_prior_problem(seed, n=12, sigma0=600.0, noise=0.5):
    """Nine beams over a rough fractal seabed (10 m cells), prior 60 cells wide (1 sigma)."""
    rng = np.random.default_rng(seed)
    grid = fractal_terrain((400, 400), 10.0, rng=rng, std=15.0, hurst=0.5)
    heading = np.full(n, np.radians(60.0))
    step = 40.0 * np.array([np.sin(heading[0]), np.cos(heading[0])])
    truth = np.array([1800.0, 1800.0]) + np.arange(n)[:, None] * step
    offsets = np.stack([np.linspace(-100.0, 100.0, 9), np.zeros(9)], axis=1)
    x, y = footprint_xy(truth, heading, offsets)
    problem = MatchProblem(
        grid=grid,
        indicated=truth + rng.normal(0.0, sigma0, 2),
        heading=heading,
        offsets=offsets,
        measured=grid.sample(x, y) + rng.normal(0.0, noise, x.shape),
        sigma_position=np.full(n, sigma0),
        times=np.arange(n) * 10.0,
        noise_std=noise,
    )
    return problem, truth


@pytest.mark.parametrize("seed", [0, 5])
def test_converges_from_a_prior_much_wider_than_the_cell(seed):
    problem, truth = _wide_prior_problem(seed)
    cell = problem.grid.cell_size
    # a fixed 61-node grid that follows the moments alone: 100 m (10 cells) between the
    # prior's nodes, and it locks on a wrong place with confidence
    old = Pmf(max_points=61, support_nats=0.0, map_model="exact").match(problem, None)
    assert np.hypot(*(old.track[-1] - truth[-1])) > 20 * cell and not old.ambiguous
    # both remedies, each, on the sharp likelihood of the exact map model; and the default
    remedies = (Pmf(max_points=61, map_model="exact"), Pmf(support_nats=0.0, map_model="exact"))
    for pmf in (Pmf(), *remedies):
        fix = pmf.match(problem, None)
        assert np.hypot(*(fix.track[-1] - truth[-1])) < 0.5 * cell
        assert not fix.ambiguous


def test_node_count_follows_the_width_of_the_posterior():
    pmf = Pmf()  # 61 to 301 nodes, at most 0.5 cell apart while the count allows
    spacing, shape = pmf.grid_layout(np.array([100.0, 600.0]), cell=10.0)
    assert shape == (61, 241)
    np.testing.assert_allclose(spacing, [200.0 / 60, 5.0])
    spacing, shape = pmf.grid_layout(np.array([3000.0, 3000.0]), cell=10.0)
    assert shape == (301, 301)
    np.testing.assert_allclose(spacing, [20.0, 20.0])
    # the prior grid of a wide prior, then a small grid once the posterior has shrunk
    problem, _ = _wide_prior_problem(0, n=3)
    state = pmf.initialize(problem, None)
    assert state.shape == (301, 301)
    narrow = ops.normalise(
        ops.gaussian_log_density(
            ops.node_positions(*state.frame, state.shape), state.centre, 4.0 * np.eye(2)
        )
    )
    _, shape = pmf.ideal_frame(state, state.centre, 400.0 * np.eye(2))
    assert shape == (301, 301)  # zoom limited to max_zoom per regrid
    state = replace(state, log_weight=narrow)
    for _ in range(4):
        (centre, axes, spacing), shape = pmf.ideal_frame(state, state.centre, 4.0 * np.eye(2))
        moved = ops.resample_grid(
            state.log_weight,
            state.frame,
            (centre, axes, spacing),
            (state.centre, 4.0 * np.eye(2)),
            shape,
        )
        state = replace(state, log_weight=moved, centre=centre, axes=axes, spacing=spacing)
    assert state.shape == (61, 61)


def test_a_small_far_mode_stays_on_the_grid():
    # 1e-4 of the mass 2 km from a narrow main mode: the grid keeps covering it
    pmf = Pmf()
    old = (np.zeros(2), np.eye(2), np.array([50.0, 50.0]))
    xy = ops.node_positions(*old, 101)
    main = ops.gaussian_log_density(xy, np.zeros(2), 25.0 * np.eye(2))
    far = ops.gaussian_log_density(xy, np.array([2000.0, 0.0]), 25.0 * np.eye(2)) + np.log(1e-4)
    log_w = ops.normalise(np.logaddexp(main, far))
    state = PmfState(log_w, *old, cell=10.0)
    mean, cov = pmf.estimate(state)
    (centre, axes, spacing), shape = pmf.ideal_frame(state, mean, cov)
    reach = 0.5 * spacing * (np.array(shape) - 1)
    assert np.max(np.abs((np.array([2000.0, 0.0]) - centre) @ axes) / reach) < 1.0
    (_, axes, spacing), shape = Pmf(support_nats=0.0).ideal_frame(state, mean, cov)
    assert (0.5 * spacing * (np.array(shape) - 1)).max() < 1000.0  # the moments alone


def test_field_prediction_matches_bilinear_sampling_at_the_footprints():
    from geofix.measurement import predict_measurements
    from geofix.problem import footprint_xy

    rng = np.random.default_rng(8)
    grid = fractal_terrain((60, 50), 10.0, rng=rng, std=5.0)
    values = grid.values.copy()
    values[20:25, 10:14] = np.nan  # a hole: NaN wherever it touches the bilinear stencil
    grid = grid.with_values(values)
    positions = rng.uniform(-50.0, 650.0, (7, 9, 2))  # some off the map
    offsets = rng.normal(0.0, 30.0, (5, 2))
    fx, fy = footprint_xy(positions.reshape(-1, 1, 2), np.full((63, 1), 0.7), offsets)
    want = grid.sample(fx, fy).reshape(7, 9, 5)
    got = predict_measurements(grid, positions, 0.7, offsets)
    assert got.shape == (7, 9, 5)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    assert np.isnan(want).any() and np.isfinite(want).any()
    np.testing.assert_allclose(got[np.isfinite(got)], want[np.isfinite(want)], atol=1e-9)


def test_per_beam_noise_variance_is_accepted_and_left_alone():
    from geofix.filters.base import Observation

    problem = _plane_problem(np.random.default_rng(1))
    pmf = Pmf()
    state = pmf.initialize(problem, None)
    var = np.array([1.0, 1.0, 1.0])
    var.setflags(write=False)
    obs = observations(problem)[0]
    per_beam = Observation(obs.values, obs.indicated, obs.heading, obs.offsets, var, 0)
    scalar = Observation(obs.values, obs.indicated, obs.heading, obs.offsets, 1.0, 0)
    a = pmf.update(state, per_beam, problem.grid, None)
    b = pmf.update(state, scalar, problem.grid, None)
    np.testing.assert_allclose(a.log_weight, b.log_weight)
    np.testing.assert_array_equal(var, 1.0)
