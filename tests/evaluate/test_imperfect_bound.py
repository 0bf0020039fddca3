"""The Cramér-Rao bound of the problem a vehicle with an imperfect prior map has."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import small_mission_data
from geofix.evaluate.crlb import imperfect_map_crlb, map_error_variance_at_track, trial_crlb
from geofix.measurement import sample_information


def test_an_unknown_offset_per_sample_leaves_what_the_shape_tells():
    gx = np.array([[1.0, 3.0]])
    gy = np.array([[0.0, 2.0]])
    # two beams of unit variance: (g1 - g2)(g1 - g2)^T / 2
    d = np.array([-2.0, -2.0])
    np.testing.assert_allclose(
        sample_information(gx, gy, 1.0, offset_var=np.inf)[0], np.outer(d, d) / 2.0
    )
    # a known offset (0) changes nothing; a finite one lies between the two
    full = sample_information(gx, gy, 1.0)[0]
    some = sample_information(gx, gy, 1.0, offset_var=0.5)[0]
    shape = sample_information(gx, gy, 1.0, offset_var=np.inf)[0]
    assert np.all(np.linalg.eigvalsh(full - some) >= -1e-12)
    assert np.all(np.linalg.eigvalsh(some - shape) >= -1e-12)
    # one beam: its level is all it tells, and an unknown offset takes it
    np.testing.assert_allclose(
        sample_information(gx[:, :1], gy[:, :1], 1.0, offset_var=np.inf), 0.0, atol=1e-15
    )


@pytest.fixture(scope="module")
def block_mission():
    from geofix.sim.scenario import scenario_from_dict
    from geofix.sim.simulate import prepare_map

    sensor = {"type": "multibeam", "beams": 9, "swath_angle_deg": 60, "altitude_m": 2000}
    data = small_mission_data(
        "bound-block",
        sensor={**sensor, "noise_std": 5.0},
        ins={"initial_error_m": [0, 0], "initial_error_std_m": 500},
        trials=2,
    )
    plain = scenario_from_dict(data)
    coarse = scenario_from_dict({**data, "seabed": {"cell_factor": 4}})
    return plain, coarse, prepare_map(plain)


def test_on_the_seabed_itself_the_bound_is_the_usual_one(block_mission):
    from geofix.sim.simulate import simulate_trial

    plain, _, grid = block_mission
    trial = simulate_trial(plain, grid, 0)
    usual = trial_crlb(trial, grid)
    same = imperfect_map_crlb(trial, grid, offset_var=0.0)
    assert same.recursive_var_m2 == pytest.approx(usual.recursive_var_m2, rel=1e-9)
    assert map_error_variance_at_track(trial, grid, grid) == 0.0
    # an unknown offset per ping costs information
    assert imperfect_map_crlb(trial, grid).recursive_var_m2 > usual.recursive_var_m2


def test_a_coarser_prior_raises_the_bound(block_mission):
    from geofix.sim.simulate import simulate_trial

    _, coarse, grid = block_mission
    trial = simulate_trial(coarse, grid, 0)
    assert trial.prior_map is not None
    # 4 x 4 block means of a 1 km deep-sea map miss tens of metres at the footprints
    assert map_error_variance_at_track(trial, grid, trial.prior_map) > 5.0**2
    on_seabed = trial_crlb(trial, grid)
    on_prior = imperfect_map_crlb(trial, grid, offset_var=0.0)
    assert on_prior.recursive_var_m2 > 2.0 * on_seabed.recursive_var_m2
