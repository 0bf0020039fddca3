"""The online navigator tells the truth about itself: lost falls back to the INS, and
``converged`` is claimed only when the filter's consistency supports it."""

import warnings
from dataclasses import fields

import numpy as np
import pytest

from geofix import Navigator
from geofix.errors import ConfigError
from geofix.filters.pmf import Pmf
from geofix.logs.mission import Mission
from geofix.maps import fractal_terrain
from geofix.navigator import NavigatorSettings, normalised_move
from geofix.problem import footprint_xy
from geofix.replay import converged_nees, nees, replay

# The navigator's rules are tested with the map taken as exact (up to white noise per
# beam), the measurement model the filters had when these failures were measured; a
# filter that also models the map's errors (``map_model``) changes what gets lost.
EXACT = "map_model=exact" if "map_model" in {f.name for f in fields(Pmf)} else ""
PMF_EXACT = f"pmf:{EXACT}" if EXACT else "pmf"

ACROSS = np.linspace(-150.0, 150.0, 21)
OFFSETS = np.column_stack([ACROSS, np.zeros_like(ACROSS)])
INS_OFFSET = np.array([25.0, -20.0])  # the INS error of the multibeam runs, metres


# ---------------------------------------------------------------------- a long track
def long_track(n=300, map_mismatch=80.0, seed=0):
    """A ship's single-beam track (68 s pings at 5 m/s) over a fractal map of 1' cells.

    The depths are the map plus ``map_mismatch`` metres of white error (an independent
    map, 3-5 km deep): with the default 2 m noise the filter cannot explain them and
    gets lost, as on the 22-hour ship track against an independent 1' grid.
    """
    rng = np.random.default_rng(seed)
    grid = fractal_terrain((150, 150), 1850.0, rng=rng, hurst=0.8, std=400.0, mean=-4000.0)
    t = np.arange(n) * 68.0
    heading = np.deg2rad(60.0) + 0.6 * np.sin(t / 20000.0)
    velocity = 5.0 * np.column_stack([np.sin(heading), np.cos(heading)])
    truth = np.array([40e3, 40e3]) + np.vstack([[0.0, 0.0], np.cumsum(velocity[1:] * 68.0, 0)])
    depth = grid.sample(*truth.T) + map_mismatch * rng.standard_normal(n)
    beams = np.zeros((n, 1, 3))
    beams[:, 0, 2] = depth
    return grid, Mission(t, truth, heading, beams, nav_source="gnss", name="long")


@pytest.fixture(scope="module")
def lost_replay():
    grid, mission = long_track()
    return replay(mission, grid, [PMF_EXACT], initial_error_m=2000.0, seed=0)


def test_a_reinitialised_navigator_keeps_following_the_ins(lost_replay):
    """The frozen estimate: re-initialised on the box's best-matching spot every time, the
    estimate stayed where it was lost while the INS went on (tens of km off)."""
    ests = lost_replay.estimates[PMF_EXACT]
    assert ests[-1].reinits >= 5  # the filter does get lost on this track
    track = np.array([e.position for e in ests])
    ins = lost_replay.inputs.indicated
    for a, b in ((100, 200), (200, 299)):
        moved, ins_moved = track[b] - track[a], ins[b] - ins[a]
        assert np.hypot(*ins_moved) > 15e3
        # no loss in between ... or one: the estimate moves with the INS either way
        assert np.hypot(*(moved - ins_moved)) < 0.1 * np.hypot(*ins_moved), (a, b)


@pytest.mark.parametrize("method", ["pmf", "pf", "sitan"])
def test_a_reinitialised_filter_fed_motions_moves_by_the_ins_displacement(method):
    grid, mission = long_track(n=3)
    nav = Navigator(grid, method, {"outage_s": 30.0}, seed=1)
    start = mission.nav[0] + (300.0, -200.0)
    nav.init(0.0, start, 500.0, float(mission.heading[0]))
    nav.measure(0.0, mission.ping(0))
    lost = nav.motion(60.0, start + np.array([250.0, 150.0]), 0.5)  # 60 s without a ping
    assert lost.status == "lost" and lost.reinits == 1
    before, _ = nav.filter.estimate(nav.state)
    position = start + np.array([250.0, 150.0])
    for k in range(1, 6):
        position = position + np.array([280.0, 120.0])
        est = nav.motion(60.0 + 55.0 * k, position, 0.5)
    after, _ = nav.filter.estimate(nav.state)
    shift = 5 * np.array([280.0, 120.0])
    # exact for a grid or an EKF; a particle set also draws its process noise (~1 m here)
    tolerance = 5.0 if method == "pf" else 1e-6 * grid.cell_size
    np.testing.assert_allclose(after - before, shift, atol=tolerance)
    # while lost, the report is the INS fallback: it moves by the INS displacement too
    np.testing.assert_allclose(est.position - lost.position, shift, atol=1e-6)


