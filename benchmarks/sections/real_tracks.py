"""Real ship tracks: MGD77T depth profiles of three GNSS-era cruises against ETOPO1."""

from __future__ import annotations

import time
import warnings
from typing import NamedTuple

import numpy as np

from sections._common import ROOT, fmt, md_table, save_section_figure

TITLE = "Real ship tracks — NOAA MGD77T depth profiles against ETOPO1 at 10′"
ORDER = 92

DATA = ROOT / "benchmarks" / "data" / "mgd77"
CRUISES = ("ew0007", "ew0102", "ew0112")
WINDOWS = ((0.0, 24.0), (24.0, 12.0))
"""Segments cut from each cruise excerpt: ``(start, length)``, hours from its start."""
QUICK = {"ew0112": ((0.0, 6.0),)}
"""The ``--quick`` run: one 6 h segment."""
METHODS = ("pmf", "mpf", "pf")
#: Settings run beside the defaults on the held-out seeds: ``pf`` and ``mpf`` without
#: their per-path offsets pooled at each resampling (``offset_pool``, in particle
#: spacings; 2 by default on these profiles).
POOLED = ("pf:offset_pool=0", "mpf:offset_pool=0")
#: What each of :data:`POOLED` is, for the tables' prose.
POOLED_WHAT = (
    "each resampled particle keeps its own path's offset",
    "the same, each copy moved by the kernel",
)
SEED = 1
"""Seed of the first segment; segment ``k`` (in table order) uses ``SEED + k`` (the
filters' generators; the default INS has no random term)."""
MORE_SEEDS = 2
"""Further runs of every segment, seeds ``SEED + k + SEED_STRIDE * j`` for ``j = 1 ..``:
the filters' outcome on one track turns on their random draws, so the verdicts count
every run."""
SEED_STRIDE = 100
HELD_OUT_WINDOW = (24.0, 12.0)
"""The segment of every cruise run at :data:`HELD_OUT_SEEDS` further seeds."""
HELD_OUT_SEEDS = tuple(range(3000, 3008))
"""Seeds of the filters never run while the defaults were chosen: the verdicts on them
say how far the ones above carry to draws nobody looked at. (Seeds 1000-1007, held out
before, were run with ``pf:offset_pool=2`` and so informed ``pf``'s default; seeds
2000-2007 with ``mpf:offset_pool=2``, and so informed ``mpf``'s.)"""
WORKERS = 2
"""Processes running the further seeds."""
NEES_3SIGMA = 11.83
"""``e^T C^-1 e`` at the 99.73 % quantile of a chi-square with 2 degrees of freedom: the
2-D ellipse of the probability a 1-D 3-sigma interval holds."""
BEYOND_3SIGMA = float(np.exp(-NEES_3SIGMA / 2.0))
"""Share of pings a consistent covariance puts beyond :data:`NEES_3SIGMA` (0.27 %: a
chi-square of 2 degrees of freedom exceeds ``x`` with probability ``exp(-x / 2)``)."""

PUBLISHED = [
    ["MBARI TRN (Monterey Bay)", "AUV multibeam / DVL", "metre-scale survey maps", "≈ 3 m"],
    [
        "Wang et al., Sensors 17:2961 (2017)",
        "gravimeter, 1–2 mGal",
        "1′ gravity anomaly map",
        "≈ 2.8 nmi (5.2 km)",
    ],
    [
        "Brodovsky, `geophysical_nav` (2024–25)",
        "829 NOAA trackline segments, particle filter",
        "15″ global grid",
        "45 % recovered, ≈ 390 m mean",
    ],
]


class Segment(NamedTuple):
    """One replayed segment: its mission, map, replay result and wall time."""

    cruise: str
    start_h: float
    hours: float
    grid: object
    result: object
    seconds: float


