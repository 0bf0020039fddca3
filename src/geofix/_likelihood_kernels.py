"""Compiled map read and likelihood fused: one pass over hypotheses x beams.

The kernels read the map and sum the Gaussian log-likelihood in one pass, without the
``(hypotheses, beams)`` array of predictions. The reads are exactly those of
:func:`geofix.maps.mapread.bilinear_beams` (unchecked where every footprint is known to
be on the map: the same stencil and operations); the sums over beams (and the node field
variance of :mod:`geofix._measurement_kernels`) are reassociated so that they vectorise,
within ~1e-15 relative of the reference's ordered sums (the tests compare both). Only
the measured beams are passed (a missing beam is skipped by both sums and needs no read).
Called through :func:`geofix.measurement.hypotheses_log_likelihood` and
:func:`geofix.measurement.node_grid_log_likelihood`.
"""

from __future__ import annotations

import numba
import numpy as np

from geofix.maps.mapread import bilinear_at


@numba.njit(cache=True, nogil=True, inline="always")
def _read_inside(values, c, r):  # pragma: no cover - compiled
    """``bilinear_at(values, c, r)`` where ``0 <= c < nx - 1`` and ``0 <= r < ny - 1``.

    No checks: there the stencil is the same (``c0 = int(c)``), and so is every operation.
    """
    c0 = int(c)
    r0 = int(r)
    fc = c - c0
    fr = r - r0
    return (values[r0, c0] * (1 - fc) + values[r0, c0 + 1] * fc) * (1 - fr) + (
        values[r0 + 1, c0] * (1 - fc) + values[r0 + 1, c0 + 1] * fc
    ) * fr


@numba.njit(cache=True, nogil=True)
def _widen(bounds, c, r):  # pragma: no cover - compiled
    """Grow ``bounds`` ``[cmin, cmax, rmin, rmax]`` to hold the cell ``(c, r)``."""
    bounds[0] = min(bounds[0], c)
    bounds[1] = max(bounds[1], c)
    bounds[2] = min(bounds[2], r)
    bounds[3] = max(bounds[3], r)


@numba.njit(cache=True, nogil=True)
def _all_inside(values, bounds, bcol, brow):  # pragma: no cover - compiled
    """True when every footprint ``(c + bcol, r + brow)`` is strictly inside the stencil range.

    ``bounds`` ``[cmin, cmax, rmin, rmax]`` bound the (finite) hypotheses' cells. Rounded
    addition is monotone, so the sums of the bounds bound every footprint; strictly below
    ``n - 1``, ``int`` of a footprint is its stencil's first cell.
    """
    ny, nx = values.shape
    if bcol.shape[0] == 0:
        return False
    return (
        bounds[0] + bcol.min() >= 0.0
        and bounds[2] + brow.min() >= 0.0
        and bounds[1] + bcol.max() < nx - 1
        and bounds[3] + brow.max() < ny - 1
    )


@numba.njit(cache=True, nogil=True, inline="always")
def _beam_sum(values, col, row, bcol, brow, measured, var, off_map, inside, buffer):
    """Log-likelihood of the beams from one hypothesis at fractional cell ``(col, row)``.

    ``inside``: every footprint is known to lie inside the stencil range (no checks).
    The reads go to ``buffer`` ``(b,)``, then one vectorised sum (:func:`_term_sum`).
    """
    if inside:  # pragma: no cover - compiled
        for j in range(measured.shape[0]):
            buffer[j] = _read_inside(values, col + bcol[j], row + brow[j])
    else:
        for j in range(measured.shape[0]):
            buffer[j] = bilinear_at(values, col + bcol[j], row + brow[j])
    return _term_sum(buffer, measured, var, off_map)


@numba.njit(cache=True, nogil=True)
def hypotheses_ll(values, origin, cell, px, py, bcol, brow, measured, var, off_map, out):
    """``out[i]``: log-likelihood from position ``(px[i], py[i])``, metres."""
    n = px.shape[0]  # pragma: no cover - compiled
    cols = np.empty(n)
    rows = np.empty(n)
    bounds = np.array([np.inf, -np.inf, np.inf, -np.inf])
    finite = True
    for i in range(n):
        c = (px[i] - origin[0]) / cell[0]
        r = (py[i] - origin[1]) / cell[1]
        cols[i] = c
        rows[i] = r
        finite = finite and c == c and r == r
        _widen(bounds, c, r)
    inside = finite and _all_inside(values, bounds, bcol, brow)
    buffer = np.empty(measured.shape[0])
    for i in range(n):
        c, r = cols[i], rows[i]
        out[i] = _beam_sum(values, c, r, bcol, brow, measured, var, off_map, inside, buffer)


@numba.njit(cache=True, nogil=True)
def _node_cell(origin, cell, centre, axes, u, v, i, j):  # pragma: no cover - compiled
    """Fractional map cell of node ``[i, j]`` (as ``node_positions`` then ``xy_to_cell``)."""
    x = centre[0] + u[i] * axes[0, 0] + v[j] * axes[0, 1]
    y = centre[1] + u[i] * axes[1, 0] + v[j] * axes[1, 1]
    return (x - origin[0]) / cell[0], (y - origin[1]) / cell[1]


