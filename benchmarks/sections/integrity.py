"""Beyond the sources: the Cramér–Rao bound beside every method, integrity, suitability."""

from __future__ import annotations

import math

import numpy as np

from sections._common import FIGURES, OUT, SCENARIOS, campaign, fmt, md_table

TITLE = "Beyond the sources — Cramér–Rao bound, integrity on flat terrain, suitability"
ORDER = 90

BOUND_METHODS = ("tercom", "pmf", "pf")
BOUND_TRIALS, QUICK_BOUND_TRIALS = 30, 2
NAVO_TRIALS, QUICK_NAVO_TRIALS = 16, 2


def build(quick: bool) -> str:
    """Bounds beside the errors, the flat-survey check of every method, a suitability map."""
    parts = [f"## {TITLE}\n", _intro()]
    parts.append(_bounds_part(QUICK_BOUND_TRIALS if quick else BOUND_TRIALS, quick))
    parts.append(_navo_part(QUICK_NAVO_TRIALS if quick else NAVO_TRIALS))
    parts.append(_suitability_part())
    return "\n".join(parts)


def _intro() -> str:
    return (
        "The Cramér–Rao lower bound (CRLB) is the smallest RMS position error any unbiased "
        "method can reach from the map gradients along the true track and the sensor (plus "
        "map) noise (`geofix.evaluate.crlb`). Two forms are given per scenario. The "
        "**recursive** bound (`crlb_m` in `geofix run --json`) is the posterior CRLB of "
        "Tichavský et al. over the whole mission for a position error that is a random "
        "walk whose per-step variance is the growth of the INS prior variance (the filters' "
        "own motion model) with the prior sigma at the first sample; it is reported as "
        "`sqrt(mean over trials of trace(J_n^-1))` (variances averaged, then the root), "
        "the bound on the end-point RMS error. The **batch** bound `sqrt(trace(J^-1))` is "
        "that of a rigid translation of the last leg from its samples alone (no prior): "
        "the model of TERCOM-like matchers.\n\n"
        "**Read the recursive bound as the limit of the random-walk motion model, not of "
        "the simulated vehicle.** The simulated INS error is far more correlated than a "
        "random walk of the same variance (a fixed initial offset, a constant velocity "
        "error, Schuler-bounded bias terms), so past soundings say more about the present "
        "position than the random-walk model admits, and a method can end below that "
        "bound (the PMF does on several scenarios below, with the same motion model "
        "inside: the data are kinder than its model). A bound for the simulated error process "
        "itself would take the INS error state (offset, velocity, bias) as the unknowns. "
        "The batch bound ignores both the prior and the drift within the leg, so it is no "
        "strict limit either; it shows how much the terrain of one leg can tell.\n\n"
        "The false-fix rate counts trials ending more than 3 "
        "cells off that the method neither flagged as ambiguous nor covered by its own "
        "3-sigma covariance ellipse.\n"
    )


# ---------------------------------------------------------------------- bounds
#: Scenarios of the quick run (the full run takes every bundled scenario).
QUICK_SCENARIOS = ("source001_gentle", "source004_main")


def _bundled_scenarios(quick: bool) -> list:
    from importlib import resources

    from geofix.sim.scenario import load_scenario

    demo = resources.files("geofix") / "scenarios" / "azores_demo.yaml"
    paths = sorted(SCENARIOS.glob("*.yaml"))
    if quick:
        paths = [p for p in paths if p.stem in QUICK_SCENARIOS]
    return [load_scenario(str(p)) for p in [demo, *paths]]


def _rms(stats: dict) -> float | None:
    mean, std = stats.mean_error_m, stats.std_error_m
    return None if mean is None else math.hypot(mean, std)


def _bounds_part(trials: int, quick: bool) -> str:
    from geofix.methods import available_methods

    methods = [m for m in BOUND_METHODS if m in available_methods()]
    rows, ratios = [], []
    for scen in _bundled_scenarios(quick):
        summary = campaign(scen, methods, trials=trials, jobs=2).summary
        stats = summary.methods
        rms = {m: _rms(stats[m]) for m in methods}
        if "pmf" in rms and rms["pmf"] and summary.crlb_m:
            ratios.append((scen.name, rms["pmf"] / summary.crlb_m))
        rows.append(
            [
                f"`{scen.name}`",
                scen.sensor.type,
                fmt(summary.crlb_m, 1),
                fmt(summary.crlb_batch_m, 1),
                *[fmt(rms[m], 1) for m in methods],
                " / ".join(fmt(100 * (stats[m].false_fix_rate or 0), 0) for m in methods),
            ]
        )
    header = [
        "scenario",
        "sensor",
        "CRLB recursive (m)",
        "CRLB batch, last leg (m)",
        *[f"RMS end error `{m}` (m)" for m in methods],
        f"false fixes % ({' / '.join(methods)})",
    ]
    text = (
        f"### The bound beside the errors\n\n{trials} trials per scenario (the bundled "
        "scenarios of the source sections and the demo), end-point RMS errors "
        "`sqrt(mean^2 + std^2)` over the trials that did not fail.\n\n"
    )
    text += md_table(header, rows)
    if ratios:
        spread = ", ".join(f"`{n}` {r:.2f}" for n, r in ratios)
        values = np.array([r for _, r in ratios])
        text += (
            f"\nPMF RMS error / recursive CRLB: {spread}. Below the bound on "
            f"{int((values < 1).sum())} of {values.size} scenarios, within 1.5 times it on "
            f"{int((values <= 1.5).sum())}; where the ratio is far above 1.5 the PMF lost "
            "the vehicle on some trials (see its false-fix rate).\n"
        )
    return text