def _segment(
    cruise: str, start_h: float, hours: float, seed: int, methods: tuple = METHODS
) -> Segment:
    from geofix.logs.mgd77 import field_segments, pick_segment
    from geofix.maps import load_grid
    from geofix.replay import replay, window_mission

    grid = load_grid(DATA / f"etopo1_10min_{cruise}.nc")
    with warnings.catch_warnings():  # the excerpts' placed times are counted in the text
        warnings.simplefilter("ignore")
        _, missions = field_segments(
            DATA / f"{cruise}_excerpt.m77t", "depth", frame=grid.meta["projection"]
        )
    mission = window_mission(pick_segment(missions, None), start_h, hours)
    t0 = time.perf_counter()
    result = replay(mission, grid, list(methods), seed=seed)
    return Segment(cruise, start_h, hours, grid, result, time.perf_counter() - t0)


def _method_stats(segment: Segment, spec: str) -> dict:
    """End / mean / max error, first fix, re-inits, share within 3 sigma, false claims."""
    from geofix.replay import nees

    result = segment.result
    ests = result.estimates[spec]
    truth = result.inputs.truth
    err = np.hypot(*(np.array([e.position for e in ests]) - truth).T)
    scores = nees(ests, truth)
    converged = np.array([e.status == "converged" for e in ests])
    row = result.summary["methods"][spec]
    return {
        "end": float(err[-1]),
        "mean": float(err.mean()),
        "max": float(err.max()),
        "first_h": None if row["converged_at_s"] is None else row["converged_at_s"] / 3600,
        "reinits": row["reinits"],
        "within": float(np.mean(scores <= NEES_3SIGMA)),
        "claims": int(converged.sum()),
        "false_claims": int(np.count_nonzero(converged & (scores > NEES_3SIGMA))),
        "worst_claim": float(scores[converged].max()) if converged.any() else 0.0,
    }


def _ins_stats(segment: Segment) -> dict:
    """The INS alone, judged by the per-axis sigma the replay gives its navigators."""
    inputs = segment.result.inputs
    err = np.hypot(*(inputs.indicated - inputs.truth).T)
    return {
        "end": float(err[-1]),
        "mean": float(err.mean()),
        "max": float(err.max()),
        "first_h": None,
        "reinits": None,
        "within": float(np.mean((err / inputs.sigma) ** 2 <= NEES_3SIGMA)),
        "claims": None,
        "false_claims": None,
        "worst_claim": None,
    }


def _km_steamed(segment: Segment) -> float:
    truth = segment.result.inputs.truth
    return float(np.hypot(*np.diff(truth, axis=0).T).sum() / 1e3)


def _rows(segments: list[Segment]) -> list[list]:
    rows = []
    for seg in segments:
        where = (
            f"{seg.cruise} {seg.start_h:g}–{seg.start_h + seg.hours:g} h "
            f"({seg.result.mission.n} pings, {_km_steamed(seg):.0f} km)"
        )
        stats = {spec: _method_stats(seg, spec) for spec in METHODS}
        stats["ins"] = _ins_stats(seg)
        for spec, s in stats.items():
            claims = "-" if s["claims"] is None else f"{s['false_claims']} / {s['claims']}"
            rows.append(
                [
                    where,
                    f"`{spec}`",
                    fmt(s["end"] / 1e3, 1),
                    fmt(s["mean"] / 1e3, 1),
                    fmt(s["max"] / 1e3, 1),
                    fmt(s["first_h"], 2),
                    "-" if s["reinits"] is None else s["reinits"],
                    fmt(100 * s["within"], 0),
                    claims,
                ]
            )
            where = ""
    return rows


HEADER = [
    "segment",
    "method",
    "end (km)",
    "mean (km)",
    "max (km)",
    "first converged (h)",
    "re-inits",
    "within 3σ (%)",
    "converged beyond 3σ / converged (pings)",
]


def _seed_stats(job: tuple) -> dict:
    """One run of a segment at a seed ``(cruise, start_h, hours, seed[, methods])``: every
    method's stats and the INS's (each method draws from its own stream, so the set run
    beside it changes none of them)."""
    seg = _segment(*job)
    stats = {spec: _method_stats(seg, spec) for spec in seg.result.estimates}
    stats["ins"] = _ins_stats(seg)
    return stats


