"""Fused fields: depth and gravity in one recursive filter, against each field alone."""

from __future__ import annotations

import dataclasses

import numpy as np

from sections._common import fmt, md_table, scenario

TITLE = "Fused fields — depth and gravity in one filter"
ORDER = 73

TRIALS, QUICK_TRIALS = 16, 2
METHODS = ("pmf", "pf", "mpf")  # pmf and pf run on the INS error state by default
SCENARIOS = {
    "fused_depth_weak": "the seabed the smoother field (depth's bound the larger)",
    "fused_gravity_weak": "the gravity anomaly the smoother field (gravity's bound the larger)",
}
ROWS = ("depth alone", "gravity alone", "depth + gravity")
FALSE_FIX_CELLS = 2.0
FALSE_FIX_SIGMAS = 3.0
#: The done criterion on the fused end RMS: within this factor of the fused bound.
BOUND_FACTOR = 1.2


def build(quick: bool) -> str:
    """Run both scenarios, every row and method on the same trials, and write the section."""
    count = QUICK_TRIALS if quick else TRIALS
    parts = [f"## {TITLE}\n", _intro(count)]
    checks = []
    for name, what in SCENARIOS.items():
        table, outcome = _scenario_table(scenario(name), count)
        parts.append(f"### `{name}` — {what}\n")
        parts.append(md_table(_HEADER, table))
        checks.append((name, outcome))
    parts.append(_criteria(checks))
    return "\n".join(parts)


_HEADER = [
    "fields",
    "method",
    "end RMS (m)",
    "RMS / fused bound",
    "RMS / own bound",
    "RMS / still-offset bound",
    "RMS / offset-aware bound",
    "median NEES",
    "false fixes",
    "flagged ambiguous",
]


def _rows(trial, grid) -> dict:
    """The trial as each row sees it: the same readings, one field or both."""
    (field,) = trial.fields
    gravity = dataclasses.replace(
        trial,
        measured=field.measured,
        offsets=field.offsets,
        noise_std=field.noise_std,
        beam_noise_std=field.beam_noise_std,
        sensor=field.sensor,
        lag_s=field.lag_s,
        unlagged_measured=field.unlagged_measured,
        fields=(),
    )
    return {
        "depth alone": (dataclasses.replace(trial, fields=()), grid),
        "gravity alone": (gravity, field.grid),
        "depth + gravity": (trial, grid),
    }


def _scenario_table(scen, count: int) -> tuple[list[list], dict]:
    from geofix.evaluate.crlb import offset_state_crlb, trial_crlb
    from geofix.evaluate.runner import method_rng, run_trial
    from geofix.methods import parse_method_spec
    from geofix.sim.simulate import prepare_map, simulate_trial

    grid = prepare_map(scen)
    trials = [_rows(simulate_trial(scen, grid, i), grid) for i in range(count)]
    bounds = {row: _rms([trial_crlb(*t[row]).recursive_var_m2 for t in trials]) for row in ROWS}
    still = {
        row: _rms([offset_state_crlb(*t[row], offset_walk=0.0).recursive_var_m2 for t in trials])
        for row in ROWS
    }
    aware = {
        row: _rms([offset_state_crlb(*t[row]).recursive_var_m2 for t in trials]) for row in ROWS
    }
    table = []
    outcome = {"bounds": bounds, "still": still, "aware": aware, "methods": {}}
    for spec in METHODS:
        method = parse_method_spec(spec)
        per_row = {}
        for row in ROWS:
            results = [
                run_trial(method, *t[row], method_rng(scen.seed, i, spec))
                for i, t in enumerate(trials)
            ]
            per_row[row] = _stats(results, [t[row][0] for t in trials], grid.cell_size)
        outcome["methods"][spec] = per_row
        for row in ROWS:
            s = per_row[row]
            table.append(
                [
                    row,
                    f"`{spec}`",
                    fmt(s["rms"], 0),
                    fmt(s["rms"] / bounds["depth + gravity"], 2),
                    fmt(s["rms"] / bounds[row], 2),
                    fmt(s["rms"] / still["depth + gravity"], 2),
                    fmt(s["rms"] / aware["depth + gravity"], 2),
                    _nees(s["nees"]),
                    f"{s['false']} of {count}",
                    f"{s['ambiguous'].sum()} of {count}",
                ]
            )
    for label, values in (
        ("error-state CRLB, end (m)", bounds),
        ("still-offset CRLB, end (m)", still),
        ("offset-aware CRLB, end (m)", aware),
    ):
        table.append([label, "", " / ".join(f"{r}: {values[r]:.0f}" for r in ROWS)] + [""] * 7)
    return table, outcome


