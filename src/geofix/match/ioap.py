"""IOAP: iterative optimal annular (ring-domain) points, gravity matching (source 004).

Two ring searches replace TERCOM's square window (source 004: Chinese patent application
of Zheng Wei, Li Zhaowei and Zhao Shijie, 2021):

1. **SPMP** (start point). Around the indicated start ``S1``, rings of radius
   ``r_i = 3 sigma0 lam i`` (``i = 1 .. 1/lam``) carry points at ``beta_j = j theta0``
   (``j = 1 .. 360 / theta0``) clockwise from north, at ``(x1 + r_i sin beta_j,
   y1 + r_i cos beta_j)``; ``S1`` itself comes first. Each point reads the map at its
   nearest node; the point with the smallest ``|g_map - g1|`` is the start fix (the first
   one on ties).
2. **EPMP** (end point). The centre ``O`` is the start fix moved by the indicated
   start-to-end displacement (distance ``d_INS`` along ``alpha_INS``). Rings every ``C``
   (the cell size) reach ``R_max = xi sigma``; their count ``M = ceil(R_max / C)`` is
   rounded up to a multiple of 3 and split into inner, middle and outer thirds. With the
   base angle ``phi = C / R_ref`` the angular spacing is ``2 phi`` on the inner third,
   ``phi`` on the middle one and ``phi / 2`` on the outer one ("double inside, half
   outside"). ``R_ref = reference * M C / 3``: ``reference`` 1, 1.5, 2, 2.5 are the
   source's "1-", "1.5-", "2-" and "2.5-IOAP" (the inner third's outer ring, the middle of
   the whole, the middle third's outer ring, the middle of the outer two thirds).
3. Every candidate end point is snapped to its nearest grid node. The candidate track is
   the indicated track **translated** so that it ends on that node: the source rebuilds
   it backwards from the node "with the vehicle's speed and heading" (the INS ones), which
   is the indicated track's own shape; the start fix only places ``O``. The map is read
   at the nearest node along the candidate and scored by the mean squared difference
   (MSD) against the measured sequence; the smallest MSD is the end fix.

The ring formulas and the rounding rule are images lost from the source text; the
reconstruction above follows its prose. Our choices where the text is silent: each ring
holds ``floor(2 pi / spacing)`` points at ``j * spacing``, ``j = 1, 2, ...`` (as SPMP's
``j``); ``R_ref`` is the exact radius ``reference * M C / 3``, not the nearest ring; the
centre ``O`` is itself a candidate (as ``S1`` is in SPMP), so a zero offset can be found;
at least 3 rings are used; candidates snapping to the same node are scored once.

``sigma0`` and ``sigma`` come from ``MatchProblem.sigma_position`` (the per-axis prior
1-sigma of the INS position error at each sample, from the INS error model):
``sigma0 = sqrt(sigma_position[1]^2 - sigma_position[0]^2)``, the drift accrued over one
sampling interval ("the INS drift std at sampling interval dt"; the initial uncertainty is
not part of it), and ``sigma = max(sigma_position)``, the accumulated error over the
window, the same value TERCOM's ``window_sigma`` multiplies, so that the 3-sigma disc is
inscribed in TERCOM's 3-sigma square as in the source's figure 7. With the source's INS
numbers ``sigma0`` is about 0.6 m, far below a 100 m cell: SPMP then keeps ``S1``.

``track_shape="anchor"`` is an extension, not the source: the candidate track runs from
the start fix to the candidate end, the indicated track rotated and scaled about its start.

Integrity (our addition): the candidates' MSDs are turned into a pseudo-likelihood whose
spread (plus the cell's quantisation) is the covariance of the end fix, and whose mass
beyond ``exclusion_cells`` flags the fix ambiguous; the INS drift inside the window,
which a translated track cannot follow, is added
(:func:`geofix.match.drift.with_leg_drift`; conservative for ``"anchor"``, whose rotation
and scale absorb part of it).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import ClassVar

import numba
import numpy as np

from geofix._threads import pick, twins
from geofix.errors import ConfigError, MatchError
from geofix.maps.grid import Grid
from geofix.match.drift import with_leg_drift
from geofix.measurement import predict_track
from geofix.memory import cells_bytes, check_allocation
from geofix.problem import Fix, MatchProblem

_SHAPES = ("translate", "anchor")


@dataclass(frozen=True, eq=False)
class RingLayout:
    """Concentric rings of candidate points around a centre.

    Parameters
    ----------
    radii : numpy.ndarray
        ``(m,)`` ring radii, metres.
    spacing : numpy.ndarray
        ``(m,)`` angle between neighbouring points on each ring, radians.
    counts : numpy.ndarray
        ``(m,)`` number of points on each ring.
    base_angle : float
        The base angle ``phi``, radians (EPMP) or ``theta0`` (SPMP).
    reference_radius : float
        ``R_ref``, metres (``nan`` for SPMP).
    """

    radii: np.ndarray
    spacing: np.ndarray
    counts: np.ndarray
    base_angle: float
    reference_radius: float = float("nan")

    @property
    def total(self) -> int:
        """Number of ring points (the centre excluded)."""
        return int(self.counts.sum())

    def offsets(self, include_centre: bool = True) -> np.ndarray:
        """``(k, 2)`` ``(east, north)`` offsets from the centre, metres.

        Ring by ring from the inside, point ``j = 1 .. count`` at angle ``j * spacing``
        clockwise from north; the centre ``(0, 0)`` first when ``include_centre``.
        """
        ring = np.repeat(np.arange(self.radii.size), self.counts)
        start = np.concatenate([[0], np.cumsum(self.counts)[:-1]]).astype(int)
        j = np.arange(self.total) - np.repeat(start, self.counts) + 1
        angle = j * self.spacing[ring]
        radius = self.radii[ring]
        points = np.column_stack([radius * np.sin(angle), radius * np.cos(angle)])
        if include_centre:
            points = np.vstack([np.zeros((1, 2)), points])
        return points


def _points_on_ring(spacing: np.ndarray) -> np.ndarray:
    """``floor(2 pi / spacing)`` (tolerant of rounding), at least 1."""
    return np.maximum(np.floor(2.0 * np.pi / spacing + 1e-9), 1).astype(int)


def spmp_layout(sigma0: float, lam: float = 1.0 / 3.0, theta0_deg: float = 45.0) -> RingLayout:
    """Start-point rings: ``r_i = 3 sigma0 lam i``, points every ``theta0``.

    Parameters
    ----------
    sigma0 : float
        INS position-error 1-sigma over one sampling interval, metres.
    lam : float
        Ring-radius ratio ``lambda``; ``round(1 / lam)`` rings (3 for 1/3).
    theta0_deg : float
        Angle between points, degrees clockwise from north (8 points for 45).

    Returns
    -------
    RingLayout
        Radii in metres, spacing ``theta0`` in radians on every ring.
    """
    rings = max(round(1.0 / lam), 1)
    theta0 = np.radians(theta0_deg)
    radii = 3.0 * sigma0 * lam * np.arange(1, rings + 1)
    spacing = np.full(rings, theta0)
    return RingLayout(radii, spacing, _points_on_ring(spacing), float(theta0))


def epmp_ring_count(sigma: float, cell: float, sigma_multiple: float = 3.0) -> int:
    """Number of EPMP rings ``M'``: ``ceil(xi sigma / C)`` rounded up to a multiple of 3.

    Parameters
    ----------
    sigma : float
        Accumulated INS position-error 1-sigma, metres.
    cell : float
        Ring spacing ``C`` (the map cell size), metres.
    sigma_multiple : float
        ``xi``: the search radius is ``xi sigma``.

    Returns
    -------
    int
        ``M'`` (at least 3).
    """
    rings = max(int(np.ceil(sigma_multiple * sigma / cell - 1e-9)), 1)
    return 3 * int(np.ceil(rings / 3))


#: Float arrays of candidates x samples x 2 alive at once (tracks, footprints, reads).
_TRACK_COPIES = 6


def _epmp_point_estimate(
    sigma: float, cell: float, sigma_multiple: float = 3.0, reference: float = 1.5
) -> float:
    """Number of EPMP ring points of :func:`epmp_layout`, computed without allocating.

    ``M'`` rings in three thirds at spacings ``2 phi``, ``phi`` and ``phi / 2`` with
    ``phi = 3 / (reference M')``: about ``7 pi reference M'^2 / 9`` points (a float, so
    that a huge ``sigma`` gives a huge number rather than an allocation).
    """
    rings = 3.0 * np.ceil(max(np.ceil(sigma_multiple * sigma / cell - 1e-9), 1.0) / 3.0)
    return 7.0 * np.pi * reference * rings**2 / 9.0 + rings


def epmp_layout(
    sigma: float, cell: float, sigma_multiple: float = 3.0, reference: float = 1.5
) -> RingLayout:
    """End-point rings: every ``C`` out to ``xi sigma``, spacing ``2 phi / phi / phi / 2``.

    Parameters
    ----------
    sigma : float
        Accumulated INS position-error 1-sigma, metres.
    cell : float
        Map cell size ``C``, metres (also the ring spacing).
    sigma_multiple : float
        ``xi`` (1, 2 or 3 in the source).
    reference : float
        Reference ring in thirds of the outermost radius: ``R_ref = reference M' C / 3``
        (1, 1.5, 2, 2.5 in the source); the base angle is ``phi = C / R_ref``.

    Returns
    -------
    RingLayout
        ``M'`` rings of radius ``zeta C``; inner / middle / outer thirds at ``2 phi``,
        ``phi``, ``phi / 2`` radians.
    """
    count = epmp_ring_count(sigma, cell, sigma_multiple)
    reference_radius = reference * count * cell / 3.0
    phi = cell / reference_radius
    radii = cell * np.arange(1, count + 1)
    spacing = np.repeat([2.0 * phi, phi, phi / 2.0], count // 3)
    return RingLayout(radii, spacing, _points_on_ring(spacing), float(phi), reference_radius)


def snap_to_nodes(grid: Grid, points: np.ndarray) -> np.ndarray:
    """Nearest grid nodes of ``(k, 2)`` points, duplicates removed (first kept, in order).

    Parameters
    ----------
    grid : Grid
        The map.
    points : numpy.ndarray
        ``(k, 2)`` positions, metres.

    Returns
    -------
    numpy.ndarray
        ``(u, 2)`` node positions, metres, in order of first appearance.
    """
    col, row = _node_cells(grid, points)
    # one integer key per node: a 1-D unique is far cheaper than a row-wise one
    key = (row - row.min()) * (col.max() - col.min() + 1) + (col - col.min())
    _, first = np.unique(key, return_index=True)  # stable sort: first occurrences
    first = np.sort(first)
    x, y = grid.cell_to_xy(col[first], row[first])
    return np.column_stack([x, y])


@dataclass(frozen=True)
class Ioap:
    """IOAP (source 004): ring searches for the start (SPMP) and end (EPMP) points, MSD.

    Parameters
    ----------
    sigma_multiple : float
        ``xi``: EPMP search radius ``xi sigma`` (1, 2, 3 for 1-, 2-, 3-sigma-IOAP).
    reference : float
        Reference-ring variant (1, 1.5, 2, 2.5): ``R_ref = reference * M' C / 3``.
    lam : float
        SPMP ring-radius ratio ``lambda`` (source example 1/3).
    theta0_deg : float
        SPMP angle between points, degrees (source example 45).
    track_shape : str
        ``"translate"`` (the source: indicated track moved to end on the candidate) or
        ``"anchor"`` (extension: start fix to candidate end, rotated and scaled).
    min_valid_fraction : float
        Candidates with valid map values for less than this share of the measured samples
        are discarded (off the map or on no-data).
    exclusion_cells : float
        Radius, in cells, around the best candidate outside which competing candidates
        count towards ambiguity.
    ambiguity_mass : float
        Pseudo-likelihood mass beyond ``exclusion_cells`` above which the fix is flagged.

    References
    ----------
    .. [1] Zheng, W., Li, Z., & Zhao, S. (2021). Gravity matching by iterative optimal
       annular points. Chinese patent application (filed 2021-06-30).

    Examples
    --------
    >>> import geofix
    >>> geofix.parse_method_spec("ioap:reference=2").reference
    2.0
    """

    name: ClassVar[str] = "ioap"
    recursive: ClassVar[bool] = False

    sigma_multiple: float = 3.0
    reference: float = 1.5
    lam: float = 1.0 / 3.0
    theta0_deg: float = 45.0
    track_shape: str = "translate"
    min_valid_fraction: float = 0.9
    exclusion_cells: float = 3.0
    ambiguity_mass: float = 0.05

    def __post_init__(self) -> None:
        if self.sigma_multiple <= 0:
            raise ConfigError(f"ioap: sigma_multiple must be positive, got {self.sigma_multiple}")
        if not 0 < self.reference <= 3:
            raise ConfigError(f"ioap: reference must be in (0, 3], got {self.reference}")
        if not 0 < self.lam <= 1 or not 0 < self.theta0_deg <= 360:
            raise ConfigError("ioap: lam must be in (0, 1] and theta0_deg in (0, 360]")
        if self.track_shape not in _SHAPES:
            raise ConfigError(f"ioap: track_shape must be one of {_SHAPES}")

    def match(self, problem: MatchProblem, rng: np.random.Generator | None = None) -> Fix:
        """Find the start fix (SPMP), then the best end node on the EPMP rings."""
        valid = np.isfinite(problem.measured)
        if not valid.any():
            raise MatchError("ioap: every measured value is missing")
        sigma0, sigma = ring_sigmas(problem.sigma_position)
        start = self.start_fix(problem, sigma0)
        centre = start + (problem.indicated[-1] - problem.indicated[0])
        k = _epmp_point_estimate(sigma, problem.grid.cell_size, self.sigma_multiple, self.reference)
        check_allocation(
            cells_bytes(k, problem.n, 2, copies=_TRACK_COPIES) + cells_bytes(k, copies=16),
            f"ioap end-point rings of about {k:.3g} candidates x {problem.n} samples "
            f"(sigma_multiple {self.sigma_multiple:g} x the INS prior sigma {sigma:.3g} m "
            "from ins.*)",
        )
        layout = epmp_layout(sigma, problem.grid.cell_size, self.sigma_multiple, self.reference)
        ends = snap_to_nodes(problem.grid, centre + layout.offsets())
        if self.track_shape == "translate":
            cost = translated_msd_scores(problem, ends, self.min_valid_fraction)
        else:
            tracks = self.candidate_tracks(problem, start, ends)
            cost = msd_scores(problem, tracks, self.min_valid_fraction)
        if not np.isfinite(cost).any():
            raise MatchError("ioap: no candidate end point gives a track on valid map data")
        best = int(np.nanargmin(cost))
        own, ambiguous = self._integrity(problem, cost, ends, best)
        track = self.candidate_tracks(problem, start, ends[best : best + 1])[0]
        covariance, drift = with_leg_drift(problem, own, track)
        return Fix(
            track=track,
            covariance=covariance,
            cost=float(cost[best]),
            evaluations=int(ends.shape[0] * valid.sum()),
            ambiguous=ambiguous,
            diagnostics={
                "start_fix": start,
                "centre": centre,
                "rings": int(layout.radii.size),
                "candidates": int(ends.shape[0]),
                "sigma0": sigma0,
                "sigma": sigma,
                "drift_covariance": drift,
            },
        )

    def start_fix(self, problem: MatchProblem, sigma0: float) -> np.ndarray:
        """SPMP: the ring point (or ``S1``) whose nearest-node value is closest to ``g1``.

        Returns the ``(2,)`` start fix, metres; ``S1`` when the first measurement is
        missing or no ring point lies on valid data.
        """
        s1 = problem.indicated[0]
        g1 = problem.measured[0]
        if not np.isfinite(g1).any():
            return s1.copy()
        points = s1 + spmp_layout(sigma0, self.lam, self.theta0_deg).offsets()
        values = predict_track(
            problem.grid, points[:, None, :], problem.heading[:1], problem.offsets, "nearest"
        )[:, 0]
        misfit = np.abs(values - g1)
        ok = np.isfinite(misfit)
        misfit = np.where(ok, misfit, 0.0).sum(axis=1) / np.maximum(ok.sum(axis=1), 1)
        misfit[~ok.any(axis=1)] = np.nan
        if not np.isfinite(misfit).any():
            return s1.copy()
        return points[int(np.nanargmin(misfit))]

    def candidate_tracks(self, problem: MatchProblem, start, ends: np.ndarray) -> np.ndarray:
        """Candidate tracks ending on ``ends``, shaped by :attr:`track_shape`.

        Parameters
        ----------
        problem : MatchProblem
            Supplies the indicated track ``(n, 2)``, metres.
        start : numpy.ndarray
            ``(2,)`` start fix, metres; used by ``track_shape="anchor"`` only (a
            ``"translate"`` track, or an anchored one whose indicated track has no extent,
            is the indicated track moved to end on each end point).
        ends : numpy.ndarray
            ``(k, 2)`` candidate end points, metres.

        Returns
        -------
        numpy.ndarray
            ``(k, n, 2)`` candidate tracks, metres.
        """
        indicated = problem.indicated
        if self.track_shape == "translate":
            return indicated[None] + (ends - indicated[-1])[:, None, :]
        rel = indicated - indicated[0]
        span = complex(*rel[-1])
        if abs(span) == 0.0:
            return indicated[None] + (ends - indicated[-1])[:, None, :]
        z = (ends[:, 0] - start[0] + 1j * (ends[:, 1] - start[1])) / span
        moved = z[:, None] * (rel[:, 0] + 1j * rel[:, 1])[None, :]
        return np.stack([start[0] + moved.real, start[1] + moved.imag], axis=-1)

    def _integrity(self, problem, cost, ends, best) -> tuple[np.ndarray, bool]:
        """Covariance of the end fix and the ambiguity flag from the candidates' MSDs."""
        samples = int(np.isfinite(problem.measured).sum())
        scale = 2.0 * max(problem.noise_std**2, float(cost[best]), 1e-12)
        logw = -samples * (np.nan_to_num(cost, nan=np.inf) - cost[best]) / scale
        weights = np.exp(logw)
        weights /= weights.sum()
        delta = ends - ends[best]
        mean = weights @ delta
        centred = delta - mean
        cell = problem.grid.cell_size
        covariance = (weights[:, None] * centred).T @ centred + np.eye(2) * cell**2 / 12
        far = np.hypot(delta[:, 0], delta[:, 1]) > self.exclusion_cells * cell
        return covariance, bool(weights[far].sum() > self.ambiguity_mass)


def ring_sigmas(sigma_position: np.ndarray) -> tuple[float, float]:
    """``(sigma0, sigma)``: drift 1-sigma over the first sampling interval, and the maximum.

    Parameters
    ----------
    sigma_position : numpy.ndarray
        ``(n,)`` per-axis prior 1-sigma of the INS position error, metres.

    Returns
    -------
    tuple of float
        ``sqrt(max(sigma_position[1]^2 - sigma_position[0]^2, 0))`` (0 for a single
        sample) and ``max(sigma_position)``, metres.
    """
    sigma_position = np.asarray(sigma_position, dtype=float)
    first = sigma_position[min(1, sigma_position.size - 1)]
    sigma0 = float(np.sqrt(max(first**2 - sigma_position[0] ** 2, 0.0)))
    return sigma0, float(np.max(sigma_position))


def msd_scores(
    problem: MatchProblem, tracks: np.ndarray, min_valid_fraction: float = 0.9
) -> np.ndarray:
    """Mean squared difference of every candidate track, nearest-node map values.

    Parameters
    ----------
    problem : MatchProblem
        Map, heading, beam offsets and measurements (NaN skipped).
    tracks : numpy.ndarray
        ``(k, n, 2)`` candidate tracks, metres.
    min_valid_fraction : float
        Candidates valid on fewer than this share of the measured values are NaN.

    Returns
    -------
    numpy.ndarray
        ``(k,)`` MSD in squared map units (mGal^2 for gravity); NaN when discarded.
    """
    mapped = predict_track(problem.grid, tracks, problem.heading, problem.offsets, "nearest")
    return _msd(mapped, problem.measured, min_valid_fraction)


def translated_msd_scores(
    problem: MatchProblem, ends: np.ndarray, min_valid_fraction: float = 0.9
) -> np.ndarray:
    """MSD of the indicated track translated to end on each grid node of ``ends``.

    The same scores as :func:`msd_scores` on translated tracks, computed on integer cell
    indices by a compiled kernel (parallel over candidates): the footprint's offset from
    the indicated end is rounded to cells once, then every candidate adds its node's
    indices. :func:`translated_msd_scores_numpy` is the vectorised reference.

    Parameters
    ----------
    problem : MatchProblem
        Map, indicated track, heading, beam offsets and measurements (NaN skipped).
    ends : numpy.ndarray
        ``(k, 2)`` candidate end points on grid nodes, metres.
    min_valid_fraction : float
        Candidates valid on fewer than this share of the measured values are NaN.

    Returns
    -------
    numpy.ndarray
        ``(k,)`` MSD in squared map units; NaN when discarded.
    """
    rel_col, rel_row = _footprint_cells(problem)
    node_col, node_row = _node_cells(problem.grid, ends)
    measured = problem.measured.reshape(-1)
    keep = np.isfinite(measured)  # a missing measurement adds nothing to any candidate
    return pick(_translated_msd_kernels())(
        np.ascontiguousarray(problem.grid.values),
        np.ascontiguousarray(rel_col.reshape(-1)[keep]),
        np.ascontiguousarray(rel_row.reshape(-1)[keep]),
        np.ascontiguousarray(measured[keep]),
        np.ascontiguousarray(node_col),
        np.ascontiguousarray(node_row),
        float(min_valid_fraction * keep.sum()),
    )


def translated_msd_scores_numpy(
    problem: MatchProblem, ends: np.ndarray, min_valid_fraction: float = 0.9
) -> np.ndarray:
    """Vectorised-numpy reference of :func:`translated_msd_scores`.

    Gathers the ``(k, n, b)`` nearest-node map values from the window the candidates
    cover, then scores them with the shared MSD rule; equal to the kernel's scores up to
    the order of summation (NaN for the same candidates).

    Parameters
    ----------
    problem : MatchProblem
        Map, indicated track, heading, beam offsets and measurements (NaN skipped).
    ends : numpy.ndarray
        ``(k, 2)`` candidate end points on grid nodes, metres.
    min_valid_fraction : float
        Candidates valid on fewer than this share of the measured values are NaN.

    Returns
    -------
    numpy.ndarray
        ``(k,)`` MSD in squared map units; NaN when discarded.
    """
    grid = problem.grid
    rel_col, rel_row = _footprint_cells(problem)
    node_col, node_row = _node_cells(grid, ends)
    ny, nx = grid.shape
    col = rel_col[None] + node_col[:, None, None]
    row = rel_row[None] + node_row[:, None, None]
    inside = (col >= 0) & (col < nx) & (row >= 0) & (row < ny)
    if not inside.any():
        return np.full(ends.shape[0], np.nan)
    # gather from the window the candidates cover (small, cache-friendly), not the whole map
    c0, r0 = max(int(col.min()), 0), max(int(row.min()), 0)
    window = grid.values[r0 : min(int(row.max()) + 1, ny), c0 : min(int(col.max()) + 1, nx)]
    window = np.ascontiguousarray(window)
    flat = np.where(inside, (row - r0) * window.shape[1] + (col - c0), 0)
    mapped = window.ravel()[flat]
    mapped[~inside] = np.nan
    return _msd(mapped, problem.measured, min_valid_fraction)


def _footprint_cells(problem: MatchProblem) -> tuple[np.ndarray, np.ndarray]:
    """``(n, b)`` integer cell offsets ``(col, row)`` of the footprint from the indicated end."""
    grid = problem.grid
    fx, fy = problem.footprint(problem.indicated)
    end = problem.indicated[-1]
    rel_col = np.rint((fx - end[0]) / grid.dx).astype(np.int64)
    rel_row = np.rint((fy - end[1]) / grid.dy).astype(np.int64)
    return rel_col, rel_row


def _node_cells(grid: Grid, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(k,)`` integer ``(col, row)`` of the nodes nearest to ``ends`` ``(k, 2)``, metres."""
    col, row = grid.xy_to_cell(ends[:, 0], ends[:, 1])
    return np.rint(col).astype(np.int64), np.rint(row).astype(np.int64)


_INDEX = numba.types.Array(numba.int64, 1, "C")
_TRANSLATED_SIGNATURES = [
    numba.float64[:](
        numba.types.Array(dtype, 2, "C", readonly=True),  # the Grid's read-only values
        _INDEX,
        _INDEX,
        numba.types.Array(numba.float64, 1, "C"),
        _INDEX,
        _INDEX,
        numba.float64,
    )
    for dtype in (numba.float64, numba.float32)  # float32: a compact shared map
]


@functools.cache
def _translated_msd_kernels():
    """The compiled kernels, with numba's thread pool and without (:mod:`geofix._threads`).

    Both are built for both signatures (and cached on disk) at first use.

    Eager signatures mean no match call pays for compilation; building them at first use
    rather than at import keeps ``import geofix`` from starting numba's threading layer
    (a parallel kernel does when it is loaded), which would make the calling process
    unsafe to fork (GNU OpenMP).
    """
    return twins(_translated_msd, _TRANSLATED_SIGNATURES, cache=True)


def _translated_msd(values, rel_col, rel_row, h, node_col, node_row, needed):  # pragma: no cover
    """``(k,)`` MSD of ``h`` against the nearest-node values at ``node + rel`` (see numpy)."""
    ny, nx = values.shape
    out = np.full(node_col.shape[0], np.nan)
    for k in numba.prange(node_col.shape[0]):
        acc = 0.0
        valid = 0
        for i in range(h.shape[0]):
            c = rel_col[i] + node_col[k]
            r = rel_row[i] + node_row[k]
            if c < 0 or r < 0 or c >= nx or r >= ny:
                continue
            d = values[r, c] - h[i]
            if not np.isfinite(d):
                continue
            acc += d * d
            valid += 1
        if valid > 0 and valid >= needed:
            out[k] = acc / valid
    return out


def _msd(mapped: np.ndarray, measured: np.ndarray, min_valid_fraction: float) -> np.ndarray:
    """``(k,)`` mean squared difference of ``(k, n, b)`` map values against ``(n, b)``."""
    diff = mapped - measured[None]
    ok = np.isfinite(diff)
    count = ok.sum(axis=(1, 2))
    total = np.where(ok, diff, 0.0)
    sums = np.einsum("knb,knb->k", total, total)
    needed = min_valid_fraction * np.isfinite(measured).sum()
    keep = (count >= needed) & (count > 0)
    return np.where(keep, sums / np.maximum(count, 1), np.nan)
