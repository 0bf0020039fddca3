"""The Cramér-Rao bound with the map's error correlated along the track."""

from __future__ import annotations

import numpy as np
import pytest
from test_offset_bound import static_trial

from conftest import gravity_dvl_mission_data, small_mission_data
from geofix.errors import MemoryBudgetError
from geofix.evaluate.crlb import offset_state_crlb, trial_beam_variance
from geofix.evaluate.crlb_correlated import correlated_map_crlb
from geofix.maps.grid import Grid
from geofix.sim.trial import Trial


def _trial(data: dict):
    from geofix.sim.scenario import scenario_from_dict
    from geofix.sim.simulate import prepare_map, simulate_trial

    scen = scenario_from_dict(data)
    grid = prepare_map(scen)
    return simulate_trial(scen, grid, 0), grid


@pytest.fixture(scope="module")
def gravity_dvl():
    """A DVL-aided gravity mission whose prior map carries a correlated error."""
    seabed = {"error_rms": 1.0, "error_corr_m": 3000.0}
    return _trial(gravity_dvl_mission_data("corr-bound-grav", seabed=seabed))


@pytest.fixture(scope="module")
def multibeam_free():
    """A free-inertial multibeam mission (9 beams) on the prior map itself."""
    sensor = {"type": "multibeam", "beams": 9, "swath_angle_deg": 60, "altitude_m": 2000}
    return _trial(small_mission_data("corr-bound-mb", sensor={**sensor, "noise_std": 5.0}))


@pytest.mark.parametrize("case", ["gravity_dvl", "multibeam_free"])
@pytest.mark.parametrize("std", [0.0, 7.0])
def test_without_a_correlated_error_it_is_the_still_offset_recursion(case, std, request):
    trial, grid = request.getfixturevalue(case)
    if case == "gravity_dvl":
        assert trial.prior_map is not None and trial.ins_model is not None
    recursion = offset_state_crlb(trial, grid, std, 0.0, prior_map=True).recursive_var_m2
    joint = correlated_map_crlb(trial, grid, offset_std=std)
    assert joint == pytest.approx(recursion, rel=1e-6)


def test_an_endless_correlation_is_a_constant_offset(multibeam_free):
    trial, grid = multibeam_free
    joint = correlated_map_crlb(trial, grid, 3.0, 1e9, offset_std=4.0)
    constant = offset_state_crlb(trial, grid, 5.0, 0.0, prior_map=True).recursive_var_m2
    assert joint == pytest.approx(constant, rel=1e-5)


def test_a_vanishing_correlation_is_white_noise(multibeam_free):
    trial, grid = multibeam_free
    joint = correlated_map_crlb(trial, grid, 3.0, 1e-6, offset_std=4.0)
    white = offset_state_crlb(
        trial, grid, 4.0, 0.0, prior_map=True, beam_var=trial_beam_variance(trial) + 9.0
    ).recursive_var_m2
    assert joint == pytest.approx(white, rel=1e-6)


def _plane_trial(samples: int) -> tuple[Trial, Grid]:
    """A vehicle heading east over a plane sloping east, one beam a sample, no INS model.

    Its position error's prior (1e4 m a side) does not grow: the error is as good as fixed.
    """
    _, x = np.indices((80, 80)) * 100.0
    grid = Grid(0.05 * x + 3000.0, 0.0, 0.0, 100.0, 100.0, kind="depth")
    return static_trial(grid, 430.0 + 110.0 * np.arange(samples), noise_std=1.0), grid


def test_on_a_plane_an_error_that_persists_tells_less_than_white_noise():
    # on one slope the position is the mean residual over the slope: n white errors of
    # variance v + s^2 average to (v + s^2) / n; an error common to all of them does not
    # (s^2 + v / n)
    trial, grid = _plane_trial(30)
    v, s2, g2 = float(trial_beam_variance(trial)[0]), 4.0, 0.05**2
    white = correlated_map_crlb(trial, grid, 2.0, 1e-6, offset_std=0.0)
    common = correlated_map_crlb(trial, grid, 2.0, 1e7, offset_std=0.0)
    # x is seen through the slope alone; y only through its prior (1e4 m, 1e8 m^2)
    assert white - 1e8 == pytest.approx((v + s2) / 30 / g2, rel=1e-3)
    assert common - 1e8 == pytest.approx((s2 + v / 30) / g2, rel=1e-3)
    # and between the two, the longer the error's correlation the less the track tells
    lengths = [1e2, 1e3, 1e4]
    middle = [correlated_map_crlb(trial, grid, 2.0, L, offset_std=0.0) for L in lengths]
    assert white < middle[0] < middle[1] < middle[2] < common


def test_it_refuses_a_covariance_beyond_the_memory_budget(multibeam_free, monkeypatch):
    trial, grid = multibeam_free
    monkeypatch.setenv("GEOFIX_MEMORY_BUDGET", "100k")
    with pytest.raises(MemoryBudgetError, match="correlated-error bound"):
        correlated_map_crlb(trial, grid, 1.0, 100.0)


@pytest.mark.parametrize("rms, corr", [(1.0, 0.0), (-1.0, 10.0), (0.0, -5.0)])
def test_it_refuses_an_error_without_a_length(rms, corr, multibeam_free):
    trial, grid = multibeam_free
    with pytest.raises(ValueError, match="error_corr_m"):
        correlated_map_crlb(trial, grid, rms, corr)
