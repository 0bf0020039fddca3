"""The TCP server over a real loopback socket: offline-identical estimates, hostile input."""

import json
import socket

import numpy as np
import pytest

from geofix.client import Client, ServerError
from geofix.logs import read_exported
from geofix.navigator import Navigator
from geofix.server import serve_in_thread
from geofix.sim.export import export_trials


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    from conftest import small_mission_data
    from geofix.sim.scenario import scenario_from_dict

    sensor = {"type": "multibeam", "beams": 7, "swath_width_m": 3000.0, "noise_std": 2.0}
    path = tmp_path_factory.mktemp("srv") / "m.nc"
    export_trials(scenario_from_dict(small_mission_data("srv", sensor=sensor, trials=1)), path)
    return read_exported(path)


def feed_server(client, mission):
    replies = []
    deg = np.rad2deg(mission.heading)
    first = client.init(mission.times[0], *mission.nav[0], mission.sigma_position[0], deg[0])
    assert first["status"] == "initialising"
    for k in range(mission.n):
        if k:
            client.nav(mission.times[k], *mission.nav[k], deg[k])
        replies.append(client.ping(mission.times[k], mission.beams[k]))
    return replies


def feed_offline(nav, mission):
    deg = [float(np.rad2deg(h)) for h in mission.heading]
    rad = [float(np.deg2rad(d)) for d in deg]  # what the server makes of heading_deg
    nav.init(mission.times[0], mission.nav[0], mission.sigma_position[0], rad[0])
    out = []
    for k in range(mission.n):
        if k:
            nav.motion(mission.times[k], mission.nav[k], rad[k])
        out.append(nav.measure(mission.times[k], mission.beams[k]))
    return out


@pytest.mark.parametrize("method", ["pmf", "pf"])
def test_server_estimates_equal_the_offline_navigator_bit_for_bit(exported, method):
    mission, grid = exported
    offline = feed_offline(Navigator(grid, method, seed=4), mission)
    with serve_in_thread(grid, method, seed=4) as (host, port), Client(host, port) as client:
        replies = feed_server(client, mission)
        last = client.estimate()
    for reply, est in zip(replies, offline, strict=True):
        assert reply["ok"] and reply["status"] == est.status
        assert (reply["x"], reply["y"]) == (est.position[0], est.position[1])
        assert reply["cov"] == est.covariance.tolist()
    assert (last["x"], last["y"]) == (offline[-1].position[0], offline[-1].position[1])
    # and it navigated: the last fix is far closer to the truth than the INS
    assert np.hypot(last["x"] - mission.truth[-1, 0], last["y"] - mission.truth[-1, 1]) < 0.2 * (
        np.hypot(*(mission.nav[-1] - mission.truth[-1]))
    )


