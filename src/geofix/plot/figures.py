"""Campaign figures: the map with true / indicated / matched tracks, and error histograms."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from geofix.maps.grid import Grid


def pyplot():
    """``matplotlib.pyplot``, imported on first use with the ``Agg`` backend unless one is set.

    Every figure of geofix (here, the report's and the replay's) draws through it, so
    importing geofix never imports matplotlib and a machine without a display can save
    figures.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


#: One colour, line style and end marker per track, told apart in grey scale too.
_STYLES = (
    ("tab:orange", "-", "o"),
    ("tab:blue", "--", "s"),
    ("tab:green", "-.", "^"),
    ("tab:purple", ":", "D"),
    ("tab:brown", (0, (5, 1, 1, 1)), "v"),
    ("tab:pink", (0, (1, 1)), "P"),
)


def campaign_figure(
    grid: Grid,
    truth: np.ndarray,
    indicated: np.ndarray,
    estimates: dict[str, np.ndarray],
    end_errors: dict[str, np.ndarray],
    title: str = "",
    margin_m: float | None = None,
    times: np.ndarray | None = None,
    bound_track: np.ndarray | None = None,
    bound_m: float | None = None,
):
    """Tracks of one trial, its error along the track, and the campaign's error curves.

    Three panels: the map with the true, INS-indicated and estimated tracks of one trial
    (each track its own colour, line style and end marker, drawn widest first so that
    tracks lying on one another all stay visible); the error of every track along that
    trial beside the Cramér–Rao bound; the cumulative share of trials within each
    end-point error, one step curve per method (no overlapping fills).

    Parameters
    ----------
    grid : Grid
        The map.
    truth, indicated : numpy.ndarray
        ``(n, 2)`` true and INS-indicated tracks of the trial shown, metres.
    estimates : dict of str to numpy.ndarray
        ``(n, 2)`` estimated track of that trial per method.
    end_errors : dict of str to numpy.ndarray
        End-point errors (metres) of every trial per method.
    title : str
        Figure title.
    margin_m : float, optional
        Map margin around the tracks, metres (default: a third of the track extent,
        at least 8 cells).
    times : numpy.ndarray, optional
        ``(n,)`` sample times of the trial shown, seconds (default: sample index).
    bound_track : numpy.ndarray, optional
        ``(n,)`` bound on the RMS position error at every sample, metres.
    bound_m : float, optional
        The campaign's bound on the end-point RMS error, metres.

    Returns
    -------
    matplotlib.figure.Figure
    """
    plt = pyplot()
    fig, (ax_map, ax_err, ax_cdf) = plt.subplots(
        1, 3, figsize=(17, 5.6), width_ratios=[1.25, 1, 1], constrained_layout=True
    )
    _draw_map(ax_map, grid, truth, indicated, estimates, margin_m)
    t = np.arange(truth.shape[0]) if times is None else np.asarray(times, float) / 60.0
    _draw_track_errors(ax_err, t, truth, indicated, estimates, bound_track, times is not None)
    _draw_cdf(ax_cdf, end_errors, grid.cell_size, bound_m)
    if title:
        fig.suptitle(title)
    return fig


#: The free INS (method ``ins``) is drawn as the indicated track is.
_INS_STYLE = ("tab:red", "--", "x")


def track_style(k: int) -> tuple:
    """``(colour, line style, end marker)`` of the ``k``-th track of a figure (from 0)."""
    return _STYLES[k % len(_STYLES)]


def field_label(kind: str, units: str) -> str:
    """What a map's values are, for a colour bar (:mod:`geofix.conventions`, *Fields*).

    Examples
    --------
    >>> field_label("depth", "m")
    'seabed elevation (m, negative below sea level)'
    >>> field_label("gravity", "mGal")
    'free-air gravity anomaly (mGal)'
    """
    if kind == "depth":  # bathymetry is stored as elevation
        return f"seabed elevation ({units}, negative below sea level)"
    if kind == "gravity":
        return f"free-air gravity anomaly ({units})"
    return f"{kind} ({units})"


