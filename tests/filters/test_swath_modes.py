"""The map error's shapes across a swath: the basis, the likelihood, the learnt variance."""

from __future__ import annotations

import numpy as np
import pytest

from geofix.filters.nuisance import (
    MAX_PINGS_PER_ERROR,
    MIN_SWATH_BEAMS,
    SwathModes,
    swath_shapes,
)
from geofix.measurement import (
    common_bias_log_likelihood,
    log_likelihood,
    low_rank_log_likelihood,
)


def _across(beams: int = 21, width: float = 200.0) -> np.ndarray:
    """``(b, 2)`` offsets of a swath across track, metres."""
    return np.column_stack([np.linspace(-width / 2, width / 2, beams), np.zeros(beams)])


def test_the_shapes_are_orthonormal_orthogonal_to_the_mean_and_keep_their_sign():
    offsets = _across()
    shapes = swath_shapes(offsets)
    assert shapes is not None and shapes.shape == (21, 2)
    np.testing.assert_allclose(shapes.T @ shapes, np.eye(2), atol=1e-12)
    np.testing.assert_allclose(shapes.sum(axis=0), 0.0, atol=1e-12)
    assert shapes[-1, 0] > 0 > shapes[0, 0]  # a tilt rising to starboard
    # the beams listed the other way round: each beam keeps its shape values
    np.testing.assert_allclose(swath_shapes(offsets[::-1])[::-1], shapes, atol=1e-12)
    # a swath turned by 30 degrees in the body frame: the same shapes along it
    turn = np.array([[np.cos(0.5), -np.sin(0.5)], [np.sin(0.5), np.cos(0.5)]])
    np.testing.assert_allclose(swath_shapes(offsets @ turn.T), shapes, atol=1e-9)


def test_the_unused_beams_carry_no_shape_and_too_few_beams_none():
    offsets = _across()
    used = np.ones(21, bool)
    used[[0, 5, 6]] = False
    shapes = swath_shapes(offsets, used)
    assert np.all(shapes[~used] == 0.0)
    np.testing.assert_allclose(shapes[used].T @ shapes[used], np.eye(2), atol=1e-12)
    assert swath_shapes(_across(MIN_SWATH_BEAMS - 1)) is None
    assert swath_shapes(np.zeros((21, 2))) is None  # footprints that do not spread


def test_the_low_rank_likelihood_is_the_dense_gaussian(rng):
    beams = 12
    predicted = rng.normal(size=(4, 3, beams))
    measured = rng.normal(size=beams)
    measured[3] = np.nan  # a missing beam
    var = rng.uniform(0.5, 2.0, beams)
    modes = rng.normal(size=(beams, 2))
    got = log_likelihood(predicted, measured, var, 1.5, modes)
    ok = np.isfinite(measured)
    z = np.column_stack([np.full(beams, np.sqrt(1.5)), modes])[ok]
    cov = np.diag(var[ok]) + z @ z.T
    for index in np.ndindex(4, 3):
        r = (measured - predicted[index])[ok]
        dense = r @ np.linalg.solve(cov, r) + np.linalg.slogdet(cov)[1] - np.log(var[ok]).sum()
        assert got[index] == pytest.approx(-0.5 * dense, rel=1e-10)
    # one column sqrt(P) 1: the closed-form common offset
    column = np.full((beams, 1), np.sqrt(1.5))
    np.testing.assert_allclose(
        low_rank_log_likelihood(predicted, measured, var, column),
        common_bias_log_likelihood(predicted, measured, var, 1.5),
        rtol=1e-12,
    )


def _learn(coefficient, rng, pings: int = 300, noise_std: float = 0.5, shift=None):
    """Modes after ``pings`` 21-beam pings.

    ``coefficient(n)``: the tilt's coefficient (map units, on the unit-norm shape) of ping
    ``n``, on top of white noise of ``noise_std``. ``shift``: ``(gradients (21, 2), cov
    (2, 2))``, a position error drawn from ``N(0, cov)`` each ping read through the
    terrain's gradients, and the fit told both (None: the position is known).
    """
    shapes = swath_shapes(_across())
    modes = SwathModes.prior(0.98)
    noise = np.full(21, noise_std**2)
    for n in range(pings):
        residual = coefficient(n) * shapes[:, 0] + rng.normal(0.0, noise_std, 21)
        if shift is None:
            modes = modes.updated(residual, shapes, None, noise, n)
            continue
        gradients, cov = shift
        residual = residual + gradients @ rng.multivariate_normal(np.zeros(2), cov)
        modes = modes.updated(residual, shapes, gradients, noise, n, cov)
    return modes


