"""The server's limits: one heavy connection never stalls another, sizes and bytes bounded,
inputs checked at the door, a clean stop; every server here listens on 127.0.0.1."""

import json
import os
import re
import signal
import socket
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from geofix.client import Client, ServerError
from geofix.errors import ConfigError, MemoryBudgetError
from geofix.maps import fractal_terrain
from geofix.server import Session, serve_in_thread
from geofix.server_limits import MemoryLedger, RateLog, ServerLimits

OFFSETS = np.column_stack([np.linspace(-150.0, 150.0, 9), np.zeros(9)])


@pytest.fixture(scope="module")
def terrain():
    """A 400 x 400 fractal seabed of 10 m cells."""
    return fractal_terrain((400, 400), 10.0, rng=np.random.default_rng(0), name="limits")


def beams_at(grid, position) -> np.ndarray:
    values = grid.sample(position[0] + OFFSETS[:, 0], position[1] + OFFSETS[:, 1])
    return np.column_stack([OFFSETS, values])


def ping_times(client, grid, first: int, count: int) -> list[float]:
    """Send ``count`` nav + ping pairs along a line; each ping's reply time, seconds."""
    times = []
    for k in range(first, first + count):
        position = np.array([1500.0 + 5.0 * k, 2000.0])
        client.nav(float(k), *position, 90.0)
        start = time.perf_counter()
        client.ping(float(k), beams_at(grid, position))
        times.append(time.perf_counter() - start)
    return times


@pytest.mark.serial  # it times pings against each other: another test beside it is noise
def test_a_heavy_connection_does_not_stall_an_ordinary_one(terrain):
    # the updates run on threads, a heavy connection's on its own lower-priority ones:
    # the ordinary connection's ping, timed against its own unloaded pings in this run,
    # stays near them while the heavy one runs updates tens of times longer; with one
    # worker for all (every update in one queue, as on a single event loop) it waits for
    # the heavy updates.
    # one common offset: the scheduling is the test, and the default's offset per
    # hypothesis would triple each heavy update's time for nothing it asserts
    heavy_spec = "pf:particles=1000000,max_particles=1000000,offset_per_hypothesis=false"
    settings = {"max_update_beams": 9}
    ratios = {}
    for workers in (4, 1):
        # with one worker and no heavy lane, every update waits in one queue
        limits = ServerLimits(workers=workers, heavy_points=10**9 if workers == 1 else 250_000)
        with (
            serve_in_thread(terrain, "pmf", settings=settings, limits=limits) as (host, port),
            Client(host, port) as ordinary,
            Client(host, port) as heavy,
        ):
            ordinary.init(0.0, 1500.0, 2000.0, 100.0)
            ping_times(ordinary, terrain, 1, 30)  # converge: later updates are alike
            alone = ping_times(ordinary, terrain, 31, 15)
            assert heavy.config(method=heavy_spec)["ok"]
            heavy.init(0.0, 1500.0, 2000.0, 1000.0)
            heavy_times: list[float] = []
            running = threading.Event()
            running.set()

            def load(client=heavy, out=heavy_times, running=running):
                k = 1
                while running.is_set():
                    out.extend(ping_times(client, terrain, k, 1))
                    k += 1

            thread = threading.Thread(target=load)
            thread.start()
            while not heavy_times:  # the heavy connection is under way
                time.sleep(0.01)
            loaded = ping_times(ordinary, terrain, 46, 15)
            running.clear()
            thread.join()
            alone += ping_times(ordinary, terrain, 61, 15)
            yardstick = statistics.median(alone)
            assert statistics.median(heavy_times) > 10 * yardstick  # it is heavy
            ratios[workers] = statistics.median(loaded) / yardstick
    assert ratios[4] < 3.0, ratios
    assert ratios[1] > 2 * ratios[4], ratios


def test_an_update_beyond_its_time_budget_gets_an_error_and_the_connection_goes_on(
    terrain, monkeypatch
):
    # an init that takes ten times the budget (a stand-in for a filter too slow for it)
    real_init = Session._init

    def slow_init(self, request):
        if request.get("sigma_m") == 999.0:
            time.sleep(2.0)
        return real_init(self, request)

    monkeypatch.setattr(Session, "_init", slow_init)
    limits = ServerLimits(update_timeout_s=0.2)
    with (
        serve_in_thread(terrain, "pmf", limits=limits) as (host, port),
        Client(host, port) as client,
        Client(host, port) as other,
    ):
        assert client.config(method="pf:particles=1000,max_particles=1000")["ok"]
        reply = client.init(0.0, 1500.0, 2000.0, 999.0, check=False)
        assert reply["ok"] is False and "update_timeout_s = 0.2 s" in reply["error"]
        assert other.init(0.0, 1500.0, 2000.0, 100.0)["ok"]  # not held up meanwhile
        # a new navigator with the server's method: it needs an init, then works
        assert "no init yet" in client.estimate(check=False)["error"]
        assert client.init(0.0, 1500.0, 2000.0, 100.0)["status"] == "initialising"


