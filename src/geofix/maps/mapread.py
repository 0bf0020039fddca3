"""The one compiled map read: bilinear and bicubic (value and gradient), nearest-node look-ups.

Every reader of a :class:`~geofix.maps.grid.Grid` -- ``Grid.sample``, the sensors, the
matchers, the filters' measurement model -- goes through these numba kernels, so the
map is interpolated one way everywhere. Conventions (those of ``Grid.sample``):

- positions are metric; the fractional cell of ``x`` is ``col = (x - x0) / dx`` (rows
  likewise), cell ``[0, 0]`` centred on ``(x0, y0)``;
- **bilinear** reads the four cell centres around ``(col, row)``; a position outside
  ``0 <= col <= nx - 1``, ``0 <= row <= ny - 1`` (or a NaN position) reads NaN, and so does
  one whose stencil holds a NaN (no-data) cell. On the last column/row the stencil is the
  last pair of cells (weight 1 on the edge cell);
- the **gradient** is that of the bilinear interpolant inside the stencil cell, field
  units per metre: ``d/dx = ((v01 - v00) (1 - fr) + (v11 - v10) fr) / dx`` and
  ``d/dy = ((v10 - v00) (1 - fc) + (v11 - v01) fc) / dy`` (one-sided at cell edges, like
  the interpolant itself);
- **nearest** rounds ``col`` and ``row`` half-to-even (``numpy.rint``) and reads NaN
  outside the grid;
- **bicubic** is Keys' cubic convolution (R. G. Keys, "Cubic convolution interpolation
  for digital image processing", IEEE Trans. ASSP 29(6), 1981) with ``a = -0.5``, which
  reproduces polynomials up to degree two exactly: the weights of the ``4 x 4`` cells
  around the bilinear stencil cell at fraction ``t`` are ``(-t^3 + 2 t^2 - t) / 2``,
  ``(3 t^3 - 5 t^2 + 2) / 2``, ``(-3 t^3 + 4 t^2 + t) / 2``, ``(t^3 - t^2) / 2``. The
  NaN rules are the bilinear ones: NaN outside ``0 <= col <= nx - 1`` (rows likewise) and
  NaN when any of the stencil's cells is no-data. Where the stencil reaches one cell past
  the edge, that cell is Keys' boundary extrapolation ``f(-1) = 3 f(0) - 3 f(1) + f(2)``
  (exact for quadratics); a grid of fewer than three cells along an axis is read bilinear.
  Its **gradient** (:func:`gradient_xy` with ``method="bicubic"``) is the exact
  derivative of that interpolant (C1 across cell edges): along one axis the derivative
  weights ``(-3 t^2 + 4 t - 1) / 2``, ``(9 t^2 - 10 t) / 2``, ``(-9 t^2 + 8 t + 1) / 2``,
  ``(3 t^2 - 2 t) / 2``, along the other the weights above, on the same stencil with the
  same extrapolation and NaN rules, divided by ``dx`` (``dy``).

The scalar kernel :func:`bilinear_at` is a numba function that other compiled kernels
(TERCOM, GA-SCA, the filters' likelihood) call inline. Values may be float64 or float32
(a float32 map is read and interpolated in float64).
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import ArrayLike


# ----------------------------------------------------------------------------- scalar kernels
@numba.njit(cache=True, nogil=True)
def _stencil(c, r, nx, ny):  # pragma: no cover - compiled
    """``(inside, c0, r0, fc, fr)`` of the bilinear stencil at fractional cell ``(c, r)``."""
    if not (c >= 0.0 and r >= 0.0 and c <= nx - 1 and r <= ny - 1):
        return False, 0, 0, 0.0, 0.0
    c0 = min(int(c), nx - 2)
    r0 = min(int(r), ny - 2)
    return True, c0, r0, c - c0, r - r0


@numba.njit(cache=True, nogil=True)
def _combine(values, c0, r0, fc, fr):  # pragma: no cover - compiled
    """Bilinear combination of the stencil at ``values[r0:r0+2, c0:c0+2]``."""
    return (values[r0, c0] * (1 - fc) + values[r0, c0 + 1] * fc) * (1 - fr) + (
        values[r0 + 1, c0] * (1 - fc) + values[r0 + 1, c0 + 1] * fc
    ) * fr


@numba.njit(cache=True, nogil=True)
def bilinear_at(values, c, r):  # pragma: no cover - compiled
    """Bilinear value at fractional cell ``(c, r)``; NaN off the grid or on no-data.

    Parameters
    ----------
    values : numpy.ndarray
        ``(ny, nx)`` map values (float64 or float32), NaN = no data.
    c, r : float
        Fractional column and row, cells (``c = (x - x0) / dx``).

    Returns
    -------
    float
        The interpolated value, map units.
    """
    ny, nx = values.shape
    inside, c0, r0, fc, fr = _stencil(c, r, nx, ny)
    if not inside:
        return np.nan
    return _combine(values, c0, r0, fc, fr)


@numba.njit(cache=True, nogil=True)
def _nearest_at(values, c, r):  # pragma: no cover - compiled
    """Value of the node nearest to ``(c, r)`` (half-to-even); NaN off the grid."""
    ny, nx = values.shape
    ic = np.rint(c)
    ir = np.rint(r)
    if not (ic >= 0.0 and ir >= 0.0 and ic <= nx - 1 and ir <= ny - 1):
        return np.nan
    return values[int(ir), int(ic)] * 1.0


@numba.njit(cache=True, nogil=True)
def _keys_weights(t):  # pragma: no cover - compiled
    """Keys (a = -0.5) weights of the cells at offsets -1, 0, 1, 2 for fraction ``t``."""
    t2 = t * t
    t3 = t2 * t
    return (
        0.5 * (-t3 + 2.0 * t2 - t),
        0.5 * (3.0 * t3 - 5.0 * t2 + 2.0),
        0.5 * (-3.0 * t3 + 4.0 * t2 + t),
        0.5 * (t3 - t2),
    )


@numba.njit(cache=True, nogil=True)
def _cubic_row(values, r, c0, w0, w1, w2, w3, nx):  # pragma: no cover - compiled
    """Cubic combination along row ``r`` of columns ``c0 - 1 .. c0 + 2`` (edge-extrapolated)."""
    v1 = values[r, c0] * 1.0
    v2 = values[r, c0 + 1] * 1.0
    v0 = values[r, c0 - 1] * 1.0 if c0 >= 1 else 3.0 * v1 - 3.0 * v2 + values[r, c0 + 2]
    last = c0 + 2 <= nx - 1
    v3 = values[r, c0 + 2] * 1.0 if last else 3.0 * v2 - 3.0 * v1 + values[r, c0 - 1]
    return w0 * v0 + w1 * v1 + w2 * v2 + w3 * v3


@numba.njit(cache=True, nogil=True)
def _keys_derivative_weights(t):  # pragma: no cover - compiled
    """Derivatives ``d/dt`` of :func:`_keys_weights` (they sum to zero)."""
    t2 = t * t
    return (
        0.5 * (-3.0 * t2 + 4.0 * t - 1.0),
        0.5 * (9.0 * t2 - 10.0 * t),
        0.5 * (-9.0 * t2 + 8.0 * t + 1.0),
        0.5 * (3.0 * t2 - 2.0 * t),
    )


@numba.njit(cache=True, nogil=True)
def _cubic_rows(values, r0, c0, w0, w1, w2, w3, nx, ny):  # pragma: no cover - compiled
    """:func:`_cubic_row` on rows ``r0 - 1 .. r0 + 2`` (edge-extrapolated), four values."""
    h1 = _cubic_row(values, r0, c0, w0, w1, w2, w3, nx)
    h2 = _cubic_row(values, r0 + 1, c0, w0, w1, w2, w3, nx)
    if r0 >= 1:
        h0 = _cubic_row(values, r0 - 1, c0, w0, w1, w2, w3, nx)
    else:
        h0 = 3.0 * h1 - 3.0 * h2 + _cubic_row(values, r0 + 2, c0, w0, w1, w2, w3, nx)
    if r0 + 2 <= ny - 1:
        h3 = _cubic_row(values, r0 + 2, c0, w0, w1, w2, w3, nx)
    else:
        h3 = 3.0 * h2 - 3.0 * h1 + _cubic_row(values, r0 - 1, c0, w0, w1, w2, w3, nx)
    return h0, h1, h2, h3


@numba.njit(cache=True, nogil=True)
def _bicubic_at(values, c, r):  # pragma: no cover - compiled
    """Keys bicubic value at fractional cell ``(c, r)``; NaN off the grid or on no-data."""
    ny, nx = values.shape
    if nx < 3 or ny < 3:
        return bilinear_at(values, c, r)
    inside, c0, r0, fc, fr = _stencil(c, r, nx, ny)
    if not inside:
        return np.nan
    a0, a1, a2, a3 = _keys_weights(fc)
    h0, h1, h2, h3 = _cubic_rows(values, r0, c0, a0, a1, a2, a3, nx, ny)
    b0, b1, b2, b3 = _keys_weights(fr)
    return b0 * h0 + b1 * h1 + b2 * h2 + b3 * h3


@numba.njit(cache=True, nogil=True)
def _bilinear_gradient_at(values, c, r):  # pragma: no cover - compiled
    """``(value, d/dc, d/dr)`` of the bilinear read at ``(c, r)``, per cell; NaN as the value."""
    ny, nx = values.shape
    inside, c0, r0, fc, fr = _stencil(c, r, nx, ny)
    if not inside:
        return np.nan, np.nan, np.nan
    v00 = values[r0, c0] * 1.0
    v01 = values[r0, c0 + 1] * 1.0
    v10 = values[r0 + 1, c0] * 1.0
    v11 = values[r0 + 1, c0 + 1] * 1.0
    value = (v00 * (1 - fc) + v01 * fc) * (1 - fr) + (v10 * (1 - fc) + v11 * fc) * fr
    d_col = (v01 - v00) * (1 - fr) + (v11 - v10) * fr
    d_row = (v10 - v00) * (1 - fc) + (v11 - v01) * fc
    return value, d_col, d_row


@numba.njit(cache=True, nogil=True)
def _bicubic_gradient_at(values, c, r):  # pragma: no cover - compiled
    """``(value, d/dc, d/dr)`` of the Keys bicubic read at ``(c, r)``, per cell.

    The value is :func:`_bicubic_at`'s (the same operations); the derivative along one axis
    combines :func:`_keys_derivative_weights` along it with :func:`_keys_weights` along the
    other, on the same edge-extrapolated ``4 x 4`` stencil, so all three are NaN off the
    grid and wherever a stencil cell is NaN. Bilinear below three cells along an axis.
    """
    ny, nx = values.shape
    if nx < 3 or ny < 3:
        return _bilinear_gradient_at(values, c, r)
    inside, c0, r0, fc, fr = _stencil(c, r, nx, ny)
    if not inside:
        return np.nan, np.nan, np.nan
    a0, a1, a2, a3 = _keys_weights(fc)
    h0, h1, h2, h3 = _cubic_rows(values, r0, c0, a0, a1, a2, a3, nx, ny)
    da0, da1, da2, da3 = _keys_derivative_weights(fc)
    g0, g1, g2, g3 = _cubic_rows(values, r0, c0, da0, da1, da2, da3, nx, ny)
    b0, b1, b2, b3 = _keys_weights(fr)
    db0, db1, db2, db3 = _keys_derivative_weights(fr)
    value = b0 * h0 + b1 * h1 + b2 * h2 + b3 * h3
    d_col = b0 * g0 + b1 * g1 + b2 * g2 + b3 * g3
    d_row = db0 * h0 + db1 * h1 + db2 * h2 + db3 * h3
    return value, d_col, d_row


# ----------------------------------------------------------------------------- array kernels
@numba.njit(cache=True, nogil=True)
def _bilinear_xy(values, x0, y0, dx, dy, x, y, out):  # pragma: no cover - compiled
    for i in range(x.shape[0]):
        out[i] = bilinear_at(values, (x[i] - x0) / dx, (y[i] - y0) / dy)


@numba.njit(cache=True, nogil=True)
def _bicubic_xy(values, x0, y0, dx, dy, x, y, out):  # pragma: no cover - compiled
    for i in range(x.shape[0]):
        out[i] = _bicubic_at(values, (x[i] - x0) / dx, (y[i] - y0) / dy)


@numba.njit(cache=True, nogil=True)
def _bicubic_beams(values, col, row, bcol, brow, out):  # pragma: no cover - compiled
    for i in range(col.shape[0]):
        for b in range(bcol.shape[0]):
            out[i, b] = _bicubic_at(values, col[i] + bcol[b], row[i] + brow[b])


@numba.njit(cache=True, nogil=True)
def _nearest_xy(values, x0, y0, dx, dy, x, y, out):  # pragma: no cover - compiled
    for i in range(x.shape[0]):
        out[i] = _nearest_at(values, (x[i] - x0) / dx, (y[i] - y0) / dy)


@numba.njit(cache=True, nogil=True)
def _gradient_xy(values, x0, y0, dx, dy, x, y, out, gx, gy):  # pragma: no cover - compiled
    for i in range(x.shape[0]):
        value, d_col, d_row = _bilinear_gradient_at(values, (x[i] - x0) / dx, (y[i] - y0) / dy)
        out[i] = value
        gx[i] = d_col / dx
        gy[i] = d_row / dy


@numba.njit(cache=True, nogil=True)
def _bicubic_gradient_xy(values, x0, y0, dx, dy, x, y, out, gx, gy):  # pragma: no cover
    for i in range(x.shape[0]):
        value, d_col, d_row = _bicubic_gradient_at(values, (x[i] - x0) / dx, (y[i] - y0) / dy)
        out[i] = value
        gx[i] = d_col / dx
        gy[i] = d_row / dy


@numba.njit(cache=True, nogil=True)
def _bilinear_cells(values, col, row, out):  # pragma: no cover - compiled
    for i in range(col.shape[0]):
        out[i] = bilinear_at(values, col[i], row[i])


@numba.njit(cache=True, nogil=True)
def _bilinear_beams(values, col, row, bcol, brow, out):  # pragma: no cover - compiled
    for i in range(col.shape[0]):
        for b in range(bcol.shape[0]):
            out[i, b] = bilinear_at(values, col[i] + bcol[b], row[i] + brow[b])


# ----------------------------------------------------------------------------- numpy façade
def _flat(a: ArrayLike) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(a, dtype=np.float64).reshape(-1))


def _map_values(values: ArrayLike) -> np.ndarray:
    values = np.asarray(values)
    if values.dtype not in (np.float32, np.float64):
        values = values.astype(np.float64)
    return np.ascontiguousarray(values)


def read_xy(
    values: ArrayLike,
    x0: float,
    y0: float,
    dx: float,
    dy: float,
    x: ArrayLike,
    y: ArrayLike,
    method: str = "bilinear",
) -> np.ndarray:
    """Field values at metric positions (see the module docstring for the conventions).

    Parameters
    ----------
    values : numpy.ndarray
        ``(ny, nx)`` map values (float64 or float32), NaN = no data.
    x0, y0, dx, dy : float
        Centre of cell ``[0, 0]`` and cell size, metres.
    x, y : array_like
        Eastings and northings, metres; broadcastable shapes.
    method : {"bilinear", "bicubic", "nearest"}
        Interpolation.

    Returns
    -------
    numpy.ndarray
        float64 values of the broadcast shape of ``x`` and ``y``.
    """
    kernels = {"bilinear": _bilinear_xy, "bicubic": _bicubic_xy, "nearest": _nearest_xy}
    kernel = kernels.get(method)
    if kernel is None:
        raise ValueError(
            f"unknown sampling method {method!r}; use 'bilinear', 'bicubic' or 'nearest'"
        )
    x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    out = np.empty(x.size)
    kernel(_map_values(values), float(x0), float(y0), float(dx), float(dy), _flat(x), _flat(y), out)
    return out.reshape(x.shape)


def gradient_xy(
    values: ArrayLike,
    x0: float,
    y0: float,
    dx: float,
    dy: float,
    x: ArrayLike,
    y: ArrayLike,
    method: str = "bilinear",
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Value of a map read and its exact gradient at metric positions.

    Parameters
    ----------
    values : numpy.ndarray
        ``(ny, nx)`` map values (float64 or float32), NaN = no data.
    x0, y0, dx, dy : float
        Centre of cell ``[0, 0]`` and cell size, metres.
    x, y : array_like
        Eastings and northings, metres; broadcastable shapes.
    method : {"bilinear", "bicubic"}
        Interpolation (the nearest-node read has no gradient).

    Returns
    -------
    tuple of numpy.ndarray
        ``(value, d value / dx, d value / dy)``: field units and field units per metre,
        broadcast shape of ``x`` and ``y``; the value is that of :func:`read_xy` with the
        same ``method`` and the gradient that of its interpolant. All three are NaN where
        the value is NaN (off the grid, or a NaN stencil cell).
    """
    kernels = {"bilinear": _gradient_xy, "bicubic": _bicubic_gradient_xy}
    kernel = kernels.get(method)
    if kernel is None:
        raise ValueError(f"unknown gradient method {method!r}; use 'bilinear' or 'bicubic'")
    x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    out, gx, gy = np.empty(x.size), np.empty(x.size), np.empty(x.size)
    kernel(
        _map_values(values),
        float(x0),
        float(y0),
        float(dx),
        float(dy),
        _flat(x),
        _flat(y),
        out,
        gx,
        gy,
    )
    return out.reshape(x.shape), gx.reshape(x.shape), gy.reshape(x.shape)


