"""Shared checks of the bad-input, fuzz and kill tests: run a command, judge its outcome.

An outcome is *clean* when the command exits non-zero, shows no traceback, prints at most
:data:`MAX_LINES` lines and names what was wrong. When the environment variable
``GEOFIX_RELIABILITY_LOG`` names a file, every judged outcome is appended to it as one
JSON line (``benchmarks/sections/reliability.py`` counts them for ``docs/RESULTS.md``).
"""

from __future__ import annotations

import json
import os
import time
import tracemalloc
from dataclasses import asdict, dataclass, field
from pathlib import Path

from typer.testing import CliRunner

MAX_LINES = 3
MAX_SECONDS = 30.0
LOG_ENV = "GEOFIX_RELIABILITY_LOG"
MEMORY_ENV = "GEOFIX_MEMORY_BUDGET"


@dataclass
class Outcome:
    """What one run of a command did."""

    case: str
    exit_code: int
    output: str
    seconds: float
    traceback: bool
    peak_bytes: int = 0
    budget_bytes: int = 0
    suite: str = "bad-inputs"
    extra: dict = field(default_factory=dict)

    @property
    def lines(self) -> list[str]:
        return [line for line in self.output.splitlines() if line.strip()]

    @property
    def memory_refusal(self) -> bool:
        return "memory budget" in self.output

    def kind(self) -> str:
        """``clean-error``, ``traceback``, ``hang``, ``messy-error`` or ``ok``."""
        if self.traceback:
            return "traceback"
        if self.seconds > MAX_SECONDS:
            return "hang"
        if self.exit_code == 0:
            return "ok"
        return "clean-error" if len(self.lines) <= MAX_LINES else "messy-error"


def record(outcome: Outcome) -> None:
    """Append the outcome to the reliability log when one is asked for."""
    path = os.environ.get(LOG_ENV)
    if not path:
        return
    row = asdict(outcome) | {"kind": outcome.kind(), "memory_refusal": outcome.memory_refusal}
    row["output"] = row["output"][:500]
    with Path(path).open("a") as f:
        f.write(json.dumps(row) + "\n")


def run_cli(
    case: str,
    args: list[str],
    env: dict | None = None,
    trace: bool = False,
    suite: str = "bad-inputs",
) -> Outcome:
    """Run ``geofix ARGS`` in this process (typer's runner), stdout and stderr together.

    Parameters
    ----------
    case : str
        Name of the case, for the log.
    args : list of str
        Command-line arguments.
    env : dict, optional
        Environment variables set during the run.
    trace : bool
        Measure the peak of Python-visible allocations (numpy included) with tracemalloc.
    suite : str
        The suite the outcome is counted in (``benchmarks/sections/reliability.py``).
    """
    from geofix.cli import app
    from geofix.memory import memory_budget_bytes

    runner = CliRunner()
    old = {k: os.environ.get(k) for k in [*(env or {}), MEMORY_ENV]}  # --memory-budget sets it
    os.environ.update(env or {})
    try:
        if trace:
            tracemalloc.start()
        start = time.perf_counter()
        result = runner.invoke(app, args, env={"COLUMNS": "200"})
        seconds = time.perf_counter() - start
        peak = tracemalloc.get_traced_memory()[1] if trace else 0
        budget = memory_budget_bytes() if trace else 0
    finally:
        if trace:
            tracemalloc.stop()
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    crashed = result.exception is not None and not isinstance(result.exception, SystemExit)
    outcome = Outcome(
        case,
        int(result.exit_code),
        result.output,
        seconds,
        crashed or "Traceback" in result.output,
        peak,
        budget,
        suite,
    )
    record(outcome)
    return outcome


def assert_clean_error(outcome: Outcome, *names: str, exit_code: int = 2) -> None:
    """Non-zero exit, no traceback, at most 3 lines, every name shown, under 30 s."""
    assert not outcome.traceback, outcome.output
    assert outcome.exit_code == exit_code, (outcome.exit_code, outcome.output)
    assert 1 <= len(outcome.lines) <= MAX_LINES, outcome.output
    for name in names:
        assert name in outcome.output, (name, outcome.output)
    assert outcome.seconds < MAX_SECONDS, outcome.seconds
    if outcome.budget_bytes:
        assert outcome.peak_bytes < outcome.budget_bytes, (outcome.peak_bytes, outcome.budget_bytes)
