"""Generated bad input (hypothesis) for ``grid``, ``replay``, ``serve`` and the GSF reader.

As :mod:`test_fuzz_inputs` does for ``run``: every generated input either works or ends
in a plain error (exit code 2, at most 3 lines, no traceback, no "internal error"), in
under 30 s, and with the memory budget set low (:data:`FUZZ_BUDGET`) nothing allocates
beyond it (the tracemalloc peak of each command stays below the budget). The faces:

- soundings tables (CSV and Parquet) given to ``geofix grid``: NaN, infinities, text,
  huge and tiny numbers, empty tables, one row, duplicate and collinear points, garbage
  files, odd cell sizes; a map written is whole (it loads, no infinite cell), a refused
  one is absent;
- ``nav`` / ``soundings`` tables given to ``geofix replay`` (through
  :func:`geofix.replay.replay_log`, the function the command calls, and a few through
  the command line with its outputs): the same hostile cells, missing columns, times out
  of order or off the navigation; an accepted replay has one finite estimate per ping;
- corrupted GSF files given to ``geofix grid``: bit flips anywhere or in record headers,
  truncations, overwritten words and dropped or repeated records of a small GSF file cut
  from the bundled EX1811 log;
- message streams sent to a ``geofix.server`` on 127.0.0.1: random JSON requests with
  hostile values and non-JSON lines; every line gets exactly one reply, an error reply is
  one plain line, the connection still takes an ``init`` afterwards and its memory
  reservation is given back when it closes.

The examples are derandomised (fixed seeds) and counted in ``docs/RESULTS.md`` by
``benchmarks/sections/reliability.py`` (suites ``fuzz-grid``, ``fuzz-replay``,
``fuzz-gsf`` and ``fuzz-serve``).
"""

from __future__ import annotations

import asyncio
import json
import math
import socket
import struct
import tempfile
import threading
import time
import warnings
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from _reliability import MAX_LINES, MAX_SECONDS, Outcome, record, run_cli
from geofix.errors import GeofixError, GeofixWarning, MemoryBudgetError
from geofix.logs.read import bundled_log_path
from geofix.maps import fractal_terrain, load_grid
from geofix.maps.io import save_grid
from geofix.memory import parse_size

pytestmark = pytest.mark.slow

GRID_EXAMPLES = 260
REPLAY_EXAMPLES = 240
REPLAY_CLI_EXAMPLES = 8
GSF_EXAMPLES = 200
SERVE_EXAMPLES = 360
FUZZ_BUDGET = "16MB"
REPLAY_BUDGET = "512MB"
SERVER_BUDGET = "1GB"

_FUZZ_SETTINGS: dict[str, Any] = {
    "deadline": None,
    "derandomize": True,
    "database": None,
    "suppress_health_check": [
        HealthCheck.too_slow,
        HealthCheck.function_scoped_fixture,
        HealthCheck.data_too_large,
    ],
}

HOSTILE = [
    math.nan,
    math.inf,
    -math.inf,
    1e300,
    -1e300,
    1e-300,
    -0.0,
    0,
    2**63,
    -(2**63),
    1e20,
    "abc",
    "",
    " ",
    "1e999",
    "NaN",
    "<b>x</b>",
    "2018-11-02",
]
hostile = st.one_of(
    st.sampled_from(HOSTILE),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(10**20), 10**20),
    st.text(max_size=6),
)


def _clean_outcome(outcome: Outcome) -> None:
    """Exit 0 or 2, no traceback, no internal error, short, fast, under the budget."""
    assert not outcome.traceback, (outcome.case, outcome.output)
    assert outcome.exit_code in (0, 2), (outcome.case, outcome.exit_code, outcome.output)
    assert "internal error" not in outcome.output, (outcome.case, outcome.output)
    assert "Traceback" not in outcome.output, outcome.output
    assert len(outcome.lines) <= MAX_LINES, (outcome.case, outcome.output)
    assert all(len(line) < 600 for line in outcome.lines), outcome.output
    if outcome.exit_code == 2:
        assert outcome.lines and outcome.lines[-1].startswith("error:"), outcome.output
    assert outcome.seconds < MAX_SECONDS, (outcome.case, outcome.seconds)
    if outcome.budget_bytes:
        assert outcome.peak_bytes < outcome.budget_bytes, (outcome.peak_bytes, outcome.case)


