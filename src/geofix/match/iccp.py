"""ICCP and multipath parallel ICCP: iterative closest contour point matching.

After Kamgar-Parsi & Kamgar-Parsi (1999), below. Every measured value ``h_j`` says the
true footprint lies on the map's ``h_j`` contour. Starting from the indicated track,
iterate:

1. for each footprint of the current track, find the closest point of its own contour
   (contours of the map window around the indicated track by
   :func:`skimage.measure.find_contours`, the exact closest point on the contour
   polylines by point-to-segment projection);
2. find the rigid transform (rotation + translation) that best maps the footprints onto
   those closest points, weighted least squares by SVD (:func:`geofix.match.rigid.rigid_transform`);
3. apply it to the track (and rotate the heading with it); stop when the step's
   translation is below ``tolerance_cells`` cells and its rotation below
   ``tolerance_rad``, or after ``max_iterations``.

``iccp`` matches the centre (nadir) beam only, like a single-beam echosounder.
``iccp-multipath`` is the multipath parallel ICCP of Wang, Xu and Zhang (IEEE Access
2018): the centre beam and the two beams nearest to ``+-Delta d`` across track (the same
adaptive spacing as :mod:`geofix.match.ga_sca`, eq. 6 of source 000), all three paths
moved by one shared rigid transform, each path's points weighted (``w1 > w2, w3``; the
weights and the spacing are this implementation's choices -- the paper's own are not in
the source -- and are the same as ga-sca's so that the comparison is like for like).

Points whose value has no contour in the window are skipped; a match with fewer than
two usable points raises :class:`~geofix.errors.MatchError`. The fix is flagged
ambiguous when ICCP did not converge or when the RMS difference between the measured
values and the map at the matched footprints exceeds ``max_residual_sigma`` times the
declared noise (sensor noise and map error, floored at 1 % of the window's std): the
track does not fit the map there, the mark of a local minimum. It is also flagged when the
terrain along the fix is flatter than ``min_terrain_snr`` sensor-noise sigmas
(:func:`geofix.match.integrity.terrain_snr`): on a plain every position fits the contours
within the noise, and the residual test cannot tell. The covariance is the Laplace
approximation of the translation from the depth residuals at the fix, widened to the
Cramér–Rao bound of the matched footprints with the window's INS prior
(:func:`geofix.match.integrity.information_covariance`; the Laplace curvature of a noisy
residual surface is far too narrow on flat terrain), plus the INS drift inside the window
(:func:`geofix.match.drift.with_leg_drift`; conservative here, as the fitted rotation
absorbs part of it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from geofix.errors import ConfigError, MatchError
from geofix.match._affine import (
    adaptive_spacing,
    map_window,
    nearest_beams,
    translation_covariance,
    window_std,
)
from geofix.match._contours import ContourMap
from geofix.match.drift import with_leg_drift
from geofix.match.integrity import terrain_integrity
from geofix.match.rigid import rigid_transform
from geofix.measurement import residuals
from geofix.problem import Fix, MatchProblem, footprint_xy


@dataclass(frozen=True)
class _IccpResult:
    track: np.ndarray
    rotation: float
    iterations: int
    converged: bool
    residual_m: float
    used_points: int


def _iccp_align(
    problem: MatchProblem,
    beams: np.ndarray,
    weights: np.ndarray,
    contours: ContourMap,
    max_iterations: int = 100,
    tolerance_m: float = 0.01,
    tolerance_rad: float = 1e-5,
) -> _IccpResult:
    """Run the ICCP iteration for the chosen beams with one shared rigid transform.

    Parameters
    ----------
    problem : MatchProblem
        Indicated track, heading, beam offsets and measurements.
    beams : numpy.ndarray
        ``(s,)`` beam indices (paths).
    weights : numpy.ndarray
        ``(s,)`` weight of each path's points.
    contours : ContourMap
        Contours of the map window.
    max_iterations : int
        Iteration limit.
    tolerance_m, tolerance_rad : float
        Convergence thresholds on one step's translation (metres) and rotation (radians).

    Returns
    -------
    _IccpResult
        Matched vehicle track ``(n, 2)`` (metres), total rotation (radians,
        counter-clockwise), iterations, convergence flag, weighted RMS distance to the
        contours (metres) and the number of points used.
    """
    levels = problem.measured[:, beams].reshape(-1)
    w = np.broadcast_to(np.asarray(weights, float), (problem.n, len(beams))).reshape(-1)
    track = problem.indicated.astype(float).copy()
    theta, converged, iteration, residual, used = 0.0, False, 0, np.nan, 0
    while iteration < max_iterations:
        iteration += 1
        x, y = footprint_xy(track, problem.heading - theta, problem.offsets[beams])
        points = np.column_stack([x.reshape(-1), y.reshape(-1)])
        targets, dist = contours.closest(points, levels)
        ok = np.isfinite(dist)
        used = int(ok.sum())
        if used < 2:
            raise MatchError("iccp: fewer than two measured values have a contour in the window")
        residual = float(np.sqrt(np.average(dist[ok] ** 2, weights=w[ok])))
        rot, t = rigid_transform(points[ok], targets[ok], w[ok])
        step = float(np.arctan2(rot[1, 0], rot[0, 0]))
        track = track @ rot.T + t
        theta += step
        moved = np.abs(points[ok] @ rot.T + t - points[ok]).max()
        if moved < tolerance_m and abs(step) < tolerance_rad:
            converged = True
            break
    return _IccpResult(track, theta, iteration, converged, residual, used)


@dataclass(frozen=True)
class _IccpBase:
    """Settings and the fix shared by both ICCP matchers."""

    name: ClassVar[str]

    window_sigma: float = 3.0
    max_iterations: int = 100
    tolerance_cells: float = 0.01
    tolerance_rad: float = 1e-5
    max_residual_sigma: float = 3.0
    min_terrain_snr: float = 1.0

    def _check(self) -> None:
        if self.window_sigma <= 0 or self.max_iterations < 1 or self.tolerance_cells <= 0:
            raise ConfigError(
                f"{self.name}: window_sigma, max_iterations, tolerance_cells must be positive"
            )

    def _window_half(self, problem: MatchProblem) -> float:
        swath = float(np.abs(problem.offsets).max())
        return self.window_sigma * float(np.max(problem.sigma_position)) + swath

    def _run(self, problem: MatchProblem, beams: np.ndarray, weights: np.ndarray, info) -> Fix:
        if problem.n < 2:
            raise MatchError(f"{self.name}: need at least two samples")
        grid = problem.grid
        x0, y0, values = map_window(problem, self._window_half(problem))
        contours = ContourMap(x0, y0, grid.dx, grid.dy, values)
        result = _iccp_align(
            problem,
            beams,
            weights,
            contours,
            self.max_iterations,
            self.tolerance_cells * grid.cell_size,
            self.tolerance_rad,
        )
        heading = problem.heading - result.rotation
        misfit = _depth_rms(problem, result.track, heading, beams)
        floor = max(
            float(np.hypot(problem.noise_std, problem.map_error_std)), 0.01 * np.nanstd(values)
        )
        check = terrain_integrity(
            problem,
            result.track,
            translation_covariance(problem, result.track, heading, beams),
            self.min_terrain_snr,
            heading,
            beams,
        )
        ambiguous = (not result.converged) or not (misfit <= self.max_residual_sigma * floor)
        covariance, drift = with_leg_drift(problem, check.covariance, result.track, heading, beams)
        return Fix(
            track=result.track,
            covariance=covariance,
            cost=result.residual_m,
            evaluations=int(result.iterations * result.used_points),
            ambiguous=bool(ambiguous or check.flat),
            diagnostics={
                "iterations": result.iterations,
                "converged": result.converged,
                "rotation_rad": result.rotation,
                "residual_m": result.residual_m,
                "depth_rms": misfit,
                "terrain_snr": check.snr,
                "beams": np.asarray(beams).tolist(),
                "drift_covariance": drift,
                **info,
            },
        )


@dataclass(frozen=True)
class Iccp(_IccpBase):
    """ICCP on the centre (nadir) beam.

    Parameters
    ----------
    window_sigma : float
        The contours are taken from the indicated track's bounding box widened by this
        many prior sigmas (largest ``sigma_position``) plus the swath half-width.
    max_iterations : int
        Iteration limit.
    tolerance_cells : float
        Convergence when one step moves every point less than this many cells...
    tolerance_rad : float
        ... and rotates less than this, radians.
    max_residual_sigma : float
        RMS depth misfit at the fix, in noise sigmas, above which the fix is ambiguous.
    min_terrain_snr : float
        The fix is ambiguous when the map's std over the matched footprints is below this
        many sensor-noise sigmas. 1, as :class:`geofix.match.tercom.Tercom`: the residual
        test is blind once the relief is within the noise.

    References
    ----------
    .. [1] Kamgar-Parsi, B., & Kamgar-Parsi, B. (1999). Vehicle localization on gravity
       maps. Proc. SPIE 3693, Unmanned Ground Vehicle Technology, 182-191.

    Examples
    --------
    >>> import geofix
    >>> geofix.parse_method_spec("iccp:max_iterations=20").max_iterations
    20
    """

    name: ClassVar[str] = "iccp"
    recursive: ClassVar[bool] = False

    def __post_init__(self) -> None:
        self._check()

    def match(self, problem: MatchProblem, rng: np.random.Generator | None = None) -> Fix:
        """Align the centre-beam track to its contours (deterministic: ``rng`` unused)."""
        beams = nearest_beams(problem.offsets, 0.0)[:1]
        return self._run(problem, beams, np.ones(1), {})


@dataclass(frozen=True)
class MultipathIccp(_IccpBase):
    """Multipath parallel ICCP (Wang, Xu, Zhang 2018): three paths, one rigid transform.

    Parameters
    ----------
    window_sigma, max_iterations, tolerance_cells, tolerance_rad, max_residual_sigma, \
