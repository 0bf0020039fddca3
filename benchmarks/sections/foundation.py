"""TERCOM on the bundled Azores demo: the four scores, and time per match."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from _common import (
    campaign,
    fmt,
    md_table,
    prose,
    save_section_figure,
    summary_header,
    summary_rows,
)

TITLE = "TERCOM baseline on real bathymetry (foundation)"
ORDER = 10
METHODS = ["tercom", "tercom:metric=mad", "tercom:metric=cor", "tercom:metric=ncor"]


def _demo_scenario():
    from geofix.cli import builtin_scenario
    from geofix.sim.scenario import load_scenario

    return load_scenario(builtin_scenario("azores_demo"))


def _timing() -> tuple[float, float]:
    """Best time per match of the numba kernel and of the numpy reference (seconds)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    from bench_tercom import best_time, make_problem, numpy_reference
    from geofix.match.tercom import Tercom

    rng = np.random.default_rng(0)
    problem = make_problem(rng)
    matcher = Tercom(window_m=150 * 100.0)
    matcher.match(problem, rng)
    ox, oy = matcher.candidate_offsets(problem)
    return (
        best_time(lambda: matcher.match(problem, rng), 5),
        best_time(lambda: numpy_reference(problem, ox, oy), 2),
    )


def _figure(scen, result) -> str:
    from geofix.plot.campaign import campaign_result_figure

    return save_section_figure(campaign_result_figure(scen, result), "foundation_azores_demo.png")


def _mean_ms(result, spec: str) -> float:
    return result.summary.methods[spec].mean_time_s * 1e3


def build(quick: bool = False) -> str:
    """Run the demo campaign with every TERCOM score and the timing benchmark."""
    scen = _demo_scenario()
    result = campaign(scen, METHODS, trials=10 if quick else scen.trials)
    keys = ("100", "0.5c", "1c", "2c")
    table = md_table(summary_header(keys), summary_rows(result.summary.methods, keys))
    t_numba, t_numpy = _timing()
    fig = _figure(scen, result)
    ins = result.frame.groupby("method")["end_error_m"].count().iloc[0]
    return prose(
        "foundation",
        title=TITLE,
        scenario=scen.name,
        ins=ins,
        table=table,
        fig=fig,
        t_numba_ms=f"{t_numba * 1e3:.1f}",
        t_numpy_ms=f"{t_numpy * 1e3:.0f}",
        ratio=f"{t_numpy / t_numba:.0f}",
        tercom_ms=fmt(_mean_ms(result, "tercom"), 1),
    )
