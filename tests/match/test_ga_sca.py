"""GA-SCA (source 000): recovers a known four-parameter transform, variants, errors."""

from __future__ import annotations

import numpy as np
import pytest

from geofix.errors import ConfigError, MatchError
from geofix.maps.synthetic import fractal_terrain, planar_grid
from geofix.match._affine import adaptive_spacing, nearest_beams, transform_tracks
from geofix.match._ga_fitness import ga_offspring, score_children
from geofix.match.ga_sca import GaSca
from geofix.methods import parse_method_spec
from geofix.problem import MatchProblem, footprint_xy

N, STEP, HEADING = 15, 12.0, np.radians(60.0)
OFFSETS = np.column_stack([np.linspace(-20, 20, 21), np.zeros(21)])


@pytest.fixture(scope="module")
def terrain():
    return fractal_terrain((320, 320), 1.0, rng=np.random.default_rng(7), std=2.0, hurst=0.7)


def make_problem(grid, tx, ty, alpha, theta_deg, noise=0.0, sigma=10.0, seed=0):
    """Truth = indicated transformed by (tx, ty, alpha, theta) about indicated[0]."""
    theta = np.radians(theta_deg)
    truth = np.array([130.0, 120.0]) + np.arange(N)[:, None] * STEP * np.array(
        [np.sin(HEADING), np.cos(HEADING)]
    )
    rel = truth - truth[0]
    c, s = np.cos(-theta), np.sin(-theta)
    indicated = truth[0] - np.array([tx, ty]) + rel @ np.array([[c, -s], [s, c]]).T / alpha
    x, y = footprint_xy(truth, np.full(N, HEADING), OFFSETS)
    measured = grid.sample(x, y) + np.random.default_rng(seed).normal(0, noise, x.shape)
    problem = MatchProblem(
        grid,
        indicated,
        np.full(N, HEADING + theta),
        OFFSETS,
        measured,
        np.full(N, sigma),
        np.arange(N) * 4.0,
        noise_std=noise,
        sensor="multibeam",
    )
    return problem, truth


def test_recovers_translation_rotation_and_scale_noiseless(terrain):
    problem, truth = make_problem(terrain, 14.0, -9.0, 1.01, 1.2)
    fix = GaSca().match(problem, np.random.default_rng(1))
    p = fix.diagnostics["params"]
    assert abs(p["t_x"] - 14.0) < 0.3 and abs(p["t_y"] + 9.0) < 0.3
    assert abs(p["alpha"] - 1.01) < 0.002
    assert abs(np.degrees(p["theta_rad"]) - 1.2) < 0.1
    assert np.hypot(*(fix.track - truth).T).max() < 0.5
    assert fix.diagnostics["generations"] >= fix.diagnostics["iterations"] > 0
    assert not fix.ambiguous


@pytest.mark.parametrize("variant", ["B", "C", "D"])
def test_every_ablation_variant_finds_the_track(terrain, variant):
    problem, truth = make_problem(terrain, -11.0, 6.0, 1.0, 0.0)
    fix = GaSca(variant=variant).match(problem, np.random.default_rng(2))
    assert np.hypot(*(fix.track - truth).T).mean() < 1.0
    assert fix.diagnostics["variant"] == variant


def test_noisy_match_is_within_a_few_cells_and_seeded(terrain):
    problem, truth = make_problem(terrain, 20.0, 15.0, 1.0, 0.5, noise=0.3, sigma=15.0)
    a = GaSca().match(problem, np.random.default_rng(3))
    b = GaSca().match(problem, np.random.default_rng(3))
    np.testing.assert_array_equal(a.track, b.track)
    assert np.hypot(*(a.track - truth).T).mean() < 3.0
    assert a.covariance is not None and np.all(np.linalg.eigvalsh(a.covariance) > 0)


def test_pivot_is_the_first_indicated_point():
    track = np.array([[10.0, 5.0], [20.0, 5.0], [30.0, 5.0]])
    params = np.array([[1.0, 2.0, 2.0, np.pi / 2]])
    out = transform_tracks(track, params, track[0])[0]
    np.testing.assert_allclose(out[0], [11.0, 7.0])
    np.testing.assert_allclose(out[1], [11.0, 27.0])  # 10 m east -> 20 m north


def test_adaptive_spacing_and_beam_choice():
    assert adaptive_spacing(1.45, 1.0, 2.0, 2.0) == pytest.approx(4.9)
    assert adaptive_spacing(0.1, 5.0, 1.0, 2.0) == 5.0  # not more than a cell: one cell
    np.testing.assert_array_equal(nearest_beams(OFFSETS, 4.9), [10, 12, 8])
    np.testing.assert_array_equal(nearest_beams(np.zeros((1, 2)), 4.9), [0])


