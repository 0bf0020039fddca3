"""Real ship tracks, gravity: the ships' free-air anomaly against EIGEN-6C4, alone and fused."""

from __future__ import annotations

import time
import warnings

import numpy as np

from sections._common import fmt, md_table, save_section_figure
from sections.real_tracks import (
    CRUISES,
    DATA,
    METHODS,
    MORE_SEEDS,
    NEES_3SIGMA,
    POOLED,
    QUICK,
    SEED,
    SEED_STRIDE,
    WINDOWS,
    WORKERS,
    Segment,
    _ins_stats,
    _method_stats,
    _runs_table,
    pooled_settings,
)

TITLE = "Real ship tracks, gravity — the ships' anomaly against EIGEN-6C4, alone and with depth"
ORDER = 93

#: The field sets replayed: gravity alone, and depth (the primary) with gravity.
FIELD_SETS = (("gravity",), ("depth", "gravity"))
#: The method whose error the figure draws.
FIGURE_METHOD = "pmf"


def _gravity_map(cruise: str):
    from geofix.maps import load_grid

    return load_grid(DATA / f"eigen6c4_10min_{cruise}.nc")


def _segment(cruise: str, start_h: float, hours: float, seed: int, fields) -> Segment:
    """One segment replayed with ``fields`` (the first the primary), every method."""
    from geofix.logs.mgd77 import field_segments, joint_segments, pick_segment
    from geofix.maps import load_grid
    from geofix.replay import replay, window_mission

    gravity = _gravity_map(cruise)
    depth = load_grid(DATA / f"etopo1_10min_{cruise}.nc")
    primary = gravity if fields[0] == "gravity" else depth
    path = DATA / f"{cruise}_excerpt.m77t"
    frame = primary.meta["projection"]
    with warnings.catch_warnings():  # the excerpts' placed times are counted in the text
        warnings.simplefilter("ignore")
        if len(fields) == 1:
            _, missions = field_segments(path, fields[0], frame=frame)
        else:
            _, missions = joint_segments(path, list(fields), frame=frame)
    mission = window_mission(pick_segment(missions, None), start_h, hours)
    further = (gravity,) if len(fields) > 1 else ()
    t0 = time.perf_counter()
    methods = [*METHODS, *POOLED]  # each its own random stream: the defaults' runs unchanged
    result = replay(mission, primary, methods, seed=seed, field_grids=further)
    return Segment(cruise, start_h, hours, primary, result, time.perf_counter() - t0)


def _stats(job) -> dict:
    """One run: every method's stats and the INS's, and the figure's series (a pool's task)."""
    seg = _segment(*job)
    stats = {spec: _method_stats(seg, spec) for spec in seg.result.estimates}
    stats["ins"] = _ins_stats(seg)
    stats["series"] = _series(seg)
    return stats


def _series(seg: Segment) -> dict:
    """Hours, the INS's error and :data:`FIGURE_METHOD`'s error and 3-sigma, km."""
    inputs = seg.result.inputs
    ests = seg.result.estimates[FIGURE_METHOD]
    track = np.array([e.position for e in ests])
    return {
        "hours": seg.start_h + np.asarray(seg.result.mission.times) / 3600.0,
        "ins": np.hypot(*(inputs.indicated - inputs.truth).T) / 1e3,
        "error": np.hypot(*(track - inputs.truth).T) / 1e3,
        "band": 3.0 * np.sqrt([np.linalg.eigvalsh(e.covariance)[-1] for e in ests]) / 1e3,
    }