def _more_seeds(jobs: list[tuple[str, float, float]], quick: bool) -> list[dict]:
    """Every segment's stats at its further seeds (none on a quick run)."""
    from concurrent.futures import ProcessPoolExecutor

    if quick or MORE_SEEDS < 1:
        return []
    runs = [
        (c, s, h, SEED + k + SEED_STRIDE * j)
        for j in range(1, MORE_SEEDS + 1)
        for k, (c, s, h) in enumerate(jobs)
    ]
    with ProcessPoolExecutor(max_workers=WORKERS) as pool:
        return list(pool.map(_seed_stats, runs))


def _over_seeds(segments: list[Segment], more: list[dict]) -> str:
    """Every run of every segment, per method: the verdicts of the criterion."""
    runs = _first_runs(segments) + more
    seeds = 1 + (MORE_SEEDS if more else 0)
    return (
        f"Every segment run at {seeds} seed{'s' if seeds > 1 else ''} of the filters "
        f"({len(runs)} runs per method; the table above shows the first):\n\n"
        + _runs_table(runs)
        + "\n"
    )


def _held_out(quick: bool) -> list[dict]:
    """The held-out segment of every cruise at every held-out seed (none on a quick run)."""
    from concurrent.futures import ProcessPoolExecutor

    if quick or not HELD_OUT_SEEDS:
        return []
    runs = [
        (c, *HELD_OUT_WINDOW, seed, METHODS + POOLED) for seed in HELD_OUT_SEEDS for c in CRUISES
    ]
    with ProcessPoolExecutor(max_workers=WORKERS) as pool:
        return list(pool.map(_seed_stats, runs))


def _held_out_part(held: list[dict]) -> str:
    if not held:
        return ""
    start, hours = HELD_OUT_WINDOW
    return (
        f"Held out: the {start:g}–{start + hours:g} h segment of every cruise at "
        f"{len(HELD_OUT_SEEDS)} further seeds of the filters "
        f"({HELD_OUT_SEEDS[0]}–{HELD_OUT_SEEDS[-1]}), never run while the defaults were "
        f"chosen (seeds 1000–1007, held out before, were run with `pf:offset_pool=2` and "
        f"so informed `pf`'s default, seeds 2000–2007 with `mpf:offset_pool=2` and so "
        f"informed `mpf`'s; {len(held)} runs per method), the defaults and "
        "beside them "
        f"{pooled_settings()}:\n\n" + _runs_table(held, METHODS + POOLED) + "\n"
    )


def pooled_settings() -> str:
    """The settings of :data:`POOLED`, each with what it does (Markdown)."""
    return " and ".join(f"`{m}` ({what})" for m, what in zip(POOLED, POOLED_WHAT, strict=True))


def _first_runs(segments: list[Segment]) -> list[dict]:
    """The stats of every method and the INS on each segment at its first seed."""
    return [
        {**{spec: _method_stats(s, spec) for spec in METHODS}, "ins": _ins_stats(s)}
        for s in segments
    ]


def _runs_table(runs: list[dict], methods: tuple = METHODS) -> str:
    """Per method over ``runs``: the criterion's verdicts."""
    rows = []
    for spec in methods:
        ratio = [r[spec]["end"] / r["ins"]["end"] for r in runs]
        claims = sum(r[spec]["claims"] for r in runs)
        rows.append(
            [
                f"`{spec}`",
                f"{sum(x < 1.0 for x in ratio)} of {len(runs)}",
                fmt(float(np.median(ratio)), 2),
                fmt(max(ratio), 2),
                f"{sum(r[spec]['false_claims'] for r in runs)} / {claims}",
                fmt(BEYOND_3SIGMA * claims, 1),
                fmt(max(r[spec]["worst_claim"] for r in runs), 1),
                fmt(100 * min(r[spec]["within"] for r in runs), 0),
            ]
        )
    header = [
        "method",
        "ends better than the INS",
        "median end / INS end",
        "worst end / INS end",
        "converged beyond 3σ / converged (pings)",
        "beyond 3σ a consistent covariance would show (pings)",
        "largest NEES claimed converged",
        "lowest within 3σ (%)",
    ]
    return md_table(header, rows)


