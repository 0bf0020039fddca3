"""The online navigator: one step shared with campaigns, statuses, gating, re-init, input checks."""

import numpy as np
import pytest

from geofix import FreeIns, InputError, Navigator
from geofix.errors import ConfigError, MemoryBudgetError
from geofix.filters.base import RecursiveFilter, observations
from geofix.logs import read_exported
from geofix.methods import available_methods, parse_method_spec
from geofix.navigator import NavigatorSettings
from geofix.problem import footprint_xy
from geofix.replay import ReplayInput, drive
from geofix.sim.export import export_trials, load_exported

ACROSS = np.linspace(-150.0, 150.0, 21)
OFFSETS = np.column_stack([ACROSS, np.zeros_like(ACROSS)])


def pings(grid, rng, n=30, noise=0.3, start=(400.0, 300.0), heading=np.pi / 4, speed=8.0):
    """A straight multibeam run on ``grid``: times, true track, beams (b, 3) per ping."""
    t = np.arange(n) * 1.0
    step = speed * np.array([np.sin(heading), np.cos(heading)])
    truth = np.asarray(start) + t[:, None] * step
    out = []
    for k in range(n):
        x, y = footprint_xy(truth[k], np.asarray(heading), OFFSETS)
        values = grid.sample(x, y) + noise * rng.standard_normal(ACROSS.size)
        out.append(np.column_stack([OFFSETS, values]))
    return t, truth, out


def run(nav, t, nav_track, beams, heading=np.pi / 4, sigma=40.0):
    nav.init(t[0], nav_track[0], sigma, heading)
    ests = []
    for k in range(t.size):
        if k:
            nav.motion(t[k], nav_track[k], heading)
        ests.append(nav.measure(t[k], beams[k]))
    return ests


def test_navigator_steps_are_the_campaign_steps_bit_for_bit(small_mission, tmp_path):
    sensor = {"type": "multibeam", "beams": 7, "swath_width_m": 3000.0, "noise_std": 2.0}
    path = export_trials(small_mission("nav-same", sensor=sensor, trials=1), tmp_path / "m.nc")
    mission, grid = read_exported(path)
    trial = load_exported(path)[1][0]
    problem = trial.problem(grid)
    for method in ("pmf:model=rw", "pf:model=rw", "sitan"):  # the campaign has an INS model
        fix = parse_method_spec(method).match(problem, np.random.default_rng(9))
        nav = Navigator(grid, method, NavigatorSettings.passive(), seed=9)
        inputs = ReplayInput(mission.nav, mission.heading, mission.sigma_position, mission.truth)
        noise_var = observations(problem)[0].noise_var
        ests = drive(nav, mission, inputs, noise_var)
        np.testing.assert_array_equal(np.array([e.position for e in ests]), fix.track)
        np.testing.assert_array_equal(ests[-1].covariance, fix.covariance)


def test_status_goes_initialising_converging_converged_and_mle_meets_mmse(synthetic_grid, rng):
    t, truth, beams = pings(synthetic_grid, rng)
    nav = Navigator(synthetic_grid, "pmf", {"noise_std": 0.3}, seed=1)
    offset = np.array([30.0, -25.0])
    first = nav.init(0.0, truth[0] + offset, 40.0, np.pi / 4)
    assert first.status == "initialising"
    ests = run(nav, t, truth + offset, beams)
    statuses = [e.status for e in ests]
    assert statuses[-1] == "converged" and "lost" not in statuses
    assert set(statuses) <= {"converging", "converged"}
    # the INS offset is removed: the fix is the true track within a map cell
    assert np.hypot(*(ests[-1].position - (truth[-1]))) < synthetic_grid.cell_size
    assert np.hypot(*(ests[-1].position - ests[-1].mle)) < synthetic_grid.cell_size
    assert ests[-1].sigma_m < 2 * synthetic_grid.cell_size