def _rms(variances: list[float]) -> float:
    """Root of the mean of ``variances``, their unit's root."""
    return float(np.sqrt(np.mean(variances)))


def _stats(results, trials, cell: float) -> dict:
    err = np.array([r.end_error_m for r in results], dtype=float)
    nees = np.array([_end_nees(r, t) for r, t in zip(results, trials, strict=True)])
    amb = np.array([bool(r.ambiguous) for r in results])
    far = err > FALSE_FIX_CELLS * cell
    false = far & ~amb & ~(nees <= FALSE_FIX_SIGMAS**2)
    finite = np.isfinite(nees)
    return {
        "rms": float(np.sqrt(np.nanmean(err**2))),
        "nees": float(np.median(nees[finite])) if finite.any() else float("nan"),
        "false": int(false.sum()),
        "ambiguous": amb,
    }


def _end_nees(result, trial) -> float:
    """``d^T P^-1 d`` of the end error ``d`` (metres) with the method's covariance ``P``."""
    cov = result.covariance
    if cov is None or result.failed:
        return float("nan")
    d = np.asarray(result.estimate[-1] - trial.truth[-1], dtype=float)
    try:
        return float(d @ np.linalg.solve(np.asarray(cov, float), d))
    except np.linalg.LinAlgError:
        return float("nan")


def _nees(value: float) -> str:
    if not np.isfinite(value):
        return "-"
    return f"{value:.2f}" if value < 100 else f"{value:.2g}"


def _criteria(checks) -> str:
    """The done criteria, measured on the tables above, stated as they came out."""
    lines = ["\n**The criteria, as measured.**\n", _summary(checks), ""]
    for name, outcome in checks:
        bound = outcome["bounds"]["depth + gravity"]
        steady = outcome["still"]["depth + gravity"]
        aware = outcome["aware"]["depth + gravity"]
        for spec, rows in outcome["methods"].items():
            fused = rows["depth + gravity"]["rms"]
            better = min(rows["depth alone"]["rms"], rows["gravity alone"]["rms"])
            both = rows["depth alone"]["ambiguous"] & rows["gravity alone"]["ambiguous"]
            either = rows["depth alone"]["ambiguous"] | rows["gravity alone"]["ambiguous"]
            fused_flag = rows["depth + gravity"]["ambiguous"]
            still = int((both & fused_flag).sum())
            ratio, ratio_still, ratio_aware = fused / bound, fused / steady, fused / aware
            lines.append(
                f"- `{name}`, `{spec}`: fused end RMS {fused:.0f} m against the better "
                f"single field's {better:.0f} m ({'at most' if fused <= better else 'above'} "
                f"it); {ratio:.2f} x the known-offset fused bound ({_near(ratio)} "
                f"{BOUND_FACTOR}x), {ratio_still:.2f} x the still-offset one "
                f"({_near(ratio_still)}) and {ratio_aware:.2f} x the offset-aware one "
                f"({_near(ratio_aware)}); {int(both.sum())} trials flagged ambiguous by both "
                f"single fields ({still} of them still flagged fused), {int(either.sum())} by "
                f"either ({int((either & fused_flag).sum())} still flagged fused)."
            )
    return "\n".join(lines) + "\n"


def _near(ratio: float) -> str:
    return "within" if ratio <= BOUND_FACTOR else "beyond"


