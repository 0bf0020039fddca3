"""Source 001: TERCOM coarse + ICP fine, multibeam surface matching (Cheng et al., 2023)."""

from __future__ import annotations

import numpy as np

from sections._common import campaign, fmt, md_table, prose, save_section_figure, scenario

TITLE = "Source 001 — TERCOM coarse + ICP fine, multibeam surface matching"
ORDER = 40

RUNS = (("source001_gentle", "run 1, gentle"), ("source001_rugged", "run 2, rugged"))
NADIR = "tercom:beams=nadir"  # the source's TERCOM: the depth profile under the track
METHODS = (NADIR, "tercom", "tercom-icp", "tercom-icp:coarse_beams=all", "icp")
ROWS = (NADIR, "tercom-icp", "tercom", "tercom-icp:coarse_beams=all", "icp")
SOURCE_SAYS = {NADIR: "> TERCOM-ICP", "tercom-icp": "< 20"}
TRIALS, QUICK_TRIALS = 100, 3
ITERATION_TRIALS, QUICK_ITERATION_TRIALS = 10, 1
CELLS_LIMIT = 2.0  # the source's figure: mean error under 20 m = 2 cells of 10 m


def build(quick: bool) -> str:
    """Run both runs with TERCOM, TERCOM-ICP and ICP alone; compare with the source."""
    trials = QUICK_TRIALS if quick else TRIALS
    runs = {}
    for name, label in RUNS:
        scen = scenario(name)
        result = campaign(scen, list(METHODS), trials=trials, jobs=2)
        runs[label] = _run_numbers(scen, result.frame, quick)
    parts = [
        f"## {TITLE}\n",
        _intro(trials),
        _map_table(runs),
        _leg_tables(runs),
        _time_table(runs),
        _figure(runs),
        _verdict(runs),
    ]
    return "\n".join(parts)


# ---------------------------------------------------------------------- numbers
def _run_numbers(scen, frame, quick: bool) -> dict:
    """Per-leg errors, times and ICP iterations of one run."""
    from geofix.maps.terrain import terrain_stats
    from geofix.sim.simulate import prepare_map

    grid = prepare_map(scen)
    out = {"scenario": scen, "stats": terrain_stats(grid), "grid": grid, "methods": {}}
    for spec in METHODS:
        rows = frame[frame["method"] == spec]
        ok = rows[~rows["failed"].astype(bool)]
        legs = np.array([np.asarray(v, float) for v in ok["leg_errors_m"]], dtype=float)
        out["methods"][spec] = {
            "legs": legs,
            "failures": int(rows["failed"].astype(bool).sum()),
            "ms_per_match": 1e3 * rows["time_s"].sum() / max(rows["n_calls"].sum(), 1),
            "ms_median": 1e3 * float(np.median(rows["time_s"] / rows["n_calls"].clip(lower=1))),
            "ambiguous": float(rows["ambiguous"].astype(bool).mean()),
        }
    n_it = QUICK_ITERATION_TRIALS if quick else ITERATION_TRIALS
    out["iteration_trials"] = n_it
    out["iterations"] = _icp_iterations(scen, grid, n_it)
    return out


def _icp_iterations(scen, grid, n_trials: int) -> dict:
    """Mean ICP iterations of ``icp`` and ``tercom-icp`` on the first leg of some trials."""
    from geofix.evaluate.runner import method_rng
    from geofix.methods import parse_method_spec
    from geofix.sim.simulate import simulate_trial

    counts = {"icp": [], "tercom-icp": []}
    for index in range(n_trials):
        trial = simulate_trial(scen, grid, index)
        problem = trial.problem(grid, trial.leg_slices()[0])
        for spec, seen in counts.items():
            fix = parse_method_spec(spec).match(problem, method_rng(scen.seed, index, spec))
            seen.append(fix.diagnostics["iterations"])
    return {spec: float(np.mean(v)) for spec, v in counts.items()}


def _leg_mean(legs: np.ndarray) -> np.ndarray:
    return np.nanmean(legs, axis=0) if legs.size else np.full(10, np.nan)


def _overall(legs: np.ndarray) -> float:
    return float(np.nanmean(legs)) if legs.size else float("nan")


# ---------------------------------------------------------------------- text
def _intro(trials: int) -> str:
    return prose("source001_intro", trials=trials)


