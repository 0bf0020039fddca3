"""The Ziv-Zakai bound: known answers, the modes of a comb, a bound on the exact MMSE."""

import numpy as np
import pytest
from scipy.stats import norm

from conftest import northward_trial
from geofix.evaluate.ambiguity import AmbiguityGrid, genie_track
from geofix.evaluate.crlb import recursive_bound, trial_information
from geofix.evaluate.zzb import (
    ShiftLadder,
    combined_track_bound,
    pair_term,
    ziv_zakai_integral,
    zzb_track,
)
from geofix.maps.grid import Grid


def _comb() -> Grid:
    """Ridges every 400 m across a northward track: whole periods read alike."""
    xx, _ = np.meshgrid(np.arange(600) * 10.0, np.arange(600) * 10.0)
    return Grid(30.0 * np.sin(2 * np.pi * xx / 400.0), 0.0, 0.0, 10.0, 10.0)


def test_the_integral_of_a_gaussian_prior_alone_is_its_variance():
    # no readings: A(h) = 2 Q(h / 2 sigma), and int h/2 A dh = sigma^2; the lower Riemann
    # sum approaches it from below
    sigma = 3.0
    for step, rtol in ((0.5, 0.1), (0.01, 2e-3)):
        h = np.arange(0.0, 12 * sigma, step)
        value = ziv_zakai_integral(h, 2 * norm.sf(h / (2 * sigma)))
        assert value <= sigma**2
        assert value == pytest.approx(sigma**2, rel=rtol)


def test_valley_filling_carries_a_far_bump_to_every_shorter_shift():
    # f is 0 but for a bump of height 0.5 at h = 10: V f = 0.5 on (0, 10], the integral
    # 0.5 * 10^2 / 4; order and repeats of the samples do not matter
    h = np.array([10.0, 2.0, 5.0, 12.0, 5.0])
    f = np.array([0.5, 0.0, 0.0, 0.0, 0.1])
    assert ziv_zakai_integral(h, f) == pytest.approx(0.5 * 100 / 4)
    assert ziv_zakai_integral(h, np.zeros(5)) == 0.0


def test_the_pair_term_is_the_prior_alone_without_readings_and_symmetric():
    u = np.linspace(-20, 20, 41)
    v = np.linspace(-10, 10, 21)
    sd = np.array([4.0, 2.0])
    a = pair_term(np.zeros((41, 21)), u, v, sd)
    expected = 2 * norm.sf(np.hypot(u[:, None] / 4.0, v[None, :] / 2.0) / 2)
    np.testing.assert_allclose(a, expected, rtol=1e-12)
    d2 = np.random.default_rng(0).uniform(0, 9, (41, 21))
    b = pair_term(d2, u, v, sd)
    np.testing.assert_allclose(b, b[::-1, ::-1])
    assert (b <= pair_term(np.zeros_like(d2), u, v, sd) + 1e-15).all()


def test_on_a_plane_the_bound_is_the_kalman_covariance_from_below():
    # linear map, Gaussian prior: d^2 = delta^T J delta and the ZZB is (P^-1 + J)^-1,
    # reached to the Riemann sum's discretisation
    xx, yy = np.meshgrid(np.arange(400) * 10.0, np.arange(400) * 10.0)
    grid = Grid(0.08 * xx - 0.05 * yy, 0.0, 0.0, 10.0, 10.0)
    trial = northward_trial(grid, 12, 60.0, (40.0, -25.0), 2.0, np.random.default_rng(1))
    bound = zzb_track(trial, grid, 4.0)
    info = trial_information(trial, grid, 4.0)
    kalman = np.trace(recursive_bound(info, np.zeros(12), 60.0**2), axis1=1, axis2=2)
    assert (bound <= kalman).all()
    np.testing.assert_allclose(bound, kalman, rtol=0.03)
    # a finer outer grid comes closer
    fine = zzb_track(trial, grid, 4.0, ShiftLadder(outer_nodes=801))
    assert (np.abs(fine - kalman) < np.abs(bound - kalman)).all()


