"""ICP surface matching of a multibeam point cloud, and TERCOM coarse + ICP fine (source 001).

Source 001 (Cheng et al., Navigation Positioning and Timing, 2023(2)) registers the multibeam swath
as a 3-D point cloud onto the map's grid points with the iterative closest point
algorithm (ICP), started from a TERCOM fix.

``icp`` -- point-to-point ICP:

- source cloud ``P``: every valid sounding at its footprint on the indicated track,
  ``(x, y, w * h)`` (``MatchProblem.footprint``), ``h`` the measured field value;
- target cloud ``Q``: the centres of the valid map cells in a window around the track,
  ``(x, y, w * z)``, held in a :class:`scipy.spatial.cKDTree` built once per call;
- iterate: transform ``P`` by the current estimate, find each point's nearest neighbour
  in ``Q``, solve the least-squares rigid transform of the pairs, compose; stop when no
  point moved by more than ``tolerance_m`` in an iteration, or after ``max_iterations``.

Depth and horizontal distance have different scales, so the field is multiplied by an
explicit weight ``w`` (metres per map unit) before the nearest-neighbour search:
``depth_weight`` when set, else ``w = cell_size / depth_std``, with
``depth_std = sqrt(noise_std^2 + map_error_std^2)`` floored at ``min_depth_std``: a depth
disagreement of one noise sigma weighs as much as a horizontal offset of one map cell.

The transform is restricted to what a navigation error can do: a rotation about the
vertical axis, a horizontal translation and, with ``vertical_offset=True``, a constant
field offset (a tide or depth-sensor bias). For that model the least-squares problem
splits exactly: the horizontal rotation and translation are the 2-D SVD (Kabsch) solution
of :func:`geofix.match.rigid.rigid_transform` (with its reflection guard) on the
horizontal coordinates of the pairs, and the offset is the mean vertical difference of
the pairs (started at the mean map-minus-measured difference on the starting footprints).
A full 3-D rotation would let the cloud tilt, which no INS error does.

``tercom-icp`` -- TERCOM (MSD) over the ``2 * window_sigma`` -sigma window (6 sigma by
default, as in the source) gives the coarse fix, by default from the depth profile of the
beam nearest nadir (the source's TERCOM is the classic line matching of the profile under
the track; the surface is left to ICP); ICP then starts from it with a small map window
(``fine_margin_cells`` around the coarse footprints).

Integrity (our addition, the source has none): the covariance is the inverse Fisher
information of the final footprints, ``s^2 (sum_i g_i g_i^T)^-1`` with ``g_i`` the map
gradient (bilinear central differences) at each matched sounding and ``s`` the RMS field
residual (at least the declared noise); the fix is *ambiguous* when ICP hit its iteration
cap, its RMS residual exceeds ``ambiguity_rms_factor`` times the declared noise (a
cloud resting on the wrong terrain cannot fit it), or the terrain under the final
footprints is flatter than ``min_terrain_snr`` noise sigmas
(:func:`geofix.match.integrity.terrain_snr`: on a plain every placement fits within the
noise, so the residual cannot tell). The covariance is widened to the Cramér–Rao bound
of the final footprints with the window's INS prior
(:func:`geofix.match.integrity.information_covariance`), which stays finite on flat
terrain, and gains the INS drift inside the window
(:func:`geofix.match.drift.with_leg_drift`; conservative, as the fitted rotation absorbs
part of it). For ``tercom-icp`` the flag is that of the ICP stage: the coarse TERCOM's own
flag (kept in the diagnostics as ``coarse_ambiguous``) is raised on most nadir profiles
of 10 depths, while the swath residual and relief after ICP tell a wrong fix from a
right one.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.spatial import cKDTree

from geofix.errors import ConfigError, MatchError
from geofix.maps.grid import Grid
from geofix.match.drift import with_leg_drift
from geofix.match.integrity import terrain_integrity
from geofix.match.rigid import apply_transform, rigid_transform
from geofix.match.tercom import Tercom
from geofix.measurement import beam_gradients
from geofix.problem import Fix, MatchProblem


@dataclass(frozen=True, eq=False)
class IcpResult:
    """Outcome of one ICP registration.

    Attributes
    ----------
    rotation : numpy.ndarray
        ``(2, 2)`` horizontal rotation (proper, det +1).
    translation : numpy.ndarray
        ``(2,)`` horizontal translation, metres; a point ``p`` maps to ``R p + t``.
    vertical_offset : float
        Constant added to the measured field values, map units (0 unless estimated).
    iterations : int
        Iterations run.
    converged : bool
        True when the last step moved no point by more than the tolerance.
    rms_residual : float
        RMS of ``measured + offset - map`` at the final footprints (bilinear), map units.
    points : int
        Soundings in the source cloud.
    targets : int
        Map points in the target cloud.
    """

    rotation: np.ndarray
    translation: np.ndarray
    vertical_offset: float
    iterations: int
    converged: bool
    rms_residual: float
    points: int
    targets: int


@dataclass(frozen=True)
class Icp:
    """Point-to-point ICP of the multibeam cloud onto the map's grid points (source 001).

    Parameters
    ----------
    window_sigma : float
        Margin of the map window around the indicated footprints, in prior sigmas (the
        INS position 1-sigma at the last sample): 3 covers the source's 6-sigma search
        square. For ``tercom-icp`` it is TERCOM's half-window instead.
    depth_weight : float
        Metres of horizontal distance per map unit of field difference in the
        nearest-neighbour search; 0 (default) = ``cell_size / depth_std``.
    min_depth_std : float
        Floor of ``depth_std`` for the automatic weight, map units (keeps the weight
        finite for noise-free data).
    vertical_offset : bool
        Also estimate a constant field offset (tide, depth-sensor bias), started at the
        mean of ``map - measured`` on the starting footprints. Off by default, as in the
        source.
    max_iterations : int
        Iteration cap.
    tolerance_m : float
        Stop when no sounding moved more than this in one iteration, metres.
    ambiguity_rms_factor : float
        Flag the fix ambiguous when the RMS field residual exceeds this many declared
        noise sigmas (noise and map error combined, floored at ``min_depth_std``).
    min_terrain_snr : float
        Flag the fix ambiguous when the map's std over the final footprints is below this
        many sensor-noise sigmas (1, as :class:`geofix.match.tercom.Tercom`: the residual
        test cannot tell a wrong placement once the relief is within the noise).

    References
    ----------
    .. [1] Besl, P. J., & McKay, N. D. (1992). A method for registration of 3-D shapes.
       IEEE Transactions on Pattern Analysis and Machine Intelligence, 14(2), 239-256.
    .. [2] Cheng, J. et al. (2023). Multibeam terrain matching by TERCOM and ICP.
       Navigation Positioning and Timing, 2023(2).

    Examples
    --------
    >>> import geofix
    >>> geofix.Icp().name
    'icp'
    """

    name: ClassVar[str] = "icp"
    recursive: ClassVar[bool] = False
    #: A point cloud needs a swath: one sounding per sample leaves the rotation unobservable.
    min_beams: ClassVar[int] = 2

    window_sigma: float = 3.0
    depth_weight: float = 0.0
    min_depth_std: float = 0.1
    vertical_offset: bool = False
    max_iterations: int = 100
    tolerance_m: float = 0.01
    ambiguity_rms_factor: float = 3.0
    min_terrain_snr: float = 1.0

    def __post_init__(self) -> None:
        if self.window_sigma <= 0 or self.max_iterations < 1 or self.tolerance_m <= 0:
            raise ConfigError(
                f"{self.name}: window_sigma, max_iterations and tolerance_m must be positive"
            )
        if self.depth_weight < 0 or self.min_depth_std <= 0:
            raise ConfigError(f"{self.name}: depth_weight must be >= 0 and min_depth_std positive")

    def match(self, problem: MatchProblem, rng: np.random.Generator | None = None) -> Fix:
        """Register the cloud from the indicated track; the window covers the prior."""
        margin = self.window_sigma * float(np.max(problem.sigma_position))
        result = self.register_cloud(problem, problem.indicated, margin)
        return self._fix(problem, problem.indicated, result, {})

    # ------------------------------------------------------------------ pieces
    def weight(self, problem: MatchProblem) -> float:
        """The depth weight ``w`` used in the 3-D search, metres per map unit."""
        if self.depth_weight > 0:
            return float(self.depth_weight)
        return problem.grid.cell_size / self._depth_std(problem)

    def _depth_std(self, problem: MatchProblem) -> float:
        std = float(np.hypot(problem.noise_std, problem.map_error_std))
        return max(std, self.min_depth_std)

    def register_cloud(
        self, problem: MatchProblem, start: np.ndarray, margin_m: float
    ) -> IcpResult:
        """Run ICP with the soundings placed along ``start``.

        Parameters
        ----------
        problem : MatchProblem
            Map, heading, beam offsets and measurements.
        start : numpy.ndarray
            ``(n, 2)`` vehicle positions where the soundings are placed first, metres.
        margin_m : float
            Margin of the map window around the footprints of ``start``, metres.

        Returns
        -------
        IcpResult
            The transform (metres, radians via its matrix), the vertical offset and
            convergence diagnostics.

        Raises
        ------
        MatchError
            Fewer than three valid soundings, or too few valid map cells in the window.
        """
        xy, h = _source_cloud(problem, start)
        w = self.weight(problem)
        targets = _target_cloud(problem.grid, xy, margin_m)
        origin = xy.mean(axis=0)
        p = xy - origin
        local = targets[:, :2] - origin
        tree = cKDTree(np.column_stack([local, w * targets[:, 2]]))
        rotation, translation = np.eye(2), np.zeros(2)
        offset = _initial_offset(problem.grid, xy, h) if self.vertical_offset else 0.0
        converged, iterations = False, 0
        while iterations < self.max_iterations:
            iterations += 1
            moved = apply_transform(p, rotation, translation)
            _, idx = tree.query(np.column_stack([moved, w * (h + offset)]))
            r_step, t_step = rigid_transform(moved, local[idx])
            dz = float(np.mean(targets[idx, 2] - h - offset)) if self.vertical_offset else 0.0
            step = np.max(np.hypot(*(apply_transform(moved, r_step, t_step) - moved).T))
            rotation, translation = r_step @ rotation, r_step @ translation + t_step
            offset += dz
            if step <= self.tolerance_m and abs(dz) * w <= self.tolerance_m:
                converged = True
                break
        # express the transform for absolute coordinates: R (x - o) + t + o
        translation_abs = translation + origin - rotation @ origin
        final = apply_transform(xy, rotation, translation_abs)
        resid = h + offset - problem.grid.sample(final[:, 0], final[:, 1])
        rms = float(np.sqrt(np.nanmean(resid**2))) if np.isfinite(resid).any() else np.inf
        return IcpResult(
            rotation, translation_abs, offset, iterations, converged, rms, len(h), len(targets)
        )

    def _fix(self, problem, start, result: IcpResult, extra: dict) -> Fix:
        track = apply_transform(start, result.rotation, result.translation)
        heading = problem.heading - np.arctan2(result.rotation[1, 0], result.rotation[0, 0])
        own = _covariance(problem, track, heading, result.rms_residual)
        check = terrain_integrity(problem, track, own, self.min_terrain_snr, heading)
        limit = self.ambiguity_rms_factor * self._depth_std(problem)
        ambiguous = (not result.converged) or result.rms_residual > limit or check.flat
        angle = float(np.degrees(np.arctan2(result.rotation[1, 0], result.rotation[0, 0])))
        covariance, drift = with_leg_drift(problem, check.covariance, track, heading)
        return Fix(
            track=track,
            covariance=covariance,
            cost=result.rms_residual,
            evaluations=result.iterations * result.points,
            ambiguous=bool(ambiguous),
            diagnostics={
                "iterations": result.iterations,
                "converged": result.converged,
                "rotation_deg": angle,
                "translation_m": result.translation,
                "vertical_offset": result.vertical_offset,
                "rms_residual": result.rms_residual,
                "terrain_snr": check.snr,
                "target_points": result.targets,
                "depth_weight": self.weight(problem),
                "drift_covariance": drift,
                **extra,
            },
        )


@dataclass(frozen=True)
class TercomIcp(Icp):
    """TERCOM (MSD) coarse fix over the 6-sigma window, then ICP from it (source 001).

    Parameters
    ----------
    window_sigma : float
        TERCOM's half-window in prior sigmas (3 = the source's 6-sigma square).
    fine_margin_cells : float
        Margin of ICP's map window around the coarse footprints, map cells (the coarse
        fix is within a cell or two when TERCOM is right).
    coarse_beams : str
        Soundings TERCOM matches: ``"nadir"`` (default) the profile of the beam nearest
        nadir, as in the source, whose TERCOM is the classic line matching of the depth
        profile under the track and leaves the swath (the surface) to ICP; ``"all"``
        every beam of the swath (more robust, about ``beams`` times the cost).

    Notes
    -----
    The other settings are those of :class:`Icp`. ``Fix.diagnostics`` holds the ICP
    iterations and the coarse fix (``coarse_track`` ``(n, 2)`` metres, ``coarse_offset``
    metres, ``coarse_ambiguous``).

    References
    ----------
    .. [1] Cheng, J. et al. (2023). Multibeam terrain matching by TERCOM and ICP.
       Navigation Positioning and Timing, 2023(2).

    Examples
    --------
    >>> import geofix
    >>> geofix.parse_method_spec("tercom-icp:coarse_beams=all").coarse_beams
    'all'
    """

    name: ClassVar[str] = "tercom-icp"
    recursive: ClassVar[bool] = False

    fine_margin_cells: float = 10.0
    coarse_beams: str = "nadir"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.coarse_beams not in ("nadir", "all"):
            raise ConfigError(
                f"tercom-icp: coarse_beams must be 'nadir' or 'all', got {self.coarse_beams!r}"
            )
        if self.fine_margin_cells <= 0:
            raise ConfigError("tercom-icp: fine_margin_cells must be positive")

    def match(self, problem: MatchProblem, rng: np.random.Generator | None = None) -> Fix:
        """TERCOM over the window, then ICP started at the TERCOM track."""
        coarse_problem = problem.nadir() if self.coarse_beams == "nadir" else problem
        coarse = Tercom(metric="msd", window_sigma=self.window_sigma).match(coarse_problem)
        margin = self.fine_margin_cells * problem.grid.cell_size
        result = self.register_cloud(problem, coarse.track, margin)
        extra = {
            "coarse_track": coarse.track,
            "coarse_offset": coarse.diagnostics.get("offset"),
            "coarse_ambiguous": coarse.ambiguous,
        }
        fix = self._fix(problem, coarse.track, result, extra)
        return dataclasses.replace(fix, evaluations=fix.evaluations + coarse.evaluations)


# ---------------------------------------------------------------------- clouds
def _source_cloud(problem: MatchProblem, start: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Footprints ``(m, 2)`` metres and field values ``(m,)`` of the valid soundings."""
    fx, fy = problem.footprint(np.asarray(start, dtype=float))
    h = np.asarray(problem.measured, dtype=float).reshape(-1)
    xy = np.column_stack([fx.reshape(-1), fy.reshape(-1)])
    keep = np.isfinite(h) & np.isfinite(xy).all(axis=1)
    if keep.sum() < 3:
        raise MatchError(f"icp: only {int(keep.sum())} valid soundings, need at least 3")
    return xy[keep], h[keep]


