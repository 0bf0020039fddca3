"""Bootstrap particle filter: agreement with the PMF, resampling, log-space, errors."""

from dataclasses import replace

import numpy as np
import pytest

from geofix.errors import ConfigError, MatchError
from geofix.filters import likelihood as likelihood_module
from geofix.filters._weights import effective_sample_size, systematic_resample
from geofix.filters.base import Observation
from geofix.filters.likelihood import field_variance_particles, spread_field_variance
from geofix.filters.pf import Pf, PfState
from geofix.filters.pmf import Pmf
from geofix.maps.synthetic import fractal_terrain
from geofix.methods import parse_method_spec
from geofix.problem import MatchProblem, footprint_xy


def _fractal_problem(seed=11, n=12, noise=2.0, sigma0=40.0):
    """Single-beam mission over a seeded fractal seabed (10 m cells, 20 m depth std)."""
    rng = np.random.default_rng(seed)
    grid = fractal_terrain((160, 160), 10.0, rng=rng, std=20.0, hurst=0.8)
    heading = np.full(n, np.radians(70.0))
    step = 30.0 * np.array([np.sin(heading[0]), np.cos(heading[0])])
    truth = np.array([500.0, 700.0]) + np.arange(n)[:, None] * step
    x, y = footprint_xy(truth, heading, np.zeros((1, 2)))
    return MatchProblem(
        grid=grid,
        indicated=truth + np.array([45.0, -30.0]),
        heading=heading,
        offsets=np.zeros((1, 2)),
        measured=grid.sample(x, y) + rng.normal(0.0, noise, x.shape),
        sigma_position=np.sqrt(sigma0**2 + 9.0 * np.arange(n)),
        times=np.arange(n) * 10.0,
        noise_std=noise,
    ), truth


def test_pf_and_pmf_agree_in_distribution():
    problem, truth = _fractal_problem()
    # one model for both: the exact map (the offset states are approximated differently)
    pmf = Pmf(map_model="exact").match(problem, None)
    pf = Pf(particles=20000, map_model="exact").match(problem, np.random.default_rng(0))
    for k in (3, 7, problem.n - 1):
        cov = pmf.diagnostics["covariances"][k]
        sd = np.sqrt(np.linalg.eigvalsh(cov))
        whiten = np.linalg.inv(np.linalg.cholesky(cov))
        assert np.linalg.norm(whiten @ (pf.track[k] - pmf.track[k])) < 0.25
        ratio = np.linalg.eigvalsh(whiten @ pf.diagnostics["covariances"][k] @ whiten.T)
        assert np.all((ratio > 0.8) & (ratio < 1.25)), (k, sd, ratio)
    # the truth is consistent with the posterior, which is narrower than the prior
    cov = pmf.diagnostics["covariances"][-1]
    whiten = np.linalg.inv(np.linalg.cholesky(cov))
    assert np.linalg.norm(whiten @ (pmf.track[-1] - truth[-1])) < 3.0
    assert np.sqrt(np.linalg.eigvalsh(cov)).max() < 0.5 * problem.sigma_position[-1]


def test_seeded_runs_repeat_and_differ_across_seeds():
    problem, _ = _fractal_problem(n=6)
    a = Pf(particles=500).match(problem, np.random.default_rng(4)).track
    b = Pf(particles=500).match(problem, np.random.default_rng(4)).track
    c = Pf(particles=500).match(problem, np.random.default_rng(5)).track
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_systematic_resample_copies_floor_or_ceil():
    rng = np.random.default_rng(2)
    w = rng.dirichlet(np.full(50, 0.3))
    counts = np.bincount(systematic_resample(w, rng), minlength=50)
    assert counts.sum() == 50
    assert np.all(counts >= np.floor(50 * w)) and np.all(counts <= np.ceil(50 * w))


def test_effective_sample_size_limits():
    assert effective_sample_size(np.full(8, 1 / 8)) == pytest.approx(8.0)
    assert effective_sample_size(np.eye(1, 8)[0]) == pytest.approx(1.0)