def test_a_lost_navigator_never_drifts_faster_than_the_ins(lost_replay):
    ests = lost_replay.estimates[PMF_EXACT]
    truth, ins = lost_replay.inputs.truth, lost_replay.inputs.indicated
    err = np.array([e.position for e in ests]) - truth
    ins_err = ins - truth
    good = 0  # the last good fix: the init (no offset) until a ping is converged
    for k, est in enumerate(ests):
        if est.status == "converged":
            good = k
        if est.status != "lost":
            continue
        # the fallback moved by the INS motion since the good fix: its error grew by
        # exactly the INS's error growth, never more
        growth = np.hypot(*(ins_err[k] - ins_err[good]))
        assert np.hypot(*err[k]) <= np.hypot(*err[good]) + growth + 1e-6, k
    statuses = [e.status for e in ests]
    assert statuses.count("lost") > len(ests) // 2
    assert np.hypot(*err[-1]) <= np.hypot(*ins_err[-1]) + 1.0
    # re-initialisation does not fire on every record: a grace of pings after each
    grace = NavigatorSettings().reinit_grace_pings
    assert ests[-1].reinits <= len(ests) / grace + 1


def test_the_lost_covariance_is_the_last_good_one_grown_by_the_ins():
    grid, mission = long_track(n=3)
    nav = Navigator(grid, "pmf", {"outage_s": 30.0}, seed=1)
    x0 = mission.nav[0]
    nav.init(0.0, x0, 400.0, 0.5)
    for k in range(1, 4):
        nav.motion(60.0 * k, x0 + np.array([300.0 * k, 0.0]), 0.5, process_var=2500.0)
    est = nav.estimate()
    assert est.status == "lost"
    # never converged: the INS itself, the init prior grown by three motions
    np.testing.assert_allclose(est.position, x0 + np.array([900.0, 0.0]))
    np.testing.assert_allclose(est.covariance, (400.0**2 + 3 * 2500.0) * np.eye(2))
    np.testing.assert_allclose(nav.fallback()[1], est.covariance)
    # the filter was restarted around it with that sigma (not the init's 400 m)
    _, cov = nav.filter.estimate(nav.state)
    assert np.sqrt(cov.max()) > 400.0


# ---------------------------------------------------------------------- converged
def multibeam_run(grid, rng, n, offset=0.0, noise=0.3, heading=np.pi / 4):
    """A straight multibeam run: truth, pings (values on the true field + ``offset``)."""
    t = np.arange(n) * 1.0
    truth = np.array([400.0, 300.0]) + t[:, None] * 8.0 * np.array(
        [np.sin(heading), np.cos(heading)]
    )
    pings = []
    for k in range(n):
        x, y = footprint_xy(truth[k], np.asarray(heading), OFFSETS)
        values = grid.sample(x, y) + offset + noise * rng.standard_normal(ACROSS.size)
        pings.append(np.column_stack([OFFSETS, values]))
    return t, truth, pings


def drive(nav, t, nav_track, pings, heading=np.pi / 4, sigma=40.0):
    nav.init(t[0], nav_track[0], sigma, heading)
    out = []
    for k in range(t.size):
        if k:
            nav.motion(t[k], nav_track[k], heading)
        out.append(nav.measure(t[k], pings[k]))
    return out


