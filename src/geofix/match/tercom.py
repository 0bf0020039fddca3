"""TERCOM: terrain contour matching by exhaustive search over rigid translations.

The indicated track is translated, with its shape kept, to every candidate offset of a
square window centred on the indicated position; the map is read (bilinear) along every
candidate and scored against the measured sequence; the best candidate is the fix
(Golden, Proc. SPIE 238, 1980). Scores, over the ``L`` valid samples (all beams of all points):

- ``msd`` -- mean squared difference (minimised; the usual default),
- ``mad`` -- mean absolute difference (minimised),
- ``cor`` -- mean product ``h_r * h_m`` (maximised; stored as its negative),
- ``ncor`` -- normalised cross-correlation (maximised; an extension, insensitive to a
  constant field offset such as a tide or gravimeter bias).

Integrity: the cost surface is turned into a pseudo-likelihood (Gaussian for ``msd``,
Laplace for ``mad``, with the sensor noise as scale) whose mass-weighted spread is the
fix covariance; the fix is *ambiguous* when more than ``ambiguity_mass`` of that mass lies
farther than ``exclusion_cells`` from the best candidate (a second minimum nearly as good
as the first, far from it). For ``cor``/``ncor``, whose values are no distances, the
integrity check scores the same window once more with ``msd``. The fix is also flagged
when the terrain along it is too flat to tell: the standard deviation of the map over the
matched footprints is below ``min_terrain_snr`` times the sensor noise (a surface whose
relief drowns in the noise, such as a flat sediment plain, makes the pseudo-likelihood
overconfident: the small INS drift inside the window then picks the minimum).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numba
import numpy as np

from geofix.errors import ConfigError, MatchError
from geofix.match.integrity import terrain_snr
from geofix.memory import cells_bytes, check_allocation
from geofix.problem import Fix, MatchProblem

_METRICS = {"msd": 0, "mad": 1, "cor": 2, "ncor": 3}
# Float arrays of the cost surface's size alive at once: two surfaces (cor/ncor score
# again with msd), the pseudo-likelihood, offset grids, distances and products.
_SURFACE_COPIES = 12


@dataclass(frozen=True)
class Tercom:
    """TERCOM: exhaustive search over rigid translations of the track (MSD, MAD, COR).

    Parameters
    ----------
    metric : str
        ``"msd"`` (default), ``"mad"``, ``"cor"`` or ``"ncor"``.
    window_sigma : float
        Half-side of the square search window in prior sigmas (the INS position 1-sigma at
        the last sample): 3 gives the 6-sigma window of source 001.
    window_m : float
        Half-side of the window in metres; overrides ``window_sigma`` when > 0.
    step_cells : float
        Candidate spacing in map cells (1 = every grid offset).
    min_valid_fraction : float
        A candidate whose map look-ups are valid for less than this share of the measured
        samples is discarded (off the map or on no-data).
    exclusion_cells : float
        Radius, in cells, around the best candidate outside which a competing minimum
        makes the fix ambiguous.
    ambiguity_mass : float
        Pseudo-likelihood mass outside the exclusion radius above which the fix is flagged.
    min_terrain_snr : float
        The fix is flagged when the map's standard deviation over the matched footprints
        is below this many sensor-noise sigmas (:func:`terrain_snr`); 1 = relief no larger
        than the noise.
    beams : str
        ``"all"`` matches every beam of a multibeam swath; ``"nadir"`` only the depth
        profile under the track (the beam nearest nadir), the classic line TERCOM.

    References
    ----------
    .. [1] Golden, J. P. (1980). Terrain contour matching (TERCOM): a cruise missile
       guidance aid. Proc. SPIE 238, Image Processing for Missile Guidance, 10-18.

    Examples
    --------
    >>> import geofix
    >>> scen = geofix.load_scenario("builtin:azores_demo")
    >>> grid = geofix.prepare_map(scen)
    >>> trial = geofix.simulate_trial(scen, grid, 0)
    >>> fix = geofix.Tercom().match(trial.problem(grid), np.random.default_rng(0))
    >>> bool(np.hypot(*(fix.track[-1] - trial.truth[-1])) < 3 * grid.cell_size)
    True
    """

    name: ClassVar[str] = "tercom"
    recursive: ClassVar[bool] = False

    metric: str = "msd"
    window_sigma: float = 3.0
    window_m: float = 0.0
    step_cells: float = 1.0
    min_valid_fraction: float = 0.9
    exclusion_cells: float = 3.0
    ambiguity_mass: float = 0.05
    min_terrain_snr: float = 1.0
    beams: str = "all"

    def __post_init__(self) -> None:
        if self.metric not in _METRICS:
            raise ConfigError(
                f"tercom: metric must be one of {sorted(_METRICS)}, got {self.metric!r}"
            )
        if self.step_cells <= 0 or self.window_sigma <= 0:
            raise ConfigError("tercom: step_cells and window_sigma must be positive")
        if self.beams not in ("all", "nadir"):
            raise ConfigError(f"tercom: beams must be 'all' or 'nadir', got {self.beams!r}")

    def match(self, problem: MatchProblem, rng: np.random.Generator | None = None) -> Fix:
        """Search the window and return the best translation of the indicated track."""
        if self.beams == "nadir":
            problem = problem.nadir()
        ox, oy = self.candidate_offsets(problem)
        cost = tercom_cost_surface(problem, ox, oy, self.metric, self.min_valid_fraction)
        if not np.isfinite(cost).any():
            raise MatchError("tercom: no candidate in the search window lies on valid map data")
        j, k = np.unravel_index(np.nanargmin(cost), cost.shape)
        offset = np.array([ox[k], oy[j]])
        surface = cost
        if self.metric in ("cor", "ncor"):
            surface = tercom_cost_surface(problem, ox, oy, "msd", self.min_valid_fraction)
        covariance, ambiguous = self._integrity(problem, surface, ox, oy, (j, k))
        track = problem.indicated + offset
        snr = terrain_snr(problem, track)
        return Fix(
            track=track,
            covariance=covariance,
            cost=float(cost[j, k]),
            evaluations=int(cost.size * np.isfinite(problem.measured).sum()),
            ambiguous=ambiguous or bool(snr < self.min_terrain_snr),
            diagnostics={"offset": offset, "candidates": int(cost.size), "terrain_snr": snr},
        )

    def candidate_offsets(self, problem: MatchProblem) -> tuple[np.ndarray, np.ndarray]:
        """Candidate translations along x and y (metres), a separable square window."""
        grid = problem.grid
        half = (
            self.window_m
            if self.window_m > 0
            else self.window_sigma * float(np.max(problem.sigma_position))
        )
        fx = 2 * np.floor(half / (self.step_cells * grid.dx)) + 1
        fy = 2 * np.floor(half / (self.step_cells * grid.dy)) + 1
        check_allocation(
            cells_bytes(fx, fy, copies=_SURFACE_COPIES),
            f"tercom search window of {fx:.0g} x {fy:.0g} candidates (half-side {half:.3g} m: "
            + (
                f"window_m {self.window_m:g})"
                if self.window_m > 0
                else f"window_sigma {self.window_sigma:g} x the INS prior sigma from ins.*)"
            ),
        )
        nx = int(np.floor(half / (self.step_cells * grid.dx)))
        ny = int(np.floor(half / (self.step_cells * grid.dy)))
        ox = np.arange(-nx, nx + 1) * self.step_cells * grid.dx
        oy = np.arange(-ny, ny + 1) * self.step_cells * grid.dy
        return ox, oy

    def _integrity(self, problem, msd, ox, oy, best) -> tuple[np.ndarray, bool]:
        """Covariance of the offset and the ambiguity flag from an msd/mad surface."""
        weights = _pseudo_likelihood(msd, "mad" if self.metric == "mad" else "msd", problem)
        dx, dy = np.meshgrid(ox - ox[best[1]], oy - oy[best[0]])
        cell = problem.grid.cell_size
        far = np.hypot(dx, dy) > self.exclusion_cells * cell
        mx, my = (weights * dx).sum(), (weights * dy).sum()
        cxx = (weights * (dx - mx) ** 2).sum() + cell**2 / 12
        cyy = (weights * (dy - my) ** 2).sum() + cell**2 / 12
        cxy = (weights * (dx - mx) * (dy - my)).sum()
        covariance = np.array([[cxx, cxy], [cxy, cyy]])
        return covariance, bool(weights[far].sum() > self.ambiguity_mass)


def tercom_cost_surface(
    problem: MatchProblem,
    ox: np.ndarray,
    oy: np.ndarray,
    metric: str = "msd",
    min_valid_fraction: float = 0.9,
) -> np.ndarray:
    """Cost of every translated candidate of the indicated track.

    Parameters
    ----------
    problem : MatchProblem
        Map, indicated track, heading, beam offsets, measurements.
    ox, oy : numpy.ndarray
        Candidate translations along x (east) and y (north), metres.
    metric : str
        ``"msd"``, ``"mad"``, ``"cor"`` or ``"ncor"``; maximised metrics are negated.
    min_valid_fraction : float
        Candidates with fewer valid map look-ups than this share are set to NaN.

    Returns
    -------
    numpy.ndarray
        ``(len(oy), len(ox))`` costs (lower is better), NaN for discarded candidates.
    """
    fx, fy = problem.footprint(problem.indicated)
    measured = problem.measured.reshape(-1)
    keep = np.isfinite(measured) & np.isfinite(fx.reshape(-1))
    if not keep.any():
        raise MatchError("tercom: every measured value is missing")
    grid = problem.grid
    col = (fx.reshape(-1)[keep] - grid.x0) / grid.dx
    row = (fy.reshape(-1)[keep] - grid.y0) / grid.dy
    values = np.ascontiguousarray(grid.values)
    return _cost_kernel(
        values,
        np.ascontiguousarray(col),
        np.ascontiguousarray(row),
        np.ascontiguousarray(measured[keep]),
        np.ascontiguousarray(ox, dtype=float) / grid.dx,
        np.ascontiguousarray(oy, dtype=float) / grid.dy,
        _METRICS[metric],
        float(min_valid_fraction),
    )


_VEC = numba.types.Array(numba.float64, 1, "C")
_KERNEL_SIGNATURE = numba.float64[:, :](
    numba.types.Array(numba.float64, 2, "C", readonly=True),  # the Grid's read-only values
    *(_VEC,) * 5,
    numba.int64,
    numba.float64,
)


# Compiled eagerly (and cached on disk) so that no match call pays for compilation.
@numba.njit(_KERNEL_SIGNATURE, parallel=True, cache=True)
def _cost_kernel(values, col, row, h, ocol, orow, metric, min_valid_fraction):  # pragma: no cover
    ny, nx = values.shape
    n = h.shape[0]
    out = np.full((orow.shape[0], ocol.shape[0]), np.nan)
    hmean = h.mean()
    for j in numba.prange(orow.shape[0]):
        for k in range(ocol.shape[0]):
            acc = 0.0
            s_m = 0.0
            s_mm = 0.0
            s_hm = 0.0
            s_h = 0.0
            s_hh = 0.0
            valid = 0
            for i in range(n):
                c = col[i] + ocol[k]
                r = row[i] + orow[j]
                if c < 0.0 or r < 0.0 or c > nx - 1 or r > ny - 1:
                    continue
                c0 = min(int(c), nx - 2)
                r0 = min(int(r), ny - 2)
                fc = c - c0
                fr = r - r0
                m = (values[r0, c0] * (1 - fc) + values[r0, c0 + 1] * fc) * (1 - fr) + (
                    values[r0 + 1, c0] * (1 - fc) + values[r0 + 1, c0 + 1] * fc
                ) * fr
                if m != m:
                    continue
                valid += 1
                d = h[i] - m
                if metric == 0:
                    acc += d * d
                elif metric == 1:
                    acc += abs(d)
                elif metric == 2:
                    acc -= h[i] * m
                else:
                    hc = h[i] - hmean
                    s_m += m
                    s_mm += m * m
                    s_hm += hc * m
                    s_h += hc
                    s_hh += hc * hc
            if valid < min_valid_fraction * n or valid == 0:
                continue
            if metric == 3:
                var_m = s_mm - s_m * s_m / valid
                denom = np.sqrt(max(var_m, 1e-300) * max(s_hh, 1e-300))
                out[j, k] = -(s_hm - s_h * s_m / valid) / denom
            else:
                out[j, k] = acc / valid
    return out


def _pseudo_likelihood(cost: np.ndarray, metric: str, problem: MatchProblem):
    """Normalised weights ``exp(-L * (cost - min) / scale)`` of an msd or mad surface."""
    samples = int(np.isfinite(problem.measured).sum())
    best = float(np.nanmin(cost))
    if metric == "msd":
        scale = 2.0 * max(problem.noise_std**2, best, 1e-12)
    else:
        scale = max(problem.noise_std / np.sqrt(2.0), best, 1e-12)
    logw = -samples * (np.nan_to_num(cost, nan=np.inf) - best) / scale
    w = np.exp(logw)
    return w / w.sum()
