"""TERCOM cost surface by FFT correlation (the "fft" route), whole-cell shifts only.

With bilinear reads at whole-cell shifts ``(j, k)`` the map value of sample ``i`` is
``m_i(j, k) = sum_ab w_i^ab V[r_i + a + j, c_i + b + k]`` (four fixed weights). Hence

- the cross term ``sum_i h_i m_i(j, k)`` is the cross-correlation of the map ``V`` with a
  sparse kernel holding ``h_i w_i^ab`` at ``(r_i + a, c_i + b)``;
- the quadratic term ``sum_i m_i(j, k)^2`` expands into products of pairs of stencil
  cells: the correlation of five product maps ``V(u) V(u + delta)``, ``delta`` in
  ``(0,0), (0,1), (1,0), (1,1), (1,-1)``, with kernels of the weight products;
- ``sum_i m_i`` (for ``ncor``) is the correlation of ``V`` with the weights alone.

All correlations are summed in the frequency domain (``scipy.fft``, real transforms), so
one inverse transform gives each whole surface. ``msd = (sum h^2 - 2 cross + quad) / n``,
``cor = -cross / n``, and ``ncor`` from the three sums. The map window and ``h`` are
first centred on the window mean (``msd`` and ``ncor`` are unchanged by a common offset,
``cor`` is corrected for it) to keep the cancellation in ``msd`` small.

The route needs every candidate of every sample on finite map cells (the window is on
the map and holds no NaN): then every candidate has all ``n`` samples valid. ``mad``
(a sum of absolute values) has no such expansion and always takes the loop route.
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.fft

from geofix.match._tercom_loop import stencil_weights

# Product maps V(u) V(u + delta) and, for each of the 10 stencil pairs, its delta, the
# corner the kernel entry sits on, and the weight factor (2 for distinct corners).
_DELTAS = ((0, 0), (0, 1), (1, 0), (1, 1), (1, -1))
_CORNERS = ((0, 0), (0, 1), (1, 0), (1, 1))  # order of the weights w00, w01, w10, w11
_PAIRS = (  # (weight a, weight b, delta index, corner of the kernel entry)
    (0, 0, 0, (0, 0)),
    (1, 1, 0, (0, 1)),
    (2, 2, 0, (1, 0)),
    (3, 3, 0, (1, 1)),
    (0, 1, 1, (0, 0)),
    (2, 3, 1, (1, 0)),
    (0, 2, 2, (0, 0)),
    (1, 3, 2, (0, 1)),
    (0, 3, 3, (0, 0)),
    (1, 2, 4, (0, 1)),
)
SUPPORTED = ("msd", "cor", "ncor", "cmsd")


def fft_window(shape, col, row, kc, kr):
    """Map window the route reads, or None when it would leave the map.

    Parameters
    ----------
    shape : tuple of int
        ``(ny, nx)`` of the map.
    col, row : numpy.ndarray
        ``(n,)`` fractional cells of the samples at zero shift.
    kc, kr : numpy.ndarray
        Increasing int64 whole-cell shifts along columns and rows.

    Returns
    -------
    tuple or None
        ``(r_lo, r_hi, c_lo, c_hi, c0, r0, w)``: the window ``values[r_lo:r_hi,
        c_lo:c_hi]`` and the stencil base cells and weights of the samples.
    """
    ny, nx = shape
    c0, r0, w = stencil_weights(col, row)
    r_lo, c_lo = int(r0.min() + kr[0]), int(c0.min() + kc[0])
    r_hi, c_hi = int(r0.max() + kr[-1] + 2), int(c0.max() + kc[-1] + 2)
    if r_lo < 0 or c_lo < 0 or r_hi > ny or c_hi > nx:
        return None
    return r_lo, r_hi, c_lo, c_hi, c0, r0, w


def fft_cost(values, window, h, kc, kr, metric: str, workers: int = 1) -> np.ndarray | None:
    """``(J, K)`` cost surface by FFT correlation; None when the window holds no-data.

    Parameters
    ----------
    values : numpy.ndarray
        ``(ny, nx)`` map values.
    window : tuple
        From :func:`fft_window` (not None).
    h : numpy.ndarray
        ``(n,)`` measured values.
    kc, kr : numpy.ndarray
        Increasing, evenly spaced int64 whole-cell shifts.
    metric : str
        ``"msd"``, ``"cor"``, ``"ncor"`` or ``"cmsd"``.
    workers : int
        Threads for ``scipy.fft``.
    """
    r_lo, r_hi, c_lo, c_hi, c0, r0, w = window
    win = np.asarray(values[r_lo:r_hi, c_lo:c_hi], dtype=np.float64)
    if not np.isfinite(win).all():
        return None
    shift = float(win.mean())
    win = win - shift
    # kernel coordinates of each sample's stencil origin, relative to the window origin
    kr0, kc0 = r0 - r0.min(), c0 - c0.min()
    kshape = (int(kr0.max()) + 2, int(kc0.max()) + 2)
    n = h.size
    rows, cols = kr[-1] - kr[0] + 1, kc[-1] - kc[0] + 1  # contiguous shifts
    fshape = (
        scipy.fft.next_fast_len(win.shape[0], True),
        scipy.fft.next_fast_len(win.shape[1], True),
    )
    fwin = scipy.fft.rfft2(win, fshape, workers=workers)

    def corr(spectrum_sum):
        full = scipy.fft.irfft2(spectrum_sum, fshape, workers=workers)
        return full[:rows:1, :cols:1][
            :: kr[1] - kr[0] if kr.size > 1 else 1, :: kc[1] - kc[0] if kc.size > 1 else 1
        ]

    def kernel_spectrum(weights):
        kern = _scatter(kshape, kr0, kc0, weights)
        return np.conj(scipy.fft.rfft2(kern, fshape, workers=workers))

    hc = h - shift
    if metric == "cor":
        cross = corr(fwin * kernel_spectrum(h[:, None] * w))  # sum h (m - shift)
        return -(cross + shift * h.sum()) / n
    quad = corr(_quadratic_spectrum(win, w, kr0, kc0, kshape, fshape, workers))
    if metric == "msd":
        cross = corr(fwin * kernel_spectrum(hc[:, None] * w))
        return (np.dot(hc, hc) - 2.0 * cross + quad) / n
    # ncor and cmsd with h centred on its own mean, as the loop route
    hm = h - h.mean()
    s_m = corr(fwin * kernel_spectrum(w))
    s_hm = corr(fwin * kernel_spectrum(hm[:, None] * w))
    var_m = quad - s_m * s_m / n
    if metric == "cmsd":
        return centred_msd(float(np.dot(hm, hm)), s_hm, var_m, n)
    denom = np.sqrt(np.maximum(var_m, 1e-300) * max(float(np.dot(hm, hm)), 1e-300))
    return -(s_hm - hm.sum() * s_m / n) / denom


def _quadratic_spectrum(win, w, kr0, kc0, kshape, fshape, workers):
    """Sum over the five product maps of their spectrum times their kernel's (conjugate)."""
    total = None
    ny, nx = win.shape
    for d, (dr, dc) in enumerate(_DELTAS):
        prod = np.zeros_like(win)
        c_from, c_to = max(0, -dc), nx - max(0, dc)
        prod[: ny - dr, c_from:c_to] = (
            win[: ny - dr, c_from:c_to] * win[dr:, c_from + dc : c_to + dc]
        )
        weights = np.zeros((w.shape[0], 4))
        for a, b, pair_delta, corner in _PAIRS:
            if pair_delta == d:
                weights[:, _CORNERS.index(corner)] += (1.0 if a == b else 2.0) * w[:, a] * w[:, b]
        kern = _scatter(kshape, kr0, kc0, weights)
        term = scipy.fft.rfft2(prod, fshape, workers=workers) * np.conj(
            scipy.fft.rfft2(kern, fshape, workers=workers)
        )
        total = term if total is None else total + term
    return total


