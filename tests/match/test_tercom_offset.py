"""TERCOM weighs a constant offset between the readings and the map in its covariance."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from test_tercom import _line, _problem, _rough_grid

from geofix.errors import ConfigError
from geofix.match._tercom_loop import exact_marginal, marginal_bound_holds
from geofix.match.tercom import Tercom, offset_surfaces
from geofix.sim.scenario import load_scenario, scenario_from_dict
from geofix.sim.simulate import prepare_map, simulate_trial

SCENARIOS = Path(__file__).parents[2] / "benchmarks" / "scenarios"


def _mahalanobis(fix, truth) -> float:
    e = fix.track[-1] - truth[-1]
    return float(np.sqrt(e @ np.linalg.solve(fix.covariance, e)))


def _biased(seed, bias, noise=0.3):
    rng = np.random.default_rng(seed)
    grid = _rough_grid(rng)
    truth = _line((700.0, 600.0), 0.3, 25.0, 30)
    problem = _problem(grid, truth, np.array([-40.0, 70.0]), noise=noise, rng=rng)
    return dataclasses.replace(problem, measured=problem.measured + bias), truth


def test_an_offset_the_msd_fix_follows_is_held_by_the_default_covariance():
    # the bundled Gulf of Alaska gravity map as the seabed, the gravimeter reading it
    # with an offset drawn from the prior (5 mGal): on this trial the msd fix is
    # kilometres off and claims to be within 3 sigma of metres; weighing the offset, the
    # same fix's covariance holds the truth
    scen = load_scenario(SCENARIOS / "imperfect_gravity.yaml")
    scen = scenario_from_dict(
        {**scen.model_dump(), "seabed": {"offset_std": 5.0}}, base_dir=scen.base_dir
    )
    grid = prepare_map(scen)
    trial = simulate_trial(scen, grid, 3)
    problem = trial.problem(grid)
    plain = Tercom(offset_std=0).match(problem)
    weighed = Tercom().match(problem)
    np.testing.assert_array_equal(weighed.track, plain.track)  # the fix is the msd's
    assert np.hypot(*(plain.track[-1] - trial.truth[-1])) > 4 * grid.cell_size
    assert not plain.ambiguous and _mahalanobis(plain, trial.truth) > 5
    assert _mahalanobis(weighed, trial.truth) < 3
    assert weighed.diagnostics["offset_probability"] > 0.5  # the offset is the likelier
    assert plain.diagnostics["offset_probability"] == 0.0


def test_without_an_offset_the_covariance_is_the_msd_surfaces():
    # readings that the map explains without an offset: the offset model pays its price
    # (a free level) and keeps no weight; the covariance is the msd surface's
    problem, truth = _biased(4, 0.0)
    plain = Tercom(offset_std=0).match(problem)
    weighed = Tercom().match(problem)
    np.testing.assert_array_equal(weighed.track, plain.track)
    assert weighed.diagnostics["offset_probability"] < 0.05
    np.testing.assert_allclose(weighed.covariance, plain.covariance, rtol=0.05)
    assert _mahalanobis(weighed, truth) < 3


@pytest.mark.parametrize("route", ["loop", "fft", "direct"])
def test_every_route_gives_the_same_covariance(route):
    problem, _ = _biased(7, 3.0)
    reference = Tercom(route="loop").match(problem)
    fix = Tercom(route=route).match(problem)
    np.testing.assert_allclose(fix.track, reference.track)
    np.testing.assert_allclose(fix.covariance, reference.covariance, rtol=1e-6)
    assert fix.diagnostics["offset_probability"] == pytest.approx(
        reference.diagnostics["offset_probability"], abs=1e-9
    )


def test_joint_pruning_keeps_every_candidate_that_carries_weight():
    # branch-and-bound on both surfaces gives the unpruned values wherever a candidate is
    # kept, and the covariance of the unpruned surfaces
    problem, _ = _biased(9, 1.0)
    matcher = Tercom(window_m=600.0)
    ox, oy = matcher.candidate_offsets(problem)
    weight = matcher._offset_weight(problem)
    margin = matcher._prune_margin(problem)
    msd, marginal, route = offset_surfaces(problem, ox, oy, weight, route="loop", margin=margin)
    full_msd, full_marginal, _ = offset_surfaces(problem, ox, oy, weight, route="loop")
    assert route == "loop"
    kept = np.isfinite(marginal)
    assert 0 < kept.sum() < 0.2 * kept.size  # it prunes, and keeps some
    np.testing.assert_allclose(marginal[kept], full_marginal[kept], rtol=1e-9)
    np.testing.assert_allclose(msd[np.isfinite(msd)], full_msd[np.isfinite(msd)], rtol=1e-9)
    j, k = np.unravel_index(np.nanargmin(full_msd), full_msd.shape)
    assert np.nanargmin(msd) == np.nanargmin(full_msd)
    cov = [
        matcher._integrity(problem, m, ox, oy, (j, k), 1.0, c)[0]
        for m, c in ((msd, marginal), (full_msd, full_marginal))
    ]
    np.testing.assert_allclose(cov[0], cov[1], rtol=1e-9)


def test_the_marginal_cost_of_a_subset_bounds_the_whole():
    # sum_S d^2 - w (sum_S d)^2 / |S| never exceeds the same over all samples
    rng = np.random.default_rng(0)
    for _ in range(200):
        d = rng.normal(rng.normal(0, 5), rng.uniform(0.1, 3), size=40)
        w = rng.uniform(0, 1)
        m = int(rng.integers(1, 40))
        assert marginal_bound_holds(d[:m], d, w)


def test_exact_marginal_is_the_msd_less_the_offset_it_asks():
    rng = np.random.default_rng(1)
    values = np.ascontiguousarray(rng.normal(0, 5, (30, 30)))
    col = rng.uniform(5, 20, 25)
    row = rng.uniform(5, 20, 25)
    h = rng.normal(0, 5, 25)
    kc, kr = np.array([0, 2]), np.array([1, -3])
    out = exact_marginal(values, col, row, h, kc, kr, 0.7, 0.0)
    from geofix.maps.mapread import bilinear_at

    for q in range(2):
        pairs = zip(col, row, strict=True)
        m = np.array([bilinear_at(values, c + kc[q], r + kr[q]) for c, r in pairs])
        d = h - m
        assert out[0, q] == pytest.approx(np.mean(d**2))
        assert out[1, q] == pytest.approx(np.mean(d**2) - 0.7 * np.mean(d) ** 2)


@pytest.mark.parametrize("bad", [-1.0, float("nan"), float("inf"), "5"])
def test_offset_std_must_be_a_number_at_least_zero(bad):
    with pytest.raises(ConfigError, match="offset_std"):
        Tercom(offset_std=bad)


def test_mad_and_cmsd_weigh_no_offset():
    problem, _ = _biased(4, 6.0)
    for metric in ("mad", "cmsd"):
        assert Tercom(metric=metric).match(problem).diagnostics["offset_probability"] == 0.0


def test_the_setting_parses_from_a_method_spec():
    from geofix.methods import parse_method_spec

    assert parse_method_spec("tercom:offset_std=0").offset_std == 0
    assert parse_method_spec("tercom:offset_std=2.5").offset_std == 2.5
    assert parse_method_spec("tercom").offset_std is None


def test_a_noise_beyond_the_float_range_weighs_no_offset_and_flags_the_fix():
    problem, _ = _biased(4, 1.0)
    huge = dataclasses.replace(problem, noise_std=1e300)
    with np.errstate(over="ignore"):
        fix = Tercom().match(huge)
    assert fix.ambiguous and fix.diagnostics["offset_probability"] == 0.0
    assert np.isfinite(fix.covariance).all()