def _write_table(path: Path, columns: dict, fmt: str, garbage: bytes | None) -> Path:
    """``columns`` as a CSV or Parquet table (text columns as text), or ``garbage`` bytes."""
    path = path.with_suffix(f".{fmt}")
    if garbage is not None:
        path.write_bytes(garbage)
        return path
    table = pd.DataFrame(columns)
    if fmt == "csv":
        table.to_csv(path, index=False)
    else:
        mixed = {c: str for c in table if table[c].dtype == object}
        table.astype(mixed).to_parquet(path, index=False)
    return path


def _mutate(columns: dict, cells) -> None:
    """Put each ``(column, row, value)`` of ``cells`` into ``columns`` (lists, in place)."""
    for column, row, value in cells:
        values = columns.get(column)
        if values:
            values[row % len(values)] = value


def _map_is_whole(path: Path) -> None:
    grid = load_grid(path)
    values = np.asarray(grid.values, dtype=float)
    assert not np.isinf(values).any()
    assert np.isfinite(values).any()


# ---------------------------------------------------------------------- grid tables
SOUNDING_NAMES = [
    ("x", "y", "value"),
    ("x", "y", "depth_m"),
    ("lon", "lat", "value"),
    ("lon", "lat", "depth_m"),
    ("x", "value"),
    ("east", "north", "value"),
]
GARBAGE = [b"", b"x,y,value\n", b"PAR1", b"PAR1\x00\x00\xffPAR1", b"\x00\xff,\n\x01"]


@st.composite
def soundings_tables(draw):
    names = draw(st.sampled_from(SOUNDING_NAMES))
    n = draw(st.sampled_from([0, 1, 2, 3, 5, 12, 40]))
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    if "lon" in names:
        first, second = -64.6 + 0.02 * rng.random(n), 17.8 + 0.02 * rng.random(n)
    else:
        first, second = 2000.0 * rng.random(n), 2000.0 * rng.random(n)
    shape = draw(st.sampled_from(["scattered"] * 4 + ["one point", "collinear"]))
    if shape == "one point":
        first, second = np.full(n, first[0] if n else 0.0), np.full(n, second[0] if n else 0.0)
    elif shape == "collinear":
        second = first * (0.5 if "lon" not in names else 1.0)
    depth = 100.0 + 5.0 * rng.standard_normal(n)
    value = depth if names[-1] == "depth_m" else -depth
    columns = {
        names[0]: first.tolist(),
        **({names[1]: second.tolist()} if len(names) == 3 else {}),
        names[-1]: value.tolist(),
    }
    if draw(st.booleans()) and draw(st.booleans()):  # duplicate points, 1 in 4
        columns = {k: v * 2 for k, v in columns.items()}
    cells = draw(
        st.lists(st.tuples(st.sampled_from(names), st.integers(0, 99), hostile), max_size=4)
    )
    _mutate(columns, cells)
    return {
        "columns": columns,
        "fmt": draw(st.sampled_from(["csv", "parquet"])),
        "cell_m": draw(st.sampled_from(["100", "100", "250", "25", "1e-3", "1e7", "-5"])),
        "garbage": draw(st.sampled_from([None] * 10 + GARBAGE)),
        "traced": draw(st.integers(0, 3)) == 0,
        "case": f"{names} n={n} {shape} cells={cells!r}"[:300],
    }


@pytest.fixture
def fuzz_dirs(tmp_path_factory):
    """A fresh folder for each example (hypothesis runs them all in one test call)."""
    root = tmp_path_factory.mktemp("fuzzfaces")
    return lambda: Path(tempfile.mkdtemp(dir=root))


@pytest.fixture(scope="module", autouse=True)
def warm(tmp_path_factory):
    """Grid a valid table and a GSF file once: the libraries' imports (tens of MB the
    first time) are not a command's allocations, measured against the budget."""
    from typer.testing import CliRunner

    from geofix.cli import app

    folder = tmp_path_factory.mktemp("warm")
    rng = np.random.default_rng(0)
    table = pd.DataFrame({"x": 900 * rng.random(30), "y": 900 * rng.random(30), "value": -1.0})
    table.to_csv(folder / "soundings.csv", index=False)
    table.to_parquet(folder / "soundings.parquet")
    (folder / "small.gsf").write_bytes(small_gsf()[0])
    for name in ("soundings.csv", "soundings.parquet", "small.gsf"):
        args = ["grid", str(folder / name), "--cell-m", "250", "--out", str(folder / "w.nc")]
        result = CliRunner().invoke(app, args)
        assert result.exit_code == 0, result.output


