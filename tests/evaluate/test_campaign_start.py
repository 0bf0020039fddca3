"""Local workers forked or spawned: the same table as one process, bit for bit.

Each pooled campaign runs in a fresh interpreter (``python -c``): there no numba thread
pool is started yet, so ``fork`` is really used (this test process may already have
started GNU OpenMP, which makes :func:`worker_start_method` fall back to ``spawn``).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from conftest import small_mission_data
from geofix.errors import ConfigError
from geofix.evaluate import _pool, campaign, run_campaign
from geofix.sim.scenario import load_scenario

METHODS = ["tercom", "tercom:metric=mad"]
TRIALS = 4
_SCRIPT = """
import json, sys
from geofix.evaluate import campaign
from geofix.sim.scenario import load_scenario
method = campaign.worker_start_method()
result = campaign.run_campaign(
    load_scenario(sys.argv[1]), sys.argv[3:], jobs=2, out_dir=sys.argv[2], progress=None
)
frame = result.frame
after = campaign.worker_start_method()
print(json.dumps({"method": method, "after": after, "rows": _ROWS}))
""".replace("_ROWS", "frame[['method', 'trial', 'end_error_m', 'track_ms_m2']].values.tolist()")


def _pooled(scenario: Path, out: Path, start: str | None, threads: str = "1") -> dict:
    src = str(Path(__file__).resolve().parents[2] / "src")
    env = {**os.environ, "PYTHONPATH": src, "NUMBA_NUM_THREADS": threads}
    env.pop(campaign.START_METHOD_ENV, None)
    if start is not None:
        env[campaign.START_METHOD_ENV] = start
    cmd = [sys.executable, "-c", _SCRIPT, str(scenario), str(out), *METHODS]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork is used on Linux only")
def test_forked_and_spawned_workers_give_the_one_process_table(tmp_path):
    scenario = tmp_path / "start.yaml"
    scenario.write_text(yaml.safe_dump(small_mission_data("start", trials=TRIALS)))
    inline = run_campaign(load_scenario(scenario), METHODS, jobs=1, out_dir=tmp_path / "one")
    rows = inline.frame[["method", "trial", "end_error_m", "track_ms_m2"]].values.tolist()
    # Two numba threads: the parent's own first trial must still leave it safe to fork
    # (it runs the serial twins of the parallel kernels, geofix._threads).
    for start, expected in ((None, "fork"), ("spawn", "spawn")):
        pooled = _pooled(scenario, tmp_path / expected, start, threads="2")
        assert pooled["method"] == expected
        assert pooled["after"] == expected
        assert pooled["rows"] == rows  # floats through JSON: exact (repr round-trips)


def test_unknown_start_method_is_refused(monkeypatch):
    monkeypatch.setenv(campaign.START_METHOD_ENV, "forkserver")
    with pytest.raises(ConfigError, match="GEOFIX_START_METHOD must be one of"):
        _pool.worker_start_method()


def test_spawn_is_used_while_another_thread_runs(monkeypatch):
    monkeypatch.delenv(campaign.START_METHOD_ENV, raising=False)
    monkeypatch.setattr(_pool.threading, "active_count", lambda: 2)
    assert _pool.worker_start_method() == "spawn"
