"""A campaign report a person opens in a browser: one self-contained HTML page.

:func:`write_report` reads a campaign folder -- the ``summary.json`` and ``results.sqlite``
that :func:`geofix.evaluate.campaign.run_campaign` (``geofix run``) writes -- and renders

- the summary of every method: end-point errors, success rates, integrity and cost;
- the Cramér–Rao bound of the campaign beside each method's RMS end error;
- each method's settings (the specification parsed by
  :func:`geofix.methods.parse_method_spec`, changed settings marked);
- figures drawn from the stored per-trial results: end-error histograms (one panel per
  method), the empirical CDF of the end errors and the error of every trial against the
  trial's own bound, plus ``campaign.png`` when ``geofix run --figure`` wrote one.

The page has no external reference: the style sheet is inline and every figure is an
embedded base64 PNG, so the file can be mailed or archived alone.
"""

from __future__ import annotations

import base64
import dataclasses
import html
import io
import math
from collections.abc import Iterable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pandas as pd

from geofix._atomic import check_target, write_text_atomic
from geofix._version import __version__
from geofix.errors import ConfigError, GeofixError
from geofix.evaluate.store import (
    STORE_NAME,
    SUMMARY_NAME,
    ResultStore,
    read_summary,
    store_errors,
)
from geofix.methods import available_methods, method_settings, parse_method_spec
from geofix.plot.figures import pyplot

REPORT_NAME = "report.html"
CAMPAIGN_FIGURE_NAME = "campaign.png"


@dataclass(frozen=True)
class Campaign:
    """What a campaign folder holds, as the report needs it.

    Parameters
    ----------
    summary : dict
        The contents of ``summary.json`` (see
        :func:`geofix.evaluate.metrics.summarize` for the per-method keys).
    frame : pandas.DataFrame
        One row per (method, trial) of this campaign, scalar columns of
        :data:`geofix.evaluate.store.SCALAR_COLUMNS` (errors in metres, times in seconds).
    trial_crlb_m : dict of int to float
        The recursive Cramér–Rao bound of each trial, metres (empty if the store has none).
    figure_png : bytes or None
        The ``campaign.png`` of the folder, if any.
    """

    summary: dict
    frame: pd.DataFrame
    trial_crlb_m: dict[int, float]
    figure_png: bytes | None


@dataclass(frozen=True)
class Setting:
    """One setting of a method: its name, the value used and its default."""

    name: str
    value: object
    default: object

    @property
    def changed(self) -> bool:
        """True when the specification overrides the default."""
        return self.value != self.default


# --------------------------------------------------------------------------- reading
def read_campaign(out_dir: str | Path) -> Campaign:
    """Read a campaign folder written by ``geofix run``.

    Parameters
    ----------
    out_dir : str or pathlib.Path
        Folder holding ``summary.json`` and ``results.sqlite``.

    Returns
    -------
    Campaign

    Raises
    ------
    ConfigError
        The folder, its summary or its results store is missing or unreadable, or the
        store holds no complete set of rows for the summary's campaign.
    """
    out = Path(out_dir)
    summary = _read_summary(out)
    if not (out / STORE_NAME).is_file():
        raise ConfigError(f"no results store {out / STORE_NAME} (run `geofix run --out {out}`)")
    with store_errors(out / STORE_NAME), ResultStore(out) as store:
        rows = store.to_frame()
        shash, frame = _campaign_rows(rows, summary, out)
        bounds = store.trial_bounds(shash)
    figure = out / CAMPAIGN_FIGURE_NAME
    return Campaign(
        summary=summary,
        frame=frame,
        trial_crlb_m=_trial_crlb_m(bounds),
        figure_png=figure.read_bytes() if figure.is_file() else None,
    )


def _read_summary(out: Path) -> dict:
    """``out/summary.json`` (:func:`geofix.evaluate.store.read_summary`), keys checked."""
    summary = read_summary(out)
    path = out / SUMMARY_NAME
    missing = {"scenario", "trials", "methods"} - set(summary)
    if missing:
        raise ConfigError(f"campaign summary {path} lacks keys {sorted(missing)}")
    _check_summary(summary, path)
    return summary