#: Widest and narrowest line width of the estimated tracks on a map, points.
_TRACK_WIDTHS = (4.5, 2.2)


def draw_track_map(
    ax,
    grid: Grid,
    truth: np.ndarray | None,
    indicated: np.ndarray,
    estimates: dict[str, np.ndarray],
    margin_m: float | None = None,
) -> None:
    """Draw the map around the tracks, in kilometres, with every track told apart.

    The estimates are drawn widest first, each narrower one on top of the wider ones and
    edged in white, then the INS-indicated track and, narrowest and on top, the true
    track: tracks lying on one another all stay visible. Every track ends in its own
    marker, which its legend entry shows; the colour bar says what the map's values are
    (:func:`field_label`).

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        Where to draw.
    grid : Grid
        The map.
    truth : numpy.ndarray or None
        ``(n, 2)`` true track, metres (None: not known).
    indicated : numpy.ndarray
        ``(n, 2)`` INS-indicated track, metres.
    estimates : dict of str to numpy.ndarray
        ``(m, 2)`` estimated track per method, metres.
    margin_m : float, optional
        Map margin around the tracks, metres (default: a third of the track extent, at
        least 8 cells).
    """
    from matplotlib import patheffects

    tracks = [t for t in (truth, indicated, *estimates.values()) if t is not None and len(t)]
    pts = np.vstack(tracks)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    margin = margin_m if margin_m is not None else max(0.3 * (hi - lo).max(), 8 * grid.cell_size)
    x0, x1 = lo[0] - margin, hi[0] + margin
    y0, y1 = lo[1] - margin, hi[1] + margin
    sub = _window(grid, x0, x1, y0, y1)
    km = 1e-3
    image = ax.imshow(
        sub.values, origin="lower", extent=[v * km for v in _edges(sub)], cmap="Greys_r"
    )
    ax.figure.colorbar(image, ax=ax, label=field_label(grid.kind, grid.units), shrink=0.8)
    widths = np.linspace(*_TRACK_WIDTHS, max(len(estimates), 2))
    for k, (name, est) in enumerate(estimates.items()):
        halo = [patheffects.withStroke(linewidth=widths[k] + 1.5, foreground="w", alpha=0.8)]
        style = track_style(k)
        _track_line(ax, est * km, name, style, widths[k], zorder=3 + k, path_effects=halo)
    top = 3 + len(estimates)
    ins_style = {"zorder": top, "mew": 2, "mec": _INS_STYLE[0]}
    _track_line(ax, indicated * km, "INS indicated", _INS_STYLE, 1.4, **ins_style)
    if truth is not None:
        ax.plot(*(truth[0] * km), "k>", ms=7, zorder=top + 1, label="start")
        _track_line(ax, truth * km, "true", ("k", "-", "*"), 1.2, zorder=top + 1, mec="w", ms=13)
    ax.set_xlim(x0 * km, x1 * km)
    ax.set_ylim(y0 * km, y1 * km)
    ax.set_xlabel("east (km)")
    ax.set_ylabel("north (km)")
    ax.set_aspect("equal")
    ax.legend(loc="best", fontsize=8, framealpha=0.9, title="marker: end point", title_fontsize=8)


def _track_line(ax, track: np.ndarray, label: str, style: tuple, width: float, **kw) -> None:
    """One track with its end marker, as one legend entry (line and marker)."""
    colour, line, marker = style
    kw = {"ms": 9, "mec": "k", "mew": 0.8, **kw}
    ax.plot(
        *track.T,
        color=colour,
        ls=line,
        lw=width,
        marker=marker,
        markevery=[len(track) - 1],
        label=label,
        **kw,
    )


def _draw_map(ax, grid, truth, indicated, estimates, margin_m):
    draw_track_map(ax, grid, truth, indicated, estimates, margin_m)
    ax.set_title("trial 0: tracks")