def _summary(checks) -> str:
    """One paragraph: how many scenario-method pairs meet each criterion."""
    pairs = better = near = near_still = near_aware = vacuous = clean = flagged = 0
    worst = worst_still = worst_aware = 0.0
    costs = []
    for name, outcome in checks:
        bound = outcome["bounds"]["depth + gravity"]
        steady = outcome["still"]["depth + gravity"]
        aware = outcome["aware"]["depth + gravity"]
        costs.append(
            f"`{name}` {aware / bound:.2f}x (depth alone "
            f"{outcome['aware']['depth alone'] / outcome['bounds']['depth alone']:.2f}x, "
            f"gravity alone "
            f"{outcome['aware']['gravity alone'] / outcome['bounds']['gravity alone']:.2f}x)"
        )
        for rows in outcome["methods"].values():
            fused = rows["depth + gravity"]
            pairs += 1
            better += fused["rms"] <= min(rows[r]["rms"] for r in ROWS[:2])
            near += fused["rms"] / bound <= BOUND_FACTOR
            near_still += fused["rms"] / steady <= BOUND_FACTOR
            near_aware += fused["rms"] / aware <= BOUND_FACTOR
            worst = max(worst, fused["rms"] / bound)
            worst_still = max(worst_still, fused["rms"] / steady)
            worst_aware = max(worst_aware, fused["rms"] / aware)
            both = rows["depth alone"]["ambiguous"] & rows["gravity alone"]["ambiguous"]
            vacuous += not both.any()
            clean += not (both & fused["ambiguous"]).any()
            flagged += int(fused["ambiguous"].sum())
    return (
        f"Of the {pairs} scenario and filter pairs, the fused end RMS is at most the better "
        f"single field's in {better}. Within {BOUND_FACTOR}x the fused bound: against the "
        f"known-offset bound in {near} (the largest ratio {worst:.2f}), against the "
        f"still-offset bound in {near_still} (the largest ratio {worst_still:.2f}), against "
        f"the offset-aware bound in {near_aware} (the largest ratio {worst_aware:.2f}). Where "
        f"both single fields end a trial flagged ambiguous the fused filter does not in "
        f"{clean} of {pairs} pairs ({flagged} fused trials flagged in all), but in "
        f"{vacuous} of the pairs no trial is flagged by both single fields at once, so there "
        "the criterion holds without being tested.\n\n"
        "Which bound to read. The known-offset bound is the limit of an estimator told every "
        "field's offset; the simulated offsets are zero here, so such an estimator exists, "
        "but the default filters are not told: they estimate one offset per field as a "
        "random-walk state from their maps' default prior (on the gravity map with a "
        "smooth offset over 2 km of track weighed beside the walks, "
        "`geofix.filters.nuisance.default_offset_smooth`). The still-offset bound is the "
        "limit of the problem these trials pose: every field's offset constant and "
        "unknown within the filters' prior (the posterior bound of the INS error state "
        "augmented with the offsets, `geofix.evaluate.crlb.offset_state_crlb` with "
        "`offset_walk=0`): no estimator not told the offsets beats it on average over "
        "offsets drawn from that prior. The offset-aware "
        "bound is the same with the offsets walking as the filters model them, the limit "
        "of the problem the default filters set themselves; what lies between the two is "
        "the cost of the declared walk. A ratio below 1 to either is no contradiction: "
        "both average over offsets drawn from the filters' prior, while these trials' "
        "offsets sit at its mean, where an estimator that leans on the prior gains. "
        "Carrying the offsets costs, "
        "at the end point: " + "; ".join(costs) + "."
    )


def _intro(count: int) -> str:
    return (
        "One recursive filter can weigh several fields at once (a scenario's `sensors:` "
        "list; [the fused-fields guide](guide/fused-fields.md)): each field has its own "
        "map, noise, common offset, residual scale and representation error, the "
        "likelihood is the product over fields and the Cramér–Rao bound the sum of their "
        "information. Here a single-beam echosounder (30 m noise, 15 m map error: about 1 % "
        "of the 2.2–5 km depth) and a 0.5 mGal gravimeter ping every 30 s at 8 m/s over the "
        "bundled `mb_1km` and `grav_1km` maps, which share one 1 km grid; free-inertial, a "
        f"3 km initial error spread, 90 pings. {count} trials per scenario, and every row of "
        "a trial gets the *same* readings: the depth row drops the gravimeter, the gravity "
        "row the echosounder (the gravimeter then its primary field), so the rows differ "
        "only in what the filter is given. Default settings throughout "
        "(`map_model=imperfect`: every field's offset is unknown, 5 m + 0.2 % of depth and "
        "5 mGal). Two tracks: one where the seabed is the smoother field, one where the "
        "gravity anomaly is. *RMS / fused bound* divides each row's end RMS by the error-"
        "state CRLB of depth + gravity with every field's offset known (its end point, RMS "
        "over the trials); *own bound* by the row's own field(s)' known-offset bound; "
        "*still-offset bound* by the bound of depth + gravity with each field's offset a "
        "constant unknown within that prior (5 m + 0.2 % of depth and 5 mGal); "
        "*offset-aware bound* by the same with each offset a "
        "random-walk state as the filters model it (walk 1e-3 units^2/s). "
        "*False fixes*: end error beyond "
        f"{FALSE_FIX_CELLS:g} map cells, not flagged ambiguous, and beyond "
        f"{FALSE_FIX_SIGMAS:g} sigma of the filter's own covariance. *Flagged ambiguous*: "
        "the filter's own integrity flag at the end.\n"
    )