def test_a_line_beyond_the_limit_is_refused_and_closes_only_its_connection(terrain):
    limits = ServerLimits(max_line_bytes=4096)
    with serve_in_thread(terrain, "pmf", limits=limits) as (host, port):
        with Client(host, port) as other, Client(host, port) as flood:
            reply = flood.send_line(b'{"type": "estimate", "pad": "' + b"x" * 5000 + b'"}')
            assert reply["ok"] is False and "longer than 4096 bytes" in reply["error"]
            with pytest.raises(ServerError):
                flood.estimate()
            assert other.init(0.0, 1500.0, 2000.0, 100.0)["ok"]
        # a line that never ends is cut off at the limit as well
        raw = socket.create_connection((host, port))
        raw.sendall(b"y" * 20_000)
        raw.settimeout(10)
        received = b""
        while chunk := raw.recv(4096):
            received += chunk
        raw.close()
        assert b"longer than 4096 bytes" in received and received.count(b"\n") == 1


def test_connections_beyond_the_limit_are_refused_and_counted_once_in_the_log(terrain):
    lines: list[str] = []
    log = RateLog(interval_s=60.0, write=lines.append)
    limits = ServerLimits(max_connections=2)
    with serve_in_thread(terrain, "pmf", limits=limits, log=log) as (host, port):
        with Client(host, port) as first, Client(host, port) as second:
            assert first.estimate(check=False)["error"].startswith("no init yet")
            assert second.estimate(check=False)["error"].startswith("no init yet")
            for _ in range(5):
                with Client(host, port) as extra:
                    assert "max_connections = 2" in extra.read_reply()["error"]
        with Client(host, port) as later:  # room again
            assert later.estimate(check=False)["error"].startswith("no init yet")
    refused = [line for line in lines if "connection refused" in line]
    assert len(refused) == 1 and "max_connections = 2" in refused[0]


def test_rate_log_writes_a_cause_once_per_interval_and_counts_the_repeats(monkeypatch):
    lines: list[str] = []
    clock = [100.0]
    monkeypatch.setattr(time, "monotonic", lambda: clock[0])
    log = RateLog(interval_s=10.0, write=lines.append)
    for _ in range(1000):
        log("accept failed", "EMFILE Too many open files")
    log("other cause")
    clock[0] += 11.0
    log("accept failed", "EMFILE Too many open files")
    assert lines == [
        "geofix serve: accept failed: EMFILE Too many open files",
        "geofix serve: other cause",
        "geofix serve: accept failed: EMFILE Too many open files "
        "(999 more since the last such line)",
    ]


def test_the_memory_ledger_holds_the_states_and_the_largest_updates():
    ledger = MemoryLedger(budget=1000.0, workers=2)
    ledger.reserve(1, 100.0, 300.0, "a")
    ledger.reserve(2, 100.0, 200.0, "b")
    ledger.reserve(3, 100.0, 100.0, "c")
    assert ledger.total() == 300.0 + 300.0 + 200.0  # states + the two largest updates
    with pytest.raises(MemoryBudgetError, match="d would need"):
        ledger.reserve(4, 160.0, 250.0, "d")  # 460 + 300 + 250 > 1000
    assert ledger.holders() == 3
    ledger.reserve(1, 100.0, 50.0, "a smaller")  # replaces its own reservation
    assert ledger.total() == 300.0 + 200.0 + 100.0
    ledger.release(2)
    ledger.release(2)
    assert ledger.total() == 200.0 + 100.0 + 50.0


def test_config_beyond_the_memory_budget_or_max_points_is_refused_and_the_navigator_kept(
    terrain,
):
    limits = ServerLimits(memory_bytes=400 * 2**20, max_points=1_000_000)
    start = "pmf:points=101,max_points=101"  # the default's 301 x 301 nodes need 503 MiB
    with serve_in_thread(terrain, start, limits=limits) as (host, port), Client(host, port) as c:
        assert c.config(method="pf:particles=1000,max_particles=1000")["ok"]
        c.init(0.0, 1500.0, 2000.0, 100.0)
        before = c.estimate()
        for spec, words in (
            ("pf:particles=900000,max_particles=900000", "memory budget"),
            ("mpf:particles=2000000,max_particles=2000000", "max_points = 1000000"),
            ("pmf:points=1201,max_points=1201", "max_points"),
        ):
            reply = c.config(method=spec, check=False)
            assert reply["ok"] is False and words in reply["error"], reply
        assert c.estimate() == before  # the pf navigator is still there


