"""The Cramér-Rao bound with every field's common offset a random-walk state."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import small_mission_data
from geofix.evaluate.crlb import (
    imperfect_map_crlb,
    offset_information,
    offset_state_crlb,
    trial_crlb,
)
from geofix.maps.grid import Grid
from geofix.measurement import sample_information
from geofix.sim.trial import Trial, TrialField

CELL = 100.0
SLOPE = 0.05  # m per m
PER_SEGMENT = 10
Y_TRACK = 2030.0  # off the grid's nodes


def three_regions(gradients) -> Grid:
    """A map of three regions along x, each a plane of its own gradient ``(gx, gy)``.

    Region ``i`` covers ``x`` in ``[2000 i, 2000 (i + 1))``; the planes need not meet (the
    track's samples stay away from the cells that straddle two regions).
    """
    y, x = np.indices((60, 60)) * CELL
    region = np.minimum(x // 2000.0, 2).astype(int)
    gx = np.choose(region, [g[0] for g in gradients])
    gy = np.choose(region, [g[1] for g in gradients])
    return Grid(gx * x + gy * (y - Y_TRACK) + 3000.0, 0.0, 0.0, CELL, CELL, kind="depth")


#: Along the track, across it, and flat: three gradients no line holds.
REGIONS = [(SLOPE, 0.0), (0.0, SLOPE), (0.0, 0.0)]


def sample_x(count: int = PER_SEGMENT) -> np.ndarray:
    """``count`` samples inside each region, clear of its edges and of the nodes."""
    return np.concatenate([2000.0 * i + 430.0 + 110.0 * np.arange(count) for i in range(3)])


def static_trial(grid: Grid, x, noise_std: float = 1.0, fields=(), sigma0=1e4) -> Trial:
    """A single-beam trial heading east at ``Y_TRACK``, its INS prior ``sigma0`` per axis.

    The prior's 1-sigma does not grow, so the position is as good as fixed (the random-walk
    model's process variance is its floor, 1e-6 m^2 a step).
    """
    x = np.asarray(x, float)
    n = x.size
    truth = np.column_stack([x, np.full(n, Y_TRACK)])
    heading = np.full(n, np.pi / 2)
    offsets = np.zeros((1, 2))
    return Trial(
        truth=truth,
        true_heading=heading,
        indicated=truth,
        indicated_heading=heading,
        times=30.0 * np.arange(n),
        measured=grid.sample(truth[:, 0], truth[:, 1])[:, None],
        offsets=offsets,
        sigma_position=np.full(n, sigma0),
        noise_std=noise_std,
        fields=tuple(fields),
    )


def test_with_no_offset_prior_it_is_the_known_offset_bound():
    from geofix.sim.scenario import scenario_from_dict
    from geofix.sim.simulate import prepare_map, simulate_trial

    sensor = {"type": "multibeam", "beams": 9, "swath_angle_deg": 60, "altitude_m": 2000}
    data = small_mission_data("offset-known", sensor={**sensor, "noise_std": 5.0}, trials=1)
    scen = scenario_from_dict(data)
    grid = prepare_map(scen)
    trial = simulate_trial(scen, grid, 0)
    assert trial.ins_model is not None  # the error-state bound is the one compared
    known = trial_crlb(trial, grid)
    state = offset_state_crlb(trial, grid, offset_std=0.0, offset_walk=0.0)
    for name in ("recursive_var_m2", "track_var_m2", "rw_var_m2", "batch_var_m2"):
        assert getattr(state, name) == pytest.approx(getattr(known, name), rel=1e-7), name
    on_prior = offset_state_crlb(trial, grid, 0.0, 0.0, prior_map=True)
    usual = imperfect_map_crlb(trial, grid, offset_var=0.0)
    assert on_prior.recursive_var_m2 == pytest.approx(usual.recursive_var_m2, rel=1e-7)


def test_the_offset_state_lies_between_a_known_and_a_fresh_offset_per_ping():
    from geofix.sim.scenario import scenario_from_dict
    from geofix.sim.simulate import prepare_map, simulate_trial

    sensor = {"type": "multibeam", "beams": 9, "swath_angle_deg": 60, "altitude_m": 2000}
    data = small_mission_data("offset-between", sensor={**sensor, "noise_std": 5.0}, trials=1)
    scen = scenario_from_dict(data)
    grid = prepare_map(scen)
    trial = simulate_trial(scen, grid, 0)
    known = trial_crlb(trial, grid).recursive_var_m2
    fresh = imperfect_map_crlb(trial, grid, offset_var=np.inf).recursive_var_m2
    previous = known
    for std, walk in [(1.0, 0.0), (10.0, 1e-3), (30.0, 1e-3), (30.0, 1.0)]:
        bound = offset_state_crlb(trial, grid, std, walk).recursive_var_m2
        assert previous * (1 - 1e-9) <= bound <= fresh * (1 + 1e-9), (std, walk)
        previous = bound
    # the filters' own model (5 m + 0.2 % of depth, 1e-3 m^2/s) costs a real share
    default = offset_state_crlb(trial, grid).recursive_var_m2
    assert known * 1.05 < default < fresh


def test_one_beam_on_one_plane_tells_nothing_when_the_offset_is_unknown():
    grid = three_regions(REGIONS)
    trial = static_trial(grid, [430.0], sigma0=1e3)
    huge = offset_state_crlb(trial, grid, offset_std=1e5, offset_walk=0.0)
    known = offset_state_crlb(trial, grid, offset_std=0.0, offset_walk=0.0)
    # known offset: x learns a^2 / R; y nothing
    assert known.recursive_var_m2 == pytest.approx(1.0 / (1e-6 + SLOPE**2) + 1e6, rel=1e-9)
    # unknown: the sample's level goes to the offset, both axes keep their prior
    assert huge.recursive_var_m2 == pytest.approx(2e6, rel=1e-5)


def test_a_profile_over_three_planes_keeps_its_shape_information():
    """Closed form: ``J = (n / R) [[a^2, 0, a], [0, a^2, a], [a, a, 3]]`` over (x, y, c)."""
    grid = three_regions(REGIONS)
    trial = static_trial(grid, sample_x())
    n, r = PER_SEGMENT, 1.0
    known_trace = 2.0 * r / (n * SLOPE**2)  # (n a^2 / R) I
    unknown_trace = 4.0 * r / (n * SLOPE**2)  # Schur complement (n a^2 / 3R) [[2,-1],[-1,2]]
    known = offset_state_crlb(trial, grid, offset_std=0.0, offset_walk=0.0)
    unknown = offset_state_crlb(trial, grid, offset_std=1e5, offset_walk=0.0)
    assert known.batch_var_m2 == pytest.approx(known_trace, rel=1e-9)
    assert unknown.batch_var_m2 == pytest.approx(unknown_trace, rel=1e-6)
    # the recursion, with a wide prior and a fixed position, ends at the batch bound
    assert known.recursive_var_m2 == pytest.approx(known_trace, rel=1e-4)
    assert unknown.recursive_var_m2 == pytest.approx(unknown_trace, rel=1e-4)
    # a per-ping offset (the bound before) loses everything a single beam has
    fresh = imperfect_map_crlb(trial, grid, offset_var=np.inf)
    assert fresh.recursive_var_m2 == pytest.approx(2.0 * 1e8, rel=1e-3)


def test_a_walking_offset_forgets_what_the_flat_region_told():
    grid = three_regions(REGIONS)
    trial = static_trial(grid, sample_x())
    still = offset_state_crlb(trial, grid, offset_std=1e5, offset_walk=0.0)
    walking = offset_state_crlb(trial, grid, offset_std=1e5, offset_walk=1e-2)
    assert walking.recursive_var_m2 > 1.2 * still.recursive_var_m2


def test_several_fields_each_with_its_own_offset_add_their_information():
    depth = three_regions(REGIONS)
    # gravity: flat where depth slopes along the track, and sloping where depth is flat
    gravity = three_regions([(0.0, 0.0), (0.0, 0.02), (0.02, 0.0)])
    x = sample_x()
    alone = static_trial(depth, x)
    read = gravity.sample(alone.truth[:, 0], alone.truth[:, 1])[:, None]
    field = TrialField(
        kind="gravity",
        sensor="gravimeter",
        measured=read,
        offsets=np.zeros((1, 2)),
        noise_std=0.5,
        beam_noise_std=np.array([0.5]),
        grid=gravity,
    )
    both = static_trial(depth, x, fields=[field])
    expected = np.zeros((2, 2))
    for grid, var in ((depth, 1.0), (gravity, 0.25)):
        _, gx, gy = grid.sample_gradient(alone.truth[:, 0], alone.truth[:, 1], "bilinear")
        rows = np.column_stack([gx, gy, np.ones_like(gx)])
        j = rows.T @ rows / var
        expected += j[:2, :2] - np.outer(j[:2, 2], j[:2, 2]) / j[2, 2]  # its offset eliminated
    bound = offset_state_crlb(both, depth, offset_std=[1e5, 1e5], offset_walk=0.0)
    assert bound.batch_var_m2 == pytest.approx(np.trace(np.linalg.inv(expected)), rel=1e-6)
    assert bound.recursive_var_m2 == pytest.approx(bound.batch_var_m2, rel=1e-4)
    # each field alone tells less than both
    gravity_alone = static_trial(gravity, x, noise_std=0.5)
    for single, grid in ((alone, depth), (gravity_alone, gravity)):
        own = offset_state_crlb(single, grid, offset_std=1e5, offset_walk=0.0)
        assert own.batch_var_m2 > 1.3 * bound.batch_var_m2
    # and with the offsets known it is the sum of the fields' information, trial_crlb's
    known = offset_state_crlb(both, depth, offset_std=0.0, offset_walk=0.0)
    assert known.batch_var_m2 == pytest.approx(trial_crlb(both, depth).batch_var_m2, rel=1e-9)


def test_offset_information_holds_sample_information_and_its_offset_limit():
    rng = np.random.default_rng(4)
    gx, gy = rng.normal(size=(5, 7)), rng.normal(size=(5, 7))
    var = rng.uniform(0.5, 2.0, size=7)
    valid = rng.uniform(size=(5, 7)) > 0.2
    info = offset_information(gx, gy, var, valid)
    np.testing.assert_allclose(info[:, :2, :2], sample_information(gx, gy, var, valid))
    schur = (
        info[:, :2, :2]
        - np.einsum("ni,nj->nij", info[:, :2, 2], info[:, :2, 2]) / info[:, 2, 2][:, None, None]
    )
    np.testing.assert_allclose(schur, sample_information(gx, gy, var, valid, offset_var=np.inf))
