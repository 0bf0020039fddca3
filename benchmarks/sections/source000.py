"""Source 000: multibeam matching by GA with sine-cosine refinement (Zhang et al., 2022)."""

from __future__ import annotations

import time

import numpy as np

from sections._common import campaign, fmt, md_table, prose, scenario

TITLE = "Source 000 — multibeam matching by GA + sine–cosine refinement, vs multipath ICCP"
ORDER = 30

K = 20.0  # every length of the source's experiment is multiplied by 20 (see the scenarios)
MU1 = f"{2 * K:g}"  # mu1 = 2 source metres, scaled; mu2 = 2 m/m is scale-free
GA = f"ga-sca:mu1={MU1}"
MULTIPATH = f"iccp-multipath:mu1={MU1}"
METHODS = (GA, MULTIPATH, "iccp")
TRACKS = (("a", "A"), ("b", "B"))
ERRORS = (30, 150)
TRIALS, QUICK_TRIALS = 50, 2
ABLATION_TRIALS, QUICK_ABLATION_TRIALS = 50, 2
SQUARE = 400.0  # side of the square (source metres) on which terrain statistics are taken

SOURCE_TERRAIN = {  # Table 1: deepest, shallowest, mean, range, std (m)
    "A": (-41.64, -33.51, -36.82, 8.13, 1.45),
    "B": (-48.39, -31.38, -41.68, 17.01, 3.32),
}
SOURCE_TABLE3 = {  # (method, track, error) -> (mean, max) metres
    ("ga-sca", "A", 30): (2.22, 2.97),
    ("ga-sca", "A", 150): (2.23, 2.97),
    ("ga-sca", "B", 30): (1.99, 3.46),
    ("ga-sca", "B", 150): (2.01, 3.45),
    ("iccp-multipath", "A", 30): (5.32, 13.70),
    ("iccp-multipath", "A", 150): (15.65, 34.05),
    ("iccp-multipath", "B", 30): (4.27, 9.33),
    ("iccp-multipath", "B", 150): (9.68, 20.12),
}
SOURCE_TABLE4 = {  # variant -> (mean error m, iterations, time s)
    "A": (2.54, 346.12, 8.01),
    "B": (3.05, 499.82, 9.81),
    "C": (3.83, 373.48, 10.21),
    "D": (4.41, 534.75, 14.63),
}
VARIANT_TEXT = {
    "A": "full: GA + new fitness + SCA",
    "B": "GA + new fitness",
    "C": "GA + SCA (plain fitness)",
    "D": "plain GA, summed absolute differences",
}


def build(quick: bool) -> str:
    """Run Tables 1, 3 and 4 of the source on the scaled deep-sea stand-in."""
    trials = QUICK_TRIALS if quick else TRIALS
    table3 = {}
    for key, label in TRACKS:
        for err in ERRORS:
            result = campaign(scenario(f"source000_{key}_{err}"), list(METHODS), trials, jobs=2)
            table3[(label, err)] = _campaign_numbers(result.frame)
    ablation = _ablation(QUICK_ABLATION_TRIALS if quick else ABLATION_TRIALS)
    parts = [
        f"## {TITLE}\n",
        _intro(trials),
        _terrain_table(),
        _table3(table3, trials),
        _table4(ablation),
        _verdict(table3, ablation),
    ]
    return "\n".join(parts)


# ---------------------------------------------------------------------- numbers
def _campaign_numbers(frame) -> dict:
    """Per method: mean of the per-trial track mean and max errors, worst, time (source m)."""
    out = {}
    for spec in METHODS:
        rows = frame[frame["method"] == spec]
        ok = rows[~rows["failed"].astype(bool)]
        out[spec] = {
            "mean": float(ok["mean_track_error_m"].mean()) / K,
            "median": float(ok["mean_track_error_m"].median()) / K,
            "max": float(ok["max_track_error_m"].mean()) / K,
            "worst": float(ok["max_track_error_m"].max()) / K,
            "failures": int(rows["failed"].astype(bool).sum()),
            "ambiguous": float(rows["ambiguous"].astype(bool).mean()),
            "ms": 1e3 * float(rows["time_s"].sum() / max(rows["n_calls"].sum(), 1)),
        }
    return out