def test_connections_are_refused_once_the_budget_is_spent(terrain):
    # every connection holds its line buffer, its filter's state and (while it runs) its
    # update's temporaries: a budget of four and a half connections holds four
    from geofix.navigator import method_size

    spec, line = "pf:particles=100,max_particles=100", 8 * 2**20
    size = method_size(spec, None, terrain)
    one = size.state_bytes + line + size.update_bytes
    limits = ServerLimits(memory_bytes=int(4.5 * one), max_line_bytes=line)
    with serve_in_thread(terrain, spec, limits=limits) as (host, port):
        clients = [Client(host, port) for _ in range(6)]
        replies = [c.estimate(check=False)["error"] for c in clients]
        for c in clients:
            c.close()
    assert sum("no init yet" in r for r in replies) == 4
    assert sum("memory budget" in r and "server busy" in r for r in replies) == 2


@pytest.mark.parametrize(
    ("message", "words"),
    [
        ({"type": "init", "t": -1e308, "x": 1500.0, "y": 2000.0, "sigma_m": 100.0}, "t = "),
        ({"type": "init", "t": 0, "x": 1e300, "y": 2000.0, "sigma_m": 100.0}, "x = "),
        ({"type": "init", "t": 0, "x": 1500.0, "y": 2000.0, "sigma_m": 1e200}, "sigma_m"),
        ({"type": "nav", "t": 1e308, "x": 1500.0, "y": 2000.0, "heading_deg": 0}, "t = "),
        ({"type": "nav", "t": 5e7, "x": 1500.0, "y": 2000.0, "heading_deg": 0}, "init time"),
        ({"type": "nav", "t": 1, "x": 1500.0, "y": 2000.0, "heading_deg": 1e300}, "heading"),
        ({"type": "ping", "t": 1, "beams": [[0, 0, 1e308]] * 3}, "beam 0 value"),
        ({"type": "ping", "t": 1, "beams": [[0, 0, -100], [0, 0, 1e160]]}, "beam 1 value"),
        ({"type": "ping", "t": 1, "beams": [[0, 0, -1e200]] * 3}, "+-12000 m"),
        ({"type": "ping", "t": 1, "beams": [[1e9, 0, -100]] * 3}, "offset"),
        ({"type": "ping", "t": 1, "beams": [[0, 0, -100]] * 3, "roll_deg": 1e300}, "roll"),
    ],
)
def test_values_outside_physical_ranges_are_refused_and_the_navigator_keeps_working(
    terrain, message, words
):
    session = Session(terrain, "pmf")
    assert session.handle(b'{"type": "init", "t": 0, "x": 1500, "y": 2000, "sigma_m": 100}')["ok"]
    reply = session.handle(json.dumps(message).encode())
    assert reply["ok"] is False and words in reply["error"], reply
    assert "internal" not in reply["error"]
    position = np.array([1505.0, 2000.0])
    nav = {"type": "nav", "t": 1.0, "x": 1505.0, "y": 2000.0, "heading_deg": 90.0}
    assert session.handle(json.dumps(nav).encode())["ok"]
    ping = {"type": "ping", "t": 1.0, "beams": beams_at(terrain, position).tolist()}
    after = session.handle(json.dumps(ping).encode())
    assert after["ok"] and np.isfinite(after["x"]), after


def test_a_gravity_map_takes_anomalies_within_a_thousand_mgal():
    from geofix.maps import Grid

    gravity = Grid(np.zeros((50, 50)), 0.0, 0.0, 100.0, 100.0, kind="gravity")
    session = Session(gravity, "pmf")
    session.handle(b'{"type": "init", "t": 0, "x": 2500, "y": 2500, "sigma_m": 100}')
    reply = session.handle(b'{"type": "ping", "t": 0, "beams": [[0, 0, -1500.0]]}')
    assert reply["ok"] is False and "+-1000 mGal for a gravity map" in reply["error"]
    assert session.handle(b'{"type": "ping", "t": 0, "beams": [[0, 0, 12.0]]}')["ok"]


@pytest.mark.parametrize(
    ("line", "words"),
    [
        (b'{"type": ' + b"9" * 400 + b"}", "request type must be a string (a int)"),
        (b'{"type": ' + b"[" * 1000 + b"]" * 1000 + b"}", "request type must be a string"),
        (b'{"type": "nav", "t": ' + b"9" * 400 + b', "x": 1, "y": 1, "heading_deg": 0}', "t"),
        (b'{"type": "config", "ins": ' + b"[" * 5000 + b"]" * 5000 + b"}", "JSON"),
    ],
)
def test_huge_integers_and_deep_lists_get_plain_errors(terrain, line, words):
    reply = Session(terrain, "pmf").handle(line)
    assert reply["ok"] is False and words in reply["error"], reply
    assert "internal" not in reply["error"]


