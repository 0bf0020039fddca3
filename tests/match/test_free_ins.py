"""The free INS method: the indicated track, uncorrected, with the prior as covariance."""

import numpy as np

from geofix.evaluate.runner import run_trial
from geofix.methods import parse_method_spec


def test_free_ins_is_the_indicated_track(small_mission):
    import geofix

    scen = small_mission("free-ins")
    grid = geofix.prepare_map(scen)
    trial = geofix.simulate_trial(scen, grid, 1)
    method = parse_method_spec("ins")
    result = run_trial(method, trial, grid, np.random.default_rng(0))
    np.testing.assert_array_equal(result.estimate, trial.indicated)
    assert result.end_error_m == np.hypot(*(trial.indicated[-1] - trial.truth[-1]))
    np.testing.assert_allclose(result.covariance, np.eye(2) * trial.sigma_position[-1] ** 2)
    assert result.n_calls == 1 and not result.ambiguous
