"""Source 004: IOAP ring-domain gravity matching against TERCOM (three tests)."""

from __future__ import annotations

import numpy as np
from _common import (
    campaign,
    fmt,
    md_table,
    save_section_figure,
    scenario,
    summary_header,
    summary_rows,
)

TITLE = "Source 004: IOAP ring-domain gravity matching vs TERCOM"
ORDER = 60

TEST1 = ["tercom", "ioap:sigma_multiple=1", "ioap:sigma_multiple=2", "ioap"]
TEST2 = ["ioap:reference=1", "ioap", "ioap:reference=2", "ioap:reference=2.5"]
TEST3 = ["tercom", "ioap"]
DRIFT = ["tercom", "ioap:sigma_multiple=2", "ioap", "ioap:track_shape=anchor"]
STARTS = {"a": "A", "b": "B", "c": "C"}
LEVELS = ("20", "40", "60", "80", "100")

# What the source text states in words (its tables and figures are images, lost in the text).
SOURCE_TEST3 = {"A": (20.37, 47.24), "B": (40.39, 63.96), "C": (13.88, 72.16)}

INTRO = """\
The source (a 2021 patent application) matches 110 gravimeter samples (every 20 s, 10 m/s,
heading N70E) against a Sandwell & Smith 1' gravity anomaly grid of the South China Sea
(113-115E, 10-12N, -33.5 .. 130.6 mGal, mean 15.4) resampled bilinearly to 100 m.
We use the bundled Sandwell & Smith grid of the Gulf of Alaska (2', coarser than the
source's 1'), cut to 138-136W, 53-55N (-24.5 .. 122.1 mGal, mean 8.9: the closest range
to the source's among the 2 x 2 degree boxes of the bundled map) and resampled bilinearly to
100 m (2194 x 1320 cells). The field is smoother than the source's: a few seamounts on a
quiet background.

**The source's tables and figures are images, missing from its text.** What it states in
words is all we can set beside our numbers: 3-sigma-IOAP (1.5) is best of the sigma
variants and beats TERCOM on mean, std and worst error at about TERCOM's time;
2-sigma-IOAP takes about half TERCOM's time with a mean error under one cell and 88 %
success at l = 100 m against TERCOM's 82 %; TERCOM has no success at l <= 40 m while the
IOAP variants have some; 1-sigma-IOAP is worse than TERCOM; test 2 ranks 2.5 > 2 > 1.5 > 1
in accuracy, 2.5-IOAP taking about twice TERCOM's time and 1-IOAP the fastest, 1-IOAP
still better than TERCOM on 6 of 7 indices; test 3 improves TERCOM's mean / worst error by
20.37 / 47.24 % (A), 40.39 / 63.96 % (B) and 13.88 / 72.16 % (C).

**Candidate track.** The source rebuilds each candidate track backwards from the candidate
end node "with the vehicle's speed and heading", i.e. the indicated track *translated* to
end on the node (no rotation or scaling about the start fix); `ioap` does exactly that.
The start fix (SPMP) only places the ring centre; with the source's INS numbers its radius
3 sigma0 is about 2 m (sigma0 = 0.6 m of drift over one 20 s interval), well inside one
100 m cell, so it keeps the indicated start. `ioap:track_shape=anchor` (rotate and scale
the track from the start fix to the candidate end) is our extension, not the source.

**INS error.** Taken literally (scenario `source004_drift`), a 1e-3 m/s^2 accelerometer
bias makes the INS error grow along the track from 0 to about 1.25 km (Schuler loop; 2.4 km
without it). No translation of the indicated track then fits the true one, and neither
TERCOM nor the source's IOAP can reach the source's ~100 m accuracy (table D below). The
source's TERCOM result (82 % within 100 m) is only possible if its indicated track had the
true track's shape, offset as a whole by a normally distributed error, as its phrase "the
INS RMS error is normal" suggests. Tests 1-3 therefore use that emulation: a random
per-axis offset of std 876 m (the accumulated 1-sigma of the same bias after 2180 s in our
Schuler-loop model), plus the 0.04 m/s velocity and 0.05 deg heading errors, no
accelerometer bias. Both methods get the same prior sigma (876 m): TERCOM searches a square
of half-side 3 sigma (53 x 53 = 2809 translations), IOAP discs of radius xi sigma.
The start is jittered by up to +-50 m per axis (a start on a grid node, as in the source,
puts the true end 46 m from the nearest node in every run, a floor for IOAP's node-snapped
fix). Times are wall seconds per match from the same campaign runner (two worker
processes, one numba thread each); TERCOM's and IOAP's scoring kernels are both compiled
(numba), so times compare the algorithms; "candidates" (mean scored translations per match)
is the implementation-free cost.
"""


