"""Gridding soundings: block means, the uncertainty layer, gap filling, refusals."""

import numpy as np
import pytest

from geofix.errors import MapError
from geofix.maps import load_grid
from geofix.maps.gridding import grid_soundings, load_map_error, save_gridded
from geofix.measurement import map_error_variance


def plane(x, y):
    return -1000.0 + 0.02 * x - 0.05 * y


def lattice_soundings(cells: int, cell: float, skip=()):
    """Four soundings per cell at +-cell/4 around each centre (cell centres at k*cell)."""
    pts = []
    for i in range(cells):
        for j in range(cells):
            if (i, j) in skip:
                continue
            for dx in (-cell / 4, cell / 4):
                for dy in (-cell / 4, cell / 4):
                    pts.append((j * cell + dx, i * cell + dy))
    x, y = np.array(pts).T
    return x, y, plane(x, y)


def test_cell_means_std_and_count_of_a_plane_are_exact():
    x, y, z = lattice_soundings(6, 10.0)
    g = grid_soundings(x, y, z, 10.0)
    assert g.grid.shape == (6, 6) and (g.grid.x0, g.grid.y0) == (0.0, 0.0)
    gx, gy = np.meshgrid(g.grid.x, g.grid.y)
    np.testing.assert_allclose(g.grid.values, plane(gx, gy), atol=1e-9)
    np.testing.assert_array_equal(g.count, 4)
    # population std of the four values plane(c +- 2.5, c +- 2.5)
    expected = 2.5 * np.hypot(0.02, 0.05)
    np.testing.assert_allclose(g.std, expected, rtol=1e-9)


def test_a_hole_is_filled_linearly_and_far_cells_stay_empty():
    x, y, z = lattice_soundings(7, 10.0, skip={(3, 3)})
    g = grid_soundings(x, y, z, 10.0)
    assert g.count[3, 3] == 0 and np.isnan(g.std[3, 3])
    assert g.grid.values[3, 3] == pytest.approx(plane(30.0, 30.0), abs=1e-9)
    # two clusters 100 cells apart: the cells between them are no data
    x2 = np.concatenate([x, x + 1000.0])
    g2 = grid_soundings(x2, np.concatenate([y, y]), np.concatenate([z, z]), 10.0)
    assert np.isnan(g2.grid.values[3, 50])


def test_gridding_refuses_bad_input_with_the_reason():
    x, y, z = lattice_soundings(3, 10.0)
    with pytest.raises(MapError, match="cell size must be positive"):
        grid_soundings(x, y, z, 0.0)
    with pytest.raises(MapError, match="at least 3 valid soundings"):
        grid_soundings([0.0, 1.0], [0.0, 1.0], [1.0, np.nan], 1.0)
    from geofix.errors import MemoryBudgetError

    with pytest.raises(MemoryBudgetError, match=r"10000001 x 10000001 cells .* would need"):
        grid_soundings([0.0, 1e7, 0.0], [0.0, 1e7, 1.0], [1.0, 2.0, 3.0], 1.0)


def test_saved_map_reads_back_with_its_uncertainty_layer(tmp_path):
    x, y, z = lattice_soundings(5, 10.0)
    g = grid_soundings(x, y, z, 10.0, meta={"projection": None})
    path = save_gridded(g, tmp_path / "map.nc")
    back = load_grid(path)
    np.testing.assert_array_equal(back.values, g.grid.values)
    err = load_map_error(path)
    np.testing.assert_array_equal(err.values, g.std)
    var = map_error_variance(err, [20.0, 20.0], 0.0, np.array([[0.0, 0.0], [1e4, 0.0]]))
    np.testing.assert_allclose(var, [g.std[2, 2] ** 2, 0.0])
    assert map_error_variance(None, [0, 0], 0.0, np.zeros((3, 2))).tolist() == [0, 0, 0]
