"""Campaign memory and scaling against their yardsticks: one worker, bytes per map cell.

Three measurements, each campaign run in a fresh child process watched from outside
(psutil):

- ``memory``: peak proportional set size (PSS: shared pages split between the processes
  that map them, so a map shared by forked or attached workers is counted once) of a
  TERCOM campaign on a synthetic ``n x n`` map (saved in float64, as a user's file would
  be), summed over the calling process and its workers, for ``--jobs 1`` and
  ``--jobs 2``; reported as bytes per map cell (goal <= 12) and as the 2-worker /
  1-worker ratio (goal <= 1.2);
- ``scaling``: wall time of a 40-trial TERCOM campaign with ``--jobs 1`` and ``--jobs 2``,
  in alternating pairs (``scaling_long``: the same with 400 trials; ``scaling_headline``:
  40 trials of the headline TERCOM size, +-150 cells x 110 points); the median of the
  pair ratios (goal >= 1.7) and their spread (on a machine whose two cores are shared the
  spread says how much of the ratio is load), and
  the CPU seconds of each run after its imports, workers included (what parallelism
  costs, whatever the load);
- ``startup``: ``--trials 1000000`` with ``--jobs 1`` and ``--jobs 2``: seconds from the
  command's start (interpreter and imports included) until the first result is recorded
  (goal <= 10 s), and the peak PSS over the first ``--watch`` seconds (goal < 1 GB; the run
  is then stopped).

Usage: ``python benchmarks/bench_campaign.py [--cells 10000] [--watch 20] [--json out.json]``
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


def scenario_file(folder: Path, map_path: Path, cells: int, trials: int, samples: int = 40) -> Path:
    """A TERCOM-friendly gravimeter scenario of ``samples`` readings mid-map."""
    text = f"""
    name: bench_campaign_{cells}_{samples}
    map:
      path: {map_path}
    track:
      start_m: [{cells * 50.0}, {cells * 50.0}]
      start_jitter_m: 2000
      heading_deg: 45
      speed_m_s: 5
      interval_s: 20
      samples: {samples}
    sensor:
      type: gravimeter
      noise_std: 1.0
    ins:
      initial_error_m: [1500, 1500]
    trials: {trials}
    seed: 13
    """
    path = folder / f"bench_{cells}_{samples}.yaml"
    path.write_text(textwrap.dedent(text))
    return path


_CHILD = """
import time
START = time.perf_counter()
import sys
from pathlib import Path
from geofix.evaluate import campaign
from geofix.sim.scenario import load_scenario
T0 = time.perf_counter()
import os
C0 = os.times()
print(f"IMPORT {{T0 - START:.3f}}", flush=True)
first = []
def progress(done, total):
    if done and not first:
        first.append(time.perf_counter())
        print(f"FIRST {{first[0] - T0:.3f}}", flush=True)
    if done and done == total:
        print(f"LAST {{time.perf_counter() - T0:.3f}}", flush=True)
scen = load_scenario(Path({scenario!r}))
campaign.run_campaign(scen, [{method!r}], trials={trials}, jobs={jobs},
                      out_dir={out!r}, progress=progress)
