"""The compiled point-mass grid loops against their numpy reference expressions."""

import numpy as np
import pytest
from scipy.ndimage import correlate1d

from geofix.filters import _grid_ops as ops
from geofix.filters.pmf import Pmf, PmfState

RTOL = 1e-12  # the compiled sums run in row order, numpy's pairwise


def _log_weight(rng, shape=(31, 27)):
    lw = (
        -0.5
        * rng.uniform(0.0, 60.0)
        * np.add.outer(np.linspace(-1, 1, shape[0]) ** 2, np.linspace(-1.3, 0.7, shape[1]) ** 2)
    )
    lw += rng.normal(0.0, 2.0, shape)
    lw[:3, :4] = -1e6  # off-map nodes
    return lw


def _frame(rng):
    theta = rng.uniform(0, np.pi)
    axes = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    return rng.normal(0.0, 500.0, 2), axes, rng.uniform(0.5, 20.0, 2)


def _numpy_moments(log_weight, centre, axes, spacing):
    w = np.exp(log_weight - log_weight.max())
    w /= w.sum()
    u, v = ops.node_offsets(w.shape, spacing)
    wu, wv = w.sum(axis=1), w.sum(axis=0)
    mu = np.array([wu @ u, wv @ v])
    du, dv = u - mu[0], v - mu[1]
    cuv = du @ w @ dv
    local = np.array([[wu @ du**2, cuv], [cuv, wv @ dv**2]]) + np.diag(spacing**2 / 12.0)
    return centre + axes @ mu, axes @ local @ axes.T


def _numpy_convolve_log(log_weight, kernels):
    top = log_weight.max()
    p = np.exp(log_weight - top)
    p = correlate1d(p, kernels[0], axis=0, mode="constant")
    p = correlate1d(p, kernels[1], axis=1, mode="constant")
    floor = log_weight - top + sum(np.log(k[k.size // 2]) for k in kernels)
    with np.errstate(divide="ignore"):
        logp = np.where(p > 0.0, np.log(np.maximum(p, np.finfo(float).tiny)), -np.inf)
    out = np.maximum(logp, floor) + top
    return out - (out.max() + np.log(np.exp(out - out.max()).sum()))


@pytest.mark.parametrize("seed", range(4))
def test_moments_and_normalise_match_numpy(seed):
    rng = np.random.default_rng(seed)
    lw = _log_weight(rng)
    frame = _frame(rng)
    for got, want in zip(ops.moments(lw, *frame), _numpy_moments(lw, *frame), strict=True):
        np.testing.assert_allclose(got, want, rtol=RTOL, atol=1e-12 * np.abs(want).max())
    expected = lw - (lw.max() + np.log(np.exp(lw - lw.max()).sum()))
    np.testing.assert_allclose(ops.normalise(lw), expected, rtol=RTOL)


@pytest.mark.parametrize("sigmas", [(0.3, 0.5), (2.5, 0.7), (7.0, 40.0)])
def test_convolve_log_matches_the_correlate1d_path(sigmas):
    rng = np.random.default_rng(5)
    lw = ops.normalise(_log_weight(rng) * 30.0)  # deep tails: the floor is used there
    kernels = tuple(ops.motion_kernel(s, n - 1) for s, n in zip(sigmas, lw.shape, strict=True))
    got, want = ops.convolve_log(lw, kernels), _numpy_convolve_log(lw, kernels)
    np.testing.assert_allclose(got, want, rtol=RTOL, atol=1e-12)


def test_support_half_extent_matches_numpy():
    rng = np.random.default_rng(6)
    centre, axes, spacing = _frame(rng)
    lw = ops.normalise(_log_weight(rng))
    state = PmfState(lw, centre, axes, spacing, cell=10.0)
    filt = Pmf()
    point, directions = centre + rng.normal(0.0, 30.0, 2), _frame(rng)[1]
    keep = lw >= lw.max() - filt.support_nats
    xy = ops.node_positions(centre, axes, spacing, lw.shape)[keep]
    want = np.abs((xy - point) @ directions).max(axis=0) + spacing.max()
    got = filt.support_half_extent(state, point, directions)
    np.testing.assert_allclose(got, want, rtol=RTOL)


def _numpy_resample(log_weight, old, new, fallback, shape):
    from scipy.ndimage import map_coordinates

    old_shape = np.array(log_weight.shape)
    xy = ops.node_positions(*new, shape)
    log_density = log_weight - np.log(np.prod(old[2]))
    frac = ((xy - old[0]) @ old[1]) / old[2] + 0.5 * (old_shape - 1)
    inside = np.all((frac >= 0.0) & (frac <= old_shape - 1), axis=-1)
    values = map_coordinates(log_density, np.moveaxis(frac, -1, 0), order=1, mode="nearest")
    outside = np.minimum(ops.gaussian_log_density(xy, *fallback), log_density.min())
    return ops.normalise(np.where(inside, values, outside) + np.log(np.prod(new[2])))


@pytest.mark.parametrize("seed", range(4))
def test_resample_grid_matches_map_coordinates(seed):
    rng = np.random.default_rng(seed)
    lw = ops.normalise(_log_weight(rng))
    old, new = _frame(rng), _frame(rng)
    # the new grid overlaps the old one in part: nodes inside and outside it
    new = (old[0] + rng.normal(0.0, 5.0, 2) * old[2], new[1], old[2] * rng.uniform(0.5, 2.0, 2))
    fallback = (old[0] + rng.normal(0.0, 20.0, 2), np.array([[400.0, 50.0], [50.0, 100.0]]))
    shape = (35, 21)
    got = ops.resample_grid(lw, old, new, fallback, shape)
    want = _numpy_resample(lw, old, new, fallback, shape)
    frac = ((ops.node_positions(*new, shape) - old[0]) @ old[1]) / old[2] + 0.5 * (
        np.array(lw.shape) - 1
    )
    inside = np.all((frac >= 0.0) & (frac <= np.array(lw.shape) - 1), axis=-1)
    assert 0 < inside.sum() < inside.size
    np.testing.assert_allclose(got, want, rtol=RTOL, atol=1e-12)
