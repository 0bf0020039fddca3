"""The design effect of fit residuals: independent, shared and persistent errors."""

import numpy as np
import pytest

from geofix.match.integrity import residual_design_effect


def test_independent_residuals_have_a_design_effect_near_one():
    rng = np.random.default_rng(1)
    effects = [residual_design_effect(rng.normal(0, 2.0, (400, 8))) for _ in range(20)]
    assert min(effects) >= 1.0
    # the initial positive sequence adds about 2 rho_1 when the first lag is positive by
    # chance (rho_1 ~ 1/sqrt(400) per ping mean, twice the beams' within term's spread)
    assert np.median(effects) < 1.15


def test_an_error_shared_by_the_beams_of_a_ping_counts_each_ping_once():
    rng = np.random.default_rng(2)
    beams = 20
    shared = rng.normal(0, 3.0, (500, 1)) + rng.normal(0, 0.1, (500, beams))
    assert residual_design_effect(shared) == pytest.approx(beams, rel=0.15)


def test_an_error_persisting_along_the_track_counts_its_correlation_time():
    rng = np.random.default_rng(3)
    rho, n = 0.8, 20000
    x = np.empty(n)
    x[0] = rng.normal()
    for k in range(1, n):
        x[k] = rho * x[k - 1] + np.sqrt(1 - rho**2) * rng.normal()
    # an AR(1) sum's variance: (1 + rho) / (1 - rho) = 9 times the independent one
    assert residual_design_effect(x[:, None]) == pytest.approx((1 + rho) / (1 - rho), rel=0.15)


def test_missing_values_are_left_out_and_too_few_give_one():
    rng = np.random.default_rng(4)
    shared = np.repeat(rng.normal(0, 1.0, (300, 1)), 6, axis=1)
    holed = shared.copy()
    holed[rng.random(holed.shape) < 0.3] = np.nan
    assert residual_design_effect(holed) == pytest.approx(
        np.nanmean(np.isfinite(holed).sum(axis=1) ** 2) / np.isfinite(holed).sum(axis=1).mean(),
        rel=0.1,
    )
    assert residual_design_effect(np.array([[np.nan, 1.0]])) == 1.0
    assert residual_design_effect(np.full((5, 3), 2.0)) == 1.0
