"""True trajectories: straight legs, turns, velocity convention."""

import numpy as np
import pytest

from geofix.nav.trajectory import true_trajectory


def test_single_leg_heading_east_moves_along_x():
    track = true_trajectory((100.0, 200.0), 90.0, 5.0, 4.0, 10)
    expected_x = 100.0 + 20.0 * np.arange(10)
    np.testing.assert_allclose(track.positions[:, 0], expected_x)
    np.testing.assert_allclose(track.positions[:, 1], 200.0, atol=1e-9)
    np.testing.assert_allclose(track.times, 4.0 * np.arange(10))
    np.testing.assert_allclose(track.velocity, np.tile([5.0, 0.0], (10, 1)), atol=1e-12)
    assert track.leg_starts == (0,)


def test_velocity_is_speed_times_sin_cos_of_heading():
    track = true_trajectory((0.0, 0.0), 30.0, 2.0, 1.0, 5)
    psi = np.radians(30.0)
    np.testing.assert_allclose(track.heading, psi)
    np.testing.assert_allclose(track.velocity[0], [2.0 * np.sin(psi), 2.0 * np.cos(psi)])
    steps = np.diff(track.positions, axis=0)
    np.testing.assert_allclose(steps, track.velocity[1:] * 1.0)


def test_legs_have_constant_heading_and_turn_between_them():
    rng = np.random.default_rng(3)
    track = true_trajectory((0.0, 0.0), 45.0, 4.0, 20.0, 10, legs=4, turn_std_deg=5.0, rng=rng)
    assert track.positions.shape == (40, 2)
    assert track.leg_starts == (0, 10, 20, 30)
    for start in track.leg_starts:
        leg = track.heading[start : start + 10]
        np.testing.assert_allclose(leg, leg[0])
    turns = np.diff(track.heading[list(track.leg_starts)])
    assert np.all(np.abs(turns) > 0)
    # the step into the first sample of a leg is taken on the new heading
    step = track.positions[10] - track.positions[9]
    psi = track.heading[10]
    np.testing.assert_allclose(step, 80.0 * np.array([np.sin(psi), np.cos(psi)]))


def test_turn_spread_matches_turn_std():
    rng = np.random.default_rng(0)
    track = true_trajectory((0.0, 0.0), 0.0, 1.0, 1.0, 2, legs=4000, turn_std_deg=5.0, rng=rng)
    turns = np.degrees(np.diff(track.heading[list(track.leg_starts)]))
    assert np.std(turns) == pytest.approx(5.0, rel=0.05)


def test_no_turn_std_keeps_a_straight_line_over_legs():
    track = true_trajectory((0.0, 0.0), 10.0, 3.0, 2.0, 5, legs=3)
    np.testing.assert_allclose(track.heading, np.radians(10.0))
    assert track.leg_starts == (0, 5, 10)


def test_random_turns_without_rng_raise():
    with pytest.raises(ValueError, match="rng"):
        true_trajectory((0.0, 0.0), 0.0, 1.0, 1.0, 5, legs=2, turn_std_deg=3.0)


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="interval_s"):
        true_trajectory((0.0, 0.0), 0.0, 1.0, 0.0, 5)
    with pytest.raises(ValueError, match="speed_m_s"):
        true_trajectory((0.0, 0.0), 0.0, -1.0, 1.0, 5)