def _draw_track_errors(ax, t, truth, indicated, estimates, bound_track, minutes: bool):
    ax.plot(t, np.hypot(*(indicated - truth).T), color="tab:red", ls="--", label="INS")
    for k, (name, est) in enumerate(estimates.items()):
        colour, style, _ = track_style(k)
        ax.plot(t, np.hypot(*(est - truth).T), color=colour, ls=style, lw=1.6, label=name)
    if bound_track is not None:
        ax.plot(t, bound_track, color="k", lw=1, label="CRLB (RMS)")
    ax.set_yscale("log")
    ax.set_xlabel("time (min)" if minutes else "sample")
    ax.set_ylabel("position error (m)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("trial 0: error along the track")


def _draw_cdf(ax, end_errors, cell_m, bound_m):
    methods = [name for name in end_errors if name != "ins"]
    for name, values in end_errors.items():
        v = np.sort(np.asarray(values, float)[np.isfinite(values)])
        if not v.size:
            continue
        colour, style, _ = _INS_STYLE if name == "ins" else track_style(methods.index(name))
        share = np.arange(1, v.size + 1) / np.asarray(values).size
        label = f"{name} (RMS {np.sqrt(np.mean(v**2)):.0f} m)"
        ax.step(v, share, where="post", color=colour, ls=style, lw=1.8, label=label)
    ax.axvline(cell_m, color="0.4", ls=":", lw=1, label=f"1 cell ({cell_m:.0f} m)")
    if bound_m is not None:
        ax.axvline(bound_m, color="k", lw=1, label=f"CRLB, end RMS ({bound_m:.0f} m)")
    ax.set_xscale("log")
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("end-point error (m)")
    ax.set_ylabel("share of trials within")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title("end-point error over the campaign")


def _window(grid: Grid, x0: float, x1: float, y0: float, y1: float) -> Grid:
    low_col, low_row = grid.xy_to_cell(x0, y0)
    high_col, high_row = grid.xy_to_cell(x1, y1)
    ny, nx = grid.shape
    c0, r0 = max(int(np.floor(low_col)), 0), max(int(np.floor(low_row)), 0)
    c1, r1 = min(int(np.ceil(high_col)) + 1, nx), min(int(np.ceil(high_row)) + 1, ny)
    return grid.crop_cells(c0, max(c1, c0 + 2), r0, max(r1, r0 + 2))


def _edges(grid: Grid) -> list[float]:
    w, e, s, n = grid.extent
    return [w - grid.dx / 2, e + grid.dx / 2, s - grid.dy / 2, n + grid.dy / 2]


def error_band_figure(errors: dict[str, np.ndarray], limit_m: float | None = None, x=None):
    """Error versus sample of several methods: one trial, and the median with a band.

    Parameters
    ----------
    errors : dict of str to numpy.ndarray
        ``(trials, n)`` position errors, metres, per method (row 0 is the trial drawn
        alone).
    limit_m : float, optional
        A horizontal reference line (a divergence threshold, say), metres.
    x : numpy.ndarray, optional
        ``(n,)`` abscissa (default: sample index).

    Returns
    -------
    matplotlib.figure.Figure
        Two panels (log scale, kilometres): the first trial; the median and 10-90 % band.
    """
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True, constrained_layout=True)
    for k, (spec, e) in enumerate(errors.items()):
        colour, style, _ = track_style(k)
        e = np.asarray(e, float) / 1e3
        steps = np.arange(e.shape[1]) if x is None else np.asarray(x)
        axes[0].plot(steps, e[0], color=colour, ls=style, label=spec)
        lo, med, hi = np.nanpercentile(e, [10, 50, 90], axis=0)
        axes[1].fill_between(steps, lo, hi, color=colour, alpha=0.2, lw=0)
        axes[1].plot(steps, med, color=colour, ls=style, label=f"{spec}: median, 10-90 %")
    for ax in axes:
        if limit_m is not None:
            ax.axhline(limit_m / 1e3, color="grey", ls="--", lw=0.8)
        ax.set_yscale("log")
        ax.set_xlabel("sample")
        ax.legend(fontsize=8)
    axes[0].set_ylabel("position error (km)")
    axes[0].set_title("one trial")
    axes[1].set_title(f"all {len(next(iter(errors.values())))} trials")
    return fig


