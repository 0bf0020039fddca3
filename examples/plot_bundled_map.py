"""
A bundled map
=============

geofix ships a few real maps (bathymetry and marine gravity) inside the package. Any of
them is read with :func:`geofix.load_map` as ``"builtin:NAME"``; a lon/lat grid is
cut to a region (in its own degrees), projected to a local metric frame (x east, y north,
metres) and resampled to square cells. The result is a :class:`geofix.Grid`.
"""

import matplotlib.pyplot as plt

import geofix as gf

for name, info in gf.bundled_maps().items():
    print(f"{name:15s} {info.description[:70]}")

# %%
# Cut the Azores bathymetry around the central islands and resample it to 2 km cells.
grid = gf.load_map("builtin:azores", region=(-29.5, -27.0, 37.6, 39.6), resample_m=2000)
print(grid)
print(f"cell {grid.cell_size:.0f} m, {grid.shape[1]} x {grid.shape[0]} cells")

# %%
# Row 0 is the southern edge, so ``origin="lower"`` draws north up.
fig, ax = plt.subplots(figsize=(6.5, 5.5))
west, east, south, north = (v / 1000 for v in grid.extent)
image = ax.imshow(grid.values, origin="lower", extent=(west, east, south, north), cmap="cividis")
fig.colorbar(image, ax=ax, label=f"elevation ({grid.units})")
ax.set_xlabel("east (km)")
ax.set_ylabel("north (km)")
ax.set_title("Azores central group, 2 km cells")
plt.show()
