"""ICP surface matching and TERCOM-ICP (source 001)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from geofix.errors import ConfigError, MatchError
from geofix.maps.synthetic import fractal_terrain
from geofix.match.icp import Icp, TercomIcp
from geofix.match.rigid import apply_transform, rotation_2d
from geofix.methods import parse_method_spec
from geofix.problem import MatchProblem, footprint_xy

# 17 beams 10 m apart across track: with a north-going track on cell centres every
# footprint of the true track is a grid point, so a noiseless cloud fits the map exactly.
OFFSETS = np.column_stack([10.0 * np.arange(-8, 9), np.zeros(17)])


@pytest.fixture(scope="module")
def rough_map():
    """A 300 x 300 fractal seabed, 10 m cells, depth std 10 m (seed 3)."""
    return fractal_terrain((300, 300), 10.0, rng=np.random.default_rng(3), std=10.0)


def _problem(grid, truth, theta, shift, sigma, noise_std=0.0, bias=0.0, rng=None):
    """Indicated track = the truth rotated by ``theta`` (rad, CCW) about its centre and
    shifted by ``shift`` (m); measurements read (noiselessly unless asked) on the truth."""
    n = truth.shape[0]
    centre = truth.mean(axis=0)
    indicated = apply_transform(truth - centre, rotation_2d(theta), np.asarray(shift)) + centre
    heading = np.zeros(n)
    x, y = footprint_xy(truth, heading, OFFSETS)
    measured = grid.sample(x, y) + bias
    if noise_std > 0:
        measured = measured + noise_std * rng.standard_normal(measured.shape)
    return MatchProblem(
        grid=grid,
        indicated=indicated,
        heading=heading - theta,  # a CCW rotation turns the heading anticlockwise
        offsets=OFFSETS,
        measured=measured,
        sigma_position=np.full(n, float(sigma)),
        times=20.0 * np.arange(n),
        noise_std=noise_std,
        sensor="multibeam",
    )


def _north_track(x=1500.0, y=1000.0, n=10, step=40.0):
    return np.column_stack([np.full(n, x), y + step * np.arange(n)])


def test_icp_recovers_known_rotation_and_translation_exactly(rough_map):
    truth = _north_track()
    problem = _problem(rough_map, truth, np.radians(2.0), (23.0, -17.0), sigma=30.0)
    # the indicated footprints are exactly the rotated and shifted true ones
    fx, fy = problem.footprint(problem.indicated)
    tx, ty = footprint_xy(truth, np.zeros(10), OFFSETS)
    moved = apply_transform(
        np.column_stack([tx.ravel(), ty.ravel()]) - truth.mean(0),
        rotation_2d(np.radians(2.0)),
        np.array([23.0, -17.0]),
    )
    np.testing.assert_allclose(np.column_stack([fx.ravel(), fy.ravel()]) - truth.mean(0), moved)
    fix = Icp().match(problem, np.random.default_rng(0))
    np.testing.assert_allclose(fix.track, truth, atol=1e-6)
    assert fix.diagnostics["converged"]
    assert fix.diagnostics["rotation_deg"] == pytest.approx(-2.0, abs=1e-9)
    assert fix.cost == pytest.approx(0.0, abs=1e-9)
    assert not fix.ambiguous
    assert fix.covariance is not None and np.all(np.linalg.eigvalsh(fix.covariance) > 0)


def test_icp_estimates_a_vertical_offset_when_asked(rough_map):
    truth = _north_track()
    problem = _problem(rough_map, truth, np.radians(-1.0), (-12.0, 8.0), sigma=30.0, bias=2.5)
    fix = Icp(vertical_offset=True).match(problem)
    np.testing.assert_allclose(fix.track, truth, atol=1e-6)
    assert fix.diagnostics["vertical_offset"] == pytest.approx(-2.5, abs=1e-9)


def test_icp_is_sub_cell_with_noise(rough_map):
    truth = _north_track()
    rng = np.random.default_rng(7)
    problem = _problem(rough_map, truth, np.radians(1.0), (15.0, 10.0), 30.0, 0.5, rng=rng)
    fix = Icp().match(problem)
    assert np.max(np.hypot(*(fix.track - truth).T)) < 5.0  # half a cell


def test_tercom_icp_converges_where_icp_alone_is_trapped(rough_map):
    truth = _north_track(x=1400.0, y=1200.0)
    rng = np.random.default_rng(11)
    problem = _problem(rough_map, truth, np.radians(0.5), (260.0, -190.0), 150.0, 0.3, rng=rng)
    alone = Icp().match(problem)
    joint = TercomIcp().match(problem)
    alone_error = np.hypot(*(alone.track[-1] - truth[-1]))
    joint_error = np.hypot(*(joint.track[-1] - truth[-1]))
    assert alone_error > 50.0  # a wrong local minimum far from the truth
    assert alone.ambiguous  # ... and its swath residual says so
    assert joint_error < 5.0  # within half a cell
    coarse_error = np.hypot(*(joint.diagnostics["coarse_track"][-1] - truth[-1]))
    assert joint_error < coarse_error
    assert joint.diagnostics["iterations"] >= 1
    assert not joint.ambiguous
    swath = TercomIcp(coarse_beams="all").match(problem)
    assert np.hypot(*(swath.track[-1] - truth[-1])) < 5.0


def test_nan_soundings_are_skipped(rough_map):
    truth = _north_track()
    problem = _problem(rough_map, truth, np.radians(2.0), (23.0, -17.0), sigma=30.0)
    measured = problem.measured.copy()
    measured[::3, ::2] = np.nan
    fix = Icp().match(dataclasses.replace(problem, measured=measured))
    np.testing.assert_allclose(fix.track, truth, atol=1e-6)


def test_all_nan_soundings_raise(rough_map):
    problem = _problem(rough_map, _north_track(), 0.0, (5.0, 5.0), sigma=30.0)
    empty = dataclasses.replace(problem, measured=np.full(problem.measured.shape, np.nan))
    with pytest.raises(MatchError, match="valid soundings"):
        Icp().match(empty)


def test_window_off_the_map_raises(rough_map):
    problem = _problem(rough_map, _north_track(), 0.0, (5.0, 5.0), sigma=30.0)
    away = dataclasses.replace(problem, indicated=problem.indicated + 1e6)
    with pytest.raises(MatchError, match="off the map"):
        Icp().match(away)


def test_registered_with_settings():
    method = parse_method_spec("tercom-icp:vertical_offset=true,max_iterations=7")
    assert isinstance(method, TercomIcp) and method.vertical_offset and method.max_iterations == 7
    assert isinstance(parse_method_spec("icp"), Icp)
    with pytest.raises(ConfigError):
        parse_method_spec("icp:tolerance_m=-1")
    with pytest.raises(ConfigError, match="coarse_beams"):
        parse_method_spec("tercom-icp:coarse_beams=both")
