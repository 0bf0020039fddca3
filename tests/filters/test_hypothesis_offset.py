"""Each hypothesis's own common offset: the Kalman step, the moves, the filters on a track."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from conftest import gravity_map_error_mission, small_mission_data, trial_ends
from geofix.errors import ConfigError
from geofix.filters.base import Observation
from geofix.filters.hypothesis_offset import (
    RATE_POOLING,
    SLOW_OFFSET_WALK,
    HypothesisOffset,
    mixed_offsets,
    regridded_offsets,
    shared_offsets,
    walk_factors,
)
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
    offset = HypothesisOffset.single(np.zeros(2), 4.0, 0.0)
    obs = _obs(np.full(3, truth[0] + 2.0), 1.0)
    after = offset.updated(grid, positions, obs)
    # S = 3, T = 3 * 2: b = 4 * 6 / (1 + 12) for the first, P = 4 / 13
    assert after.mean[0] == pytest.approx(24.0 / 13.0)
    assert after.mean[1] == pytest.approx(4.0 * 3.0 * (truth[0] + 2.0 - truth[1]) / 13.0)
    assert after.variances[0] == pytest.approx(4.0 / 13.0)
    assert after.predicted(10.0).variances[0] == pytest.approx(4.0 / 13.0)  # no walk
    assert HypothesisOffset.single(np.zeros(1), 1.0, 0.5).predicted(4.0).variances[0] == 3.0


def test_moments_add_the_spread_of_the_means_to_the_common_variance():
    offset = HypothesisOffset.single(np.array([1.0, 3.0]), 0.5, 0.0)
    mean, var = offset.moments(np.array([0.5, 0.5]))
    assert mean == pytest.approx(2.0) and var == pytest.approx(1.5)
    assert offset.take(np.array([1, 1, 0])).mean.tolist() == [3.0, 3.0, 1.0]
    assert HypothesisOffset.start(3, _obs([1.0], 1.0)) is None  # no prior variance: none
    assert HypothesisOffset.start(3, _obs([1.0], 1.0, bias_var=9.0, own=False)) is None
    started = HypothesisOffset.start((2, 2), _obs([1.0], 1.0, bias_var=9.0, walk=0.1))
    assert started.mean.shape == (2, 2) and started.variances.tolist() == [9.0]
    assert started.walks.tolist() == [0.1] and started.stationary == np.inf  # a random walk
    two = HypothesisOffset.start(2, _obs([1.0], 1.0, 9.0, 0.1), 10.0, slow=0.0)
    np.testing.assert_allclose(two.walks, [0.1, 1.0])
    assert two.stationary == 9.0 and np.allclose(np.exp(two.log_prob), 0.5)
    # by default a slower rate beside them, the three equally likely
    three = HypothesisOffset.start(2, _obs([1.0], 1.0, 9.0, 0.1), 10.0)
    np.testing.assert_allclose(three.walks, [0.1 * SLOW_OFFSET_WALK, 0.1, 1.0])
    assert three.stationary == 9.0 and np.allclose(np.exp(three.log_prob), 1.0 / 3.0)
    assert HypothesisOffset.start(2, _obs([1.0], 1.0, 9.0), 10.0).models == 1
    for bad in (0.5, 1.0, -2.0, np.nan):
        with pytest.raises(ConfigError, match="fast_offset_walk"):
            walk_factors(bad)
    assert walk_factors(10.0, 0.01) == (0.01, 1.0, 10.0)
    assert walk_factors(0.0, 0.01) == (1.0,)  # no faster rate: the declared one alone
    for bad in (1.0, 2.0, -0.1, np.inf):
        with pytest.raises(ConfigError, match="slow_offset_walk"):
            walk_factors(10.0, bad)
    with pytest.raises(ConfigError, match="fast_offset_walk"):
        parse_method_spec("pmf:fast_offset_walk=0.5")
    for spec in ("pmf", "pf", "mpf"):
        with pytest.raises(ConfigError, match="slow_offset_walk"):
            parse_method_spec(f"{spec}:slow_offset_walk=3")
        assert parse_method_spec(f"{spec}:slow_offset_walk=0").slow_offset_walk == 0.0


def test_the_faster_walk_is_the_map_kinds_unless_the_filter_says_otherwise():
    from dataclasses import replace

    from geofix.filters.nuisance import default_fast_offset_walk

    depth = _ramp()
    gravity = Grid(values=depth.values, x0=0.0, y0=0.0, dx=10.0, dy=10.0, kind="gravity")
    assert default_fast_offset_walk(depth) == 0.0
    assert default_fast_offset_walk(gravity) == 10.0
    obs = replace(_obs([1.0], 1.0, 9.0, 0.1), bias_fast_walk=10.0)
    np.testing.assert_allclose(HypothesisOffset.start(2, obs, slow=0).walks, [0.1, 1.0])
    assert HypothesisOffset.start(2, obs, 0).models == 1
    assert HypothesisOffset.start(2, _obs([1.0], 1.0, 9.0, 0.1)).models == 1
    assert parse_method_spec("pf").fast_offset_walk is None
    assert parse_method_spec("mpf:fast_offset_walk=0").fast_offset_walk == 0


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


def _rate_probabilities(offset_at, rng, pings: int = 150, dt: float = 20.0) -> np.ndarray:
    """Each walk rate's probability at one hypothesis after ``pings`` single readings.

    The reading is the map at the hypothesis plus ``offset_at(k)`` plus N(0, 1) noise; the
    prior offset is N(0, 25) walking 1e-3 units^2/s at the slowest rate.
    """
    grid = _ramp()
    position = np.array([[300.0, 300.0]])
    mapped = float(grid.sample(position[:, 0], position[:, 1])[0])
    first = _obs([mapped], 1.0, bias_var=25.0, walk=1e-3)
    offset = HypothesisOffset.start(1, first, 10.0)
    for k in range(pings):
        offset = offset.predicted(dt)
        reading = mapped + offset_at(k) + rng.normal()
        offset = offset.updated(grid, position, _obs([reading], 1.0, 25.0, 1e-3))
    return np.exp(offset.log_prob[:, 0])


def test_each_hypothesis_finds_how_fast_its_offset_walks():
    """An offset walking at the faster rate is found; a constant one keeps the slower."""
    rng = np.random.default_rng(3)
    fast_q = 1e-3 * 10.0
    steps = rng.normal(0.0, np.sqrt(fast_q * 20.0), 150).cumsum()
    fast = _rate_probabilities(lambda k: steps[k], np.random.default_rng(4))
    assert fast[-1] > 0.8, fast
    constant = _rate_probabilities(lambda k: 3.0, np.random.default_rng(4))
    assert constant[0] == constant.max() and constant[-1] < 0.1, constant


def test_each_rate_is_a_gauss_markov_offset_at_the_prior_variance():
    """A short step gains ``walk * dt``; a long one forgets the mean, back at the prior."""
    offset = HypothesisOffset(
        means=np.array([[4.0], [4.0]]),
        variances=np.array([1.0, 1.0]),
        walks=np.array([1e-3, 1e-1]),
        log_prob=np.log(np.full((2, 1), 0.5)),
        stationary=25.0,
    )
    short = offset.predicted(1.0)
    np.testing.assert_allclose(short.variances, 1.0 + np.array([1e-3, 1e-1]), rtol=1e-2)
    long = offset.predicted(1e6)
    np.testing.assert_allclose(long.variances, [25.0, 25.0], rtol=1e-6)
    np.testing.assert_allclose(long.means[1], 0.0, atol=1e-9)
    # a random walk (no stationary variance) keeps its mean and grows without bound
    walk = HypothesisOffset.single(np.array([4.0]), 1.0, 0.1).predicted(1e6)
    assert walk.means[0, 0] == 4.0 and walk.variances[0] == pytest.approx(1.0 + 1e5)


def test_the_rates_are_carried_through_the_moves_and_summarised():
    offset = HypothesisOffset(
        means=np.array([[1.0, 3.0], [5.0, 7.0]]),
        variances=np.array([0.5, 2.0]),
        walks=np.array([0.0, 0.0]),
        log_prob=np.log(np.array([[0.75, 0.5], [0.25, 0.5]])),
    )
    # hypothesis 0: 0.75 * 1 + 0.25 * 5 = 2; hypothesis 1: 5
    np.testing.assert_allclose(offset.mean, [2.0, 5.0])
    mean, var = offset.moments(np.array([0.5, 0.5]))
    weights = np.array([0.375, 0.25, 0.125, 0.25])  # (rate, hypothesis) flattened
    means = np.array([1.0, 3.0, 5.0, 7.0])
    assert mean == pytest.approx(3.5)
    expected = weights @ (np.array([0.5, 0.5, 2.0, 2.0]) + (means - 3.5) ** 2)
    assert var == pytest.approx(expected)
    taken = offset.take(np.array([1, 1]))
    np.testing.assert_allclose(taken.mean, [5.0, 5.0])
    # a uniform mass under a kernel that keeps each node: nothing changes
    grid_offset = HypothesisOffset(
        means=np.arange(50.0).reshape(2, 5, 5),
        variances=np.ones(2),
        walks=np.zeros(2),
        log_prob=np.log(np.full((2, 5, 5), 0.5)),
    )
    keep = (np.array([0.0, 1.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    mixed = grid_offset.mixed(np.zeros((5, 5)), keep)
    np.testing.assert_allclose(mixed.means, grid_offset.means)
    np.testing.assert_allclose(np.exp(mixed.log_prob), 0.5)
    frame = (np.zeros(2), np.eye(2), np.array([10.0, 10.0]))
    moved = grid_offset.regridded(frame, frame, (5, 5))
    np.testing.assert_allclose(moved.means, grid_offset.means)
    np.testing.assert_allclose(np.exp(moved.log_prob), 0.5)


def _gravity_correlated_mission():
    """A held-in copy of the ``imperfect_gravity`` benchmark with a 2 mGal, 3 km map error."""
    return gravity_map_error_mission(
        "gravity-correlated-map-error", {"error_rms": 2.0, "error_corr_m": 3000.0}, 11
    )


def test_a_map_error_over_kilometres_is_followed_as_a_faster_offset():
    """A gravity map 2 mGal wrong over 3 km, one gravimeter reading every 200 m.

    Along the track the error reads as an offset that moves faster than the declared
    walk. With the walks alone (``offset_smooth_m=0``) and the declared rate alone, pmf
    ends 2.4 and 2.5 km off on trials 4 and 5 claiming a few hundred metres (NEES 196 and
    2333); weighing a rate ten times faster too (a gravity map's default), it ends 301 and
    159 m off (NEES 1.1 and 0.2). The default beside them weighs a smooth offset of 2 km
    (shorter than this error's 3 km): 277 and 718 m off, NEES 0.9 and 2.2, within its
    covariance.
    """
    scen, grid = _gravity_correlated_mission()

    def ends(spec):
        return trial_ends(scen, grid, spec, (4, 5))

    for error, nees in ends("pmf:offset_smooth_m=0"):
        assert error < 400.0 and nees < 5.0, (error, nees)
    for error, nees in ends("pmf:offset_smooth_m=0,fast_offset_walk=0"):
        assert error > 2000.0 and nees > 100.0, (error, nees)
    for error, nees in ends("pmf"):
        assert error < 1000.0 and nees < 5.0, (error, nees)


def test_shared_rates_weigh_a_still_offset_and_refuse_an_unknown_setting():
    obs = _obs([1.0], 1.0, bias_var=9.0, walk=0.1)
    shared = HypothesisOffset.start(2, obs, 10.0, "shared", slow=0.0)
    np.testing.assert_allclose(shared.walks, [0.0, 0.1, 1.0])
    np.testing.assert_allclose(np.exp(shared.log_prob), 1.0 / 3.0)
    slow = HypothesisOffset.start(2, obs, 10.0, "shared")
    np.testing.assert_allclose(slow.walks, [0.0, 0.1 * SLOW_OFFSET_WALK, 0.1, 1.0])
    assert shared.shared_steady and shared.stationary == 9.0
    # one rate: nothing to share
    alone = HypothesisOffset.start(2, obs, 0.0, "shared")
    assert alone.models == 1 and not alone.shared_steady
    own = HypothesisOffset.start(2, obs, 10.0)
    assert own.models == 3 and not own.shared_steady
    for spec in ("pmf", "pf", "mpf"):
        with pytest.raises(ConfigError, match="offset_rates must be one of own, shared, pooled"):
            parse_method_spec(f"{spec}:offset_rates=mine")


def test_the_steady_split_is_the_whole_posteriors_and_the_fast_rate_each_hypothesiss():
    # rates (still, declared, fast) of two hypotheses, weights 0.8 and 0.2
    prob = np.array([[0.6, 0.1], [0.2, 0.3], [0.2, 0.6]])
    offset = HypothesisOffset(
        means=np.zeros((3, 2)),
        variances=np.ones(3),
        walks=np.array([0.0, 1e-3, 1e-2]),
        log_prob=np.log(prob),
        stationary=25.0,
        shared_steady=True,
    )
    weights = np.array([0.8, 0.2])
    after = np.exp(offset.shared(np.log(weights)).log_prob)
    # still: (0.8 * 0.6 + 0.2 * 0.1) / (0.8 * 0.8 + 0.2 * 0.4) = 0.5 / 0.72
    still = 0.5 / 0.72
    np.testing.assert_allclose(after[2], prob[2])  # the fast rate stays each one's own
    np.testing.assert_allclose(after[0], still * (1.0 - prob[2]))
    np.testing.assert_allclose(after[1], (1.0 - still) * (1.0 - prob[2]))
    np.testing.assert_allclose(after.sum(axis=0), 1.0)
    own = HypothesisOffset(offset.means, offset.variances, offset.walks, np.log(prob))
    assert own.shared(np.log(weights)) is own
    # a filter state's offset and every further field's, by the state's weights
    state = _State(np.log(weights), offset, (None, offset))
    done = shared_offsets(state)
    np.testing.assert_allclose(np.exp(done.offset.log_prob), after)
    np.testing.assert_allclose(np.exp(done.field_offsets[1].log_prob), after)
    assert done.field_offsets[0] is None
    plain = _State(np.log(weights), own, ())
    assert shared_offsets(plain) is plain


@dataclass(frozen=True)
class _State:
    log_weight: np.ndarray
    offset: HypothesisOffset | None
    field_offsets: tuple


def _steady_pings(rates: str, pings: int = 120, dt: float = 20.0, slow=None):
    """Two hypotheses on a ramp: one on the track, one whose residuals drift.

    Readings are the map at the first plus a constant 3-unit offset and N(0, 1) noise;
    the second reads a map that differs by a slow sinusoid, as a hypothesis off the
    track on a smooth field does. Returns the second's summed log-likelihood relative
    to the first's.
    """
    rng = np.random.default_rng(8)
    grid = _ramp()
    positions = np.array([[300.0, 300.0], [300.0, 300.0]])
    mapped = float(grid.sample(positions[:1, 0], positions[:1, 1])[0])
    first = _obs([mapped], 1.0, bias_var=25.0, walk=1e-3)
    offset = HypothesisOffset.start(2, first, 10.0, rates, slow)
    log_weight = np.log(np.array([0.5, 0.5]))
    for k in range(pings):
        offset = offset.predicted(dt)
        drift = np.array([0.0, 4.0 * np.sin(k / 60.0)])
        reading = mapped + 3.0 + rng.normal()
        obs = _obs([reading], 1.0, 25.0, 1e-3)

        def given(var, mean, drift=drift, reading=reading):
            r = reading - (mapped + drift) - mean
            return -0.5 * (r * r / (1.0 + var) + np.log(1.0 + var))

        log_weight = log_weight + offset.marginal(given)
        log_weight -= np.logaddexp.reduce(log_weight)
        predicted = (mapped + drift)[:, None]
        offset = offset.updated(grid, positions, obs, predicted).shared(log_weight)
    return log_weight[1] - log_weight[0]


def test_pooled_rates_move_each_hypothesiss_fast_rate_toward_the_posteriors():
    # rates (still, declared, fast) of two hypotheses, weights 0.8 and 0.2
    prob = np.array([[0.6, 0.1], [0.2, 0.3], [0.2, 0.6]])
    common = dict(means=np.zeros((3, 2)), variances=np.ones(3), walks=np.array([0, 1e-3, 1e-2]))
    shared = HypothesisOffset(**common, log_prob=np.log(prob), shared_steady=True)
    pooled = HypothesisOffset(**common, log_prob=np.log(prob), shared_steady=True, pooling=0.5)
    weights = np.array([0.8, 0.2])
    split = np.exp(shared.shared(np.log(weights)).log_prob)
    after = np.exp(pooled.shared(np.log(weights)).log_prob)
    # the geometric mean of each one's (steady split shared) and the posterior's, normalised
    posterior = split @ weights
    want = np.sqrt(split * posterior[:, None])
    np.testing.assert_allclose(after, want / want.sum(axis=0))
    # the light hypothesis's fast rate (0.6) moves toward the posterior's (0.28)
    assert posterior[2] < after[2, 1] < split[2, 1] - 0.1
    assert pooled.shared(np.log(weights)).pooling == 0.5
    obs = _obs([1.0], 1.0, bias_var=9.0, walk=0.1)
    assert HypothesisOffset.start(2, obs, 10.0, "pooled").pooling == RATE_POOLING
    assert HypothesisOffset.start(2, obs, 10.0, "shared").pooling == 0.0


def test_a_hypothesis_off_the_track_cannot_take_a_drift_the_posterior_does_not_see():
    """With shared rates the drifting hypothesis is judged by the steady rate the track
    shows, so it loses more weight than when it picks its own rate."""
    own = _steady_pings("own")
    shared = _steady_pings("shared")
    # measured: -4.0 nats with its own rates (-2.2 without the slow one), -8.6 shared
    assert shared < own - 4.0, (own, shared)
    # pooled, it cannot take the fast rate the posterior does not see either (-19.8)
    pooled = _steady_pings("pooled")
    assert pooled < shared - 3.0, (shared, pooled)


def test_a_slow_rate_gives_a_still_offset_its_information_back():
    """Each hypothesis by its own readings: beside the declared walk a slow one lets the
    hypothesis on the track explain its still offset better than the drifting one can."""
    declared = _steady_pings("own", slow=0.0)
    slow = _steady_pings("own")
    assert slow < declared - 1.0, (declared, slow)
