"""The suitability figure: window std, roughness and the CRLB of a standard track."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from geofix.evaluate.suitability import Suitability
from geofix.plot.figures import save_figure


def suitability_figure(result: Suitability, crlb_range_m: tuple[float, float] | None = None):
    """A three-panel figure: window std, roughness and the CRLB (log scale, metres).

    Parameters
    ----------
    result : Suitability
        The layers.
    crlb_range_m : (float, float), optional
        Colour range of the CRLB panel, metres (default: its 2nd..98th percentiles).

    Returns
    -------
    matplotlib.figure.Figure
        The figure (axes in kilometres).
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    grid = result.crlb
    west, east, south, north = grid.extent
    extent = np.array([west, east, south, north]) / 1e3
    crlb = np.where(np.isfinite(grid.values), grid.values, np.nan)
    lo, hi = crlb_range_m or np.nanpercentile(crlb, [2, 98])
    lo = max(float(lo), 1e-3)
    hi = max(float(hi), 2 * lo)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6), constrained_layout=True)
    panels = (
        (result.std.values, None, "viridis", f"std in {result.window_cells}-cell window"),
        (result.roughness.values, None, "magma", "roughness (adjacent-cell |diff|)"),
        (np.clip(crlb, lo, hi), LogNorm(lo, hi), "RdYlGn_r", "CRLB of a standard track (m)"),
    )
    units = result.std.units
    labels = (f"std ({units})", f"mean |difference| ({units})", "CRLB (m)")
    for ax, (values, norm, cmap, title), label in zip(axes, panels, labels, strict=True):
        im = ax.imshow(values, origin="lower", extent=extent, cmap=cmap, norm=norm)
        fig.colorbar(im, ax=ax, shrink=0.85, label=label)
        ax.set_title(title)
        ax.set_xlabel("x (km)")
    axes[0].set_ylabel("y (km)")
    fig.suptitle(
        f"{grid.name.removesuffix('_crlb')}: suitability for matching "
        f"(noise {result.noise_std:g} {result.std.units})"
    )
    return fig


def save_suitability_figure(result: Suitability, out_dir: str | Path) -> Path:
    """Write :func:`suitability_figure` as ``suitability.png`` in ``out_dir``; its path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return save_figure(suitability_figure(result), out / "suitability.png")
