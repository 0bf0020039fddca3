"""Campaign figures: the map with true / indicated / matched tracks, and error histograms."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from geofix.maps.grid import Grid


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def campaign_figure(
    grid: Grid,
    truth: np.ndarray,
    indicated: np.ndarray,
    estimates: dict[str, np.ndarray],
    end_errors: dict[str, np.ndarray],
    title: str = "",
    margin_m: float | None = None,
):
    """Map and tracks of one trial beside the end-point error histogram of every method.

    Parameters
    ----------
    grid : Grid
        The map.
    truth, indicated : numpy.ndarray
        ``(n, 2)`` true and INS-indicated tracks of the trial shown, metres.
    estimates : dict of str to numpy.ndarray
        ``(n, 2)`` matched track of that trial per method.
    end_errors : dict of str to numpy.ndarray
        End-point errors (metres) of every trial per method, for the histograms.
    title : str
        Figure title.
    margin_m : float, optional
        Map margin around the tracks, metres (default: a quarter of the track extent,
        at least 8 cells).

    Returns
    -------
    matplotlib.figure.Figure
    """
    plt = _pyplot()
    fig, (ax_map, ax_hist) = plt.subplots(1, 2, figsize=(13, 5.5), width_ratios=[1.2, 1])
    _draw_map(ax_map, grid, truth, indicated, estimates, margin_m)
    _draw_histogram(ax_hist, end_errors, grid.cell_size)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def _draw_map(ax, grid, truth, indicated, estimates, margin_m):
    pts = np.vstack([truth, indicated, *estimates.values()])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    margin = margin_m if margin_m is not None else max(0.3 * (hi - lo).max(), 8 * grid.cell_size)
    x0, x1 = lo[0] - margin, hi[0] + margin
    y0, y1 = lo[1] - margin, hi[1] + margin
    sub = _window(grid, x0, x1, y0, y1)
    km = 1e-3
    image = ax.imshow(
        sub.values,
        origin="lower",
        extent=[v * km for v in _edges(sub)],
        cmap="viridis" if grid.kind == "gravity" else "cividis",
    )
    ax.figure.colorbar(image, ax=ax, label=f"{grid.kind} ({grid.units})", shrink=0.8)
    ax.plot(*(truth * km).T, "k-", lw=2, label="true")
    ax.plot(*(indicated * km).T, "r--", lw=1.5, label="INS indicated")
    for name, est in estimates.items():
        ax.plot(*(est * km).T, "-", lw=1.2, label=name)
    ax.plot(*(truth[0] * km), "ko", ms=5)
    ax.set_xlabel("east (km)")
    ax.set_ylabel("north (km)")
    ax.set_aspect("equal")
    ax.legend(loc="best", fontsize=8)
    ax.set_title("trial 0")


def _window(grid: Grid, x0, x1, y0, y1) -> Grid:
    c0, r0 = grid.xy_to_cell(x0, y0)
    c1, r1 = grid.xy_to_cell(x1, y1)
    ny, nx = grid.shape
    c0, r0 = max(int(np.floor(c0)), 0), max(int(np.floor(r0)), 0)
    c1, r1 = min(int(np.ceil(c1)) + 1, nx), min(int(np.ceil(r1)) + 1, ny)
    return grid.crop_cells(c0, max(c1, c0 + 2), r0, max(r1, r0 + 2))


def _edges(grid: Grid) -> list[float]:
    w, e, s, n = grid.extent
    return [w - grid.dx / 2, e + grid.dx / 2, s - grid.dy / 2, n + grid.dy / 2]


def _draw_histogram(ax, end_errors, cell_m):
    finite = [np.asarray(v)[np.isfinite(v)] for v in end_errors.values()]
    top = max((float(v.max()) for v in finite if v.size), default=1.0)
    bins = np.linspace(0, max(top, 1e-9) * 1.05, 25)
    for (name, _), values in zip(end_errors.items(), finite, strict=True):
        ax.hist(values, bins=bins, alpha=0.6, label=f"{name} (mean {values.mean():.1f} m)")
    ax.axvline(cell_m, color="k", ls=":", lw=1, label=f"1 cell ({cell_m:.0f} m)")
    ax.set_xlabel("end-point error (m)")
    ax.set_ylabel("trials")
    ax.legend(fontsize=8)
    ax.set_title("end-point error over the campaign")


def save_figure(fig, path: str | Path, dpi: int = 120) -> Path:
    """Write a figure to ``path`` (PNG by suffix), creating folders; return the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    _pyplot().close(fig)
    return path
