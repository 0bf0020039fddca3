"""The server with further maps: a ping's ``fields``, an init's ``fields``, one-line errors."""

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from geofix.cli import app
from geofix.client import Client, ping_message
from geofix.errors import ConfigError
from geofix.filters.base import observations
from geofix.navigator import Navigator
from geofix.replay import map_in_frame
from geofix.server import serve_in_thread
from geofix.sim import prepare_map, scenario_from_dict, simulate_trial

SCENARIO = {
    "name": "srv-fused",
    "sensors": [
        {"map": {"path": "builtin:mb_1km"}, "sensor": {"type": "singlebeam", "noise_std": 30}},
        {"map": {"path": "builtin:grav_1km"}, "sensor": {"type": "gravimeter", "noise_std": 0.5}},
    ],
    "track": {
        "start_cell": [15, 135],
        "heading_deg": 60,
        "speed_m_s": 8,
        "interval_s": 30,
        "samples": 25,
    },
    "ins": {"initial_error_m": [0, 0], "initial_error_std_m": 3000, "velocity_error_m_s": 0.05},
    "trials": 1,
    "seed": 2602,
}
GRAVITY_VAR = 0.25


@pytest.fixture(scope="module")
def problem():
    scen = scenario_from_dict(SCENARIO)
    grid = prepare_map(scen)
    return simulate_trial(scen, grid, 0).problem(grid)


def readings(problem, k):
    """The primary beams and the gravity field of sample ``k``."""
    beams = np.column_stack([problem.offsets, problem.measured[k]])
    field = problem.fields[0]
    gravity = np.column_stack([field.offsets, field.measured[k]])
    return beams, [{"kind": "gravity", "beams": gravity, "noise_var": GRAVITY_VAR}]


def feed(problem, send_init, send_nav, send_ping, fields=True):
    """Feed a problem's samples through three callables; their answers."""
    deg = [float(np.rad2deg(h)) for h in problem.heading]
    out = [send_init(problem.times[0], *problem.indicated[0], problem.sigma_position[0], deg[0])]
    for k in range(problem.n):
        if k:
            out.append(send_nav(problem.times[k], *problem.indicated[k], deg[k]))
        beams, extra = readings(problem, k)
        out.append(send_ping(problem.times[k], beams, extra if fields else None))
    return out


def offline(problem, fields=True):
    grid, maps = problem.grid, [f.grid for f in problem.fields]
    nav = Navigator(grid, "pmf", {"noise_std": 30.0}, seed=4, field_grids=maps)
    noise = observations(problem)[0].noise_var

    def init(t, x, y, sigma, deg):
        return nav.init(t, (x, y), sigma, float(np.deg2rad(deg)))

    def motion(t, x, y, deg):
        return nav.motion(t, (x, y), float(np.deg2rad(deg)))

    def ping(t, beams, extra):
        assert noise == 30.0**2
        return nav.measure(t, beams, fields=extra)

    return feed(problem, init, motion, ping, fields)


def serve(problem, **kw):
    maps = [f.grid for f in problem.fields]
    return serve_in_thread(
        problem.grid, "pmf", settings={"noise_std": 30.0}, seed=4, field_grids=maps, **kw
    )


def test_server_fuses_a_pings_fields_as_the_offline_navigator_bit_for_bit(problem):
    expected = offline(problem)
    alone = offline(problem, fields=False)
    with serve(problem) as (host, port), Client(host, port) as client:
        replies = feed(
            problem, client.init, client.nav, lambda t, b, e: client.ping(t, b, fields=e)
        )
    assert len(replies) == len(expected)
    for reply, est in zip(replies, expected, strict=True):
        assert reply["ok"] and reply["status"] == est.status
        assert (reply["x"], reply["y"]) == (est.position[0], est.position[1])
        assert reply["cov"] == est.covariance.tolist()
    # the gravity readings move the fix: the same pings without them end elsewhere
    assert not np.array_equal(expected[-1].position, alone[-1].position)


def test_an_init_names_the_further_maps_a_connection_weighs(problem):
    alone = offline(problem, fields=False)
    beams, extra = readings(problem, 0)
    with serve(problem) as (host, port), Client(host, port) as client:
        replies = feed(
            problem,
            lambda *a: client.init(*a, fields=[]),
            client.nav,
            lambda t, b, e: client.ping(t, b),
        )
        # the primary map alone: a ping's gravity has no map on this connection
        refused = client.ping(problem.times[-1], beams, fields=extra, check=False)
        assert not refused["ok"] and "field kind 'gravity' has no map here" in refused["error"]
        # naming a kind the server lacks is refused, naming gravity brings it back
        bad = client.init(0.0, *problem.indicated[0], 500.0, fields=["magnetic"], check=False)
        assert not bad["ok"] and bad["error"].startswith("init: no further map of kind magnetic")
        assert "\n" not in bad["error"]
        client.init(problem.times[0], *problem.indicated[0], 3000.0, fields=["gravity"])
        assert client.ping(problem.times[0], beams, fields=extra)["ok"]
    for reply, est in zip(replies, alone, strict=True):
        assert (reply["x"], reply["y"]) == (est.position[0], est.position[1])


