"""ICCP and multipath ICCP: recover a known rigid transform; closest points; errors."""

from __future__ import annotations

import numpy as np
import pytest

from geofix.errors import ConfigError, MatchError
from geofix.maps.synthetic import fractal_terrain, planar_grid
from geofix.match._contours import ContourMap, closest_on_segments
from geofix.match.iccp import Iccp, MultipathIccp
from geofix.methods import parse_method_spec
from geofix.problem import MatchProblem, footprint_xy

N, STEP, HEADING = 15, 12.0, np.radians(60.0)
OFFSETS = np.column_stack([np.linspace(-20, 20, 21), np.zeros(21)])


@pytest.fixture(scope="module")
def terrain():
    return fractal_terrain((320, 320), 1.0, rng=np.random.default_rng(7), std=2.0, hurst=0.7)


def rigid_problem(grid, tx, ty, theta_deg, offsets=OFFSETS):
    """Truth = indicated rotated by theta about indicated[0], then shifted by (tx, ty)."""
    theta = np.radians(theta_deg)
    truth = np.array([130.0, 120.0]) + np.arange(N)[:, None] * STEP * np.array(
        [np.sin(HEADING), np.cos(HEADING)]
    )
    c, s = np.cos(-theta), np.sin(-theta)
    indicated = truth[0] - np.array([tx, ty]) + (truth - truth[0]) @ np.array([[c, -s], [s, c]]).T
    x, y = footprint_xy(truth, np.full(N, HEADING), offsets)
    problem = MatchProblem(
        grid,
        indicated,
        np.full(N, HEADING + theta),
        offsets,
        grid.sample(x, y),
        np.full(N, 10.0),
        np.arange(N) * 4.0,
        sensor="multibeam",
    )
    return problem, truth


@pytest.mark.parametrize("method", [Iccp(), MultipathIccp()])
def test_recovers_a_known_rigid_transform_noiseless(terrain, method):
    problem, truth = rigid_problem(terrain, 6.0, -4.0, 1.5)
    fix = method.match(problem, None)
    assert np.hypot(*(fix.track - truth).T).max() < 0.1
    assert fix.diagnostics["converged"]
    assert np.degrees(fix.diagnostics["rotation_rad"]) == pytest.approx(1.5, abs=0.02)
    assert not fix.ambiguous


def test_single_beam_problem_works_for_both(terrain):
    problem, truth = rigid_problem(terrain, 3.0, 2.0, 0.0, offsets=np.zeros((1, 2)))
    for method in (Iccp(), MultipathIccp()):
        fix = method.match(problem, None)
        assert np.hypot(*(fix.track - truth).T).max() < 0.1


def test_closest_point_on_segments_known_answer():
    a = np.array([[0.0, 0.0], [10.0, 0.0]])
    b = np.array([[10.0, 0.0], [10.0, 10.0]])
    q, d = closest_on_segments(np.array([4.0, 3.0]), a, b)
    np.testing.assert_allclose(q, [4.0, 0.0])
    assert d == pytest.approx(3.0)
    q, d = closest_on_segments(np.array([13.0, 14.0]), a, b)
    np.testing.assert_allclose(q, [10.0, 10.0])
    assert d == pytest.approx(5.0)


def test_contours_of_a_plane_are_straight_lines():
    grid = planar_grid((40, 40), 2.0, slope_x=0.5, offset=-100.0)
    contours = ContourMap(grid.x0, grid.y0, grid.dx, grid.dy, grid.values)
    targets, dist = contours.closest(np.array([[31.0, 20.0]]), np.array([-90.0]))
    np.testing.assert_allclose(targets, [[20.0, 20.0]], atol=1e-9)  # -100 + 0.5 x = -90
    assert dist[0] == pytest.approx(11.0)


def test_flat_map_raises_match_error(terrain):
    problem, _ = rigid_problem(terrain, 0.0, 0.0, 0.0)
    flat = planar_grid((320, 320), 1.0, offset=-100.0)
    with pytest.raises(MatchError):
        Iccp().match(
            MatchProblem(
                flat,
                problem.indicated,
                problem.heading,
                OFFSETS,
                problem.measured,
                problem.sigma_position,
                problem.times,
            ),
            None,
        )


def test_settings_are_validated_and_parsed():
    with pytest.raises(ConfigError):
        MultipathIccp(weights=(0.2, 0.5, 0.3))
    with pytest.raises(ConfigError):
        Iccp(max_iterations=0)
    method = parse_method_spec("iccp-multipath:side_offset_m=5,max_iterations=20")
    assert method.side_offset_m == 5.0 and method.max_iterations == 20