def test_an_outlier_ping_is_gated_out_and_leaves_the_estimate(synthetic_grid, rng):
    t, truth, beams = pings(synthetic_grid, rng, n=20)
    nav = Navigator(synthetic_grid, "pmf", {"noise_std": 0.3, "gate_nis": 25.0}, seed=1)
    run(nav, t, truth, beams)
    before = nav.estimate()
    nav.motion(20.0, truth[-1], np.pi / 4)
    bad = beams[-1].copy()
    bad[:, 2] += 40.0
    est = nav.measure(20.0, bad)
    assert not est.accepted and est.rejected == 1 and est.nis > 25.0
    np.testing.assert_allclose(est.position, before.position, atol=1e-6)


def test_a_biased_sensor_is_lost_by_the_nis_window_and_reinitialised(synthetic_grid, rng):
    t, truth, beams = pings(synthetic_grid, rng, n=40)
    settings = {"noise_std": 0.3, "gate_nis": None, "nis_window": 5, "nis_limit": 9.0}
    nav = Navigator(synthetic_grid, "pmf", settings, seed=2)
    ests = run(nav, t[:20], truth[:20], beams[:20])
    assert ests[-1].status == "converged"
    statuses = []
    for k in range(20, 40):
        nav.motion(t[k], truth[k], np.pi / 4)
        biased = beams[k].copy()
        biased[:, 2] += 15.0  # a 15 m depth bias (50 sigma)
        statuses.append(nav.measure(t[k], biased).status)
    assert "lost" in statuses
    assert nav.estimate().reinits >= 1


def test_an_outage_reinitialises_around_the_last_good_offset(synthetic_grid, rng):
    t, truth, beams = pings(synthetic_grid, rng, n=20)
    offset = np.array([25.0, 10.0])
    nav = Navigator(synthetic_grid, "pmf", {"noise_std": 0.3, "outage_s": 30.0}, seed=3)
    ests = run(nav, t, truth + offset, beams)
    assert ests[-1].status == "converged"
    est = nav.motion(60.0, truth[-1] + offset, np.pi / 4)  # 41 s without a ping
    assert est.status == "lost" and est.reinits == 1
    # the restarted prior is centred on the navigation corrected by the last good offset
    mean, _ = nav.filter.estimate(nav.state)
    assert np.hypot(*(mean - truth[-1])) < synthetic_grid.cell_size


def test_inputs_are_validated_with_clear_errors(synthetic_grid):
    nav = Navigator(synthetic_grid, "pmf", seed=0)
    with pytest.raises(InputError, match="no init yet"):
        nav.measure(0.0, [[0.0, 0.0, -100.0]])
    with pytest.raises(InputError, match="start box"):
        nav.init(0.0, (-5000.0, -5000.0), 10.0)
    with pytest.raises(InputError, match="sigma_m must be positive"):
        nav.init(0.0, (600.0, 600.0), 0.0)
    nav.init(10.0, (600.0, 600.0), 30.0)
    with pytest.raises(InputError, match="before the previous input"):
        nav.motion(5.0, (600.0, 600.0), 0.0)
    with pytest.raises(InputError, match="limit 30 m/s"):
        nav.motion(11.0, (700.0, 600.0), 0.0)
    with pytest.raises(InputError, match="from the last nav"):
        nav.measure(20.0, [[0.0, 0.0, -100.0]])
    with pytest.raises(InputError, match=r"shape \(b, 3\)"):
        nav.measure(10.0, [[0.0, -100.0]])
    with pytest.raises(InputError, match="finite"):
        nav.measure(10.0, [[np.nan, 0.0, -100.0]])
    with pytest.raises(InputError, match="more than max_beams"):
        nav.measure(10.0, np.zeros((5000, 3)))
    with pytest.raises(InputError, match="t must be finite"):
        nav.motion(float("nan"), (600.0, 600.0), 0.0)
    # the refused inputs left the navigator usable
    three = [[a, 0.0, float(synthetic_grid.sample(600.0 + a, 600.0))] for a in (-20, 0, 20)]
    assert nav.measure(10.5, three).accepted
    assert not nav.measure(10.6, three[:2]).accepted  # fewer than min_beams


