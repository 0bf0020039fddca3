"""ABC-MHD: gravity matching by an artificial bee colony, screened by mean Hausdorff distance.

Source 003 (Chinese patent CN103487056A, Harbin Engineering University, 2014). Every
pair of consecutive indicated positions ``(p_k, p_k+1)`` gets its own colony; a food
source is a candidate position pair ``(a, b)``, ``a`` near ``p_k`` and ``b`` near
``p_k+1`` (the "two swarms"). All colonies of a track run at once: every phase is one
numpy step over an array ``(pairs, sources, 4)``.

- Search box: ``a`` and ``b`` lie within ``window_sigma`` prior sigmas of their indicated
  positions (per axis), the same 3-sigma window as TERCOM.
- Misfit (reconstruction: the patent's formula was lost in the scan)
  ``f = |g_k - g_map(a)| + |g_k+1 - g_map(b)|`` (mGal; a NaN measurement is skipped, a
  candidate off the map scores ``inf``), fitness ``fit = 1 / (1 + f)``.
- Constraint (reconstruction): ``|(b - a) - v_dvl dt| <= tolerance``, ``v_dvl`` the mean DVL
  velocity of the two samples (``problem.dvl_velocity``), or the INS displacement
  ``p_k+1 - p_k`` without a DVL. A new source that breaks it is rejected.
- Employed bees: source ``i`` moves towards or away from a random other source ``m`` of its
  colony along one random axis (x or y), both points of the pair with the same
  ``phi ~ U(-1, 1)`` (the two swarms step together); greedy selection on ``f``.
- Onlookers: as many as employed bees; each picks a source with probability
  ``P_i = fit_i / sum fit`` and searches around it the same way; per source the best
  onlooker result replaces it if better. Sources not improved for ``limit`` trials are
  abandoned, the worst one per colony and cycle, and a scout draws a new feasible source.
- Screening (reconstruction of how the mean Hausdorff distance is applied): the final food
  sources of a colony whose misfit passes a noise gate are its candidate results. For
  candidate ``(a, b)`` of pair ``k`` the indicated track of the pairs ``k-h .. k+h`` is
  *aligned* by the translation that carries the centroid of ``(p_k, p_k+1)`` onto that of
  ``(a, b)`` (the INS error is nearly a translation over ``2h+2`` samples); the candidate
  track is ``(a, b)`` plus, for every other pair of the window, its candidate closest to
  the aligned indicated points. The candidate with the smallest mean Hausdorff distance
  between its candidate track and the aligned indicated track is the pair's match.
- Each position is matched twice (second point of pair ``k-1``, first of pair ``k``) and
  the two are averaged. The covariance is the spread of the estimated INS error over the
  last ``2h+2`` samples plus the cell's quantisation. Each position is matched locally,
  not by one offset over the leg, so the drift term of the rigid-offset matchers
  (:mod:`geofix.match.drift`) does not apply.
- Simplified model (``full_every > 1``): only every ``full_every``-th pair is matched with
  the full model; the others search, without the DVL constraint, a small box
  (``simplified_radius_cells``) around the indicated positions moved by the offset
  interpolated between the screened full matches.

A gravimeter's first-order lag is undone before matching when the method's own
``lag_s > 0`` (:func:`geofix.sensors.gravimeter.compensate_first_order_lag`). The
problem's declared ``lag_s`` (which the recursive filters undo) is not read, so the
readings are compensated once at most, and ``abc-mhd`` with ``lag_s = 0`` matches the
raw lagged readings (the comparison of the source-003 section).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from geofix.errors import ConfigError, MatchError
from geofix.match._hausdorff import batch_mean_hausdorff
from geofix.measurement import predict_track
from geofix.problem import Fix, MatchProblem, registered_covariance
from geofix.sensors.gravimeter import compensate_first_order_lag


@dataclass(frozen=True)
class AbcMhd:
    """Artificial bee colony over position pairs, mean-Hausdorff screening (source 003).

    The patent gives no parameter values; the defaults are Karaboga's usual ones and
    choices justified here.

    Parameters
    ----------
    colony_size : int
        Bees per colony (half employed, half onlookers): 40, so 20 food sources
        (Karaboga & Basturk 2007).
    cycles : int
        ABC cycles (maximum cycle number) per colony: 100.
    limit : int
        Trials without improvement before a source is abandoned: 0 means Karaboga &
        Akay's rule ``SN * D`` (food sources x 4 coordinates = 80 by default).
    window_sigma : float
        Half-side of each point's search box in prior sigmas (``sigma_position``): 3.
    tolerance_cells : float
        DVL displacement tolerance in map cells (1: a smaller disagreement cannot be
        resolved on the map; it is far above the DVL noise over one interval).
    misfit_gate_sigma : float
        A final source is a candidate result when ``f <= gate * noise_std`` (or it is the
        colony's best): 6, since ``f`` of the true pair sums two absolute noises.
    screen_half_window : int
        ``h``: pairs each side of a pair in its screening window (10 = 21 pairs, 420 s at
        20 s; the INS error changes by well under a 100 m cell over it).
    full_every : int
        Full-model match every this many pairs, simplified model between (1 = all full).
    simplified_radius_cells : float
        Half-side of the simplified model's search box, map cells.
    lag_s : float
        Gravimeter lag time constant to compensate before matching, seconds (0 = none).
    ambiguity_cells : float
        The fix is flagged ambiguous when the median screening distance of the chosen
        candidates exceeds this many cells.

    References
    ----------
    .. [1] Harbin Engineering University (2014). Gravity matching method based on the
       artificial bee colony algorithm and the mean Hausdorff distance. Chinese patent
       CN103487056A.
    .. [2] Karaboga, D. (2005). An idea based on honey bee swarm for numerical
       optimization. Technical report TR06, Erciyes University.
    .. [3] Dubuisson, M.-P., & Jain, A. K. (1994). A modified Hausdorff distance for
       object matching. Proc. 12th International Conference on Pattern Recognition.

    Examples
    --------
    >>> import geofix
    >>> geofix.AbcMhd().name
    'abc-mhd'
    """

    name: ClassVar[str] = "abc-mhd"
    recursive: ClassVar[bool] = False

    colony_size: int = 40
    cycles: int = 100
    limit: int = 0
    window_sigma: float = 3.0
    tolerance_cells: float = 1.0
    misfit_gate_sigma: float = 6.0
    screen_half_window: int = 10
    full_every: int = 1
    simplified_radius_cells: float = 3.0
    lag_s: float = 0.0
    ambiguity_cells: float = 2.0

    def __post_init__(self) -> None:
        if self.colony_size < 4 or self.colony_size % 2:
            raise ConfigError("abc-mhd: colony_size must be an even number >= 4")
        if self.cycles < 1 or self.limit < 0 or self.full_every < 1:
            raise ConfigError("abc-mhd: cycles and full_every must be >= 1, limit >= 0")
        if self.window_sigma <= 0 or self.tolerance_cells <= 0 or self.lag_s < 0:
            raise ConfigError("abc-mhd: window_sigma and tolerance_cells > 0, lag_s >= 0")
        if self.screen_half_window < 0 or self.simplified_radius_cells <= 0:
            raise ConfigError("abc-mhd: bad screen_half_window or simplified_radius_cells")

    @property
    def food_sources(self) -> int:
        """Number of food sources per colony (employed bees), ``SN``."""
        return self.colony_size // 2

    def match(self, problem: MatchProblem, rng: np.random.Generator) -> Fix:
        """Match every consecutive pair, screen, and average each position's two matches."""
        if problem.n < 2:
            raise MatchError("abc-mhd: needs at least two samples")
        measured = self._measured(problem)
        pairs = np.arange(problem.n - 1)
        full = pairs[pairs % self.full_every == 0]
        colony = self._search(problem, measured, full, None, rng)
        chosen = _screen_candidates(problem.indicated, colony, self.screen_half_window)
        if self.full_every > 1:
            colony, chosen = self._simplified(problem, measured, colony, chosen, rng)
        track = average_pair_matches(problem.indicated, colony.pairs, chosen.positions)
        return self._fix(problem, track, colony, chosen)

    # ------------------------------------------------------------------ stages
    def _measured(self, problem: MatchProblem) -> np.ndarray:
        measured = np.asarray(problem.measured, dtype=float)
        if not np.isfinite(measured).any():
            raise MatchError("abc-mhd: every measured value is missing")
        if self.lag_s > 0:
            measured = compensate_first_order_lag(measured, problem.times, self.lag_s)
        return measured

    def _search(self, problem, measured, pairs, centre_offset, rng) -> Colonies:
        """Run the colonies of ``pairs`` (full model when ``centre_offset`` is None)."""
        ind = problem.indicated
        centre = np.concatenate([ind[pairs], ind[pairs + 1]], axis=1)
        cell = problem.grid.cell_size
        if centre_offset is None:
            sig = np.asarray(problem.sigma_position, dtype=float)
            half = self.window_sigma * np.stack([sig[pairs]] * 2 + [sig[pairs + 1]] * 2, 1)
            displacement = pair_displacements(problem)[pairs]
        else:
            centre = centre + np.tile(centre_offset, 2)
            half = np.full(centre.shape, self.simplified_radius_cells * cell)
            displacement = None
        misfit = PairMisfit(problem, measured, pairs)
        colonies = Colonies(pairs=pairs, centre=centre, half=np.maximum(half, cell))
        colonies.run(self, misfit, displacement, self.tolerance_cells * cell, rng)
        gate = self.misfit_gate_sigma * max(problem.noise_std, 1e-9)
        colonies.gate(gate)
        return colonies

    def _simplified(self, problem, measured, colony, chosen, rng):
        """Match the pairs between full matches with the simplified model, then rescreen."""
        pairs = np.arange(problem.n - 1)
        rest = pairs[pairs % self.full_every != 0]
        if rest.size == 0:
            return colony, chosen
        ind = problem.indicated
        offset = 0.5 * (chosen.positions[:, :2] - ind[colony.pairs])
        offset += 0.5 * (chosen.positions[:, 2:] - ind[colony.pairs + 1])
        centre_offset = np.stack(
            [np.interp(rest, colony.pairs, offset[:, a]) for a in range(2)], axis=1
        )
        simple = self._search(problem, measured, rest, centre_offset, rng)
        merged = Colonies.merge(colony, simple)
        return merged, _screen_candidates(ind, merged, self.screen_half_window)

    def _fix(self, problem, track, colony, chosen) -> Fix:
        cell = problem.grid.cell_size
        distance = float(np.median(chosen.distance))
        h = self.screen_half_window
        tail = slice(max(problem.n - 2 * h - 2, 0), problem.n)
        resid = track[tail] - problem.indicated[tail]
        covariance = np.atleast_2d(np.cov(resid.T)) if resid.shape[0] > 2 else np.zeros((2, 2))
        covariance = registered_covariance(problem.grid, covariance + np.eye(2) * cell**2 / 12.0)
        return Fix(
            track=track,
            covariance=covariance,
            cost=distance,
            evaluations=int(colony.evaluations),
            ambiguous=bool(distance > self.ambiguity_cells * cell),
            diagnostics={
                "screen_distance_m": chosen.distance,
                "candidates": colony.candidate_count(),
                "pair_misfit": chosen.misfit,
            },
        )


# ---------------------------------------------------------------------- misfit and geometry
def pair_displacements(problem: MatchProblem) -> np.ndarray:
    """Expected displacement between consecutive samples, metres, ``(n - 1, 2)``.

    The mean DVL velocity of the two samples times the interval when
    ``problem.dvl_velocity`` (``(n, 2)`` m/s) is there, else the INS
    displacement ``indicated[k+1] - indicated[k]``.
    """
    dvl = problem.dvl_velocity
    if dvl is None:
        return np.diff(problem.indicated, axis=0)
    dvl = np.asarray(dvl, dtype=float)
    dt = np.diff(np.asarray(problem.times, dtype=float))[:, None]
    return 0.5 * (dvl[1:] + dvl[:-1]) * dt


def satisfies_displacement(sources, displacement, tolerance_m: float) -> np.ndarray:
    """True where a candidate pair agrees with the expected displacement.

    Parameters
    ----------
    sources : numpy.ndarray
        ``(..., 4)`` candidate pairs ``(ax, ay, bx, by)``, metres.
    displacement : numpy.ndarray
        ``(..., 2)`` expected displacement ``b - a`` (DVL velocity x interval), metres,
        broadcastable with ``sources[..., :2]``.
    tolerance_m : float
        Largest accepted distance between ``b - a`` and ``displacement``, metres.

    Returns
    -------
    numpy.ndarray
        Boolean ``(...)``.
    """
    sources = np.asarray(sources, dtype=float)
    diff = sources[..., 2:] - sources[..., :2] - displacement
    return np.hypot(diff[..., 0], diff[..., 1]) <= tolerance_m


class PairMisfit:
    """``f = |g_k - g_map(a)| + |g_k+1 - g_map(b)|`` for many candidate pairs at once.

    A multibeam-like footprint is averaged over its beams; NaN measurements are skipped; a
    candidate whose map value is missing where a measurement exists scores ``inf``.
    """

    def __init__(self, problem: MatchProblem, measured: np.ndarray, pairs: np.ndarray):
        self.grid = problem.grid
        self.offsets = problem.offsets
        self.heading = np.stack([problem.heading[pairs], problem.heading[pairs + 1]], 1)
        self.measured = np.stack([measured[pairs], measured[pairs + 1]], 1)  # (K, 2, b)
        self.calls = 0

    def __call__(self, sources: np.ndarray) -> np.ndarray:
        """Misfit of ``sources`` ``(K, S, 4)`` metres; returns ``(K, S)`` map units."""
        points = sources.reshape((*sources.shape[:-1], 2, 2))  # (K, S, 2, 2)
        values = predict_track(self.grid, points, self.heading[:, None, :], self.offsets)
        meas = self.measured[:, None]
        have = np.isfinite(meas)
        missing = (have & ~np.isfinite(values)).any(axis=(-1, -2))
        diff = np.where(have, np.abs(values - meas), 0.0)
        beams = np.maximum(have.sum(axis=-1), 1)
        f = (diff.sum(axis=-1) / beams).sum(axis=-1)
        self.calls += sources.shape[0] * sources.shape[1]
        return np.where(missing, np.inf, f)


# ---------------------------------------------------------------------- the colonies
@dataclass
class Colonies:
    """The food sources of one colony per pair, ``(K, SN, 4)``, and their state."""

    pairs: np.ndarray
    centre: np.ndarray
    half: np.ndarray
    sources: np.ndarray | None = None
    misfit: np.ndarray | None = None
    trials: np.ndarray | None = None
    evaluations: int = 0

    def run(
        self,
        cfg: AbcMhd,
        misfit: PairMisfit,
        displacement: np.ndarray | None,
        tolerance: float,
        rng: np.random.Generator,
    ) -> None:
        """Initialise, then employed, onlooker and scout phases for ``cfg.cycles``.

        Fills :attr:`sources`, :attr:`misfit`, :attr:`trials` and :attr:`evaluations`.

        Parameters
        ----------
        cfg : AbcMhd
            Supplies the number of food sources, ``cycles`` and the abandonment ``limit``
            (``0``: four times the number of food sources).
        misfit : PairMisfit
            Misfit of candidate pairs, map units.
        displacement : numpy.ndarray or None
            ``(K, 2)`` expected displacement ``b - a`` per pair, metres; ``None`` leaves
            ``b`` free in its box.
        tolerance : float
            Largest accepted distance between ``b - a`` and ``displacement``, metres
            (candidates beyond it score ``inf``).
        rng : numpy.random.Generator
            Source of the random draws.
        """
        sn = cfg.food_sources
        limit = cfg.limit or sn * 4
        self.sources = self._random_sources(sn, displacement, tolerance, rng)
        self.misfit = misfit(self.sources)
        self.trials = np.zeros(self.misfit.shape, dtype=int)
        for _ in range(cfg.cycles):
            self._employed(misfit, displacement, tolerance, rng)
            self._onlookers(misfit, displacement, tolerance, rng)
            self._scouts(limit, misfit, displacement, tolerance, rng)
        self.evaluations = misfit.calls * 2 * max(misfit.offsets.shape[0], 1)

    def _random_sources(
        self,
        count: int,
        displacement: np.ndarray | None,
        tolerance: float,
        rng: np.random.Generator,
    ) -> np.ndarray:
        """Uniform ``a`` in its box; ``b = a + displacement`` within the tolerance."""
        k = self.centre.shape[0]
        u = rng.uniform(-1.0, 1.0, (k, count, 4))
        sources = self.centre[:, None, :] + u * self.half[:, None, :]
        if displacement is not None:
            r = tolerance * np.sqrt(rng.uniform(0.0, 1.0, (k, count)))
            ang = rng.uniform(0.0, 2.0 * np.pi, (k, count))
            jitter = np.stack([r * np.cos(ang), r * np.sin(ang)], -1)
            sources[..., 2:] = sources[..., :2] + displacement[:, None, :] + jitter * 0.999
        return sources

    def _neighbour_step(self, index: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """New sources around ``sources[k, index]``: one axis, both points, same ``phi``."""
        assert self.sources is not None
        k, sn = index.shape
        rows = np.arange(self.sources.shape[0])[:, None]
        partner = (index + rng.integers(1, self.sources.shape[1], (k, sn))) % self.sources.shape[1]
        base = self.sources[rows, index]
        other = self.sources[rows, partner]
        axis = rng.integers(0, 2, (k, sn))
        phi = rng.uniform(-1.0, 1.0, (k, sn))
        mask = np.zeros(base.shape, dtype=bool)
        for point in (0, 2):
            mask[..., point][axis == 0] = True
            mask[..., point + 1][axis == 1] = True
        new = base + np.where(mask, phi[..., None] * (base - other), 0.0)
        low = self.centre[:, None, :] - self.half[:, None, :]
        return np.clip(new, low, self.centre[:, None, :] + self.half[:, None, :])

    def _evaluate(
        self,
        new: np.ndarray,
        misfit: PairMisfit,
        displacement: np.ndarray | None,
        tolerance: float,
    ) -> np.ndarray:
        f = misfit(new)
        if displacement is not None:
            ok = satisfies_displacement(new, displacement[:, None, :], tolerance)
            f = np.where(ok, f, np.inf)
        return f

    def _employed(
        self,
        misfit: PairMisfit,
        displacement: np.ndarray | None,
        tolerance: float,
        rng: np.random.Generator,
    ) -> None:
        assert self.sources is not None and self.misfit is not None and self.trials is not None
        index = np.broadcast_to(np.arange(self.sources.shape[1]), self.misfit.shape)
        new = self._neighbour_step(index, rng)
        f = self._evaluate(new, misfit, displacement, tolerance)
        better = f < self.misfit
        self.sources = np.where(better[..., None], new, self.sources)
        self.misfit = np.where(better, f, self.misfit)
        self.trials = np.where(better, 0, self.trials + 1)

    def _onlookers(
        self,
        misfit: PairMisfit,
        displacement: np.ndarray | None,
        tolerance: float,
        rng: np.random.Generator,
    ) -> None:
        assert self.sources is not None and self.misfit is not None and self.trials is not None
        fit = 1.0 / (1.0 + self.misfit)  # 0 for an infinite misfit
        total = fit.sum(axis=1, keepdims=True)
        prob = np.where(total > 0, fit / np.where(total > 0, total, 1.0), 1.0 / fit.shape[1])
        cum = np.cumsum(prob, axis=1)
        u = rng.uniform(0.0, 1.0, self.misfit.shape) * cum[:, -1:]
        index = np.minimum((u[:, :, None] > cum[:, None, :]).sum(-1), fit.shape[1] - 1)
        new = self._neighbour_step(index, rng)
        f = self._evaluate(new, misfit, displacement, tolerance)
        rows = np.broadcast_to(np.arange(fit.shape[0])[:, None], index.shape)
        best = np.full(self.misfit.shape, np.inf)
        np.minimum.at(best, (rows, index), f)
        wins = (f == best[rows, index]) & (f < self.misfit[rows, index])
        failed = np.zeros(self.trials.shape, dtype=int)
        np.add.at(failed, (rows, index), ~wins)
        improved = np.zeros(self.misfit.shape, dtype=bool)
        improved[rows[wins], index[wins]] = True
        self.sources[rows[wins], index[wins]] = new[wins]
        self.misfit[rows[wins], index[wins]] = f[wins]
        self.trials = np.where(improved, 0, self.trials + failed)

    def _scouts(
        self,
        limit: int,
        misfit: PairMisfit,
        displacement: np.ndarray | None,
        tolerance: float,
        rng: np.random.Generator,
    ) -> None:
        assert self.sources is not None and self.misfit is not None and self.trials is not None
        worst = np.argmax(self.trials, axis=1)
        rows = np.arange(self.trials.shape[0])
        abandon = self.trials[rows, worst] > limit
        if not abandon.any():
            return
        fresh = self._random_sources(1, displacement, tolerance, rng)[:, 0]
        f = misfit(fresh[:, None, :])[:, 0]
        r, w = rows[abandon], worst[abandon]
        self.sources[r, w] = fresh[abandon]
        self.misfit[r, w] = f[abandon]
        self.trials[r, w] = 0

    # ------------------------------------------------------------------ results
    def gate(self, threshold: float) -> None:
        """Keep as candidate results the sources with ``misfit <= threshold`` (or the best)."""
        assert self.misfit is not None
        best = self.misfit.min(axis=1, keepdims=True)
        keep = np.isfinite(self.misfit) & (self.misfit <= np.maximum(threshold, best))
        self.misfit = np.where(keep, self.misfit, np.inf)

    def candidate_count(self) -> np.ndarray:
        """Number of candidate results of every pair."""
        assert self.misfit is not None
        return np.isfinite(self.misfit).sum(axis=1)

    @staticmethod
    def merge(a: Colonies, b: Colonies) -> Colonies:
        """Two colony sets (pairs disjoint) as one, ordered by pair."""
        assert a.sources is not None and b.sources is not None
        sn = max(a.sources.shape[1], b.sources.shape[1])
        pairs = np.concatenate([a.pairs, b.pairs])
        order = np.argsort(pairs)

        def cat(x, y, fill):
            pad = [
                np.pad(
                    v,
                    [(0, 0), (0, sn - v.shape[1])] + [(0, 0)] * (v.ndim - 2),
                    constant_values=fill,
                )
                for v in (x, y)
            ]
            return np.concatenate(pad)[order]

        return Colonies(
            pairs=pairs[order],
            centre=np.concatenate([a.centre, b.centre])[order],
            half=np.concatenate([a.half, b.half])[order],
            sources=cat(a.sources, b.sources, np.nan),
            misfit=cat(a.misfit, b.misfit, np.inf),
            trials=cat(a.trials, b.trials, 0),
            evaluations=a.evaluations + b.evaluations,
        )


# ---------------------------------------------------------------------- screening
@dataclass(frozen=True)
class _Screened:
    """The chosen candidate of every pair.

    ``positions`` ``(K, 4)``, its screening distance ``distance`` ``(K,)`` metres and its
    misfit ``misfit`` ``(K,)``.
    """

    positions: np.ndarray
    distance: np.ndarray
    misfit: np.ndarray


def _screen_candidates(indicated: np.ndarray, colony: Colonies, half_window: int) -> _Screened:
    """Pick each pair's candidate by the mean Hausdorff distance to the aligned track.

    Parameters
    ----------
    indicated : numpy.ndarray
        ``(n, 2)`` indicated positions, metres.
    colony : Colonies
        Candidate results: ``sources`` ``(K, S, 4)`` metres, ``misfit`` ``(K, S)`` (``inf``
        = not a candidate), ``pairs`` ``(K,)`` sample index of every pair's first point.
    half_window : int
        Neighbouring pairs each side (by position in ``colony.pairs``).

    Returns
    -------
    _Screened
        The chosen pair for each of the ``K`` pairs (the best-misfit source when a pair
        has a single candidate), with its mean Hausdorff distance, metres.
    """
    assert colony.sources is not None and colony.misfit is not None
    src, valid = colony.sources, np.isfinite(colony.misfit)
    k, s = valid.shape
    ref_pair = np.concatenate([indicated[colony.pairs], indicated[colony.pairs + 1]], 1)
    offset = 0.5 * (src[..., :2] - ref_pair[:, None, :2] + src[..., 2:] - ref_pair[:, None, 2:])
    win = np.clip(np.arange(k)[:, None] + np.arange(-half_window, half_window + 1), 0, k - 1)
    # aligned indicated pairs of the window, for every candidate: (K, S, W, 4)
    ref = ref_pair[win][:, None] + np.tile(offset, 2)[:, :, None, :]
    neigh, neigh_ok = src[win], valid[win]  # (K, W, S, 4), (K, W, S)
    gap = np.linalg.norm(
        (neigh[:, None] - ref[:, :, :, None, :]).reshape(k, s, win.shape[1], s, 2, 2), axis=-1
    ).sum(-1)  # (K, S, W, S)
    gap = np.where(neigh_ok[:, None], np.nan_to_num(gap, nan=np.inf), np.inf)
    pick = np.argmin(gap, axis=-1)  # (K, S, W)
    track = np.take_along_axis(neigh[:, None], pick[..., None, None], axis=3)[..., 0, :]
    track = np.where(np.isfinite(np.take_along_axis(gap, pick[..., None], -1)), track, ref)
    centre = half_window
    track[:, :, centre, :] = np.where(valid[..., None], src, ref[:, :, centre, :])
    dist = batch_mean_hausdorff(track.reshape(k, s, -1, 2), ref.reshape(k, s, -1, 2))
    dist = np.where(valid, dist, np.inf)
    best = np.argmin(dist, axis=1)
    rows = np.arange(k)
    if not np.isfinite(dist[rows, best]).all():
        raise MatchError("abc-mhd: a pair has no candidate on valid map data")
    return _Screened(src[rows, best], dist[rows, best], colony.misfit[rows, best])


def average_pair_matches(indicated: np.ndarray, pairs: np.ndarray, chosen: np.ndarray):
    """Average each position's two matches (second of pair ``k-1``, first of pair ``k``).

    Parameters
    ----------
    indicated : numpy.ndarray
        ``(n, 2)`` indicated positions, metres (only the shape is used).
    pairs : numpy.ndarray
        ``(K,)`` first-sample index of every matched pair.
    chosen : numpy.ndarray
        ``(K, 4)`` matched pairs ``(ax, ay, bx, by)``, metres.

    Returns
    -------
    numpy.ndarray
        ``(n, 2)`` track, metres; a position matched by neither pair keeps the indicated
        position moved by the nearest matched offset.
    """
    n = indicated.shape[0]
    total = np.zeros((n, 2))
    count = np.zeros(n)
    np.add.at(total, pairs, chosen[:, :2])
    np.add.at(total, pairs + 1, chosen[:, 2:])
    np.add.at(count, pairs, 1)
    np.add.at(count, pairs + 1, 1)
    have = count > 0
    track = indicated.astype(float).copy()
    track[have] = total[have] / count[have, None]
    if not have.all():
        idx = np.flatnonzero(have)
        offset = track[idx] - indicated[idx]
        missing = np.flatnonzero(~have)
        for axis in range(2):
            track[missing, axis] += np.interp(missing, idx, offset[:, axis])
    return track
