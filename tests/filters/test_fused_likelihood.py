"""The fused map read + likelihood equals the reference path (predictions, then sums) to
1e-13 relative (the same reads, reassociated sums), on seeded maps with no-data holes,
off-map hypotheses and missing beams; the compiled particle loops bit for bit."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.special import logsumexp

import geofix
from geofix.filters import _grid_ops as ops
from geofix.filters import _particle_kernels as particle_kernels
from geofix.filters._weights import log_normalised, systematic_resample
from geofix.filters.base import Observation
from geofix.filters.pf import Pf, PfState
from geofix.filters.pmf import Pmf, PmfState, node_field_variance
from geofix.maps.grid import Grid
from geofix.measurement import (
    hypotheses_log_likelihood,
    local_field_reference,
    log_likelihood,
    node_grid_log_likelihood,
    predict_measurements,
)
from geofix.problem import footprint_xy

BEAMS = 23
RTOL = 1e-13  # reassociated sums over beams and nodes


def _map(rng, dtype=np.float64) -> Grid:
    values = np.cumsum(np.cumsum(rng.standard_normal((60, 70)), axis=0), axis=1)
    values[20:24, 5:8] = np.nan  # a no-data hole
    return Grid(values=values.astype(dtype), x0=-40.0, y0=25.0, dx=20.0, dy=18.0)


def _beams(rng):
    offsets = np.stack([np.linspace(-150.0, 150.0, BEAMS), rng.normal(0.0, 5.0, BEAMS)], 1)
    measured = rng.normal(0.0, 20.0, BEAMS)
    measured[[2, 11]] = np.nan  # missing beams
    return offsets, measured, rng.uniform(0.5, 9.0, BEAMS)


def _frame(theta=0.4, inside=False):
    axes = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    # off the map: the port beams of the western nodes read off the map (checked reads);
    # inside: every footprint on the map (the unchecked reads), the no-data hole still read
    centre = np.array([250.0, 420.0]) if inside else np.array([100.0, 410.0])
    return centre, axes, np.array([6.3, 4.1]), (21, 17)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("per_beam", [False, True])
@pytest.mark.parametrize("field_variance", [False, True])
@pytest.mark.parametrize("inside", [False, True])
def test_node_grid_log_likelihood_is_the_reference(dtype, per_beam, field_variance, inside):
    rng = np.random.default_rng(11)
    grid = _map(rng, dtype)
    offsets, measured, var_b = _beams(rng)
    var = var_b if per_beam else 2.5
    centre, axes, spacing, shape = _frame(inside=inside)
    xy = ops.node_positions(centre, axes, spacing, shape)
    predicted = predict_measurements(grid, xy, 0.7, offsets)
    assert np.isnan(predicted).any() and np.isfinite(predicted).any()
    x, _ = footprint_xy(xy.reshape(-1, 2), np.full(xy.size // 2, 0.7), offsets)
    on_map = (x >= grid.x0) & (x < grid.x0 + (grid.shape[1] - 1) * grid.dx)
    assert on_map.all() == inside
    field = node_field_variance(predicted, measured) if field_variance else 0.0
    reference = log_likelihood(predicted, measured, var + field)
    u, v = ops.node_offsets(shape, spacing)
    fused, fused_field = node_grid_log_likelihood(
        grid, (centre, axes, u, v), 0.7, offsets, measured, var, field_variance
    )
    assert fused_field == pytest.approx(field, rel=RTOL, abs=0.0)
    assert field_variance is False or field > 0
    np.testing.assert_allclose(fused, reference, rtol=RTOL)


@pytest.mark.parametrize("per_beam", [False, True])
def test_hypotheses_log_likelihood_is_the_reference(per_beam):
    rng = np.random.default_rng(12)
    grid = _map(rng)
    offsets, measured, var_b = _beams(rng)
    var = var_b if per_beam else 1.5
    positions = np.array([600.0, 500.0]) + rng.normal(0.0, 400.0, (3, 500, 2))
    reference = log_likelihood(predict_measurements(grid, positions, -1.1, offsets), measured, var)
    fused = hypotheses_log_likelihood(grid, positions, -1.1, offsets, measured, var)
    assert fused.shape == (3, 500)
    assert (reference < -1e5).any()  # some hypotheses read off the map
    np.testing.assert_allclose(fused, reference, rtol=RTOL)
    near = np.array([250.0, 420.0]) + rng.normal(0.0, 20.0, (400, 2))  # all on the map
    reference = log_likelihood(predict_measurements(grid, near, 0.2, offsets), measured, var)
    assert np.isfinite(reference).all() and (reference < -1e5).any()  # the hole is read
    fused = hypotheses_log_likelihood(grid, near, 0.2, offsets, measured, var)
    np.testing.assert_allclose(fused, reference, rtol=RTOL)


def test_pmf_and_pf_updates_are_the_reference_updates():
    rng = np.random.default_rng(13)
    grid = _map(rng)
    offsets, measured, var_b = _beams(rng)
    obs = Observation(measured, np.zeros(2), 0.3, offsets, var_b, 0)
    centre, axes, spacing, shape = _frame(0.1)
    prior = ops.normalise(rng.normal(0.0, 3.0, shape))
    state = PmfState(prior, centre, axes, spacing, cell=19.0)
    xy = ops.node_positions(centre, axes, spacing, shape)
    predicted = predict_measurements(grid, xy, obs.heading, offsets)
    var = var_b + node_field_variance(predicted, measured)
    expected = ops.normalise(prior + log_likelihood(predicted, measured, var))
    got = Pmf(field_variance="global").update(state, obs, grid, None).log_weight
    np.testing.assert_allclose(got, expected, rtol=RTOL, atol=RTOL * np.abs(expected).max())
    # the default: each node's own field change over its cell (one node step per axis)
    sides = (axes * spacing).T
    local = local_field_reference(grid, xy, obs.heading, offsets, measured, var_b, sides)
    expected = ops.normalise(prior + local)
    got = Pmf().update(state, obs, grid, None).log_weight
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())
    particles = np.array([500.0, 500.0]) + rng.normal(0.0, 200.0, (400, 2))
    weights = rng.normal(0.0, 1.0, 400)
    pf_state = PfState(particles, weights, cell=19.0)
    updated = Pf(discretisation_noise=False).update(pf_state, obs, grid, rng)
    ll = log_likelihood(predict_measurements(grid, particles, 0.3, offsets), measured, var_b)
    raw = weights + ll
    want = raw - logsumexp(raw)
    np.testing.assert_allclose(updated.log_weight, want, rtol=RTOL, atol=RTOL * np.abs(want).max())


def test_log_normalised_is_scipys_logsumexp_bit_for_bit():
    rng = np.random.default_rng(14)
    for trial in range(200):
        a = rng.normal(0.0, 10.0 ** rng.uniform(-3, 4), rng.integers(1, 2000))
        if trial % 3 == 0:
            a[rng.integers(0, a.size, 3)] = a.max()  # ties at the maximum
        if trial % 4 == 0:
            a[: a.size // 2] = -1e6  # off-map hypotheses
        np.testing.assert_array_equal(log_normalised(a), a - logsumexp(a))
    with np.errstate(invalid="ignore"):  # -inf - -inf: scipy's answer, NaN
        np.testing.assert_array_equal(log_normalised(np.full(3, -np.inf)), np.full(3, np.nan))


def test_compiled_particle_move_and_resample_are_the_numpy_expressions():
    rng = np.random.default_rng(15)
    particles = rng.normal(0.0, 300.0, (997, 2))
    draws = rng.standard_normal(particles.shape)
    moved = particle_kernels.moved(particles, np.array([3.3, -1.7]), 0.37, draws)
    np.testing.assert_array_equal(moved, particles + np.array([3.3, -1.7]) + 0.37 * draws)
    for count in (1, 50, 997, 3001):
        w = rng.exponential(1.0, 997) ** 3
        w[rng.integers(0, 997, 100)] = 0.0  # empty slices
        w /= w.sum()
        u = rng.random()
        cumulative = np.cumsum(w)
        cumulative[-1] = 1.0
        got = systematic_resample(w, np.random.default_rng(np.random.SeedSequence(0)), count)
        ref = np.random.default_rng(np.random.SeedSequence(0)).random()
        want = np.searchsorted(cumulative, (ref + np.arange(count)) / count, side="right")
        np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(
            particle_kernels.systematic_indices(cumulative, u, count),
            np.searchsorted(cumulative, (u + np.arange(count)) / count, side="right"),
        )


class _ReferencePmf(Pmf):
    """The PMF update of the prediction-array path (predictions, field variance, sums).

    ``field_variance=local``: :func:`local_field_reference` at the nodes, their cells one
    node step along each grid axis.
    """

    def update(self, state, obs, grid, rng):
        if not np.isfinite(obs.values).any():
            return state
        xy = ops.node_positions(*state.frame, state.shape)
        if self.field_variance == "local":
            sides = (state.axes * state.spacing).T
            args = (obs.heading, obs.offsets, obs.values, obs.noise_var, sides)
            ll = local_field_reference(grid, xy, *args)
            return replace(state, log_weight=ops.normalise(state.log_weight + ll))
        predicted = predict_measurements(grid, xy, obs.heading, obs.offsets)
        var = obs.noise_var + node_field_variance(predicted, obs.values)
        log_weight = ops.normalise(state.log_weight + log_likelihood(predicted, obs.values, var))
        return replace(state, log_weight=log_weight)


@pytest.mark.parametrize("field_variance", ["local", "global"])
def test_pmf_track_on_a_seeded_trial_is_the_reference_paths_to_1e9(field_variance):
    scen = geofix.load_scenario("builtin:azores_demo")
    grid = geofix.prepare_map(scen)
    problem = geofix.simulate_trial(scen, grid, 0).problem(grid)
    fast = Pmf(field_variance=field_variance, map_model="exact").match(
        problem, np.random.default_rng(0)
    )
    reference = _ReferencePmf(field_variance=field_variance, map_model="exact").match(
        problem, np.random.default_rng(0)
    )
    np.testing.assert_allclose(fast.track, reference.track, rtol=1e-9)
    np.testing.assert_allclose(fast.covariance, reference.covariance, rtol=1e-9)
