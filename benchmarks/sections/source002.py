"""Source 002: SITAN and the parallel SITAN bank (Zheng, Wang & Bian, 2008)."""

from __future__ import annotations

import numpy as np

from sections._common import OUT, campaign, fmt, md_table, save_section_figure, scenario

TITLE = "Source 002 — SITAN and the parallel-filter bank (recursive, multibeam)"
ORDER = 50

METHODS = ("sitan", "sitan-bank", "tercom")
FILTERS = METHODS[:2]
TRIALS, QUICK_TRIALS = 100, 3
SMALL_TRIALS, QUICK_SMALL_TRIALS = 50, 5
DIVERGENCE_CELLS = 3.0
NORMALISED_RMS_BOUND = 1.5
FIGURE = "source002_error_vs_time.png"


def build(quick: bool) -> str:
    """Run the large-error campaign (both filters, TERCOM for reference) and the
    small-error consistency campaign (single SITAN), then the figure."""
    from geofix.maps.terrain import terrain_stats
    from geofix.sim.simulate import prepare_map

    big_scen, small_scen = scenario("source002_bank"), scenario("source002_small")
    grid = prepare_map(big_scen)
    n_big = QUICK_TRIALS if quick else TRIALS
    n_small = QUICK_SMALL_TRIALS if quick else SMALL_TRIALS
    big = campaign(big_scen, list(METHODS), n_big, jobs=2)
    small = campaign(small_scen, ["sitan"], n_small, jobs=2)
    big_rows = _campaign_rows(big.frame, grid.cell_size)
    consistency = _consistency(small.frame)
    parts = [
        f"## {TITLE}\n",
        _intro(big_scen, grid, terrain_stats(grid), n_big),
        _table(big_rows, grid.cell_size, n_big),
        _figure(big, grid.cell_size),
        _consistency_text(consistency, n_small),
        _verdict(big_rows, consistency),
    ]
    return "\n".join(parts)


# ---------------------------------------------------------------------- numbers
def _campaign_rows(frame, cell_m: float) -> dict:
    """Per method: divergence rate, mean / median / max end error, flagged share, time."""
    out = {}
    for spec in METHODS:
        rows = frame[frame["method"] == spec]
        failed = rows["failed"].astype(bool).to_numpy()
        end = rows["end_error_m"].to_numpy(dtype=float)
        diverged = failed | ~(end <= DIVERGENCE_CELLS * cell_m)
        ok = end[~failed]
        amb = rows["ambiguous"].astype(bool).to_numpy()
        out[spec] = {
            "trials": len(rows),
            "divergence": float(diverged.mean()) if len(rows) else float("nan"),
            "mean": float(np.mean(ok)) if ok.size else float("nan"),
            "median": float(np.median(ok)) if ok.size else float("nan"),
            "max": float(np.max(ok)) if ok.size else float("nan"),
            "flagged_diverged": int(np.count_nonzero(diverged & amb)),
            "flagged_good": int(np.count_nonzero(~diverged & amb)),
            "diverged": int(np.count_nonzero(diverged)),
            "time": float(rows["time_s"].mean()),
            "failures": int(failed.sum()),
        }
    return out


def _consistency(frame) -> dict:
    """Normalised end error of the single SITAN: RMS over trials of ``d / sqrt(2)``.

    ``d`` is the Mahalanobis distance of the end error against the filter's own covariance
    (``end_mahalanobis``); ``d^2`` is chi-square with 2 degrees of freedom for a
    consistent filter, so ``d / sqrt(2)`` is the per-axis normalised error (RMS 1).
    """
    rows = frame[(frame["method"] == "sitan") & ~frame["failed"].astype(bool)]
    d = rows["end_mahalanobis"].to_numpy(dtype=float)
    d = d[np.isfinite(d)]
    per_axis = d / np.sqrt(2.0)
    rms = float(np.sqrt(np.mean(per_axis**2))) if d.size else float("nan")
    return {
        "rms": rms,
        "n": int(d.size),
        "within_3": float(np.mean(d <= 3.0)) if d.size else float("nan"),
        "mean_error": float(rows["end_error_m"].mean()),
    }


