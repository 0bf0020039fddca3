"""Real pings through the online navigator: replaying the EX1811 EM302 log, and its timing."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from sections._common import FIGURES, fmt, md_table

TITLE = "Real pings — replaying the EX1811 multibeam log through the online navigator"
ORDER = 90

METHODS = ("pmf", "mpf", "pf", "sitan", "sitan-bank")
SEEDS = (1, 2, 3, 4, 5)
CELL_M = 50.0
INITIAL_ERROR_M = 500.0
NOISE_STD = 4.0

INTRO = f"""\
The bundled log `builtin:ex1811` holds 50 real Kongsberg EM302 pings of 432 beams (NOAA
Okeanos Explorer, cruise EX1811, 2018-11-02, ≈ 17.84° N 64.59° W, depth 1170–2320 m) with
the ship's GNSS navigation, over 298.5 s and 1.24 km. The map is gridded from **the same
pings** with `geofix grid --cell-m {CELL_M:g}` (cell means placed at their soundings and
interpolated linearly, per-cell standard deviation as map error). Map and measurements
thus share the survey: this section measures the pipeline and the navigator (readers,
gridding, gating, statuses, re-initialisation, timing) on real swath geometry and real
terrain, **not** the accuracy a vehicle would reach against an independent prior map.

An INS drift is simulated on the GNSS track (`geofix replay`: velocity error 5 cm/s,
heading error 0.05°, gyro drift 0.01°/h, and a {INITIAL_ERROR_M:g} m initial error in a
seeded direction); the navigator starts from the INS with the prior sigma the INS model
gives (250 m per axis) and uses 64 evenly spread beams of each ping, noise
{NOISE_STD:g} m per beam plus the map's per-cell error. Seeds {", ".join(map(str, SEEDS))}
(one INS draw each). Errors are against the GNSS track; the done-when bound is two map
cells ({2 * CELL_M:g} m).
"""


READING = """
How to read it: `converged at` is the first ping the navigator's test passed: a small,
resolved, near-Gaussian posterior (largest 1-sigma below two cells, MMSE within 50 m of
the MLE and, for a grid or particle posterior, a KL divergence to its moment-matched
Gaussian of at most 0.2 nats and at least 30 effective points) that the filter's own
consistency supports (five accepted pings or more since the start, their mean NIS within
its chi-square range, a move since earlier pings that the covariance allows, a fix the
INS prior does not rule out, a residual scale below 25: `geofix.navigator.NavigatorSettings`).
`pmf`, `pf` and `mpf` take the map as imperfect by default (representation error,
residual scale, a common offset, the map error's tilt and curvature across the swath), so
their covariance stays wide until the innovations support a narrow one, and they pass the
test after five to thirty pings (the column), within two cells throughout. One 64-beam update is
too sharp for a particle set on the 25 m prior lattice (applied at once it leaves one or a
few particles, a cell or two off, far from Gaussian), so `pf` and `mpf` apply it in
stages (progressive correction: a fraction of the likelihood that keeps 100 effective
particles, the copies spread over their original's share, the likelihood read again, up
to four times). `mpf` carries the whole INS error state (velocity, tilt, biases, heading
error; the model of the INS numbers the replay simulates, `geofix replay` builds it from
them). The EKFs (`sitan`, `sitan-bank`) take the map as exact and report a small
covariance before their linearisation has found the right basin: `sitan` settles (≈ 2-3 m
at the end), while the NIS-window rule re-initialises the bank again and again (the
re-inits column); each loss drops only the fixes made while the window of inconsistent
pings filled and restarts the bank around the last good fix before it, so the bank ends
near the truth although its error runs to hundreds of metres between. The test trusts a
filter's own
covariance: it is a grid/particle-filter test, as it is in TRN.
"""


def _replays(grid, error, mission) -> dict:
    from geofix.errors import InputError
    from geofix.replay import replay

    results, refused = {}, {}
    for seed in SEEDS:
        try:
            results[seed] = replay(
                mission,
                grid,
                list(METHODS),
                initial_error_m=INITIAL_ERROR_M,
                seed=seed,
                settings={"noise_std": NOISE_STD},
                map_error=error,
            )
        except InputError as exc:  # start-up gating: the INS start box is off the map
            refused[seed] = str(exc)
    return results, refused


def _accuracy_table(results: dict) -> str:
    rows = []
    for method in METHODS:
        rows_m = [r.summary["methods"][method] for r in results.values()]
        end = [r["end_error_m"] for r in rows_m]
        mean = [r["mean_error_m"] for r in rows_m]
        worst = [r["max_error_m"] for r in rows_m]
        conv = [r["converged_at_s"] for r in rows_m if r["converged_at_s"] is not None]
        within = sum(w <= 2 * CELL_M for w in worst)
        rows.append(
            [
                f"`{method}`",
                fmt(np.mean(end), 1),
                fmt(np.max(end), 1),
                fmt(np.mean(mean), 1),
                fmt(np.max(worst), 1),
                f"{within}/{len(worst)}",
                fmt(np.mean(conv), 1) if conv else "-",
                sum(r["reinits"] for r in rows_m),
            ]
        )
    header = [
        "method",
        "end error, mean (m)",
        "end error, worst (m)",
        "track error, mean (m)",
        "track error, worst (m)",
        "runs always ≤ 2 cells",
        "converged at (s)",
        "re-inits",
    ]
    return md_table(header, rows)


def _refused_text(refused: dict) -> str:
    if not refused:
        return "\nEvery seed started (start-up gating let every INS start box in).\n"
    lines = [f"- seed {seed}: `{message}`" for seed, message in sorted(refused.items())]
    return (
        "\nStart-up gating refused to start "
        f"{len(refused)} of {len(SEEDS)} seeds: the map is a 2.5 km strip, and an INS "
        "start 500 m off it leaves too little of the ±2σ start box on valid map data "
        "(MBARI TRN waits in that case too). The table covers the seeds that started.\n\n"
        + "\n".join(lines)
        + "\n"
    )


def _timing_table(timing: dict) -> str:
    rows = []
    for method, row in timing["methods"].items():
        rows.append(
            [
                f"`{method}`",
                fmt(row["update_ms"], 1),
                fmt(row["update_all_beams_ms"], 1),
                fmt(row["round_trip_ms"], 1),
                fmt(row.get("server_overhead_ms"), 1),
                fmt(row.get("server_cpu_ms"), 1),
            ]
        )
    header = [
        "method",
        "update, 64 beams used (ms)",
        "update, all 432 beams (ms)",
        "server round trip (ms)",
        "round trip minus the server's update (ms)",
        "server handling minus update, in-process (ms)",
    ]
    return md_table(header, rows)


def build(quick: bool = False) -> str:
    """The section's Markdown; the figure goes to ``docs/figures/navigator_ex1811.png``."""
    import bench_navigator
    from geofix.replay import replay_figure

    with tempfile.TemporaryDirectory() as tmp:
        grid, error, mission, _ = bench_navigator.setup(Path(tmp))
    results, refused = _replays(grid, error, mission)
    FIGURES.mkdir(parents=True, exist_ok=True)
    figure = replay_figure(results[SEEDS[0]], grid, FIGURES / "navigator_ex1811.png")
    timing = bench_navigator.run(["pmf", "mpf", "pf", "sitan"])
    parts = [
        f"## {TITLE}\n",
        INTRO,
        _accuracy_table(results),
        _refused_text(refused),
        READING,
        f"\n![EX1811 replay, seed {SEEDS[0]}](figures/{figure.name})\n",
        "\n**Timing.** Median wall time of one navigator update (`measure`: NIS, gating, "
        "the filter's update, the estimate) on the converged pings of the replay above "
        "(seed 1), one thread; the same ping sent through `geofix serve` over 127.0.0.1 "
        "by `geofix.client` (round trip with the client's JSON encoding, and the median "
        "of round trip minus the update the server's own navigator made for that ping: "
        "what serving adds, JSON both ways, checks, socket and thread wake-ups); and the "
        "server's request handling called in-process (JSON in and out, checks; no socket) "
        "minus the same update made offline. "
        f"Yardstick in the same run: a 300×300 matrix product took "
        f"{timing['yardstick_matmul_ms']:.2f} ms (the machine is shared; compare ratios). "
        "Regenerate with `python benchmarks/bench_navigator.py`.\n\n",
        _timing_table(timing),
    ]
    return "\n".join(parts)
