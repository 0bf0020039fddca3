"""The genie-aided bound: a known answer on a plane, the modes of a periodic map."""

import numpy as np
import pytest

from conftest import northward_trial
from geofix.evaluate.ambiguity import AmbiguityGrid, genie_track, likelihood_width, track_bound
from geofix.evaluate.crlb import recursive_bound, trial_information
from geofix.maps.grid import Grid


def test_on_a_plane_the_genie_variance_is_the_kalman_covariance():
    # linear map, Gaussian prior, no drift: the posterior is Gaussian whatever the
    # readings, with the information filter's covariance (the CRLB recursion, no noise)
    gx, gy = 0.08, -0.05
    xx, yy = np.meshgrid(np.arange(400) * 10.0, np.arange(400) * 10.0)
    grid = Grid(gx * xx + gy * yy, 0.0, 0.0, 10.0, 10.0)
    rng = np.random.default_rng(1)
    trial = northward_trial(grid, 12, 60.0, (40.0, -25.0), 2.0, rng)
    genie = genie_track(trial, grid, 4.0).variance
    info = trial_information(trial, grid, 4.0)
    kalman = np.trace(recursive_bound(info, np.zeros(12), 60.0**2), axis1=1, axis2=2)
    resolved = np.isfinite(genie)
    assert resolved[:6].all()  # the prior's perpendicular direction keeps it wide
    np.testing.assert_allclose(genie[resolved], kalman[resolved], rtol=2e-3)


def test_a_periodic_map_keeps_the_genie_far_above_the_crlb():
    # ridges every 400 m across a northward track: every offset of a whole period
    # reads the same, so the posterior keeps several modes while the CRLB shrinks
    xx, _ = np.meshgrid(np.arange(600) * 10.0, np.arange(600) * 10.0)
    grid = Grid(30.0 * np.sin(2 * np.pi * xx / 400.0), 0.0, 0.0, 10.0, 10.0)
    rng = np.random.default_rng(2)
    # a 20 m noise: each mode ~10 m wide after 20 readings, resolved by 10 m nodes
    trial = northward_trial(grid, 20, 600.0, (150.0, 0.0), 20.0, rng)
    genie, squared = genie_track(trial, grid, 400.0, AmbiguityGrid(max_nodes=601))
    info = trial_information(trial, grid, 400.0)
    crlb = np.trace(recursive_bound(info, np.zeros(20), 600.0**2), axis1=1, axis2=2)
    # along x the modes 400 m apart under a 600 m prior: a variance of order 400^2,
    # the CRLB's x variance is tens of m^2; along y the prior stays (no information)
    assert np.isfinite(genie).all()
    x_genie = genie - 600.0**2
    x_crlb = crlb - 600.0**2
    assert x_genie[-1] > 100.0**2
    assert x_crlb[-1] < 20.0**2
    # the posterior mean of a comb under a wide prior sits near the prior's mean: its
    # error is about the drawn x offset (150 m) plus y's prior-sized miss
    assert np.isfinite(squared).all()
    combined = track_bound(crlb[None], genie[None])
    np.testing.assert_array_equal(combined, np.fmax(crlb, genie))


def test_a_known_start_or_a_resolved_posterior_leaves_the_crlb():
    xx, yy = np.meshgrid(np.arange(300) * 10.0, np.arange(300) * 10.0)
    grid = Grid(np.sin(xx / 70.0) * np.cos(yy / 90.0) * 40.0, 0.0, 0.0, 10.0, 10.0)
    rng = np.random.default_rng(3)
    trial = northward_trial(grid, 15, 30.0, (5.0, 5.0), 0.5, rng)
    genie = genie_track(trial, grid, 0.25).variance
    # a rugged map and a sharp sensor: the posterior falls within a few nodes, and the
    # grid stops reporting from there on
    first_nan = int(np.argmax(~np.isfinite(genie)))
    assert not np.isfinite(genie[first_nan:]).any()
    assert first_nan < 15
    crlb = np.full(15, 7.0)
    assert track_bound(crlb, genie)[first_nan:] == pytest.approx(7.0)
    # over trials, one whose grid no longer resolves its posterior counts 0
    two = np.vstack([genie, np.full(15, 1e9)])
    two[1, 0] = np.nan
    combined = track_bound(np.full((2, 15), 7.0), two)
    assert combined[0] == pytest.approx(max(7.0, 0.5 * genie[0]))
    assert combined[-1] == pytest.approx(0.5e9)


