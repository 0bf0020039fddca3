"""What the command line draws: the campaign progress bar and the summary table (rich)."""

from __future__ import annotations

import math

from rich.console import Console
from rich.markup import escape
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Table

from geofix.evaluate.summary import CampaignSummary


class ProgressBar:
    """A rich progress bar on stderr, usable as ``run_campaign(..., progress=bar)``.

    Before the first result, :meth:`phase` prints what is being done on a terminal
    (preparing the map, running the first trial), one still line each: no refresh thread
    runs before the bar, since a campaign forks its workers only while no other thread
    runs.

    Parameters
    ----------
    name : str
        The label in front of the bar (the scenario's name).
    enabled : bool
        False draws nothing (a bar that is only counted).

    Examples
    --------
    >>> with ProgressBar("demo", enabled=False) as bar:
    ...     bar.phase("preparing the map")
    ...     bar(0, 10)
    ...     bar(10, 10)
    """

    def __init__(self, name: str, enabled: bool = True) -> None:
        self._console = Console(stderr=True)
        self._name = name
        self._enabled = enabled
        self._progress = Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            console=self._console,
            disable=not enabled,
        )
        self._task = self._progress.add_task(name, total=None)
        self._started = False

    def phase(self, what: str) -> None:
        """Print ``name: what...`` on stderr: a step before the first result (no bar yet).

        Only on a terminal: piped or logged, stderr keeps to warnings and one-line errors.
        """
        if self._enabled and not self._started and self._console.is_terminal:
            line = f"[bold]{escape(self._name)}[/]: {escape(what)}..."
            self._console.print(line, highlight=False)

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, exc_type, *exc) -> None:
        if not self._started:
            return
        if exc_type is not None:
            self._progress.live.transient = True  # the error line alone, no stale bar
        self._progress.stop()

    def __call__(self, done: int, total: int) -> None:
        """Show ``done`` of ``total`` results (the bar appears with the first call)."""
        if not self._started:
            self._progress.start()
            self._started = True
        self._progress.update(self._task, completed=done, total=total)


def summary_table(summary: CampaignSummary, width: int | None = None) -> Table:
    """A printable table of a campaign summary.

    Parameters
    ----------
    summary : CampaignSummary
        As returned in :attr:`geofix.evaluate.campaign.CampaignResult.summary`.
    width : int, optional
        Terminal width, characters. When the full table is wider, the least important
        columns are left out (named in the caption) and long method names wrap; numbers
        are never cut.

    Returns
    -------
    rich.table.Table
        One row per method: trials, failures, mean / std / median / max / RMS end-point
        error and mean along-track error (metres), success rates within 100 m, 1 cell and
        3 cells (%), mean time per ``match`` call (milliseconds). The title carries the
        Cramér–Rao bound on the end-point RMS error (``crlb_m``), which the ``rms``
        column is to be read against, and the bound along the track (``crlb_track_m``);
        then the valid bound at the end and along the track (``valid_bound_m``,
        ``valid_bound_track_m``) when the campaign computed it.

    Examples
    --------
    >>> from geofix.evaluate.summary import CampaignSummary, MethodStats
    >>> s = CampaignSummary("demo", 2, crlb_m=12.34, methods={"pmf": MethodStats(trials=2)})
    >>> summary_table(s).title
    'demo: 2 trials, errors in metres; CRLB on the RMS error: 12.3 m at the end'
    """
    title = f"{summary.scenario}: {summary.trials} trials, errors in metres{_bounds(summary)}"
    rows = {
        spec: [cell(stats) for _, cell in _TABLE_COLUMNS] for spec, stats in summary.methods.items()
    }
    widths = [
        max([len(head), *(len(r[k]) for r in rows.values())])
        for k, (head, _) in enumerate(_TABLE_COLUMNS)
    ]
    keep = _columns_that_fit(widths, max(map(len, rows), default=6), width)
    dropped = [head for k, (head, _) in enumerate(_TABLE_COLUMNS) if k not in keep]
    caption = f"left out to fit: {', '.join(dropped)} (--json has all)" if dropped else None
    table = Table(title=title, caption=caption)
    table.add_column("method", style="bold", overflow="fold")
    for k in keep:
        table.add_column(_TABLE_COLUMNS[k][0], justify="right", no_wrap=True, min_width=widths[k])
    for spec, cells in rows.items():
        table.add_row(spec, *(cells[k] for k in keep))
    return table


def _bounds(summary: CampaignSummary) -> str:
    """The bounds of the title: the Cramér–Rao bound, then the valid bound when computed.

    ``"; CRLB on the RMS error: 12.3 m at the end, 9.8 m along the track; valid bound:
    15.0 m at the end, 11.2 m along the track"``.
    """
    crlb = _at_end_and_along(summary.crlb_m, summary.crlb_track_m)
    valid = _at_end_and_along(summary.valid_bound_m, summary.valid_bound_track_m)
    return (f"; CRLB on the RMS error: {crlb}" if crlb else "") + (
        f"; valid bound: {valid}" if valid else ""
    )


def _at_end_and_along(end: float | None, track: float | None) -> str:
    """``"12.3 m at the end, 9.8 m along the track"``, leaving out a missing value."""
    parts = [
        f"{value:.1f} m {where}"
        for value, where in ((end, "at the end"), (track, "along the track"))
        if value is not None and math.isfinite(value)
    ]
    return ", ".join(parts)


#: Columns left out first when the table does not fit the terminal (by header).
_DROP_ORDER = ("track", "std", "≤1 cell", "max", "trials", "median", "≤3 cells", "failed")
_METHOD_MIN_WIDTH = 12


def _columns_that_fit(widths: list[int], method_width: int, width: int | None) -> list[int]:
    """Indices of the table columns to show within ``width`` characters (all if None)."""
    keep = list(range(len(widths)))
    if width is None:
        return keep
    method = min(method_width, _METHOD_MIN_WIDTH)
    heads = [head for head, _ in _TABLE_COLUMNS]
    for head in _DROP_ORDER:
        # one border per column plus the outer one, one space of padding on each side
        if 1 + (method + 3) + sum(widths[k] + 3 for k in keep) <= width:
            break
        keep.remove(heads.index(head))
    return keep


def _fmt(value: float | None, digits: int = 1, scale: float = 1.0) -> str:
    return "-" if value is None else f"{scale * value:.{digits}f}"


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.0f}%"


_TABLE_COLUMNS = (
    ("trials", lambda s: str(s.trials)),
    ("failed", lambda s: str(s.failures)),
    ("mean", lambda s: _fmt(s.mean_error_m)),
    ("std", lambda s: _fmt(s.std_error_m)),
    ("median", lambda s: _fmt(s.median_error_m)),
    ("max", lambda s: _fmt(s.max_error_m)),
    ("rms", lambda s: _fmt(s.rms_error_m)),
    ("track", lambda s: _fmt(s.mean_track_error_m)),
    ("≤100 m", lambda s: _pct(s.success_rate.get("100"))),
    ("≤1 cell", lambda s: _pct(s.success_rate.get("1c"))),
    ("≤3 cells", lambda s: _pct(s.success_rate.get("3c"))),
    ("ms/call", lambda s: _fmt(s.mean_time_s, 2, 1e3)),
)