def _verdicts(segments: list[Segment]) -> str:
    lines = []
    for spec in METHODS:
        better = sum(
            _method_stats(s, spec)["end"] < _ins_stats(s)["end"] for s in segments
        )  # fmt: skip
        false = sum(_method_stats(s, spec)["false_claims"] for s in segments)
        lines.append(
            f"- `{spec}` ends better than the INS alone on {better} of {len(segments)} "
            f"segments; {false} pings claimed `converged` with the error beyond 3σ."
        )
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------- figure
def _figure(cruise: str, segments: list[Segment]) -> str:
    """Track on the map beside each method's error against time with its 3-sigma band."""
    from geofix.plot.figures import pyplot

    plt = pyplot()
    fig = plt.figure(figsize=(13, 7.5))
    grid = segments[0].grid
    ax_map = fig.add_subplot(1, 2, 1)
    west, east, south, north = (v / 1e3 for v in grid.extent)
    image = ax_map.imshow(
        grid.values, origin="lower", extent=(west, east, south, north), cmap="viridis"
    )
    fig.colorbar(image, ax=ax_map, shrink=0.6, label="ETOPO1 elevation, m")
    axes = [fig.add_subplot(len(METHODS), 2, 2 * (k + 1)) for k in range(len(METHODS))]
    colours = dict(zip(METHODS, ("tab:orange", "tab:green", "tab:purple"), strict=True))
    for n, seg in enumerate(segments):
        _draw_segment(ax_map, axes, seg, colours, label=n == 0)
    ax_map.set_xlabel("x east, km")
    ax_map.set_ylabel("y north, km")
    _zoom(ax_map, np.vstack([s.result.inputs.truth for s in segments]) / 1e3)
    ax_map.set_aspect("equal")
    ax_map.legend(loc="best", fontsize=8)
    for ax, spec in zip(axes, METHODS, strict=True):
        ax.set_ylabel(f"{spec} error, km")
        ax.set_ylim(bottom=0)
        ax.legend(loc="upper left", fontsize=7)
    axes[-1].set_xlabel("hours from the excerpt's start")
    fig.suptitle(f"{cruise}: depth profile against ETOPO1 10′, INS drift simulated on GNSS")
    fig.tight_layout()
    name = save_section_figure(fig, f"real_tracks_{cruise}.png")
    plt.close(fig)
    return name


def _zoom(ax, xy_km: np.ndarray, margin_km: float = 60.0) -> None:
    """Limit the map axes to the track plus ``margin_km`` kilometres each side."""
    low, high = xy_km.min(axis=0) - margin_km, xy_km.max(axis=0) + margin_km
    ax.set_xlim(low[0], high[0])
    ax.set_ylim(low[1], high[1])


def _draw_segment(ax_map, axes, seg: Segment, colours: dict, label: bool) -> None:
    inputs = seg.result.inputs
    hours = seg.start_h + np.asarray(seg.result.mission.times) / 3600.0
    ax_map.plot(*(inputs.truth.T / 1e3), "k-", lw=2, label="GNSS track" if label else None)
    ax_map.plot(*(inputs.indicated.T / 1e3), "r--", lw=1, label="INS" if label else None)
    ins_err = np.hypot(*(inputs.indicated - inputs.truth).T) / 1e3
    for ax, spec in zip(axes, METHODS, strict=True):
        ests = seg.result.estimates[spec]
        track = np.array([e.position for e in ests])
        ax_map.plot(
            *(track.T / 1e3), "-", lw=0.8, color=colours[spec], label=spec if label else None
        )
        err = np.hypot(*(track - inputs.truth).T) / 1e3
        band = 3.0 * np.sqrt([np.linalg.eigvalsh(e.covariance)[-1] for e in ests]) / 1e3
        ax.fill_between(hours, 0.0, band, color=colours[spec], alpha=0.25,
                        label="3σ (largest axis)" if label else None)  # fmt: skip
        ax.plot(hours, err, color=colours[spec], lw=1,
                label=f"{spec} error" if label else None)  # fmt: skip
        ax.plot(hours, ins_err, "r--", lw=0.8, label="INS" if label else None)
        ax.axvline(seg.start_h, color="grey", lw=0.5)


