"""The Student-t likelihood per ping: its density, its paths, and what it buys on spikes."""

import dataclasses

import numpy as np
import pytest
from scipy import stats

from conftest import gravity_dvl_mission_data
from geofix.errors import ConfigError
from geofix.filters.offset_sums import ResidualSums
from geofix.measurement import log_likelihood, low_rank_log_likelihood, student_t
from geofix.methods import parse_method_spec
from geofix.sim.scenario import scenario_from_dict
from geofix.sim.simulate import prepare_map, simulate_trial

BEAMS = 6


def _ping(rng, hypotheses=9):
    predicted = rng.normal(50.0, 3.0, (hypotheses, BEAMS))
    measured = rng.normal(50.0, 3.0, BEAMS)
    return predicted, measured, rng.uniform(0.5, 2.0, BEAMS)


@pytest.mark.parametrize("dof", [1.0, 4.0, 30.0])
def test_the_ping_density_is_the_multivariate_t_of_the_residual_covariance(dof):
    # R + P 1 1^T + M M^T as the t's scale matrix; the constant log det R is dropped, so
    # the hypotheses' differences are compared
    rng = np.random.default_rng(1)
    predicted, measured, var = _ping(rng)
    bias_var = 4.0
    modes = np.column_stack([np.linspace(-1.0, 1.0, BEAMS), np.ones(BEAMS) * 0.3])
    got = log_likelihood(predicted, measured, var, bias_var, modes, dof)
    shape = np.diag(var) + bias_var + modes @ modes.T
    want = np.array([stats.multivariate_t(p, shape, df=dof).logpdf(measured) for p in predicted])
    np.testing.assert_allclose(got - got[0], want - want[0], atol=1e-9)
    # the plain and the one-offset paths too
    for b, m in ((0.0, None), (bias_var, None)):
        cov = np.diag(var) + b
        got = log_likelihood(predicted, measured, var, b, m, dof)
        want = np.array([stats.multivariate_t(p, cov, df=dof).logpdf(measured) for p in predicted])
        np.testing.assert_allclose(got - got[0], want - want[0], atol=1e-9)


def test_many_degrees_of_freedom_give_the_gaussian_and_few_bound_an_outlier():
    rng = np.random.default_rng(2)
    predicted, measured, var = _ping(rng)
    gauss = log_likelihood(predicted, measured, var, 1.0)
    near = log_likelihood(predicted, measured, var, 1.0, dof=1e9)
    # off the Gaussian by about q^2 / (4 nu): 2e-5 nats at q = 260
    np.testing.assert_allclose(near, gauss, rtol=1e-6)
    # a hypothesis 40 sigma off costs 800 nats as a Gaussian, a few tens as a t(4)
    q = np.array([0.0, 1600.0])
    gaussian_gap = np.ptp(student_t(q, 0.0, BEAMS, np.inf))
    t_gap = np.ptp(student_t(q, 0.0, BEAMS, 4.0))
    assert gaussian_gap == pytest.approx(800.0)
    assert t_gap < 0.05 * gaussian_gap


@pytest.mark.parametrize("with_own", [False, True])
def test_the_residual_sums_give_the_t_of_the_shifted_predictions(with_own):
    rng = np.random.default_rng(3)
    predicted, measured, var = _ping(rng)
    predicted[2, 1] = np.nan  # off the map: one beam fewer for that hypothesis
    measured[4] = np.nan
    shift = rng.normal(0.0, 2.0, predicted.shape[0])
    own = rng.normal(0.0, 0.7, (predicted.shape[0], BEAMS, 2)) if with_own else None
    if own is not None:
        own[~np.isfinite(predicted)] = 0.0
    got = ResidualSums.of(predicted, measured, var, None, own).log_likelihood(3.0, shift, 4.0)
    common = np.full((BEAMS, 1), np.sqrt(3.0))
    want = low_rank_log_likelihood(predicted + shift[:, None], measured, var, common, own, 4.0)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("bad", [0, -1.0, True, "four"])
def test_a_bad_student_dof_is_refused(bad):
    from geofix.filters.likelihood import check_student_dof

    with pytest.raises(ConfigError, match="student_dof"):
        check_student_dof("pmf", bad)


def _spiked_end_errors(specs, spike: float) -> dict:
    """End errors (m) of four trials of a gravimeter mission with a tenth of its pings
    moved by ``spike`` mGal (either sign), every spec on the same readings."""
    scen = scenario_from_dict(gravity_dvl_mission_data("spikes"))
    grid = prepare_map(scen)
    out = {s: [] for s in specs}
    for i in range(4):
        trial = simulate_trial(scen, grid, i)
        measured = np.array(trial.measured, dtype=float)
        rng = np.random.default_rng(10 + i)
        bad = rng.choice(np.arange(5, measured.shape[0]), measured.shape[0] // 10, replace=False)
        measured[bad] += spike * rng.choice([-1.0, 1.0], size=(bad.size, 1))
        problem = dataclasses.replace(trial, measured=measured).problem(grid)
        for spec in specs:
            fix = parse_method_spec(spec).match(problem, np.random.default_rng(i))
            out[spec].append(np.hypot(*(np.asarray(fix.track)[-1] - trial.truth[-1])))
    return {s: float(np.sqrt(np.mean(np.square(v)))) for s, v in out.items()}


def test_a_t_likelihood_holds_a_gravimeter_filter_through_spikes_at_little_cost():
    # measured: 15 mGal spikes on a tenth of the 1 mGal pings, end RMS pmf 289 m against
    # 158 m with t(4), pf 307 against 168; without spikes 191 against 204, 188 against 200
    specs = ("pmf", "pmf:student_dof=4", "pf", "pf:student_dof=4")
    spiked = _spiked_end_errors(specs, 15.0)
    clean = _spiked_end_errors(specs, 0.0)
    for name in ("pmf", "pf"):
        robust = f"{name}:student_dof=4"
        assert spiked[robust] < 0.7 * spiked[name], spiked
        assert clean[robust] < 1.2 * clean[name], clean