@pytest.mark.parametrize("method", ["pmf", "pf", "sitan"])
def test_one_ping_never_makes_converged(synthetic_grid, rng, method):
    t, truth, pings = multibeam_run(synthetic_grid, rng, 14)
    # a small prior and a sharp 21-beam swath: one ping pins the position
    nav = Navigator(synthetic_grid, method, {"noise_std": 0.3}, seed=3)
    ests = drive(nav, t, truth + np.array([4.0, -3.0]), pings, sigma=5.0)
    need = NavigatorSettings().converge_min_pings
    assert all(e.status != "converged" for e in ests[: need - 1])
    assert ests[-1].status == "converged", [e.status for e in ests]
    with pytest.raises(ConfigError, match="converge_min_pings"):
        NavigatorSettings(converge_min_pings=1)


def test_an_offset_map_is_not_claimed_converged_beyond_three_sigma(synthetic_grid):
    """Readings on the true field + 3 m (the map 3 m off, 1 m noise, no offset state).

    The filter runs 60-180 m off with a few metres of sigma; the old rules called 34 of
    its 40 pings ``converged``, every one beyond 3 sigma (NEES in the thousands).
    """
    settings = {"noise_std": 1.0, "depth_bias_std": 0.0}
    for seed in (1, 2):
        t, truth, pings = multibeam_run(
            synthetic_grid, np.random.default_rng(seed), 40, offset=3.0, noise=1.0
        )
        start = truth + INS_OFFSET
        ests = drive(Navigator(synthetic_grid, PMF_EXACT, settings, seed=2), t, start, pings)
        scores = nees(ests, truth)
        claimed = np.array([e.status == "converged" for e in ests])
        assert (scores[claimed] <= 9.0).all(), (seed, scores[claimed], np.flatnonzero(claimed))
        assert (scores > 9.0).mean() > 0.5  # the filter is wrong here, and says it is not sure
    # the control: the same run on the true field converges and stays within 3 sigma
    t, truth, pings = multibeam_run(synthetic_grid, np.random.default_rng(5), 40, noise=1.0)
    ests = drive(
        Navigator(synthetic_grid, PMF_EXACT, settings, seed=2), t, truth + INS_OFFSET, pings
    )
    claimed = np.array([e.status == "converged" for e in ests])
    assert claimed.sum() >= 20 and (nees(ests, truth)[claimed] <= 9.0).all()


def test_a_fix_the_ins_rules_out_is_not_converged(synthetic_grid, rng):
    t, truth, pings = multibeam_run(synthetic_grid, rng, 14)
    settings = {"noise_std": 0.3, "converge_shift_max": None}  # the INS term alone
    nav = Navigator(synthetic_grid, PMF_EXACT, settings, seed=3)
    ests = drive(nav, t, truth + np.array([4.0, -3.0]), pings, sigma=5.0)
    assert ests[-1].status == "converged"
    mean, cov = nav.filter.estimate(nav.state)
    assert nav.consistency(mean, cov) is None
    position, spread = nav.fallback()  # the INS plus the last good offset: the fix itself
    np.testing.assert_allclose(position, ests[-1].position, atol=1e-6)
    # the same posterior 5 fallback sigmas away: the INS all but rules it out
    away = mean + np.array([5.0 * np.sqrt(spread[0, 0] + cov[0, 0]), 0.0])
    assert nav.consistency(away, cov) == "ins"
    assert nav.consistency(mean + np.array([1.0, 0.0]) * np.sqrt(cov[0, 0]), cov) is None


def test_the_shift_term_is_the_chi_square_of_what_the_filter_learnt():
    predicted = np.diag([4.0, 9.0])
    posterior = np.diag([1.0, 9.0])  # learnt 3 m^2 along x, nothing along y
    assert normalised_move([3.0, 0.0], predicted, posterior) == pytest.approx(3.0)
    # a move along y, where nothing was learnt, meets the floor: 10 % of the prediction
    assert normalised_move([0.0, 3.0], predicted, posterior) == pytest.approx(10.0)
    # a consistent Kalman filter's moves: chi-square of two degrees of freedom
    rng = np.random.default_rng(7)
    gained = predicted - posterior + np.diag([0.0, 2.0])
    moves = rng.multivariate_normal(np.zeros(2), gained, size=4000)
    stats = np.array([normalised_move(m, predicted, posterior - np.diag([0, 2])) for m in moves])
    assert abs(stats.mean() - 2.0) < 0.15  # 2 +- 3 x 2 / sqrt(4000)
    # beyond the default limit, the 97.5 % point: 2.5 % +- 3 x 0.25 % (sampling)
    assert abs((stats > NavigatorSettings().converge_shift_max).mean() - 0.025) < 0.0075