# ---------------------------------------------------------------------- text
def _intro(segments: list[Segment]) -> str:
    from geofix.replay import DEFAULT_INS

    ins = DEFAULT_INS
    return f"""\
geofix's first navigation on real measurements against a map made by others. Three
cruises of R/V Maurice Ewing (NOAA NCEI MGD77T trackline files, public domain): EW0007
(2000, NW Atlantic, 41–43° N 66–57° W), EW0102 (2001, off Cape Hatteras, 33° N 75–67° W)
and EW0112 (2001, off Western Australia, 32–30° S 108–115° E). From each, a 36 h excerpt
of deep-water transit (the 36 h with the most distance steamed and every depth below
1000 m) is bundled in `benchmarks/data/mgd77/` with provenance; segments of
{", ".join(f"{s:g}–{s + h:g} h" for s, h in WINDOWS)} are cut from it (`geofix replay
EXCERPT --map CROP --field depth --start-h S --hours H`). The measurement is the ship's
corrected centre-beam depth (`CORR_DEPTH`, one a minute, one beam per ping); the prior map
is ETOPO1 at 10 arc-minutes (≈ 15–17 km cells; fatiando/data's global grid, public
domain), cropped 1.5° around each excerpt. No bundled cruise crosses the bundled Azores
1′ grid (lon −33…−23, lat 35.5…43), so ETOPO1 is the only prior here.

The ship's GNSS track (2000–2001, after selective availability ended: ≈ 10 m) is the
truth. An INS drift is simulated on it by `geofix.replay` with the `geofix replay`
defaults, a free inertial navigator: velocity error {ins["velocity_error_m_s"]:g} m/s,
heading error {ins["heading_error_deg"]:g}°, gyro drift {ins["gyro_bias_deg_h"]:g}°/h, no
initial error. These numbers have no random term, so the INS drift is the same on every
segment of a length (the seed, {SEED} + `k` for segment `k` of the table, drives the
filters). No DVL-aided INS is run here. `pmf`, `mpf` and `pf` run with
their default settings (`map_model=imperfect`, the navigator's default noise), each in its
own `geofix.Navigator`, one ping at a time.

Columns: errors against the GNSS track (km); `first converged` the first ping the
navigator reports `converged` (hours from the segment's start); `within 3σ` the share of
pings whose error lies inside the reported covariance's 99.73 % ellipse
(`e^T C^-1 e <= {NEES_3SIGMA}`, the 2-D 3σ; for the INS, against the per-axis sigma the
replay gives the navigators); the last column the pings claimed `converged` while their
error lies outside that ellipse, out of all `converged` pings.
"""


