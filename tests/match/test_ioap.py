"""IOAP: ring geometry against hand-computed cases, exact recovery, start fix, errors."""

import dataclasses

import numpy as np
import pytest

from geofix.errors import ConfigError, MatchError
from geofix.maps.grid import Grid
from geofix.match.ioap import (
    Ioap,
    epmp_layout,
    epmp_ring_count,
    msd_scores,
    ring_sigmas,
    snap_to_nodes,
    spmp_layout,
    translated_msd_scores,
    translated_msd_scores_numpy,
)
from geofix.methods import parse_method_spec
from geofix.problem import MatchProblem

CELL = 100.0


def _smooth_grid(rng, shape=(160, 180), cell=CELL):
    """A smooth random gravity field (sum of random sinusoids), mGal."""
    ny, nx = shape
    yy, xx = np.mgrid[0:ny, 0:nx] * cell
    z = np.zeros(shape)
    for _ in range(14):
        k = rng.uniform(0.0002, 0.002, size=2)
        z += rng.normal(0, 8) * np.sin(k[0] * xx + k[1] * yy + rng.uniform(0, 6.3))
    return Grid(z + 15.0, x0=0.0, y0=0.0, dx=cell, dy=cell, kind="gravity", units="mGal")


def _problem(grid, truth, offset, sigma=300.0, noise=0.0, rng=None):
    measured = grid.sample(truth[:, 0], truth[:, 1], method="nearest")[:, None]
    if noise:
        measured = measured + rng.normal(0, noise, measured.shape)
    n = len(truth)
    return MatchProblem(
        grid=grid,
        indicated=truth + offset,
        heading=np.full(n, np.radians(70.0)),
        offsets=np.zeros((1, 2)),
        measured=measured,
        sigma_position=np.linspace(0.0, sigma, n),
        times=np.arange(n) * 20.0,
        noise_std=noise,
        sensor="gravimeter",
    )


def _line(start, n=60, step=200.0, heading_deg=70.0):
    psi = np.radians(heading_deg)
    t = np.arange(n)[:, None] * step
    return np.asarray(start, float) + t * np.array([np.sin(psi), np.cos(psi)])


def _line_ending_on_node(end_node, n=60, step=200.0, heading_deg=70.0):
    line = _line((0.0, 0.0), n, step, heading_deg)
    return line - line[-1] + np.asarray(end_node, float)


# ---------------------------------------------------------------- ring geometry (hand cases)
def test_spmp_hand_case_sigma0_10_lambda_third_theta_45():
    layout = spmp_layout(10.0, lam=1.0 / 3.0, theta0_deg=45.0)
    np.testing.assert_allclose(layout.radii, [10.0, 20.0, 30.0])
    np.testing.assert_array_equal(layout.counts, [8, 8, 8])
    pts = layout.offsets()
    assert pts.shape == (25, 2)
    s = np.sqrt(0.5)
    np.testing.assert_allclose(pts[0], [0.0, 0.0])  # S1 itself comes first
    np.testing.assert_allclose(pts[1], [10 * s, 10 * s], atol=1e-12)  # i=1, j=1: N45E
    np.testing.assert_allclose(pts[2], [10.0, 0.0], atol=1e-12)  # j=2: due east
    np.testing.assert_allclose(pts[4], [0.0, -10.0], atol=1e-12)  # j=4: due south
    np.testing.assert_allclose(pts[6], [-10.0, 0.0], atol=1e-12)  # j=6: due west
    np.testing.assert_allclose(pts[8], [0.0, 10.0], atol=1e-12)  # j=8: 360 deg, north
    np.testing.assert_allclose(pts[9], [20 * s, 20 * s], atol=1e-12)  # i=2, j=1
    np.testing.assert_allclose(pts[24], [0.0, 30.0], atol=1e-12)  # i=3, j=8


@pytest.mark.parametrize(
    ("sigma", "xi", "expected"),
    [(250.0, 3, 9), (250.0, 2, 6), (250.0, 1, 3), (300.0, 3, 9), (301.0, 3, 12), (10.0, 1, 3)],
)
def test_epmp_ring_count_rounds_up_to_multiple_of_three(sigma, xi, expected):
    assert epmp_ring_count(sigma, CELL, xi) == expected


