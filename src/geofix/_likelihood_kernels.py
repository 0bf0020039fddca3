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


@numba.njit(cache=True, nogil=True)
def _beam_major_reads(values, cols, rows, n, bcol, brow, inside, out):  # pragma: no cover
    """``out[k, i]``: the map read by beam ``k`` from fractional cell ``(cols[i], rows[i])``.

    For ``i < n``, beam by beam. ``inside``: every footprint is known to lie inside the
    stencil range, and :func:`_read_beam_inside` reads without checks.
    """
    if not inside:
        for k in range(bcol.shape[0]):
            bc, br = bcol[k], brow[k]
            for i in range(n):
                out[k, i] = bilinear_at(values, cols[i] + bc, rows[i] + br)
        return
    flat = values.ravel()  # a view: map values are C-contiguous (Grid stores them so)
    first = np.empty(n, np.uint64)
    weights = np.empty((2, n))
    for k in range(bcol.shape[0]):
        reads = out[k]
        _read_beam_inside(
            flat, values.shape[1], cols, rows, n, bcol[k], brow[k], first, weights, reads
        )


@numba.njit(cache=True, nogil=True, inline="always")
def _read_beam_inside(flat, nx, cols, rows, n, bc, br, first, weights, out):  # pragma: no cover
    """``out[i] = bilinear_at(values, cols[i] + bc, rows[i] + br)`` for ``i < n``.

    Every footprint lies inside the stencil range (``0 <= c < nx - 1``, ``0 <= r < ny -
    1``): there the stencil is the same (truncation is ``int``'s for ``c >= 0``) and so is
    every operation, without checks. Two loops: the first (stencil corners and weights,
    arithmetic only) vectorises; the second reads through unsigned flat indices, which
    carry no negative-index wraparound. Its speed against the checked
    :func:`~geofix.maps.mapread.bilinear_at` is measured by
    ``benchmarks/bench_map_reads.py``. ``first`` ``(>= n,)`` uint64 and ``weights``
    ``(2, >= n)`` are scratch.
    """
    for i in range(n):
        c = cols[i] + bc
        r = rows[i] + br
        c0 = np.int64(c)
        r0 = np.int64(r)
        weights[0, i] = c - c0
        weights[1, i] = r - r0
        first[i] = r0 * nx + c0
    step = np.uint64(nx)
    one = np.uint64(1)
    for i in range(n):
        q = first[i]
        fc = weights[0, i]
        fr = weights[1, i]
        out[i] = (flat[q] * (1 - fc) + flat[q + one] * fc) * (1 - fr) + (
            flat[q + step] * (1 - fc) + flat[q + step + one] * fc
        ) * fr


#: Hypotheses read per block before their likelihoods are summed in one call: a compiled
#: call with array arguments costs about 70 ns (reference counting), as much as 20 reads,
#: so reads and sums are made a block of hypotheses at a time.
BLOCK = 128


@numba.njit(cache=True, nogil=True)
def _hypothesis_cells(values, origin, cell, px, py, bcol, brow):  # pragma: no cover
    """``(cols, rows, inside)``: fractional map cells of positions ``(px, py)``, metres.

    ``inside``: every footprint of every position lies inside the stencil range.
    """
    n = px.shape[0]
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
    return cols, rows, finite and _all_inside(values, bounds, bcol, brow)


@numba.njit(cache=True, nogil=True)
def hypotheses_ll(values, origin, cell, px, py, bcol, brow, measured, var, off_map, out):
    """``out[i]``: log-likelihood from position ``(px[i], py[i])``, metres."""
    cols, rows, inside = _hypothesis_cells(values, origin, cell, px, py, bcol, brow)
    n = px.shape[0]
    buffer = np.empty((measured.shape[0], BLOCK))
    for start in range(0, n, BLOCK):  # pragma: no cover - compiled
        stop = min(start + BLOCK, n)
        c, r = cols[start:stop], rows[start:stop]
        _beam_major_reads(values, c, r, stop - start, bcol, brow, inside, buffer)
        _beam_major_sums(buffer, stop - start, measured, var, off_map, out[start:stop])


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
    n1 = v.shape[0]
    buffer = np.empty((measured.shape[0], n1))
    for i in range(u.shape[0]):  # pragma: no cover - compiled
        _node_row_reads(values, origin, cell, centre, axes, u, v, bcol, brow, i, inside, buffer)
        _beam_major_sums(buffer, n1, measured, var, off_map, out[i])


