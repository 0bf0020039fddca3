"""Map contours as line segments, and the closest point on them (used by ICCP)."""

from __future__ import annotations

import numpy as np
from skimage.measure import find_contours


class ContourMap:
    """Iso-value contours of a map window, computed once per level and kept.

    Parameters
    ----------
    x0, y0 : float
        Centre of the window's cell ``[0, 0]``, metres.
    dx, dy : float
        Cell size, metres.
    values : numpy.ndarray
        ``(rows, cols)`` map values (row 0 south); NaN cells are masked out.
    """

    def __init__(self, x0: float, y0: float, dx: float, dy: float, values: np.ndarray):
        self.x0, self.y0, self.dx, self.dy = x0, y0, dx, dy
        self.mask = np.isfinite(values)
        fill = float(np.nanmean(values)) if self.mask.any() else 0.0
        self.values = np.where(self.mask, values, fill)
        self._cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    def segments(self, level: float) -> tuple[np.ndarray, np.ndarray]:
        """Start and end points ``(S, 2)`` (metres) of every segment of the ``level`` contour.

        Empty ``(0, 2)`` arrays when the level does not occur in the window.
        """
        level = float(level)
        if level not in self._cache:
            starts, ends = [], []
            lo, hi = np.min(self.values), np.max(self.values)
            if lo < level < hi:
                for line in find_contours(self.values, level, mask=self.mask):
                    xy = np.column_stack(
                        [self.x0 + line[:, 1] * self.dx, self.y0 + line[:, 0] * self.dy]
                    )
                    starts.append(xy[:-1])
                    ends.append(xy[1:])
            empty = np.zeros((0, 2))
            self._cache[level] = (
                np.vstack(starts) if starts else empty,
                np.vstack(ends) if ends else empty,
            )
        return self._cache[level]

    def closest(self, points: np.ndarray, levels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Closest point of each point's own contour.

        Parameters
        ----------
        points : numpy.ndarray
            ``(m, 2)`` positions, metres.
        levels : numpy.ndarray
            ``(m,)`` contour value of each point (map units); NaN = none.

        Returns
        -------
        tuple of numpy.ndarray
            ``(m, 2)`` closest contour points (metres; NaN where the level has no contour
            in the window) and ``(m,)`` distances, metres.
        """
        out = np.full(points.shape, np.nan)
        dist = np.full(len(points), np.nan)
        for i, (p, level) in enumerate(zip(points, levels, strict=True)):
            if not np.isfinite(level):
                continue
            a, b = self.segments(level)
            if len(a):
                out[i], dist[i] = closest_on_segments(p, a, b)
        return out, dist


def closest_on_segments(
    point: np.ndarray, a: np.ndarray, b: np.ndarray
) -> tuple[np.ndarray, float]:
    """Exact closest point to ``point`` on a set of segments ``a[k] -> b[k]``.

    Parameters
    ----------
    point : numpy.ndarray
        ``(2,)`` position, metres.
    a, b : numpy.ndarray
        ``(S, 2)`` segment ends, metres (``S >= 1``).

    Returns
    -------
    tuple
        ``(q, d)``: the closest point ``(2,)`` and its distance, metres.
    """
    ab = b - a
    length2 = np.einsum("ij,ij->i", ab, ab)
    u = np.einsum("ij,ij->i", point - a, ab) / np.where(length2 > 0, length2, 1.0)
    q = a + np.clip(u, 0.0, 1.0)[:, None] * ab
    d2 = np.einsum("ij,ij->i", q - point, q - point)
    k = int(np.argmin(d2))
    return q[k], float(np.sqrt(d2[k]))