# ---------------------------------------------------------------------- text
def _intro(scen, grid, stats, trials: int) -> str:
    ins = scen.ins
    offset = float(np.hypot(*ins.initial_error_m))
    corr = stats.correlation_length_m
    return (
        "The source (Zheng, Wang & Bian, *Ship Electronic Engineering* 28(7), 2008) runs "
        "SITAN -- an extended Kalman filter on `[dx, dy, dh, dvx, dvy]` with stochastic "
        "terrain linearisation -- on a real multibeam survey (16 beams of 2° x 2°, 44° "
        "swath) and shows only a figure: the single filter diverges, the bank of N x N "
        "filters selected by smoothed weighted residuals (SWRS) follows the true track. It "
        "gives no N, beta, spacing or re-initialisation rule; ours are documented in "
        "`geofix.filters.sitan.SitanBank` (defaults: N up to 25, bank spanning +-3 prior "
        "sigma, beta = 0.95, spacing and N halved at each re-initialisation down to 3 x 3 "
        "filters one cell apart).\n\n"
        f"Our stand-in: the bundled real multibeam bathymetry `{scen.map.path}` "
        f"({grid.shape[1]} x {grid.shape[0]} cells of {grid.cell_size:.0f} m; depth std "
        f"{stats.std:.0f} m; e-folding correlation length {stats.correlation_length_x_m / 1e3:.1f}"
        f" km east, {stats.correlation_length_y_m / 1e3:.1f} km north, mean "
        f"{corr / 1e3:.1f} km). A survey line heading {scen.track.heading_deg:.0f}° (east to "
        f"west, as in the source) at {scen.track.speed_m_s:g} m/s, one swath every "
        f"{scen.track.interval_s:g} s, {scen.track.samples} swaths "
        f"({scen.track.samples * scen.track.speed_m_s * scen.track.interval_s / 1e3:.0f} km); "
        f"16 beams over 44° from {scen.sensor.altitude_m:.0f} m above the seabed "
        f"({2 * scen.sensor.altitude_m * np.tan(np.radians(22)) / 1e3:.1f} km swath), beam "
        f"noise {scen.sensor.noise_std:g} m plus map error {scen.sensor.map_error_std:g} m. "
        f"Initial INS error {offset / 1e3:.0f} km (plus {ins.initial_error_std_m / 1e3:g} km "
        f"per axis at random), **{offset / corr:.1f} times the correlation length**, then "
        f"INS drift (velocity error {ins.velocity_error_m_s} m/s, accelerometer bias "
        f"{ins.accel_bias_ug} ug, gyro drift {ins.gyro_bias_deg_h} deg/h). {trials} Monte "
        "Carlo trials (each with its own start and INS errors). Both filters are "
        "recursive: the end-point error is the error of the estimate at the last swath. "
        "TERCOM over the whole line (one batch match of all swaths) is shown for "
        "reference.\n"
    )


def _table(rows: dict, cell_m: float, trials: int) -> str:
    header = [
        "method",
        f"divergence (end > {DIVERGENCE_CELLS:g} cells) (%)",
        "mean end error (m)",
        "median (m)",
        "max (m)",
        "diverged & flagged",
        "good & flagged",
        "time/trial (s)",
        "failures",
    ]
    body = [
        [
            f"`{spec}`",
            fmt(100 * r["divergence"], 0),
            fmt(r["mean"], 0),
            fmt(r["median"], 0),
            fmt(r["max"], 0),
            f"{r['flagged_diverged']} / {r['diverged']}",
            r["flagged_good"],
            fmt(r["time"], 2),
            r["failures"],
        ]
        for spec, r in rows.items()
    ]
    return (
        f"**Large initial error, {trials} trials** (a trial diverges when its end error "
        f"exceeds {DIVERGENCE_CELLS:g} cells = {DIVERGENCE_CELLS * cell_m:.0f} m; "
        "*flagged* = `Fix.ambiguous`):\n\n" + md_table(header, body)
    )


