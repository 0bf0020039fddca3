"""The online navigator with several fields per ping: the campaign's fused steps, the checks."""

import numpy as np
import pytest

from geofix import InputError, Navigator
from geofix.errors import ConfigError
from geofix.filters.base import observations
from geofix.maps.grid import Grid
from geofix.methods import parse_method_spec
from geofix.navigator import NavigatorSettings
from geofix.sim import prepare_map, scenario_from_dict, simulate_trial

FUSED = {
    "name": "nav-fused",
    "sensors": [
        {
            "map": {"path": "builtin:mb_1km"},
            "sensor": {"type": "singlebeam", "noise_std": 30, "map_error_std": 15},
        },
        {"map": {"path": "builtin:grav_1km"}, "sensor": {"type": "gravimeter", "noise_std": 0.5}},
    ],
    "track": {
        "start_cell": [15, 135],
        "heading_deg": 60,
        "speed_m_s": 8,
        "interval_s": 30,
        "samples": 40,
    },
    "ins": {"initial_error_m": [0, 0], "initial_error_std_m": 3000, "velocity_error_m_s": 0.05},
    "trials": 1,
    "seed": 2601,
}


@pytest.fixture(scope="module")
def fused_problem():
    scen = scenario_from_dict(FUSED)
    grid = prepare_map(scen)
    return simulate_trial(scen, grid, 0).problem(grid)


def plane(kind: str, gradient: tuple[float, float], units: str, size: int = 200) -> Grid:
    """A plane on 100 m cells: value = gradient . (x, y) (plus -1000 m for a depth map)."""
    x = np.arange(size) * 100.0
    gx, gy = np.meshgrid(x, x)
    base = -1000.0 if kind == "depth" else 0.0
    values = base + gradient[0] * gx + gradient[1] * gy
    return Grid(values, 0.0, 0.0, 100.0, 100.0, kind=kind, units=units, name=kind)


DEPTH = plane("depth", (0.05, 0.0), "m")  # tells x only
GRAVITY = plane("gravity", (0.0, 0.005), "mGal")  # tells y only


def drive_problem(nav: Navigator, problem, with_fields: bool = True):
    """Feed a navigator a problem's samples as a replay would, the fields with each ping."""
    obs = observations(problem)
    sigma = np.asarray(problem.sigma_position, dtype=float)
    nav.init(problem.times[0], problem.indicated[0], float(sigma[0]), float(problem.heading[0]))
    out = []
    for k in range(problem.n):
        if k:
            var = max(float(sigma[k] ** 2 - sigma[k - 1] ** 2), 1e-6)
            nav.motion(problem.times[k], problem.indicated[k], float(problem.heading[k]), var)
        beams = np.column_stack([problem.offsets, problem.measured[k]])
        fields = None
        if with_fields:
            fields = [
                {
                    "kind": f.kind,
                    "beams": np.column_stack([f.offsets, f.measured[k]]),
                    "noise_var": f.noise_std**2 + f.map_error_std**2,
                }
                for f in problem.fields
            ]
        out.append(nav.measure(problem.times[k], beams, obs[k].noise_var, fields=fields))
    return out


@pytest.mark.parametrize("method", ["pmf:model=rw", "pf:model=rw"])  # the campaign has an INS
def test_navigator_fuses_fields_as_the_campaign_filter_bit_for_bit(fused_problem, method):
    problem = fused_problem
    assert [f.kind for f in problem.fields] == ["gravity"]
    fix = parse_method_spec(method).match(problem, np.random.default_rng(4))
    maps = [f.grid for f in problem.fields]
    nav = Navigator(problem.grid, method, NavigatorSettings.passive(), 4, field_grids=maps)
    ests = drive_problem(nav, problem)
    np.testing.assert_array_equal(np.array([e.position for e in ests]), fix.track)
    np.testing.assert_array_equal(ests[-1].covariance, fix.covariance)
    # the same readings without the gravity field: another track
    alone = Navigator(problem.grid, method, NavigatorSettings.passive(), 4)
    track = np.array([e.position for e in drive_problem(alone, problem, with_fields=False)])
    assert not np.array_equal(track, fix.track)


@pytest.mark.parametrize("method", ["pmf", "pf:map_model=imperfect"])
def test_further_maps_without_readings_change_no_number(fused_problem, method):
    problem = fused_problem
    maps = [f.grid for f in problem.fields]
    one = Navigator(problem.grid, method, seed=5)
    two = Navigator(problem.grid, method, seed=5, field_grids=maps)
    a = drive_problem(one, problem, with_fields=False)
    b = drive_problem(two, problem, with_fields=False)
    for x, y in zip(a, b, strict=True):
        assert np.array_equal(x.position, y.position)
        assert np.array_equal(x.covariance, y.covariance)
        assert x.status == y.status and np.array_equal(x.nis, y.nis, equal_nan=True)


