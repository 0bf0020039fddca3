"""TERCOM: exact recovery on a noiseless map, metrics, integrity, errors."""

import dataclasses

import numpy as np
import pytest

from geofix.errors import ConfigError, MatchError
from geofix.maps.grid import Grid
from geofix.maps.synthetic import fractal_terrain
from geofix.match.tercom import Tercom
from geofix.measurement import predict_track
from geofix.methods import parse_method_spec
from geofix.problem import MatchProblem


def _rough_grid(rng, shape=(200, 220), cell=10.0):
    """A smooth random surface (sum of random sinusoids), metres."""
    ny, nx = shape
    yy, xx = np.mgrid[0:ny, 0:nx] * cell
    z = np.zeros(shape)
    for _ in range(12):
        k = rng.uniform(0.002, 0.02, size=2)
        z += rng.normal(0, 3) * np.sin(k[0] * xx + k[1] * yy + rng.uniform(0, 6.3))
    return Grid(z - 100.0, x0=0.0, y0=0.0, dx=cell, dy=cell, kind="depth", units="m")


def _problem(grid, truth, offset, heading=0.3, offsets=None, noise=0.0, rng=None, sigma=30.0):
    offsets = np.zeros((1, 2)) if offsets is None else offsets
    psi = np.full(len(truth), heading)
    from geofix.problem import footprint_xy

    fx, fy = footprint_xy(truth, psi, offsets)
    measured = grid.sample(fx, fy)
    if noise:
        measured = measured + rng.normal(0, noise, measured.shape)
    return MatchProblem(
        grid=grid,
        indicated=truth + offset,
        heading=psi,
        offsets=offsets,
        measured=measured,
        sigma_position=np.full(len(truth), sigma),
        times=np.arange(len(truth)) * 10.0,
        noise_std=noise,
    )


def _line(start, heading, step, n):
    t = np.arange(n)[:, None] * step
    return np.asarray(start) + t * np.array([np.sin(heading), np.cos(heading)])


@pytest.mark.parametrize("metric", ["msd", "mad", "ncor", "cmsd"])
def test_finds_known_offset_exactly_on_noiseless_map(metric):
    rng = np.random.default_rng(1)
    grid = _rough_grid(rng)
    truth = _line((700.0, 600.0), 0.3, 25.0, 30)
    offset = np.array([-40.0, 70.0])  # whole cells: the candidate grid contains the truth
    fix = Tercom(metric=metric).match(_problem(grid, truth, offset), rng)
    np.testing.assert_allclose(fix.track, truth, atol=1e-9)
    assert not fix.ambiguous


def test_cmsd_fix_and_covariance_ignore_a_constant_field_offset():
    """A tide or gravimeter bias added to every reading: cmsd's fix, covariance and cost
    are those without it, while msd's fix moves."""
    rng = np.random.default_rng(4)
    grid = _rough_grid(rng)
    truth = _line((700.0, 600.0), 0.3, 25.0, 30)
    problem = _problem(grid, truth, np.array([-40.0, 70.0]))
    biased = dataclasses.replace(problem, measured=problem.measured + 6.0)
    plain = Tercom(metric="cmsd").match(problem, rng)
    shifted = Tercom(metric="cmsd").match(biased, rng)
    np.testing.assert_allclose(shifted.track, plain.track, atol=1e-9)
    np.testing.assert_allclose(shifted.covariance, plain.covariance, rtol=1e-6)
    assert shifted.cost == pytest.approx(plain.cost, abs=1e-9)
    np.testing.assert_allclose(plain.track, truth, atol=1e-9)
    moved = Tercom(metric="msd").match(biased, rng)
    assert np.hypot(*(moved.track[-1] - truth[-1])) > grid.cell_size


def test_cor_cost_is_the_negated_mean_product():
    rng = np.random.default_rng(6)
    grid = _rough_grid(rng)
    truth = _line((700.0, 600.0), 0.3, 25.0, 20)
    prob = _problem(grid, truth, np.zeros(2))
    fix = Tercom(metric="cor", window_m=1.0).match(prob, rng)  # a single candidate
    expected = -np.mean(prob.measured[:, 0] * grid.sample(truth[:, 0], truth[:, 1]))
    assert fix.cost == pytest.approx(expected, rel=1e-12)


