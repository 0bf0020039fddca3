"""TERCOM: terrain contour matching by exhaustive search over rigid translations.

The indicated track is translated, with its shape kept, to every candidate offset of a
square window centred on the indicated position; the map is read (bilinear) along every
candidate and scored against the measured sequence; the best candidate is the fix
(Baker and Clem, "Terrain contour matching (TERCOM) primer", ASD-TR-77-61, 1977).
Scores, over the ``L`` valid samples (all beams of all points):

- ``msd`` -- mean squared difference (minimised; the usual default),
- ``mad`` -- mean absolute difference (minimised),
- ``cor`` -- mean product ``h_r * h_m`` (maximised; stored as its negative),
- ``ncor`` -- normalised cross-correlation (maximised; an extension, insensitive to a
  constant field offset such as a tide or gravimeter bias, and to the field's scale),
- ``cmsd`` -- centred mean squared difference, the ``msd`` of the differences less their
  mean (minimised; an extension: the best constant offset between the measurements and
  the map is removed at each candidate, the field's scale kept).

Integrity: the cost surface is turned into a pseudo-likelihood (Gaussian for ``msd`` and
``cmsd``, Laplace for ``mad``, with the sensor noise as scale) whose mass-weighted spread is the
fix covariance; the fix is *ambiguous* when more than ``ambiguity_mass`` of that mass lies
farther than ``exclusion_cells`` from the best candidate (a second minimum nearly as good
as the first, far from it). The samples count as many as the residuals at the fix show
independent (``L`` over their design effect, :func:`~geofix.match.integrity.
residual_design_effect`: a map error shared by a swath's beams or persisting along the
track), so a correlated map error widens the covariance instead of making a confident
wrong fix. For ``cor``/``ncor``, whose values are no distances, the
integrity check scores the same window once more with ``msd``. The INS drift inside the
window, which one rigid offset cannot follow, is added to that covariance
(:func:`geofix.match.drift.with_leg_drift`: the error of the last sample against the
information-weighted mean error the offset fits). The fix is also flagged
when the terrain along it is too flat to tell: the standard deviation of the map over the
matched footprints is below ``min_terrain_snr`` times the sensor noise (a surface whose
relief drowns in the noise, such as a flat sediment plain, makes the pseudo-likelihood
overconfident: the small INS drift inside the window then picks the minimum).

Computation (:func:`tercom_cost_surface`, all routes give the same surface to rounding):
with whole-cell candidate spacing the ``loop`` route keeps each sample's four bilinear
weights fixed and sweeps contiguous map rows (``msd``/``mad`` with branch-and-bound on
samples ordered by map gradient), the ``fft`` route correlates the map with sparse
kernels built from the track (``msd``, ``cor``, ``ncor``, ``cmsd``; not ``mad``); any other spacing
takes the ``direct`` route. ``route="auto"`` picks the cheaper of the first two by a cost
model of reads against transform sizes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numba
import numpy as np

from geofix._threads import pick, twins
from geofix.errors import ConfigError, MatchError
from geofix.maps import mapread
from geofix.maps.mapread import bilinear_at
from geofix.match._tercom_fft import SUPPORTED, centred_msd, fft_cost, fft_window
from geofix.match._tercom_integrity import surface_moments
from geofix.match._tercom_loop import (
    MODES,
    UNDERFLOW_LOG,
    distance_cost,
    exact_costs,
    loop_sums,
    whole_cell_shifts,
)
from geofix.match.drift import with_leg_drift
from geofix.match.integrity import residual_design_effect, terrain_snr
from geofix.measurement import predict_track
from geofix.memory import cells_bytes, check_allocation
from geofix.problem import Fix, MatchProblem

_METRICS = {"msd": 0, "mad": 1, "cor": 2, "ncor": 3, "cmsd": 4}
# Float arrays of the cost surface's size alive at once: two surfaces (cor/ncor score
# again with msd), the pseudo-likelihood, offset grids, distances and products.
_SURFACE_COPIES = 12


@dataclass(frozen=True)
class Tercom:
    """TERCOM: exhaustive search over rigid translations of the track (MSD, MAD, COR).

    Parameters
    ----------
    metric : str
        ``"msd"`` (default), ``"mad"``, ``"cor"``, ``"ncor"`` or ``"cmsd"``. ``cmsd`` is
        ``msd`` with the mean difference removed at each candidate: a constant offset of
        the field (a tide, a gravimeter's bias) does not move the fix.
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

    correlated_residuals : bool
        Count the samples of the pseudo-likelihood as the residuals at the fix show them:
        ``L`` divided by their design effect (:func:`~geofix.match.integrity.
        residual_design_effect`: a map error shared by a swath's beams or persisting
        along the track makes fewer independent samples than values), so the covariance
        and the ambiguity test widen where the residuals are correlated; the fix is
        unchanged (default True; False counts every value as independent). Where the
        design effect is large enough that the branch-and-bound's pruned candidates could
        carry weight, the window is scored again without it.
    route : str
        How the cost surface is computed (:func:`tercom_cost_surface`): ``"auto"`` (the
        faster of ``"loop"`` and ``"fft"`` where they apply, else ``"direct"``) or one of
        them. On the loop route the ``msd``/``mad`` surfaces use branch-and-bound, which
        leaves the fix and its integrity analysis unchanged.

    References
    ----------
    .. [1] Baker, W. R., & Clem, R. W. (1977). Terrain contour matching (TERCOM) primer.
       ASD-TR-77-61, Aeronautical Systems Division, Wright-Patterson AFB.
    .. [2] Golden, J. P. (1980). Terrain contour matching (TERCOM): a cruise missile
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
    correlated_residuals: bool = True
    route: str = "auto"

    def __post_init__(self) -> None:
        if self.metric not in _METRICS:
            raise ConfigError(
                f"tercom: metric must be one of {sorted(_METRICS)}, got {self.metric!r}"
            )
        if self.step_cells <= 0 or self.window_sigma <= 0:
            raise ConfigError("tercom: step_cells and window_sigma must be positive")
        if self.beams not in ("all", "nadir"):
            raise ConfigError(f"tercom: beams must be 'all' or 'nadir', got {self.beams!r}")
        if self.route not in ROUTES:
            raise ConfigError(f"tercom: route must be one of {ROUTES}, got {self.route!r}")

    def match(self, problem: MatchProblem, rng: np.random.Generator | None = None) -> Fix:
        """Search the window and return the best translation of the indicated track."""
        if self.beams == "nadir":
            problem = problem.nadir()
        ox, oy = self.candidate_offsets(problem)
        margin = self._prune_margin(problem)
        cost, route = _surface(
            problem, ox, oy, self.metric, self.min_valid_fraction, self.route, margin
        )
        if not np.isfinite(cost).any():
            raise MatchError("tercom: no candidate in the search window lies on valid map data")
        j, k = np.unravel_index(np.nanargmin(cost), cost.shape)
        offset = np.array([ox[k], oy[j]])
        track = problem.indicated + offset
        effect = self._design_effect(problem, track)
        if self.metric in ("cor", "ncor"):
            surface = self._rescored(problem, ox, oy, "msd", margin, effect)
        elif route == "loop" and margin is not None and not pruning_holds(effect, cost.size):
            surface = self._rescored(problem, ox, oy, self.metric, None, effect)
        else:
            surface = cost
        own, ambiguous = self._integrity(problem, surface, ox, oy, (j, k), effect)
        snr = terrain_snr(problem, track)
        covariance, drift = with_leg_drift(problem, own, track)
        return Fix(
            track=track,
            covariance=covariance,
            cost=float(cost[j, k]),
            evaluations=int(cost.size * np.isfinite(problem.measured).sum()),
            ambiguous=ambiguous or bool(snr < self.min_terrain_snr),
            diagnostics={
                "offset": offset,
                "candidates": int(cost.size),
                "terrain_snr": snr,
                "route": route,
                "drift_covariance": drift,
                "design_effect": effect,
            },
        )

    def _rescored(self, problem, ox, oy, metric, margin, effect) -> np.ndarray:
        """The window scored again with ``metric`` for the integrity analysis.

        Pruned with ``margin`` only while the pruned weights stay negligible at the
        residuals' design effect (:func:`pruning_holds`).
        """
        if not pruning_holds(effect, ox.size * oy.size):
            margin = None
        return _surface(problem, ox, oy, metric, self.min_valid_fraction, self.route, margin)[0]

    def _design_effect(self, problem: MatchProblem, track: np.ndarray) -> float:
        """The residuals' design effect at the fix (1 unless ``correlated_residuals``)."""
        if not self.correlated_residuals:
            return 1.0
        mapped = predict_track(problem.grid, track, problem.heading, problem.offsets)
        return residual_design_effect(problem.measured - mapped)

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

    def _prune_margin(self, problem: MatchProblem):
        """Cost gap beyond which a candidate's pseudo-likelihood weight is exactly zero.

        The weight is ``exp(-L (cost - best) / scale)`` (:meth:`_integrity`);
        with ``scale`` evaluated at an upper bound of the best cost the gap is
        conservative, so pruning such candidates changes neither fix nor integrity.
        """
        samples = int(np.isfinite(problem.measured).sum())
        kind = "mad" if self.metric == "mad" else "msd"
        return lambda best: UNDERFLOW_LOG * _likelihood_scale(kind, problem, best) / samples

    def _integrity(self, problem, msd, ox, oy, best, effect=1.0) -> tuple[np.ndarray, bool]:
        """Covariance of the offset and the ambiguity flag from an msd/mad surface.

        The pseudo-likelihood ``exp(-L (cost - min) / scale)`` (Gaussian scale for
        ``msd``, Laplace for ``mad``; ``L`` the valid samples over ``effect``, their
        design effect) is normalised over the window; its weighted spread plus the cell's
        quantisation variance is the covariance, its mass beyond ``exclusion_cells`` from
        the best candidate the ambiguity test.
        """
        kind = "mad" if self.metric == "mad" else "msd"
        samples = int(np.isfinite(problem.measured).sum()) / effect
        low = float(np.nanmin(msd))
        factor = samples / _likelihood_scale(kind, problem, low)
        cell = problem.grid.cell_size
        _, _, cxx, cyy, cxy, far = surface_moments(
            np.ascontiguousarray(msd, dtype=float),
            low,
            factor,
            np.ascontiguousarray(ox, dtype=float),
            np.ascontiguousarray(oy, dtype=float),
            int(best[0]),
            int(best[1]),
            self.exclusion_cells * cell,
        )
        quantisation = cell**2 / 12
        covariance = np.array([[cxx + quantisation, cxy], [cxy, cyy + quantisation]])
        return covariance, bool(far > self.ambiguity_mass)


ROUTES = ("auto", "loop", "fft", "direct")

#: The pruned candidates' total weight against the best's, at most (:func:`pruning_holds`).
PRUNED_MASS = 1e-12


def pruning_holds(effect: float, candidates: int) -> bool:
    """Whether a surface pruned for independent samples serves a design effect.

    Branch-and-bound drops a candidate whose weight with all ``L`` samples independent
    is ``exp(-746)`` or less (:data:`~geofix.match._tercom_loop.UNDERFLOW_LOG`); counted
    as ``L / effect`` samples its weight is at most ``exp(-746 / effect)``. The pruning
    holds while ``candidates`` such weights sum to at most :data:`PRUNED_MASS` of the
    best's.
    """
    return candidates * np.exp(-UNDERFLOW_LOG / max(effect, 1.0)) <= PRUNED_MASS


# Rough per-operation costs on one core (seconds), measured by benchmarks/bench_tercom.py,
# used only to pick a route: the loop per sample x candidate, the FFT per transform point
# and log2 of the transform size.
_LOOP_S_PER_READ = 0.5e-9
_FFT_S_PER_POINT_LOG = 1.0e-9
_FFT_TRANSFORMS = {"msd": 13, "cor": 3, "ncor": 15, "cmsd": 15}


@dataclass(frozen=True)
class _Samples:
    """The kept samples of a problem in fractional map cells, and their measurements."""

    col: np.ndarray
    row: np.ndarray
    h: np.ndarray


def _samples(problem: MatchProblem) -> _Samples:
    fx, fy = problem.footprint(problem.indicated)
    measured = problem.measured.reshape(-1)
    keep = np.isfinite(measured) & np.isfinite(fx.reshape(-1)) & np.isfinite(fy.reshape(-1))
    if not keep.any():
        raise MatchError("tercom: every measured value is missing")
    grid = problem.grid
    col = (fx.reshape(-1)[keep] - grid.x0) / grid.dx
    row = (fy.reshape(-1)[keep] - grid.y0) / grid.dy
    return _Samples(
        np.ascontiguousarray(col), np.ascontiguousarray(row), np.ascontiguousarray(measured[keep])
    )


def tercom_cost_surface(
    problem: MatchProblem,
    ox: np.ndarray,
    oy: np.ndarray,
    metric: str = "msd",
    min_valid_fraction: float = 0.9,
    route: str = "auto",
    prune_margin=None,
) -> np.ndarray:
    """Cost of every translated candidate of the indicated track.

    Parameters
    ----------
    problem : MatchProblem
        Map, indicated track, heading, beam offsets, measurements.
    ox, oy : numpy.ndarray
        Candidate translations along x (east) and y (north), metres, increasing and
        evenly spaced.
    metric : str
        ``"msd"``, ``"mad"``, ``"cor"``, ``"ncor"`` or ``"cmsd"``; maximised metrics are
        negated.
    min_valid_fraction : float
        Candidates with fewer valid map look-ups than this share are set to NaN.
    route : str
        ``"loop"`` (compiled loop with per-sample weights, whole-cell shifts:
        :mod:`geofix.match._tercom_loop`), ``"fft"`` (FFT correlation, whole-cell shifts,
        window on finite map data, not ``mad``: :mod:`geofix.match._tercom_fft`),
        ``"direct"`` (one bilinear read per sample and candidate, any shifts) or
        ``"auto"``: the fastest applicable by a cost model of the first two.
    prune_margin : callable, optional
        ``margin(best_cost)`` for branch-and-bound (``msd``/``mad`` on the loop route):
        candidates proven costlier than the best by more than the margin come out
        ``+inf`` instead of their cost.

    Returns
    -------
    numpy.ndarray
        ``(len(oy), len(ox))`` costs (lower is better), NaN for discarded candidates.

    Raises
    ------
    ConfigError
        An unknown route, or one that does not apply to the candidates or metric.
    """
    return _surface(problem, ox, oy, metric, min_valid_fraction, route, prune_margin)[0]


def _surface(problem, ox, oy, metric, min_valid_fraction, route, prune_margin):
    """Cost surface and the route that computed it."""
    if route not in ROUTES:
        raise ConfigError(f"tercom: route must be one of {ROUTES}, got {route!r}")
    samples = _samples(problem)
    grid = problem.grid
    values = np.ascontiguousarray(grid.values)
    ocol = np.asarray(ox, dtype=float) / grid.dx
    orow = np.asarray(oy, dtype=float) / grid.dy
    kc, kr = whole_cell_shifts(ocol), whole_cell_shifts(orow)
    whole = kc is not None and kr is not None
    if route in ("loop", "fft") and not whole:
        raise ConfigError(f"tercom: route {route!r} needs whole-cell, evenly spaced offsets")
    if route == "direct" or not whole:
        return _direct(values, samples, ocol, orow, metric, min_valid_fraction), "direct"
    if route in ("auto", "fft") and metric in SUPPORTED:
        window = fft_window(values.shape, samples.col, samples.row, kc, kr)
        if window is not None and (
            route == "fft" or _fft_is_faster(samples, kc, kr, window, metric)
        ):
            cost = fft_cost(values, window, samples.h, kc, kr, metric, numba.get_num_threads())
            if cost is not None:
                return cost, "fft"
    if route == "fft":
        raise ConfigError("tercom: route 'fft' needs a window on finite map data and not 'mad'")
    return _loop(values, samples, kc, kr, metric, min_valid_fraction, prune_margin), "loop"


def _fft_is_faster(samples, kc, kr, window, metric) -> bool:
    """Cost model: the loop's reads against the FFT's transforms of the window."""
    r_lo, r_hi, c_lo, c_hi = window[:4]
    points = float((r_hi - r_lo) * (c_hi - c_lo))
    fft_s = _FFT_TRANSFORMS[metric] * points * np.log2(points) * _FFT_S_PER_POINT_LOG
    loop_s = samples.h.size * kc.size * kr.size * _LOOP_S_PER_READ
    return fft_s < loop_s


def _loop(values, samples, kc, kr, metric, min_valid_fraction, prune_margin) -> np.ndarray:
    mode = MODES[metric]
    n = samples.h.size
    h = samples.h - samples.h.mean() if metric in ("ncor", "cmsd") else samples.h
    prune = None
    if prune_margin is not None and metric in ("msd", "mad"):
        order = _information_order(values, samples)

        need = float(min_valid_fraction) * n

        def exact(j, k):
            cost = exact_costs(
                values,
                samples.col,
                samples.row,
                samples.h,
                kc[k : k + 1],
                kr[j : j + 1],
                mode,
                need,
            )[0]
            return float(cost) if np.isfinite(cost) else np.inf

        prune = (order, exact, prune_margin)
    sums, count, alive = loop_sums(values, samples.col, samples.row, h, kc, kr, mode, prune)
    if mode in (0, 1):
        return distance_cost(sums[0], count, alive, float(min_valid_fraction) * n)
    cost = _finish(sums, count, n, mode, min_valid_fraction)
    cost[~alive] = np.inf
    return cost


def _information_order(values, samples) -> np.ndarray:
    """Samples by decreasing squared map gradient at the indicated footprint."""
    _, gx, gy = mapread.gradient_xy(values, 0.0, 0.0, 1.0, 1.0, samples.col, samples.row)
    return np.argsort(-np.nan_to_num(gx * gx + gy * gy, nan=0.0), kind="stable")


def _finish(sums, count, n, mode, min_valid_fraction) -> np.ndarray:
    """Cost from the loop's sums; NaN where too few samples were valid."""
    valid = count.astype(float)
    bad = (count < min_valid_fraction * n) | (count == 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        if mode in (0, 1):
            cost = sums[0] / valid
        elif mode == 2:
            cost = -sums[0] / valid
        elif mode == 3:
            s_m, s_mm, s_hm, s_h, s_hh = sums
            var_m = s_mm - s_m * s_m / valid
            denom = np.sqrt(np.maximum(var_m, 1e-300) * np.maximum(s_hh, 1e-300))
            cost = -(s_hm - s_h * s_m / valid) / denom
        else:
            s_m, s_mm, s_hm, s_h, s_hh = sums
            cost = centred_msd(
                s_hh - s_h * s_h / valid,
                s_hm - s_h * s_m / valid,
                s_mm - s_m * s_m / valid,
                valid,
            )
    cost[bad] = np.nan
    return cost


def _direct(values, samples, ocol, orow, metric, min_valid_fraction) -> np.ndarray:
    return pick(_COST_KERNEL)(
        values,
        samples.col,
        samples.row,
        samples.h,
        np.ascontiguousarray(ocol, dtype=float),
        np.ascontiguousarray(orow, dtype=float),
        _METRICS[metric],
        float(min_valid_fraction),
    )


def _cost_kernel(values, col, row, h, ocol, orow, metric, min_valid_fraction):  # pragma: no cover
    """The direct route: one compiled bilinear read per sample and candidate."""
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
                m = bilinear_at(values, col[i] + ocol[k], row[i] + orow[j])
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
            elif metric == 4:
                out[j, k] = centred_msd(
                    s_hh - s_h * s_h / valid,
                    s_hm - s_h * s_m / valid,
                    s_mm - s_m * s_m / valid,
                    float(valid),
                )
            else:
                out[j, k] = acc / valid
    return out


_COST_KERNEL = twins(_cost_kernel, cache=True)
"""``_cost_kernel`` with numba's thread pool and without (:mod:`geofix._threads`)."""


def _likelihood_scale(metric: str, problem: MatchProblem, best: float) -> float:
    """Scale of the pseudo-likelihood: Gaussian (``msd``) or Laplace (``mad``)."""
    if metric == "msd":
        return 2.0 * max(problem.noise_std**2, best, 1e-12)
    return max(problem.noise_std / np.sqrt(2.0), best, 1e-12)