def straight_run(fields: bool, primary: bool = True, n: int = 40, seed: int = 3):
    """A straight single-beam run on the depth plane with a gravimeter; the last estimate."""
    rng = np.random.default_rng(seed)
    heading = np.deg2rad(45.0)
    t = np.arange(n) * 10.0
    truth = np.array([6000.0, 6000.0]) + t[:, None] * 10.0 * np.array([np.sin(heading)] * 2)
    ins_error = np.array([300.0, -400.0])
    maps = [GRAVITY] if fields else None
    # exact maps: on a plane along a straight track a common offset is one with a shift
    nav = Navigator(DEPTH, "pmf:map_model=exact", {"noise_std": 2.0}, seed=seed, field_grids=maps)
    nav.init(t[0], truth[0] + ins_error, 500.0, heading)
    est = None
    for k in range(n):
        if k:
            nav.motion(t[k], truth[k] + ins_error, heading)
        depth = DEPTH.sample(truth[k, 0], truth[k, 1]) + 2.0 * rng.standard_normal()
        gravity = GRAVITY.sample(truth[k, 0], truth[k, 1]) + 0.5 * rng.standard_normal()
        value = float(depth) if primary else np.nan
        extra = [{"kind": "gravity", "beams": [[0, 0, float(gravity)]], "noise_var": 0.25}]
        est = nav.measure(t[k], [[0.0, 0.0, value]], fields=extra if fields else None)
    return est, truth[-1]


def test_a_field_that_tells_the_other_axis_fixes_both():
    # depth varies with x only, gravity with y only: each alone leaves an axis to the INS
    depth_only, truth = straight_run(fields=False)
    fused, _ = straight_run(fields=True)
    gravity_only, _ = straight_run(fields=True, primary=False)
    runs = {"depth": depth_only, "fused": fused, "gravity": gravity_only}
    err = {name: est.position - truth for name, est in runs.items()}
    sd = {name: np.sqrt(np.diag(est.covariance)) for name, est in runs.items()}
    # depth alone: x is fixed (2 m / 0.05 = 40 m a ping, 40 pings), y keeps the INS's 400 m
    assert abs(err["depth"][0]) < 30.0 and abs(err["depth"][1]) > 350.0
    assert sd["depth"][0] < 20.0 and sd["depth"][1] > 400.0
    # gravity alone (no valid depth in any ping): y is fixed (0.5 / 0.005 = 100 m a ping),
    # x keeps its 300 m error; the primary's NIS is the health rules' and there is none
    assert abs(err["gravity"][1]) < 50.0 and abs(err["gravity"][0]) > 250.0
    assert sd["gravity"][1] < 30.0 and sd["gravity"][0] > 400.0
    assert np.isnan(gravity_only.nis) and gravity_only.accepted
    # both: both axes fixed, each as well as its own field alone fixes it
    assert np.all(np.abs(err["fused"]) < 50.0)
    assert sd["fused"][0] < 20.0 and sd["fused"][1] < 30.0


def test_bad_further_maps_are_config_errors():
    with pytest.raises(ConfigError, match="weighs one field only"):
        Navigator(DEPTH, "sitan", field_grids=[GRAVITY])
    with pytest.raises(ConfigError, match="gravity is given twice"):
        Navigator(DEPTH, "pmf", field_grids=[GRAVITY, GRAVITY])
    with pytest.raises(ConfigError, match="depth is given twice"):
        Navigator(DEPTH, "pmf", field_grids=[DEPTH])
    with pytest.raises(ConfigError, match="must be maps"):
        Navigator(DEPTH, "pmf", field_grids=["builtin:grav_1km"])
    assert Navigator(DEPTH, "pmf", field_grids=GRAVITY).field_kinds == ("gravity",)


def test_bad_field_readings_are_input_errors_that_change_nothing():
    nav = Navigator(DEPTH, "pmf", {"noise_std": 2.0}, field_grids=[GRAVITY])
    nav.init(0.0, (6000.0, 6000.0), 300.0, 0.0)
    before = nav.estimate()
    good = {"kind": "gravity", "beams": [[0, 0, 30.0]], "noise_var": 0.25}
    bad = [
        ([{**good, "kind": "magnetic"}], "field kind 'magnetic' has no map"),
        ([good, good], "field gravity given twice"),
        ([{"kind": "gravity", "beams": [[0, 0, 30.0]]}], "needs its noise_var"),
        ([{**good, "lag_s": 2}], "unknown key"),
        ([{**good, "beams": [[0, 0]]}], "gravity field ping: beams must have shape"),
        ([{**good, "noise_var": -1}], "noise_var must be"),
        ({"kind": "gravity"}, "fields must be a list"),
        (["gravity"], "must be an object"),
    ]
    for fields, message in bad:
        with pytest.raises(InputError, match=message):
            nav.measure(0.0, [[0.0, 0.0, -700.0]], fields=fields)
    after = nav.estimate()
    assert after.pings == before.pings == 0
    assert np.array_equal(after.position, before.position)
    one = Navigator(DEPTH, "pmf")
    one.init(0.0, (6000.0, 6000.0), 300.0, 0.0)
    with pytest.raises(InputError, match="has no map"):
        one.measure(0.0, [[0.0, 0.0, -700.0]], fields=[good])