def test_a_persistent_tilt_is_learnt_with_its_persistence(rng):
    modes = _learn(lambda n: 2.0, rng)
    # a tilt of 2 on every ping: variance 4 (its square), about 50 pings in memory
    assert 3.0 < modes.variance[0] < 5.0
    assert modes.variance[1] < 0.1  # no curvature in the readings
    # consecutive pings see the same tilt: rho = 4 / 4.25, about 30 pings per error
    assert 15.0 < modes.pings_per_error[0] <= MAX_PINGS_PER_ERROR
    columns = modes.columns(swath_shapes(_across()))
    assert columns[:, 0] @ columns[:, 0] > 15.0 * 3.0


def test_a_tilt_drawn_anew_every_ping_is_not_counted_as_persistent(rng):
    modes = _learn(lambda n: rng.normal(0.0, 2.0), rng)
    assert 2.5 < modes.variance[0] < 6.0
    assert modes.pings_per_error[0] < 1.6


def test_white_noise_leaves_the_shapes_near_zero(rng):
    """A map that is the seabed: the shapes' variance stays a fraction of the noise."""
    modes = _learn(lambda n: 0.0, rng)
    # per ping the excess is 0.25 (chi2_1 - 1): sd 0.35; ~55 pings in memory: sd ~0.05
    assert np.all(modes.variance < 0.15)
    assert np.all(modes.pings_per_error < 2.0)


def test_a_position_error_the_prior_allows_is_not_read_as_a_map_error(rng):
    """Residuals a position error of the prior's size makes on rough terrain."""
    gradients = rng.normal(0.0, 0.3, (21, 2))  # map units per metre
    cov = np.diag([4.0, 9.0])  # m^2
    modes = _learn(lambda n: 0.0, rng, shift=(gradients, cov))
    assert np.all(modes.variance < 0.15)
    # the same residuals fitted as if the position were known: a map error appears
    shapes = swath_shapes(_across())
    naive = SwathModes.prior(0.98)
    noise = np.full(21, 0.25)
    for n in range(300):
        error = gradients @ rng.multivariate_normal(np.zeros(2), cov)
        naive = naive.updated(error + rng.normal(0.0, 0.5, 21), shapes, None, noise, n)
    assert naive.variance.max() > 0.5


def _correlated_mission():
    """A held-in copy of the ``imperfect_depth`` benchmark with a 2 m, 300 m map error."""
    from geofix.sim.scenario import scenario_from_dict
    from geofix.sim.simulate import prepare_map

    data = {
        "name": "correlated-map-error",
        "map": {
            "path": "builtin:deep_nans",
            "region": [-134.84, -134.73, -15.45, -15.34],
            "resample_m": 10,
        },
        "track": {
            "start_cell": [300, 300],
            "start_jitter_m": 200,
            "heading_deg": 45,
            "speed_m_s": 2,
            "interval_s": 10,
            "samples": 121,
        },
        "sensor": {"type": "multibeam", "beams": 61, "swath_width_m": 200, "noise_std": 0.5},
        "ins": {
            "initial_error_m": [0, 0],
            "initial_error_std_m": 150,
            "velocity_error_m_s": 0.05,
            "gyro_bias_deg_h": 0.01,
            "accel_bias_ug": 20,
        },
        "seabed": {"error_rms": 2.0, "error_corr_m": 300.0},
        "trials": 3,
        "seed": 7,
    }
    scen = scenario_from_dict(data)
    return scen, prepare_map(scen)


def _ends(scen, grid, spec: str, trials: int | None = None) -> list[tuple[float, float]]:
    """``(end error m, end NEES)`` of the first ``trials`` trials of ``spec`` (default all)."""
    from geofix.evaluate.runner import method_rng, run_trial
    from geofix.methods import parse_method_spec
    from geofix.sim.simulate import simulate_trial

    out = []
    for index in range(scen.trials if trials is None else trials):
        trial = simulate_trial(scen, grid, index)
        result = run_trial(parse_method_spec(spec), trial, grid, method_rng(7, index, spec))
        e = result.estimate[-1] - trial.truth[-1]
        out.append((float(np.hypot(*e)), float(e @ np.linalg.solve(result.covariance, e))))
    return out


def test_a_correlated_map_error_no_longer_draws_the_filters_away(monkeypatch):
    """2 m of map error over 300 m under a 200 m swath, default settings.

    Without the shapes (their columns dropped) the particle filter ends 197 m off on
    trial 0 with a 1-sigma under a metre; with them every filter ends within a map
    cell (10 m) and inside its 99.9 % ellipse (NEES 13.8).
    """
    scen, grid = _correlated_mission()
    for spec in ("pf", "mpf"):
        for error, nees in _ends(scen, grid, spec):
            assert error < 10.0 and nees < 13.8, (spec, error, nees)
    monkeypatch.setattr(SwathModes, "columns", lambda self, shapes: None)
    ((error, nees),) = _ends(scen, grid, "pf", trials=1)  # trial 0, as the docstring says
    assert error > 50.0 and nees > 100.0