def _figure(runs: dict) -> str:
    """Error against time at each segment's first seed: INS, gravity, depth + gravity."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    first = {
        fields: {job[:3]: stats["series"] for job, stats in done if job[3] < SEED + SEED_STRIDE}
        for fields, done in runs.items()
    }
    cruises = sorted({key[0] for series in first.values() for key in series})
    fig, axes = plt.subplots(len(cruises), 1, figsize=(10, 2.6 * len(cruises)), squeeze=False)
    colours = dict(zip(FIELD_SETS, ("tab:green", "tab:blue"), strict=True))
    for ax, cruise in zip(axes[:, 0], cruises, strict=True):
        for n, (fields, series) in enumerate(first.items()):
            for key, one in sorted(series.items()):
                if key[0] != cruise:
                    continue
                label = _label(fields) if key[1] == 0 or len(series) == 1 else None
                ax.fill_between(one["hours"], 0.0, one["band"], color=colours[fields],
                                alpha=0.15)  # fmt: skip
                ax.plot(one["hours"], one["error"], color=colours[fields], lw=1, label=label)
                if n == 0:
                    ax.plot(one["hours"], one["ins"], "r--", lw=0.8,
                            label="INS" if label else None)  # fmt: skip
                    ax.axvline(one["hours"][0], color="grey", lw=0.5)
        ax.set_title(f"{cruise}: `{FIGURE_METHOD}` error (line) and its 3σ (band)", fontsize=9)
        ax.set_ylabel("km")
    axes[-1, 0].set_xlabel("hours into the excerpt")
    axes[0, 0].legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    name = save_section_figure(fig, "real_tracks_gravity.png")
    plt.close(fig)
    return f"![Gravity and depth + gravity: error against time](figures/{name})\n"


def _runs(quick: bool) -> dict:
    """``{fields: [(job, stats), ...]}``: every segment at every seed, per field set."""
    from concurrent.futures import ProcessPoolExecutor

    plan = QUICK if quick else {c: WINDOWS for c in CRUISES}
    windows = [(c, s, h) for c, ws in plan.items() for s, h in ws]
    seeds = 1 if quick else 1 + MORE_SEEDS
    jobs = [
        (c, s, h, SEED + k + SEED_STRIDE * j, fields)
        for fields in FIELD_SETS
        for j in range(seeds)
        for k, (c, s, h) in enumerate(windows)
    ]
    with ProcessPoolExecutor(max_workers=WORKERS) as pool:
        done = list(pool.map(_stats, jobs))
    out: dict = {fields: [] for fields in FIELD_SETS}
    for job, stats in zip(jobs, done, strict=True):
        out[job[-1]].append((job, stats))
    return out


def _label(fields) -> str:
    return " + ".join(fields)


def _first_seed_table(runs: dict) -> str:
    """Per segment at its first seed: each field set's methods beside the INS."""
    rows = []
    for fields, done in runs.items():
        for job, stats in done:
            cruise, start, hours, seed, _ = job
            if seed >= SEED + SEED_STRIDE:
                continue
            where = f"{cruise} {start:g}–{start + hours:g} h"
            ins = stats["ins"]["end"]
            for spec in METHODS:
                s = stats[spec]
                rows.append(
                    [
                        where,
                        _label(fields),
                        f"`{spec}`",
                        fmt(s["end"] / 1e3, 1),
                        fmt(s["end"] / ins, 2),
                        fmt(100 * s["within"], 0),
                        f"{s['false_claims']} / {s['claims']}",
                    ]
                )
            rows.append([where, _label(fields), "`ins`", fmt(ins / 1e3, 1), "1.00", "", ""])
    header = [
        "segment",
        "fields",
        "method",
        "end (km)",
        "end / INS end",
        "within 3σ (%)",
        "converged beyond 3σ / converged (pings)",
    ]
    return md_table(header, rows)


def _level(cruise: str) -> dict:
    """The ship's anomaly against the model at the GNSS track: level, scatter, likeness."""
    from geofix.logs.mgd77 import field_segments, pick_segment

    grid = _gravity_map(cruise)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, missions = field_segments(
            DATA / f"{cruise}_excerpt.m77t", "gravity", frame=grid.meta["projection"]
        )
    mission = pick_segment(missions, None)
    xy, read = mission.nav, mission.beams[:, 0, 2]
    model = grid.sample(xy[:, 0], xy[:, 1])
    ok = np.isfinite(read) & np.isfinite(model)
    diff = read[ok] - model[ok]
    return {
        "level": float(diff.mean()),
        "scatter": float(diff.std()),
        "read": float(read[ok].std()),
        "model": float(model[ok].std()),
        "corr": float(np.corrcoef(read[ok], model[ok])[0, 1]),
        "stated": grid.stated_offset_std,
    }