@pytest.mark.parametrize(
    ("reference", "r_ref", "counts"),
    [
        # sigma 250 m, C 100 m, xi 3 -> M = ceil(7.5) = 8 -> M' = 9; phi = C / R_ref;
        # points per ring = floor(2 pi / spacing), spacing 2 phi / phi / phi / 2
        (1.0, 300.0, (9, 18, 37)),  # phi = 1/3: floor(9.42), floor(18.85), floor(37.70)
        (1.5, 450.0, (14, 28, 56)),  # phi = 2/9: floor(14.14), floor(28.27), floor(56.55)
        (2.0, 600.0, (18, 37, 75)),  # phi = 1/6: floor(18.85), floor(37.70), floor(75.40)
        (2.5, 750.0, (23, 47, 94)),  # phi = 2/15: floor(23.56), floor(47.12), floor(94.25)
    ],
)
def test_epmp_hand_case_counts_radii_angles(reference, r_ref, counts):
    layout = epmp_layout(250.0, CELL, sigma_multiple=3, reference=reference)
    np.testing.assert_allclose(layout.radii, CELL * np.arange(1, 10))
    assert layout.reference_radius == pytest.approx(r_ref)
    phi = CELL / r_ref
    assert layout.base_angle == pytest.approx(phi)
    np.testing.assert_allclose(layout.spacing, np.repeat([2 * phi, phi, phi / 2], 3))
    np.testing.assert_array_equal(layout.counts, np.repeat(counts, 3))
    pts = layout.offsets()
    assert pts.shape == (1 + 3 * sum(counts), 2)
    # first point of ring 1 at 2 phi clockwise from north; first of ring 4 at phi, radius 4C
    np.testing.assert_allclose(pts[1], CELL * np.array([np.sin(2 * phi), np.cos(2 * phi)]))
    first_middle = 1 + 3 * counts[0]
    np.testing.assert_allclose(pts[first_middle], 4 * CELL * np.array([np.sin(phi), np.cos(phi)]))
    np.testing.assert_allclose(np.hypot(*pts[-1]), 9 * CELL)


def test_snap_to_nodes_keeps_first_and_removes_duplicates(rng):
    grid = _smooth_grid(rng, shape=(20, 20))
    nodes = snap_to_nodes(grid, np.array([[310.0, 240.0], [290.0, 210.0], [140.0, 160.0]]))
    np.testing.assert_allclose(nodes, [[300.0, 200.0], [100.0, 200.0]])


def test_ring_sigmas_from_prior():
    assert ring_sigmas(np.array([0.0, 4.0, 50.0, 40.0])) == (4.0, 50.0)
    assert ring_sigmas(np.array([3.0, 5.0, 9.0])) == (4.0, 9.0)  # drift over one interval
    assert ring_sigmas(np.array([7.0])) == (0.0, 7.0)


# ---------------------------------------------------------------- matching
@pytest.mark.parametrize("offset", [(-300.0, 500.0), (0.0, 0.0), (600.0, -200.0)])
def test_finds_exact_end_point_on_noiseless_map(rng, offset):
    grid = _smooth_grid(rng)
    truth = _line_ending_on_node((12000.0, 9000.0))
    fix = Ioap().match(_problem(grid, truth, np.array(offset)), rng)
    np.testing.assert_allclose(fix.track, truth, atol=1e-9)
    assert fix.cost == 0.0
    assert not fix.ambiguous
    assert fix.covariance.shape == (2, 2)


def test_noisy_map_end_fix_within_two_cells(rng):
    grid = _smooth_grid(rng)
    truth = _line((4000.0, 3000.0), n=110)
    problem = _problem(grid, truth, np.array([-430.0, 260.0]), noise=1.0, rng=rng)
    fix = Ioap().match(problem, rng)
    assert np.hypot(*(fix.track[-1] - truth[-1])) < 2 * CELL


def test_one_sigma_searches_fewer_candidates_than_three_sigma(rng):
    grid = _smooth_grid(rng)
    truth = _line_ending_on_node((12000.0, 9000.0))
    problem = _problem(grid, truth, np.array([100.0, 100.0]))
    small = Ioap(sigma_multiple=1).match(problem, rng).diagnostics["candidates"]
    large = Ioap(sigma_multiple=3).match(problem, rng).diagnostics["candidates"]
    assert 3 * small < large


def test_spmp_picks_ring_point_matching_first_measurement(rng):
    grid = _smooth_grid(rng)
    truth = _line((4000.0, 3000.0))  # S1 on a node
    problem = _problem(grid, truth, np.zeros(2))
    s1 = problem.indicated[0]
    target = s1 + np.array([100.0, 0.0])  # ring 1 (radius 3 sigma0 / 3 = 1 cell), j = 2
    g1 = grid.sample(target[0], target[1], method="nearest")
    measured = problem.measured.copy()
    measured[0] = g1
    problem = dataclasses.replace(problem, measured=measured)
    np.testing.assert_allclose(Ioap().start_fix(problem, sigma0=100.0), target)
    # S1 itself wins ties: with its own value it is chosen first
    measured[0] = grid.sample(s1[0], s1[1], method="nearest")
    problem = dataclasses.replace(problem, measured=measured)
    np.testing.assert_allclose(Ioap().start_fix(problem, sigma0=100.0), s1)


