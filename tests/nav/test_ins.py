"""INS error model: closed forms, rotation by the heading error, prior sigma vs spread."""

import numpy as np
import pytest

from geofix.nav.dvl import simulate_dvl
from geofix.nav.ins import (
    SCHULER_OMEGA,
    discrete_error_model,
    position_sigma,
    schuler_bias_error,
    schuler_gyro_error,
    simulate_ins,
)
from geofix.nav.spec import DvlSpec, InsSpec
from geofix.nav.trajectory import true_trajectory

UG = 9.80665e-6


def mission(samples=111, interval=20.0, heading=70.0, legs=1, turn_std=0.0, seed=0):
    rng = np.random.default_rng(seed)
    return true_trajectory((1000.0, 2000.0), heading, 10.0, interval, samples, legs, turn_std, rng)


def test_schuler_frequency_of_the_discrete_model():
    transition, _ = discrete_error_model(20.0)
    loop = transition[:3, :3]
    angles = np.sort(np.abs(np.angle(np.linalg.eigvals(loop))))
    assert pytest.approx(1.2407e-3, rel=1e-4) == SCHULER_OMEGA
    assert angles[-1] == pytest.approx(SCHULER_OMEGA * 20.0, rel=1e-9)
    assert 2 * np.pi / SCHULER_OMEGA / 60 == pytest.approx(84.4, abs=0.1)


def test_accelerometer_bias_matches_schuler_closed_form_over_2200_s():
    true = mission()
    assert true.times[-1] == 2200.0
    ins = simulate_ins(true, InsSpec(accel_bias_ug=102.0), np.random.default_rng(5))
    assert np.hypot(*ins.accel_bias) == pytest.approx(102.0 * UG)
    expected = schuler_bias_error(ins.accel_bias[None, :], true.times[:, None])
    err = np.abs(ins.position_error - expected).max() / np.abs(expected).max()
    assert err < 1e-6


def test_source_note_numbers_for_1e_3_bias_at_2200_s():
    assert schuler_bias_error(1e-3, 2200.0) == pytest.approx(1250.0, rel=0.01)


def test_without_schuler_a_bias_integrates_to_half_b_t_squared():
    true = mission()
    spec = InsSpec(accel_bias_ug=1e-3 / UG, schuler=False)
    ins = simulate_ins(true, spec, np.random.default_rng(1))
    expected = 0.5 * ins.accel_bias[None, :] * true.times[:, None] ** 2
    np.testing.assert_allclose(ins.position_error, expected, rtol=1e-9, atol=1e-9)
    assert np.hypot(*ins.position_error[-1]) == pytest.approx(2420.0)


def test_velocity_error_with_and_without_schuler():
    true = mission()
    for schuler in (True, False):
        spec = InsSpec(velocity_error_m_s=0.04, schuler=schuler)
        ins = simulate_ins(true, spec, np.random.default_rng(2))
        assert np.hypot(*ins.velocity_error) == pytest.approx(0.04)
        t = true.times[:, None]
        shape = np.sin(SCHULER_OMEGA * t) / SCHULER_OMEGA if schuler else t
        np.testing.assert_allclose(ins.position_error, ins.velocity_error * shape, atol=1e-8)


def test_level_gyro_drift_matches_closed_form_and_sign():
    true = mission()
    ins = simulate_ins(true, InsSpec(gyro_bias_deg_h=0.01), np.random.default_rng(4))
    eps = ins.gyro_bias[:2]
    assert np.abs(ins.gyro_bias) == pytest.approx([0.01 * np.pi / 180 / 3600] * 3)
    expected = schuler_gyro_error(eps[None, :], true.times[:, None])
    np.testing.assert_allclose(ins.schuler_error, expected, rtol=1e-7, atol=1e-9)
    # a positive drift drives the position error negative, about 580 m after 2200 s
    assert schuler_gyro_error(0.01 * np.pi / 180 / 3600, 2200.0) == pytest.approx(-580, rel=0.01)


def test_zero_errors_give_the_truth():
    true = mission(legs=3, samples=20, turn_std=10.0)
    ins = simulate_ins(true, InsSpec(), np.random.default_rng(0))
    np.testing.assert_array_equal(ins.indicated, true.positions)
    np.testing.assert_array_equal(ins.heading, true.heading)