@numba.njit(cache=True, nogil=True)
def _node_row_reads(values, origin, cell, centre, axes, u, v, bcol, brow, i, inside, out):
    """``out[k, j]``: the map read by beam ``k`` from node ``[i, j]``, for one row ``i``."""
    n1 = v.shape[0]
    cols = np.empty(n1)
    rows = np.empty(n1)
    for j in range(n1):  # pragma: no cover - compiled
        cols[j], rows[j] = _node_cell(origin, cell, centre, axes, u, v, i, j)
    _beam_major_reads(values, cols, rows, n1, bcol, brow, inside, out)


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
def _beam_major_sums(predicted, n, measured, var, off_map, out):  # pragma: no cover - compiled
    """``out[i] = sum_k -0.5 (p[k, i] - y_k)^2 / var_k`` for ``i < n``, in beam order.

    ``predicted`` is ``(b, >= n)`` (a block of hypotheses, beam by beam); ``off_map`` for a
    non-finite term. The sum over beams of each hypothesis is in beam order (the
    reference's); the loop over hypotheses vectorises.
    """
    for i in range(n):
        out[i] = 0.0
    for k in range(measured.shape[0]):
        y = measured[k]
        scale = -0.5 / var[k]
        for i in range(n):
            d = predicted[k, i] - y
            term = d * d * scale
            out[i] += term if np.isfinite(term) else off_map


@numba.njit(cache=True, nogil=True, fastmath=_REASSOC)
def _step_difference_sums(row):  # pragma: no cover - compiled
    """``(sum(d^2), count)`` of the finite differences ``row[k, j + 1] - row[k, j]``."""
    acc = 0.0
    count = 0
    for k in range(row.shape[0]):
        for j in range(row.shape[1] - 1):
            d = row[k, j + 1] - row[k, j]
            finite = np.isfinite(d)
            acc += d * d if finite else 0.0
            count += 1 if finite else 0
    return acc, count


@numba.njit(cache=True, nogil=True)
def node_ll_flattened(
    values, origin, cell, centre, axes, u, v, bcol, brow, measured, var, off_map, p, out
):  # pragma: no cover - compiled
    """Node log-likelihoods with the node field variance added to every beam's variance.

    ``p`` is a scratch ``(N0, b, N1)`` array. Rows are read one ahead, so the neighbour
    differences of row ``i`` are summed while rows ``i`` and ``i + 1`` are in cache. The
    reads are exact; the sums (field variance, then each node's log-likelihood) are
    reassociated so that they vectorise: within ~1e-15 relative of the reference's
    ordered sums. Returns the field variance, map units squared.
    """
    n0, n1, b = u.shape[0], v.shape[0], bcol.shape[0]
    acc0 = acc1 = 0.0
    count0 = count1 = 0
    inside = _nodes_inside(values, origin, cell, centre, axes, u, v, bcol, brow)
    _node_row_reads(values, origin, cell, centre, axes, u, v, bcol, brow, 0, inside, p[0])
    flat_p = p.reshape(n0, b * n1)
    for i in range(n0):
        if i + 1 < n0:
            args = (values, origin, cell, centre, axes, u, v, bcol, brow, i + 1, inside)
            _node_row_reads(*args, p[i + 1])
            s, c = _difference_sums(flat_p[i], flat_p[i + 1])
            acc0 += s
            count0 += c
        s, c = _step_difference_sums(p[i])
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
        _beam_major_sums(p[i], n1, measured, flat, off_map, out[i])
    return field_var


@numba.njit(cache=True, nogil=True, fastmath=_REASSOC)
def _local_term_sums(f0, f1, f2, n, measured, var, off_map, out):  # pragma: no cover
    """``out[i]``: log-likelihood of the beams from anywhere in hypothesis ``i``'s share.

    ``f0[k, i]`` is beam ``k``'s read at hypothesis ``i < n``, ``f1``, ``f2`` its reads
    at the hypothesis moved by each side of its share (``(b, >= n)`` each, beam by beam;
    one call sums a block). The reading of beam ``k`` from a position uniform over the
    share is, to first order, ``f0_k + (d1_k a + d2_k c)`` with ``a``, ``c``
    uniform on ``[-1/2, 1/2]`` (variance 1/12) for all beams at once: the residual ``r``
    is ``N(0, R + D D^T / 12)``, ``D`` the ``(b, 2)`` differences. With ``W = R^-1``
    (Woodbury, matrix determinant lemma): ``r^T S^-1 r = r^T W r - u^T (12 I + D^T W D)^-1 u``,
    ``u = D^T W r``, and ``log(det S / det R) = log det(I + D^T W D / 12)``. A
    non-finite difference counts 0; an off-map read costs ``off_map``.
    """
    sums = np.zeros((7, n))  # q, a11, a12, a22, u1, u2, penalty
    for k in range(measured.shape[0]):
        w = 1.0 / var[k]
        y = measured[k]
        for i in range(n):
            d1 = f1[k, i] - f0[k, i]
            d2 = f2[k, i] - f0[k, i]
            d1 = d1 if np.isfinite(d1) else 0.0
            d2 = d2 if np.isfinite(d2) else 0.0
            r = y - f0[k, i]
            if not np.isfinite(r):
                sums[6, i] += off_map
                continue
            sums[0, i] += w * r * r
            sums[1, i] += w * d1 * d1
            sums[2, i] += w * d1 * d2
            sums[3, i] += w * d2 * d2
            sums[4, i] += w * d1 * r
            sums[5, i] += w * d2 * r
    for i in range(n):
        q, a11, a12, a22, u1, u2, penalty = sums[:, i]
        m11 = 12.0 + a11
        m22 = 12.0 + a22
        det = m11 * m22 - a12 * a12
        explained = (m22 * u1 * u1 - 2.0 * a12 * u1 * u2 + m11 * u2 * u2) / det
        log_det = np.log(det / 144.0)
        out[i] = -0.5 * (q - explained + log_det) + penalty