# ---------------------------------------------------------------------- flat survey
def navo_scenario(sensor: str):
    """The bundled flat-survey mission (``navo_flat_<sensor>.yaml``) of the integrity test."""
    from geofix.sim.scenario import builtin_scenario_path, load_scenario

    return load_scenario(builtin_scenario_path(f"navo_flat_{sensor}"))


def _navo_part(trials: int) -> str:
    from geofix.console import ProgressBar
    from geofix.evaluate.campaign import run_campaign
    from geofix.methods import available_methods

    classes = available_methods()
    rows, failing = [], []
    for sensor in ("singlebeam", "multibeam"):
        scen = navo_scenario(sensor)
        beams = scen.sensor.beams if sensor == "multibeam" else 1
        # a swath method (min_beams > 1, e.g. icp) is refused on a single-beam mission
        methods = [m for m, cls in classes.items() if getattr(cls, "min_beams", 1) <= beams]
        with ProgressBar(scen.name) as bar:
            result = run_campaign(
                scen, methods, trials=trials, jobs=2, out_dir=OUT / scen.name, progress=bar
            )
        frame = result.frame
        for spec in methods:
            s = result.summary.methods[spec]
            rows_m = frame[frame["method"] == spec]
            covered = np.mean(rows_m["end_mahalanobis"].to_numpy(float) <= 3.0)
            rows.append(
                [
                    f"`{spec}`",
                    sensor,
                    fmt(100 * s.ambiguous_rate, 0),
                    fmt(100 * s.false_fix_rate, 0),
                    fmt(s.mean_error_m, 1),
                    fmt(100 * covered, 0),
                    s.failures,
                ]
            )
            if s.false_fix_rate and s.false_fix_rate > 0.1:
                failing.append(f"`{spec}` ({sensor}, {100 * s.false_fix_rate:.0f} %)")
        crlb = result.summary.crlb_m
    header = [
        "method",
        "sensor",
        "flagged ambiguous %",
        "false fixes %",
        "mean end error (m)",
        "error within own 3 sigma %",
        "failures",
    ]
    text = (
        "### Integrity on the flat NAVO survey\n\n"
        "The bundled 2 m NAVO survey (`builtin:navo_flat`, depth std 0.3 m over 3 km) cut to "
        f"a fully valid 1.6 x 1.2 km part; an AUV at 2 m/s, a sounding every 5 s, 30 "
        "soundings, echosounder noise 0.2 m (multibeam: 7 beams over 100 m), INS error "
        f"about 50 m; {trials} trials per sensor. The relief along a track is about a third "
        "of the noise. A method passes when it flags the fix as ambiguous, or its error is "
        "within 3 cells or within its own 3-sigma ellipse (no false fix); the multibeam's "
        f"recursive CRLB here is {fmt(crlb, 1)} m, so a near-optimal filter may localise "
        "honestly instead of flagging.\n\n"
    )
    text += md_table(header, rows)
    verdict = ", ".join(failing) if failing else "none"
    text += (
        f"\nMethods giving confident wrong fixes on more than 10 % of the trials: {verdict}. "
        "A residual (or innovation) test alone cannot catch a plain, since every position "
        "fits within the noise there; every batch matcher therefore also flags a fix when "
        "the map's standard deviation over the matched footprints is below the sensor "
        "noise (`geofix.match.integrity.terrain_snr`; `ga-sca` uses 0.6 of it), SITAN when "
        "more than 5 % of its Gaussian posterior lies beyond 3 cells, and the point-mass "
        "and particle filters when more than 5 % of their posterior does.\n"
    )
    return text


# ---------------------------------------------------------------------- suitability
def _suitability_part() -> str:
    from geofix.evaluate.suitability import suitability
    from geofix.maps.io import load_grid
    from geofix.plot.figures import save_figure
    from geofix.plot.suitability import suitability_figure

    grid = load_grid("builtin:azores", region=(-31.5, -28.5, 37.5, 40.0), resample_m=1000)
    result = suitability(grid, window_cells=21, noise_std=5.0)
    path = save_figure(suitability_figure(result), FIGURES / "integrity_suitability_azores.png")
    crlb = result.crlb.values[np.isfinite(result.crlb.values)]
    q = np.percentile(crlb, [10, 50, 90])
    return (
        "### Where to route the vehicle: suitability of the Azores demo map\n\n"
        "`geofix suitability builtin:azores --region -31.5 -28.5 37.5 40 --resample-m 1000 "
        "--noise-std 5`: the depth std and roughness in a 21-cell window, and the CRLB of a "
        "21-sounding straight track through each cell (worst of four headings, 5 m noise). "
        f"CRLB percentiles over the map: 10 % {q[0]:.0f} m, median {q[1]:.0f} m, 90 % "
        f"{q[2]:.0f} m (1000 m cells): a factor {q[2] / q[0]:.0f} between the best and the "
        "worst tenth of the map, the steep ridge flanks best, the smooth basins worst.\n\n"
        f"![suitability](figures/{path.name})\n"
    )
