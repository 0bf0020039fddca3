"""Imperfect maps: the readings on the seabed, the methods on a degraded prior map."""

from __future__ import annotations

import numpy as np

from sections._common import campaign, fmt, md_table, scenario

TITLE = "Imperfect maps — the prior map is not the seabed"
ORDER = 72

TRIALS, QUICK_TRIALS = 8, 2
METHODS = (
    "pmf",
    "pmf:map_model=exact",
    "pf",
    "pf:map_model=exact",
    "mpf",
    "mpf:map_model=exact",
    "pmf:model=errstate",
    "tercom",
)
#: Each row's seabed: block, per bundled scenario (None: the prior is the seabed).
ROWS = {
    "imperfect_depth": {
        "identical": None,
        "5 x 5 block means (50 m cells)": {"cell_factor": 5},
        "+3 m vertical offset": {"offset": 3.0},
        "correlated error, 2 m rms over 300 m": {"error_rms": 2.0, "error_corr_m": 300.0},
        "20 m misregistration": {"misregistration_m": 20.0},
        "mix: 50 m cells, 10 m shift, 1 m offset, 1 m correlated": {
            "cell_factor": 5,
            "misregistration_m": 10.0,
            "offset": 1.0,
            "error_rms": 1.0,
            "error_corr_m": 300.0,
        },
    },
    "imperfect_gravity": {
        "identical": None,
        "5 x 5 block means (500 m cells)": {"cell_factor": 5},
        "+3 mGal offset": {"offset": 3.0},
        "gravimeter drift 2 mGal/h": {"drift_per_h": 2.0},
        "correlated error, 2 mGal rms over 3 km": {"error_rms": 2.0, "error_corr_m": 3000.0},
        "mix: 500 m cells, 100 m shift, 1 mGal offset, 1 mGal correlated": {
            "cell_factor": 5,
            "misregistration_m": 100.0,
            "offset": 1.0,
            "error_rms": 1.0,
            "error_corr_m": 3000.0,
        },
    },
}
FALSE_FIX_CELLS = 2.0
FALSE_FIX_SIGMAS = 3.0


def build(quick: bool) -> str:
    """Run every row of both scenarios and write the section."""
    trials = QUICK_TRIALS if quick else TRIALS
    parts = [f"## {TITLE}\n", _intro(trials)]
    for name, rows in ROWS.items():
        base = scenario(name)
        parts.append(f"### `{name}`\n")
        table = []
        for label, seabed in rows.items():
            scen = _with_seabed(base, label, seabed)
            result = campaign(scen, list(METHODS), trials=trials, jobs=2)
            cell = float(base.map.resample_m) * (seabed or {}).get("cell_factor", 1)
            table += [[label, spec, *_cells(result.frame, spec, cell)] for spec in METHODS]
        header = ["prior map", "method", "end RMS (m)", "median NEES", "false fixes"]
        parts.append(md_table(header, table))
    parts.append(_reading())
    return "\n".join(parts)


def _with_seabed(base, label: str, seabed: dict | None):
    from geofix.sim.scenario import scenario_from_dict

    data = base.model_dump()
    if seabed is not None:
        slug = "".join(c if c.isalnum() else "_" for c in label.split(":")[0])[:24]
        data["name"] = f"{base.name}-{slug}"
        data["seabed"] = dict(seabed)
    return scenario_from_dict(data, base_dir=base.base_dir)


def _cells(frame, spec: str, prior_cell: float) -> list[str]:
    rows = frame[frame["method"] == spec]
    err = rows["end_error_m"].to_numpy(dtype=float)
    dist = rows["end_mahalanobis"].to_numpy(dtype=float)
    amb = rows["ambiguous"].to_numpy(dtype=bool)
    false = (err > FALSE_FIX_CELLS * prior_cell) & ~amb & ~(dist <= FALSE_FIX_SIGMAS)
    finite = np.isfinite(dist)
    nees = float(np.median(dist[finite] ** 2)) if finite.any() else float("nan")
    rms = float(np.sqrt(np.nanmean(err**2))) if err.size else float("nan")
    return [fmt(rms, 1), _nees(nees), f"{int(false.sum())} of {err.size}"]


def _nees(value: float) -> str:
    if not np.isfinite(value):
        return "-"
    return f"{value:.2f}" if value < 100 else f"{value:.2g}"


def _intro(trials: int) -> str:
    return (
        "Every other section simulates its readings from the very grid its methods match "
        "against. Here the scenario's map is the *seabed*, the field the sensor reads, and "
        "the methods get a *prior map* degraded from it by a `seabed:` block "
        "(`geofix.sim.seabed`), one mismatch per row and a realistic mix, "
        f"{trials} trials per row with the same seeds in every row. Default settings, nothing "
        "told about the map's errors. The filters' default `map_model=imperfect` adds the "
        "map's representation error per beam at the share the innovations support, scales "
        "the noise to the innovations and estimates a common offset (measured minus map): "
        "per hypothesis for single-beam profiles, one for the navigator for multibeam pings "
        "(`geofix.filters.nuisance`, `geofix.filters.hypothesis_offset`); "
        "`map_model=exact` is the map taken as the seabed. A false fix ends more than "
        f"{FALSE_FIX_CELLS:g} prior cells from the truth, outside its "
        f"{FALSE_FIX_SIGMAS:g}-sigma ellipse and not flagged ambiguous. The NEES is the "
        "median over the trials of the end point's `e' C^-1 e` (2 when consistent). "
        "No bound of the imperfect-map problem is computed yet, so this section states no "
        "ratio to one.\n"
    )


def _reading() -> str:
    return (
        "\nReading the tables: with the map taken as exact (`map_model=exact`) an offset or "
        "a correlated error makes every filter diverge with a small covariance (median NEES "
        "in the thousands and more); the default keeps the covariance honest on the offset "
        "and the coarser map, at a cost in accuracy on the identical map: a campaign reports "
        "no status, so a multibeam ping is marginalised over the offset's prior and forgets "
        "the absolute level (the online navigator learns it once converged). Where a row "
        "still shows false fixes or a NEES above 5, the model does not yet hold there: the "
        "open work is listed in the imperfect-maps issue.\n"
    )