def _map_table(runs: dict) -> str:
    rows = []
    for label, run in runs.items():
        s, m = run["stats"], run["scenario"].map
        rows.append(
            [
                label,
                f"`{m.path}` {list(m.region)}",
                "×".join(str(v) for v in run["grid"].shape),
                fmt(s.std, 1),
                fmt(s.range, 0),
                fmt(s.mean_slope, 3),
                fmt(s.roughness, 2),
            ]
        )
    header = ["run", "map, region (lon, lat)", "cells (10 m)", "depth std (m)", "range (m)"]
    header += ["mean slope", "roughness (m/cell)"]
    return "Terrain of the two runs (statistics of the whole prepared map):\n\n" + md_table(
        header, rows
    )


def _label(spec: str) -> str:
    return f"`{spec}`"


def _leg_tables(runs: dict) -> str:
    out = []
    for label, run in runs.items():
        header = ["method", *[f"match {k}" for k in range(1, 11)], "mean", "source"]
        rows = []
        for spec in ROWS:
            legs = run["methods"][spec]["legs"]
            rows.append(
                [
                    _label(spec),
                    *[fmt(v, 1) for v in _leg_mean(legs)],
                    fmt(_overall(legs), 1),
                    SOURCE_SAYS.get(spec, "-"),
                ]
            )
        out.append(
            f"Mean error (m) at the end of each match, {label} "
            f"({len(run['methods']['tercom']['legs'])} missions):\n\n" + md_table(header, rows)
        )
    return "\n".join(out)


def _time_table(runs: dict) -> str:
    header = ["run", "method", "ms per match", "median mission (ms/match)", "ICP iterations"]
    header += ["mean error (m)", "ambiguous missions (%)", "failures"]
    rows = []
    for label, run in runs.items():
        for spec in ROWS:
            m = run["methods"][spec]
            rows.append(
                [
                    label,
                    _label(spec),
                    fmt(m["ms_per_match"], 1),
                    fmt(m["ms_median"], 1) if np.isfinite(m["ms_median"]) else "-",
                    fmt(run["iterations"].get(spec), 1),
                    fmt(_overall(m["legs"]), 1),
                    fmt(100 * m["ambiguous"], 0) if np.isfinite(m["ambiguous"]) else "-",
                    m["failures"],
                ]
            )
    return (
        "Time per match (wall clock inside `match`, two campaign workers sharing the machine "
        "with other jobs, so times are indicative). ICP iterations: mean per match over the "
        f"first leg of the first {_iteration_trials(runs)} missions. The source reports "
        "only that TERCOM-ICP takes less time than ICP alone on both runs:\n\n"
        + md_table(header, rows)
    )


def _iteration_trials(runs: dict) -> int:
    return min(run["iteration_trials"] for run in runs.values())


def _figure(runs: dict) -> str:
    from geofix.plot import leg_errors_figure

    panels = {
        label: {spec: _leg_mean(run["methods"][spec]["legs"]) for spec in (NADIR, *METHODS[1:3])}
        for label, run in runs.items()
    }
    name = save_section_figure(leg_errors_figure(panels, limit_m=20.0), "source001_legs.png")
    return f"![Per-match error of TERCOM and TERCOM-ICP](figures/{name})\n"


def _verdict(runs: dict) -> str:
    lines = ["**Against the source.**"]
    for label, run in runs.items():
        m = run["methods"]
        t, t_all, ti, icp = (_overall(m[s]["legs"]) for s in (NADIR, "tercom", "tercom-icp", "icp"))
        faster = m["tercom-icp"]["ms_per_match"] < m["icp"]["ms_per_match"]
        under = ti < CELLS_LIMIT * run["grid"].cell_size
        lines.append(
            f"- {label}: TERCOM-ICP {fmt(ti, 1)} m vs TERCOM {fmt(t, 1)} m on the nadir profile "
            f"({'better, as the source reports' if ti < t else 'NOT better: disagrees'}) and "
            f"{fmt(t_all, 1)} m on the whole swath "
            f"({'better' if ti < t_all else 'NOT better'}); "
            f"{'under' if under else 'NOT under'} 20 m (2 cells), as the source reports"
            f"{'' if under else ' -- disagrees'}; "
            f"{fmt(m['tercom-icp']['ms_per_match'], 1)} ms vs ICP alone "
            f"{fmt(m['icp']['ms_per_match'], 1)} ms per match "
            f"({'faster, as the source reports' if faster else 'NOT faster: disagrees'}); "
            f"ICP alone from the indicated track: mean error {fmt(icp, 1)} m."
        )
    lines.append(_discussion())
    return "\n".join(lines) + "\n"


def _discussion() -> str:
    return prose("source001_discussion")
