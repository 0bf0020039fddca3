"""Maps: the :class:`Grid`, map readers and writers, projection, terrain numerics, synthetic maps.

Bundled maps are read with ``load_grid("builtin:NAME")``; :func:`bundled_maps` lists them.
"""

from geofix.maps.bundled import BUNDLED_MAPS, BundledMap, builtin_path, bundled_maps
from geofix.maps.grid import Grid
from geofix.maps.io import load_grid, save_grid
from geofix.maps.project import ProjectedValues, local_tmerc, project_lonlat_grid, resample_m
from geofix.maps.synthetic import fractal_terrain, planar_grid
from geofix.maps.terrain import (
    PlaneFit,
    TerrainStats,
    autocorrelation,
    gradient,
    local_std,
    plane_fit,
    terrain_stats,
)

__all__ = [
    "BUNDLED_MAPS",
    "BundledMap",
    "Grid",
    "PlaneFit",
    "ProjectedValues",
    "TerrainStats",
    "autocorrelation",
    "builtin_path",
    "bundled_maps",
    "fractal_terrain",
    "gradient",
    "load_grid",
    "local_std",
    "local_tmerc",
    "planar_grid",
    "plane_fit",
    "project_lonlat_grid",
    "resample_m",
    "save_grid",
    "terrain_stats",
]
