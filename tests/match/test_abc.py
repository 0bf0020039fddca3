"""ABC-MHD: the DVL constraint, recovery of a known offset, settings, errors, lag handling."""

import numpy as np
import pytest

from geofix.errors import ConfigError, MatchError
from geofix.maps.synthetic import fractal_terrain
from geofix.match.abc import (
    AbcMhd,
    Colonies,
    PairMisfit,
    average_pair_matches,
    pair_displacements,
    satisfies_displacement,
)
from geofix.methods import parse_method_spec
from geofix.problem import MatchProblem
from geofix.sensors.gravimeter import apply_first_order_lag

HEADING = 1.2  # radians clockwise from north
SPEED, DT = 10.0, 20.0


@pytest.fixture(scope="module")
def gravity_grid():
    """A 200 x 200 fractal gravity field, 100 m cells, std 20 mGal (seed 3)."""
    rng = np.random.default_rng(3)
    return fractal_terrain((200, 200), 100.0, rng=rng, hurst=0.8, std=20.0, kind="gravity")


def _problem(grid, offset, n=40, noise=0.0, lag_s=0.0, seed=0, dvl=True):
    rng = np.random.default_rng(seed)
    step = SPEED * DT * np.array([np.sin(HEADING), np.cos(HEADING)])
    truth = np.array([6000.0, 7000.0]) + np.arange(n)[:, None] * step
    times = np.arange(n) * DT
    measured = grid.sample(truth[:, 0], truth[:, 1])[:, None]
    measured = measured + rng.normal(0.0, noise, measured.shape) if noise else measured
    measured = apply_first_order_lag(measured, times, lag_s)
    dvl_velocity = np.tile(step / DT, (n, 1)) if dvl else None
    problem = MatchProblem(
        grid=grid,
        indicated=truth + np.asarray(offset, float),
        heading=np.full(n, HEADING),
        offsets=np.zeros((1, 2)),
        measured=measured,
        sigma_position=np.full(n, 150.0),
        times=times,
        noise_std=max(noise, 0.1),
        sensor="gravimeter",
        dvl_velocity=dvl_velocity,
    )
    return problem, truth


def test_constraint_rejects_pair_that_breaks_it():
    displacement = np.array([200.0, 0.0])
    good = np.array([0.0, 0.0, 250.0, 20.0])  # b - a = (250, 20): 53.9 m off
    bad = np.array([0.0, 0.0, 200.0, 120.0])  # b - a = (200, 120): 120 m off
    assert satisfies_displacement(good, displacement, 100.0)
    assert not satisfies_displacement(bad, displacement, 100.0)
    assert not satisfies_displacement(good, displacement, 50.0)


def test_colony_scores_a_constraint_breaking_pair_infinite(gravity_grid):
    problem, truth = _problem(gravity_grid, (0.0, 0.0))
    pairs = np.arange(2)
    misfit = PairMisfit(problem, problem.measured, pairs)
    centre = np.concatenate([truth[:2], truth[1:3]], axis=1)
    colony = Colonies(pairs=pairs, centre=centre, half=np.full((2, 4), 500.0))
    displacement = pair_displacements(problem)[pairs]
    exact = centre[:, None, :]  # the true pairs: zero misfit, displacement exact
    broken = exact + np.array([0.0, 0.0, 300.0, 0.0])  # b moved by 3 cells
    f_exact = colony._evaluate(exact, misfit, displacement, 100.0)
    f_broken = colony._evaluate(broken, misfit, displacement, 100.0)
    np.testing.assert_allclose(f_exact, 0.0, atol=1e-9)
    assert np.all(np.isinf(f_broken))


def test_final_sources_all_satisfy_the_dvl_constraint(gravity_grid):
    problem, _ = _problem(gravity_grid, (250.0, -150.0), n=12)
    method = AbcMhd(cycles=30)
    colony = method._search(
        problem, problem.measured, np.arange(11), None, np.random.default_rng(1)
    )
    ok = satisfies_displacement(colony.sources, pair_displacements(problem)[:, None, :], 100.0)
    assert ok.all()


def test_displacement_falls_back_to_ins_without_dvl(gravity_grid):
    problem, _ = _problem(gravity_grid, (0.0, 0.0), n=5, dvl=False)
    np.testing.assert_allclose(pair_displacements(problem), np.diff(problem.indicated, axis=0))


def test_recovers_known_offset_on_noiseless_map(gravity_grid):
    problem, truth = _problem(gravity_grid, (300.0, -200.0))
    fix = AbcMhd().match(problem, np.random.default_rng(0))
    error = np.hypot(*(fix.track - truth).T)
    assert np.median(error) < 50.0  # half a cell; the indicated track is 361 m off
    assert error.mean() < 100.0
    assert fix.track.shape == truth.shape
    assert fix.evaluations > 0


def test_simplified_model_between_full_matches(gravity_grid):
    problem, truth = _problem(gravity_grid, (300.0, -200.0))
    fix = AbcMhd(full_every=4).match(problem, np.random.default_rng(0))
    assert np.median(np.hypot(*(fix.track - truth).T)) < 100.0


def test_lag_compensation_restores_the_unlagged_measurements(gravity_grid):
    lagged, _ = _problem(gravity_grid, (0.0, 0.0), lag_s=60.0)
    clean, _ = _problem(gravity_grid, (0.0, 0.0))
    restored = AbcMhd(lag_s=60.0)._measured(lagged)
    np.testing.assert_allclose(restored, clean.measured, atol=1e-9)
    assert np.abs(lagged.measured - clean.measured).max() > 1.0


def test_average_pair_matches_means_the_two_matches():
    indicated = np.zeros((3, 2))
    chosen = np.array([[0.0, 0.0, 10.0, 0.0], [20.0, 0.0, 30.0, 4.0]])
    track = average_pair_matches(indicated, np.array([0, 1]), chosen)
    np.testing.assert_allclose(track, [[0.0, 0.0], [15.0, 0.0], [30.0, 4.0]])


def test_registered_and_settings_parse():
    method = parse_method_spec("abc-mhd:lag_s=60,full_every=3")
    assert isinstance(method, AbcMhd)
    assert method.lag_s == 60.0 and method.full_every == 3
    with pytest.raises(ConfigError):
        parse_method_spec("abc-mhd:colony_size=3")


def test_all_nan_measurements_raise(gravity_grid):
    problem, _ = _problem(gravity_grid, (0.0, 0.0), n=5)
    import dataclasses

    empty = dataclasses.replace(problem, measured=np.full((5, 1), np.nan))
    with pytest.raises(MatchError):
        AbcMhd().match(empty, np.random.default_rng(0))


def test_off_map_track_raises(gravity_grid):
    problem, _ = _problem(gravity_grid, (1e6, 1e6), n=5)
    with pytest.raises(MatchError):
        AbcMhd(cycles=5).match(problem, np.random.default_rng(0))