def bilinear_cells(values: ArrayLike, col: ArrayLike, row: ArrayLike) -> np.ndarray:
    """Bilinear values at fractional cell indices ``(col, row)``.

    Parameters
    ----------
    values : numpy.ndarray
        ``(ny, nx)`` map values (float64 or float32), NaN = no data.
    col, row : array_like
        Fractional columns and rows, cells; broadcastable shapes.

    Returns
    -------
    numpy.ndarray
        float64 values, map units, of the broadcast shape of ``col`` and ``row``; NaN off
        the grid or on no-data.
    """
    col, row = np.broadcast_arrays(np.asarray(col, dtype=float), np.asarray(row, dtype=float))
    out = np.empty(col.size)
    _bilinear_cells(_map_values(values), _flat(col), _flat(row), out)
    return out.reshape(col.shape)


def bilinear_beams(
    values: ArrayLike,
    col: ArrayLike,
    row: ArrayLike,
    beam_col: ArrayLike,
    beam_row: ArrayLike,
) -> np.ndarray:
    """Bilinear values at every hypothesis ``(col, row)`` plus every beam offset.

    Parameters
    ----------
    values : numpy.ndarray
        ``(ny, nx)`` map values.
    col, row : numpy.ndarray
        ``(k,)`` fractional cells of the hypotheses.
    beam_col, beam_row : numpy.ndarray
        ``(b,)`` beam offsets in cells.

    Returns
    -------
    numpy.ndarray
        ``(k, b)`` values read at ``(col + beam_col, row + beam_row)``.
    """
    col, row = _flat(col), _flat(row)
    bcol, brow = _flat(beam_col), _flat(beam_row)
    out = np.empty((col.size, bcol.size))
    _bilinear_beams(_map_values(values), col, row, bcol, brow, out)
    return out