def test_bad_method_or_setting_is_a_config_error(synthetic_grid):
    with pytest.raises(ConfigError, match="batch matcher"):
        Navigator(synthetic_grid, "tercom")
    with pytest.raises(ConfigError, match="'ins' cannot run ping by ping"):
        Navigator(synthetic_grid, "ins")  # the free INS has no filter steps
    with pytest.raises(ConfigError, match="'FreeIns' cannot run ping by ping"):
        Navigator(synthetic_grid, FreeIns())
    with pytest.raises(ConfigError, match="needs an INS error model"):
        Navigator(synthetic_grid, "pmf:model=errstate")
    with pytest.raises(ConfigError, match="unknown setting"):
        Navigator(synthetic_grid, "pmf", {"gate": 3})
    with pytest.raises(ConfigError, match="unknown method"):
        Navigator(synthetic_grid, "nope")


def test_a_mounting_offset_moves_every_beam_by_it(synthetic_grid, rng):
    t, truth, beams = pings(synthetic_grid, rng, n=25, noise=0.1)
    mount = np.array([12.0, -8.0])  # sonar 12 m to starboard, 8 m aft of the nav point
    # the beams were measured from the sonar: give them relative to it, and the nav point
    shifted = []
    for b in beams:
        rel = b.copy()
        rel[:, :2] -= mount
        shifted.append(rel)
    settings = {"noise_std": 0.1, "mount_offset_m": tuple(mount)}
    right = run(Navigator(synthetic_grid, "pmf", settings, seed=1), t, truth, shifted)
    wrong = run(Navigator(synthetic_grid, "pmf", {"noise_std": 0.1}, seed=1), t, truth, shifted)
    assert np.hypot(*(right[-1].position - truth[-1])) < 2.0
    # without it the fix absorbs the 14 m lever arm
    assert np.hypot(*(wrong[-1].position - truth[-1])) > 8.0


def test_attitude_levels_a_nadir_beam_by_the_known_angle():
    from geofix.sensors.attitude import level_offsets

    roll = pitch = np.radians(10.0)
    slant = 100.0 / np.cos(roll)  # a nadir beam that meets the bottom 100 m down
    rolled = level_offsets([[0.0, 0.0, slant]], roll=roll)[0]
    np.testing.assert_allclose(rolled, [-100.0 * np.tan(roll), 0.0, 100.0], atol=1e-12)
    pitched = level_offsets([[0.0, 0.0, slant]], pitch=pitch)[0]
    np.testing.assert_allclose(pitched, [0.0, 100.0 * np.tan(pitch), 100.0], atol=1e-12)
    # a sensor 2 m below the reference point moves 2 sin(30 deg) = 1 m to port
    lever = level_offsets([[0.0, 0.0, 0.0]], roll=np.radians(30.0), mount=(0.0, 0.0, 2.0))[0]
    np.testing.assert_allclose(lever[:2], [-1.0, 0.0], atol=1e-12)
    # an attitude-free beam is unchanged
    np.testing.assert_allclose(level_offsets([[40.0, -5.0, 90.0]])[0], [40.0, -5.0, 90.0])