def test_the_genie_squared_error_averages_to_its_variance_over_prior_draws():
    # start errors drawn from the prior itself: E[|posterior mean - e_0|^2] = MMSE, which
    # on a plane is the (data-independent) Kalman covariance's trace
    xx, yy = np.meshgrid(np.arange(300) * 10.0, np.arange(300) * 10.0)
    grid = Grid(0.08 * xx - 0.05 * yy, 0.0, 0.0, 10.0, 10.0)
    rng = np.random.default_rng(4)
    settings = AmbiguityGrid(max_nodes=401)
    squared, variance = [], []
    for _ in range(200):
        trial = northward_trial(grid, 4, 60.0, 60.0 * rng.standard_normal(2), 2.0, rng)
        track = genie_track(trial, grid, 4.0, settings)
        squared.append(track.squared_error[-1])
        variance.append(track.variance[-1])
    # 200 draws of a sum of two squared normals: relative spread of the mean <= 10 %
    assert np.mean(squared) == pytest.approx(np.mean(variance), rel=0.3)
    # a plane: the same every trial (to the grid's discretisation and +-5 sigma truncation)
    assert np.std(variance) < 1e-3 * np.mean(variance)


def test_bad_settings_and_a_grid_beyond_the_budget_are_refused(monkeypatch):
    from geofix.errors import ConfigError, GeofixError

    with pytest.raises(ConfigError, match="max_nodes"):
        AmbiguityGrid(max_nodes=1)
    with pytest.raises(ConfigError, match="extent_sigmas"):
        AmbiguityGrid(extent_sigmas=0.0)
    xx, yy = np.meshgrid(np.arange(50) * 10.0, np.arange(50) * 10.0)
    grid = Grid(0.1 * xx + 0.0 * yy, 0.0, 0.0, 10.0, 10.0)
    trial = northward_trial(grid, 3, 30.0, (5.0, 5.0), 1.0, np.random.default_rng(5))
    monkeypatch.setenv("GEOFIX_MEMORY_BUDGET", "1MB")
    with pytest.raises(GeofixError, match="genie grid of 801 x 801 nodes"):
        genie_track(trial, grid, 1.0)


def test_a_likelihood_narrower_than_the_nodes_is_not_reported():
    # the same comb with a 1 m noise: modes ~2 m wide against 10 m nodes alias (their
    # sampled weights, so the posterior mean, depend on where the nodes fall)
    xx, _ = np.meshgrid(np.arange(600) * 10.0, np.arange(600) * 10.0)
    grid = Grid(30.0 * np.sin(2 * np.pi * xx / 400.0), 0.0, 0.0, 10.0, 10.0)
    trial = northward_trial(grid, 20, 600.0, (150.0, 0.0), 1.0, np.random.default_rng(2))
    settings = AmbiguityGrid(max_nodes=601)
    width = likelihood_width(trial, grid, np.ones(1))
    step = settings.extent_sigmas * 600.0 / 300
    assert width[0] < 0.5 * step
    assert not np.isfinite(genie_track(trial, grid, 1.0, settings).variance).any()
    # with the guard off the grid reports numbers, and they change with the node count
    off = [
        genie_track(trial, grid, 1.0, AmbiguityGrid(max_nodes=n, min_width_steps=0.0))
        for n in (601, 801)
    ]
    assert np.isfinite(off[0].squared_error[:5]).all()
    assert not np.allclose(off[0].squared_error[:5], off[1].squared_error[:5], rtol=0.05)