min_terrain_snr
        As for :class:`Iccp`.
    weights : tuple of float
        ``(w1, w2, w3)`` of the centre, starboard and port paths, ``w1 > w2, w3``.
    mu1, mu2 : float
        Side-path spacing ``Delta d = mu1 + mu2 * sigma`` (metres; metres per map unit),
        at least one cell, as in :class:`geofix.match.ga_sca.GaSca`.
    side_offset_m : float
        Fixed side-path spacing, metres; overrides ``mu1``/``mu2`` when > 0.

    References
    ----------
    .. [1] Wang, K., Xu, X., & Zhang, T. (2018). Multipath parallel ICCP underwater
       terrain matching algorithm based on multibeam bathymetric data. IEEE Access, 6.

    Examples
    --------
    >>> import geofix
    >>> geofix.MultipathIccp().name
    'iccp-multipath'
    """

    name: ClassVar[str] = "iccp-multipath"
    recursive: ClassVar[bool] = False

    weights: tuple = (0.5, 0.25, 0.25)
    mu1: float = 2.0
    mu2: float = 2.0
    side_offset_m: float = 0.0

    def __post_init__(self) -> None:
        self._check()
        w = tuple(float(v) for v in self.weights)
        if len(w) != 3 or min(w) < 0 or not (w[0] > w[1] and w[0] > w[2]):
            raise ConfigError(f"iccp-multipath: weights need w1 > w2, w3; got {w}")

    def match(self, problem: MatchProblem, rng: np.random.Generator | None = None) -> Fix:
        """Align the three paths to their contours (deterministic: ``rng`` unused)."""
        if self.side_offset_m > 0:
            spacing = self.side_offset_m
        else:
            depth_std = window_std(problem, self._window_half(problem))
            spacing = adaptive_spacing(depth_std, problem.grid.cell_size, self.mu1, self.mu2)
        beams = nearest_beams(problem.offsets, spacing)
        weights = np.asarray(self.weights, float)[: len(beams)]
        return self._run(problem, beams, weights / weights.sum(), {"spacing_m": spacing})


def _depth_rms(problem: MatchProblem, track, heading, beams) -> float:
    """RMS of measured minus map values at the footprints of ``track`` (map units)."""
    d = residuals(problem.grid, track, heading, problem.offsets[beams], problem.measured[:, beams])
    return float(np.sqrt(np.nanmean(d**2))) if np.isfinite(d).any() else float("nan")