_NUMBER_KEYS = ("crlb_m", "crlb_batch_m")
_METHOD_COUNTS = ("trials", "failures")
_METHOD_NUMBERS = (
    *("mean_error_m", "std_error_m", "median_error_m", "max_error_m", "mean_track_error_m"),
    *("false_fix_rate", "ambiguous_rate", "mean_time_s", "mean_evaluations", "success_rate"),
)


def _check_summary(summary: dict, path: Path) -> None:
    """Refuse a summary whose values the page shows do not have the types ``run`` writes.

    ``scenario`` a string, ``trials`` a count, ``methods`` an object of objects whose
    counts are counts and whose shown values are numbers, null or, for
    ``success_rate``, an object of them.
    """
    if not isinstance(summary["scenario"], str):
        raise ConfigError(f"campaign summary {path}: scenario is not a string")
    if not _is_count(summary["trials"]):
        raise ConfigError(f"campaign summary {path}: trials is not a count")
    for key in _NUMBER_KEYS:
        if not _is_number(summary.get(key)):
            raise ConfigError(f"campaign summary {path}: {key} is not a number")
    methods = summary["methods"]
    if not isinstance(methods, dict) or not all(isinstance(v, dict) for v in methods.values()):
        raise ConfigError(f"campaign summary {path}: methods is not an object of methods")
    for spec, stats in methods.items():
        for key in (k for k in (*_METHOD_COUNTS, *_METHOD_NUMBERS) if k in stats):
            value = stats[key]
            fine = _is_count(value) if key in _METHOD_COUNTS else _is_number_or_rates(value)
            if not fine:
                raise ConfigError(
                    f"campaign summary {path}: methods.{spec[:60]}.{key} is not a "
                    + ("count" if key in _METHOD_COUNTS else "number")
                )
        if "trials" not in stats:
            raise ConfigError(f"campaign summary {path}: methods.{spec[:60]} lacks trials")