@numba.njit(cache=True)
def _scatter_kernel(kern, kr0, kc0, weights):  # pragma: no cover - compiled
    for i in range(kr0.shape[0]):
        kern[kr0[i], kc0[i]] += weights[i, 0]
        kern[kr0[i], kc0[i] + 1] += weights[i, 1]
        kern[kr0[i] + 1, kc0[i]] += weights[i, 2]
        kern[kr0[i] + 1, kc0[i] + 1] += weights[i, 3]


def _scatter(kshape, kr0, kc0, weights) -> np.ndarray:
    """Sparse kernel: ``weights[i, corner]`` added at sample ``i``'s stencil corners."""
    kern = np.zeros(kshape)
    _scatter_kernel(kern, kr0, kc0, np.ascontiguousarray(weights, dtype=np.float64))
    return kern


@numba.njit(cache=True)
def centred_msd(s_hh, s_hm, var_m, n):  # pragma: no cover - compiled
    """``cmsd`` from sums over the ``n`` valid samples, ``h`` centred on its own mean.

    ``sum (d - mean d)^2 / n`` with ``d = h - m``: the mean squared difference once the
    best constant offset between the measurements and the map is removed. ``s_hh`` is
    ``sum h^2``, ``s_hm`` ``sum h m - sum h sum m / n`` and ``var_m``
    ``sum m^2 - (sum m)^2 / n`` (map units squared).
    """
    return np.maximum(s_hh - 2.0 * s_hm + var_m, 0.0) / n
