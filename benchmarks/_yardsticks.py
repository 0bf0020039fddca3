"""Plain-numpy yardsticks the benchmarks measure against (same problem, same run).

They are deliberately the straightforward numpy programs a user would write: no numba,
no FFT. Kept here, not in the package, so that speeding up ``geofix`` never speeds up
its yardstick.
"""

from __future__ import annotations

import time

import numpy as np


def numpy_bilinear(values: np.ndarray, col, row) -> np.ndarray:
    """Bilinear read in plain numpy (NaN off the grid and on no-data cells)."""
    col, row = np.broadcast_arrays(np.asarray(col, float), np.asarray(row, float))
    ny, nx = values.shape
    inside = (col >= 0) & (col <= nx - 1) & (row >= 0) & (row <= ny - 1)
    c, r = np.where(inside, col, 0.0), np.where(inside, row, 0.0)
    c0 = np.minimum(np.floor(c).astype(np.intp), nx - 2)
    r0 = np.minimum(np.floor(r).astype(np.intp), ny - 2)
    fc, fr = c - c0, r - r0
    top = values[r0, c0] * (1 - fc) + values[r0, c0 + 1] * fc
    bottom = values[r0 + 1, c0] * (1 - fc) + values[r0 + 1, c0 + 1] * fc
    return np.where(inside, top * (1 - fr) + bottom * fr, np.nan)


def numpy_tercom_rows(problem, ox: np.ndarray, oy: np.ndarray) -> np.ndarray:
    """MSD surface in plain numpy, one candidate row at a time.

    The straightforward script: per row of candidates, one vectorised bilinear read of
    ``len(ox) x samples`` positions (every candidate on the map, as in the benchmark)
    and a mean over the samples. Row chunks keep the temporaries in cache.
    """
    grid = problem.grid
    v = grid.values
    fx, fy = problem.footprint(problem.indicated)
    h = problem.measured.reshape(-1)
    col = (fx.reshape(-1) - grid.x0) / grid.dx
    row = (fy.reshape(-1) - grid.y0) / grid.dy
    c = col[None, :] + (ox / grid.dx)[:, None]
    c0 = np.floor(c).astype(np.intp)
    fc = c - c0
    out = np.empty((oy.size, ox.size))
    for j, dy in enumerate(oy / grid.dy):
        r = row + dy
        r0 = np.floor(r).astype(np.intp)
        fr = r - r0
        top = v[r0, c0] * (1 - fc) + v[r0, c0 + 1] * fc
        bottom = v[r0 + 1, c0] * (1 - fc) + v[r0 + 1, c0 + 1] * fc
        m = top * (1 - fr) + bottom * fr
        out[j] = ((m - h) ** 2).mean(axis=1)
    return out


def paired_ratio(fast, slow, repeat: int = 7) -> dict:
    """Median times of ``fast`` and ``slow`` run alternately, and the median ratio.

    Alternating the two in one loop exposes both to the same load of a shared machine;
    the median of the per-pair ratios is robust to a burst of load during one pair.
    """
    tf, ts = [], []
    for _ in range(repeat):
        t0 = time.perf_counter()
        slow()
        ts.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        fast()
        tf.append(time.perf_counter() - t0)
    ratios = np.asarray(ts) / np.asarray(tf)
    return {
        "fast_s": float(np.median(tf)),
        "slow_s": float(np.median(ts)),
        "ratio": float(np.median(ratios)),
        "ratio_spread": [float(np.min(ratios)), float(np.max(ratios))],
    }
