"""Campaign memory and scaling: shared map for local workers, bounded submission.

Three measurements, each run in a fresh child process watched from outside (psutil):

- ``memory``: peak proportional set size (PSS: shared pages split between the processes
  that map them, so a shared map is counted once) of a TERCOM campaign on a synthetic
  ``n x n`` map, summed over the calling process and its workers, for ``--jobs 1`` and
  ``--jobs 2``; reported as bytes per map cell and as the 2-worker / 1-worker ratio;
- ``scaling``: wall time of a 40-trial TERCOM campaign with ``--jobs 1`` and ``--jobs 2``
  (a ratio; on a machine whose two cores are shared the ratio says more about the other
  load than about the code);
- ``startup``: ``--trials 1000000``: seconds until the first result is recorded, and the
  peak PSS over the first ``--watch`` seconds (the run is then stopped).

Usage: ``python benchmarks/bench_campaign.py [--cells 5000] [--watch 20] [--json out.json]``
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np
import psutil

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def make_map(path: Path, cells: int, seed: int = 0) -> Path:
    """A smooth random ``cells x cells`` gravity-like map (100 m cells), saved with geofix."""
    from geofix.maps.grid import Grid
    from geofix.maps.io import save_grid

    rng = np.random.default_rng(seed)
    axis = np.arange(cells) * 100.0
    terms = [(rng.uniform(2e-4, 2e-3, 2), rng.normal(0, 10), rng.uniform(0, 6)) for _ in range(6)]
    z = np.zeros((cells, cells))
    step = max(1, 2**22 // cells)
    for r0 in range(0, cells, step):  # separable terms, a block of rows at a time
        rows = axis[r0 : r0 + step]
        for (kx, ky), amplitude, phase in terms:
            z[r0 : r0 + step] += amplitude * np.outer(np.cos(ky * rows + phase), np.sin(kx * axis))
    save_grid(Grid(z, 0.0, 0.0, 100.0, 100.0, kind="gravity", units="mGal", name="synth"), path)
    return path


def scenario_file(folder: Path, map_path: Path, cells: int, trials: int) -> Path:
    """A TERCOM-friendly gravimeter scenario in the middle of the synthetic map."""
    text = f"""
    name: bench_campaign_{cells}
    map:
      path: {map_path}
    track:
      start_m: [{cells * 50.0}, {cells * 50.0}]
      start_jitter_m: 2000
      heading_deg: 45
      speed_m_s: 5
      interval_s: 20
      samples: 40
    sensor:
      type: gravimeter
      noise_std: 1.0
    ins:
      initial_error_m: [1500, 1500]
    trials: {trials}
    seed: 13
    """
    path = folder / f"bench_{cells}.yaml"
    path.write_text(textwrap.dedent(text))
    return path


_CHILD = """
import sys, time
from pathlib import Path
from geofix.evaluate import campaign
from geofix.sim.scenario import load_scenario
T0 = time.perf_counter()
first = []
def progress(done, total):
    if done and not first:
        first.append(time.perf_counter())
        print(f"FIRST {{first[0] - T0:.3f}}", flush=True)
scen = load_scenario(Path({scenario!r}))
campaign.run_campaign(scen, ["tercom:window_sigma=3"], trials={trials}, jobs={jobs},
                      out_dir={out!r}, progress=progress)
print(f"DONE {{time.perf_counter() - T0:.3f}}", flush=True)
"""


def _tree_pss(proc: psutil.Process) -> int:
    """PSS of a process and its children, bytes (0 for processes that vanished)."""
    total = 0
    for p in [proc, *proc.children(recursive=True)]:
        with contextlib.suppress(psutil.NoSuchProcess, psutil.AccessDenied):
            total += p.memory_full_info().pss
    return total


def watch_campaign(scenario: Path, jobs: int, trials: int, out: Path, limit_s: float) -> dict:
    """Run a campaign in a child process; peak PSS, time to first result, wall time."""
    code = _CHILD.format(scenario=str(scenario), trials=trials, jobs=jobs, out=str(out))
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", "PYTHONPATH": str(ROOT / "src")}
    t0 = time.perf_counter()
    log = out.with_suffix(".stderr")
    out.parent.mkdir(parents=True, exist_ok=True)
    with log.open("w") as err:
        child = subprocess.Popen(
            [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=err, text=True, env=env
        )
    proc = psutil.Process(child.pid)
    peak, lines = 0, []
    os.set_blocking(child.stdout.fileno(), False)
    while child.poll() is None and time.perf_counter() - t0 < limit_s:
        peak = max(peak, _tree_pss(proc))
        lines += child.stdout.readlines() or []
        time.sleep(0.05)
    stopped = child.poll() is None
    if stopped:
        for p in proc.children(recursive=True):
            p.kill()
        child.kill()
    child.wait()
    lines += child.stdout.readlines() or []
    marks = {line.split()[0]: float(line.split()[1]) for line in lines if line[:4] in "FIRSTDONE"}
    first, done = marks.get("FIRST"), marks.get("DONE")
    if child.returncode not in (0, -9) and not stopped:
        raise RuntimeError(f"campaign child failed:\n{log.read_text()[-2000:]}")
    return {"peak_pss_bytes": peak, "first_result_s": first, "wall_s": done, "stopped": stopped}


def main() -> None:
    """Run the three measurements and print (or save) them as JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", type=int, default=5000, help="map side, cells")
    parser.add_argument("--trials", type=int, default=4, help="trials of the memory runs")
    parser.add_argument("--scaling-trials", type=int, default=40)
    parser.add_argument("--watch", type=float, default=20.0, help="seconds of the 1e6 run")
    parser.add_argument("--skip", nargs="*", default=[], choices=["memory", "scaling", "startup"])
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    report: dict = {"cells": args.cells}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        if "memory" not in args.skip:
            big = make_map(folder / "big.nc", args.cells)
            scen = scenario_file(folder, big, args.cells, args.trials)
            for jobs in (1, 2):
                run = watch_campaign(scen, jobs, args.trials, folder / f"m{jobs}", 1800.0)
                run["bytes_per_cell"] = run["peak_pss_bytes"] / args.cells**2
                report[f"memory_jobs{jobs}"] = run
            report["memory_ratio"] = (
                report["memory_jobs2"]["peak_pss_bytes"] / report["memory_jobs1"]["peak_pss_bytes"]
            )
        small = make_map(folder / "small.nc", 800)
        scen = scenario_file(folder, small, 800, args.scaling_trials)
        if "scaling" not in args.skip:
            runs = {
                j: watch_campaign(scen, j, args.scaling_trials, folder / f"s{j}", 1800.0)
                for j in (1, 2)
            }
            report["scaling"] = {f"jobs{j}": r for j, r in runs.items()}
            report["scaling"]["speedup"] = runs[1]["wall_s"] / runs[2]["wall_s"]
        if "startup" not in args.skip:
            report["startup"] = watch_campaign(scen, 2, 10**6, folder / "u", args.watch)
    text = json.dumps(report, indent=2)
    print(text)
    if args.json:
        args.json.write_text(text + "\n")


if __name__ == "__main__":
    main()
