"""Figures (matplotlib, imported lazily). Functions take results and return a Figure."""

from geofix.plot.figures import campaign_figure, save_figure

__all__ = ["campaign_figure", "save_figure"]
