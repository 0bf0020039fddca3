"""The genie-aided bound with the map's error correlated: the linear answer, modes, refusals."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from test_zzb_correlated import _comb, _plane

from conftest import northward_trial
from geofix.evaluate.ambiguity import initial_offset_prior
from geofix.evaluate.crlb_correlated import (
    CorrelatedError,
    correlated_map_crlb,
    reading_covariance,
    trial_beams,
)
from geofix.evaluate.genie_correlated import correlated_map_genie
from geofix.evaluate.zzb_correlated import correlated_map_zzb
from geofix.maps.error_posterior import MapPosterior


@pytest.mark.parametrize(
    ("rms", "corr", "std"), [(0.0, 0.0, 0.0), (3.0, 300.0, 0.0), (0.0, 0.0, 5.0)]
)
def test_on_a_plane_it_is_the_linear_gaussian_posterior(rms, corr, std):
    # a linear map: the start error's posterior is Gaussian, (P0^-1 + G^T R^-1 G)^-1 with
    # G the plane's gradient on every reading and R their covariance
    grid = _plane()
    trial = northward_trial(grid, 30, 60.0, (40.0, -25.0), 2.0, np.random.default_rng(1))
    beams = trial_beams(trial, grid, rms, None)
    error = CorrelatedError(rms, corr)
    cov = reading_covariance(beams, [std], error, trial.truth.shape[0], 0)
    info = beams.gradient.T @ np.linalg.solve(cov, beams.gradient)
    prior = initial_offset_prior(trial)[1]
    exact = float(np.trace(np.linalg.inv(np.linalg.inv(prior) + info)))
    genie = correlated_map_genie(trial, grid, rms, corr, offset_std=std)
    assert genie == pytest.approx(exact, rel=0.01)


def test_on_a_comb_it_keeps_the_modes_the_crlb_does_not_see():
    # ridges every 400 m under a 600 m prior: every whole period fits, so the posterior
    # keeps several of them (its x variance of the order of a period, as the ZZB's)
    grid = _comb()
    trial = northward_trial(grid, 20, 600.0, (0.0, 0.0), 2.0, np.random.default_rng(7))
    crlb = correlated_map_crlb(trial, grid, 2.0, 500.0, offset_std=5.0)
    zzb = correlated_map_zzb(trial, grid, 2.0, 500.0, offset_std=5.0)
    genie = correlated_map_genie(trial, grid, 2.0, 500.0, offset_std=5.0)
    assert genie - 600.0**2 > 100.0**2
    assert genie > crlb + 0.5 * (zzb - crlb)


def test_it_reads_the_posterior_mean_and_charges_its_covariance():
    grid = _plane()
    trial = northward_trial(grid, 30, 60.0, (40.0, -25.0), 2.0, np.random.default_rng(1))
    constant = MapPosterior(grid, np.full((4, 4), 16.0))
    assert correlated_map_genie(trial, grid, offset_std=3.0, posterior=constant) == (
        pytest.approx(correlated_map_genie(trial, grid, offset_std=5.0), rel=1e-9)
    )
    half = grid.with_values(0.5 * grid.values)
    flatter = MapPosterior(half, np.zeros((4, 4)))
    as_prior = correlated_map_genie(replace(trial, prior_map=half), grid, offset_std=0.0)
    assert correlated_map_genie(trial, grid, offset_std=0.0, posterior=flatter) == (
        pytest.approx(as_prior, rel=1e-9)
    )


def test_a_known_start_is_zero_and_a_second_field_is_refused():
    grid = _plane()
    trial = northward_trial(grid, 10, 0.0, (0.0, 0.0), 2.0, np.random.default_rng(1))
    assert correlated_map_genie(trial, grid) == 0.0
    busy = replace(trial, fields=(object(),))
    with pytest.raises(ValueError, match="one field"):
        correlated_map_genie(busy, grid)