print(f"DONE {{time.perf_counter() - T0:.3f}}", flush=True)
t = [b - a for a, b in zip(C0, os.times())]
print(f"CPU {{t[0] + t[1] + t[2] + t[3]:.3f}}", flush=True)
"""


_MARKS = ("IMPORT", "FIRST", "LAST", "DONE", "CPU")
#: Trials of the second scaling figure: long enough for the campaign's fixed costs (the
#: map read, the store, the summary, starting the workers: about 0.1 s) to be amortised.
LONG_TRIALS = 400

#: The goals each figure is held against.
GOALS = {
    "bytes_per_cell": 12.0,
    "memory_ratio": 1.2,
    "speedup": 1.7,
    "startup_s": 10.0,
    "startup_peak_bytes": 1e9,
}


def _tree_pss(proc: psutil.Process) -> int:
    """PSS of a process and its children, bytes (0 for processes that vanished)."""
    total = 0
    for p in [proc, *proc.children(recursive=True)]:
        with contextlib.suppress(psutil.NoSuchProcess, psutil.AccessDenied):
            total += p.memory_full_info().pss
    return total


#: The quick TERCOM of the campaign figures: a +-3 sigma window (+-45 cells of 100 m).
QUICK_TERCOM = "tercom:window_sigma=3"
#: The TERCOM size of the headline figure, +-150 cells x 110 points (100 m cells).
HEADLINE_TERCOM, HEADLINE_SAMPLES = "tercom:window_m=15000", 110


def watch_campaign(
    scenario: Path,
    jobs: int,
    trials: int,
    out: Path,
    limit_s: float,
    memory: bool = True,
    method: str = QUICK_TERCOM,
) -> dict:
    """Run a campaign in a child process; peak PSS, time to first result, wall time.

    ``memory=False`` does not sample the PSS (``peak_pss_bytes`` 0): reading every
    process's page map each 50 ms costs CPU that a 2-worker run on two cores would
    otherwise have, and so would slow the very run whose wall time is measured.
    """
    code = _CHILD.format(
        scenario=str(scenario), trials=trials, jobs=jobs, out=str(out), method=method
    )
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
        if memory:
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
    words = [line.split() for line in lines]
    marks = {w[0]: float(w[1]) for w in words if len(w) == 2 and w[0] in _MARKS}
    first, done = marks.get("FIRST"), marks.get("DONE")
    if child.returncode not in (0, -9) and not stopped:
        raise RuntimeError(f"campaign child failed:\n{log.read_text()[-2000:]}")
    started = None if first is None else first + marks.get("IMPORT", 0.0)
    return {
        "peak_pss_bytes": peak,
        "import_s": marks.get("IMPORT"),
        "first_result_s": first,
        "first_result_from_start_s": started,
        "wall_s": done,
        "last_result_s": marks.get("LAST"),
        "cpu_s": marks.get("CPU"),
        "stopped": stopped,
    }


def memory_figures(folder: Path, cells: int, trials: int = 4) -> dict:
    """Peak PSS of a campaign on a ``cells x cells`` map, ``--jobs 1`` and ``--jobs 2``."""
    big = make_map(folder / "big.nc", cells)
    scen = scenario_file(folder, big, cells, trials)
    report: dict = {"cells": cells}
    for jobs in (1, 2):
        run = watch_campaign(scen, jobs, trials, folder / f"m{jobs}", 1800.0)
        run["bytes_per_cell"] = run["peak_pss_bytes"] / cells**2
        report[f"memory_jobs{jobs}"] = run
    big.unlink()
    one, two = report["memory_jobs1"], report["memory_jobs2"]
    report["memory_ratio"] = two["peak_pss_bytes"] / one["peak_pss_bytes"]
    return report


def scaling_figures(
    folder: Path,
    trials: int = 40,
    pairs: int = 3,
    samples: int = 40,
    method: str = QUICK_TERCOM,
) -> dict:
    """Wall times of ``--jobs 1`` and ``--jobs 2`` in alternating pairs, and their ratios."""
    small = folder / "small.nc"
    if not small.exists():
        make_map(small, 800)
    scen = scenario_file(folder, small, 800, trials, samples)
    runs: dict = {1: [], 2: []}
    for k in range(pairs):
        for jobs in (1, 2):
            out = folder / f"s{jobs}_{k}_{samples}_{trials}"
            run = watch_campaign(scen, jobs, trials, out, 1800.0, memory=False, method=method)
            runs[jobs].append(run)
    ratios = [a["wall_s"] / b["wall_s"] for a, b in zip(runs[1], runs[2], strict=True)]
    return {
        **serial_share(runs[1]),
        "trials": trials,
        "samples": samples,
        "method": method,
        "jobs1_wall_s": [r["wall_s"] for r in runs[1]],
        "jobs2_wall_s": [r["wall_s"] for r in runs[2]],
        "jobs1_cpu_s": [r["cpu_s"] for r in runs[1]],
        "jobs2_cpu_s": [r["cpu_s"] for r in runs[2]],
        "speedup": float(np.median(ratios)),
        "speedup_spread": [min(ratios), max(ratios)],
    }


def serial_share(one_worker: list[dict]) -> dict:
    """What no worker count can shorten, from ``--jobs 1`` runs (medians, seconds).

    ``serial_s``: until the first result (the map read, the checks, the first trial with
    its one-time kernel loads -- which the calling process runs before forking) plus after
    the last (the summary). ``amdahl_limit``: the speed-up two workers would give if
    everything between the first and the last result were shared perfectly between them,
    ``wall / (serial + (wall - serial) / 2)``.
    """
    wall = float(np.median([r["wall_s"] for r in one_worker]))
    serial = float(
        np.median([r["first_result_s"] + r["wall_s"] - r["last_result_s"] for r in one_worker])
    )
    return {"serial_s": serial, "amdahl_limit": wall / (serial + 0.5 * (wall - serial))}


def startup_figures(folder: Path, watch_s: float = 20.0) -> dict:
    """``--trials 1000000``: first result and peak PSS over ``watch_s``, ``--jobs 1`` and 2."""
    small = folder / "small.nc"
    if not small.exists():
        make_map(small, 800)
    scen = scenario_file(folder, small, 800, 10**6)
    return {f"jobs{j}": watch_campaign(scen, j, 10**6, folder / f"u{j}", watch_s) for j in (1, 2)}


def campaign_figures(cells: int, watch_s: float = 20.0, skip=()) -> dict:
    """Every campaign figure of one run, with the goals they are held against."""
    report: dict = {"cells": cells, "goals": GOALS}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        if "memory" not in skip:
            report.update(memory_figures(folder, cells))
        if "scaling" not in skip:
            report["scaling"] = scaling_figures(folder)
            report["scaling_long"] = scaling_figures(folder, trials=LONG_TRIALS, pairs=2)
            report["scaling_headline"] = scaling_figures(
                folder, samples=HEADLINE_SAMPLES, method=HEADLINE_TERCOM
            )
        if "startup" not in skip:
            report["startup"] = startup_figures(folder, watch_s)
    return report


def main() -> None:
    """Run the three measurements and print (or save) them as JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", type=int, default=10000, help="map side, cells")
    parser.add_argument("--watch", type=float, default=20.0, help="seconds of the 1e6 runs")
    parser.add_argument("--skip", nargs="*", default=[], choices=["memory", "scaling", "startup"])
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    text = json.dumps(campaign_figures(args.cells, args.watch, args.skip), indent=2)
    print(text)
    if args.json:
        args.json.write_text(text + "\n")


if __name__ == "__main__":
    main()
