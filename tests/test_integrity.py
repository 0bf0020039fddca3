"""Integrity on flat terrain: every method flags its fix on the bundled flat NAVO survey.

The 2 m NAVO survey (``builtin:navo_flat``) is a sediment plain with a depth std of 0.3 m
over 3 km and a relief along a 300 m track smaller than the echosounder noise (terrain /
noise ratio about 0.3). No method can tell one position from its neighbours there: each
must say so (``Fix.ambiguous``) instead of returning a confident wrong fix.
"""

from __future__ import annotations

import numpy as np
import pytest

from geofix.evaluate.runner import method_rng, run_trial
from geofix.filters.sitan import posterior_too_wide
from geofix.maps.synthetic import planar_grid
from geofix.match import integrity, tercom
from geofix.match.integrity import (
    cover_covariance,
    information_covariance,
    terrain_integrity,
    terrain_snr,
)
from geofix.methods import available_methods, parse_method_spec
from geofix.problem import MatchProblem
from geofix.sim.scenario import builtin_scenario_path, load_scenario
from geofix.sim.simulate import prepare_map, simulate_trial

TRIALS = 4
SENSORS = ("singlebeam", "multibeam")


def navo_scenario(sensor: str, trials: int = TRIALS, seed: int = 8):
    """The bundled flat-survey mission (``navo_flat_<sensor>.yaml``), ``trials`` trials."""
    scen = load_scenario(builtin_scenario_path(f"navo_flat_{sensor}"))
    return scen.model_copy(update={"trials": trials, "seed": seed})


@pytest.fixture(scope="module")
def navo_trials():
    cases = {}
    for sensor in SENSORS:
        scen = navo_scenario(sensor)
        grid = prepare_map(scen)
        cases[sensor] = (scen, grid, [simulate_trial(scen, grid, i) for i in range(scen.trials)])
    return cases


def _method_params():
    return [
        pytest.param(name, sensor, id=f"{name}-{sensor}")
        for name in available_methods()
        if name != "ins"  # the free INS makes no fix to flag
        for sensor in SENSORS
    ]


def test_the_survey_is_flatter_than_the_noise(navo_trials):

    for scen, grid, trials in navo_trials.values():
        for trial in trials:
            snr = terrain_snr(trial.problem(grid), trial.truth)
            assert snr < 0.5, (scen.name, snr)


def test_tercom_is_covered():
    assert "tercom" in available_methods()


_OUTCOMES: dict = {}


def _outcomes(name, sensor, navo_trials):
    """Per trial: (flagged or failed, end error in cells, Mahalanobis distance of the end).

    Computed once per (method, sensor) and shared by the tests below.
    """
    from geofix.evaluate.metrics import end_mahalanobis

    if (name, sensor) not in _OUTCOMES:
        scen, grid, trials = navo_trials[sensor]
        method = parse_method_spec(name)
        rows = []
        for t in trials:
            r = run_trial(method, t, grid, method_rng(scen.seed, t.index, name))
            maha = end_mahalanobis(r.estimate[-1] - t.truth[-1], r.covariance)
            rows.append((r.ambiguous or r.failed, r.end_error_m / grid.cell_size, maha))
        _OUTCOMES[name, sensor] = rows
    return _OUTCOMES[name, sensor]


@pytest.mark.parametrize(("name", "sensor"), _method_params())
def test_every_method_flags_the_flat_survey(name, sensor, navo_trials):
    """Flagged, or right (within 3 cells), on all trials but at most one."""
    rows = _outcomes(name, sensor, navo_trials)
    good = [flag or cells <= 3.0 for flag, cells, _ in rows]
    assert sum(good) >= len(rows) - 1, f"{name} on {sensor}: (flag, cells, sigmas) {rows}"


@pytest.mark.parametrize(("name", "sensor"), _method_params())
def test_no_method_gives_a_false_fix(name, sensor, navo_trials):
    """The campaign's false-fix rule: far (> 3 cells), unflagged and outside its 3 sigmas."""
    rows = _outcomes(name, sensor, navo_trials)
    false = [not flag and cells > 3.0 and not maha <= 3.0 for flag, cells, maha in rows]
    assert sum(false) <= 1, f"{name} on {sensor}: (flag, cells, sigmas) {rows}"


# ---------------------------------------------------------------------- the shared helpers
def _plane_problem(slope_x: float, slope_y: float, noise: float = 0.5, sigma: float = 30.0):

    grid = planar_grid((80, 80), 10.0, slope_x, slope_y, offset=-100.0)
    n = 12
    track = np.column_stack([np.linspace(200.0, 600.0, n), np.full(n, 400.0)])
    return MatchProblem(
        grid=grid,
        indicated=track,
        heading=np.full(n, np.pi / 2),
        offsets=np.zeros((1, 2)),
        measured=grid.sample(track[:, 0], track[:, 1])[:, None],
        sigma_position=np.full(n, sigma),
        times=np.arange(n) * 10.0,
        noise_std=noise,
    )


def test_information_covariance_on_a_plane_is_the_hand_computed_bound():

    problem = _plane_problem(0.2, -0.1)
    g = np.array([0.2, -0.1])
    expected = np.linalg.inv(12 * np.outer(g, g) / 0.25 + np.eye(2) / 30.0**2)
    got = information_covariance(problem, problem.indicated)
    np.testing.assert_allclose(got, expected, rtol=1e-6)


def test_terrain_snr_and_flag_on_a_plane():

    steep = _plane_problem(0.05, 0.0)  # 400 m of track: 20 m of relief, std ~6.9 m
    flat = _plane_problem(0.0005, 0.0)  # 0.2 m of relief under 0.5 m of noise
    assert terrain_snr(steep, steep.indicated) > 10
    assert terrain_snr(flat, flat.indicated) < 0.5
    assert not terrain_integrity(steep, steep.indicated, None, 1.0).flat
    assert terrain_integrity(flat, flat.indicated, None, 1.0).flat


def test_cover_covariance_widens_only_where_the_bound_is_larger():

    own = np.diag([4.0, 1.0])
    bound = np.diag([1.0, 9.0])
    np.testing.assert_allclose(cover_covariance(own, bound), np.diag([4.0, 9.0]))
    np.testing.assert_allclose(cover_covariance(None, bound), bound)
    rot = np.array([[np.cos(0.4), -np.sin(0.4)], [np.sin(0.4), np.cos(0.4)]])
    out = cover_covariance(rot @ own @ rot.T, bound)
    for c in (rot @ own @ rot.T, bound):
        assert np.linalg.eigvalsh(out - c).min() > -1e-9


def test_sitan_wide_posterior_rule():

    # exp(-r^2 / (2 lambda)) > 0.05  <=>  lambda > r^2 / (2 ln 20): r = 6 m -> 6.01 m^2
    assert posterior_too_wide(np.diag([6.1, 1.0]), 6.0, 0.05)
    assert not posterior_too_wide(np.diag([5.9, 5.9]), 6.0, 0.05)
    assert posterior_too_wide(np.full((2, 2), np.inf), 6.0, 0.05)


def test_tercom_still_exports_terrain_snr():

    assert tercom.terrain_snr is integrity.terrain_snr is terrain_snr