@settings(max_examples=GRID_EXAMPLES, **_FUZZ_SETTINGS)
@given(soundings_tables())
def test_fuzzed_soundings_tables_given_to_grid(fuzz_dirs, table):
    fuzz_dir = fuzz_dirs()
    path = _write_table(fuzz_dir / "soundings", table["columns"], table["fmt"], table["garbage"])
    out = fuzz_dir / "map.nc"
    args = ["grid", str(path), "--cell-m", table["cell_m"], "--out", str(out)]
    outcome = run_cli(
        f"{table['fmt']} garbage={table['garbage']!r} cell={table['cell_m']} {table['case']}",
        args,
        env={"GEOFIX_MEMORY_BUDGET": FUZZ_BUDGET},
        trace=table["traced"],
        suite="fuzz-grid",
    )
    _clean_outcome(outcome)
    if outcome.exit_code == 0:
        _map_is_whole(out)
    else:
        assert not out.exists(), outcome.output


def test_collinear_soundings_are_one_short_line(tmp_path):
    # the gridder's interpolation failed with Qhull's 60-line explanation in the message
    x = np.arange(10) * 100.0
    path = tmp_path / "line.csv"
    pd.DataFrame({"x": x, "y": 0.5 * x, "value": -100.0 - x / 100}).to_csv(path, index=False)
    out = tmp_path / "m.nc"
    outcome = run_cli("collinear", ["grid", str(path), "--cell-m", "10", "--out", str(out)])
    assert outcome.exit_code == 2 and not outcome.traceback, outcome.output
    assert len(outcome.lines) == 1 and len(outcome.output) < 300, outcome.output
    assert "line.csv" in outcome.output and "lie on one line" in outcome.output
    assert "Qhull" not in outcome.output and not out.exists()


# ---------------------------------------------------------------------- replay tables
MAP_CELL_M = 20.0
BEAM_ACROSS = np.array([-200.0, -100.0, 0.0, 100.0, 200.0])
NAV_GROUPS = [("roll_deg",), ("pitch_deg",), ("vx", "vy"), ("sigma_m",), ("truth_x", "truth_y")]
NAV_COLUMNS = ["t", "x", "y", "heading_deg", *(c for group in NAV_GROUPS for c in group)]
SOUNDING_COLUMNS = ["t", "across_m", "along_m", "value"]


@cache
def _terrain():
    return fractal_terrain((100, 100), MAP_CELL_M, rng=np.random.default_rng(0), name="fuzz")


