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
integrity check scores the same window once more with ``msd``. A constant offset between
the readings and the map (a tide, a datum, a gravimeter's bias) moves an ``msd`` fix
without widening its surface, so the covariance of an ``msd``-scored fix weighs two
models by their evidence (:func:`offset_weighed_moments`): no offset, and an offset drawn
from its prior (:func:`geofix.maps.offset.default_offset_std`) and marginalised at
every candidate; the fix stays the ``msd`` minimum, its covariance and ambiguity mass
are the mixture's about the no-offset mean. The INS drift inside the
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
from scipy.special import logsumexp

from geofix._threads import pick, twins
from geofix.errors import ConfigError, MatchError
from geofix.maps import mapread
from geofix.maps.mapread import bilinear_at
from geofix.maps.offset import default_offset_std
from geofix.match._tercom_fft import SUPPORTED, centred_msd, fft_cost, fft_window
from geofix.match._tercom_integrity import surface_moments
from geofix.match._tercom_loop import (
    MARGINAL,
    MODES,
    UNDERFLOW_LOG,
    JointPrune,
    distance_cost,
    exact_costs,
    exact_marginal,
    loop_sums,
    marginal_cost,
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
    offset_std : float or None
        Prior 1-sigma of a constant offset between the readings and the map, map units
        (a tide, a datum, a gravimeter's bias): the covariance and the ambiguity test of an
        ``msd``-scored fix (``msd``, ``cor``, ``ncor``) weigh the fix with and without such
        an offset by their evidence (:func:`offset_weighed_moments`); the fix is
        unchanged. None (default): the map's prior (:func:`geofix.maps.offset.
        default_offset_std`: what the map states, else 5 m + 0.2 % of the depth, 5 mGal,
        20 nT); 0: no offset weighed (the covariance of the ``msd`` surface alone).
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
    offset_std: float | None = None
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
        if self.offset_std is not None and not (
            isinstance(self.offset_std, int | float) and 0 <= self.offset_std < np.inf
        ):
            raise ConfigError(
                f"tercom: offset_std must be a number >= 0 or None, got {self.offset_std!r}"
            )

    def match(self, problem: MatchProblem, rng: np.random.Generator | None = None) -> Fix:
        """Search the window and return the best translation of the indicated track."""
        if self.beams == "nadir":
            problem = problem.nadir()
        ox, oy = self.candidate_offsets(problem)
        margin = self._prune_margin(problem)
        weight = self._offset_weight(problem)
        marginal = None
        if weight is not None and self.metric == "msd":
            cost, marginal, route = offset_surfaces(
                problem, ox, oy, weight, self.min_valid_fraction, self.route, margin
            )
        else:
            cost, route = _surface(
                problem, ox, oy, self.metric, self.min_valid_fraction, self.route, margin
            )
        if not np.isfinite(cost).any():
            raise MatchError("tercom: no candidate in the search window lies on valid map data")
        j, k = np.unravel_index(np.nanargmin(cost), cost.shape)
        offset = np.array([ox[k], oy[j]])
        track = problem.indicated + offset
        effect = self._design_effect(problem, track)
        surface = cost
        if self.metric in ("cor", "ncor"):
            surface, marginal = self._rescored(problem, ox, oy, "msd", margin, effect, weight)
        elif route == "loop" and margin is not None and not pruning_holds(effect, cost.size):
            surface, marginal = self._rescored(problem, ox, oy, self.metric, None, effect, weight)
        own, ambiguous, p_offset = self._integrity(
            problem, surface, ox, oy, (j, k), effect, marginal
        )
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
                "offset_probability": p_offset,
            },
        )

    def _rescored(self, problem, ox, oy, metric, margin, effect, weight=None) -> tuple:
        """The window scored again with ``metric`` for the integrity analysis.

        Pruned with ``margin`` only while the pruned weights stay negligible at the
        residuals' design effect (:func:`pruning_holds`). Returns ``(surface, marginal)``:
        with an offset ``weight`` and ``msd``, the offset-marginalised cost beside it
        (:func:`offset_surfaces`), else None.
        """
        if not pruning_holds(effect, ox.size * oy.size):
            margin = None
        if weight is not None and metric == "msd":
            msd, marginal, _ = offset_surfaces(
                problem, ox, oy, weight, self.min_valid_fraction, self.route, margin
            )
            return msd, marginal
        cost = _surface(problem, ox, oy, metric, self.min_valid_fraction, self.route, margin)
        return cost[0], None

    def _offset_weight(self, problem: MatchProblem) -> float | None:
        """Share of a candidate's squared mean difference an offset takes out, or None.

        ``offset_std^2 / (offset_std^2 + noise^2 / L)`` over the ``L`` valid samples, the
        offset's prior from the setting or the map (:func:`default_offset_std`); None
        where no offset is weighed (``offset_std=0``, or ``mad`` and ``cmsd``, whose
        surfaces are no Gaussian ``msd``, or which removes the offset itself).
        """
        if self.metric in ("mad", "cmsd"):
            return None
        prior = default_offset_std(problem.grid) if self.offset_std is None else self.offset_std
        if prior <= 0:
            return None
        noise_var = _noise_var(problem)
        if not np.isfinite(noise_var):
            return None
        samples = max(int(np.isfinite(problem.measured).sum()), 1)
        return prior**2 / (prior**2 + max(noise_var, 1e-12) / samples)

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

    def _integrity(
        self, problem, msd, ox, oy, best, effect=1.0, marginal=None
    ) -> tuple[np.ndarray, bool, float]:
        """Covariance, ambiguity flag and offset probability from an msd/mad surface.

        The pseudo-likelihood ``exp(-L (cost - min) / scale)`` (Gaussian scale for
        ``msd``, Laplace for ``mad``; ``L`` the valid samples over ``effect``, their
        design effect) is normalised over the window; its weighted spread plus the cell's
        quantisation variance is the covariance, its mass beyond ``exclusion_cells`` from
        the best candidate the ambiguity test. With the offset-marginalised cost beside
        it (``marginal``) the no-offset and the offset model are weighed by their
        evidence (:func:`offset_weighed_moments`); the third value is the offset model's
        probability (0 when none is weighed).
        """
        kind = "mad" if self.metric == "mad" else "msd"
        samples = int(np.isfinite(problem.measured).sum()) / effect
        low = float(np.nanmin(msd))
        factor = samples / _likelihood_scale(kind, problem, low)
        radius = self.exclusion_cells * problem.grid.cell_size
        mx, my, cxx, cyy, cxy, far = _moments(msd, low, factor, ox, oy, best, radius)
        spread = np.array([[cxx, cxy], [cxy, cyy]])
        p_offset = 0.0
        if marginal is not None:
            prior = default_offset_std(problem.grid) if self.offset_std is None else self.offset_std
            model = OffsetModel.at_fix(problem, ox, oy, best, samples, prior, radius)
            spread, far, p_offset = offset_weighed_moments(
                msd, marginal, ox, oy, best, model, (np.array([mx, my]), spread, far)
            )
        covariance = spread + np.eye(2) * problem.grid.cell_size**2 / 12
        return covariance, bool(far > self.ambiguity_mass), p_offset


@dataclass(frozen=True)
class OffsetModel:
    """A constant offset between the readings and the map, as TERCOM weighs it.

    The readings are the map plus white noise of variance ``var``, plus (in the offset
    model) an offset ``b ~ N(0, offset_std^2)``. Marginalising ``b`` at a candidate whose
    differences ``d`` (measured minus map) have mean ``mean d`` leaves the likelihood
    ``exp(-factor [(1 - weight) msd + weight cmsd])`` times :attr:`occam`, with ``factor
    = L / (2 var)``, ``se^2 = var / L`` and ``weight = offset_std^2 / (offset_std^2 +
    se^2)``: the ``msd`` with the offset the candidate asks for taken out, less a penalty
    on its size. The cost's ``weight`` is set before the search from the sensor's noise
    and all valid samples (:meth:`Tercom._offset_weight`), so that one branch-and-bound
    prunes both surfaces; the residuals' variance and their design effect only widen
    ``se``, so that weight is the largest and its penalty on an offset's size at most
    the model's.

    Attributes
    ----------
    samples : float
        Independent samples ``L`` (the valid samples over their design effect).
    var : float
        Residual variance both models share, map units squared.
    offset_std : float
        Prior 1-sigma of the offset, map units (> 0).
    radius : float
        Exclusion radius of the ambiguity test, metres.
    """

    samples: float
    var: float
    offset_std: float
    radius: float

    @classmethod
    def at_fix(cls, problem, ox, oy, best, samples, offset_std, radius) -> OffsetModel:
        """The model with ``var`` the residuals' variance about their mean at the fix.

        Floored at the sensor's noise variance: what both models must explain, taken
        where the ``msd`` put the fix (the best constant offset removed there).
        """
        grid = problem.grid
        j, k = int(best[0]), int(best[1])
        samples_at = _samples(problem)
        # weight 1: the msd less the squared mean difference, the cmsd (one compiled
        # serial read, the same on any number of threads)
        centred = exact_marginal(
            np.ascontiguousarray(grid.values),
            samples_at.col,
            samples_at.row,
            samples_at.h,
            np.array([ox[k] / grid.dx]),
            np.array([oy[j] / grid.dy]),
            1.0,
            0.0,
        )[1, 0]
        var = max(_noise_var(problem), float(np.nan_to_num(centred, nan=0.0)), 1e-12)
        return cls(float(samples), var, float(offset_std), float(radius))

    @property
    def factor(self) -> float:
        """``L / (2 var)``: the pseudo-likelihood's factor on a cost, per map unit squared."""
        return self.samples / (2.0 * self.var)

    @property
    def occam(self) -> float:
        """``log(se / hypot(se, offset_std))``: the price of a free offset in the evidence."""
        se2 = self.var / self.samples
        return 0.5 * float(np.log(se2 / (se2 + self.offset_std**2)))


def offset_weighed_moments(msd, marginal, ox, oy, best, model: OffsetModel, no_offset):
    """The fix's spread and ambiguity mass with and without a constant offset.

    The two models of :class:`OffsetModel` are weighed by their evidence, the sum of
    their likelihoods over the window (the offset model's carries its
    :attr:`OffsetModel.occam`, the price of a free offset): a surface whose ``msd``
    minimum is explained without an offset keeps its own spread; one that needs an offset
    takes the offset model's spread about the no-offset mean, which holds the shift the
    offset makes in the ``msd`` fix.

    Parameters
    ----------
    msd, marginal : numpy.ndarray
        ``(J, K)`` the ``msd`` surface of the fix and the offset-marginalised cost
        (:func:`offset_surfaces`), NaN where no valid candidate, ``+inf`` where
        pruned (a weight that underflows).
    ox, oy : numpy.ndarray
        ``(K,)`` and ``(J,)`` candidate offsets, metres.
    best : tuple of int
        ``(j, k)`` the fix's candidate.
    model : OffsetModel
        Samples, residual variance, the offset's prior and the exclusion radius.
    no_offset : tuple
        ``(mean, spread, far)`` of the no-offset model as the fix computed them: its
        weighted mean offset from the best candidate (metres), its ``(2, 2)`` spread about
        that mean (m^2) and its mass beyond the radius.

    Returns
    -------
    tuple
        ``(spread, far, p_offset)``: the mixture's ``(2, 2)`` second moment about the
        no-offset mean (m^2), its mass beyond the radius, and the offset model's
        probability.
    """
    reference = float(np.nanmin(marginal))
    log_none = _log_evidence(msd, model.factor, reference)
    log_offset = _log_evidence(marginal, model.factor, reference) + model.occam
    p_offset = float(np.exp(-np.logaddexp(0.0, log_none - log_offset)))
    mean0, spread0, far0 = no_offset
    mx, my, cxx, cyy, cxy, far1 = _moments(
        marginal, reference, model.factor, ox, oy, best, model.radius
    )
    shift = np.array([mx, my]) - mean0
    spread1 = np.array([[cxx, cxy], [cxy, cyy]]) + np.outer(shift, shift)
    spread = (1.0 - p_offset) * spread0 + p_offset * spread1
    return spread, (1.0 - p_offset) * far0 + p_offset * far1, p_offset


def offset_surfaces(
    problem: MatchProblem,
    ox,
    oy,
    weight: float,
    min_valid_fraction: float = 0.9,
    route: str = "auto",
    margin=None,
) -> tuple[np.ndarray, np.ndarray, str]:
    """The ``msd`` and the offset-marginalised cost of every candidate, and the route.

    The marginalised cost is ``(1 - weight) msd + weight cmsd`` (:class:`OffsetModel`).
    The loop route computes both in one pass of squared and plain differences, with
    branch-and-bound on both at once when ``margin`` is given
    (:class:`~geofix.match._tercom_loop.JointPrune`: a candidate is ``+inf`` in both only
    when its weight underflows in both); the FFT route, where faster, its ``msd`` and
    ``cmsd`` surfaces; the direct route (any other spacing) the same by direct reads.

    Parameters
    ----------
    problem : MatchProblem
        Map, indicated track, heading, beam offsets, measurements.
    ox, oy : numpy.ndarray
        Candidate translations along x and y, metres.
    weight : float
        Share of the squared mean difference taken out, in ``[0, 1]``.
    min_valid_fraction : float
        Candidates with fewer valid map look-ups than this share are NaN.
    route : str
        As :func:`tercom_cost_surface`.
    margin : callable, optional
        ``margin(best_msd)``, the cost gap beyond which a candidate's weight underflows.

    Returns
    -------
    tuple
        ``(msd, marginal, route)``: two ``(len(oy), len(ox))`` surfaces, map units
        squared, and the route taken.
    """
    samples, values, ocol, orow, kc, kr = _search(problem, ox, oy, route)
    if route == "direct" or kc is None or kr is None:
        if route in ("loop", "fft"):
            raise ConfigError(f"tercom: route {route!r} needs whole-cell, evenly spaced offsets")
        msd = _direct(values, samples, ocol, orow, "msd", min_valid_fraction)
        centred = _direct(values, samples, ocol, orow, "cmsd", min_valid_fraction)
        return msd, (1.0 - weight) * msd + weight * centred, "direct"
    if route in ("auto", "fft"):
        window = fft_window(values.shape, samples.col, samples.row, kc, kr)
        if window is not None and (
            route == "fft" or _fft_is_faster(samples, kc, kr, window, "msd+cmsd")
        ):
            threads = numba.get_num_threads()
            plain = fft_cost(values, window, samples.h, kc, kr, "msd", threads)
            less = fft_cost(values, window, samples.h, kc, kr, "cmsd", threads)
            if plain is not None and less is not None:
                return plain, (1.0 - weight) * plain + weight * less, "fft"
        if route == "fft":
            raise ConfigError("tercom: route 'fft' needs a window on finite map data and not 'mad'")
    need = float(min_valid_fraction) * samples.h.size
    prune = None
    if margin is not None:

        def exact(j, k):
            costs = exact_marginal(
                values, samples.col, samples.row, samples.h, kc[k], kr[j], weight, need
            )
            return np.where(np.isfinite(costs), costs, np.inf)

        prune = JointPrune(_information_order(values, samples), exact, margin, weight)
    sums, count, alive = loop_sums(
        values, samples.col, samples.row, samples.h, kc, kr, MARGINAL, prune
    )
    msd = marginal_cost(sums, count, alive, need, 0.0)
    return msd, marginal_cost(sums, count, alive, need, weight), "loop"


def _log_evidence(cost, factor, reference) -> float:
    """``log sum exp(-factor (cost - reference))`` over the finite candidates."""
    finite = np.isfinite(cost)
    return float(logsumexp(-factor * (cost[finite] - reference))) if finite.any() else -np.inf


def _moments(cost, low, factor, ox, oy, best, radius):
    """:func:`surface_moments` of a surface at the best candidate ``(j, k)``."""
    return surface_moments(
        np.ascontiguousarray(cost, dtype=float),
        low,
        factor,
        np.ascontiguousarray(ox, dtype=float),
        np.ascontiguousarray(oy, dtype=float),
        int(best[0]),
        int(best[1]),
        radius,
    )


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
_FFT_TRANSFORMS = {"msd": 13, "cor": 3, "ncor": 15, "cmsd": 15, "msd+cmsd": 28}


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
    samples, values, ocol, orow, kc, kr = _search(problem, ox, oy, route)
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


def _search(problem: MatchProblem, ox, oy, route: str) -> tuple:
    """The samples, map values, candidate offsets in cells and their whole-cell shifts.

    Returns ``(samples, values, ocol, orow, kc, kr)``; ``kc``/``kr`` None where the
    offsets are not whole, evenly spaced cells. ConfigError for an unknown route.
    """
    if route not in ROUTES:
        raise ConfigError(f"tercom: route must be one of {ROUTES}, got {route!r}")
    grid = problem.grid
    ocol = np.asarray(ox, dtype=float) / grid.dx
    orow = np.asarray(oy, dtype=float) / grid.dy
    values = np.ascontiguousarray(grid.values)
    return _samples(problem), values, ocol, orow, whole_cell_shifts(ocol), whole_cell_shifts(orow)


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
            cost = _at_candidate(exact_costs, values, samples, kc, kr, j, k, mode, need)[0]
            return float(cost) if np.isfinite(cost) else np.inf

        prune = (order, exact, prune_margin)
    sums, count, alive = loop_sums(values, samples.col, samples.row, h, kc, kr, mode, prune)
    if mode in (0, 1):
        return distance_cost(sums[0], count, alive, float(min_valid_fraction) * n)
    cost = _finish(sums, count, n, mode, min_valid_fraction)
    cost[~alive] = np.inf
    return cost


def _at_candidate(kernel, values, samples, kc, kr, j, k, *args):
    """``kernel`` (:func:`exact_costs`, :func:`exact_marginal`) at the one candidate ``(j, k)``."""
    return kernel(values, samples.col, samples.row, samples.h, kc[k : k + 1], kr[j : j + 1], *args)


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
        return 2.0 * max(_noise_var(problem), best, 1e-12)
    return max(problem.noise_std / np.sqrt(2.0), best, 1e-12)


def _noise_var(problem: MatchProblem) -> float:
    """The sensor's noise variance, map units squared (inf beyond the float range)."""
    with np.errstate(over="ignore"):
        return float(np.square(np.float64(problem.noise_std)))