def test_fixed_initial_error_is_a_constant_offset():
    true = mission(samples=30)
    ins = simulate_ins(true, InsSpec(initial_error_m=(30.0, -40.0)), np.random.default_rng(0))
    np.testing.assert_allclose(ins.position_error, np.tile([30.0, -40.0], (30, 1)))


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_without_schuler_a_heading_error_rotates_the_track_about_its_start(seed):
    # the velocity gained since alignment is rotated; without the Schuler loop it
    # integrates to the travelled displacement rotated (to first order in the angle)
    true = mission(samples=25, legs=3, turn_std=20.0, seed=seed)
    spec = InsSpec(heading_error_deg=2.0, initial_error_m=(50.0, 0.0), schuler=False)
    ins = simulate_ins(true, spec, np.random.default_rng(seed))
    angle = ins.heading_error[0]
    assert abs(angle) == pytest.approx(np.radians(2.0))
    np.testing.assert_allclose(ins.heading_error, angle)
    rel_true = true.positions - true.positions[0]
    rel_ind = ins.indicated - ins.indicated[0]
    rotated = rel_true + angle * np.column_stack([rel_true[:, 1], -rel_true[:, 0]])
    np.testing.assert_allclose(rel_ind, rotated, atol=1e-8)
    np.testing.assert_allclose(ins.heading - true.heading, angle)
    np.testing.assert_allclose(ins.rotation_error, ins.position_error - [50.0, 0.0], atol=1e-9)


def test_free_ins_heading_error_runs_through_the_schuler_loop():
    # straight track at velocity v: dv0 = psi J v, so dp = psi J v sin(w t) / w
    true = mission()
    ins = simulate_ins(true, InsSpec(heading_error_deg=0.5), np.random.default_rng(3))
    psi = ins.heading_error[0]
    v = true.velocity[0]
    t = true.times[:, None]
    expected = psi * np.array([v[1], -v[0]]) * np.sin(SCHULER_OMEGA * t) / SCHULER_OMEGA
    np.testing.assert_allclose(ins.position_error, expected, rtol=1e-7, atol=1e-8)


def test_free_ins_heading_error_through_the_earth_rate():
    # at rest the only effect is a north-channel level drift Omega cos L psi
    true = true_trajectory((0.0, 0.0), 0.0, 0.0, 20.0, 111)
    spec = InsSpec(heading_error_deg=0.05, latitude_deg=54.0)
    ins = simulate_ins(true, spec, np.random.default_rng(0))
    psi = ins.heading_error[0]
    drift = 7.292115e-5 * np.cos(np.radians(54.0)) * psi
    np.testing.assert_allclose(ins.position_error[:, 0], 0.0, atol=1e-9)
    expected = schuler_gyro_error(drift, true.times)
    np.testing.assert_allclose(ins.position_error[:, 1], expected, rtol=1e-7, atol=1e-9)
    # R * 3.74e-8 rad/s * (2200 s - sin(2.73) / omega_s): about 447 m after 2200 s
    assert abs(expected[-1]) == pytest.approx(447.0, rel=0.01)


@pytest.mark.parametrize(("bias", "scale"), [(0.0, 0.004), (0.03, 0.0)])
def test_dvl_dead_reckoning_closed_form(bias, scale):
    # straight track: dp = p0 + (psi0 J v + s v + b) t + eps_z J v t^2 / 2
    true = mission(samples=60, heading=30.0)
    dvl = DvlSpec(noise_std_m_s=0.0, bias_m_s=bias, scale_error=scale)
    spec = InsSpec(
        mode="dvl", initial_error_m=(10.0, -5.0), heading_error_deg=0.3, gyro_bias_deg_h=0.5
    )
    ins = simulate_ins(true, spec, np.random.default_rng(9), dvl)
    psi0, eps_z = ins.heading_error[0], ins.gyro_bias[2]
    assert abs(psi0) == pytest.approx(np.radians(0.3))
    assert abs(eps_z) == pytest.approx(0.5 * np.pi / 180 / 3600)
    np.testing.assert_allclose(ins.heading_error, psi0 + eps_z * true.times, atol=1e-12)
    t = true.times[:, None]
    v = true.velocity[0]
    jv = np.array([v[1], -v[0]])
    err = ins.position_error - np.array([10.0, -5.0]) - (psi0 * t + eps_z * t**2 / 2) * jv
    rate = err[-1] / true.times[-1]  # s v + b, constant
    np.testing.assert_allclose(err, rate * t, atol=1e-9)
    if scale:
        assert abs(rate @ v / (v @ v)) == pytest.approx(scale, rel=1e-9)
        assert abs(rate @ jv) < 1e-12
    else:
        assert np.hypot(*rate) == pytest.approx(bias, rel=1e-9)


def test_dvl_mode_needs_a_dvl():
    from geofix.errors import ConfigError

    true = mission(samples=5)
    with pytest.raises(ConfigError, match="dvl"):
        simulate_ins(true, InsSpec(mode="dvl"), np.random.default_rng(0))


