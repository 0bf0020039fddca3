"""Each hypothesis's own common offset: the Kalman step, the moves, the filters on a track."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import small_mission_data
from geofix.filters.base import Observation
from geofix.filters.hypothesis_offset import HypothesisOffset, mixed_offsets, regridded_offsets
from geofix.maps.grid import Grid
from geofix.methods import parse_method_spec


def _ramp(n: int = 60, cell: float = 10.0) -> Grid:
    y, x = np.mgrid[0:n, 0:n] * cell
    z = -1000.0 + 0.05 * x + 0.02 * y
    return Grid(values=z, x0=0.0, y0=0.0, dx=cell, dy=cell, kind="depth", units="m")


def _obs(values, noise_var, bias_var=0.0, walk=0.0, own=True) -> Observation:
    values = np.asarray(values, dtype=float)
    offsets = np.zeros((values.size, 2))
    return Observation(values, np.zeros(2), 0.0, offsets, noise_var, 0, bias_var, walk, own)


def test_the_kalman_step_of_each_hypothesis_is_the_scalar_one():
    grid = _ramp()
    positions = np.array([[300.0, 300.0], [200.0, 100.0]])
    truth = grid.sample(positions[:, 0], positions[:, 1])
    # both hypotheses read 3 beams 2 m above their own map value; prior N(0, 4)
    offset = HypothesisOffset(np.zeros(2), 4.0, 0.0)
    obs = _obs(np.full(3, truth[0] + 2.0), 1.0)
    after = offset.updated(grid, positions, obs)
    # S = 3, T = 3 * 2: b = 4 * 6 / (1 + 12) for the first, P = 4 / 13
    assert after.mean[0] == pytest.approx(24.0 / 13.0)
    assert after.mean[1] == pytest.approx(4.0 * 3.0 * (truth[0] + 2.0 - truth[1]) / 13.0)
    assert after.var == pytest.approx(4.0 / 13.0)
    assert after.predicted(10.0).var == pytest.approx(4.0 / 13.0)  # no walk
    assert HypothesisOffset(np.zeros(1), 1.0, 0.5).predicted(4.0).var == pytest.approx(3.0)


def test_moments_add_the_spread_of_the_means_to_the_common_variance():
    offset = HypothesisOffset(np.array([1.0, 3.0]), 0.5, 0.0)
    mean, var = offset.moments(np.array([0.5, 0.5]))
    assert mean == pytest.approx(2.0) and var == pytest.approx(1.5)
    assert offset.take(np.array([1, 1, 0])).mean.tolist() == [3.0, 3.0, 1.0]
    assert HypothesisOffset.start(3, _obs([1.0], 1.0)) is None  # no prior variance: none
    assert HypothesisOffset.start(3, _obs([1.0], 1.0, bias_var=9.0, own=False)) is None
    started = HypothesisOffset.start((2, 2), _obs([1.0], 1.0, bias_var=9.0, walk=0.1))
    assert started.mean.shape == (2, 2) and started.var == 9.0 and started.walk == 0.1


def test_the_convolution_mixes_the_means_by_the_mass_that_arrives():
    log_weight = np.full((5, 5), -np.inf)
    log_weight[2, 1], log_weight[2, 3] = 0.0, np.log(3.0)
    mean = np.zeros((5, 5))
    mean[2, 1], mean[2, 3] = 4.0, 8.0
    kernel = np.array([0.5, 0.0, 0.5])  # a node gets half of each neighbour two apart
    mixed = mixed_offsets(log_weight, mean, (np.array([0.0, 1.0, 0.0]), kernel))
    assert mixed[2, 2] == pytest.approx((4.0 + 3.0 * 8.0) / 4.0)  # from both, by mass
    assert mixed[0, 0] == 0.0  # nothing arrives: its own


def test_regridding_onto_the_same_frame_keeps_the_means_and_a_shift_moves_them():
    mean = np.arange(25.0).reshape(5, 5)
    frame = (np.zeros(2), np.eye(2), np.array([10.0, 10.0]))
    np.testing.assert_allclose(regridded_offsets(mean, frame, frame, (5, 5)), mean)
    moved = (np.array([10.0, 0.0]), np.eye(2), np.array([10.0, 10.0]))
    np.testing.assert_allclose(regridded_offsets(mean, frame, moved, (5, 5))[:4], mean[1:])


@pytest.fixture(scope="module")
def offset_singlebeam(tmp_path_factory):
    """A single-beam mission on the bundled 1 km grid with readings 20 m off the map."""
    from geofix.sim.scenario import scenario_from_dict
    from geofix.sim.simulate import prepare_map

    data = small_mission_data(
        "offset-singlebeam",
        track={"samples": 40},
        ins={"initial_error_m": [0, 0], "initial_error_std_m": 1000, "velocity_error_m_s": 0.05},
        seabed={"offset": 20.0},
        trials=6,
        seed=5,
    )
    scen = scenario_from_dict(data)
    return scen, prepare_map(scen)


@pytest.mark.parametrize("name", ["pmf", "pf:particles=2000"])
def test_a_single_beam_profile_with_an_offset_is_matched_by_default(offset_singlebeam, name):
    """One beam a ping cannot separate an offset from a position; the profile can."""
    from geofix.evaluate.runner import method_rng, run_trial
    from geofix.sim.simulate import simulate_trial

    scen, grid = offset_singlebeam
    ends = {"default": [], "exact": []}
    for index in range(scen.trials):
        trial = simulate_trial(scen, grid, index)
        for model, spec in (("default", name), ("exact", f"{name},map_model=exact")):
            if model == "exact" and ":" not in name:
                spec = f"{name}:map_model=exact"
            result = run_trial(parse_method_spec(spec), trial, grid, method_rng(5, index, spec))
            e = result.estimate[-1] - trial.truth[-1]
            ends[model].append((np.hypot(*e), float(e @ np.linalg.solve(result.covariance, e))))
    default, exact = (np.array(ends[m]) for m in ("default", "exact"))
    # the exact model takes the 20 m offset for a position: confident and wrong
    assert np.median(exact[:, 1]) > 20.0
    # the default carries each hypothesis's offset: its covariance honest (6 trials of a
    # chi-square(2): the median is below 5 with probability 0.98) and closer
    assert np.median(default[:, 1]) < 5.0
    assert np.sqrt(np.mean(default[:, 0] ** 2)) < 0.5 * np.sqrt(np.mean(exact[:, 0] ** 2))