def test_bad_fields_get_one_line_errors_and_leave_the_navigator_as_it_was(problem):
    beams, extra = readings(problem, 0)
    gravity = extra[0]["beams"].tolist()
    good = {"kind": "gravity", "beams": gravity, "noise_var": GRAVITY_VAR}
    bad = [
        ({"fields": {"kind": "gravity"}}, "ping: fields must be a list"),
        ({"fields": [good, good]}, "ping: field gravity given twice"),
        ({"fields": [{**good, "kind": "magnetic"}]}, "field kind 'magnetic' has no map here"),
        ({"fields": [{**good, "lag": 1}]}, "ping: a field has unknown key(s) lag"),
        ({"fields": [{**good, "noise_var": None}]}, "gravity field noise_var is missing"),
        ({"fields": [{**good, "noise_var": -1}]}, "noise_var must lie within 0 .. 1e+12"),
        ({"fields": [{**good, "noise_var": [1, 2]}]}, "noise_var has 2 values for 1 beams"),
        ({"fields": [{**good, "noise_var": "1"}]}, "noise_var must be a number"),
        ({"fields": [{**good, "beams": [[0, 0, 5000.0]]}]}, "gravity field beam 0 value 5000"),
        ({"fields": [{**good, "beams": [[0, 0, "x"]]}]}, "gravity field beam 0 holds a str"),
        ({"fields": [{**good, "beams": []}]}, "gravity field beams must be a non-empty list"),
    ]
    with serve(problem) as (host, port), Client(host, port) as client:
        client.init(problem.times[0], *problem.indicated[0], 3000.0)
        before = client.estimate()
        for change, message in bad:
            request = {**ping_message(problem.times[0], beams), **change}
            reply = client.request(request, check=False)
            assert not reply["ok"], change
            assert message in reply["error"] and "\n" not in reply["error"]
        after = client.estimate()
        assert after == before and after["pings"] == 0
        # a ping of the gravity field alone (no valid primary beam) is taken, NIS null
        line = json.dumps({**ping_message(problem.times[0], [[0, 0, None]]), "fields": [good]})
        reply = client.send_line(line.encode())
        assert reply["ok"] and reply["accepted"] and reply["nis"] is None


def test_a_server_of_one_map_refuses_fields_and_answers_as_before(problem):
    beams, extra = readings(problem, 0)
    with (
        serve_in_thread(problem.grid, "pmf", seed=4) as (host, port),
        Client(host, port) as client,
    ):
        client.init(problem.times[0], *problem.indicated[0], 3000.0)
        reply = client.ping(problem.times[0], beams, fields=extra, check=False)
        assert not reply["ok"]
        assert reply["error"] == (
            "ping: field kind 'gravity' has no map here (none: this connection has one map)"
        )
        bad = client.init(0.0, *problem.indicated[0], 500.0, fields=["gravity"], check=False)
        assert bad["error"] == (
            "init: no further map of kind gravity (none: the server has one map)"
        )
        assert client.ping(problem.times[0], beams)["ok"]


def test_geofix_serve_takes_a_further_map_and_refuses_two_of_one_kind():
    exe = Path(sys.executable).with_name("geofix")
    args = [str(exe), "serve", "--map", "builtin:mb_1km", "--map", "builtin:grav_1km"]
    proc = subprocess.Popen(
        [*args, "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        line = proc.stderr.readline()
        while line and "serving" not in line:
            line = proc.stderr.readline()
        found = re.search(r"on 127\.0\.0\.1:(\d+) \(Ctrl-C stops\)", line)
        assert found and "grav_1km" in line, line
        with Client("127.0.0.1", int(found.group(1))) as client:
            client.init(0.0, 0.0, 0.0, 2000.0)
            extra = [{"kind": "gravity", "beams": [[0.0, 0.0, 10.0]], "noise_var": 1.0}]
            reply = client.ping(0.0, [[0.0, 0.0, -3000.0]], fields=extra)
            assert reply["ok"] and reply["accepted"] and reply["pings"] == 1
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate(timeout=30)
    result = CliRunner().invoke(
        app, ["serve", "--map", "builtin:grav_1km", "--map", "builtin:grav_1km", "--port", "0"]
    )
    assert result.exit_code != 0
    assert "is a gravity map like an earlier --map" in result.output


def test_a_further_map_in_another_frame_is_read_at_the_same_places():
    from geofix.maps.grid import Grid
    from geofix.maps.project import frame_proj, local_tmerc

    own, primary = local_tmerc(-28.0, 38.5), local_tmerc(-27.5, 38.0)
    x = np.arange(-40, 41) * 1000.0
    gx, gy = np.meshgrid(x, x)
    lon, lat = frame_proj(own)(gx, gy, inverse=True)
    values = 10.0 * lon + 3.0 * lat  # a field linear in lon / lat
    grid = Grid(
        values, -40e3, -40e3, 1000.0, 1000.0, kind="gravity", units="mGal", meta={"projection": own}
    )
    moved = map_in_frame(grid, primary)
    assert moved.meta["projection"] == primary and moved.meta["resampled_from"] == own
    assert map_in_frame(grid, own) is grid
    # where both hold data the resampled map reads the value of the same lon / lat
    px, py = frame_proj(primary)(np.array([-28.1, -27.9]), np.array([38.4, 38.6]))
    np.testing.assert_allclose(
        moved.sample(px, py),
        10.0 * np.array([-28.1, -27.9]) + 3.0 * np.array([38.4, 38.6]),
        atol=0.01,
    )
    with pytest.raises(ConfigError, match="cannot be related"):
        map_in_frame(grid, None)