def test_resampling_and_roughening_on_low_ess():
    rng = np.random.default_rng(1)
    particles = rng.normal(0.0, 100.0, (1000, 2))
    log_w = np.full(1000, -1e4)
    log_w[:3] = 0.0  # three particles carry all the weight
    state = PfState(particles, log_w - np.log(3.0), cell=10.0)
    from geofix.filters.base import Motion

    pf = Pf(particles=1000, max_particles=1000)
    moved = pf.predict(state, Motion(np.array([5.0, 0.0]), 1.0, 1e-6), rng)
    assert moved.resamples == 1
    assert np.allclose(np.exp(moved.log_weight), 1e-3)
    # every particle sits near one of the three survivors, jittered by Gordon's rule
    # (roughening K = 0.5 by default: sd K * E * M^(-1/2))
    d = np.linalg.norm(
        moved.particles[:, None] - (particles[:3] + np.array([5.0, 0.0])), axis=-1
    ).min(1)
    spread = np.ptp(particles[:3], axis=0).max()
    assert pf.roughening == 0.5
    assert np.all(d < 5 * pf.roughening * spread / np.sqrt(1000))
    assert d.max() > 0


def test_needle_likelihood_gives_no_nan():
    problem, _ = _fractal_problem(n=5, noise=1e-6)
    fix = Pf(particles=2000).match(problem, np.random.default_rng(0))
    assert np.all(np.isfinite(fix.track))
    assert np.all(np.isfinite(fix.diagnostics["covariances"]))


def test_settings_and_errors():
    assert parse_method_spec("pf:particles=300,roughening=0").particles == 300
    with pytest.raises(ConfigError):
        Pf(particles=3)
    problem, _ = _fractal_problem(n=3)
    far = MatchProblem(**{**problem.__dict__, "indicated": problem.indicated - 1e6})
    with pytest.raises(MatchError):
        Pf().match(far, np.random.default_rng(0))


def test_converges_from_a_prior_much_wider_than_the_cell():
    from test_pmf import _wide_prior_problem

    problem, truth = _wide_prior_problem(0)
    cell = problem.grid.cell_size
    # 5000 random draws over a prior 60 cells wide (1 sigma), the update applied at once:
    # a wrong place, with confidence
    # (the map is the seabed here; the likelihood takes it as exact, so that the test is
    # of the sampling alone)
    few = Pf(
        max_particles=5000, discretisation_noise=False, progressive_stages=0, map_model="exact"
    )
    fix = few.match(problem, np.random.default_rng(0))
    assert np.hypot(*(fix.track[-1] - truth[-1])) > 20 * cell and not fix.ambiguous
    # the same 5000 with the update in stages (progressive correction) find the truth
    staged = replace(few, progressive_stages=4).match(problem, np.random.default_rng(0))
    assert np.hypot(*(staged.track[-1] - truth[-1])) < 0.5 * cell
    fix = Pf().match(problem, np.random.default_rng(0))
    assert np.hypot(*(fix.track[-1] - truth[-1])) < 0.5 * cell
    assert not fix.ambiguous


@pytest.mark.xfail(
    strict=True,
    reason="5000 particles on the default imperfect-map likelihood (the representation "
    "layer at 1.2 of the plane-fit residual) end 691 m off (983 m with roughening 0.2) "
    "and not flagged ambiguous, "
    "where the exact likelihood finds the truth: the wider per-beam variance leaves "
    "several modes a sparse staged set cannot tell apart",
)
def test_progressive_correction_finds_the_truth_on_the_default_map_model():
    from test_pmf import _wide_prior_problem

    problem, truth = _wide_prior_problem(0)
    few = Pf(max_particles=5000, discretisation_noise=False, progressive_stages=4)
    fix = few.match(problem, np.random.default_rng(0))
    assert np.hypot(*(fix.track[-1] - truth[-1])) < 0.5 * problem.grid.cell_size


def test_prior_is_a_stratified_sample_sized_by_its_area():
    problem, _ = _fractal_problem(sigma0=100.0)  # 10 m cells, +-4 sigma box 800 m wide
    pf = Pf(particles=1000, max_particles=50_000)
    state = pf.initialize(problem, np.random.default_rng(0))
    assert state.particles.shape[0] == 160**2  # (800 m / 5 m)^2 squares, one particle each
    assert state.spacing == pytest.approx(5.0)
    offsets = state.particles - problem.indicated[0]
    counts = np.histogram2d(*offsets.T, bins=160, range=[[-400, 400], [-400, 400]])[0]
    assert np.all(counts == 1)
    mean, cov = pf.estimate(state)  # the prior's moments, from the weights
    np.testing.assert_allclose(mean, problem.indicated[0], atol=1.0)
    np.testing.assert_allclose(cov, 100.0**2 * np.eye(2), rtol=0.02, atol=50.0)
    capped = Pf(particles=1000, max_particles=4000).initialize(problem, np.random.default_rng(0))
    assert capped.particles.shape[0] == 63**2  # the most squares within max_particles