@numba.njit(cache=True, nogil=True)
def hypotheses_ll_local(
    values, origin, cell, px, py, bcol, brow, shifts, measured, var, off_map, out
):  # pragma: no cover - compiled
    """``out[i]``: log-likelihood from ``(px[i], py[i])`` with its own field variance.

    ``shifts`` ``(2, 2)`` are the two sides of the hypothesis's share in map cells (rows
    ``(dcol, drow)``); the field is read at the hypothesis and at its position moved by
    each side (checked reads there), the likelihood of :func:`_local_term_sums`.
    """
    b = measured.shape[0]
    n = px.shape[0]
    cols, rows, inside = _hypothesis_cells(values, origin, cell, px, py, bcol, brow)
    f0 = np.empty((b, BLOCK))
    f1 = np.empty((b, BLOCK))
    f2 = np.empty((b, BLOCK))
    for start in range(0, n, BLOCK):
        stop = min(start + BLOCK, n)
        c, r, m = cols[start:stop], rows[start:stop], stop - start
        _beam_major_reads(values, c, r, m, bcol, brow, inside, f0)
        _beam_major_reads(values, c + shifts[0, 0], r + shifts[0, 1], m, bcol, brow, False, f1)
        _beam_major_reads(values, c + shifts[1, 0], r + shifts[1, 1], m, bcol, brow, False, f2)
        _local_term_sums(f0, f1, f2, m, measured, var, off_map, out[start:stop])


@numba.njit(cache=True, nogil=True)
def node_ll_local(
    values, origin, cell, centre, axes, u, v, bcol, brow, measured, var, off_map, p, out
):  # pragma: no cover - compiled
    """Node log-likelihoods, each node with its own field variation within its cell.

    ``u``, ``v`` hold one node more than the grid along each axis (``N0 + 1``,
    ``N1 + 1``), ``p`` is a scratch ``(N0 + 1, b, N1 + 1)`` array: every read is made
    once, and the next node along each axis gives the field's change over one node step
    (:func:`_local_term_sums`). ``out`` is ``(N0, N1)``.
    """
    inside = _nodes_inside(values, origin, cell, centre, axes, u, v, bcol, brow)
    for i in range(u.shape[0]):
        _node_row_reads(values, origin, cell, centre, axes, u, v, bcol, brow, i, inside, p[i])
    n1 = out.shape[1]
    for i in range(out.shape[0]):
        _local_term_sums(p[i], p[i + 1], p[i, :, 1:], n1, measured, var, off_map, out[i])


@numba.njit(cache=True, nogil=True)
def shift_squares(values, origin, cell, px, py, bcol, brow, shift, out):  # pragma: no cover
    """Sums and counts of the squared change of every beam's read under a shift.

    ``out[0]``, ``out[1]``: sum of ``d^2`` and count of finite ``d`` for the shift
    ``(shift, 0)``; ``out[2]``, ``out[3]`` the same for ``(0, shift)`` (metres). Each read
    is that of :func:`geofix.measurement.predict_measurements` at the shifted position:
    ``((x + s) - x0) / dx`` plus the beam's offset in cells, bilinear.
    """
    out[:] = 0.0
    for i in range(px.shape[0]):
        c = (px[i] - origin[0]) / cell[0]
        r = (py[i] - origin[1]) / cell[1]
        cx = ((px[i] + shift) - origin[0]) / cell[0]
        ry = ((py[i] + shift) - origin[1]) / cell[1]
        for j in range(bcol.shape[0]):
            base = bilinear_at(values, c + bcol[j], r + brow[j])
            dx = bilinear_at(values, cx + bcol[j], r + brow[j]) - base
            dy = bilinear_at(values, c + bcol[j], ry + brow[j]) - base
            if dx == dx:
                out[0] += dx * dx
                out[1] += 1.0
            if dy == dy:
                out[2] += dy * dy
                out[3] += 1.0