def test_off_map_and_missing_data_raise(terrain):
    problem, _ = make_problem(terrain, 5.0, 5.0, 1.0, 0.0)
    empty = MatchProblem(
        problem.grid,
        problem.indicated,
        problem.heading,
        OFFSETS,
        np.full(problem.measured.shape, np.nan),
        problem.sigma_position,
        problem.times,
    )
    with pytest.raises(MatchError):
        GaSca(max_generations=2).match(empty, np.random.default_rng(0))
    far = MatchProblem(
        planar_grid((50, 50), 1.0, 0.1, 0.0),
        problem.indicated + 1e5,
        problem.heading,
        OFFSETS,
        problem.measured,
        problem.sigma_position,
        problem.times,
    )
    with pytest.raises(MatchError):
        GaSca(max_generations=2).match(far, np.random.default_rng(0))


def test_settings_are_validated_and_parsed():
    with pytest.raises(ConfigError):
        GaSca(variant="E")
    with pytest.raises(ConfigError):
        GaSca(weights=(0.2, 0.4, 0.4))
    method = parse_method_spec("ga-sca:variant=C,weights=0.6/0.2/0.2,decay=0.9")
    assert method.variant == "C" and method.weights == (0.6, 0.2, 0.2)
    assert method.uses_sca and not method.uses_new_fitness


@pytest.mark.parametrize("variant", ["A", "D"])
def test_compiled_fitness_equals_the_numpy_reference(terrain, variant):
    problem, _ = make_problem(terrain, 14.0, -9.0, 1.01, 1.2, noise=0.3)
    problem.measured[4, 10] = np.nan  # a missing centre beam
    matcher = GaSca(variant=variant)
    ctx = matcher._context(problem)
    rng = np.random.default_rng(5)
    params = rng.uniform(ctx.lower, ctx.upper, size=(300, 4))
    params[:3, :2] = [[1e4, 0.0], [0.0, -1e4], [150.0, 150.0]]  # off the map, or partly
    compiled = matcher._evaluate(ctx, params)
    reference = matcher._evaluate_numpy(ctx, params)
    for got, expected in zip(compiled, reference, strict=True):
        np.testing.assert_array_equal(np.isinf(got), np.isinf(expected))
        ok = np.isfinite(expected)
        assert 0 < ok.sum() < len(params)
        np.testing.assert_allclose(got[ok], expected[ok], rtol=1e-12)


def test_numpy_engine_gives_the_same_fix(terrain):
    problem, _ = make_problem(terrain, 6.0, 4.0, 0.995, -0.8, noise=0.3)
    fast = GaSca(max_generations=60).match(problem, np.random.default_rng(3))
    slow = GaSca(max_generations=60, engine="numpy").match(problem, np.random.default_rng(3))
    np.testing.assert_allclose(fast.track, slow.track, atol=1e-6)
    assert fast.diagnostics["generations"] == slow.diagnostics["generations"]
    assert fast.diagnostics["candidates"] == slow.diagnostics["candidates"]
    with pytest.raises(ConfigError, match="engine"):
        GaSca(engine="fortran")


def test_children_that_copy_a_parent_keep_its_numbers_in_both_engines(terrain):
    problem, _ = make_problem(terrain, 6.0, 4.0, 0.995, -0.8, noise=0.3)
    matcher = GaSca()
    ctx = matcher._context(problem)
    pool = np.random.default_rng(8).uniform(ctx.lower, ctx.upper, size=(210, 4))
    pool_cost, _, pool_mad = matcher._evaluate(ctx, pool)
    settings = (matcher.population, 0.8, 0.2, 0.3, ctx.lower, ctx.upper)
    children, source = ga_offspring(np.random.default_rng(9), pool, pool_cost, *settings)
    numpy_children, numpy_source = GaSca(engine="numpy")._offspring(
        ctx, pool, pool_cost, np.random.default_rng(9)
    )
    np.testing.assert_array_equal(children, numpy_children)
    np.testing.assert_array_equal(source, numpy_source)
    copies = source >= 0
    # 20 % of pairs uncrossed x 0.8^4 unmutated: about 8 % of the 199 children
    assert 5 <= copies.sum() <= 30
    np.testing.assert_array_equal(children[copies], pool[source[copies]])
    assert not any((pool == child).all(axis=1).any() for child in children[~copies])
    cost, mad, scored = score_children(
        children, source, pool_cost, pool_mad, matcher._fitness_args(ctx)
    )
    full_cost, _, full_mad = matcher._evaluate(ctx, children)
    np.testing.assert_array_equal(cost, full_cost)
    np.testing.assert_array_equal(mad, full_mad)
    assert scored == (~copies).sum()
