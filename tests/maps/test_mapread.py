"""The compiled map read against a plain-numpy reference of the former ``Grid.sample``."""

import numpy as np
import pytest

from geofix.errors import MapError
from geofix.maps import mapread
from geofix.maps.grid import Grid


def _numpy_bilinear(values, col, row):
    """Reference: the numpy bilinear read ``Grid.sample`` used before the compiled one."""
    col, row = np.broadcast_arrays(np.asarray(col, float), np.asarray(row, float))
    ny, nx = values.shape
    inside = (col >= 0) & (col <= nx - 1) & (row >= 0) & (row <= ny - 1)
    c = np.where(inside, col, 0.0)
    r = np.where(inside, row, 0.0)
    c0 = np.minimum(np.floor(c).astype(np.intp), nx - 2)
    r0 = np.minimum(np.floor(r).astype(np.intp), ny - 2)
    fc, fr = c - c0, r - r0
    v00, v01 = values[r0, c0], values[r0, c0 + 1]
    v10, v11 = values[r0 + 1, c0], values[r0 + 1, c0 + 1]
    out = (v00 * (1 - fc) + v01 * fc) * (1 - fr) + (v10 * (1 - fc) + v11 * fc) * fr
    return np.where(inside, out, np.nan)


def _numpy_nearest(values, col, row):
    """Reference: the numpy nearest-node read."""
    col, row = np.broadcast_arrays(np.asarray(col, float), np.asarray(row, float))
    ny, nx = values.shape
    ic, ir = np.rint(col), np.rint(row)
    inside = (ic >= 0) & (ic <= nx - 1) & (ir >= 0) & (ir <= ny - 1)
    ic = np.where(inside, ic, 0).astype(np.intp)
    ir = np.where(inside, ir, 0).astype(np.intp)
    return np.where(inside, values[ir, ic], np.nan)


@pytest.fixture(scope="module")
def grid():
    rng = np.random.default_rng(11)
    values = rng.normal(-100.0, 5.0, (37, 53))
    values[5, 7] = np.nan  # a no-data cell
    values[20:23, 40:42] = np.nan
    return Grid(values, x0=1000.0, y0=-500.0, dx=10.0, dy=12.5)


def _positions(grid, rng, n=4000):
    """Random positions on and around the map, plus exact nodes, edges and NaNs."""
    west, east, south, north = grid.extent
    x = rng.uniform(west - 30.0, east + 30.0, n)
    y = rng.uniform(south - 30.0, north + 30.0, n)
    # exact nodes, the last column/row, half-cells (rounding ties) and NaN positions
    nodes_x = grid.x0 + grid.dx * np.array([0, 1, 52, 52, 0, 26.5, 3.5, 52])
    nodes_y = grid.y0 + grid.dy * np.array([0, 36, 0, 36, 17.5, 2.5, 36, 4])
    x = np.concatenate([x, nodes_x, [np.nan, 1100.0]])
    y = np.concatenate([y, nodes_y, [0.0, np.nan]])
    return x, y


def test_bilinear_matches_numpy_reference_on_and_off_the_map(grid):
    x, y = _positions(grid, np.random.default_rng(0))
    col, row = grid.xy_to_cell(x, y)
    expected = _numpy_bilinear(grid.values, col, row)
    got = grid.sample(x, y)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(expected))
    np.testing.assert_allclose(got, expected, rtol=1e-14, atol=0)
    # the reference does produce the NaN cases this test is about
    assert np.isnan(expected).sum() > 100 and np.isfinite(expected).sum() > 1000


def test_nearest_matches_numpy_reference_with_half_to_even_ties(grid):
    x, y = _positions(grid, np.random.default_rng(1))
    col, row = grid.xy_to_cell(x, y)
    expected = _numpy_nearest(grid.values, col, row)
    np.testing.assert_array_equal(grid.sample(x, y, method="nearest"), expected)