def test_body_frame_beams_with_roll_and_pitch_are_the_levelled_beams(synthetic_grid, rng):
    """(b, 4) body beams + attitude give the estimates of the same beams levelled by hand."""
    from geofix.sensors.attitude import level_offsets

    t, truth, _ = pings(synthetic_grid, rng, n=12)
    roll = np.radians(8.0) * np.sin(0.5 * t)
    pitch = np.radians(-3.0) * np.cos(0.3 * t)
    mount = (1.0, 2.0, 3.0)
    body_pings, flat_pings = [], []
    for k in range(t.size):
        body = np.column_stack([OFFSETS, np.full(ACROSS.size, 80.0)])
        level = level_offsets(body, roll[k], pitch[k], mount)
        values = synthetic_grid.sample(*footprint_xy(truth[k], np.asarray(np.pi / 4), level[:, :2]))
        body_pings.append(np.column_stack([body, values]))
        flat_pings.append(np.column_stack([level[:, :2], values]))
        assert abs(level[ACROSS.size // 2, 0] - (1.0 - 83.0 * np.sin(roll[k]))) < 3.0
    a = Navigator(synthetic_grid, "pmf", {"noise_std": 0.3, "mount_offset_m": mount}, seed=2)
    b = Navigator(synthetic_grid, "pmf", {"noise_std": 0.3}, seed=2)
    for nav in (a, b):
        nav.init(t[0], truth[0] + 20.0, 40.0, np.pi / 4)
    for k in range(t.size):
        if k:
            a.motion(t[k], truth[k] + 20.0, np.pi / 4)
            b.motion(t[k], truth[k] + 20.0, np.pi / 4)
        ea = a.measure(t[k], body_pings[k], roll=roll[k], pitch=pitch[k])
        eb = b.measure(t[k], flat_pings[k])
        np.testing.assert_allclose(ea.position, eb.position, atol=1e-6)
    assert np.hypot(*(ea.position - truth[-1])) < 5.0
    with pytest.raises(InputError, match="roll must be within"):
        a.measure(t[-1], body_pings[-1], roll=2.0)
    with pytest.raises(InputError, match="pitch must be finite"):
        a.measure(t[-1], body_pings[-1], pitch=float("nan"))


def test_a_bicubic_navigator_reads_the_map_bicubic_and_converges(synthetic_grid, rng):
    t, truth, beams = pings(synthetic_grid, rng, n=15)
    nav = Navigator(synthetic_grid, "pmf", {"noise_std": 0.3, "interpolation": "bicubic"})
    assert nav.grid.interpolation == "bicubic" and synthetic_grid.interpolation == "bilinear"
    ests = run(nav, t, truth + 25.0, beams)
    assert ests[-1].status == "converged" and np.hypot(*(ests[-1].position - truth[-1])) < 5.0
    with pytest.raises(ConfigError, match="interpolation"):
        Navigator(synthetic_grid, "pmf", {"interpolation": "spline"})


def test_an_all_beam_bicubic_update_beyond_the_budget_is_refused(synthetic_grid, monkeypatch):
    # A bicubic read predicts (particles, beams) before its likelihood: 100 000 beams of a
    # few thousand particles (~GBs) must be refused under a 1 GB budget, with the estimate.
    monkeypatch.setenv("GEOFIX_MEMORY_BUDGET", "1GB")
    settings = {"noise_std": 0.3, "interpolation": "bicubic", "max_update_beams": None}
    nav = Navigator(synthetic_grid, "pf", {**settings, "max_beams": 10**6}, seed=1)
    nav.init(0.0, (400.0, 300.0), 40.0, 0.0)
    across = np.linspace(-100.0, 100.0, 100_000)
    ping = np.column_stack([across, np.zeros_like(across), np.full_like(across, -100.0)])
    with pytest.raises(
        MemoryBudgetError, match=r"hypotheses x 100000 beams would need .* GiB; memory budget"
    ):
        nav.measure(1.0, ping)


def test_min_beams_default_takes_single_beam_pings_and_gates_multibeam_ones(synthetic_grid, rng):
    assert NavigatorSettings().min_beams is None
    heading, n = np.pi / 4, 60
    t = np.arange(n) * 1.0
    truth = np.array([300.0, 250.0]) + t[:, None] * 8.0 * np.array(
        [np.sin(heading), np.cos(heading)]
    )
    nav = Navigator(synthetic_grid, "pmf", {"noise_std": 0.3}, seed=5)
    nav.init(t[0], truth[0] + (20.0, -15.0), 25.0, heading)
    for k in range(n):
        if k:
            nav.motion(t[k], truth[k] + (20.0, -15.0), heading)
        value = synthetic_grid.sample(*truth[k]) + 0.3 * rng.standard_normal()
        est = nav.measure(t[k], [[0.0, 0.0, value]])
        assert est.accepted or est.rejected  # a one-beam ping is used (or NIS-gated)
    assert est.rejected < n // 4 and np.hypot(*(est.position - truth[-1])) < 15.0
    # a multibeam ping still needs three valid beams
    beams = np.column_stack([OFFSETS, np.full(ACROSS.size, np.nan)])
    beams[:2, 2] = synthetic_grid.sample(*footprint_xy(truth[-1], np.asarray(heading), OFFSETS[:2]))
    assert not nav.measure(t[-1], beams).accepted
    beams[2, 2] = synthetic_grid.sample(
        *footprint_xy(truth[-1], np.asarray(heading), OFFSETS[2:3])
    )[0]
    assert nav.measure(t[-1], beams).accepted
    # an explicit setting still rules: min_beams=2 takes the two-beam ping
    explicit = Navigator(synthetic_grid, "pmf", {"noise_std": 0.3, "min_beams": 2}, seed=5)
    explicit.init(t[-1], truth[-1], 25.0, heading)
    beams[2, 2] = np.nan
    assert explicit.measure(t[-1], beams).accepted
    with pytest.raises(ConfigError, match="min_beams"):
        Navigator(synthetic_grid, "pmf", {"min_beams": 0})


def test_every_recursive_filter_declares_what_the_navigator_reads():
    declared = {}
    for name, cls in available_methods().items():
        if issubclass(cls, RecursiveFilter):
            filt = cls()
            assert filt.name == name and filt.recursive is True
            declared[name] = (filt.needs_ins_model, filt.map_model, filt.carries_offset)
    assert declared == {
        "pmf": (False, "imperfect", True),
        "pf": (False, "imperfect", True),
        "mpf": (True, "imperfect", True),
        "sitan": (False, "exact", False),
        "sitan-bank": (False, "exact", False),
    }
    errstate = parse_method_spec("pmf:model=errstate,map_model=exact")
    assert errstate.needs_ins_model and errstate.map_model == "exact"
    assert not errstate.carries_offset


def test_a_nis_window_loss_drops_only_the_fixes_made_while_it_filled(synthetic_grid):
    """The fallback goes back to the last good fix before the window's first ping."""
    from geofix.navigator.health import Health

    health = Health(NavigatorSettings(nis_window=3), synthetic_grid)
    health.restart(100.0)
    nav = np.zeros(2)
    for k, offset in enumerate(([1.0, 0.0], [2.0, 0.0], [3.0, 0.0], [4.0, 0.0])):
        health.add_nis(1.0 + k)  # a ping's NIS, then its fix (the navigator's order)
        health.remember_good(np.array(offset), np.eye(2), nav)
    # the window holds the NIS of pings 2, 3 and 4: the fixes of pings 2 to 4 are suspect
    health.forget_good_fix()
    position, cov = health.fallback(nav)
    assert position.tolist() == [1.0, 0.0] and cov.tolist() == np.eye(2).tolist()
    # a second loss with no good fix since: the same fix again, not the INS alone
    for _ in range(3):
        health.add_nis(50.0)
    health.forget_good_fix()
    assert health.fallback(nav)[0].tolist() == [1.0, 0.0]
    # no good fix before the window at all: the INS alone, at the init prior
    health.restart(100.0)
    health.add_nis(50.0)
    health.remember_good(np.array([9.0, 9.0]), np.eye(2), nav)
    for _ in range(2):
        health.add_nis(50.0)
    health.forget_good_fix()
    position, cov = health.fallback(nav)
    assert position.tolist() == [0.0, 0.0] and cov[0, 0] == pytest.approx(100.0**2)