def _ablation(n_trials: int) -> dict:
    """Table 4: variants A-D on track A, (150, 150) m; errors, iterations and times."""
    from geofix.evaluate.runner import method_rng
    from geofix.methods import parse_method_spec
    from geofix.sim.simulate import prepare_map, simulate_trial

    scen = scenario("source000_a_150")
    grid = prepare_map(scen)
    trials = [simulate_trial(scen, grid, i) for i in range(n_trials)]
    out = {}
    for variant in "ABCD":
        spec = f"ga-sca:variant={variant},mu1={MU1}"
        method = parse_method_spec(spec)
        errors, iterations, times = [], [], []
        for trial in trials:
            rng = method_rng(scen.seed, trial.index, spec)
            start = time.perf_counter()
            fix = method.match(trial.problem(grid), rng)
            times.append(time.perf_counter() - start)
            errors.append(float(np.hypot(*(fix.track - trial.truth).T).mean()) / K)
            iterations.append(fix.diagnostics["iterations"])
        out[variant] = {
            "mean": float(np.mean(errors)),
            "median": float(np.median(errors)),
            "iterations": float(np.mean(iterations)),
            "time": float(np.mean(times)),
        }
    return out


def _terrain_rows() -> list[list]:
    """Statistics of the SQUARE x SQUARE source-metre square centred on each track."""
    from geofix.sim.simulate import prepare_map, start_position

    rows = []
    for key, label in TRACKS:
        scen = scenario(f"source000_{key}_30")
        grid = prepare_map(scen)
        x0, y0 = start_position(scen, grid)
        psi = np.radians(scen.track.heading_deg)
        half_track = 0.5 * scen.track.speed_m_s * scen.track.interval_s * (scen.track.samples - 1)
        cx, cy = x0 + half_track * np.sin(psi), y0 + half_track * np.cos(psi)
        half = 0.5 * SQUARE * K
        inside = (np.abs(grid.x - cx) <= half)[None, :] & (np.abs(grid.y - cy) <= half)[:, None]
        z = grid.values[inside]
        z = z[np.isfinite(z)]
        src = SOURCE_TERRAIN[label]
        rows.append(
            [
                label,
                f"{fmt(src[3])} / {fmt((z.max() - z.min()) / K)}",
                f"{fmt(src[4])} / {fmt(z.std() / K)}",
                f"{fmt(src[2])} / {fmt(z.mean(), 0)}",
            ]
        )
    return rows


# ---------------------------------------------------------------------- text
def _intro(trials: int) -> str:
    return prose("source000_intro", trials=trials, GA=GA, MULTIPATH=MULTIPATH, K=f"{K:g}")


def _terrain_table() -> str:
    header = ["terrain", "range (m)", "std (m)", "mean depth (m, unscaled)"]
    note = (
        "\n_Source / ours over a 400 × 400 source-metre square centred on the track; our "
        "range and std divided by k = 20, our mean depth is the real one (a constant depth "
        "offset plays no part in the matching)._\n"
    )
    return "### Table 1 — terrain\n\n" + md_table(header, _terrain_rows()) + note


def _table3(table3: dict, trials: int) -> str:
    header = [
        "method",
        "initial error (m)",
        "A mean: source / ours",
        "A max: source / ours",
        "B mean: source / ours",
        "B max: source / ours",
        "ours: A / B worst max",
        "ours: ms per match (A / B)",
    ]
    rows = []
    for spec, short in ((GA, "ga-sca"), (MULTIPATH, "iccp-multipath"), ("iccp", "iccp")):
        for err in ERRORS:
            cells = []
            for label in ("A", "B"):
                src = SOURCE_TABLE3.get((short, label, err), (None, None))
                ours = table3[(label, err)][spec]
                cells += [
                    f"{fmt(src[0])} / {fmt(ours['mean'])}",
                    f"{fmt(src[1])} / {fmt(ours['max'])}",
                ]
            a, b = table3[("A", err)][spec], table3[("B", err)][spec]
            cells += [
                f"{fmt(a['worst'], 1)} / {fmt(b['worst'], 1)}",
                f"{fmt(a['ms'], 0)} / {fmt(b['ms'], 0)}",
            ]
            rows.append([f"`{spec}`", f"({err}, {err})", *cells])
    note = (
        f"\n_Mean = mean over {trials} trials of the mean error along the 15 matched points; "
        "max = mean over trials of the largest error along the track (the source's single "
        "run gives one of each); worst = the largest over all trials. Source metres._\n"
    )
    return "### Table 3 — matching errors\n\n" + md_table(header, rows) + note