def test_anchor_tracks_start_at_start_fix_and_end_on_candidates(rng):
    grid = _smooth_grid(rng)
    truth = _line((4000.0, 3000.0))
    problem = _problem(grid, truth, np.zeros(2))
    ends = np.array([[truth[-1, 0] + 300, truth[-1, 1]], [truth[-1, 0], truth[-1, 1] - 200]])
    tracks = Ioap(track_shape="anchor").candidate_tracks(problem, truth[0], ends)
    np.testing.assert_allclose(tracks[:, 0], [truth[0], truth[0]])
    np.testing.assert_allclose(tracks[:, -1], ends)
    moved = Ioap().candidate_tracks(problem, truth[0], ends)
    np.testing.assert_allclose(
        moved - problem.indicated, np.repeat((ends - truth[-1])[:, None], 60, 1)
    )


def test_nan_measurements_are_skipped(rng):
    grid = _smooth_grid(rng)
    truth = _line_ending_on_node((12000.0, 9000.0))
    problem = _problem(grid, truth, np.array([200.0, -100.0]))
    measured = problem.measured.copy()
    measured[::7] = np.nan
    fix = Ioap().match(dataclasses.replace(problem, measured=measured), rng)
    np.testing.assert_allclose(fix.track, truth, atol=1e-9)


def test_errors(rng):
    grid = _smooth_grid(rng)
    truth = _line_ending_on_node((12000.0, 9000.0))
    problem = _problem(grid, truth, np.zeros(2))
    with pytest.raises(MatchError):
        Ioap().match(dataclasses.replace(problem, measured=np.full((60, 1), np.nan)), rng)
    with pytest.raises(MatchError):
        Ioap().match(dataclasses.replace(problem, indicated=problem.indicated + 1e6), rng)
    with pytest.raises(ConfigError):
        Ioap(reference=4.0)
    with pytest.raises(ConfigError):
        parse_method_spec("ioap:track_shape=bent")


def test_method_spec_sets_variant():
    method = parse_method_spec("ioap:sigma_multiple=2,reference=2.5")
    assert isinstance(method, Ioap)
    assert (method.sigma_multiple, method.reference) == (2.0, 2.5)


def test_translated_scores_equal_generic_nearest_node_scores(rng):
    grid = _smooth_grid(rng)
    truth = _line((4000.0, 3000.0), n=110)
    problem = _problem(grid, truth, np.array([-430.0, 260.0]), noise=1.0, rng=rng)
    ends = snap_to_nodes(grid, truth[-1] + rng.uniform(-2500, 2500, (300, 2)))
    ends = np.vstack([ends, [[-5e4, 0.0]]])  # one candidate off the map
    tracks = Ioap().candidate_tracks(problem, truth[0], ends)
    fast = translated_msd_scores(problem, ends)
    np.testing.assert_allclose(fast, msd_scores(problem, tracks), rtol=1e-12)
    assert np.isnan(fast[-1])


def test_kernel_scores_equal_numpy_reference(rng):
    # a no-data patch in the map, three beams, missing measurements, candidates partly and
    # wholly off the map: the compiled kernel and the numpy path agree on every candidate
    base = _smooth_grid(rng)
    values = base.values.copy()
    values[40:55, 60:80] = np.nan
    grid = Grid(values, x0=0.0, y0=0.0, dx=CELL, dy=CELL, kind="gravity", units="mGal")
    truth = _line((4000.0, 3000.0))
    offsets = np.array([[-150.0, 0.0], [0.0, 0.0], [150.0, 40.0]])
    problem = dataclasses.replace(_problem(grid, truth, np.array([-430.0, 260.0])), offsets=offsets)
    fx, fy = problem.footprint(truth)
    measured = grid.sample(fx, fy, method="nearest") + rng.normal(0.0, 1.0, fx.shape)
    measured[::5, 1] = np.nan
    measured[7] = np.nan
    problem = dataclasses.replace(problem, measured=measured)
    ends = snap_to_nodes(grid, truth[-1] + rng.uniform(-6000, 6000, (600, 2)))
    ends = np.vstack([ends, [[-5e4, 0.0]]])
    discarded = []
    for fraction in (0.9, 0.5):
        kernel = translated_msd_scores(problem, ends, fraction)
        numpy_path = translated_msd_scores_numpy(problem, ends, fraction)
        np.testing.assert_array_equal(np.isnan(kernel), np.isnan(numpy_path))
        np.testing.assert_allclose(kernel, numpy_path, rtol=1e-13, atol=0.0)
        assert np.nanargmin(kernel) == np.nanargmin(numpy_path)
        assert np.isnan(kernel[-1])  # wholly off the map
        assert np.isfinite(kernel).sum() > 100
        discarded.append(int(np.isnan(kernel).sum()))
    assert discarded[0] > discarded[1] > 1  # the min_valid_fraction rule is exercised