def _is_count(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _is_number(value: object) -> bool:
    """A JSON number or null (a bool is not a number here)."""
    return value is None or (isinstance(value, int | float) and not isinstance(value, bool))


def _is_number_or_rates(value: object) -> bool:
    if isinstance(value, dict):
        return all(_is_number(v) for v in value.values())
    return _is_number(value)


def _campaign_rows(rows: pd.DataFrame, summary: dict, out: Path) -> tuple[str, pd.DataFrame]:
    """The scenario hash and rows that the summary was computed from.

    A store may hold several scenarios (or versions of one); the rows chosen are those of
    the summary's scenario name whose every (method, trial) pair is present and whose mean
    end errors agree best with the summary's.
    """
    specs = list(summary["methods"])
    trials = int(summary["trials"])
    mine = rows[
        (rows["scenario"] == summary["scenario"])
        & rows["method"].isin(specs)
        & (rows["trial"] < trials)
    ]
    best, best_gap = None, math.inf
    for shash, group in mine.groupby("scenario_hash", sort=False):
        if len(group) != len(specs) * trials:
            continue
        gap = _summary_gap(group, summary)
        if gap < best_gap:
            best, best_gap = shash, gap
    if best is None:
        raise ConfigError(
            f"{out / STORE_NAME} holds no complete results of campaign "
            f"{summary['scenario']!r} ({len(specs)} methods x {trials} trials)"
        )
    frame = mine[mine["scenario_hash"] == best].copy()
    order = {spec: k for k, spec in enumerate(specs)}
    frame["_order"] = frame["method"].map(order)
    frame = frame.sort_values(["_order", "trial"], kind="stable").drop(columns="_order")
    return str(best), frame.reset_index(drop=True)


def _summary_gap(group: pd.DataFrame, summary: dict) -> float:
    """Sum over methods of ``|mean end error of the rows - the summary's|``, metres."""
    gap = 0.0
    for spec, stats in summary["methods"].items():
        rows = group[(group["method"] == spec) & ~group["failed"]]
        mean = stats.get("mean_error_m")
        if mean is not None and len(rows):
            gap += abs(float(rows["end_error_m"].mean()) - float(mean))
    return gap


def _trial_crlb_m(bounds: dict) -> dict[int, float]:
    """Per-trial recursive CRLB, metres, from the store's trial bounds (those known)."""
    return {t: math.sqrt(i.crlb_var_m2) for t, i in bounds.items() if i.crlb_var_m2 >= 0}


def method_description(spec: str) -> str:
    """The first line of the docstring of the method a specification names ('' if unknown)."""
    cls = available_methods().get(spec.partition(":")[0].strip())
    doc = (cls.__doc__ or "").strip() if cls else ""
    return doc.splitlines()[0] if doc else ""


def spec_settings(spec: str) -> list[Setting]:
    """Every setting of the method a specification builds, with its default.

    Raises
    ------
    ConfigError
        The specification names an unknown method or setting.
    """
    method = parse_method_spec(spec)
    values = dataclasses.asdict(method)
    return [
        Setting(name, values[name], default)
        for name, default, _ in method_settings(type(method))
        if name in values
    ]


# --------------------------------------------------------------------------- figures
def _ticker():
    import matplotlib.ticker

    return matplotlib.ticker


def _log_axis(axis) -> None:
    """A logarithmic axis labelled in plain numbers (1, 2, 5, 10, 20, ...), not powers."""
    ticker = _ticker()
    axis.axes.set_xscale("log") if axis.axis_name == "x" else axis.axes.set_yscale("log")

    def label(value: float, _pos=None, every: tuple = (1,)) -> str:
        mantissa = round(value / 10 ** math.floor(math.log10(value))) if value > 0 else 0
        return f"{value:g}" if mantissa in every else ""

    axis.set_major_formatter(ticker.FuncFormatter(label))
    axis.set_minor_formatter(ticker.FuncFormatter(lambda v, p: label(v, p, every=(2, 5))))


def _line_style(k: int, n: int) -> dict:
    """Line width and dash of curve ``k`` of ``n``: earlier curves wider, so none hides."""
    dashes = ("-", "--", "-.", ":")
    return {"linewidth": 1.4 + 2.2 * (n - 1 - k) / max(n - 1, 1), "linestyle": dashes[k % 4]}


def _colours(n: int) -> list:
    cmap = pyplot().get_cmap("tab10")
    return [cmap(k % 10) for k in range(n)]


def _end_errors(frame: pd.DataFrame, spec: str) -> np.ndarray:
    rows = frame[(frame["method"] == spec) & ~frame["failed"]]
    errors = rows["end_error_m"].to_numpy(dtype=float)
    return errors[np.isfinite(errors)]


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    pyplot().close(fig)
    return buf.getvalue()


def _error_bins(
    errors: Iterable[np.ndarray], crlb_m: float | None = None
) -> tuple[np.ndarray, bool]:
    """Common bins over all methods and the bound; logarithmic when they span > 30x."""
    values = np.concatenate([e for e in errors if e.size] or [np.array([1.0])])
    if crlb_m and math.isfinite(crlb_m):
        values = np.append(values, crlb_m)
    low, high = max(float(values.min()), 1e-3), max(float(values.max()), 1e-3)
    if high / low > 30.0:
        return np.geomspace(low / 1.05, high * 1.05, 31), True
    pad = 0.05 * (high - low) or 0.5
    return np.linspace(max(low - pad, 0.0), high + pad, 31), False


def histogram_figure(frame: pd.DataFrame, specs: list[str], crlb_m: float | None) -> bytes:
    """End-point error histograms, one panel per method on a shared axis, as PNG bytes.

    Parameters
    ----------
    frame : pandas.DataFrame
        The campaign's rows (:attr:`Campaign.frame`; end errors in metres).
    specs : list of str
        The methods, in the summary's order.
    crlb_m : float or None
        The campaign's RMS CRLB, metres (a dashed line; None: none).
    """
    plt = pyplot()
    errors = [_end_errors(frame, s) for s in specs]
    bins, log = _error_bins(errors, crlb_m)
    fig, axes = plt.subplots(
        len(specs), 1, figsize=(8, 1.3 + 1.25 * len(specs)), sharex=True, squeeze=False
    )
    for ax, spec, err, colour in zip(axes[:, 0], specs, errors, _colours(len(specs)), strict=True):
        ax.hist(err, bins=bins, color=colour, edgecolor="white", linewidth=0.5)
        _bound_line(ax, crlb_m)
        ax.set_ylabel("trials")
        ax.yaxis.set_major_locator(_ticker().MaxNLocator(integer=True))
        ax.set_title(spec, loc="left", fontsize=10)
        ax.spines[["top", "right"]].set_visible(False)
    if log:
        _log_axis(axes[-1, 0].xaxis)
    axes[-1, 0].set_xlabel("end-point error (m)")
    if crlb_m:
        axes[0, 0].legend(loc="upper right", frameon=False, fontsize=8)
    fig.tight_layout()
    return _png(fig)


def cdf_figure(frame: pd.DataFrame, specs: list[str], crlb_m: float | None) -> bytes:
    """Empirical CDF of the end-point errors of every method, as PNG bytes.

    Parameters
    ----------
    frame : pandas.DataFrame
        The campaign's rows (:attr:`Campaign.frame`; end errors in metres).
    specs : list of str
        The methods, in the summary's order.
    crlb_m : float or None
        The campaign's RMS CRLB, metres (a dashed line; None: none).
    """
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.2))
    errors = [_end_errors(frame, s) for s in specs]
    for k, (spec, err, colour) in enumerate(zip(specs, errors, _colours(len(specs)), strict=True)):
        if err.size:
            values = np.sort(err)
            share = np.arange(1, values.size + 1) / values.size
            ax.step(
                values, share, where="post", color=colour, label=spec, **_line_style(k, len(specs))
            )
    _bound_line(ax, crlb_m)
    if _error_bins(errors, crlb_m)[1]:
        _log_axis(ax.xaxis)
    ax.set_xlabel("end-point error (m)")
    ax.set_ylabel("share of trials with a smaller error")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(frameon=False, fontsize=8, loc="lower right")
    ax.spines[["top", "right"]].set_visible(False)
    fig.tight_layout()
    return _png(fig)