def hostile_lines(rng, count: int) -> list[bytes]:
    """``count`` bad requests of many kinds, none containing a newline."""
    big = json.dumps({"type": "ping", "t": 1.0, "beams": [[0.0, 0.0, 1.0]] * 5000}).encode()
    kinds = [
        lambda: b"{not json",
        lambda: b"[1, 2, 3]",
        lambda: b'"just a string"',
        lambda: b"",
        lambda: b"\xff\xfe\x00garbage",
        lambda: b'{"type": "warp", "t": 1}',
        lambda: b'{"t": 1}',
        lambda: b'{"type": "nav", "t": "soon", "x": 1, "y": 2, "heading_deg": 0}',
        lambda: b'{"type": "nav", "t": true, "x": 1, "y": 2, "heading_deg": 0}',
        lambda: b'{"type": "nav", "t": NaN, "x": 1, "y": 2, "heading_deg": 0}',
        lambda: b'{"type": "nav", "t": 1, "x": Infinity, "y": 2, "heading_deg": 0}',
        lambda: b'{"type": "nav", "t": 1e400, "x": 1, "y": 2, "heading_deg": 0}',
        lambda: b'{"type": "ping", "t": 1, "beams": "many"}',
        lambda: b'{"type": "ping", "t": 1, "beams": [[1, 2]]}',
        lambda: b'{"type": "ping", "t": 1, "beams": [[1, 2, {"a": 1}]]}',
        lambda: b'{"type": "ping", "t": 1, "beams": []}',
        lambda: b'{"type": "init", "t": 0, "x": 1, "y": 2, "sigma_m": -5}',
        lambda: b'{"type": "init", "t": 0, "lon": 1, "lat": 2, "sigma_m": 5}',
        lambda: b"[" * 50_000 + b"]" * 50_000,
        lambda: bytes(rng.integers(32, 127, int(rng.integers(1, 300)), dtype=np.uint8)),
        lambda: b'{"type": "nav", "t": -100, "x": 1, "y": 2, "heading_deg": 0}',
    ]
    lines = [kinds[int(rng.integers(len(kinds)))]() for _ in range(count)]
    for k in range(0, count, count // 20):  # huge arrays, a few of them
        lines[k] = big
    return [line.replace(b"\n", b" ") for line in lines]


def test_ten_thousand_hostile_lines_each_get_one_error_and_never_crash_it(exported):
    mission, grid = exported
    rng = np.random.default_rng(7)
    lines = hostile_lines(rng, 10_000)
    with serve_in_thread(grid, "pmf") as (host, port):
        with Client(host, port) as before_init, Client(host, port) as started:
            started.init(mission.times[0], *mission.nav[0], mission.sigma_position[0])
            errors = 0
            for client in (before_init, started):
                for lo in range(0, len(lines) // 2, 250):  # bounded batches: write, then read
                    batch = (
                        lines[lo : lo + 250] if client is before_init else lines[5000 + lo :][:250]
                    )
                    client._file.write(b"".join(line + b"\n" for line in batch))
                    client._file.flush()
                    for _ in batch:
                        reply = client.read_reply()
                        assert reply["ok"] is False and reply["error"]
                        assert "\n" not in reply["error"]
                        errors += 1
            assert errors == 10_000
            # messages before init are refused by name, and both connections still work
            assert "no init yet" in before_init.request({"type": "estimate"}, check=False)["error"]
            assert started.estimate()["status"] == "initialising"
        # a client that vanishes mid-line takes nothing down
        raw = socket.create_connection((host, port))
        raw.sendall(b'{"type": "nav", "t": 1, "x"')
        raw.close()
        with Client(host, port) as again:
            assert again.init(0.0, *mission.nav[0], 500.0)["ok"]
            with pytest.raises(ServerError, match="before the previous input"):
                again.nav(-1.0, *mission.nav[0], 0.0)


def test_lon_lat_requests_land_in_the_map_frame_and_null_offsets_are_refused():
    from pyproj import Proj

    from geofix.logs import read_mission
    from geofix.maps.gridding import grid_soundings
    from geofix.server import Session

    mission = read_mission("builtin:ex1811").subset(slice(0, 10))
    x, y, v = mission.soundings().T
    grid = grid_soundings(x, y, v, 100.0, meta={"projection": mission.frame}).grid
    session = Session(grid, "pmf")
    lon, lat = mission.meta["lon"][0], mission.meta["lat"][0]
    line = json.dumps({"type": "init", "t": 0.0, "lon": lon, "lat": lat, "sigma_m": 50.0})
    reply = session.handle(line.encode())
    assert reply["ok"], reply
    expected = Proj(mission.frame)(lon, lat)
    assert (reply["x"], reply["y"]) == pytest.approx(expected, abs=1e-6)
    bad = {"type": "ping", "t": 0.0, "beams": [[None, 0.0, -1500.0]] * 3}
    assert "finite" in session.handle(json.dumps(bad).encode())["error"]
    wrong = {"type": "ping", "t": 0.0, "beams": [[0.0, True, -1500.0]] * 3}
    assert "holds a bool" in session.handle(json.dumps(wrong).encode())["error"]


def test_ping_message_sends_missing_values_as_null_and_refuses_bad_offsets():
    from geofix.client import ping_message

    beams = np.array([[-10.0, 0.5, 101.25], [0.0, 0.0, np.nan], [10.0, -0.5, np.inf]])
    message = ping_message(3.0, beams)
    assert message == {
        "type": "ping",
        "t": 3.0,
        "beams": [[-10.0, 0.5, 101.25], [0.0, 0.0, None], [10.0, -0.5, None]],
    }
    beams[0, 0] = np.nan
    with pytest.raises(ValueError, match="beam offsets must be finite"):
        ping_message(3.0, beams)
    with pytest.raises(ValueError, match=r"\(b, 3\)"):
        ping_message(3.0, np.zeros((4, 2)))


def test_requests_orjson_refuses_are_answered_as_the_standard_library_would():
    from geofix.server import RequestError, parse_request

    assert parse_request(b'{"type": "estimate", "n": 1.5e3}') == {"type": "estimate", "n": 1500.0}
    with pytest.raises(RequestError, match="NaN is not valid JSON"):
        parse_request(b'{"type": "ping", "t": NaN}')
    assert parse_request(b'{"type": "nav", "t": 123456789012345678901234567890}')["t"] > 1e29
    with pytest.raises(RequestError, match="not JSON"):
        parse_request(b'{"type": "nav",')


def test_a_ping_of_body_frame_beams_with_attitude_is_levelled(synthetic_grid):
    from geofix.sensors.attitude import level_offsets
    from geofix.server import Session

    body = np.column_stack([np.linspace(-100, 100, 9), np.zeros(9), np.full(9, 60.0)])
    roll, pitch = np.radians(6.0), np.radians(-2.0)
    level = level_offsets(body, roll, pitch)[:, :2]
    values = synthetic_grid.sample(600.0 + level[:, 0], 500.0 + level[:, 1])
    init = json.dumps({"type": "init", "t": 0, "x": 600.0, "y": 500.0, "sigma_m": 30.0})
    four = [[*b, v] for b, v in zip(body.tolist(), values.tolist(), strict=True)]
    three = [[*b, v] for b, v in zip(level.tolist(), values.tolist(), strict=True)]
    ping4 = {"type": "ping", "t": 0, "beams": four, "roll_deg": 6.0, "pitch_deg": -2.0}
    ping3 = {"type": "ping", "t": 0, "beams": three}
    replies = []
    for ping in (ping4, ping3):
        session = Session(synthetic_grid, "pmf", seed=3)
        session.handle(init.encode())
        replies.append(session.handle(json.dumps(ping).encode()))
    assert replies[0]["ok"] and replies[1]["ok"]
    assert replies[0]["x"] == pytest.approx(replies[1]["x"], abs=1e-6)
    assert replies[0]["y"] == pytest.approx(replies[1]["y"], abs=1e-6)
    mixed = {"type": "ping", "t": 0, "beams": [four[0], three[1]]}
    reply = session.handle(json.dumps(mixed).encode())
    assert not reply["ok"] and "beam 1 must be" in reply["error"]


def test_ping_message_carries_body_frame_beams_and_the_attitude():
    from geofix.client import ping_message

    beams = np.array([[-10.0, 0.0, 50.0, 101.0], [10.0, 0.0, 50.0, np.nan]])
    message = ping_message(1.0, beams, roll_deg=5.0, pitch_deg=-1.0)
    assert message["beams"] == [[-10.0, 0.0, 50.0, 101.0], [10.0, 0.0, 50.0, None]]
    assert (message["roll_deg"], message["pitch_deg"]) == (5.0, -1.0)
    assert "roll_deg" not in ping_message(1.0, beams)
    with pytest.raises(ValueError, match="attitude"):
        ping_message(1.0, beams, roll_deg=float("nan"))


@pytest.mark.parametrize(
    "beams",
    [
        [[1.5, -2, 30.25], [0, 1e3, -4]],
        [[1, 2, None], [3, 4, 5]],
        [[1, 2, 3, 4], [5, 6, 7, 8]],
        [[1, 2, True], [3, 4, 5]],
        [[1, 2, "3"], [3, 4, 5]],
        [[1, 2], [3, 4, 5, 6]],
        [[1, 2, [3]], [3, 4, 5]],
        [[1, 2, 3], "abc"],
        [[1, 2, 3], {"a": 1, "b": 2, "c": 3}],
        [[1, 2, 10**400], [3, 4, 5]],
    ],
)
def test_the_one_pass_beam_read_agrees_with_the_checked_one(beams):
    # The raw line decides whether the beams may be read in one pass (no boolean, no
    # string beyond the keys); either way the array, or the error, is the checked path's.
    from geofix.server import _beams, parse_request

    line = json.dumps({"type": "ping", "t": 1.0, "beams": beams}).encode()
    request = parse_request(line)
    outcomes = []
    for raw in (None, line):
        try:
            outcomes.append(_beams(request, 100, raw))
        except Exception as exc:  # the outcome compared is the error itself
            outcomes.append(f"{type(exc).__name__}: {exc}")
    if isinstance(outcomes[0], str):
        assert outcomes[1] == outcomes[0] and "beam" in outcomes[0]
    else:
        np.testing.assert_array_equal(outcomes[1], outcomes[0])


def test_a_connection_chooses_its_own_method_and_ins_model(exported):
    mission, grid = exported
    ins = {"initial_error_m": [100.0, 100.0], "velocity_error_m_s": 0.05}
    with (
        serve_in_thread(grid, "pmf") as (host, port),
        Client(host, port) as own,
        Client(host, port) as default,
    ):
        assert own.config(method="pf:particles=500")["method"] == "pf:particles=500"
        served = feed_server(own, mission)
        offline = feed_offline(Navigator(grid, "pf:particles=500"), mission)
        assert [r["x"] for r in served] == [e.to_dict()["x"] for e in offline]
        # the other connection keeps the server's method
        assert (
            feed_server(default, mission)[-1]["x"]
            == (feed_offline(Navigator(grid, "pmf"), mission)[-1].to_dict()["x"])
        )
        # an error-state filter needs an INS model: refused without one, kept going
        refused = own.config(method="mpf", check=False)
        assert refused["ok"] is False and "INS" in refused["error"]
        assert own.estimate()["pings"] == mission.n  # the pf navigator is still there
        assert own.config(method="mpf:particles=500", ins=ins)["ok"]
        assert own.estimate(check=False)["ok"] is False  # a new navigator: init first
        mpf = feed_server(own, mission)
        assert np.isfinite(mpf[-1]["x"])
        for bad in (
            {"type": "config", "method": 3},
            {"type": "config", "colour": "red"},
            {"type": "config", "method": "mpf", "ins": {"initial_error_m": "far"}},
            {"type": "config", "method": "warp"},
        ):
            reply = own.request(bad, check=False)
            assert reply["ok"] is False and "\n" not in reply["error"]
