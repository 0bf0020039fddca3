"""TERCOM cost surface by a compiled loop over whole-cell shifts (the "loop" route).

When every candidate translation is a whole number of cells, the bilinear stencil of a
sample moves with the candidate but its four weights do not: they are computed once per
sample. The loops run candidate rows in parallel (numba ``prange``), samples in the
middle and candidate columns innermost, so each sample reads two contiguous map rows and
updates one contiguous row of sums.

Branch-and-bound (for the distance metrics ``msd`` and ``mad``): samples are taken in
blocks, most informative first (largest map gradient at the indicated footprint); after
each block a candidate whose lower bound ``partial sum / (valid so far + samples left)``
already exceeds the best complete cost found so far plus a margin is dropped from the
remaining blocks and reported as ``+inf``. The margin is chosen so that every dropped
candidate has a pseudo-likelihood weight that underflows to zero in double precision
(``exp(-746) == 0``): the integrity analysis of the surface is unchanged by the pruning.
"""

from __future__ import annotations

import itertools

import numba
import numpy as np

from geofix._threads import pick, twins
from geofix.maps.mapread import bilinear_at

MODES = {"msd": 0, "mad": 1, "cor": 2, "ncor": 3, "cmsd": 4}
MARGINAL = 5
"""Mode of the offset-marginalised cost (sums of ``d^2`` and ``d``, :func:`marginal_cost`)."""
SUMS = {0: 1, 1: 1, 2: 1, 3: 5, 4: 5, MARGINAL: 2}
UNDERFLOW_LOG = 746.0
"""``exp(-746)`` is zero in double precision: weights beyond this log-gap vanish."""


def whole_cell_shifts(offsets_cells: np.ndarray) -> np.ndarray | None:
    """The integer shifts of an evenly spaced array of cell offsets, or None if not whole."""
    shifts = np.rint(offsets_cells)
    if not np.allclose(offsets_cells, shifts, rtol=0, atol=1e-9):
        return None
    shifts = shifts.astype(np.int64)
    if shifts.size > 1 and np.any(np.diff(shifts) != shifts[1] - shifts[0]):
        return None
    if shifts.size > 1 and shifts[1] <= shifts[0]:
        return None
    return shifts


def stencil_weights(col: np.ndarray, row: np.ndarray):
    """Base cells ``(c0, r0)`` (int64) and ``(n, 4)`` weights ``w00, w01, w10, w11``."""
    c0 = np.floor(col)
    r0 = np.floor(row)
    fc, fr = col - c0, row - r0
    w = np.column_stack([(1 - fc) * (1 - fr), fc * (1 - fr), (1 - fc) * fr, fc * fr])
    return c0.astype(np.int64), r0.astype(np.int64), np.ascontiguousarray(w)