def test_gradient_is_that_of_the_interpolant(grid):
    rng = np.random.default_rng(2)
    x = rng.uniform(grid.x0 + 1, grid.x0 + 51 * grid.dx, 500)
    y = rng.uniform(grid.y0 + 1, grid.y0 + 35 * grid.dy, 500)
    value, gx, gy = grid.sample_gradient(x, y)
    np.testing.assert_allclose(value, grid.sample(x, y), rtol=1e-14)
    # central differences inside one stencil cell are exact for a bilinear patch in x or y
    h = 1e-4
    col, row = grid.xy_to_cell(x, y)
    safe = (np.abs(col - np.rint(col)) > 1e-3) & (np.abs(row - np.rint(row)) > 1e-3)
    fx = (grid.sample(x + h, y) - grid.sample(x - h, y)) / (2 * h)
    fy = (grid.sample(x, y + h) - grid.sample(x, y - h)) / (2 * h)
    ok = safe & np.isfinite(value)
    assert ok.sum() > 400
    np.testing.assert_allclose(gx[ok], fx[ok], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(gy[ok], fy[ok], rtol=1e-6, atol=1e-9)
    # NaN wherever the value is NaN
    off = grid.sample_gradient(np.array([grid.x0 - 1.0]), np.array([grid.y0]))
    assert all(np.isnan(a[0]) for a in off)


def test_known_gradient_of_a_plane():
    yy, xx = np.mgrid[0:10, 0:12]
    plane = Grid(3.0 * xx * 5.0 - 2.0 * yy * 4.0, 0.0, 0.0, 5.0, 4.0)
    value, gx, gy = plane.sample_gradient(np.array([12.3, 54.9]), np.array([7.1, 35.0]))
    np.testing.assert_allclose(value, [3.0 * 12.3 - 2.0 * 7.1, 3.0 * 54.9 - 2.0 * 35.0])
    np.testing.assert_allclose(gx, 3.0)
    np.testing.assert_allclose(gy, -2.0)


def test_shapes_broadcast_and_float32_maps_read_in_float64(grid):
    x = grid.x0 + np.linspace(0, 500, 7)[:, None]
    y = grid.y0 + np.linspace(0, 400, 3)[None, :]
    assert grid.sample(x, y).shape == (7, 3)
    assert grid.sample(grid.x0 + 5.0, grid.y0 + 5.0).shape == ()
    single = grid.values.astype(np.float32)
    got = mapread.read_xy(single, grid.x0, grid.y0, grid.dx, grid.dy, x, y)
    assert got.dtype == np.float64
    expected = _numpy_bilinear(single.astype(float), *grid.xy_to_cell(x, y))
    np.testing.assert_allclose(got, expected, rtol=1e-14)


def test_beams_read_equals_pointwise_read(grid):
    rng = np.random.default_rng(3)
    col, row = rng.uniform(-2, 54, 300), rng.uniform(-2, 38, 300)
    bcol, brow = np.array([-1.5, 0.0, 2.25]), np.array([0.5, 0.0, -0.75])
    got = mapread.bilinear_beams(grid.values, col, row, bcol, brow)
    expected = _numpy_bilinear(grid.values, col[:, None] + bcol, row[:, None] + brow)
    np.testing.assert_allclose(got, expected, rtol=1e-14)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(expected))


def test_unknown_method_raises(grid):
    with pytest.raises(ValueError, match="unknown sampling method"):
        grid.sample(0.0, 0.0, method="cubic")


def test_grid_keeps_read_only_float_arrays_and_copies_the_rest():
    base = np.arange(12.0).reshape(3, 4)
    copied = Grid(base, 0.0, 0.0, 1.0, 1.0)
    base[0, 0] = 99.0
    assert copied.values[0, 0] == 0.0 and not copied.values.flags.writeable
    single = base.astype(np.float32)
    assert Grid(single, 0.0, 0.0, 1.0, 1.0).values.dtype == np.float64  # writeable: copied
    single.flags.writeable = False
    kept = Grid(single, 0.0, 0.0, 1.0, 1.0)
    assert kept.values is single and kept.values.dtype == np.float32
    strided = np.arange(24.0).reshape(3, 8)[:, ::2]
    strided.flags.writeable = False
    assert Grid(strided, 0.0, 0.0, 1.0, 1.0).values.flags.c_contiguous