def test_field_variance_of_an_all_beam_ping_reads_fewer_particles_and_keeps_its_value(
    monkeypatch,
):
    # Up to 64 beams: 2000 particles (every campaign scenario); 432 beams: 296, whose
    # estimate (20 seeds) sits on the all-particle value within 3 standard errors, each
    # within 5 % (its spread is ~1 %).
    assert field_variance_particles(5000, 33) == 2000
    assert field_variance_particles(5000, 432) == 296
    assert field_variance_particles(5000, 100_000) == 64
    assert field_variance_particles(30, 432) == 30
    rng = np.random.default_rng(3)
    grid = fractal_terrain((200, 200), 10.0, rng=rng, std=20.0, hurst=0.8)
    across = np.linspace(-200.0, 200.0, 432)
    offsets = np.column_stack([across, np.zeros_like(across)])
    particles = np.array([1000.0, 1000.0]) + rng.normal(0.0, 60.0, (5000, 2))
    state = PfState(particles, np.full(5000, -np.log(5000)), 10.0, spacing=8.0)
    obs = Observation(np.zeros(432), np.zeros(2), 0.3, offsets, 1.0, 0)
    capped = np.array(
        [
            spread_field_variance(grid, state.particles, 8.0, obs, np.random.default_rng(s))
            for s in range(20)
        ]
    )
    monkeypatch.setattr(likelihood_module, "FIELD_VARIANCE_SUBSET", 5000)
    monkeypatch.setattr(likelihood_module, "FIELD_VARIANCE_DIFFERENCES", 10**9)
    every = spread_field_variance(grid, state.particles, 8.0, obs, np.random.default_rng(0))
    assert abs(capped.mean() - every) < 3.0 * capped.std(ddof=1) / np.sqrt(capped.size)
    assert np.all(np.abs(capped / every - 1.0) < 0.05)


def test_shift_field_variance_is_the_prediction_array_estimate_in_one_pass():
    # The compiled pass reads what predict_measurements reads (off-map and missing beams
    # included) and sums the squared changes: within 1e-12 of the numpy estimate; on a
    # plane the change is the gradient times the shift, exactly (gx^2 + gy^2) s^2 / 12.
    from geofix.maps import Grid
    from geofix.measurement import predict_measurements, shift_field_variance

    rng = np.random.default_rng(8)
    grid = fractal_terrain((120, 120), 10.0, rng=rng, std=20.0)
    positions = np.array([600.0, 600.0]) + rng.normal(0.0, 400.0, (300, 2))
    offsets = np.column_stack([np.linspace(-200.0, 200.0, 9), np.zeros(9)])
    measured = np.zeros(9)
    measured[2] = np.nan
    used = offsets[np.isfinite(measured)]
    read = [
        predict_measurements(grid, positions + shift, 0.4, used)
        for shift in ((0.0, 0.0), (7.0, 0.0), (0.0, 7.0))
    ]
    expected = sum(np.nanmean((moved - read[0]) ** 2) for moved in read[1:]) / 12.0
    got = shift_field_variance(grid, positions, 0.4, offsets, measured, 7.0)
    assert np.isnan(read[0]).any()  # some beams off the map
    assert got == pytest.approx(expected, rel=1e-12)
    x, y = np.meshgrid(np.arange(50) * 10.0, np.arange(40) * 10.0)
    plane = Grid(0.3 * x - 0.2 * y, 0.0, 0.0, 10.0, 10.0)
    inside = np.array([[200.0, 150.0], [260.0, 210.0]])
    assert shift_field_variance(plane, inside, 0.0, offsets[3:6], measured[3:6], 5.0) == (
        pytest.approx((0.3**2 + 0.2**2) * 25.0 / 12.0, rel=1e-12)
    )