def _map_error(cruise: str) -> dict:
    """The grid's error along the whole excerpt's GNSS track, and what the filters see of it.

    ``error``: the readings less the grid at the GNSS track, its mean removed (m rms);
    ``layer``: the grid's own representation layer there (median, m); ``floor``: the
    relief the readings show and the grid lacks, as the filters measure it along the
    track (:class:`geofix.filters.nuisance.ProfileRoughness`, median after its first
    window, m); ``shown``: the grid's own relief over the same windows, measured alike
    (median, m).
    """
    from geofix.filters.nuisance import (
        ROUGHNESS_WINDOW_CELLS,
        ProfileRoughness,
        representation_std,
    )
    from geofix.logs.mgd77 import field_segments, pick_segment
    from geofix.maps import load_grid

    grid = load_grid(DATA / f"etopo1_10min_{cruise}.nc")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, missions = field_segments(
            DATA / f"{cruise}_excerpt.m77t", "depth", frame=grid.meta["projection"]
        )
    mission = pick_segment(missions, None)
    xy, depth = mission.nav, mission.beams[:, 0, 2]
    on_grid = grid.sample(xy[:, 0], xy[:, 1])
    error = depth - on_grid
    window = ROUGHNESS_WINDOW_CELLS * grid.cell_size
    steps = np.r_[0.0, np.hypot(*np.diff(xy, axis=0).T)]
    state, floors = ProfileRoughness.empty(), []
    grid_relief, shown = ProfileRoughness.empty(), []
    for k in range(len(depth)):
        step = None if k == 0 else steps[k]
        state = state.updated(step, depth[k], on_grid[k], window)
        grid_relief = grid_relief.updated(step, on_grid[k], 0.0, window)
        floors.append(state.variance)
        shown.append(grid_relief.variance)
    first = int(np.searchsorted(np.cumsum(steps), window))
    layer = representation_std(grid).sample(xy[:, 0], xy[:, 1])
    return {
        "cell_km": grid.cell_size / 1e3,
        "error": float(np.std(error)),
        "layer": float(np.median(layer)),
        "floor": float(np.sqrt(np.median(floors[first:]))),
        "shown": float(np.sqrt(np.median(shown[first:]))),
    }


def _map_errors_table() -> str:
    rows = []
    for cruise in CRUISES:
        m = _map_error(cruise)
        rows.append(
            [
                cruise,
                fmt(m["cell_km"], 1),
                fmt(m["error"], 0),
                fmt(m["layer"], 0),
                fmt(m["shown"], 0),
                fmt(m["floor"], 0),
            ]
        )
    header = [
        "excerpt",
        "cell (km)",
        "grid error at the GNSS track (m rms)",
        "grid's own layer there (m, median)",
        "grid's relief over four cells (m, median)",
        "relief the readings show and the grid lacks (m, median)",
    ]
    return md_table(header, rows)


def _reading(
    cells_m: list[float], segments: list[Segment], more: list[dict], held: list[dict]
) -> str:
    low, high = min(cells_m) / 1e3, max(cells_m) / 1e3
    runs = _first_runs(segments) + more
    false = sum(r[spec]["false_claims"] for r in runs for spec in METHODS)
    better = sum(r[spec]["end"] < r["ins"]["end"] for r in runs for spec in METHODS)
    total = len(runs) * len(METHODS)
    claims = (
        "no filter claims `converged` while its error lies beyond 3σ"
        if false == 0
        else f"{false} pings are still claimed `converged` with the error beyond 3σ"
    )
    claims += _held_out_claims(held)
    return f"""\
How to read it. The grid's error at the ship's true track, beside what the filters can see
of it:

{_map_errors_table()}
ETOPO1 at 10′ is smoothed: over four cells of track ({4 * low:.0f}–{4 * high:.0f} km) it
shows almost none of the relief the echosounder reads, and its own layer (from its
curvature) is several times smaller than its error. The default filters take the relief
the readings show and the grid lacks as a floor under each ping's map-error variance,
counted once over the window; it does not depend on where a filter thinks it is, so it
holds from the first pings. Each ping then carries little: the filters follow the INS
within a covariance that holds their error, and gain on it where the grid's relief is
the seabed's at the scales it resolves. Over every run, {better} of {total} end better
than the INS alone and {claims}. Errors on the order of the maps' cells
({low:.1f}–{high:.1f} km) are what a map this coarse can give at best; the section
measures the pipeline on real tracks and an independent prior, and the honesty of the
claims, not an accuracy to compare with the finer maps of the other sections.
"""


