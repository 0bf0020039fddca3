"""
Where can a vehicle fix its position?
=====================================

:func:`geofix.suitability` maps three layers a mission planner can
route with: the relief in a moving window (standard deviation), its fine texture
(roughness) and the Cramér–Rao bound of a standard straight track centred on every cell
(worst heading), for a given sensor noise. Low bound: good place for a fix.
"""

import numpy as np

import geofix as gf
from geofix.plot import suitability_figure

grid = gf.load_map("builtin:azores", region=(-29.5, -27.0, 37.6, 39.6), resample_m=2000)
layers = gf.suitability(grid, window_cells=11, noise_std=5.0)

crlb = layers.crlb.values[np.isfinite(layers.crlb.values)]
p10, p50, p90 = np.percentile(crlb, [10, 50, 90])
print(f"CRLB of an 11-sample track: p10 {p10:.0f} m, median {p50:.0f} m, p90 {p90:.0f} m")

# %%
fig = suitability_figure(layers)
