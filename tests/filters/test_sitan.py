"""SITAN and the SITAN bank: Kalman algebra, linearisation, consistency, bank behaviour."""

import numpy as np
import pytest

from geofix.errors import ConfigError, MatchError
from geofix.filters.base import motions, observations, run_filter
from geofix.filters.sitan import (
    LinearModel,
    Sitan,
    SitanBank,
    ekf_update,
    lattice_offsets,
    linear_model,
    patch_half_width,
    transition,
)
from geofix.maps.synthetic import fractal_terrain, planar_grid
from geofix.methods import parse_method_spec
from geofix.problem import MatchProblem, footprint_xy

SLOPE = np.array([0.05, -0.02])  # metres of depth per metre: a steep, tilted plane
OFFSETS = np.array([[-40.0, 0.0], [0.0, 0.0], [40.0, 0.0]])  # three beams across track


def _problem(grid, rng, n, start, sigma0, q, noise, offsets=OFFSETS, heading_deg=60.0, error=None):
    """A straight mission whose INS error follows the filter's own model exactly.

    The initial error is ``error`` or a draw from ``N(0, sigma0^2)`` per axis; each step
    adds a random walk of variance ``q`` per axis; beams read the map at the truth plus
    Gaussian noise.
    """
    heading = np.full(n, np.radians(heading_deg))
    step = 20.0 * np.array([np.sin(heading[0]), np.cos(heading[0])])
    truth = np.asarray(start, float) + np.arange(n)[:, None] * step
    first = rng.normal(0.0, sigma0, 2) if error is None else np.asarray(error, float)
    walk = np.vstack([np.zeros(2), np.cumsum(rng.normal(0.0, np.sqrt(q), (n - 1, 2)), axis=0)])
    indicated = truth + first + walk  # the INS error is indicated - truth
    x, y = footprint_xy(truth, heading, offsets)
    measured = grid.sample(x, y) + rng.normal(0.0, noise, x.shape)
    problem = MatchProblem(
        grid=grid,
        indicated=indicated,
        heading=heading,
        offsets=offsets,
        measured=measured,
        sigma_position=np.sqrt(sigma0**2 + q * np.arange(n)),
        times=np.arange(n) * 10.0,
        noise_std=noise,
        sensor="multibeam",
    )
    return problem, truth


@pytest.fixture(scope="module")
def rough():
    """A 160 x 160 fractal seabed, 10 m cells, depth std 8 m (seed 4)."""
    return fractal_terrain((160, 160), 10.0, rng=np.random.default_rng(4), std=8.0)


# ---------------------------------------------------------------------- algebra
def test_transition_is_the_sources_phi():
    phi = transition(30.0)
    expected = np.eye(5)
    expected[0, 3] = expected[1, 4] = 30.0
    np.testing.assert_array_equal(phi, expected)
    state = np.array([1.0, 2.0, 0.5, 0.1, -0.2])
    np.testing.assert_allclose(phi @ state, [4.0, -4.0, 0.5, 0.1, -0.2])


def test_ekf_update_matches_the_textbook_formulas():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(5, 5))
    cov = a @ a.T + np.eye(5)
    x = rng.normal(size=5)
    h = rng.normal(size=(3, 5))
    r = np.diag([0.5, 1.0, 2.0])
    innovation = rng.normal(size=3)
    model = LinearModel(innovation[None], h[None], r[None], np.ones((1, 3), bool))
    x_new, cov_new, wrs = ekf_update(x[None], cov[None], model)
    s = h @ cov @ h.T + r
    gain = cov @ h.T @ np.linalg.inv(s)
    np.testing.assert_allclose(x_new[0], x + gain @ innovation, rtol=1e-10)
    np.testing.assert_allclose(cov_new[0], (np.eye(5) - gain @ h) @ cov, atol=1e-10)
    assert wrs[0] == pytest.approx(innovation @ np.linalg.solve(s, innovation) / 3)


