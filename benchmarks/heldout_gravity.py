"""Held-out gravity missions: a gravity default judged on maps and errors no section runs.

``python benchmarks/heldout_gravity.py [--trials N] [--spec SPEC ...]`` runs every row of
:data:`ROWS` (a ``seabed:`` block on each held-out mission of ``benchmarks/heldout/``) for
each method spec and prints one Markdown table: end RMS (m) / median NEES / false fixes
(as the section *Imperfect maps* counts them). Campaigns are stored under
``out/heldout/`` and resumed. The default specs are the INS alone (what a filter must beat
for the map to have helped) and the filters at their defaults beside the walks alone
(``offset_smooth_m=0``), the comparison on which a gravity map's default smooth offset was
judged.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
HELD_OUT = HERE / "heldout"
OUT = HERE.parent / "out" / "heldout"

#: Per held-out mission, the prior maps against its field: label -> seabed block.
ROWS = {
    "heldout_gravity_ak": {
        "2.5 mGal over 1 km": {"error_rms": 2.5, "error_corr_m": 1000.0},
        "2.5 mGal over 2.5 km": {"error_rms": 2.5, "error_corr_m": 2500.0},
        "2 mGal over 5 km": {"error_rms": 2.0, "error_corr_m": 5000.0},
    },
    "heldout_gravity_1km": {
        "3 mGal over 1.2 km": {"error_rms": 3.0, "error_corr_m": 1200.0},
        "2 mGal over 4 km": {"error_rms": 2.0, "error_corr_m": 4000.0},
        "mix: 4x cells, 80 m shift, 1.5 mGal offset, 1.5 mGal over 2 km": {
            "cell_factor": 4,
            "misregistration_m": 80.0,
            "offset": 1.5,
            "error_rms": 1.5,
            "error_corr_m": 2000.0,
        },
    },
}
SPECS = (
    "ins",
    "pmf",
    "pf",
    "mpf",
    "pmf:offset_smooth_m=0",
    "pf:offset_smooth_m=0",
    "mpf:offset_smooth_m=0",
)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=8)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--spec", action="append", help="a method spec (repeatable)")
    args = parser.parse_args(argv)
    specs = list(args.spec or SPECS)
    sys.path.insert(0, str(HERE))
    from geofix.evaluate.campaign import run_campaign
    from geofix.sim.scenario import load_scenario
    from sections._common import md_table
    from sections.imperfect import _cells, _with_seabed

    table = []
    for name, rows in ROWS.items():
        base = load_scenario(HELD_OUT / f"{name}.yaml")
        for label, seabed in rows.items():
            scen = _with_seabed(base, label, seabed)
            result = run_campaign(
                scen, specs, trials=args.trials, jobs=args.jobs, out_dir=OUT / scen.name
            )
            cell = float(base.map.resample_m) * seabed.get("cell_factor", 1)
            for spec in specs:
                table.append([name, label, f"`{spec}`", *_cells(result.frame, spec, cell)])
            print(f"{name} {json.dumps(seabed)}: done", file=sys.stderr, flush=True)
    header = ["mission", "prior map", "method", "end RMS (m)", "median NEES", "false fixes"]
    print(md_table(header, table))


if __name__ == "__main__":
    main()
