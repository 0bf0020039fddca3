"""The INS error state: its prior and propagated covariance are the simulator's moments."""

import numpy as np
import pytest

from geofix.nav.errstate import InsErrorModel, error_state, propagate_cov
from geofix.nav.ins import simulate_ins
from geofix.nav.spec import DvlSpec, InsSpec
from geofix.nav.trajectory import true_trajectory


def _track():
    return true_trajectory((0.0, 0.0), 70.0, 10.0, 20.0, 40, 2, 30.0, np.random.default_rng(1))


@pytest.mark.parametrize(
    ("spec", "dvl"),
    [
        (
            InsSpec(
                initial_error_m=(30.0, -20.0),
                initial_error_std_m=10.0,
                velocity_error_m_s=0.05,
                accel_bias_ug=50.0,
                gyro_bias_deg_h=0.01,
                heading_error_deg=0.1,
                accel_noise_ug_rt_hz=20.0,
                latitude_deg=40.0,
            ),
            None,
        ),
        (
            InsSpec(
                mode="dvl",
                initial_error_std_m=5.0,
                heading_error_deg=0.2,
                gyro_bias_deg_h=0.05,
                gyro_noise_deg_rt_h=0.01,
            ),
            DvlSpec(noise_std_m_s=0.02, bias_m_s=0.02, scale_error=0.003),
        ),
    ],
)
def test_error_state_covariance_is_the_simulated_second_moment(spec, dvl):
    true = _track()
    es = error_state(InsErrorModel.from_specs(spec, dvl), true.times, true.positions)
    predicted = es.position_cov(propagate_cov(es))
    draws = np.array(
        [
            simulate_ins(true, spec, np.random.default_rng([4, i]), dvl).position_error
            for i in range(400)
        ]
    )
    moment = np.einsum("tki,tkj->kij", draws, draws) / draws.shape[0]
    for k in (0, 20, 39, 79):
        # 400 draws: a second moment's relative sampling error is about sqrt(2 / 400) = 7 %
        np.testing.assert_allclose(np.diag(moment[k]), np.diag(predicted[k]), rtol=0.25)


@pytest.mark.parametrize("mode", ["free", "dvl"])
def test_online_steps_are_the_precomputed_steps(mode):
    """Built one motion at a time, the steps equal those of the whole track."""
    from geofix.nav.errstate import step_matrices

    spec = InsSpec(mode=mode, velocity_error_m_s=0.05, heading_error_deg=0.1, gyro_bias_deg_h=0.01)
    model = InsErrorModel.from_specs(spec, DvlSpec(bias_m_s=0.01) if mode == "dvl" else None)
    track = _track()
    times, positions = track.times[:12], track.positions[:12]
    whole = error_state(model, times, positions)
    online = error_state(model, times[:1], positions[:1])
    assert online.transitions.shape[0] == 0
    for k in range(times.size - 1):
        step = positions[k + 1] - positions[k]
        online, f, q = step_matrices(online, k, step, times[k + 1] - times[k])
        np.testing.assert_allclose(f, whole.transitions[k], atol=1e-12)
        np.testing.assert_allclose(q, whole.process_cov[k], atol=1e-18)
    _, f, q = step_matrices(online, 99, np.zeros(2), 0.0, position_var=4.0)
    np.testing.assert_array_equal(f, np.eye(model.dim))
    assert q[0, 0] == q[1, 1] == 4.0 and q[2:, 2:].sum() == 0.0