@numba.njit(cache=True, nogil=True)
def _nodes_inside(values, origin, cell, centre, axes, u, v, bcol, brow):  # pragma: no cover
    """True when every footprint of every node is inside the map's stencil range."""
    bounds = np.array([np.inf, -np.inf, np.inf, -np.inf])
    for i in range(u.shape[0]):
        for j in range(v.shape[0]):
            c, r = _node_cell(origin, cell, centre, axes, u, v, i, j)
            if not (c == c and r == r):
                return False
            _widen(bounds, c, r)
    return _all_inside(values, bounds, bcol, brow)


@numba.njit(cache=True, nogil=True)
def node_ll(values, origin, cell, centre, axes, u, v, bcol, brow, measured, var, off_map, out):
    """``out[i, j]``: log-likelihood from node ``[i, j]`` of a point-mass grid."""
    inside = _nodes_inside(values, origin, cell, centre, axes, u, v, bcol, brow)
    buffer = np.empty(measured.shape[0])
    for i in range(u.shape[0]):  # pragma: no cover - compiled
        for j in range(v.shape[0]):
            col, row = _node_cell(origin, cell, centre, axes, u, v, i, j)
            c, r = col, row
            out[i, j] = _beam_sum(values, c, r, bcol, brow, measured, var, off_map, inside, buffer)


@numba.njit(cache=True, nogil=True)
def _node_predictions(values, origin, cell, centre, axes, u, v, bcol, brow, i, p, inside):
    """``p[i, j, k]``: the map read by beam ``k`` from node ``[i, j]``, for one row ``i``."""
    for j in range(v.shape[0]):  # pragma: no cover - compiled
        col, row = _node_cell(origin, cell, centre, axes, u, v, i, j)
        if inside:
            for k in range(bcol.shape[0]):
                p[i, j, k] = _read_inside(values, col + bcol[k], row + brow[k])
        else:
            for k in range(bcol.shape[0]):
                p[i, j, k] = bilinear_at(values, col + bcol[k], row + brow[k])


_REASSOC = {"reassoc"}
"""Fast-math flag of the flattened path's sums: only reassociation (so they vectorise),
no assumption about NaN or infinity (the off-map test needs both)."""


@numba.njit(cache=True, nogil=True, fastmath=_REASSOC)
def _difference_sums(a, b):  # pragma: no cover - compiled
    """``(sum((b - a)^2), count)`` over the finite differences of two 1-D arrays."""
    acc = 0.0
    count = 0
    for k in range(a.shape[0]):
        d = b[k] - a[k]
        finite = np.isfinite(d)
        acc += d * d if finite else 0.0
        count += 1 if finite else 0
    return acc, count


@numba.njit(cache=True, nogil=True, fastmath=_REASSOC)
def _term_sum(predicted, measured, var, off_map):  # pragma: no cover - compiled
    """``sum(-0.5 (p - y)^2 / var)`` over beams, ``off_map`` for a non-finite term."""
    acc = 0.0
    for k in range(measured.shape[0]):
        d = predicted[k] - measured[k]
        term = -0.5 * d * d / var[k]
        acc += term if np.isfinite(term) else off_map
    return acc


@numba.njit(cache=True, nogil=True)
def node_ll_flattened(
    values, origin, cell, centre, axes, u, v, bcol, brow, measured, var, off_map, p, out
):  # pragma: no cover - compiled
    """Node log-likelihoods with the node field variance added to every beam's variance.

    ``p`` is a scratch ``(N0, N1, b)`` array. Rows are read one ahead, so the neighbour
    differences of row ``i`` are summed while rows ``i`` and ``i + 1`` are in cache. The
    reads are exact; the sums (field variance, then each node's log-likelihood) are
    reassociated so that they vectorise: within ~1e-15 relative of the reference's
    ordered sums. Returns the field variance, map units squared.
    """
    n0, n1, b = u.shape[0], v.shape[0], bcol.shape[0]
    acc0 = acc1 = 0.0
    count0 = count1 = 0
    inside = _nodes_inside(values, origin, cell, centre, axes, u, v, bcol, brow)
    _node_predictions(values, origin, cell, centre, axes, u, v, bcol, brow, 0, p, inside)
    flat_p = p.reshape(n0, n1 * b)
    for i in range(n0):
        if i + 1 < n0:
            args = (values, origin, cell, centre, axes, u, v, bcol, brow, i + 1, p, inside)
            _node_predictions(*args)
            s, c = _difference_sums(flat_p[i], flat_p[i + 1])
            acc0 += s
            count0 += c
        s, c = _difference_sums(flat_p[i, : (n1 - 1) * b], flat_p[i, b:])
        acc1 += s
        count1 += c
    total = 0.0  # the reference: (acc0 / count0 + acc1 / count1) / 12, each when counted
    if count0:
        total += acc0 / count0
    if count1:
        total += acc1 / count1
    field_var = total / 12.0
    flat = var + field_var
    for i in range(n0):
        for j in range(n1):
            out[i, j] = _term_sum(p[i, j], measured, flat, off_map)
    return field_var