def test_invalid_rows_carry_no_information():
    cov = np.eye(5)[None] * 4.0
    model = LinearModel(
        np.zeros((1, 2)), np.zeros((1, 2, 5)), np.eye(2)[None], np.zeros((1, 2), bool)
    )
    x_new, cov_new, wrs = ekf_update(np.ones((1, 5)), cov, model)
    np.testing.assert_allclose(x_new, 1.0)
    np.testing.assert_allclose(cov_new, cov)
    assert np.isnan(wrs[0])


def test_patch_half_width_ladder():
    cov = np.zeros((3, 5, 5))
    cov[:, 0, 0] = [1.0, 30.0**2, 100.0**2]
    cov[:, 1, 1] = [1.0, 10.0**2, 1.0]
    hw = patch_half_width(cov, 2.0, 10.0)
    # one cell at least; 60 m -> 10 * sqrt(2)^6 = 80 m; 200 m -> 10 * sqrt(2)^9 = 226 m
    np.testing.assert_allclose(hw, [10.0, 80.0, 10.0 * np.sqrt(2.0) ** 9])


def test_lattice_is_centred_and_evenly_spaced():
    off = lattice_offsets(3, 5.0)
    assert off.shape == (9, 2)
    np.testing.assert_allclose(off[4], [0.0, 0.0])
    np.testing.assert_allclose(np.unique(off[:, 0]), [-5.0, 0.0, 5.0])


# ---------------------------------------------------------------------- linearisation
def test_linearisation_on_a_plane_is_exact_and_stacks_one_row_per_beam():
    grid = planar_grid((80, 80), 10.0, *SLOPE, offset=-100.0)
    problem, _ = _problem(grid, np.random.default_rng(1), 3, (400.0, 400.0), 20.0, 1.0, 0.5)
    obs = observations(problem)[0]
    x = np.zeros((2, 5))
    x[1, :3] = [30.0, -20.0, 2.0]
    cov = np.tile(np.diag([400.0, 400.0, 1.0, 0.01, 0.01]), (2, 1, 1))
    model, lookups = linear_model(grid, x, cov, obs, 2.0, 0.0)
    assert model.h.shape == (2, 3, 5) and model.valid.all() and lookups > 0
    np.testing.assert_allclose(model.h[..., :2], np.broadcast_to(SLOPE, (2, 3, 2)), atol=1e-9)
    np.testing.assert_allclose(model.h[..., 2], 1.0)
    # innovation = measured - map(estimate) - bias; the fit residual of a plane is zero
    bx, by = footprint_xy(obs.indicated + x[1, :2], np.full(1, obs.heading), OFFSETS)
    expected = obs.values - grid.sample(bx, by)[0] - 2.0
    np.testing.assert_allclose(model.innovation[1], expected, atol=1e-9)
    np.testing.assert_allclose(np.diagonal(model.r_cov, axis1=1, axis2=2), obs.noise_var, atol=1e-9)


def test_sitan_equals_the_linear_kalman_filter_on_a_plane():
    grid = planar_grid((120, 120), 10.0, *SLOPE, offset=-100.0)
    problem, _ = _problem(grid, np.random.default_rng(2), 8, (500.0, 400.0), 25.0, 4.0, 0.5)
    filt = Sitan(bias_sigma=0.0, velocity_sigma_m_s=0.0, velocity_walk=0.0)
    fix = run_filter(filt, problem, np.random.default_rng(0))
    mean = problem.indicated[0].copy()
    cov = problem.sigma_position[0] ** 2 * np.eye(2)
    obs, steps = observations(problem), motions(problem)
    for k in range(problem.n):
        if k:
            mean, cov = mean + steps[k - 1].displacement, cov + steps[k - 1].process_var * np.eye(2)
        bx, by = footprint_xy(mean[None], problem.heading[k : k + 1], OFFSETS)
        h = np.tile(SLOPE, (3, 1))
        s = h @ cov @ h.T + obs[k].noise_var * np.eye(3)
        gain = cov @ h.T @ np.linalg.inv(s)
        mean = mean + gain @ (problem.measured[k] - grid.sample(bx, by)[0])
        cov = (np.eye(2) - gain @ h) @ cov
        np.testing.assert_allclose(fix.track[k], mean, atol=1e-6)
        np.testing.assert_allclose(fix.diagnostics["covariances"][k], cov, atol=1e-6)