def _held_out_claims(held: list[dict]) -> str:
    """What the held-out runs add to the reading of the claims ('' without them)."""
    if not held:
        return ""
    bad = {spec: sum(r[spec]["false_claims"] for r in held) for spec in METHODS}
    if not any(bad.values()):
        return "; on the held-out seeds none does either"
    said = ", ".join(
        f"`{spec}` {bad[spec]} of {sum(r[spec]['claims'] for r in held)} "
        f"(in {sum(r[spec]['false_claims'] > 0 for r in held)} of {len(held)} runs)"
        for spec in METHODS
        if bad[spec]
    )
    worst = max(r[spec]["worst_claim"] for r in held for spec in METHODS if bad[spec])
    return (
        f"; on the held-out seeds some do: {said} pings claimed `converged` with the "
        "error beyond 3σ, so that verdict does not yet carry to every draw. A covariance "
        f"that keeps its promise puts {100 * BEYOND_3SIGMA:.2f} % of its pings there, so a "
        "few are expected; the count alone does not convict. The largest NEES claimed "
        f"`converged` does: {worst:.1f}, which a consistent 2-D covariance exceeds with "
        f"probability {np.exp(-worst / 2):.0e} per ping, is an error the covariance did "
        "not hold"
    )


def _pre_gnss() -> str:
    return """
**Why the 1973 and 1979 cruises are not used.** The other two cruises of the data set,
WI933014 (1973) and 78123006 (1979), were navigated before GNSS, by Transit satellite fixes
hours apart and dead reckoning between them: their positions are good to hundreds of
metres to kilometres (`geofix.logs.read_mgd77` tags them `pre-gnss`, ≈ 500 m), drift
between fixes like an INS, and jump at each fix. A truth that is itself a drifting
estimate cannot score an estimator whose errors against a 10′ map are of the same order;
they are read (every cruise reads) but not used as truth.
"""


def _published() -> str:
    table = md_table(["source", "measurement", "prior map", "reported"], PUBLISHED)
    return f"""
**Published figures beside ours.**

{table}
These are not like for like. MBARI's maps are surveys at metre scale of the same seabed
the vehicle's multibeam sees; Wang et al. navigate on gravity with a 1′ map; Brodovsky's
particle filter reads a 15″ grid (≈ 40× finer in area than 10′) over 829 segments.
Here a single centre-beam depth a minute reads a 10′ global grid whose cells are wider
than the terrain features a depth profile resolves; the table above is what defaults give
on that map.
"""


def build(quick: bool) -> str:
    """The section's Markdown (figures to ``docs/figures/``)."""
    plan = QUICK if quick else {c: WINDOWS for c in CRUISES}
    t0 = time.perf_counter()
    jobs = [(c, s, h) for c, windows in plan.items() for s, h in windows]
    done = [_segment(c, s, h, SEED + k) for k, (c, s, h) in enumerate(jobs)]
    more = _more_seeds(jobs, quick)
    held = _held_out(quick)
    by_cruise = {c: [seg for seg in done if seg.cruise == c] for c in plan}
    segments = [s for segs in by_cruise.values() for s in segs]
    figures = {c: _figure(c, segs) for c, segs in by_cruise.items()}
    elapsed = time.perf_counter() - t0
    text = f"## {TITLE}\n\n{_intro(segments)}\n"
    text += md_table(HEADER, _rows(segments)) + "\n"
    text += _verdicts(segments) + "\n" + _over_seeds(segments, more) + "\n"
    text += _held_out_part(held)
    text += _reading([s.grid.cell_size for s in segments], segments, more, held) + "\n"
    for cruise, name in figures.items():
        text += f"![{cruise}: track on the map, error against time](figures/{name})\n\n"
    text += _pre_gnss() + _published()
    replay_s = sum(s.seconds for s in segments)
    text += (
        f"\n{len(segments)} segments, {sum(s.result.mission.n for s in segments)} pings, "
        f"{len(METHODS)} filters: {replay_s:.0f} s of replay at the first seed "
        f"({elapsed:.0f} s in all, the further and held-out seeds in {WORKERS} processes).\n"
    )
    return text