def test_a_non_finite_estimate_is_an_error_and_the_navigator_starts_again(terrain):
    session = Session(terrain, "pmf")
    session.handle(b'{"type": "init", "t": 0, "x": 1500, "y": 2000, "sigma_m": 100}')
    broken = session.navigator

    class Poisoned:
        def to_dict(self):
            return {"x": float("nan"), "y": 1.0}

    broken.estimate = lambda: Poisoned()  # a state gone non-finite, whatever the cause
    reply = session.handle(b'{"type": "estimate"}')
    assert reply["ok"] is False and "not finite" in reply["error"]
    assert session.navigator is not broken
    assert "no init yet" in session.handle(b'{"type": "estimate"}')["error"]
    assert session.handle(b'{"type": "init", "t": 0, "x": 1500, "y": 2000, "sigma_m": 100}')["ok"]


def test_bad_addresses_are_refused_before_listening(terrain):
    from geofix.server import serve

    with pytest.raises(ConfigError, match=r"every interface; give 0\.0\.0\.0"):
        serve(terrain, "pmf", host="", port=0)
    with pytest.raises(ConfigError, match="not a TCP port"):
        serve(terrain, "pmf", port=70000)
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        announced = []
        with pytest.raises(ConfigError, match=f"cannot listen on 127.0.0.1:{port}"):
            serve(terrain, "pmf", port=port, announce=lambda h, p: announced.append(p))
        assert announced == []


def geofix_serve(*args, preexec_fn=None) -> tuple[subprocess.Popen, int]:
    """``geofix serve`` on the bundled 1 km map at a free port; the process and its port."""
    exe = Path(sys.executable).with_name("geofix")
    proc = subprocess.Popen(
        [str(exe), "serve", "--map", "builtin:mb_1km", "--port", "0", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=preexec_fn,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    assert proc.stderr is not None
    line = proc.stderr.readline()
    while line and "serving" not in line:
        line = proc.stderr.readline()
    found = re.search(r"on 127\.0\.0\.1:(\d+) \(Ctrl-C stops\)", line)
    if not found:
        end(proc)
    assert found, line
    return proc, int(found.group(1))


def end(proc: subprocess.Popen) -> None:
    """Kill a server a failed test left running."""
    if proc.poll() is None:
        proc.kill()
        proc.communicate(timeout=30)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_ctrl_c_and_sigterm_stop_the_server_cleanly_with_clients_connected(sig):
    proc, port = geofix_serve()
    try:
        assert port > 0  # the port actually bound, not 0
        clients = [Client("127.0.0.1", port) for _ in range(3)]
        assert "no init yet" in clients[0].estimate(check=False)["error"]
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=60)
        for c in clients:
            c.close()
    finally:
        end(proc)
    assert proc.returncode == 0
    assert "Traceback" not in err and "Error" not in err and out == ""


def test_at_the_descriptor_limit_connections_are_refused_in_a_few_log_lines():
    import resource

    def low_limit():
        resource.setrlimit(resource.RLIMIT_NOFILE, (48, 48))

    proc, port = geofix_serve(preexec_fn=low_limit)
    try:
        sockets = [socket.create_connection(("127.0.0.1", port), timeout=10) for _ in range(100)]
        answered = 0
        for s in sockets[:60]:
            s.sendall(b'{"type": "estimate"}\n')
            answered += s.recv(1000).startswith(b'{"ok":false')
        for s in sockets:
            s.close()
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        end(proc)
    assert proc.returncode == 0 and answered == 60
    assert "Traceback" not in err and len(err.splitlines()) <= 6, err
    assert "max_connections" in err


def test_serve_takes_its_limits_on_the_command_line(monkeypatch):
    """``geofix serve --max-connections ... --workers ...`` reach the server; bad ones refused."""
    from typer.testing import CliRunner

    import geofix.server
    from geofix.cli import app

    seen = {}

    def fake_serve(*args, announce=None, **kwargs):
        seen["limits"] = args[8] if len(args) > 8 else kwargs.get("limits")

    monkeypatch.setattr(geofix.server, "serve", fake_serve)
    base = ["serve", "--map", "builtin:azores", "--port", "0", "--resample-m", "5000"]
    flags = ["--max-connections", "7", "--max-line-bytes", "4096", "--workers", "2"]
    result = CliRunner().invoke(app, [*base, *flags, "--update-timeout-s", "5"])
    assert result.exit_code == 0, result.output
    limits = seen["limits"]
    assert (limits.max_connections, limits.max_line_bytes, limits.workers) == (7, 4096, 2)
    assert limits.update_timeout_s == 5.0 and limits.max_points == ServerLimits().max_points
    bad = CliRunner().invoke(app, [*base, "--workers", "0"])
    assert bad.exit_code == 2 and "workers must be a positive integer" in bad.output
    assert "Traceback" not in bad.output
