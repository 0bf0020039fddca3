"""Figures (matplotlib, imported lazily). Functions take results and return a Figure."""

from geofix.plot.figures import (
    campaign_figure,
    error_band_figure,
    leg_errors_figure,
    save_figure,
    success_rate_figure,
)
from geofix.plot.suitability import save_suitability_figure, suitability_figure

__all__ = [
    "campaign_figure",
    "error_band_figure",
    "leg_errors_figure",
    "save_figure",
    "save_suitability_figure",
    "success_rate_figure",
    "suitability_figure",
]