def build(quick: bool) -> str:
    """Run the three tests (and the literal-drift check) and write the Markdown section."""
    trials = 10 if quick else 100
    main = campaign(scenario("source004_main"), TEST1 + TEST2[:1] + TEST2[2:], trials, jobs=2)
    starts = {
        label: campaign(scenario(f"source004_{key}"), TEST3, trials, jobs=2)
        for key, label in STARTS.items()
    }
    drift = campaign(scenario("source004_drift"), DRIFT, trials, jobs=2)
    figure = _figure(main.summary)
    parts = [f"## {TITLE}\n", INTRO, _where(), f"{trials} runs per scenario.\n"]
    parts += ["### Test 1: 1 / 2 / 3 sigma IOAP vs TERCOM (main start)\n"]
    parts += [_table(main, TEST1), _test1_verdict(main.summary)]
    parts += ["### Test 2: reference radius 1 / 1.5 / 2 / 2.5 (3 sigma, main start)\n"]
    parts += [_table(main, ["tercom", *TEST2]), _test2_verdict(main.summary)]
    parts += [f"![success rate versus l](figures/{figure})\n"]
    parts += ["### Test 3: three start points, 1.5-IOAP vs TERCOM\n"]
    parts += [_test3(starts)]
    parts += ["### D: the INS drift taken literally (accelerometer bias 1e-3 m/s^2, main start)\n"]
    parts += [_table(drift, DRIFT), _drift_verdict(drift.summary)]
    return "\n".join(parts)


def _where() -> str:
    from geofix.sim.simulate import prepare_map

    grid = prepare_map(scenario("source004_main"))
    rows = []
    for key, label in [("main", "main (tests 1, 2)"), *STARTS.items()]:
        track = scenario(f"source004_{key}").track
        col, row = track.start_cell
        end_col = col + 21800 * np.sin(np.radians(70)) / grid.dx
        end_row = row + 21800 * np.cos(np.radians(70)) / grid.dy
        values = grid.sample(*grid.cell_to_xy(np.array([col, end_col]), np.array([row, end_row])))
        rows.append(
            [label, f"({col:.0f}, {row:.0f})", f"({end_col:.0f}, {end_row:.0f})"]
            + [fmt(v, 1) for v in values]
        )
    header = ["start", "start cell (col, row)", "end cell", "g start (mGal)", "g end (mGal)"]
    text = "Start points (cells of the 100 m grid, row 0 south; track 21.8 km to N70E):\n\n"
    return text + md_table(header, rows)


def _candidates(result) -> dict:
    frame = result.frame
    samples = 110
    return {m: float(g["evaluations"].mean()) / samples for m, g in frame.groupby("method")}


def _table(result, methods: list[str]) -> str:
    rows = summary_rows({m: result.summary.methods[m] for m in methods}, LEVELS)
    cands = _candidates(result)
    rows = [[*r, fmt(cands.get(m), 0)] for r, m in zip(rows, methods, strict=True)]
    return md_table([*summary_header(LEVELS), "candidates"], rows)


def _stats(summary, method: str):
    return summary.methods[method]


def _test1_verdict(summary) -> str:
    ter, s1, s2, s3 = (_stats(summary, m) for m in TEST1)
    beats = s3.mean_error_m < ter.mean_error_m and s3.max_error_m < ter.max_error_m
    ratio2 = s2.mean_time_s / ter.mean_time_s
    ratio3 = s3.mean_time_s / ter.mean_time_s
    rank = sorted(TEST1, key=lambda m: _stats(summary, m).mean_error_m)
    return (
        f"\nRanking by mean error: {', '.join(f'`{m}`' for m in rank)}. "
        f"3-sigma-IOAP {'beats' if beats else 'does not beat'} TERCOM on both mean and worst "
        f"error ({fmt(s3.mean_error_m, 1)} / {fmt(s3.max_error_m, 0)} m against "
        f"{fmt(ter.mean_error_m, 1)} / {fmt(ter.max_error_m, 0)} m; the source says it "
        f"does). Success at 100 m: 2-sigma-IOAP {fmt(100 * s2.success_rate['100'], 0)} %, "
        f"TERCOM {fmt(100 * ter.success_rate['100'], 0)} % (source: 88 % and 82 %); "
        f"1-sigma-IOAP {fmt(100 * s1.success_rate['100'], 0)} % (the source also finds it "
        f"worse than TERCOM). Time per match relative to TERCOM: 2-sigma "
        f"{fmt(ratio2, 2)}x, 3-sigma {fmt(ratio3, 2)}x (source: about 0.5x and about 1x); "
        "IOAP scores far fewer candidates than TERCOM at 2 sigma and somewhat fewer at 3 "
        "sigma, as in the source, each a cheaper nearest-node read (TERCOM reads "
        "bilinearly). TERCOM succeeds "
        f"{fmt(100 * ter.success_rate['40'], 0)} % of the time within 40 m "
        "(the source: never): its lattice of whole-cell translations is as fine as IOAP's "
        "nodes. IOAP's larger worst errors come from runs whose true offset lies in a corner "
        "of TERCOM's square, outside the disc, and from nearest-node map reads (TERCOM reads "
        "bilinearly).\n"
    )