# ---------------------------------------------------------------------- SITAN
def test_sitan_corrects_a_small_error_on_rough_terrain(rough):
    problem, truth = _problem(
        rough, np.random.default_rng(5), 60, (300.0, 300.0), 30.0, 4.0, 0.3, error=(40.0, -30.0)
    )
    fix = parse_method_spec("sitan").match(problem, np.random.default_rng(0))
    end = np.hypot(*(fix.track[-1] - truth[-1]))
    ins = np.hypot(*(problem.indicated[-1] - truth[-1]))
    assert end < 10.0 < ins
    assert not fix.ambiguous
    assert fix.evaluations > 0


def test_sitan_error_is_consistent_with_its_covariance(rough):
    """pyins-style statistical test: 50 seeded missions whose INS error follows the model.

    The per-axis position errors divided by the filter's own sigmas should have an RMS of
    1 for a perfectly consistent filter; the sampling spread of that RMS over 50 runs x 2
    axes x 40 samples is a few percent, so the bound 1.5 leaves room only for the
    linearisation error that an EKF on real-looking terrain must carry (the plane-fit
    residual in R makes it err on the conservative side, RMS < 1).
    """
    normalised = []
    for seed in range(50):
        problem, truth = _problem(
            rough, np.random.default_rng(100 + seed), 40, (300.0, 300.0), 15.0, 2.0, 0.3
        )
        fix = run_filter(Sitan(), problem, np.random.default_rng(seed))
        covs = fix.diagnostics["covariances"]
        sd = np.sqrt(np.stack([covs[:, 0, 0], covs[:, 1, 1]], axis=1))
        normalised.append((fix.track - truth) / sd)
    rms = float(np.sqrt(np.mean(np.square(normalised))))
    assert 0.3 < rms < 1.5


# ---------------------------------------------------------------------- the bank
def test_bank_recovers_where_single_sitan_diverges(rough):
    """A 250 m initial error (25 cells) on the rough map: SITAN is lost, the bank is not."""
    single, bank = [], []
    for seed in range(3):
        problem, truth = _problem(
            rough,
            np.random.default_rng(200 + seed),
            50,
            (500.0, 400.0),
            125.0,
            1.0,
            0.3,
            error=(200.0, -150.0),
        )
        single.append(np.hypot(*(Sitan().match(problem, None).track[-1] - truth[-1])))
        fix = SitanBank(side=15).match(problem, None)
        bank.append(np.hypot(*(fix.track[-1] - truth[-1])))
    assert max(bank) < 10.0
    assert min(single) > 30.0


def test_bank_reinitialises_smaller_and_closer(rough):
    problem, truth = _problem(
        rough, np.random.default_rng(7), 50, (500.0, 400.0), 125.0, 1.0, 0.3, error=(200.0, -150.0)
    )
    filt = SitanBank(side=15)
    state = filt.initialize(problem, None)
    assert (state.side, state.generation) == (15, 0)
    assert state.spacing == pytest.approx(6 * 125.0 / 14)
    obs, steps = observations(problem), motions(problem)
    sides, spacings = [], []
    state = filt.update(state, obs[0], rough, None)
    for k in range(1, problem.n):
        state = filt.update(filt.predict(state, steps[k - 1], None), obs[k], rough, None)
        sides.append(state.side)
        spacings.append(state.spacing)
    assert state.generation >= 2 and state.final
    assert np.all(np.diff(sides) <= 0) and np.all(np.diff(spacings) <= 0)
    assert sides[-1] == 3 and spacings[-1] == pytest.approx(rough.cell_size)
    assert np.hypot(*(filt.estimate(state)[0] - truth[-1])) < 10.0