def test_a_comb_keeps_the_bound_far_above_the_crlb_and_below_the_exact_mmse():
    # ridges every 400 m under a 600 m prior: every whole period fits, so the error along
    # x stays of the order of the period while the CRLB's x variance is tens of m^2; the
    # genie's exact posterior (resolved at this noise) gives the MMSE the ZZB must bound
    grid = _comb()
    rng = np.random.default_rng(7)
    bounds, squared = [], []
    for _ in range(40):
        start = 600.0 * rng.standard_normal(2)
        trial = northward_trial(grid, 20, 600.0, start, 20.0, rng)
        bounds.append(zzb_track(trial, grid, 400.0))
        squared.append(genie_track(trial, grid, 400.0, AmbiguityGrid(max_nodes=601)).squared_error)
    bound = np.mean(bounds, axis=0)
    info = trial_information(trial, grid, 400.0)
    crlb = np.trace(recursive_bound(info, np.zeros(20), 600.0**2), axis1=1, axis2=2)
    # y keeps its prior (600^2) in all three; x: the ZZB far above the CRLB
    assert bound[-1] - 600.0**2 > 100.0**2
    assert crlb[-1] - 600.0**2 < 20.0**2
    # the exact MMSE over 40 prior draws (a mean of squared errors: relative spread about
    # sqrt(2 / 40) = 22 %) lies above the bound at every sample
    mmse = np.mean(squared, axis=0)
    spread = np.std(squared, axis=0) / np.sqrt(len(squared))
    assert (mmse + 2 * spread >= bound).all()
    assert bound[-1] > 0.5 * mmse[-1]


def test_off_map_shifts_are_told_apart_and_a_known_start_gives_zero():
    # a prior far wider than the map: shifts whose footprints leave the map would read
    # nothing, so they are not confused with the truth and the bound falls below the prior
    xx, yy = np.meshgrid(np.arange(60) * 10.0, np.arange(60) * 10.0)
    grid = Grid(np.sin(xx / 70.0) * np.cos(yy / 90.0) * 40.0, 0.0, 0.0, 10.0, 10.0)
    trial = northward_trial(grid, 6, 3000.0, (5.0, 5.0), 0.5, np.random.default_rng(3))
    bound = zzb_track(trial, grid, 0.25)
    assert bound[-1] < 0.01 * 2 * 3000.0**2
    known = northward_trial(grid, 6, 0.0, (0.0, 0.0), 0.5, np.random.default_rng(3))
    np.testing.assert_array_equal(zzb_track(known, grid, 0.25), np.zeros(6))


def test_combined_bound_takes_the_larger_per_trial_then_the_mean():
    crlb = np.array([[4.0, 1.0], [2.0, 1.0]])
    zzb = np.array([[1.0, 3.0], [5.0, 0.0]])
    np.testing.assert_allclose(combined_track_bound(crlb, zzb), [4.5, 2.0])


def test_bad_settings_and_a_ladder_beyond_the_budget_are_refused(monkeypatch):
    from geofix.errors import ConfigError, GeofixError

    with pytest.raises(ConfigError, match="outer_nodes"):
        ShiftLadder(outer_nodes=1)
    with pytest.raises(ConfigError, match="ratio"):
        ShiftLadder(ratio=1.0)
    with pytest.raises(ConfigError, match="extent_sigmas"):
        ShiftLadder(extent_sigmas=float("nan"))
    xx, yy = np.meshgrid(np.arange(50) * 10.0, np.arange(50) * 10.0)
    grid = Grid(0.1 * xx + 0.0 * yy, 0.0, 0.0, 10.0, 10.0)
    trial = northward_trial(grid, 3, 30.0, (5.0, 5.0), 1.0, np.random.default_rng(5))
    monkeypatch.setenv("GEOFIX_MEMORY_BUDGET", "1MB")
    with pytest.raises(GeofixError, match="Ziv-Zakai shifts of 301 x 301 nodes"):
        zzb_track(trial, grid, 1.0)