# ----------------------------------------------------------------------------- bicubic
def _quadratic_grid():
    ny, nx = 12, 15
    yy, xx = np.mgrid[0:ny, 0:nx] * 10.0

    def surface(x, y):
        return 3.0 + 0.2 * x - 0.1 * y + 0.004 * x * x - 0.003 * x * y + 0.002 * y * y

    return Grid(surface(xx, yy), 0.0, 0.0, 10.0, 10.0), surface


def test_bicubic_reproduces_a_quadratic_surface_exactly(rng):
    grid, surface = _quadratic_grid()
    x, y = rng.uniform(0.0, 140.0, 500), rng.uniform(0.0, 110.0, 500)  # edges included
    np.testing.assert_allclose(grid.sample(x, y, method="bicubic"), surface(x, y), atol=1e-9)
    # bilinear is not exact there (the curvature term), bicubic at the nodes is the node
    assert np.abs(grid.sample(x, y) - surface(x, y)).max() > 0.01
    gx, gy = np.meshgrid(grid.x, grid.y)
    np.testing.assert_allclose(grid.sample(gx, gy, method="bicubic"), grid.values, atol=1e-12)


def test_bicubic_nan_rules_are_the_bilinear_ones():
    from dataclasses import replace

    grid, _ = _quadratic_grid()
    values = grid.values.copy()
    values[5, 6] = np.nan  # the cell centred on (60, 50)
    holed = grid.with_values(values)
    off = [(-0.1, 50.0), (140.1, 50.0), (60.0, -1.0), (60.0, 110.5), (np.nan, 3.0)]
    for x, y in off:
        assert np.isnan(holed.sample(x, y, method="bicubic"))
    # every position whose 4 x 4 stencil holds the no-data cell reads NaN
    assert np.isnan(holed.sample(55.0, 45.0, method="bicubic"))  # bilinear NaN too
    assert np.isnan(holed.sample(45.0, 35.0, method="bicubic"))  # cell two away: in the 4 x 4
    assert np.isfinite(holed.sample(45.0, 35.0))  # (bilinear's 2 x 2 misses it)
    assert np.isfinite(holed.sample(25.0, 25.0, method="bicubic"))
    # the grid's default read and the measurement model follow Grid.interpolation
    cubic = replace(holed, interpolation="bicubic")
    assert np.isnan(cubic.sample(45.0, 35.0))
    from geofix.measurement import predict_measurements

    got = predict_measurements(cubic, np.array([[25.0, 25.0]]), 0.0, np.array([[3.0, 4.0]]))
    assert got[0, 0] == pytest.approx(holed.sample(28.0, 29.0, method="bicubic"))
    with pytest.raises(MapError, match="interpolation"):
        replace(grid, interpolation="spline")


# ----------------------------------------------------------------------------- bicubic gradient
def _wavy_grid(**changes):
    """A sin/cos field on a 40 x 30 grid with unequal cells (7 m by 11 m)."""
    ny, nx, dx, dy = 30, 40, 7.0, 11.0
    yy, xx = np.mgrid[0:ny, 0:nx]
    x, y = 100.0 + dx * xx, -40.0 + dy * yy
    values = 20.0 * np.sin(x / 37.0) * np.cos(y / 53.0) + 5.0 * np.cos(x / 23.0 + y / 31.0)
    return Grid(values, 100.0, -40.0, dx, dy, **changes)


def _cells_with_edges(grid, rng, n=600):
    """Fractional cells away from cell edges; a quarter in the first/last column or row."""
    ny, nx = grid.shape
    col = rng.integers(0, nx - 1, n) + rng.uniform(0.05, 0.95, n)
    row = rng.integers(0, ny - 1, n) + rng.uniform(0.05, 0.95, n)
    q = n // 8
    col[:q] = rng.uniform(0.05, 0.95, q)  # first column of cells
    col[q : 2 * q] = nx - 2 + rng.uniform(0.05, 0.95, q)  # last one
    row[2 * q : 3 * q] = rng.uniform(0.05, 0.95, q)
    row[3 * q : 4 * q] = ny - 2 + rng.uniform(0.05, 0.95, q)
    return col, row