# ---------------------------------------------------------------------- EX1811
@pytest.fixture(scope="module")
def ex1811():
    import tempfile
    from pathlib import Path

    from geofix.logs import read_mission
    from geofix.logs.gridmap import grid_log
    from geofix.maps import load_grid
    from geofix.maps.gridding import load_map_error

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "ex1811_50m.nc"
        grid_log("builtin:ex1811", 50.0, path)
        grid, error = load_grid(path), load_map_error(path)
    return grid, error, read_mission("builtin:ex1811", frame=grid.meta["projection"])


def test_ex1811_pmf_is_honest_when_it_says_converged(ex1811):
    """``geofix replay builtin:ex1811 --map <50 m grid of it> --method pmf`` (seed 0).

    It reported ``converged`` from the first ping with sigma 0.14 m while 15 m off (mean
    NEES 1112); the grid had collapsed onto a few nodes and then walked back over 15
    pings by far more than its covariance allowed.
    """
    grid, error, mission = ex1811
    result = replay(mission, grid, ["pmf"], seed=0, map_error=error)
    ests = result.estimates["pmf"]
    row = result.summary["methods"]["pmf"]
    claimed = [k for k, e in enumerate(ests) if e.status == "converged"]
    assert len(claimed) >= 10 and claimed[0] >= NavigatorSettings().converge_min_pings - 1
    assert row["converged_nees"] <= 5.0, row
    assert row["converged_nees"] == pytest.approx(nees(ests, result.inputs.truth)[claimed].mean())
    assert row["converged_pings"] == len(claimed)
    assert converged_nees(ests, None) is None


def test_the_server_does_not_call_one_ping_converged(ex1811):
    """It said ``converged`` after the first EX1811 ping, sigma 2.4 m while 42 m off."""
    from geofix.client import Client
    from geofix.server import serve_in_thread

    grid, _, mission = ex1811
    deg = np.rad2deg(mission.heading)
    with serve_in_thread(grid, "pmf") as (host, port), Client(host, port) as client:
        client.init(0.0, *mission.nav[0], 50.0, float(deg[0]))
        replies = [client.ping(float(mission.times[0]), mission.ping(0))]
        for k in range(1, 4):
            client.nav(float(mission.times[k]), *mission.nav[k], float(deg[k]))
            replies.append(client.ping(float(mission.times[k]), mission.ping(k)))
    assert all(r["ok"] and r["status"] == "converging" for r in replies)
    first = replies[0]
    error = np.hypot(first["x"] - mission.nav[0][0], first["y"] - mission.nav[0][1])
    assert error > 20.0  # the first ping's fix is tens of metres off: rightly not converged


@pytest.mark.parametrize("poison", [1e160, -1e200, 1e308])
def test_a_poisoned_ping_is_refused_and_the_navigator_keeps_its_state(poison):
    """A reading the input checks let through cannot leave a non-finite estimate."""
    grid = fractal_terrain((128, 128), 10.0, rng=np.random.default_rng(0), name="synthetic")
    nav = Navigator(grid, "pmf", {"noise_std": 0.3, "gate_nis": None}, seed=1)
    nav.init(0.0, (600.0, 600.0), 30.0, 0.0)
    offsets = np.column_stack([np.linspace(-50.0, 50.0, 9), np.zeros(9)])
    clean = grid.sample(600.0 + offsets[:, 0], 600.0 + offsets[:, 1])
    nav.motion(1.0, (600.0, 600.0), 0.0)
    before = nav.measure(1.0, np.column_stack([offsets, clean]))
    nav.motion(2.0, (600.0, 600.0), 0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # and no overflow warning on the way
        poisoned = nav.measure(2.0, np.column_stack([offsets, clean + poison]))
    assert not poisoned.accepted and poisoned.rejected == 1
    np.testing.assert_allclose(poisoned.position, before.position)
    assert np.isfinite(poisoned.covariance).all()
    nav.motion(3.0, (600.0, 600.0), 0.0)
    after = nav.measure(3.0, np.column_stack([offsets, clean]))
    assert after.accepted and np.hypot(*(after.position - (600.0, 600.0))) < before.sigma_m
    assert after.sigma_m < before.sigma_m
