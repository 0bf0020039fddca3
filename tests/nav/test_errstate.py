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