def test_bicubic_gradient_matches_finite_differences_of_the_bicubic_read(rng):
    grid = _wavy_grid()
    col, row = _cells_with_edges(grid, rng)
    x, y = grid.cell_to_xy(col, row)
    value, gx, gy = grid.sample_gradient(x, y, method="bicubic")
    # the value is the bicubic read itself, bit for bit
    np.testing.assert_array_equal(value, grid.sample(x, y, method="bicubic"))
    h = 1e-4
    fx = (grid.sample(x + h, y, method="bicubic") - grid.sample(x - h, y, method="bicubic")) / (
        2 * h
    )
    fy = (grid.sample(x, y + h, method="bicubic") - grid.sample(x, y - h, method="bicubic")) / (
        2 * h
    )
    assert np.isfinite(gx).all() and np.isfinite(gy).all()
    np.testing.assert_allclose(gx, fx, rtol=1e-6, atol=1e-6 * np.abs(fx).max())
    np.testing.assert_allclose(gy, fy, rtol=1e-6, atol=1e-6 * np.abs(fy).max())
    # the edge cells (extrapolated stencil) are checked too
    ny, nx = grid.shape
    edge = (col < 1) | (col > nx - 2) | (row < 1) | (row > ny - 2)
    assert edge.sum() >= 300
    # and it is not the bilinear slope
    _, bx, by = grid.sample_gradient(x, y, method="bilinear")
    assert np.abs(bx - gx).max() > 1e-2 and np.abs(by - gy).max() > 1e-2


def test_bicubic_gradient_is_continuous_across_cell_edges():
    grid = _wavy_grid()
    ny, nx = grid.shape
    # every interior column and row edge (the first and last included: extrapolated on one
    # side of them)
    col = np.arange(1, nx - 1, dtype=float)
    row = np.full(col.shape, 7.3)
    eps = 1e-9
    below = grid.sample_gradient(*grid.cell_to_xy(col - eps, row), method="bicubic")
    above = grid.sample_gradient(*grid.cell_to_xy(col + eps, row), method="bicubic")
    np.testing.assert_allclose(below[1], above[1], rtol=0, atol=1e-7)
    row = np.arange(1, ny - 1, dtype=float)
    col = np.full(row.shape, 11.6)
    below = grid.sample_gradient(*grid.cell_to_xy(col, row - eps), method="bicubic")
    above = grid.sample_gradient(*grid.cell_to_xy(col, row + eps), method="bicubic")
    np.testing.assert_allclose(below[2], above[2], rtol=0, atol=1e-7)
    # the bilinear slope jumps across the column edges
    col, row = np.arange(1, nx - 1, dtype=float), np.full(nx - 2, 7.3)
    lin_below = grid.sample_gradient(*grid.cell_to_xy(col - eps, row), method="bilinear")
    lin_above = grid.sample_gradient(*grid.cell_to_xy(col + eps, row), method="bilinear")
    assert np.abs(lin_below[1] - lin_above[1]).max() > 1e-2


def test_bicubic_gradient_nan_rules():
    grid, _ = _quadratic_grid()
    values = grid.values.copy()
    values[5, 6] = np.nan  # the cell centred on (60, 50)
    holed = grid.with_values(values)
    # (45, 35): the 4 x 4 stencil holds the no-data cell, the bilinear 2 x 2 does not
    value, gx, gy = holed.sample_gradient(np.array([45.0]), np.array([35.0]), method="bicubic")
    assert np.isnan(value[0]) and np.isnan(gx[0]) and np.isnan(gy[0])
    assert np.isfinite(holed.sample_gradient(45.0, 35.0, method="bilinear")).all()
    # off the grid or at a NaN position: all NaN
    x = np.array([-0.1, 140.1, 60.0, 60.0, np.nan])
    y = np.array([50.0, 50.0, -1.0, 110.5, 3.0])
    for part in holed.sample_gradient(x, y, method="bicubic"):
        assert np.isnan(part).all()
    # away from the hole every part is finite
    assert np.isfinite(holed.sample_gradient(25.0, 25.0, method="bicubic")).all()