def test_multibeam_uses_every_beam():
    rng = np.random.default_rng(2)
    grid = _rough_grid(rng)
    truth = _line((800.0, 500.0), 1.2, 30.0, 10)
    beams = np.column_stack([np.linspace(-60, 60, 9), np.zeros(9)])
    fix = Tercom().match(_problem(grid, truth, np.array([50.0, -30.0]), offsets=beams), rng)
    np.testing.assert_allclose(fix.track, truth, atol=1e-9)
    assert fix.evaluations > 9 * 10


def test_noisy_fix_is_within_a_cell_and_covariance_is_sane():
    rng = np.random.default_rng(3)
    grid = _rough_grid(rng)
    truth = _line((700.0, 700.0), 2.0, 25.0, 40)
    prob = _problem(grid, truth, np.array([33.0, -47.0]), noise=0.3, rng=rng)
    fix = Tercom().match(prob, rng)
    err = np.hypot(*(fix.track[-1] - truth[-1]))
    assert err <= grid.cell_size
    assert np.all(np.linalg.eigvalsh(fix.covariance) > 0)


def test_flat_map_is_flagged_ambiguous():
    rng = np.random.default_rng(4)
    flat = Grid(np.full((100, 100), -50.0) + rng.normal(0, 1e-3, (100, 100)), 0, 0, 10, 10)
    truth = _line((400.0, 400.0), 0.5, 20.0, 15)
    fix = Tercom().match(_problem(flat, truth, np.array([20.0, 20.0]), noise=0.3, rng=rng), rng)
    assert fix.ambiguous


def test_window_off_map_raises_match_error():
    rng = np.random.default_rng(5)
    grid = _rough_grid(rng, shape=(50, 50))
    truth = _line((100.0, 100.0), 0.0, 10.0, 10)
    prob = _problem(grid, truth, np.array([0.0, 0.0]))
    far = MatchProblem(**{**prob.__dict__, "indicated": truth + 1e6})
    with pytest.raises(MatchError):
        Tercom().match(far, rng)


def test_spec_parsing_and_bad_settings():
    assert parse_method_spec("tercom:metric=mad,window_sigma=2").metric == "mad"
    with pytest.raises(ConfigError, match="metric"):
        parse_method_spec("tercom:metric=bogus")
    with pytest.raises(ConfigError, match="unknown setting"):
        parse_method_spec("tercom:bogus=1")
    with pytest.raises(ConfigError, match="unknown method"):
        parse_method_spec("nosuch")


def test_nadir_beams_match_the_nadir_problem():
    grid = fractal_terrain((120, 120), cell_m=50.0, std=20.0, rng=np.random.default_rng(3))
    truth = np.column_stack([np.linspace(2000, 4000, 30), np.linspace(2500, 3500, 30)])
    heading = np.full(30, np.arctan2(2000, 1000))
    offsets = np.array([[-100.0, 0.0], [0.0, 0.0], [100.0, 0.0]])
    measured = predict_track(grid, truth, heading, offsets)
    problem = MatchProblem(
        grid=grid,
        indicated=truth + np.array([100.0, -50.0]),
        heading=heading,
        offsets=offsets,
        measured=measured,
        sigma_position=np.full(30, 100.0),
        times=np.arange(30.0),
        noise_std=0.5,
        sensor="multibeam",
    )
    nadir = problem.nadir()
    assert nadir.offsets.tolist() == [[0.0, 0.0]] and nadir.measured.shape == (30, 1)
    fix = Tercom(beams="nadir").match(problem)
    ref = Tercom().match(nadir)
    np.testing.assert_array_equal(fix.track, ref.track)
    np.testing.assert_allclose(fix.track[-1], truth[-1], atol=1e-6)
    with pytest.raises(ConfigError):
        Tercom(beams="centre")
