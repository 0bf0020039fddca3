"""The local field variance: each hypothesis's own discretisation noise, common to its beams.

Known answers: the compiled pass equals the multivariate normal density of covariance
``R + D D^T / 12`` (+ ``P 1 1^T`` with a common offset) written out as a dense matrix, and
the prediction-array reference; with no field change in the share it is the plain
likelihood. Its job: a node a fraction of its cell off the truth on rough terrain keeps its
weight against a chance fit on flat ground, which one global variance takes from it.
"""

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from geofix.errors import ConfigError
from geofix.filters.base import Observation
from geofix.filters.likelihood import spread_field_variance
from geofix.filters.mpf import Mpf
from geofix.filters.pf import Pf, PfState
from geofix.filters.pmf import Pmf
from geofix.maps.grid import Grid
from geofix.measurement import (
    hypotheses_log_likelihood,
    local_field_log_likelihood,
    local_field_reference,
    node_grid_local_log_likelihood,
    predict_measurements,
)

BEAMS = 9


def particle_log_likelihood(filt, grid, state, obs, rng):
    """The filter's terrain likelihood of a particle state's particles."""
    return filt.likelihood.particles(
        grid, obs, state.particles, state.spacing, state.cell, state.offset, rng
    )


def _map(rng) -> Grid:
    values = np.cumsum(np.cumsum(rng.standard_normal((50, 60)), axis=0), axis=1)
    return Grid(values=values, x0=0.0, y0=0.0, dx=20.0, dy=20.0)


def _case(rng):
    offsets = np.stack([np.linspace(-80.0, 80.0, BEAMS), np.zeros(BEAMS)], axis=1)
    measured = rng.normal(0.0, 20.0, BEAMS)
    measured[3] = np.nan  # a missing beam
    positions = rng.uniform(150.0, 800.0, (40, 2))
    positions[0] = (-300.0, 400.0)  # every footprint off the map
    return offsets, measured, rng.uniform(0.5, 4.0, BEAMS), positions


def _dense(grid, positions, heading, offsets, measured, var, sides, bias_var=0.0):
    """The multivariate normal log-density with the full ``b x b`` covariance, per position."""
    use = np.isfinite(measured)
    out = []
    for p in positions:
        f0 = predict_measurements(grid, p[None], heading, offsets)[0][use]
        d = [
            predict_measurements(grid, (p + s)[None], heading, offsets)[0][use] - f0 for s in sides
        ]
        d = np.nan_to_num(np.stack(d, axis=1))
        cov = np.diag(np.broadcast_to(var, measured.shape)[use]) + d @ d.T / 12.0 + bias_var
        log_r = np.sum(np.log(np.broadcast_to(var, measured.shape)[use]))
        # the density up to the common constant (-0.5 log det R - b/2 log 2 pi)
        dens = multivariate_normal(mean=f0, cov=cov).logpdf(measured[use])
        out.append(dens + 0.5 * log_r + 0.5 * use.sum() * np.log(2 * np.pi))
    return np.array(out)


@pytest.mark.parametrize("bias_var", [0.0, 3.0])
def test_local_likelihood_is_the_dense_gaussian(bias_var):
    rng = np.random.default_rng(5)
    grid = _map(rng)
    offsets, measured, var, positions = _case(rng)
    sides = np.array([[14.0, 6.0], [-5.0, 11.0]])
    on_map = positions[1:]
    fused = local_field_log_likelihood(grid, on_map, 0.3, offsets, measured, var, sides, bias_var)
    dense = _dense(grid, on_map, 0.3, offsets, measured, var, sides, bias_var)
    np.testing.assert_allclose(fused, dense, rtol=1e-9)
    reference = local_field_reference(grid, positions, 0.3, offsets, measured, var, sides, bias_var)
    full = local_field_log_likelihood(grid, positions, 0.3, offsets, measured, var, sides, bias_var)
    np.testing.assert_allclose(full, reference, rtol=1e-11)
    assert full[0] == pytest.approx(-1e6 * np.isfinite(measured).sum(), rel=1e-6)


