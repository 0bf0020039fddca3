"""Helpers shared by the result sections: run a scenario, format tables."""

from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent
SCENARIOS = HERE.parent / "scenarios"
ROOT = HERE.parent.parent
FIGURES = ROOT / "docs" / "figures"
OUT = ROOT / "out" / "results"


PROSE = HERE / "prose"


def prose(name: str, **values) -> str:
    """The Markdown text ``sections/prose/NAME.md`` with ``{key}`` fields filled in."""
    return (PROSE / f"{name}.md").read_text().format_map(values)


def scenario(name: str):
    """Load ``benchmarks/scenarios/NAME.yaml``."""
    from geofix.sim.scenario import load_scenario

    return load_scenario(SCENARIOS / f"{name}.yaml")


def campaign(scen, methods: list[str], trials: int | None = None, jobs: int | None = None):
    """Run (or resume) a campaign into ``out/results/<scenario name>``; return its result."""
    from geofix.console import ProgressBar
    from geofix.evaluate.campaign import run_campaign

    with ProgressBar(scen.name) as bar:
        return run_campaign(
            scen, methods, trials=trials, jobs=jobs, out_dir=OUT / scen.name, progress=bar
        )


def fmt(value, digits: int = 2) -> str:
    """A number for a Markdown table (``-`` for missing)."""
    if value is None:
        return "-"
    try:
        return f"{float(value):.{digits}f}"
    except (TypeError, ValueError):
        return str(value)


def md_table(header: list[str], rows: list[list]) -> str:
    """A Markdown table from a header and rows of already formatted cells."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def summary_rows(methods: dict, success_keys=("20", "40", "60", "80", "100")) -> list[list]:
    """Rows of method, mean/std/median/max end error, success rates, time per match.

    ``methods`` is ``{spec: MethodStats}`` (a campaign summary's ``methods``, or a part).
    """
    rows = []
    for spec, m in methods.items():
        rates = [
            fmt(100 * m.success_rate[k], 0) if m.success_rate.get(k) is not None else "-"
            for k in success_keys
        ]
        rows.append(
            [
                f"`{spec}`",
                fmt(m.mean_error_m),
                fmt(m.std_error_m),
                fmt(m.median_error_m),
                fmt(m.max_error_m),
                *rates,
                fmt(m.mean_time_s * 1e3, 1),
                m.failures,
            ]
        )
    return rows


def summary_header(success_keys=("20", "40", "60", "80", "100")) -> list[str]:
    """Header matching :func:`summary_rows`."""
    return [
        "method",
        "mean (m)",
        "std (m)",
        "median (m)",
        "max (m)",
        *[f"≤{k} m (%)" if not k.endswith("c") else f"≤{k[:-1]} cells (%)" for k in success_keys],
        "time/match (ms)",
        "failures",
    ]


def save_section_figure(fig, name: str) -> str:
    """Write a figure to ``docs/figures/NAME`` (:func:`geofix.plot.save_figure`); its name."""
    from geofix.plot import save_figure

    return save_figure(fig, FIGURES / name, dpi=110).name