def _target_cloud(grid: Grid, xy: np.ndarray, margin_m: float) -> np.ndarray:
    """``(k, 3)`` centres ``(x, y, z)`` of the valid cells within ``margin_m`` of ``xy``."""
    (low_col, low_row), (high_col, high_row) = (
        grid.xy_to_cell(*(xy.min(axis=0) - margin_m)),
        grid.xy_to_cell(*(xy.max(axis=0) + margin_m)),
    )
    ny, nx = grid.shape
    c0, r0 = max(int(np.floor(low_col)), 0), max(int(np.floor(low_row)), 0)
    c1, r1 = min(int(np.ceil(high_col)) + 1, nx), min(int(np.ceil(high_row)) + 1, ny)
    if c1 - c0 < 2 or r1 - r0 < 2:
        raise MatchError("icp: the map window around the track lies off the map")
    z = grid.values[r0:r1, c0:c1]
    rows, cols = np.nonzero(np.isfinite(z))
    if rows.size < 3:
        raise MatchError("icp: the map window around the track has no valid data")
    x, y = grid.cell_to_xy(cols + c0, rows + r0)
    return np.column_stack([x, y, z[rows, cols]])


def _initial_offset(grid: Grid, xy: np.ndarray, h: np.ndarray) -> float:
    """Mean of ``map - measured`` at the starting footprints, map units (0 if none valid)."""
    diff = grid.sample(xy[:, 0], xy[:, 1]) - h
    return float(np.nanmean(diff)) if np.isfinite(diff).any() else 0.0


def _covariance(problem: MatchProblem, track, heading, rms: float) -> np.ndarray | None:
    """Inverse Fisher information of the final footprints, m^2 (None when singular)."""
    gx, gy = beam_gradients(problem.grid, track, heading, problem.offsets, "bilinear")
    keep = np.isfinite(problem.measured)
    g = np.column_stack([gx[keep], gy[keep]])
    g = g[(g != 0).any(axis=1)]
    info = g.T @ g
    scale = max(rms, float(np.hypot(problem.noise_std, problem.map_error_std)), 1e-12)
    if g.shape[0] < 2 or np.linalg.cond(info) > 1e12:
        return None
    return scale**2 * np.linalg.inv(info)