READS = ("bilinear", "bicubic")
"""Interpolations a model of the map may use (:attr:`geofix.maps.grid.Grid.interpolation`)."""


def read_beams(
    values: ArrayLike,
    col: ArrayLike,
    row: ArrayLike,
    beam_col: ArrayLike,
    beam_row: ArrayLike,
    method: str = "bilinear",
) -> np.ndarray:
    """Values at every hypothesis plus every beam offset, bilinear or bicubic.

    Parameters
    ----------
    values : numpy.ndarray
        ``(ny, nx)`` map values.
    col, row : numpy.ndarray
        ``(k,)`` fractional cells of the hypotheses.
    beam_col, beam_row : numpy.ndarray
        ``(b,)`` beam offsets in cells.
    method : {"bilinear", "bicubic"}
        Interpolation (one of :data:`READS`).

    Returns
    -------
    numpy.ndarray
        ``(k, b)`` values read at ``(col + beam_col, row + beam_row)``, as
        :func:`bilinear_beams` for ``"bilinear"``.

    Raises
    ------
    ValueError
        If ``method`` is not one of :data:`READS`.
    """
    if method == "bilinear":
        return bilinear_beams(values, col, row, beam_col, beam_row)
    if method != "bicubic":
        raise ValueError(f"unknown map read {method!r}; use one of {READS}")
    col, row = _flat(col), _flat(row)
    bcol, brow = _flat(beam_col), _flat(beam_row)
    out = np.empty((col.size, bcol.size))
    _bicubic_beams(_map_values(values), col, row, bcol, brow, out)
    return out