def _levels_table() -> tuple[str, float]:
    rows, stated = [], float("nan")
    for cruise in CRUISES:
        m = _level(cruise)
        stated = m["stated"]
        rows.append(
            [
                cruise,
                fmt(m["level"], 1),
                fmt(m["scatter"], 1),
                fmt(m["read"], 1),
                fmt(m["model"], 1),
                fmt(m["corr"], 2),
            ]
        )
    header = [
        "excerpt",
        "ship less model, mean (mGal)",
        "about that mean (mGal rms)",
        "ship's anomaly (mGal rms)",
        "model at the track (mGal rms)",
        "correlation",
    ]
    return md_table(header, rows), stated


def _intro(stated: float, levels: str) -> str:
    return f"""\
The same excerpts, segments and INS drift as the depth section above, now with the
ships' free-air gravity anomaly (`FREEAIR`, one a minute) against a gravity model made by
others: EIGEN-6C4 (GFZ, ICGEM; CC-BY 4.0) as fatiando/data grids it at 10 arc-minutes and
10 km above the ellipsoid, turned into a free-air anomaly there by WGS84's normal gravity
at the geoid height below (boule), and cropped to the depth crops' nodes
(`benchmarks/data/mgd77/eigen6c4_10min_*.nc`, provenance beside them). It is not the
sea-level anomaly a ship reads: 10 km of upward continuation smooths out what is shorter
than some tens of kilometres, and its level is not the ships' (reference formula, datum,
base ties). Each file states that level's 1-sigma as its `offset_std` attribute
({stated:g} mGal, fixed from that budget before any replay), which the filters take as the
prior of their common offset in place of the gravity default (5 mGal, a tied sea-level
grid's). At the GNSS track:

{levels}
Each segment is replayed with the gravity alone and with depth and gravity in one filter
(`geofix replay --field depth --field gravity`: the ETOPO1 crop for the depth, this model
for the gravity, each field with its own offset, scale and representation error), every
method at its default settings (the gravity's noise 1-sigma 2 mGal: the navigator's
default, and the replay's for a further field).
"""


def _reading(runs: dict) -> str:
    lines = []
    for fields, done in runs.items():
        stats = [s for _, s in done]
        for spec in METHODS:
            better = sum(s[spec]["end"] < s["ins"]["end"] for s in stats)
            bad = sum(s[spec]["false_claims"] for s in stats)
            claims = sum(s[spec]["claims"] for s in stats)
            lines.append(
                f"- {_label(fields)}, `{spec}`: ends better than the INS alone in {better} "
                f"of {len(stats)} runs; {bad} of {claims} `converged` pings beyond 3σ."
            )
    return "\n".join(lines) + "\n"


def build(quick: bool) -> str:
    """The section's Markdown."""
    t0 = time.perf_counter()
    runs = _runs(quick)
    levels, stated = _levels_table()
    text = f"## {TITLE}\n\n{_intro(stated, levels)}\n"
    text += "At the first seed of each segment:\n\n" + _first_seed_table(runs) + "\n"
    seeds = 1 if quick else 1 + MORE_SEEDS
    for fields, done in runs.items():
        text += (
            f"{_label(fields)}, every segment at {seeds} seed{'s' if seeds > 1 else ''} "
            f"({len(done)} runs per method; beside the defaults "
            f"{pooled_settings()}, as in the depth section's held-out runs):\n\n"
            + _runs_table([s for _, s in done], METHODS + POOLED)
            + "\n"
        )
    text += _reading(runs) + "\n" + _figure(runs)
    text += (
        f"\nColumns as in the depth section (`within 3σ`: `e^T C^-1 e <= {NEES_3SIGMA}`). "
        f"{time.perf_counter() - t0:.0f} s in all, in {WORKERS} processes.\n"
    )
    return text