def test_no_field_change_gives_the_plain_likelihood():
    rng = np.random.default_rng(6)
    grid = _map(rng)
    offsets, measured, var, positions = _case(rng)
    plain = hypotheses_log_likelihood(grid, positions, 0.3, offsets, measured, var)
    local = local_field_log_likelihood(
        grid, positions, 0.3, offsets, measured, var, np.zeros((2, 2))
    )
    np.testing.assert_allclose(local, plain, rtol=1e-12)


def _rough_and_flat() -> tuple[Grid, np.ndarray, np.ndarray, np.ndarray]:
    """A map with east-west ridges in the west, flat in the east; a ping, two nodes.

    The swath lies along a ridge (its beams read nearly one value), the ridges rise and
    fall 40 m over 1 km northward; the flat ground lies 3 m (1.5 noise sigmas) off the
    reading. One node is 100 m north of the truth (a quarter of its 400 m cell), the other
    on the flat ground.
    """
    x = np.arange(120) * 100.0
    ridges = 40.0 * np.sin(2.0 * np.pi * x / 2000.0)[:, None] + 0.0 * x[None, :]
    values = np.where(x[None, :] < 6000.0, ridges, 3.0)
    grid = Grid(values=values, x0=0.0, y0=0.0, dx=100.0, dy=100.0)
    offsets = np.stack([np.linspace(-300.0, 300.0, 16), np.zeros(16)], axis=1)
    truth = np.array([3000.0, 6000.0])
    measured = predict_measurements(grid, truth[None], 0.0, offsets)[0]
    measured += np.random.default_rng(3).normal(0.0, 2.0, measured.shape)
    nodes = np.array([truth + np.array([0.0, 100.0]), (9000.0, 6000.0)])
    return grid, offsets, measured, nodes


def test_a_node_near_the_truth_on_rough_terrain_keeps_its_weight():
    grid, offsets, measured, nodes = _rough_and_flat()
    noise_var, heading = 4.0, 0.0
    sides = 400.0 * np.eye(2)
    args = (grid, nodes, heading, offsets, measured)
    local = local_field_log_likelihood(*args, noise_var, sides)
    # the global model: one variance for both, the mean over nodes and beams
    reads = [predict_measurements(grid, nodes + s, heading, offsets) for s in ((0, 0), *sides)]
    spread = sum(np.mean((r - reads[0]) ** 2) for r in reads[1:]) / 12.0
    glob = hypotheses_log_likelihood(*args, noise_var + spread)
    plain = hypotheses_log_likelihood(*args, noise_var)
    # without discretisation noise the node near the truth is lost outright; one global
    # variance leaves the chance fit on the flat ground ahead ...
    assert plain[1] - plain[0] > 100.0
    assert glob[1] > glob[0]
    # ... its own variance puts the node near the truth ahead, by more than 10 nats
    assert local[0] - local[1] > 10.0


@pytest.mark.parametrize(("cls", "default"), [(Pmf, "local"), (Pf, "global"), (Mpf, "global")])
def test_field_variance_is_checked(cls, default):
    assert cls().field_variance == default
    with pytest.raises(ConfigError, match="field_variance"):
        cls(field_variance="wide")