def leg_errors_figure(panels: dict[str, dict[str, np.ndarray]], limit_m: float | None = None):
    """Mean error at the end of each leg, one panel per run, one line per method.

    Parameters
    ----------
    panels : dict
        ``{panel title: {method: (legs,) mean end error of every leg, metres}}``.
    limit_m : float, optional
        A horizontal reference line (a claim of the source, say), metres.

    Returns
    -------
    matplotlib.figure.Figure
    """
    plt = pyplot()
    fig, axes = plt.subplots(
        1, len(panels), figsize=(5.5 * len(panels), 4), sharey=True, constrained_layout=True
    )
    for ax, (title, lines) in zip(np.atleast_1d(axes), panels.items(), strict=True):
        for k, (spec, legs) in enumerate(lines.items()):
            colour, style, marker = track_style(k)
            legs = np.asarray(legs, float)
            ax.plot(
                np.arange(1, legs.size + 1), legs, color=colour, ls=style, marker=marker, label=spec
            )
        if limit_m is not None:
            ax.axhline(limit_m, color="grey", lw=0.8, ls="--", label=f"{limit_m:g} m")
        ax.set_title(title)
        ax.set_xlabel("leg (match)")
        ax.legend(fontsize=8)
    np.atleast_1d(axes)[0].set_ylabel("mean error at the end of the leg (m)")
    return fig


def success_rate_figure(panels: dict[str, dict[str, dict[str, float]]], xlabel: str = "l (m)"):
    """Success rate against a threshold, one panel per test, grouped bars per method.

    Parameters
    ----------
    panels : dict
        ``{panel title: {method: {threshold label: share in [0, 1]}}}``; the threshold
        labels are numbers (``"20"``, ``"40"``...).
    xlabel : str
        Label of the threshold axis.

    Returns
    -------
    matplotlib.figure.Figure
    """
    plt = pyplot()
    fig, axes = plt.subplots(
        1, len(panels), figsize=(5 * len(panels), 3.8), sharey=True, constrained_layout=True
    )
    for ax, (title, methods) in zip(np.atleast_1d(axes), panels.items(), strict=True):
        levels = [float(k) for k in next(iter(methods.values()))]
        width = 0.8 * (levels[1] - levels[0] if len(levels) > 1 else 1.0) / len(methods)
        for i, (method, rates) in enumerate(methods.items()):
            colour = track_style(i)[0]
            offset = (i - (len(methods) - 1) / 2) * width
            values = [100 * (v or 0.0) for v in rates.values()]
            ax.bar(np.array(levels) + offset, values, width, color=colour, label=method)
        ax.set_xticks(levels)
        ax.set_xlabel(xlabel)
        ax.set_title(title)
        ax.legend(fontsize=7)
    np.atleast_1d(axes)[0].set_ylabel("success rate (%)")
    return fig


def save_figure(fig, path: str | Path, dpi: int = 120, metadata: dict | None = None) -> Path:
    """Write a figure to ``path`` (format by suffix, PNG by default), creating folders.

    The image is written to a temporary name and renamed when complete
    (:mod:`geofix._atomic`): it is whole or absent. ``metadata`` (text keys, e.g. a
    run id) is stored in the file where the format allows it (PNG text chunks).

    Returns
    -------
    pathlib.Path
        The path written.
    """
    from geofix._atomic import write_atomic

    path = Path(path)
    fmt = path.suffix.lstrip(".").lower() or "png"
    try:
        return write_atomic(
            path, lambda part: fig.savefig(part, dpi=dpi, format=fmt, metadata=metadata)
        )
    finally:
        pyplot().close(fig)