@pytest.fixture(scope="module")
def replay_map(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("fuzzmap") / "map.nc"
    save_grid(_terrain(), path)
    return path


@st.composite
def replay_tables(draw):
    """A valid small log on :func:`_terrain` (eastward, 5 beams a ping), then damaged."""
    grid = _terrain()
    pings = draw(st.sampled_from([1, 2, 3, 6]))
    t = 1000.0 + 2.0 * np.arange(pings)
    x, y = 600.0 + 10.0 * np.arange(pings), np.full(pings, 1000.0)
    nav = {"t": t.tolist(), "x": x.tolist(), "y": y.tolist(), "heading_deg": [90.0] * pings}
    for group in draw(st.lists(st.sampled_from(NAV_GROUPS), max_size=3, unique=True)):
        for column in group:
            base = {"sigma_m": 5.0, "truth_x": 600.0, "truth_y": 1000.0}.get(column, 0.0)
            nav[column] = [base] * pings
    rows_t = np.repeat(t, BEAM_ACROSS.size)
    across = np.tile(BEAM_ACROSS, pings)
    value = grid.sample(np.repeat(x, BEAM_ACROSS.size), np.repeat(y, BEAM_ACROSS.size) - across)
    sound = {
        "t": rows_t.tolist(),
        "across_m": across.tolist(),
        "along_m": [0.0] * rows_t.size,
        "value": value.tolist(),
    }
    change = draw(
        st.sampled_from(
            ["none"] * 6
            + ["drop nav column", "drop soundings column", "lon/lat", "depth_m", "reverse nav"]
            + ["empty soundings", "empty nav", "duplicate nav", "late pings", "garbage"]
        )
    )
    garbage = None
    if change == "drop nav column":
        nav.pop(draw(st.sampled_from(["t", "x", "heading_deg"])))
    elif change == "drop soundings column":
        sound.pop(draw(st.sampled_from(SOUNDING_COLUMNS)))
    elif change == "lon/lat":
        nav["lon"], nav["lat"] = nav.pop("x"), nav.pop("y")
    elif change == "depth_m":
        sound["depth_m"] = [-v for v in sound.pop("value")]
    elif change == "reverse nav":
        nav = {k: v[::-1] for k, v in nav.items()}
    elif change == "empty soundings":
        sound = {k: [] for k in sound}
    elif change == "empty nav":
        nav = {k: [] for k in nav}
    elif change == "duplicate nav":
        nav = {k: v * 2 for k, v in nav.items()}
    elif change == "late pings":
        sound["t"] = [v + draw(st.sampled_from([30.0, 1e7, -1e12])) for v in sound["t"]]
    elif change == "garbage":
        garbage = draw(st.sampled_from(GARBAGE))
    nav_cells = draw(
        st.lists(st.tuples(st.sampled_from(NAV_COLUMNS), st.integers(0, 99), hostile), max_size=3)
    )
    sound_cells = draw(
        st.lists(
            st.tuples(st.sampled_from(SOUNDING_COLUMNS), st.integers(0, 99), hostile), max_size=3
        )
    )
    _mutate(nav, nav_cells)
    _mutate(sound, sound_cells)
    return {
        "nav": nav,
        "soundings": sound,
        "fmt": draw(st.sampled_from(["csv", "parquet"])),
        "garbage": garbage,
        "garbage_in": draw(st.sampled_from(["nav", "soundings"])),
        "initial_error_m": draw(st.sampled_from([None, None, 50.0, 1e-300, 1e300])),
        "case": f"{pings} pings {change} nav={nav_cells!r} soundings={sound_cells!r}"[:300],
    }


def _write_log(folder: Path, log: dict) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name in ("nav", "soundings"):
        garbage = log["garbage"] if log["garbage_in"] == name else None
        _write_table(folder / name, log[name], log["fmt"], garbage)
    return folder


def _judge(case: str, suite: str, fn) -> tuple[Outcome, object]:
    """Run ``fn`` as the command line would: its warnings and error, one line each.

    A GeofixError (or an operating-system or memory error, which the command line also
    reports in one line) is a clean error; any other exception is a traceback.
    """
    import tracemalloc

    from geofix.memory import memory_budget_bytes

    start = time.perf_counter()
    result, code, message, crash = None, 0, "", False
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        tracemalloc.start()
        try:
            result = fn()
        except MemoryBudgetError as exc:
            message, code = f"error: {exc} [memory budget]", 2
        except (GeofixError, OSError, MemoryError) as exc:
            message, code = f"error: {exc}", 2
        except Exception as exc:  # the bug this suite hunts
            crash, message, code = True, f"Traceback: {type(exc).__name__}: {exc}", 1
        finally:
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
    shown = [f"warning: {w.message}" for w in caught if issubclass(w.category, GeofixWarning)]
    output = "\n".join(" ".join(line.split()) for line in [*shown, message] if line)
    seconds = time.perf_counter() - start
    outcome = Outcome(case[:300], code, output, seconds, crash, peak, memory_budget_bytes(), suite)
    record(outcome)
    return outcome, result


@pytest.fixture
def replay_budget(monkeypatch):
    """A budget that holds a default ``pmf`` (sized for 64 beams), and little more."""
    monkeypatch.setenv("GEOFIX_MEMORY_BUDGET", REPLAY_BUDGET)


@settings(max_examples=REPLAY_EXAMPLES, **_FUZZ_SETTINGS)
@given(replay_tables())
def test_fuzzed_nav_and_soundings_tables_given_to_replay(replay_budget, fuzz_dirs, replay_map, log):
    from geofix.replay import replay_log

    fuzz_dir = fuzz_dirs()

    folder = _write_log(fuzz_dir / "log", log)

    def go():
        return replay_log(str(folder), str(replay_map), ["pmf"], None, log["initial_error_m"])

    outcome, result = _judge(log["case"], "fuzz-replay", go)
    _clean_outcome(outcome)
    if outcome.exit_code == 0:
        replayed, paths = result
        estimates = replayed.estimates["pmf"]
        assert paths == {} and len(estimates) == replayed.summary["pings"] >= 1
        track = np.array([e.position for e in estimates])
        assert np.isfinite(track).all() and np.isfinite([e.covariance for e in estimates]).all()


@settings(max_examples=REPLAY_CLI_EXAMPLES, **_FUZZ_SETTINGS)
@given(replay_tables())
def test_fuzzed_replay_tables_through_the_command_line(fuzz_dirs, replay_map, log):
    fuzz_dir = fuzz_dirs()
    folder = _write_log(fuzz_dir / "log", log)
    out = fuzz_dir / "replay"
    args = ["replay", str(folder), "--map", str(replay_map), "-m", "pmf", "--json"]
    if log["initial_error_m"] is not None:
        args += ["--ins-initial-error-m", repr(log["initial_error_m"])]
    outcome = run_cli(
        f"cli {log['case']}",
        [*args, "--out", str(out)],
        env={"GEOFIX_MEMORY_BUDGET": REPLAY_BUDGET},
        suite="fuzz-replay",
    )
    _clean_outcome(outcome)
    if outcome.exit_code == 0:  # outputs whole: one row per method and ping
        summary = json.loads(outcome.output.strip().splitlines()[-1])
        assert len(pd.read_csv(out / "estimates.csv")) == summary["pings"]
        assert (out / "replay.png").stat().st_size > 0
    else:
        assert not (out / "estimates.csv").exists()


def test_an_initial_error_beyond_the_earth_is_one_error(tmp_path, replay_map):
    # 1e300 m overflowed in the INS simulation (OverflowError, an internal error)
    folder = tmp_path / "log"
    log = {
        "nav": {"t": [0.0, 1.0], "x": [600.0, 610.0], "y": [1e3, 1e3], "heading_deg": [90.0] * 2}
    }
    log["soundings"] = {"t": [0.0, 1.0], "across_m": [0.0] * 2, "along_m": [0.0] * 2}
    log["soundings"]["value"] = [-100.0, -100.0]
    _write_log(folder, {**log, "fmt": "csv", "garbage": None, "garbage_in": "nav"})
    args = ["replay", str(folder), "--map", str(replay_map), "-m", "pmf", "--out", str(tmp_path)]
    outcome = run_cli("initial error 1e300", [*args, "--ins-initial-error-m", "1e300"])
    assert outcome.exit_code == 2 and not outcome.traceback, outcome.output
    assert outcome.lines == [
        "error: --ins-initial-error-m must lie within 0 .. 4e+07 m, got 1e+300"
    ], outcome.output


# ---------------------------------------------------------------------- GSF files
GSF_PINGS = 4
GSF_ATTITUDE_RECORDS = 12


def _gsf_records(data: bytes) -> list[tuple[int, int, int]]:
    """``(offset, length, record type)`` of each record of a GSF file (big-endian headers)."""
    records, offset = [], 0
    while offset + 8 <= len(data):
        size, ident = struct.unpack(">II", data[offset : offset + 8])
        length = (12 if ident & 0x80000000 else 8) + size
        records.append((offset, length, ident & 0x003FFFFF))
        offset += length
    return records


@cache
def small_gsf() -> tuple[bytes, tuple[tuple[int, int, int], ...]]:
    """The bundled EX1811 file cut to its header records, a few attitude records and
    :data:`GSF_PINGS` pings (a valid GSF file of about 130 kB); its records' layout."""
    data = bundled_log_path("ex1811").read_bytes()
    records = _gsf_records(data)
    attitude = [r for r in records if r[2] == 12][:GSF_ATTITUDE_RECORDS]
    pings = [r for r in records if r[2] == 2][:GSF_PINGS]
    keep = sorted([r for r in records if r[2] not in (2, 12)] + attitude + pings)
    small = b"".join(data[o : o + n] for o, n, _ in keep)
    return small, tuple(_gsf_records(small))


GSF_DAMAGE = ["flip", "flip", "flip header", "truncate", "truncate at record", "overwrite"]
GSF_DAMAGE += ["overwrite size", "drop record", "repeat record"]
WORDS = [b"\x00\x00\x00\x00", b"\xff\xff\xff\xff", b"\x7f\xff\xff\xff", b"\x80\x00\x00\x00"]


@st.composite
def gsf_corruptions(draw):
    data, records = small_gsf()
    out = bytearray(data)
    kind = draw(st.sampled_from(GSF_DAMAGE))
    record_index = draw(st.integers(0, len(records) - 1))
    start, length, _ = records[record_index]
    if kind == "flip":
        for bit in draw(st.lists(st.integers(0, 8 * len(out) - 1), min_size=1, max_size=16)):
            out[bit // 8] ^= 1 << (bit % 8)
    elif kind == "flip header":
        bit = draw(st.integers(0, 8 * 12 - 1))
        out[start + bit // 8] ^= 1 << (bit % 8)
    elif kind == "truncate":
        del out[draw(st.integers(0, len(out) - 1)) :]
    elif kind == "truncate at record":
        del out[max(start + draw(st.integers(-3, 3)), 0) :]
    elif kind == "overwrite":
        at = draw(st.integers(0, len(out) - 4))
        out[at : at + 4] = draw(
            st.one_of(st.sampled_from(WORDS), st.binary(min_size=4, max_size=4))
        )
    elif kind == "overwrite size":
        out[start : start + 4] = draw(st.sampled_from(WORDS))
    elif kind == "drop record":
        del out[start : start + length]
    else:
        out[start:start] = data[start : start + length]
    traced = draw(st.integers(0, 3)) == 0
    case = f"{kind} record {record_index} of {len(records)}"
    return {"data": bytes(out), "case": case, "traced": traced}


def test_the_small_gsf_file_grids_cleanly(tmp_path):
    # the base of the corruptions is itself valid: its damage is what the fuzz tests
    path = tmp_path / "small.gsf"
    path.write_bytes(small_gsf()[0])
    out = tmp_path / "map.nc"
    outcome = run_cli("small gsf", ["grid", str(path), "--cell-m", "250", "--out", str(out)])
    assert outcome.exit_code == 0 and not outcome.lines[0].startswith("warning"), outcome.output
    _map_is_whole(out)


@settings(max_examples=GSF_EXAMPLES, **_FUZZ_SETTINGS)
@given(gsf_corruptions())
def test_corrupted_gsf_files_given_to_grid(fuzz_dirs, corruption):
    fuzz_dir = fuzz_dirs()
    path = fuzz_dir / "corrupt.gsf"
    path.write_bytes(corruption["data"])
    out = fuzz_dir / "map.nc"
    outcome = run_cli(
        corruption["case"],
        ["grid", str(path), "--cell-m", "500", "--out", str(out)],
        env={"GEOFIX_MEMORY_BUDGET": FUZZ_BUDGET},
        trace=corruption["traced"],
        suite="fuzz-gsf",
    )
    _clean_outcome(outcome)
    if outcome.exit_code == 0:
        _map_is_whole(out)
    else:
        assert not out.exists(), outcome.output


def test_a_gsf_beam_with_an_impossible_offset_is_dropped_with_one_warning(tmp_path):
    # four bytes of the first ping overwritten put one beam 1174 km behind the ship: the
    # map then spanned 1174 km, and gridding it at 100 m ran for minutes
    from geofix.logs.gsf import MAX_GSF_OFFSET_M, read_gsf

    data, records = small_gsf()
    first_ping = next(offset for offset, _, kind in records if kind == 2)
    damaged = bytearray(data)
    at = first_ping + 5077
    damaged[at : at + 4] = bytes.fromhex("e41618f8")
    path = tmp_path / "damaged.gsf"
    path.write_bytes(bytes(damaged))
    with pytest.warns(GeofixWarning, match="1 beams in 1 of 4 pings dropped as corrupt"):
        mission = read_gsf(path)
    offsets = mission.beams[..., :2]
    assert (np.abs(offsets[np.isfinite(offsets)]) < MAX_GSF_OFFSET_M).all()
    plain = tmp_path / "plain.gsf"
    plain.write_bytes(data)
    missing = np.isnan(read_gsf(plain).beams).any(axis=2).sum()
    assert np.isnan(mission.beams).any(axis=2).sum() == missing + 1
    outcome = run_cli(
        "damaged gsf", ["grid", str(path), "--cell-m", "100", "--out", str(tmp_path / "m.nc")]
    )
    assert outcome.exit_code == 0 and outcome.seconds < 20, outcome.output
    assert sum(line.startswith("warning:") for line in outcome.lines) == 1, outcome.output
    grid = load_grid(tmp_path / "m.nc")
    assert max(grid.values.shape) * grid.cell_size < 50_000  # km, not 1174 km


# ---------------------------------------------------------------------- server streams
REQUEST_TYPES = ["init", "nav", "ping", "estimate", "config"]
REQUEST_KEYS = ["t", "x", "y", "sigma_m", "heading_deg", "lon", "lat", "beams", "roll_deg"]
METHODS = ["pmf", "pf:particles=500", "pf:particles=10000000", "pmf:bogus=1", "nosuch", ""]
METHODS += ["mpf", "pf:particles=-3", "tercom", "pmf:nodes=1e300", "pf:particles=3000000"]
numbers = st.one_of(
    st.sampled_from([0, 1, -1, 1e-300, 1e300, -1e300, 1e10, 1e16, 10**400, -(10**30), 2**63]),
    st.floats(allow_nan=False, allow_infinity=False),
    st.integers(-(10**6), 10**6),
)
json_values = st.one_of(
    numbers,
    st.text(max_size=6),
    st.none(),
    st.booleans(),
    st.lists(numbers, max_size=3),
    st.dictionaries(st.sampled_from(["a", "type", "t"]), numbers, max_size=2),
)
plausible = {
    "t": st.floats(0.0, 200.0),
    "x": st.floats(0.0, 2000.0),
    "y": st.floats(0.0, 2000.0),
    "sigma_m": st.floats(1.0, 500.0),
    "heading_deg": st.floats(-360.0, 360.0),
}
plausible_beams = st.lists(
    st.tuples(st.floats(-300.0, 300.0), st.floats(-50.0, 50.0), st.floats(-130.0, -70.0)).map(list),
    min_size=1,
    max_size=9,
)
hostile_beams = st.lists(
    st.lists(st.one_of(numbers, st.none(), st.text(max_size=3)), min_size=0, max_size=5),
    max_size=6,
)
RAW_LINES = [
    b"",
    b"   ",
    b"{",
    b"NaN",
    b"[[[[[[[[[[",
    b'{"type": "nav", "t": NaN, "x": 1, "y": 2, "heading_deg": 0}',
    b'{"type": "ping", "t": 1, "beams": [[1, 2, 1e999]]}',
    b'{"type": "init", "t": -Infinity, "x": 1, "y": 2, "sigma_m": 5}',
    b'{"type": "init", "type": "nav"}',
    b"\xff\xfe\x00garbage",
    b'{"type": "' + b"[" * 1000 + b'"}',
    b"[" * 3000 + b"]" * 3000,
]


REQUIRED = {
    "init": ["t", "x", "y", "sigma_m"],
    "nav": ["t", "x", "y", "heading_deg"],
    "ping": ["t", "beams"],
    "estimate": [],
    "config": [],
}


@st.composite
def requests(draw):
    """A request: half of them well formed (then 0 to 2 values made hostile), half anything."""
    if draw(st.booleans()):
        kind = draw(st.sampled_from(REQUEST_TYPES))
        request: dict = {"type": kind}
        for key in REQUIRED[kind]:
            request[key] = draw(plausible_beams if key == "beams" else plausible[key])
        for key in draw(st.lists(st.sampled_from(REQUEST_KEYS), max_size=2, unique=True)):
            request[key] = draw(st.one_of(json_values, hostile_beams))
    else:
        kind = draw(st.sampled_from([*REQUEST_TYPES, "warp", "", None, 1, ["ping"]]))
        request = {} if draw(st.integers(0, 9)) == 0 else {"type": kind}
        for key in draw(st.lists(st.sampled_from(REQUEST_KEYS), max_size=6, unique=True)):
            if key == "beams":
                request[key] = draw(st.one_of(plausible_beams, hostile_beams, json_values))
            elif key in plausible and draw(st.booleans()):
                request[key] = draw(plausible[key])
            else:
                request[key] = draw(json_values)
    if kind == "config":
        if draw(st.booleans()):
            request["method"] = draw(st.one_of(st.sampled_from(METHODS), json_values))
        if draw(st.integers(0, 3)) == 0:
            request[draw(st.sampled_from(["ins", "dvl", "bogus"]))] = draw(
                st.one_of(json_values, st.just({"initial_error_m": [5, 5]}))
            )
    return json.dumps(request).encode()


lines = st.one_of(
    requests(),
    requests(),
    requests(),
    requests(),
    st.sampled_from(RAW_LINES),
    st.binary(max_size=60).map(lambda b: b.replace(b"\n", b" ")),
)
VALID_INIT = b'{"type": "init", "t": 0.0, "x": 1000.0, "y": 1000.0, "sigma_m": 50.0}'


@pytest.fixture(scope="module")
def fuzz_server():
    """A server on 127.0.0.1 (a free port) in a thread; yields ``(port, server, log)``."""
    from geofix.server import NavigatorServer
    from geofix.server_limits import ServerLimits

    limits = ServerLimits(
        max_line_bytes=1 << 16, update_timeout_s=20.0, memory_bytes=parse_size(SERVER_BUDGET)
    )
    logged: list[str] = []
    server = NavigatorServer(
        _terrain(), "pmf", limits=limits, log=lambda cause, detail="": logged.append(cause)
    )
    loop = asyncio.new_event_loop()
    port = loop.run_until_complete(server.start("127.0.0.1", 0))
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    try:
        yield port, server, logged
    finally:
        asyncio.run_coroutine_threadsafe(server.stop(), loop).result(timeout=10)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(timeout=10)
        loop.close()


def _exchange(port: int, stream: list[bytes]) -> list[dict]:
    """Send ``stream`` and a valid ``init`` on one connection; every reply, decoded."""
    with socket.create_connection(("127.0.0.1", port), timeout=MAX_SECONDS) as sock:
        reader = sock.makefile("rb")
        sock.sendall(b"".join(line + b"\n" for line in [*stream, VALID_INIT]))
        replies: list[dict] = []
        for _ in range(len(stream) + 1):
            raw = reader.readline()
            assert raw.endswith(b"\n"), (raw, len(replies))
            replies.append(json.loads(raw))
        reader.close()
    return replies


def _released(server, seconds: float = 5.0) -> bool:
    """Whether every connection's memory reservation is given back within ``seconds``."""
    deadline = time.monotonic() + seconds
    while server.ledger.holders() and time.monotonic() < deadline:
        time.sleep(0.005)
    return server.ledger.holders() == 0


@settings(max_examples=SERVE_EXAMPLES, **_FUZZ_SETTINGS)
@given(st.booleans(), st.lists(lines, min_size=1, max_size=8))
def test_fuzzed_message_streams_sent_to_the_server(fuzz_server, started, stream):
    port, server, logged = fuzz_server
    if started:  # half the streams reach a started navigator
        stream = [VALID_INIT, *stream]
    start = time.perf_counter()
    crash, error = False, ""
    replies: list[dict] = []
    try:
        replies = _exchange(port, stream)
    except (OSError, ValueError, AssertionError) as exc:
        crash, error = True, f"Traceback: no reply ({type(exc).__name__}: {exc})"
    errors = [r.get("error", "") for r in replies if isinstance(r, dict) and not r.get("ok")]
    output = error or f"{len(replies)} replies"
    if errors and not error:
        output = f"error: {len(errors)} of {len(replies)} replies refused; first: {errors[0]}"
    outcome = Outcome(
        repr(stream)[:300],
        2 if errors or crash else 0,
        " ".join(str(output).split()),
        time.perf_counter() - start,
        crash or any("internal error" in str(e) for e in errors),
        suite="fuzz-serve",
        extra={"lines": len(stream), "error_replies": len(errors)},
    )
    record(outcome)
    assert not crash, (stream, error)
    assert len(replies) == len(stream) + 1
    for reply in replies:
        assert isinstance(reply, dict) and isinstance(reply.get("ok"), bool), reply
        if not reply["ok"]:
            message = reply.get("error")
            assert isinstance(message, str) and message and "\n" not in message, reply
            assert len(message) < 600, reply
    assert not [e for e in errors if "internal error" in str(e)], (stream, errors)
    assert replies[-1]["ok"] and replies[-1]["type"] == "init", (stream, replies[-1])
    assert outcome.seconds < MAX_SECONDS
    assert _released(server), "a closed connection kept its memory reservation"
    assert server.ledger.total() <= server.ledger.budget
    assert not [line for line in logged if "Traceback" in line or "error" in line], logged