def test_bank_on_a_flat_map_is_flagged_ambiguous():
    flat = planar_grid((100, 100), 10.0, 0.0, 0.0, offset=-50.0)
    problem, _ = _problem(flat, np.random.default_rng(3), 30, (300.0, 300.0), 60.0, 1.0, 0.3)
    fix = SitanBank(side=9).match(problem, None)
    assert fix.ambiguous


def test_first_bank_size_follows_the_prior():
    bank = SitanBank()
    assert bank.first_side(12400.0, 1000.0) == 25  # capped by side
    assert bank.first_side(447.0, 1000.0) == 5  # 6 sigma / 4 = 670 m <= one cell
    assert bank.first_side(1.0, 1000.0) == 3  # min_side


def test_bank_ignores_filters_off_the_map(rough):
    """A fifth of the first bank starts off the map: those filters must never be chosen."""
    problem, truth = _problem(
        rough,
        np.random.default_rng(9),
        40,
        (60.0, 800.0),
        40.0,
        1.0,
        0.3,
        heading_deg=90.0,
        error=(20.0, 10.0),
    )
    fix = SitanBank(side=9).match(problem, None)
    assert np.isfinite(fix.track).all()
    assert np.hypot(*(fix.track[-1] - truth[-1])) < 10.0


# ---------------------------------------------------------------------- robustness, registry
@pytest.mark.parametrize("method", ["sitan", "sitan-bank"])
def test_missing_samples_are_skipped(rough, method):
    problem, truth = _problem(
        rough, np.random.default_rng(11), 50, (300.0, 300.0), 30.0, 4.0, 0.3, error=(30.0, 20.0)
    )
    measured = problem.measured.copy()
    measured[10:20] = np.nan
    measured[25:, 0] = np.nan
    gappy = MatchProblem(**{**problem.__dict__, "measured": measured})
    # the INS error here is a pure position random walk: the prior's growth is not drift
    fix = parse_method_spec(f"{method}:drift_in_velocity=false").match(gappy, None)
    assert np.isfinite(fix.track).all()
    assert np.hypot(*(fix.track[-1] - truth[-1])) < 10.0


@pytest.mark.parametrize("method", ["sitan", "sitan-bank"])
def test_no_measurement_at_all_raises(rough, method):
    problem, _ = _problem(rough, np.random.default_rng(1), 5, (300.0, 300.0), 30.0, 1.0, 0.3)
    empty = MatchProblem(**{**problem.__dict__, "measured": np.full_like(problem.measured, np.nan)})
    with pytest.raises(MatchError, match="no finite measurement"):
        parse_method_spec(method).match(empty, None)


def test_registry_settings_and_validation():
    bank = parse_method_spec("sitan-bank:side=7,beta=0.95,shrink=0.4")
    assert (bank.side, bank.beta, bank.shrink) == (7, 0.95, 0.4)
    assert bank.recursive and Sitan.recursive
    with pytest.raises(ConfigError, match="beta"):
        parse_method_spec("sitan:beta=1.5")
    with pytest.raises(ConfigError, match="odd"):
        parse_method_spec("sitan-bank:side=6")


def test_position_noise_is_the_prior_growth_not_explained_by_the_velocity_states():
    from geofix.filters.sitan import MIN_POSITION_VAR, position_process_var

    # no velocity states: the whole growth is position noise
    assert position_process_var(9.0, 100.0, 10.0, 0.0, 0.0) == pytest.approx(9.0)
    # a 0.05 m/s velocity prior explains 0.05^2 ((110)^2 - 100^2) = 5.25 m^2 of it
    assert position_process_var(9.0, 100.0, 10.0, 0.05, 0.0) == pytest.approx(3.75)
    # a growth that is all drift leaves only the floor
    assert position_process_var(5.0, 100.0, 10.0, 0.05, 0.0) == MIN_POSITION_VAR
