"""What the command line draws: the campaign progress bar and the summary table (rich)."""

from __future__ import annotations

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from geofix.evaluate.summary import CampaignSummary


class ProgressBar:
    """A rich progress bar on stderr, usable as ``run_campaign(..., progress=bar)``.

    Parameters
    ----------
    name : str
        The label in front of the bar (the scenario's name).
    enabled : bool
        False draws nothing (a bar that is only counted).

    Examples
    --------
    >>> with ProgressBar("demo", enabled=False) as bar:
    ...     bar(0, 10)
    ...     bar(10, 10)
    """

    def __init__(self, name: str, enabled: bool = True) -> None:
        self._progress = Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeRemainingColumn(),
            console=Console(stderr=True),
            disable=not enabled,
        )
        self._task = self._progress.add_task(name, total=None)

    def __enter__(self) -> ProgressBar:
        self._progress.start()
        return self

    def __exit__(self, *exc) -> None:
        self._progress.stop()

    def __call__(self, done: int, total: int) -> None:
        """Show ``done`` of ``total`` results."""
        self._progress.update(self._task, completed=done, total=total)


def summary_table(summary: CampaignSummary) -> Table:
    """A printable table of a campaign summary.

    Parameters
    ----------
    summary : CampaignSummary
        As returned in :attr:`geofix.evaluate.campaign.CampaignResult.summary`.

    Returns
    -------
    rich.table.Table
        One row per method: trials, failures, mean / std / median / max end-point error
        and mean along-track error (metres), success rates within 100 m, 1 cell and
        3 cells (%), mean time per ``match`` call (milliseconds).
    """
    title = f"{summary.scenario}: {summary.trials} trials, errors in metres"
    table = Table(title=title)
    table.add_column("method", style="bold", no_wrap=True)
    for head, _ in _TABLE_COLUMNS:
        table.add_column(head, justify="right")
    for spec, stats in summary.methods.items():
        table.add_row(spec, *(cell(stats) for _, cell in _TABLE_COLUMNS))
    return table


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
    ("track", lambda s: _fmt(s.mean_track_error_m)),
    ("≤100 m", lambda s: _pct(s.success_rate["100"])),
    ("≤1 cell", lambda s: _pct(s.success_rate["1c"])),
    ("≤3 cells", lambda s: _pct(s.success_rate["3c"])),
    ("ms/call", lambda s: _fmt(s.mean_time_s, 2, 1e3)),
)
