"""Per-path offsets pooled with the neighbours' at each resampling (``offset_pool``)."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

from geofix.errors import ConfigError
from geofix.filters.base import observations
from geofix.filters.hypothesis_offset import HypothesisOffset, pooled_offsets
from geofix.maps.grid import Grid
from geofix.methods import parse_method_spec
from geofix.sim import scenario_from_dict, simulate_trial

TRACKS = "benchmarks/data/mgd77"


def test_points_together_share_the_weighted_mean_offset():
    """Every point at one place: each gets the weighted mean, per rate, moment-matched."""
    rng = np.random.default_rng(3)
    points = np.full((50, 2), 1234.5)
    log_weight = np.log(rng.random(50))
    means = rng.normal(size=(2, 50))
    log_prob = np.log(np.stack([np.full(50, 0.3), np.full(50, 0.7)]))
    log_prob[:, :10] = np.log([[0.9], [0.1]])
    got, got_prob = pooled_offsets(points, log_weight, means, log_prob, 10.0)
    mass = np.exp(log_weight) * np.exp(log_prob)  # (2, 50)
    expected = (mass * means).sum(axis=1) / mass.sum(axis=1)
    np.testing.assert_allclose(got, np.repeat(expected[:, None], 50, axis=1))
    share = mass.sum(axis=1) / mass.sum()
    np.testing.assert_allclose(np.exp(got_prob), np.repeat(share[:, None], 50, axis=1))


def test_points_further_apart_than_the_kernel_do_not_mix():
    """Two clusters three lattice widths apart keep their own means; within, they mix."""
    rng = np.random.default_rng(4)
    left = rng.uniform(0.0, 4.0, (40, 2))
    right = left + np.array([30.0, 0.0])
    points = np.vstack([left, right])
    means = np.concatenate(
        [1.0 + 0.1 * rng.standard_normal(40), -1.0 + 0.1 * rng.standard_normal(40)]
    )
    got, _ = pooled_offsets(points, np.zeros(80), means[None], np.zeros((1, 80)), 10.0)
    assert np.all(np.abs(got[0, :40] - 1.0) < 0.1) and np.all(np.abs(got[0, 40:] + 1.0) < 0.1)
    assert got[0, :40].std() < 0.5 * means[:40].std()  # neighbours within the kernel mix


def test_an_outlying_particle_does_not_size_the_lattice():
    """One point a thousand kilometres off: the lattice holds the touched nodes only."""
    points = np.vstack([np.random.default_rng(5).uniform(0, 100, (1000, 2)), [[1e9, 1e9]]])
    means = np.arange(1001.0)[None]
    got, _ = pooled_offsets(points, np.zeros(1001), means, np.zeros((1, 1001)), 0.5)
    assert got[0, -1] == 1000.0  # alone: keeps its own


def test_zero_width_leaves_the_offsets():
    offset = HypothesisOffset.single(np.arange(5.0), 1.0, 0.0)
    assert offset.pooled(np.zeros((5, 2)), np.zeros(5), 0.0) is offset


@pytest.mark.parametrize("spec", ["pf", "mpf"])
@pytest.mark.parametrize("value", ["-1", "nan", "inf"])
def test_a_bad_pool_width_is_refused(spec, value):
    with pytest.raises(ConfigError, match="offset_pool"):
        parse_method_spec(f"{spec}:offset_pool={value}")


def _singlebeam_state(spec: str):
    """A filter and its state after three single-beam pings on a rough synthetic map."""
    y, x = np.indices((120, 120)) * 50.0
    grid = Grid(-3000.0 + 40.0 * np.sin(x / 400.0) * np.cos(y / 300.0), 0.0, 0.0, 50.0, 50.0)
    scen = scenario_from_dict(
        {
            "name": "pooled",
            "map": {"path": "depth.nc"},
            "sensor": {"type": "singlebeam", "noise_std": 1.0},
            "track": {"start_m": [3000.0, 3000.0], "heading_deg": 30.0, "speed_m_s": 4.0,
                      "interval_s": 10.0, "samples": 10},
            "ins": {"initial_error_m": [0, 0], "initial_error_std_m": 300.0},
            "trials": 1,
            "seed": 2,
        }
    )  # fmt: skip
    problem = simulate_trial(scen, grid, 0).problem(grid)
    filt = parse_method_spec(spec)
    rng = np.random.default_rng(0)
    state = filt.initialize(problem, rng)
    for obs in observations(problem)[:3]:
        state = filt.update(state, obs, grid, rng)
    return filt, state


def test_mpf_pooling_keeps_each_copy_on_the_path_its_offset_was_learnt_on():
    """Pooling, by default on profile pings, mpf jitters its copies within their share.

    Each particle's offset is tagged with its index; a copy must stay within a few
    share widths of the particle it copies (the kernel move carries copies about half
    the set's spread away). Unset, the pool is 2 on profile pings and 0 on a swath's.
    """
    cases = (  # spec, the last ping a profile's, the copies near their paths
        ("mpf:offset_pool=2", True, True),
        ("mpf", True, True),
        ("mpf:offset_pool=0", True, False),
        ("mpf:offset_pool=2", False, True),
        ("mpf", False, False),
    )
    for spec, profile, near in cases:
        filt, state = _singlebeam_state(spec)
        assert state.profile  # single-beam pings
        count = state.dp.shape[0]
        tagged = dataclasses.replace(
            state, offset=HypothesisOffset.single(np.arange(count), 1.0, 0), profile=profile
        )
        before = tagged.positions
        after = filt._resample(tagged, np.random.default_rng(1))
        source = after.offset.means[0].astype(int)
        moved = np.hypot(*(after.positions - before[source]).T)
        bound = 3.5 * np.sqrt(2.0) * after.spacing / np.sqrt(12.0)
        assert (np.quantile(moved, 0.99) <= bound) == near, (spec, np.quantile(moved, 0.99), bound)


@pytest.mark.parametrize("spec", ["pf", "mpf:offset_pool=2"])
def test_pooled_offsets_hold_the_covariance_on_a_held_out_real_track(spec):
    """EW0112, 24-36 h, seed 1006, against ETOPO1 at 10': unpooled, pf claimed 15 pings
    converged beyond 3 sigma there (largest NEES 26); pooled (pf's default), none."""
    from geofix.logs.mgd77 import field_segments, pick_segment
    from geofix.maps import load_grid
    from geofix.replay import nees, replay, window_mission

    grid = load_grid(f"{TRACKS}/etopo1_10min_ew0112.nc")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, missions = field_segments(
            f"{TRACKS}/ew0112_excerpt.m77t", "depth", frame=grid.meta["projection"]
        )
    mission = window_mission(pick_segment(missions, None), 24.0, 12.0)
    result = replay(mission, grid, [spec], seed=1006)
    ests = result.estimates[spec]
    truth = result.inputs.truth
    scores = nees(ests, truth)
    converged = np.array([e.status == "converged" for e in ests])
    error = np.hypot(*(np.array([e.position for e in ests]) - truth).T)
    ins_end = float(np.hypot(*(result.inputs.indicated[-1] - truth[-1])))
    assert converged.sum() > 20
    assert np.count_nonzero(converged & (scores > 11.83)) == 0, scores[converged].max()
    assert error[-1] < ins_end
