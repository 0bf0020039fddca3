"""The compiled map read against plain numpy and ``scipy.ndimage.map_coordinates``.

Part of the pytest-benchmark suite (``make bench``; see ``bench_tercom.py`` for why
pytest-benchmark). Yardsticks: the numpy bilinear read ``Grid.sample`` used before, and
the ``map_coordinates`` call the filters' measurement prediction used before.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import map_coordinates

from _yardsticks import numpy_bilinear, paired_ratio
from geofix.maps.grid import Grid
from geofix.measurement import predict_measurements
from geofix.problem import footprint_xy


def _grid(rng, n=1000):
    return Grid(rng.normal(size=(n, n)).cumsum(axis=0), 0.0, 0.0, 5.0, 5.0)


def test_grid_sample_against_numpy(benchmark, figures):
    """One million bilinear reads at random positions."""
    rng = np.random.default_rng(0)
    grid = _grid(rng)
    x, y = rng.uniform(0, 4995, (2, 1_000_000))
    col, row = grid.xy_to_cell(x, y)
    grid.sample(x, y)
    figures["grid_sample_1e6"] = paired_ratio(
        lambda: grid.sample(x, y), lambda: numpy_bilinear(grid.values, col, row)
    )
    benchmark.pedantic(grid.sample, args=(x, y), rounds=5, iterations=1)


def _map_coordinates_prediction(grid, positions, heading, offsets):
    """The former prediction: beam offsets in cells, then one ``map_coordinates`` call."""
    ox, oy = footprint_xy(np.zeros(2), np.asarray(heading), offsets)
    col, row = grid.xy_to_cell(positions[:, 0], positions[:, 1])
    coords = np.empty((2, col.size, offsets.shape[0]))
    np.add(row[:, None], oy / grid.dy, out=coords[0])
    np.add(col[:, None], ox / grid.dx, out=coords[1])
    out = map_coordinates(
        grid.values, coords.reshape(2, -1), order=1, mode="constant", cval=np.nan, prefilter=False
    )
    return out.reshape(col.size, offsets.shape[0])


def test_filter_prediction_against_map_coordinates(benchmark, figures):
    """A multibeam PMF step's read: 40 000 hypotheses x 33 beams."""
    rng = np.random.default_rng(1)
    grid = _grid(rng)
    positions = rng.uniform(500, 4500, (40_000, 2))
    offsets = np.column_stack([np.linspace(-100, 100, 33), np.zeros(33)])
    predict_measurements(grid, positions, 0.3, offsets)
    figures["filter_prediction_40000x33"] = paired_ratio(
        lambda: predict_measurements(grid, positions, 0.3, offsets),
        lambda: _map_coordinates_prediction(grid, positions, 0.3, offsets),
    )
    benchmark.pedantic(
        predict_measurements, args=(grid, positions, 0.3, offsets), rounds=5, iterations=1
    )
