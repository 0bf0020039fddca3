"""The Ziv-Zakai bound with the map's error correlated: the linear answer, modes, refusals."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from conftest import northward_trial
from geofix.evaluate.crlb_correlated import correlated_map_crlb
from geofix.evaluate.zzb import ShiftLadder
from geofix.evaluate.zzb_correlated import correlated_map_zzb
from geofix.maps.grid import Grid


def _plane() -> Grid:
    xx, yy = np.meshgrid(np.arange(400) * 10.0, np.arange(400) * 10.0)
    return Grid(0.08 * xx - 0.05 * yy, 0.0, 0.0, 10.0, 10.0)


@pytest.mark.parametrize(("rms", "corr"), [(0.0, 0.0), (3.0, 300.0)])
def test_on_a_plane_it_is_the_linear_gaussian_posterior_from_below(rms, corr):
    # a linear map and a known offset: d^2 = delta^T G^T R^-1 G delta, and the bound is the
    # posterior (P^-1 + G^T R^-1 G)^-1, which the correlated CRLB computes exactly
    grid = _plane()
    trial = northward_trial(grid, 30, 60.0, (40.0, -25.0), 2.0, np.random.default_rng(1))
    exact = correlated_map_crlb(trial, grid, rms, corr, offset_std=0.0)
    bound = correlated_map_zzb(trial, grid, rms, corr, offset_std=0.0)
    assert bound <= exact * (1 + 1e-9)
    assert bound == pytest.approx(exact, rel=0.03)
    fine = correlated_map_zzb(trial, grid, rms, corr, 0.0, ladder=ShiftLadder(outer_nodes=801))
    assert abs(fine - exact) < abs(bound - exact)


def test_an_unknown_offset_and_a_persisting_error_each_tell_less():
    # a bowl: the readings' shape along the track tells the position, their level too
    # while the offset is known; both the offset and an error common to neighbouring
    # readings take from what the level told
    xx, yy = np.meshgrid(np.arange(400) * 10.0, np.arange(400) * 10.0)
    grid = Grid(1e-4 * ((xx - 1700.0) ** 2 + (yy - 1500.0) ** 2), 0.0, 0.0, 10.0, 10.0)
    trial = northward_trial(grid, 30, 60.0, (40.0, -25.0), 2.0, np.random.default_rng(1))
    known = correlated_map_zzb(trial, grid, 0.0, 0.0, offset_std=0.0)
    offset = correlated_map_zzb(trial, grid, 0.0, 0.0, offset_std=10.0)
    persisting = correlated_map_zzb(trial, grid, 3.0, 2000.0, offset_std=0.0)
    white = correlated_map_zzb(trial, grid, 3.0, 1e-6, offset_std=0.0)
    assert offset > 1.5 * known
    assert persisting > 1.5 * white


def _comb() -> Grid:
    """Ridges every 400 m across a northward track: whole periods read alike."""
    xx, _ = np.meshgrid(np.arange(600) * 10.0, np.arange(600) * 10.0)
    return Grid(30.0 * np.sin(2 * np.pi * xx / 400.0), 0.0, 0.0, 10.0, 10.0)


def test_a_comb_keeps_the_bound_far_above_the_crlb():
    # ridges every 400 m under a 600 m prior: every whole period fits; the CRLB sees only
    # the slopes at the truth
    grid = _comb()
    trial = northward_trial(grid, 20, 600.0, (0.0, 0.0), 2.0, np.random.default_rng(7))
    crlb = correlated_map_crlb(trial, grid, 2.0, 500.0, offset_std=5.0)
    bound = correlated_map_zzb(trial, grid, 2.0, 500.0, offset_std=5.0)
    # y keeps its prior (600^2) in both; the ZZB's x variance is of the order of a period
    assert crlb - 600.0**2 < 20.0**2
    assert bound - 600.0**2 > 100.0**2


def test_a_second_field_and_a_bad_correlation_are_refused():
    grid = _plane()
    trial = northward_trial(grid, 10, 60.0, (0.0, 0.0), 2.0, np.random.default_rng(1))
    with pytest.raises(ValueError, match="error_corr_m"):
        correlated_map_zzb(trial, grid, 1.0, 0.0)
    with pytest.raises(ValueError, match="one field"):
        correlated_map_zzb(replace(trial, fields=(object(),)), grid)
    known = replace(trial, sigma_position=np.zeros(10))
    assert correlated_map_zzb(known, grid) == 0.0


def test_a_map_posterior_gives_its_mean_and_covariance_to_both_bounds():
    # a posterior whose covariance is the same between every two readings is a constant
    # offset of that variance more; its mean, not the prior map, is what the readings
    # are compared with (half the plane's slope: a quarter of its information)
    from geofix.maps.error_posterior import MapPosterior

    grid = _plane()
    trial = northward_trial(grid, 30, 60.0, (40.0, -25.0), 2.0, np.random.default_rng(1))
    constant = MapPosterior(grid, np.full((4, 4), 16.0))
    for bound in (correlated_map_crlb, correlated_map_zzb):
        with_posterior = bound(trial, grid, offset_std=3.0, posterior=constant)
        assert with_posterior == pytest.approx(bound(trial, grid, offset_std=5.0), rel=1e-9)
    half = grid.with_values(0.5 * grid.values)
    flatter = MapPosterior(half, np.zeros((4, 4)))
    for bound in (correlated_map_crlb, correlated_map_zzb):
        with_posterior = bound(trial, grid, offset_std=0.0, posterior=flatter)
        as_prior = bound(replace(trial, prior_map=half), grid, offset_std=0.0)
        assert with_posterior == pytest.approx(as_prior, rel=1e-9)
        # a quarter of the information under a prior that stays: 1.33 times the variance
        assert with_posterior > 1.2 * bound(trial, grid, offset_std=0.0)