def _table4(ablation: dict) -> str:
    header = [
        "variant",
        "what",
        "mean error (m): source / ours",
        "ours: median (m)",
        "iterations: source / ours",
        "time (s): source / ours",
    ]
    rows = []
    for v, ours in ablation.items():
        src = SOURCE_TABLE4[v]
        rows.append(
            [
                v,
                VARIANT_TEXT[v],
                f"{fmt(src[0])} / {fmt(ours['mean'])}",
                fmt(ours["median"]),
                f"{fmt(src[1], 0)} / {fmt(ours['iterations'], 0)}",
                f"{fmt(src[2])} / {fmt(ours['time'], 3)}",
            ]
        )
    note = (
        "\n_Track A, initial error (150, 150) m, same trials for every variant. Iterations: "
        "the generation of the last improvement of the best cost by more than the "
        "tolerance (the source's 'iterations at convergence'); the run stops 100 "
        "generations later._\n"
    )
    return "### Table 4 — ablation\n\n" + md_table(header, rows) + note


def _verdict(table3: dict, ablation: dict) -> str:
    lines = ["### Verdict\n"]
    for label in ("A", "B"):
        for err in ERRORS:
            ga = table3[(label, err)][GA]["mean"]
            mp = table3[(label, err)][MULTIPATH]["mean"]
            word = "below" if ga < mp else "NOT below"
            lines.append(
                f"- Track {label}, ({err}, {err}) m: ga-sca mean {fmt(ga)} m is {word} "
                f"multipath ICCP's {fmt(mp)} m."
            )
    for label in ("A", "B"):
        small = table3[(label, 30)][GA]["mean"]
        large = table3[(label, 150)][GA]["mean"]
        ratio = large / small if small > 0 else float("nan")
        same = "nearly the same" if 0.75 <= ratio <= 1.33 else "NOT the same"
        lines.append(
            f"- Track {label}: ga-sca at (30, 30) vs (150, 150): {fmt(small)} vs {fmt(large)} m, "
            f"{same} (ratio {fmt(ratio)}; the source: insensitive to the initial error)."
        )
    order = sorted(ablation, key=lambda v: ablation[v]["mean"])
    ranked = " < ".join(f"{v} ({fmt(ablation[v]['mean'])})" for v in order)
    agree = order[0] == "A" and order[-1] == "D"
    lines.append(
        f"- Ablation, mean error: {ranked}. The source ranks A < B < C < D; "
        + ("ours agrees that A is best and D worst." if agree else "**ours disagrees**.")
    )
    by_median = sorted(ablation, key=lambda v: ablation[v]["median"])
    gap = ablation["B"]["mean"] - ablation["A"]["mean"]
    lines.append(
        f"- The A–B gap in mean error is {fmt(gap)} m, small against the trial-to-trial "
        "spread; by median the order is "
        + " < ".join(f"{v} ({fmt(ablation[v]['median'])})" for v in by_median)
        + ". The means differ through the few trials that end farther off; the typical "
        "(median) error is set by the map and the noise, and there our variants are within "
        "a few tenths of a metre of each other, so the ranking of A and B is not firm."
    )
    src_ratio = SOURCE_TABLE4["A"][1] / SOURCE_TABLE4["D"][1]
    our_ratio = ablation["A"]["iterations"] / max(ablation["D"]["iterations"], 1e-9)
    lines.append(
        f"- Iterations A / D: source {fmt(src_ratio)}, ours {fmt(our_ratio)}. Absolute "
        "iteration counts and times are not comparable (population and stop rule are ours). "
        "One ga-sca match takes "
        + " to ".join(fmt(ablation[v]["time"]) for v in ("B", "A"))
        + " s run alone (Table 4) against the source's 8 s; the per-match times of Table 3 "
        "are longer because two campaign workers share a busy 2-core machine."
    )
    lines.append(
        "- Absolute errors: the stand-in terrain is a 107 m grid resampled, i.e. smooth "
        "below about 5 source metres, where the source's lake map is resolved to 1 m; "
        "larger absolute errors than the source's are expected from the map, not the "
        "method."
    )
    return "\n".join(lines) + "\n"