def test_heading_error_sign_is_random_per_trial():
    true = mission(samples=5)
    signs = {
        np.sign(
            simulate_ins(
                true, InsSpec(heading_error_deg=1.0), np.random.default_rng(i)
            ).heading_error[0]
        )
        for i in range(20)
    }
    assert signs == {-1.0, 1.0}


def test_prior_initial_sigma_from_fixed_and_random_parts():
    times = np.array([0.0])
    assert position_sigma(InsSpec(initial_error_m=(30.0, -60.0)), times)[0] == pytest.approx(30)
    spec = InsSpec(initial_error_m=(30.0, 0.0), initial_error_std_m=20.0)
    assert position_sigma(spec, times)[0] == pytest.approx(np.hypot(20.0, 15.0))
    spec = InsSpec(initial_error_m=(30.0, 0.0), prior_sigma_m=7.0)
    assert position_sigma(spec, times)[0] == pytest.approx(7.0)


def test_double_integrated_accelerometer_noise_variance():
    spec = InsSpec(accel_noise_ug_rt_hz=50.0, schuler=False)
    times = np.arange(0.0, 601.0, 20.0)
    q = (50.0 * UG) ** 2
    np.testing.assert_allclose(position_sigma(spec, times), np.sqrt(q * times**3 / 3), rtol=1e-9)


SOURCE_LIKE = InsSpec(
    initial_error_std_m=20.0,
    velocity_error_m_s=0.05,
    accel_bias_ug=100.0,
    gyro_bias_deg_h=0.005,
    gyro_noise_deg_rt_h=0.002,
    accel_noise_ug_rt_hz=50.0,
)


def test_position_sigma_grows_over_the_mission():
    times = np.arange(111) * 20.0
    sigma = position_sigma(SOURCE_LIKE, times, distance_m=10.0 * times)
    assert sigma[0] == pytest.approx(20.0)
    assert np.all(np.diff(sigma) > 0)
    with_heading = position_sigma(
        SOURCE_LIKE.model_copy(update={"heading_error_deg": 0.05}), times, 10.0 * times
    )
    assert np.all(with_heading[1:] > sigma[1:])


def _draws(spec, true, draws=300):
    return [simulate_ins(true, spec, np.random.default_rng([7, i])) for i in range(draws)]


def _rms(errors):
    return np.sqrt(np.mean(np.asarray(errors) ** 2, axis=0))  # (n, 2) RMS per axis


@pytest.mark.parametrize("schuler", [True, False])
def test_position_sigma_matches_empirical_spread(schuler):
    true = mission()
    spec = SOURCE_LIKE.model_copy(update={"schuler": schuler})
    rms = _rms([ins.position_error for ins in _draws(spec, true)])
    sigma = position_sigma(spec, true.times)
    for k in (25, 50, 80, 110):
        assert rms[k].mean() == pytest.approx(sigma[k], rel=0.2)


def test_position_sigma_heading_term_matches_cross_track_spread():
    true = mission(heading=0.0)  # northward: the heading error shows on the east axis
    spec = InsSpec(heading_error_deg=0.1, initial_error_std_m=5.0, schuler=False)
    rms = _rms([ins.position_error for ins in _draws(spec, true)])
    sigma = position_sigma(spec, true.times, distance_m=10.0 * true.times)
    for k in (10, 50, 110):
        assert rms[k, 0] == pytest.approx(sigma[k], rel=0.2)
        assert rms[k, 1] == pytest.approx(5.0, rel=0.2)


def test_position_sigma_heading_random_walk_term():
    # gyro noise also drives the level channels, so compare the rotation part alone
    # (without the Schuler loop the heading walk rotates the travelled distance)
    true = mission(heading=0.0)
    spec = InsSpec(gyro_noise_deg_rt_h=0.05, schuler=False)
    rms = _rms([ins.position_error for ins in _draws(spec, true)])
    total = position_sigma(spec, true.times, distance_m=10.0 * true.times)
    level = position_sigma(spec, true.times)
    for k in (10, 50, 110):
        assert rms[k, 0] == pytest.approx(total[k], rel=0.2)
        assert rms[k, 1] == pytest.approx(level[k], rel=0.2)


def test_dvl_is_truth_plus_constant_bias_plus_noise():
    true = mission(samples=4000, interval=1.0)
    dvl = simulate_dvl(true, DvlSpec(noise_std_m_s=0.02, bias_m_s=0.1), np.random.default_rng(1))
    error = dvl - true.velocity
    assert np.hypot(*error.mean(axis=0)) == pytest.approx(0.1, abs=0.002)
    np.testing.assert_allclose(error.std(axis=0), 0.02, rtol=0.05)
    exact = simulate_dvl(true, DvlSpec(noise_std_m_s=0.0), np.random.default_rng(1))
    np.testing.assert_array_equal(exact, true.velocity)