def _consistency_text(c: dict, trials: int) -> str:
    return (
        f"\n**Consistency of the single SITAN on a small initial error** (scenario "
        f"`source002_small`: the same line, 300 m per axis initial error, {trials} seeded "
        f"trials): mean end error {fmt(c['mean_error'], 0)} m; the end error normalised by "
        f"the filter's own covariance has a per-axis RMS of **{fmt(c['rms'], 2)}** over "
        f"{c['n']} trials ({fmt(100 * c['within_3'], 0)} % inside the 3-sigma ellipse). "
        "A consistent filter gives 1, with a sampling spread of about 0.1 over 50 trials; "
        f"our bound is {NORMALISED_RMS_BOUND:g}, leaving room for the linearisation error "
        "an EKF on real terrain carries but not for an overconfident filter (the unit "
        "test `test_sitan_error_is_consistent_with_its_covariance` applies the same bound "
        "to every sample of 50 seeded missions on a synthetic map whose INS error follows "
        "the filter's model, and gets about 0.9). A value well below 1 means the filter "
        "is conservative: its R counts the whole plane-fit residual as noise, and the INS "
        "drift enters twice (as the prior's growth in the position process noise and "
        "through the velocity-error states).\n"
    )


def _verdict(rows: dict, c: dict) -> str:
    single, bank = rows["sitan"], rows["sitan-bank"]
    below = bank["divergence"] <= 0.5 * single["divergence"] and bank["divergence"] < 0.25
    consistent = c["rms"] < NORMALISED_RMS_BOUND
    lines = [
        "**Against the source.**",
        f"- Single SITAN diverges in {fmt(100 * single['divergence'], 0)} % of the trials, "
        f"the bank in {fmt(100 * bank['divergence'], 0)} %: "
        + (
            "the bank is well below the single filter, as the source's figure shows."
            if below
            else "NOT well below the single filter -- this disagrees with the source."
        ),
        f"- Of the bank's diverged trials, {bank['flagged_diverged']} of {bank['diverged']} "
        "are flagged ambiguous by the bank itself (no filter clearly best, or the best "
        "filter's residuals inconsistent).",
        f"- Single SITAN on a small error: normalised RMS {fmt(c['rms'], 2)} "
        + (
            f"< {NORMALISED_RMS_BOUND:g}: consistent with its covariance."
            if consistent
            else f">= {NORMALISED_RMS_BOUND:g}: NOT consistent with its covariance."
        ),
        f"- TERCOM over the whole line never diverges here (mean end error "
        f"{fmt(rows['tercom']['mean'], 0)} m: one rigid shift for 60 km of drifting INS "
        f"track), while the bank, once locked, ends at a median {fmt(bank['median'], 0)} m.",
        "- The source reports no numbers, only the two tracks of one run; the table above "
        "is ours alone. The bank costs about "
        f"{fmt(bank['time'] / max(single['time'], 1e-9), 0)} times the single filter.",
    ]
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------- figure
def _figure(result, cell_m: float) -> str:
    """Error versus time of both filters: one trial, median and 10-90 % band."""
    from geofix.evaluate.store import ResultStore
    from geofix.plot import error_band_figure

    with ResultStore(OUT / result.scenario) as store:
        frame = store.to_frame(result.scenario_hash, arrays=True)
    frame = frame[frame["method"].isin(FILTERS) & (frame["trial"] < result.trials)]
    errors = {}
    for spec in FILTERS:
        rows = frame[(frame["method"] == spec) & ~frame["failed"].astype(bool)]
        if not rows.empty:
            errors[spec] = np.stack(rows["error"].to_list())
    save_section_figure(error_band_figure(errors, limit_m=DIVERGENCE_CELLS * cell_m), FIGURE)
    return (
        f"\n![Error versus time of SITAN and the SITAN bank](figures/{FIGURE})\n\n"
        "Error versus time (log scale; dashed: 3 cells). Single SITAN wanders off as in "
        "the source's figure 4; the bank's best filter jumps between hypotheses during the "
        "first tens of swaths, then locks on and stays within a cell or so.\n"
    )