# ----------------------------------------------------------------------------- kernel
def _accumulate(
    values, cbase, rbase, w, col, row, h, kc, kr, p0, p1, span_lo, span_hi, sums, count, mode
):  # pragma: no cover - compiled
    """Add samples ``p0:p1`` to ``sums`` / ``count`` of the live candidates of each row."""
    ny, nx = values.shape
    n_rows = kr.shape[0]
    step = kc[1] - kc[0] if kc.shape[0] > 1 else 1
    for j in numba.prange(n_rows):
        lo, hi = span_lo[j], span_hi[j]
        if lo >= hi:
            continue
        for i in range(p0, p1):
            rr = rbase[i] + kr[j]
            first = cbase[i] + kc[0]
            klo, khi = lo, lo
            if rr >= 0 and rr <= ny - 2:
                klo = max(lo, -((first) // step))
                khi = min(hi, (nx - 2 - first) // step + 1)
                if klo >= khi:
                    klo, khi = lo, lo
            if khi > klo:
                _fast_row(values, rr, cbase[i], w[i], h[i], kc, klo, khi, sums, count, j, mode)
            for k in range(lo, klo):
                _edge(values, col[i] + kc[k], row[i] + kr[j], h[i], sums, count, j, k, mode)
            for k in range(khi, hi):
                _edge(values, col[i] + kc[k], row[i] + kr[j], h[i], sums, count, j, k, mode)


@numba.njit(cache=True, inline="always")
def _stencil(values, ur0, ur1, cc, w00, w01, w10, w11):  # pragma: no cover - compiled
    """The bilinear read at column ``cc`` of rows ``ur0``/``ur1`` (unsigned indices)."""
    c1 = cc + np.uint64(1)
    return (
        w00 * values[ur0, cc]
        + w01 * values[ur0, c1]
        + w10 * values[ur1, cc]
        + w11 * values[ur1, c1]
    )


@numba.njit(cache=True)
def _fast_row(values, rr, cb, wi, hi_, kc, klo, khi, sums, count, j, mode):  # pragma: no cover
    """Interior candidates ``klo:khi`` of row ``j``: precomputed weights, contiguous reads.

    Branch-free for ``msd``/``mad`` (a NaN read adds zero through a select) and without
    array views (whose reference counting would cost more than the loop), so that the
    unit-stride loop vectorises.
    """
    w00, w01, w10, w11 = wi[0], wi[1], wi[2], wi[3]
    step = kc[1] - kc[0] if kc.shape[0] > 1 else 1
    base = cb + kc[klo] - klo * step
    r1 = rr + 1
    if mode == 0 and step == 1:
        # unsigned indices: no negative-index wrap-around test, so the loop vectorises
        ur0, ur1, ub, uj = np.uint64(rr), np.uint64(r1), np.uint64(base + klo), np.uint64(j)
        uk0, u0 = np.uint64(klo), np.uint64(0)
        for u in range(np.uint64(khi - klo)):
            k = uk0 + u
            m = _stencil(values, ur0, ur1, ub + u, w00, w01, w10, w11)
            ok = m == m
            d = hi_ - m
            sums[u0, uj, k] += d * d if ok else 0.0
            count[uj, k] += 1.0 if ok else 0.0
        return
    if mode == 5 and step == 1:
        ur0, ur1, ub, uj = np.uint64(rr), np.uint64(r1), np.uint64(base + klo), np.uint64(j)
        uk0, u0, u1 = np.uint64(klo), np.uint64(0), np.uint64(1)
        for u in range(np.uint64(khi - klo)):
            k = uk0 + u
            m = _stencil(values, ur0, ur1, ub + u, w00, w01, w10, w11)
            ok = m == m
            d = hi_ - m
            sums[u0, uj, k] += d * d if ok else 0.0
            sums[u1, uj, k] += d if ok else 0.0
            count[uj, k] += 1.0 if ok else 0.0
        return
    for k in range(klo, khi):
        cc = base + k * step
        m = (
            w00 * values[rr, cc]
            + w01 * values[rr, cc + 1]
            + w10 * values[r1, cc]
            + w11 * values[r1, cc + 1]
        )
        ok = m == m
        if mode == 0:
            d = hi_ - m
            sums[0, j, k] += d * d if ok else 0.0
        elif mode == 1:
            sums[0, j, k] += abs(hi_ - m) if ok else 0.0
        elif mode == 5:
            d = hi_ - m
            sums[0, j, k] += d * d if ok else 0.0
            sums[1, j, k] += d if ok else 0.0
        elif ok:
            _add_products(sums, j, k, hi_, m, mode)
        count[j, k] += 1.0 if ok else 0.0


@numba.njit(cache=True)
def _add_products(sums, j, k, h, m, mode):  # pragma: no cover - compiled
    if mode == 2:
        sums[0, j, k] += h * m
    else:
        sums[0, j, k] += m
        sums[1, j, k] += m * m
        sums[2, j, k] += h * m
        sums[3, j, k] += h
        sums[4, j, k] += h * h


@numba.njit(cache=True)
def _edge(values, c, r, h, sums, count, j, k, mode):  # pragma: no cover - compiled
    """A candidate whose stencil touches the map's edge: the generic compiled read."""
    m = bilinear_at(values, c, r)
    if m != m:
        return
    count[j, k] += 1
    if mode == 0:
        sums[0, j, k] += (h - m) * (h - m)
    elif mode == 1:
        sums[0, j, k] += abs(h - m)
    elif mode == 5:
        sums[0, j, k] += (h - m) * (h - m)
        sums[1, j, k] += h - m
    else:
        _add_products(sums, j, k, h, m, mode)


# ----------------------------------------------------------------------------- driver
_ACCUMULATE = twins(_accumulate, cache=True)
"""``_accumulate`` compiled with numba's thread pool and without (:mod:`geofix._threads`)."""


def loop_sums(values, col, row, h, kc, kr, mode, prune=None):
    """Sums and valid counts of every candidate, optionally with branch-and-bound.

    Parameters
    ----------
    values : numpy.ndarray
        ``(ny, nx)`` map values, C-contiguous.
    col, row : numpy.ndarray
        ``(n,)`` fractional cells of the samples along the indicated track.
    h : numpy.ndarray
        ``(n,)`` measured values (for ``ncor`` and ``cmsd``: centred on their mean).
    kc, kr : numpy.ndarray
        Increasing, evenly spaced int64 whole-cell shifts along columns and rows.
    mode : int
        :data:`MODES` value.
    prune : tuple or JointPrune, optional
        ``(order, exact_cost, margin)`` for branch-and-bound (``msd``/``mad`` only):
        ``order`` the sample order (most informative first), ``exact_cost(j, k)`` the
        complete cost of one candidate, ``margin(best)`` the cost gap beyond which a
        candidate's weight underflows; or a :class:`JointPrune` (:data:`MARGINAL`: the
        ``msd`` and the offset-marginalised cost at once).

    Returns
    -------
    tuple
        ``(sums, count, alive)``: ``(s, J, K)`` sums, ``(J, K)`` valid counts (float) and the
        ``(J, K)`` mask of candidates not pruned (all True without ``prune``).
    """
    n = h.shape[0]
    cbase, rbase, w = stencil_weights(col, row)
    if prune is not None:
        order = prune.order if isinstance(prune, JointPrune) else prune[0]
        col, row, h, cbase, rbase, w = (a[order] for a in (col, row, h, cbase, rbase, w))
        w = np.ascontiguousarray(w)
    args = [np.ascontiguousarray(a) for a in (cbase, rbase)]
    sums = np.zeros((SUMS[mode], kr.size, kc.size))
    count = np.zeros((kr.size, kc.size))
    alive = np.ones((kr.size, kc.size), dtype=bool)
    lo = np.zeros(kr.size, dtype=np.int64)
    hi = np.full(kr.size, kc.size, dtype=np.int64)
    bounds = _blocks(n) if prune is not None else [0, n]
    accumulate = pick(_ACCUMULATE)
    best = np.inf
    for p0, p1 in itertools.pairwise(bounds):
        accumulate(values, *args, w, col, row, h, kc, kr, p0, p1, lo, hi, sums, count, int(mode))
        if p1 < n and isinstance(prune, JointPrune):
            prune.update(sums, count, n - p1, alive, lo, hi)
        elif p1 < n:
            best = _prune(sums[0], count, n - p1, alive, best, prune[1], prune[2], lo, hi)
    return sums, count, alive


def _blocks(n: int) -> list[int]:
    """Block boundaries: eighths up to half the samples (at least 8 each), then quarters.

    The lower bound of a wrong candidate grows with the share of samples seen, so most
    candidates fall in the first few blocks; later blocks run on the few survivors.
    """
    shares = (0.125, 0.25, 0.375, 0.5, 0.75, 1.0)
    bounds = {0, n}
    for share in shares:
        bounds.add(min(n, max(8, round(share * n))))
    return sorted(bounds)


def _prune(partial, count, left, alive, best, exact_cost, margin, lo, hi) -> float:
    """Drop candidates whose lower bound exceeds the best complete cost plus the margin.

    The best complete cost is improved first from the few candidates with the lowest
    partial mean (the likeliest minima). Updates ``alive``, ``lo``, ``hi`` in place.
    """
    for index in _lowest_means(partial, count, alive, lo, hi, _PROBES):
        if index >= 0:
            j, k = divmod(int(index), partial.shape[1])
            best = min(best, exact_cost(j, k))
    if np.isfinite(best):
        _prune_pass(partial, count, float(left), alive, best + margin(best), lo, hi)
    return best


_PROBES = 8
"""Candidates whose complete cost is computed to bound the best after each block."""


@numba.njit(cache=True)
def _lowest_means(partial, count, alive, lo, hi, few):  # pragma: no cover - compiled
    """Flat indices of the ``few`` live candidates of lowest partial mean (-1 = none)."""
    best_index = np.full(few, -1, dtype=np.int64)
    best_mean = np.full(few, np.inf)
    for j in range(partial.shape[0]):
        for k in range(lo[j], hi[j]):
            if not alive[j, k] or count[j, k] <= 0:
                continue
            mean = partial[j, k] / count[j, k]
            if mean >= best_mean[few - 1]:
                continue
            q = few - 1
            while q > 0 and best_mean[q - 1] > mean:
                best_mean[q], best_index[q] = best_mean[q - 1], best_index[q - 1]
                q -= 1
            best_mean[q], best_index[q] = mean, j * partial.shape[1] + k
    return best_index


@numba.njit(cache=True)
def _new_span(alive, lo, hi, j, first, last):  # pragma: no cover - compiled
    """Row ``j`` keeps candidates ``first..last`` live: the rest dropped, the span set."""
    for k in range(0, lo[j]):
        alive[j, k] = False
    for k in range(hi[j], alive.shape[1]):
        alive[j, k] = False
    if first < 0:
        lo[j], hi[j] = 0, 0
    else:
        lo[j], hi[j] = first, last + 1


@numba.njit(cache=True)
def _prune_pass(partial, count, left, alive, threshold, lo, hi):  # pragma: no cover
    """``alive &= partial / (count + left) <= threshold``; new live span of every row."""
    for j in range(partial.shape[0]):
        first, last = -1, -1
        for k in range(lo[j], hi[j]):
            if alive[j, k]:
                if partial[j, k] > threshold * (count[j, k] + left):
                    alive[j, k] = False
                else:
                    if first < 0:
                        first = k
                    last = k
        _new_span(alive, lo, hi, j, first, last)


@numba.njit(cache=True)
def exact_costs(values, col, row, h, kc, kr, mode, need):  # pragma: no cover - compiled
    """Complete ``msd``/``mad`` cost of candidates ``(kr[i], kc[i])`` (NaN if too few valid).

    Parameters
    ----------
    values : numpy.ndarray
        ``(ny, nx)`` map values.
    col, row : numpy.ndarray
        ``(n,)`` fractional cells of the samples at zero shift.
    h : numpy.ndarray
        ``(n,)`` measured values, map units.
    kc, kr : numpy.ndarray
        ``(q,)`` shifts of the candidates, cells.
    mode : int
        0: mean squared difference, 1: mean absolute difference.
    need : float
        Fewest valid samples a candidate needs.

    Returns
    -------
    numpy.ndarray
        ``(q,)`` costs, squared or plain map units.
    """
    out = np.full(kc.shape[0], np.nan)
    for q in range(kc.shape[0]):
        acc, valid = 0.0, 0
        for i in range(h.shape[0]):
            m = bilinear_at(values, col[i] + kc[q], row[i] + kr[q])
            if m == m:
                d = h[i] - m
                acc += d * d if mode == 0 else abs(d)
                valid += 1
        if valid > 0 and valid >= need:
            out[q] = acc / valid
    return out


@numba.njit(cache=True)
def exact_marginal(values, col, row, h, kc, kr, weight, need):  # pragma: no cover - compiled
    """Complete ``msd`` and offset-marginalised cost of candidates ``(kr[i], kc[i])``.

    Returns a ``(2, q)`` array: the mean squared difference, and the same less ``weight``
    times the square of the mean difference (:func:`marginal_cost`); NaN where fewer than
    ``need`` samples are valid.
    """
    out = np.full((2, kc.shape[0]), np.nan)
    for q in range(kc.shape[0]):
        s2, s1, valid = 0.0, 0.0, 0
        for i in range(h.shape[0]):
            m = bilinear_at(values, col[i] + kc[q], row[i] + kr[q])
            if m == m:
                d = h[i] - m
                s2 += d * d
                s1 += d
                valid += 1
        if valid > 0 and valid >= need:
            out[0, q] = s2 / valid
            out[1, q] = (s2 - weight * s1 * s1 / valid) / valid
    return out


def marginal_bound_holds(subset, whole, weight: float) -> bool:
    """Whether ``subset``'s marginalised partial sum is at most ``whole``'s (a check).

    :class:`JointPrune` prunes on ``sum_S d^2 - weight (sum_S d)^2 / |S|`` as a lower
    bound of the same over all valid samples; this states it for given differences.
    """
    sub, all_ = np.asarray(subset, float), np.asarray(whole, float)
    part = float(np.sum(sub**2) - weight * np.sum(sub) ** 2 / sub.size)
    full = float(np.sum(all_**2) - weight * np.sum(all_) ** 2 / all_.size)
    return part <= full * (1 + 1e-12) + 1e-12


class JointPrune:
    """Branch-and-bound on the ``msd`` and the offset-marginalised cost at once.

    A candidate is dropped when both its lower bounds exceed the best complete cost of
    their own surface plus the margin: ``sum_S d^2`` for the ``msd``, and ``sum_S d^2 -
    weight (sum_S d)^2 / |S|`` for the marginalised cost, which over any subset ``S`` of
    the valid samples is ``(1 - weight) sum_S d^2 + weight sum_S (d - mean_S d)^2`` and so
    at most its value over all of them (a subset's own mean minimises its squared
    deviations). Both are over ``count + left`` samples, as :func:`_prune_pass` bounds one.

    Parameters
    ----------
    order : numpy.ndarray
        The sample order, most informative first.
    exact_costs : callable
        ``exact_costs(j, k)`` the complete ``(2, q)`` ``msd`` and marginal of the ``q``
        candidates of row and column indices ``j``, ``k`` (int arrays; inf: none).
    margin : callable
        ``margin(best_msd)``, the cost gap beyond which a candidate's weight underflows in
        either model.
    weight : float
        Share of the squared mean difference the marginalised cost takes out.
    """

    def __init__(self, order, exact_costs, margin, weight: float):
        self.order = order
        self.exact_costs = exact_costs
        self.margin = margin
        self.weight = float(weight)
        self.best = np.array([np.inf, np.inf])

    def update(self, sums, count, left, alive, lo, hi) -> None:
        """Improve both bests from the likeliest candidates, then drop (in place)."""
        index = _lowest_joint_means(sums, count, alive, lo, hi, _PROBES, self.weight)
        index = np.unique(index[index >= 0])
        if index.size:
            j, k = np.divmod(index, sums.shape[2])
            self.best = np.minimum(self.best, self.exact_costs(j, k).min(axis=1))
        if np.isfinite(self.best).all():
            threshold = self.best + self.margin(float(self.best[0]))
            _joint_prune_pass(sums, count, float(left), alive, threshold, self.weight, lo, hi)


@numba.njit(cache=True)
def _joint_partial(sums, count, j, k, which, weight):  # pragma: no cover - compiled
    """Partial ``sum d^2`` (``which`` 0) or ``sum d^2 - weight (sum d)^2 / count`` (1)."""
    if which == 0:
        return sums[0, j, k]
    return sums[0, j, k] - weight * sums[1, j, k] ** 2 / max(count[j, k], 1.0)


@numba.njit(cache=True)
def _lowest_joint_means(sums, count, alive, lo, hi, few, weight):  # pragma: no cover
    """:func:`_lowest_means` of both of :class:`JointPrune`'s partial sums, in one scan.

    Flat indices of the ``few`` live candidates of lowest partial ``msd`` followed by the
    ``few`` of lowest partial marginalised cost (-1 = none).
    """
    best_index = np.full((2, few), -1, dtype=np.int64)
    best_mean = np.full((2, few), np.inf)
    for j in range(sums.shape[1]):
        for k in range(lo[j], hi[j]):
            if not alive[j, k] or count[j, k] <= 0:
                continue
            for which in range(2):
                mean = _joint_partial(sums, count, j, k, which, weight) / count[j, k]
                if mean >= best_mean[which, few - 1]:
                    continue
                q = few - 1
                while q > 0 and best_mean[which, q - 1] > mean:
                    best_mean[which, q] = best_mean[which, q - 1]
                    best_index[which, q] = best_index[which, q - 1]
                    q -= 1
                best_mean[which, q], best_index[which, q] = mean, j * sums.shape[2] + k
    return best_index.ravel()


@numba.njit(cache=True)
def _joint_prune_pass(sums, count, left, alive, threshold, weight, lo, hi):  # pragma: no cover
    """:func:`_prune_pass` dropping a candidate only when both bounds exceed theirs."""
    for j in range(sums.shape[1]):
        first, last = -1, -1
        for k in range(lo[j], hi[j]):
            if alive[j, k]:
                samples = count[j, k] + left
                if (
                    sums[0, j, k] > threshold[0] * samples
                    and _joint_partial(sums, count, j, k, 1, weight) > threshold[1] * samples
                ):
                    alive[j, k] = False
                else:
                    if first < 0:
                        first = k
                    last = k
        _new_span(alive, lo, hi, j, first, last)


@numba.njit(cache=True)
def marginal_cost(sums, count, alive, need, weight):  # pragma: no cover - compiled
    """``(1 - weight) msd + weight cmsd`` from the :data:`MARGINAL` sums (NaN, inf as msd).

    Parameters
    ----------
    sums : numpy.ndarray
        ``(2, J, K)`` sums of ``d^2`` and ``d`` (``d`` measured minus map) per shift.
    count, alive : numpy.ndarray
        ``(J, K)`` valid samples and the mask of shifts not pruned.
    need : float
        Fewest valid samples a shift needs.
    weight : float
        Share of the mean difference taken out, in ``[0, 1]`` (0: the ``msd``).

    Returns
    -------
    numpy.ndarray
        ``(J, K)`` cost, map units squared.
    """
    out = np.empty(count.shape)
    for j in range(count.shape[0]):
        for k in range(count.shape[1]):
            c = count[j, k]
            if not alive[j, k]:
                out[j, k] = np.inf
            elif c == 0 or c < need:
                out[j, k] = np.nan
            else:
                out[j, k] = (sums[0, j, k] - weight * sums[1, j, k] ** 2 / c) / c
    return out


@numba.njit(cache=True)
def distance_cost(partial, count, alive, need):  # pragma: no cover - compiled
    """``msd``/``mad`` surface: mean where enough samples were valid, NaN if not, inf if pruned.

    Parameters
    ----------
    partial : numpy.ndarray
        ``(J, K)`` sums of squared (or absolute) differences per shift.
    count : numpy.ndarray
        ``(J, K)`` valid samples per shift.
    alive : numpy.ndarray
        ``(J, K)`` False where the shift was pruned.
    need : float
        Fewest valid samples a shift needs.

    Returns
    -------
    numpy.ndarray
        ``(J, K)`` cost surface.
    """
    out = np.empty(partial.shape)
    for j in range(partial.shape[0]):
        for k in range(partial.shape[1]):
            if not alive[j, k]:
                out[j, k] = np.inf
            elif count[j, k] == 0 or count[j, k] < need:
                out[j, k] = np.nan
            else:
                out[j, k] = partial[j, k] / count[j, k]
    return out
