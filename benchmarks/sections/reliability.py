"""Reliability: bad input, memory refusals, killed campaigns -- counted from the test suite.

Runs the bad-input, fuzz and kill tests (``tests/test_bad_inputs.py``,
``tests/test_fuzz_inputs.py``, ``tests/test_fuzz_faces.py``, ``tests/test_kill.py``) with
``GEOFIX_RELIABILITY_LOG`` set, so that every judged outcome is logged, and counts the log:
nothing here is typed by hand. The generated inputs are counted per face: ``run``
(scenarios, map files), ``grid`` (soundings tables), ``replay`` (nav / soundings tables),
the GSF reader (corrupted files) and ``serve`` (message streams).
"""

from __future__ import annotations

import collections
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import ROOT, md_table

TITLE = "Reliability — bad input, memory guards, killed campaigns"
ORDER = 95

TEST_FILES = (
    "tests/test_bad_inputs.py",
    "tests/test_fuzz_inputs.py",
    "tests/test_fuzz_faces.py",
    "tests/test_kill.py",
)
SUITES = {
    "bad-inputs": "hand-made bad inputs (CLI, in process)",
    "fuzz-scenario": "`run`: generated scenarios (hypothesis)",
    "fuzz-map": "`run`: generated map files (hypothesis)",
    "fuzz-grid": "`grid`: generated soundings tables, CSV and Parquet (hypothesis)",
    "fuzz-replay": "`replay`: generated nav / soundings tables (hypothesis)",
    "fuzz-gsf": "`grid`: corrupted GSF files (hypothesis)",
    "fuzz-serve": "`serve`: generated message streams, one connection each (hypothesis)",
    "kill": "SIGKILL of a `--jobs 2` campaign",
}
TIMEOUT_S = 1800


def build(quick: bool) -> str:
    """Run the tests with outcome logging and tabulate the counts."""
    rows, status, seconds = _run_tests()
    parts = [f"## {TITLE}\n", _intro(), _counts_table(rows), _suite_table(rows)]
    parts.append(_status_line(status, seconds))
    parts.append(_reproduce())
    return "\n".join(parts)


def _run_tests() -> tuple[list[dict], dict, float]:
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", "PYTHONPATH": str(ROOT / "src")}
    status = {}
    rows: list[dict] = []
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "outcomes.jsonl"
        env["GEOFIX_RELIABILITY_LOG"] = str(log)
        for test_file in TEST_FILES:
            cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", test_file]
            try:
                proc = subprocess.run(
                    cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=TIMEOUT_S
                )
                status[test_file] = _last_line(proc.stdout) if proc.returncode == 0 else "FAILED"
            except subprocess.TimeoutExpired:
                status[test_file] = f"HANG (over {TIMEOUT_S} s)"
        if log.exists():
            rows = [json.loads(line) for line in log.read_text().splitlines() if line.strip()]
    return rows, status, time.perf_counter() - start


def _last_line(text: str) -> str:
    lines = [line for line in text.strip().splitlines() if line.strip()]
    return lines[-1].strip("= ") if lines else ""


def _intro() -> str:
    return (
        "Every input a user can get wrong must end in one plain line on stderr, exit code 2, "
        "no traceback, in under 30 s, without allocating more than the memory budget "
        "(`GEOFIX_MEMORY_BUDGET` / `geofix --memory-budget`, default half the RAM). The "
        "counts below come from running the test files named at the end with outcome "
        "logging: *clean error* = non-zero exit, at most 3 lines; *traceback* = any "
        "exception other than a geofix error; *hang* = over 30 s; *memory refusal* = "
        "refused with the size estimate against the budget, before allocating; *kill "
        "survived* = after a SIGKILL of the parent at a random point, no worker was left "
        "after 5 s and the rerun gave exactly the table of an uninterrupted run. The "
        "generated inputs come from hypothesis in its derandomised mode (fixed seeds; the "
        "exact mix of examples can still shift between hypothesis versions); the fuzz tests "
        "use a 64 MB budget so that sizes are refused rather than allocated. *Accepted* "
        "inputs are valid ones (a fuzzed scenario that is still a valid mission, `--jobs` "
        "above the cores: capped with a one-line warning). The generated inputs of `grid`, "
        "`replay` and the GSF reader run the command (or the function it calls) in process "
        "with a 16 MB budget (512 MB for `replay`, which holds a default `pmf`); their "
        "tracemalloc peak is checked against it. A `serve` case is a stream of one to nine "
        "lines (JSON requests with hostile values, non-JSON lines) on one connection to a "
        "server on 127.0.0.1: *accepted* when every reply is a result, *clean error* when "
        "each error reply is one plain line, the connection still takes an `init` and its "
        "memory reservation is given back when it closes.\n"
    )


def _counts_table(rows: list[dict]) -> str:
    inputs = [r for r in rows if r["suite"] != "kill"]
    kinds = collections.Counter(r["kind"] for r in inputs)
    kills = [r for r in rows if r["suite"] == "kill"]
    survived = sum(1 for r in kills if r["extra"].get("orphans", 1) == 0)
    table = [
        ["inputs tried", len(inputs)],
        ["clean errors", kinds["clean-error"]],
        ["accepted (valid input)", kinds["ok"]],
        ["tracebacks", kinds["traceback"]],
        ["hangs (over 30 s)", kinds["hang"]],
        ["errors over 3 lines", kinds["messy-error"]],
        ["memory refusals", sum(1 for r in inputs if r["memory_refusal"])],
        ["kills survived", f"{survived} of {len(kills)}"],
    ]
    return md_table(["what", "count"], table)


def _suite_table(rows: list[dict]) -> str:
    out = []
    for suite, label in SUITES.items():
        chosen = [r for r in rows if r["suite"] == suite]
        if not chosen:
            continue
        kinds = collections.Counter(r["kind"] for r in chosen)
        slowest = max(r["seconds"] for r in chosen)
        out.append(
            [
                label,
                len(chosen),
                kinds["clean-error"],
                kinds["ok"],
                kinds["traceback"],
                kinds["hang"],
                sum(1 for r in chosen if r["memory_refusal"]),
                f"{slowest:.1f}",
            ]
        )
    header = ["suite", "runs", "clean errors", "accepted", "tracebacks", "hangs"]
    return md_table([*header, "memory refusals", "slowest (s)"], out)


def _status_line(status: dict, seconds: float) -> str:
    parts = [f"`{name}`: {result}" for name, result in status.items()]
    return "Test runs: " + "; ".join(parts) + f" (all in {seconds:.0f} s).\n"


def _reproduce() -> str:
    return (
        "Regenerate with `python benchmarks/results.py --only reliability`; the tests alone "
        f"with `pytest {' '.join(TEST_FILES)}`.\n"
    )
