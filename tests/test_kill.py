"""Killed campaigns: SIGKILL leaves no worker behind and a rerun gives the same table;
Ctrl-C prints one line, not the workers' tracebacks.

Real processes (``python -m geofix run --jobs 2``): the parent is killed at random points
(seeded, counted from the moment its two workers exist), its pool workers must be gone
within 5 s, and rerunning the same command must give exactly the summary of an
uninterrupted run (wall times aside).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pytest
import yaml

from _reliability import MAX_LINES, Outcome, record
from conftest import small_mission_data

pytestmark = pytest.mark.slow

METHODS = ("tercom", "tercom:metric=mad")
TRIALS = 10
CTRL_C_TRIALS = 1000
KILLS = 2
ORPHAN_GRACE_S = 5.0


def _command(scenario: Path, out: Path, trials: int = TRIALS) -> list[str]:
    cmd = [sys.executable, "-m", "geofix", "run", str(scenario), "--jobs", "2"]
    for spec in METHODS:
        cmd += ["-m", spec]
    return [*cmd, "--trials", str(trials), "--out", str(out), "--json"]


def _env() -> dict:
    src = str(Path(__file__).resolve().parents[1] / "src")
    path = os.pathsep.join(p for p in (src, os.environ.get("PYTHONPATH")) if p)
    return {**os.environ, "PYTHONPATH": path, "NUMBA_NUM_THREADS": "1"}


def _without_times(summary: dict) -> dict:
    for stats in summary["methods"].values():
        stats.pop("mean_time_s")
    return summary


def _descendants(pid: int) -> list[psutil.Process]:
    try:
        return psutil.Process(pid).children(recursive=True)
    except psutil.NoSuchProcess:
        return []


def _scenario(tmp_path: Path) -> Path:
    path = tmp_path / "kill.yaml"
    path.write_text(yaml.safe_dump(small_mission_data("kill-campaign", trials=TRIALS)))
    return path


def _kill_at(cmd: list[str], delay_s: float) -> tuple[list[psutil.Process], bool]:
    """Start ``cmd``; SIGKILL it ``delay_s`` after its workers exist (or it ended).

    Returns its descendants seen just before the kill and whether it had ended.
    """
    proc = subprocess.Popen(cmd, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    start = time.monotonic()
    while len(_descendants(proc.pid)) < 2 and proc.poll() is None:
        if time.monotonic() - start > 60:
            break
        time.sleep(0.05)
    deadline = time.monotonic() + delay_s
    children: list[psutil.Process] = []
    while time.monotonic() < deadline and proc.poll() is None:
        children = _descendants(proc.pid) or children
        time.sleep(0.05)
    children = _descendants(proc.pid) or children
    finished = proc.poll() is not None
    if not finished:
        proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=10)
    return children, finished


def test_sigkill_at_random_points_then_rerun_gives_the_same_table(tmp_path, small_mission):
    from geofix.evaluate.campaign import run_campaign

    reference = run_campaign(
        small_mission("kill-campaign", trials=TRIALS),
        list(METHODS),
        jobs=1,
        out_dir=tmp_path / "reference",
    ).summary.to_json()
    cmd = _command(_scenario(tmp_path), tmp_path / "out")
    rng = np.random.default_rng(20261201)
    kills = []
    for k, delay in enumerate(rng.uniform(0.0, 4.0, KILLS)):
        start = time.perf_counter()
        children, finished = _kill_at(cmd, float(delay))
        _, alive = psutil.wait_procs(children, timeout=ORPHAN_GRACE_S)
        for p in alive:  # never leave them running, even when the test fails
            p.kill()
        outcome = Outcome(
            f"SIGKILL {k} at {delay:.2f} s",
            -9,
            f"{len(children)} workers, {len(alive)} left after {ORPHAN_GRACE_S:g} s",
            time.perf_counter() - start,
            False,
            suite="kill",
            extra={"orphans": len(alive), "finished_before_kill": finished},
        )
        assert not alive, f"{len(alive)} orphan workers after {ORPHAN_GRACE_S} s"
        kills.append(outcome)
    done = subprocess.run(cmd, env=_env(), capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    assert _without_times(json.loads(done.stdout)) == _without_times(reference)
    for outcome in kills:  # survived: no orphan, and the rerun gave the same table
        record(outcome)


def _terminal_sigint() -> None:
    """Give the child the default Ctrl-C disposition, as a terminal's foreground job has.

    A job started in the background by a non-interactive shell inherits ``SIGINT``
    ignored, and Python then installs no KeyboardInterrupt handler.
    """
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_prints_one_line_without_worker_tracebacks(tmp_path):
    # enough trials that forked workers (which start at once) are still busy after 1 s
    cmd = _command(_scenario(tmp_path), tmp_path / "out", trials=CTRL_C_TRIALS)
    proc = subprocess.Popen(
        cmd,
        env=_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,
        preexec_fn=_terminal_sigint,
    )
    start = time.perf_counter()
    while len(_descendants(proc.pid)) < 2 and time.perf_counter() - start < 20:
        time.sleep(0.05)
    time.sleep(1.0)  # workers importing or running trials
    children = _descendants(proc.pid)
    os.killpg(proc.pid, signal.SIGINT)  # as a terminal does: the whole process group
    _, err = proc.communicate(timeout=30)
    err = err.decode()
    lines = [line for line in err.splitlines() if line.strip()]
    outcome = Outcome("Ctrl-C --jobs 2", proc.returncode, err, time.perf_counter() - start, False)
    outcome.traceback = "Traceback" in err
    record(outcome)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    assert len(lines) <= MAX_LINES and lines[-1].startswith("interrupted:"), err
    _, alive = psutil.wait_procs(children, timeout=ORPHAN_GRACE_S)
    assert not alive