def trial_figure(frame: pd.DataFrame, specs: list[str], trial_crlb_m: dict[int, float]) -> bytes:
    """End-point error of every trial and method beside the trial's own bound, as PNG bytes.

    Parameters
    ----------
    frame : pandas.DataFrame
        The campaign's rows (:attr:`Campaign.frame`; end errors in metres).
    specs : list of str
        The methods, in the summary's order.
    trial_crlb_m : dict of int to float
        Each trial's recursive CRLB, metres (:attr:`Campaign.trial_crlb_m`).
    """
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.2))
    markers = "os^Dv<>ph*"
    for k, (spec, colour) in enumerate(zip(specs, _colours(len(specs)), strict=True)):
        rows = frame[(frame["method"] == spec) & ~frame["failed"]]
        ax.plot(
            rows["trial"],
            rows["end_error_m"],
            linestyle="none",
            marker=markers[k % len(markers)],
            markersize=4 + 2.5 * (len(specs) - 1 - k) / max(len(specs) - 1, 1),
            markerfacecolor="none",
            color=colour,
            label=spec,
        )
    if trial_crlb_m:
        trials = sorted(trial_crlb_m)
        bound = [trial_crlb_m[t] for t in trials]
        ax.plot(trials, bound, color="0.3", linewidth=1.2, label="CRLB of the trial")
    _log_axis(ax.yaxis)
    ax.xaxis.set_major_locator(_ticker().MaxNLocator(integer=True))
    ax.set_xlabel("trial")
    ax.set_ylabel("end-point error (m)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(frameon=False, fontsize=8, ncols=2)
    ax.spines[["top", "right"]].set_visible(False)
    fig.tight_layout()
    return _png(fig)


def _bound_line(ax, crlb_m: float | None) -> None:
    if crlb_m:
        ax.axvline(crlb_m, color="0.2", linestyle="--", linewidth=1, label="CRLB (RMS)")


# --------------------------------------------------------------------------- HTML
_CSS = """
body{font:15px/1.5 system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;color:#1d2330;
margin:0;background:#f5f6f8}
main{max-width:1100px;margin:0 auto;padding:24px 28px 48px;background:#fff}
h1{font-size:26px;margin:8px 0 4px}h2{font-size:19px;margin:34px 0 8px;
border-bottom:2px solid #e3e6ec;padding-bottom:4px}h3{font-size:15px;margin:18px 0 4px}
p.meta{color:#5b6475;margin:0 0 10px}p.note{color:#5b6475;font-size:13px;margin:4px 0}
table{border-collapse:collapse;margin:8px 0 6px;font-size:13.5px}
th,td{padding:4px 10px;border-bottom:1px solid #e3e6ec;text-align:right}
th{background:#eef1f6;font-weight:600}th:first-child,td:first-child{text-align:left}
td.spec{font-family:ui-monospace,SFMono-Regular,Menlo,monospace;white-space:nowrap}
tbody tr:nth-child(even){background:#fafbfc}td.best{font-weight:700;color:#0b5d1e}
tr.changed td{background:#fff6d6}code{font-family:ui-monospace,Menlo,monospace}
dl.bound{display:grid;grid-template-columns:max-content auto;gap:2px 16px;margin:6px 0}
dl.bound dt{font-weight:600}dl.bound dd{margin:0}
figure{margin:14px 0}figure img{max-width:100%;border:1px solid #e3e6ec}
figcaption{color:#5b6475;font-size:13px}
div.cards{display:flex;flex-wrap:wrap;gap:10px 28px}div.card h3{margin-bottom:0}
"""


def _esc(value: object) -> str:
    return html.escape(str(value), quote=True)


def _num(value: float | None, digits: int = 1, scale: float = 1.0) -> str:
    if value is None or not math.isfinite(float(value)):
        return "–"
    return f"{scale * float(value):.{digits}f}"


def _pct(value: float | None) -> str:
    return _num(value, 0, 100.0) + ("" if value is None else " %")


def _table(
    caption: str,
    head: list[str],
    rows: list[list[str]],
    best: dict[int, int | None] | None = None,
) -> str:
    """An HTML table; ``rows`` are escaped cells, the first one the method specification.

    ``best`` maps a column to the row of its best value (None: no best in that column).
    """
    best = best or {}
    body = []
    for r, row in enumerate(rows):
        cells = [f'<td class="spec">{row[0]}</td>']
        cells += [
            f'<td class="best">{c}</td>' if best.get(k + 1) == r else f"<td>{c}</td>"
            for k, c in enumerate(row[1:])
        ]
        body.append(f"<tr>{''.join(cells)}</tr>")
    header = "".join(f"<th>{_esc(h)}</th>" for h in head)
    return (
        f'<table data-caption="{_esc(caption)}"><thead><tr>{header}</tr></thead>'
        f"<tbody>{''.join(body)}</tbody></table>"
    )


def _lowest(values: list[float | None]) -> int | None:
    """Index of the smallest finite value, None if there is none."""
    finite = [(v, k) for k, v in enumerate(values) if v is not None and math.isfinite(v)]
    return min(finite)[1] if finite else None


def _accuracy_table(methods: dict) -> str:
    keys = ["mean_error_m", "std_error_m", "median_error_m", "max_error_m", "mean_track_error_m"]
    head = ["method", "trials", "failed", "mean", "std", "median", "max", "mean along track"]
    rows = [
        [_esc(spec), _esc(s["trials"]), _esc(s.get("failures", 0))] + [_num(s.get(k)) for k in keys]
        for spec, s in methods.items()
    ]
    best = {k + 3: _lowest([s.get(key) for s in methods.values()]) for k, key in enumerate(keys)}
    return _table("accuracy", head, rows, best)


def _success_table(methods: dict) -> str:
    keys = ["20", "40", "60", "80", "100", "0.5c", "1c", "2c", "3c"]
    head = ["method"] + [f"≤ {k} m" for k in keys[:5]] + [f"≤ {k[:-1]} cell" for k in keys[5:]]
    rows = [
        [_esc(spec)] + [_pct(s.get("success_rate", {}).get(k)) for k in keys]
        for spec, s in methods.items()
    ]
    return _table("success", head, rows)


def _integrity_table(methods: dict) -> str:
    head = ["method", "false fixes", "flagged ambiguous", "ms per call", "evaluations / trial"]
    rows = [
        [
            _esc(spec),
            _pct(s.get("false_fix_rate")),
            _pct(s.get("ambiguous_rate")),
            _num(s.get("mean_time_s"), 2, 1000.0),
            _num(s.get("mean_evaluations"), 0),
        ]
        for spec, s in methods.items()
    ]
    return _table("integrity", head, rows)


def rms_error_m(stats: dict) -> float | None:
    """RMS end-point error of a method from its summary: ``sqrt(mean^2 + std^2)``, metres.

    Exact, since the summary's standard deviation is the population one (``ddof=0``).
    """
    mean, std = stats.get("mean_error_m"), stats.get("std_error_m")
    if mean is None or std is None:
        return None
    return math.hypot(float(mean), float(std))


def _bound_section(summary: dict) -> str:
    crlb, batch = summary.get("crlb_m"), summary.get("crlb_batch_m")
    rows = []
    for spec, stats in summary["methods"].items():
        rms = rms_error_m(stats)
        ratio = rms / crlb if rms is not None and crlb else None
        rows.append([_esc(spec), _num(rms), _num(ratio, 2)])
    return (
        "<h2>Cramér–Rao bound</h2>"
        '<dl class="bound">'
        f"<dt>recursive (whole mission)</dt><dd>{_num(crlb, 2)} m</dd>"
        f"<dt>batch (last leg)</dt><dd>{_num(batch, 2)} m</dd></dl>"
        '<p class="note">The RMS end-point error no unbiased estimator can beat on these '
        "trials, from the map gradients under the true track and the declared sensor and map "
        "noise. A ratio near 1 is as good as the terrain allows; below 1 the method leans on "
        "its prior (the bound is local and per trial, not strict).</p>"
        + _table(
            "bound",
            ["method", "RMS end error (m)", "RMS / CRLB"],
            rows,
        )
    )


def _settings_section(specs: list[str]) -> str:
    cards = []
    for spec in specs:
        head = f"<h3><code>{_esc(spec)}</code></h3><p class=note>{_esc(method_description(spec))}"
        try:
            settings = spec_settings(spec)
        except GeofixError as exc:
            cards.append(
                f'<div class="card">{head}</p><p>settings unavailable: {_esc(exc)}</p></div>'
            )
            continue
        changed = sum(s.changed for s in settings)
        rows = "".join(
            f'<tr{" class=changed" if s.changed else ""}><td class="spec">{_esc(s.name)}</td>'
            f"<td>{_esc(_value(s.value))}</td><td>{_esc(_value(s.default))}</td></tr>"
            for s in settings
        )
        cards.append(
            f'<div class="card">{head} {len(settings)} settings, {changed} changed.</p>'
            f'<table data-caption="settings {_esc(spec)}"><thead><tr><th>setting</th>'
            f"<th>value</th><th>default</th></tr></thead><tbody>{rows}</tbody></table></div>"
        )
    return (
        "<h2>Method settings</h2><p class=note>Settings changed by the specification are "
        f'highlighted.</p><div class="cards">{"".join(cards)}</div>'
    )


def _value(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, tuple | list):
        return "/".join(_value(v) for v in value)
    return repr(value) if isinstance(value, str) else str(value)


def _figure(png: bytes, alt: str, caption: str) -> str:
    data = base64.b64encode(png).decode("ascii")
    return (
        f'<figure><img alt="{_esc(alt)}" src="data:image/png;base64,{data}">'
        f"<figcaption>{_esc(caption)}</figcaption></figure>"
    )


def _figures_section(campaign: Campaign, specs: list[str]) -> str:
    crlb = campaign.summary.get("crlb_m")
    parts = [
        "<h2>Figures</h2>",
        _figure(
            histogram_figure(campaign.frame, specs, crlb),
            "end-point error histograms",
            "End-point error of every trial, one panel per method (dashed: the RMS CRLB).",
        ),
        _figure(
            cdf_figure(campaign.frame, specs, crlb),
            "cumulative distribution of end-point errors",
            "Share of trials whose end-point error is below a value (dashed: the RMS CRLB).",
        ),
        _figure(
            trial_figure(campaign.frame, specs, campaign.trial_crlb_m),
            "end-point error per trial",
            "End-point error of each trial beside that trial's own recursive CRLB.",
        ),
    ]
    if campaign.figure_png is not None:
        parts.append(
            _figure(
                campaign.figure_png,
                "campaign figure",
                "Trial 0 on the map and the error histograms (campaign.png, geofix run --figure).",
            )
        )
    return "".join(parts)


def campaign_report(out_dir: str | Path) -> str:
    """The HTML page of a campaign folder (see the module docstring for its content).

    Parameters
    ----------
    out_dir : str or pathlib.Path
        Folder holding ``summary.json`` and ``results.sqlite`` (``geofix run --out``).

    Returns
    -------
    str
        A complete, self-contained HTML5 document.

    Raises
    ------
    ConfigError
        See :func:`read_campaign`.
    """
    campaign = read_campaign(out_dir)
    summary = campaign.summary
    specs = list(summary["methods"])
    title = f"{summary['scenario']}: {summary['trials']} trials, {len(specs)} methods"
    stamp = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    methods = summary["methods"]
    body = (
        f"<h1>{_esc(summary['scenario'])}</h1>"
        f'<p class="meta">{_esc(summary["trials"])} trials · {len(specs)} methods · '
        f"written by geofix {_esc(__version__)} on {stamp}</p>"
        "<h2>Summary</h2>"
        '<p class="note">End-point errors in metres; the best value of each column in '
        "green. Failed trials count in <em>trials</em> and as unsuccessful.</p>"
        + _accuracy_table(methods)
        + "<h3>Success rates</h3>"
        + '<p class="note">Share of trials whose end-point error is within a distance, in '
        "metres or in map cells.</p>"
        + _success_table(methods)
        + "<h3>Integrity and cost</h3>"
        + '<p class="note">A false fix ends more than 3 cells off, is not flagged ambiguous '
        "and lies outside the method's own 3-sigma ellipse. Times exclude one-time start-up "
        "costs.</p>"
        + _integrity_table(methods)
        + _bound_section(summary)
        + _figures_section(campaign, specs)
        + _settings_section(specs)
    )
    return (
        '<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{_esc(title)}</title><style>{_CSS}</style></head>"
        f"<body><main>{body}</main></body></html>\n"
    )


def write_report(out_dir: str | Path, path: str | Path | None = None) -> Path:
    """Write :func:`campaign_report` of a campaign folder to ``path``; return the path.

    Parameters
    ----------
    out_dir : str or pathlib.Path
        The campaign folder.
    path : str or pathlib.Path, optional
        The HTML file (default ``out_dir/report.html``); its folder is created. It is
        written to a temporary name and renamed when complete: whole or absent.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    ConfigError
        See :func:`read_campaign`.
    OutputError
        The page cannot be written (disk full, permission denied, not a file).
    """
    target = Path(path) if path is not None else Path(out_dir) / REPORT_NAME
    check_target(target)
    page = campaign_report(out_dir)
    return write_text_atomic(target, page)