def _test2_verdict(summary) -> str:
    rank = sorted(TEST2, key=lambda m: _stats(summary, m).mean_error_m)
    times = ", ".join(f"`{m}` {fmt(_stats(summary, m).mean_time_s * 1e3, 1)} ms" for m in TEST2)
    same = rank == ["ioap:reference=2.5", "ioap:reference=2", "ioap", "ioap:reference=1"]
    return (
        f"\nRanking by mean error: {', '.join(f'`{m}`' for m in rank)} (source: 2.5, 2, "
        f"1.5, 1 from best to worst; {'the same order' if same else 'a different order'}). "
        "Time per match grows with the reference radius: "
        f"{times} (source: 1-IOAP fastest, 2.5-IOAP about twice TERCOM). The differences "
        "between the variants are a few metres of mean error, smaller than the run-to-run "
        "spread, and none of them beats TERCOM's mean error here: a denser outer ring "
        "rarely changes which node wins.\n"
    )


def _test3(starts: dict) -> str:
    rows = []
    for label, result in starts.items():
        ter, ioap = _stats(result.summary, "tercom"), _stats(result.summary, "ioap")
        gain_mean = 100 * (1 - ioap.mean_error_m / ter.mean_error_m)
        gain_max = 100 * (1 - ioap.max_error_m / ter.max_error_m)
        src_mean, src_max = SOURCE_TEST3[label]
        for spec, m in (("tercom", ter), ("ioap", ioap)):
            rates = [fmt(100 * m.success_rate[k], 0) for k in LEVELS]
            rows.append(
                [
                    label,
                    f"`{spec}`",
                    fmt(m.mean_error_m, 1),
                    fmt(m.std_error_m, 1),
                    fmt(m.max_error_m, 0),
                    *rates,
                    fmt(m.mean_time_s * 1e3, 1),
                    (
                        f"{fmt(gain_mean, 1)} / {fmt(gain_max, 1)} (source {src_mean} / {src_max})"
                        if spec == "ioap"
                        else ""
                    ),
                ]
            )
    header = [
        "start",
        "method",
        "mean (m)",
        "std (m)",
        "max (m)",
        *[f"≤{k} m (%)" for k in LEVELS],
        "time/match (ms)",
        "IOAP gain on mean / worst (%)",
    ]
    return (
        md_table(header, rows)
        + "\nA negative gain means IOAP is worse than TERCOM. The source's gains are all "
        "positive (13.9-40.4 % on the mean, 47.2-72.2 % on the worst error).\n"
    )


def _drift_verdict(summary) -> str:
    ter, anchor = _stats(summary, "tercom"), _stats(summary, "ioap:track_shape=anchor")
    return (
        "\nWith the drift growing along the track, every translation-only method (TERCOM "
        f"and the source's IOAP) misses by about the drift itself (TERCOM mean "
        f"{fmt(ter.mean_error_m, 0)} m). Anchoring the candidate track at the start fix "
        "(our extension; the start error is zero here) absorbs most of the bend: mean "
        f"{fmt(anchor.mean_error_m, 0)} m, worst {fmt(anchor.max_error_m, 0)} m.\n"
    )


def _figure(summary) -> str:
    from geofix.plot import success_rate_figure

    panels = {
        title: {m: {k: summary.methods[m].success_rate[k] for k in LEVELS} for m in methods}
        for methods, title in (
            (TEST1, "test 1: sigma multiple"),
            (["tercom", *TEST2], "test 2: reference radius (3 sigma)"),
        )
    }
    return save_section_figure(success_rate_figure(panels), "source004_success.png")