def test_bicubic_gradient_of_a_quadratic_is_exact_a_cubic_is_not(rng):
    ny, nx, dx, dy = 14, 17, 6.0, 9.0
    yy, xx = np.mgrid[0:ny, 0:nx]
    X, Y = dx * xx, dy * yy
    x, y = rng.uniform(0.0, dx * (nx - 1), 800), rng.uniform(0.0, dy * (ny - 1), 800)
    # z = 2 + 0.3 x - 0.2 y + 0.004 x^2 - 0.003 x y + 0.005 y^2 (edge cells included)
    quad = 2.0 + 0.3 * X - 0.2 * Y + 0.004 * X**2 - 0.003 * X * Y + 0.005 * Y**2
    grid = Grid(quad, 0.0, 0.0, dx, dy)
    value, gx, gy = grid.sample_gradient(x, y, method="bicubic")
    np.testing.assert_allclose(
        value, 2.0 + 0.3 * x - 0.2 * y + 0.004 * x**2 - 0.003 * x * y + 0.005 * y**2, atol=1e-9
    )
    np.testing.assert_allclose(gx, 0.3 + 0.008 * x - 0.003 * y, atol=1e-9)
    np.testing.assert_allclose(gy, -0.2 - 0.003 * x + 0.010 * y, atol=1e-9)
    # Keys (a = -0.5) stops at degree two along each axis: a cubic's gradient is only
    # approximated
    cubic = grid.with_values(quad + 1e-4 * X**3 + 2e-4 * Y**3)
    _, cx, cy = cubic.sample_gradient(x, y, method="bicubic")
    true_cx = 0.3 + 0.008 * x - 0.003 * y + 3e-4 * x**2
    true_cy = -0.2 - 0.003 * x + 0.010 * y + 6e-4 * y**2
    assert np.abs(cx - true_cx).max() > 1e-4 and np.abs(cy - true_cy).max() > 1e-4
    assert np.abs(cx - true_cx).max() < 0.1 * np.abs(true_cx).max()


def test_bicubic_gradient_on_a_narrow_grid_is_the_bilinear_one(rng):
    values = rng.normal(0.0, 3.0, (2, 9))  # two rows: read bilinear, as _bicubic_at does
    x, y = rng.uniform(0.0, 8.0, 50), rng.uniform(0.0, 1.0, 50)
    cubic = mapread.gradient_xy(values, 0.0, 0.0, 1.0, 1.0, x, y, method="bicubic")
    linear = mapread.gradient_xy(values, 0.0, 0.0, 1.0, 1.0, x, y)
    for a, b in zip(cubic, linear, strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(
        cubic[0], mapread.read_xy(values, 0.0, 0.0, 1.0, 1.0, x, y, method="bicubic")
    )


def test_sample_gradient_follows_the_grid_interpolation_and_rejects_other_methods():
    from dataclasses import replace

    grid = _wavy_grid()
    x, y = np.array([150.0, 300.0]), np.array([0.0, 200.0])
    cubic = replace(grid, interpolation="bicubic")
    for got, want in zip(
        cubic.sample_gradient(x, y), grid.sample_gradient(x, y, method="bicubic"), strict=True
    ):
        np.testing.assert_array_equal(got, want)
    for got, want in zip(
        grid.sample_gradient(x, y),
        mapread.gradient_xy(grid.values, grid.x0, grid.y0, grid.dx, grid.dy, x, y),
        strict=True,
    ):
        np.testing.assert_array_equal(got, want)
    with pytest.raises(ValueError, match="unknown gradient method 'nearest'"):
        grid.sample_gradient(x, y, method="nearest")
    with pytest.raises(ValueError, match="unknown gradient method"):
        mapread.gradient_xy(grid.values, 0.0, 0.0, 1.0, 1.0, x, y, method="cubic")