def test_particle_likelihood_follows_the_setting():
    grid, offsets, measured, nodes = _rough_and_flat()  # 100 m map cells
    obs = Observation(measured, nodes[0], 0.0, offsets, 4.0, 0)
    args = (grid, nodes, 0.0, offsets, measured, 4.0)
    weights = np.log([0.5, 0.5])
    local = Pf(field_variance="local")
    # a share one map cell across: each particle's own field variation
    state = PfState(nodes, weights, grid.cell_size, spacing=100.0)
    got = particle_log_likelihood(local, grid, state, obs, np.random.default_rng(0))
    np.testing.assert_array_equal(got, local_field_log_likelihood(*args, 100.0 * np.eye(2)))
    # four cells across: the global variance, drawn as Pf(field_variance="global") draws it
    coarse = PfState(nodes, weights, grid.cell_size, spacing=400.0)
    got = particle_log_likelihood(local, grid, coarse, obs, np.random.default_rng(1))
    want = particle_log_likelihood(Pf(), grid, coarse, obs, np.random.default_rng(1))
    np.testing.assert_array_equal(got, want)
    spread = spread_field_variance(grid, coarse.particles, 400.0, obs, np.random.default_rng(1))
    np.testing.assert_allclose(want, hypotheses_log_likelihood(*args[:-1], 4.0 + spread))
    # a dense set (spacing 0): no discretisation noise
    dense = PfState(nodes, weights, grid.cell_size, spacing=0.0)
    got = particle_log_likelihood(local, grid, dense, obs, np.random.default_rng(0))
    np.testing.assert_array_equal(got, hypotheses_log_likelihood(*args))


@pytest.mark.parametrize("inside", [False, True])
def test_node_grid_local_is_the_reference(inside):
    rng = np.random.default_rng(8)
    grid = _map(rng)
    offsets, measured, var, _ = _case(rng)
    theta = 0.4
    axes = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    # off the map: the western nodes' port beams read off the map (checked reads)
    centre = np.array([600.0, 500.0]) if inside else np.array([60.0, 500.0])
    spacing, shape = np.array([6.3, 4.1]), (21, 17)
    u, v = (np.arange(n) - (n - 1) / 2 for n in shape)
    u, v = u * spacing[0], v * spacing[1]
    fused = node_grid_local_log_likelihood(
        grid, (centre, axes, u, v), spacing, 0.3, offsets, measured, var
    )
    xy = centre + u[:, None, None] * axes[:, 0] + v[None, :, None] * axes[:, 1]
    sides = (axes * spacing).T
    reference = local_field_reference(grid, xy, 0.3, offsets, measured, var, sides)
    np.testing.assert_allclose(fused, reference, rtol=1e-9, atol=1e-6)
    assert (fused < -1e5).any() != inside  # off-map beams present only when not inside


@pytest.mark.parametrize("spacing", [100.0, 0.0])
def test_several_walk_rates_read_the_map_once_with_each_rate_s_numbers(spacing):
    """A particle's likelihood under its walk rates: each rate's, as if computed alone.

    A share one map cell across takes each particle's own field variation; a dense set
    (spacing 0) none.
    """
    from scipy.special import logsumexp

    from geofix.filters.hypothesis_offset import HypothesisOffset

    grid, offsets, measured, nodes = _rough_and_flat()  # 100 m map cells
    rng = np.random.default_rng(3)
    points = nodes[:1] + rng.uniform(-150.0, 150.0, (12, 2))
    obs = Observation(measured, nodes[0], 0.0, offsets, 4.0, 0)
    means = rng.normal(0.0, 2.0, (2, points.shape[0]))
    log_prob = np.log(np.stack([np.full(12, 0.3), np.full(12, 0.7)]))
    offset = HypothesisOffset(means, np.array([0.5, 3.0]), np.array([1e-3, 1e-2]), log_prob)
    filt = Pf(field_variance="local")
    weights = np.full(12, -np.log(12))
    state = PfState(points, weights, grid.cell_size, spacing=spacing, offset=offset)
    got = particle_log_likelihood(filt, grid, state, obs, rng)
    args = (grid, points, 0.0, offsets, measured, 4.0)
    each = []
    for var, mean in zip(offset.variances, means, strict=True):
        if spacing > 0:
            each.append(local_field_log_likelihood(*args, 100.0 * np.eye(2), var, mean))
        else:
            each.append(hypotheses_log_likelihood(*args, var, mean))
    want = logsumexp(np.stack(each) + log_prob, axis=0)
    np.testing.assert_allclose(got, want, rtol=1e-12)
    # the rates do differ: a mixture, not one rate's numbers twice
    assert np.max(np.abs(each[0] - each[1])) > 0.1
