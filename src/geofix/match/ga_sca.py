"""GA-SCA: multibeam matching by a genetic algorithm refined with the sine-cosine algorithm.

Source 000 (Zhang, Zhang, Zhang, J. Chinese Inertial Technology 30(4), 2022). The
matched track is a four-parameter transform of the indicated track,

    p' = p_0 + alpha * R(theta) (p - p_0) + (t_x, t_y),

with ``R`` the counter-clockwise rotation and the pivot ``p_0`` the *first point of the
indicated track* (so ``t_x, t_y`` is the correction of the start, ``alpha`` absorbs a
speed error and ``theta`` a heading error).

Three depth sequences are matched at once: the centre beam and the beams nearest to
``+-Delta d`` across track, ``Delta d = mu1 + mu2 * sigma`` (eq. 6; ``C`` if that is not
larger than the cell size ``C``), ``sigma`` the standard deviation of the map depths over
the search area (the indicated track's bounding box widened by the search box). The
beams are the MatchProblem's own beams nearest to ``+-Delta d`` (no interpolation
between beams: a beam is a measurement, an interpolated one would mix two footprints).
A single-beam problem falls back to one sequence of weight 1.

Costs (lower is better; the source's GA fitness is the reciprocal ``f_GA = 1 / cost``,
and the rank-based tournament selection used here depends only on the order):

- new fitness (eq. 8): ``sum_i w_i sum_j lambda^j |c_ij - c*_ij| / N``,
- plain fitness (Table 4, variants C and D): ``sum_i sum_j |c_ij - c*_ij|``,
- SCA fitness (eq. 9): ``sum_i w_i max_j |c_ij - c*_ij|``,

with ``c`` the map (bilinear) along the transformed track and ``c*`` the measured depth.
Missing measurements are skipped; a candidate whose map look-ups are valid for fewer
than ``min_valid_fraction`` of the measured samples (off the map, on no-data) gets an
infinite cost.

The variants of the source's Table 4 are settings of one matcher: ``variant="A"`` full
method (new fitness + SCA), ``"B"`` GA + new fitness, ``"C"`` GA + SCA (plain fitness),
``"D"`` plain GA with the plain fitness.

What the source leaves out, and what is used instead (all constructor settings): a
real-coded GA with binary tournament selection, blend crossover (BLX-0.25) and Gaussian
mutation, one elite; the SCA (Mirjalili 2016) works in coordinates normalised to its box
(elite at the centre, half-widths ``0.1 eps_x, 0.1 eps_y, 0.2 eps_alpha, 0.2 eps_theta``)
so that ``r3 * P`` is meaningful for the scale ``alpha`` near 1, and is clipped to that
box; its initial population contains the elite; its best (by ``f_SCA``) replaces the
elite and its final population joins the GA population for selection. Stop rule: the
best cost seen has not improved by more than ``tolerance`` (relative) for
``stall_generations`` generations, or ``max_generations`` is reached; ``iterations`` in
the diagnostics is the generation of the last such improvement (the source's
"iterations at convergence"), ``generations`` the number run.

The whole generation loop -- SCA refinement, selection, crossover, mutation, scoring and
the stop rule -- runs in one compiled call per match (:func:`geofix.match._ga_fitness.ga_search`;
each population is scored in one pass of transform, footprints, the shared bilinear read
and the three costs); ``engine="numpy"`` keeps the vectorised numpy formulation (one
look-up of all individuals x samples x sequences, the loop in Python) as the reference.
Both draw the same random numbers in the same order and give the same fix. In both, a
child that is a bit-for-bit copy of a parent (its pair not crossed, none of its genes
mutated: about 8 % of the children) keeps the parent's costs instead of being scored
again; the ``candidates`` diagnostic counts the individuals actually scored.

The fix covariance (our addition) is the Laplace approximation of the translation
(:func:`geofix.match._affine.translation_covariance`) widened to the Cramér–Rao bound of
the matched footprints (:func:`geofix.match.integrity.terrain_integrity`), plus the INS
drift inside the window (:func:`geofix.match.drift.with_leg_drift`; conservative, as the
fitted rotation and scale absorb part of it).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from geofix.errors import ConfigError, MatchError
from geofix.match._affine import (
    adaptive_spacing,
    beam_positions,
    nearest_beams,
    transform_tracks,
    translation_covariance,
    window_std,
)
from geofix.match._ga_fitness import ga_costs, ga_search
from geofix.match.drift import with_leg_drift
from geofix.match.integrity import terrain_integrity
from geofix.problem import Fix, MatchProblem

_VARIANTS = {"A": (True, True), "B": (True, False), "C": (False, True), "D": (False, False)}

_FitnessHead = tuple[np.ndarray, ...]
"""``ga_costs`` arguments before ``params``: values, geometry, indicated, sin and cos of the
heading, pivot, offsets."""
_FitnessTail = tuple[np.ndarray, np.ndarray, np.ndarray, bool, float, int]
"""``ga_costs`` arguments after ``params``: measured, decay, weights, new_fitness,
min_valid_fraction, n_valid."""


@dataclass(frozen=True)
class _Context:
    """Per-problem constants of one match."""

    problem: MatchProblem
    pivot: np.ndarray
    beams: np.ndarray
    weights: np.ndarray
    decay: np.ndarray
    measured: np.ndarray
    valid: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    spacing_m: float
    values: np.ndarray
    geometry: np.ndarray
    indicated: np.ndarray
    sin_heading: np.ndarray
    cos_heading: np.ndarray
    offsets: np.ndarray
    counter: list = field(default_factory=lambda: [0])


@dataclass(frozen=True)
class GaSca:
    """Genetic algorithm with sine-cosine refinement of the elite (source 000).

    Parameters
    ----------
    variant : str
        ``"A"`` full, ``"B"`` GA + new fitness, ``"C"`` GA + SCA, ``"D"`` plain GA.
    population : int
        GA population size (not given by the source). A small population with gentle
        mutation stalls in local minima of a smooth map; the default, with the mutation
        below, is sized to escape them.
    max_generations : int
        Upper bound on GA generations.
    stall_generations : int
        Stop after this many generations without a relative improvement > ``tolerance``.
    tolerance : float
        Relative improvement of the best cost that counts as progress.
    crossover_rate, mutation_rate : float
        Probability of crossing a pair, of mutating a gene.
    mutation_scale : float
        Mutation 1-sigma as a share of the box half-width (0.3 with ``mutation_rate``
        0.2: large jumps keep exploring the box while the elite and SCA refine).
    weights : tuple of float
        ``(w1, w2, w3)`` of the centre, starboard and port sequences; ``w1 > w2, w3``,
        normalised to sum 1 (source: unspecified; 0.5/0.25/0.25 is the simplest choice
        that trusts the centre beam most).
    decay : float
        ``lambda`` of eq. 8, weight ``lambda^j`` of sample ``j = 1..N`` (source:
        unspecified; 0.98 gives the last of 15 samples 74 % of the first's weight).
    mu1 : float
        Constant of ``Delta d``, metres (source: unspecified).
    mu2 : float
        Gain of ``Delta d`` on the depth std, metres per metre (source: unspecified;
        with ``mu1 = mu2 = 2`` a 1 m map with std 1.45 m / 3.32 m gives 4.9 m / 8.6 m).
    window_sigma : float
        Translation half-box ``eps_x = eps_y`` in prior sigmas (largest
        ``sigma_position`` of the problem).
    eps_xy_m : float
        Translation half-box, metres; overrides ``window_sigma`` when > 0.
    eps_scale : float
        Half-box of ``alpha`` around 1 (0.02: a 2 % speed error).
    eps_rotation_deg : float
        Half-box of ``theta``, degrees (2: the heading error TERCOM already fails at).
    sca_population, sca_iterations : int
        SCA population and iterations ``T`` per generation (source: unspecified; 10 and
        5 keep the refinement to about a quarter of a generation's look-ups).
    sca_a : float
        SCA constant ``a`` of ``r1 = a (1 - t / T)`` (Mirjalili's 2).
    min_valid_fraction : float
        Share of valid map look-ups below which a candidate is discarded.
    exclusion_cells : float
        Distance, in cells, beyond which a visited candidate counts as a rival minimum
        (widened to 3 sigma of the fix's covariance when that is larger).
    ambiguity_mass : float
        Relative pseudo-likelihood of the best rival above which the fix is ambiguous.
    min_terrain_snr : float
        The fix is also ambiguous when the map's std over the matched footprints (the
        three sequences) is below this many sensor-noise sigmas: on terrain flatter than
        the noise the pseudo-likelihood of the rivals is overconfident. 0.6, lower than
        TERCOM's 1 because the rival test already covers rough multimodal terrain and this
        is only the backstop for a plain (a threshold of 1 also flags good fixes on gentle
        terrain).
    engine : str
        ``"numba"`` (compiled fitness, the default) or ``"numpy"`` (the vectorised
        reference); both give the same costs up to the order of summation.

    References
    ----------
    .. [1] Zhang, T., Zhang, C., & Zhang, J. (2022). Underwater terrain matching with an
       improved genetic algorithm and the sine-cosine algorithm (multibeam). Journal of
       Chinese Inertial Technology, 30(4).
    .. [2] Mirjalili, S. (2016). SCA: a sine cosine algorithm for solving optimization
       problems. Knowledge-Based Systems, 96, 120-133.

    Examples
    --------
    >>> import geofix
    >>> geofix.parse_method_spec("ga-sca:variant=B").variant
    'B'
    """

    name: ClassVar[str] = "ga-sca"
    recursive: ClassVar[bool] = False

    variant: str = "A"
    population: int = 200
    max_generations: int = 600
    stall_generations: int = 100
    tolerance: float = 1e-4
    crossover_rate: float = 0.8
    mutation_rate: float = 0.2
    mutation_scale: float = 0.3
    weights: tuple = (0.5, 0.25, 0.25)
    decay: float = 0.98
    mu1: float = 2.0
    mu2: float = 2.0
    window_sigma: float = 3.0
    eps_xy_m: float = 0.0
    eps_scale: float = 0.02
    eps_rotation_deg: float = 2.0
    sca_population: int = 10
    sca_iterations: int = 5
    sca_a: float = 2.0
    min_valid_fraction: float = 0.9
    exclusion_cells: float = 10.0
    ambiguity_mass: float = 0.05
    min_terrain_snr: float = 0.6
    engine: str = "numba"

    def __post_init__(self) -> None:
        if self.variant not in _VARIANTS:
            raise ConfigError(f"ga-sca: variant must be one of A, B, C, D, got {self.variant!r}")
        if self.population < 4 or self.max_generations < 1 or self.sca_population < 2:
            raise ConfigError("ga-sca: population >= 4, sca_population >= 2, generations >= 1")
        w = tuple(float(v) for v in self.weights)
        if len(w) != 3 or min(w) < 0 or not (w[0] > w[1] and w[0] > w[2]):
            raise ConfigError(f"ga-sca: weights need three values with w1 > w2, w3; got {w}")
        if not 0 < self.decay <= 1:
            raise ConfigError(f"ga-sca: decay must be in (0, 1], got {self.decay}")
        if self.engine not in ("numba", "numpy"):
            raise ConfigError(f"ga-sca: engine must be 'numba' or 'numpy', got {self.engine!r}")

    @property
    def uses_new_fitness(self) -> bool:
        """True for variants A and B (eq. 8), False for C and D (plain sum)."""
        return _VARIANTS[self.variant][0]

    @property
    def uses_sca(self) -> bool:
        """True for variants A and C."""
        return _VARIANTS[self.variant][1]

    # ------------------------------------------------------------------ main loop
    def match(self, problem: MatchProblem, rng: np.random.Generator) -> Fix:
        """Search the four-parameter transform; return the transformed indicated track."""
        ctx = self._context(problem)
        pop = rng.uniform(ctx.lower, ctx.upper, size=(self.population, 4))
        cost, _, mad = self._evaluate(ctx, pop)
        if self.engine == "numba":
            return self._match_compiled(ctx, pop, cost, mad, rng)
        archive = [(pop, mad)]
        best_x, best_cost = pop[np.argmin(cost)].copy(), float(np.min(cost))
        last_gain, generation = 0, 0
        for generation in range(1, self.max_generations + 1):
            pop, cost, mad = self._generation(ctx, pop, cost, mad, rng, archive)
            k = int(np.argmin(cost))
            if cost[k] < best_cost * (1 - self.tolerance):
                last_gain = generation
            if cost[k] < best_cost:
                best_x, best_cost = pop[k].copy(), float(cost[k])
            if generation - last_gain >= self.stall_generations:
                break
        if not np.isfinite(best_cost):
            raise MatchError("ga-sca: no candidate in the search box lies on valid map data")
        return self._fix(ctx, best_x, best_cost, archive, last_gain, generation)

    def _match_compiled(self, ctx, pop, cost, mad, rng) -> Fix:
        """The generation loop in one compiled call (:func:`ga_search`), same draws."""
        half = _sca_half_widths(ctx)
        ga_settings = (
            int(self.max_generations),
            int(self.stall_generations),
            float(self.tolerance),
            float(self.crossover_rate),
            float(self.mutation_rate),
            float(self.mutation_scale),
        )
        sca_settings = (
            self.uses_sca,
            int(self.sca_population),
            int(self.sca_iterations),
            float(self.sca_a),
        )
        best_x, best_cost, params, mads, last_gain, generations, scored = ga_search(
            rng,
            np.ascontiguousarray(pop, dtype=float),
            cost,
            mad,
            self._fitness_args(ctx),
            (ctx.lower, ctx.upper, half),
            ga_settings,
            sca_settings,
        )
        ctx.counter[0] += int(scored)
        if not np.isfinite(best_cost):
            raise MatchError("ga-sca: no candidate in the search box lies on valid map data")
        archive = [(params, mads)]
        return self._fix(ctx, best_x, float(best_cost), archive, last_gain, generations)

    def _generation(self, ctx, pop, cost, mad, rng, archive):
        """One GA generation (numpy engine): SCA on the elite, selection, crossover, mutation.

        Returns the new population with its GA costs and mean absolute differences; a
        child that copies a pool member bit for bit keeps that member's numbers.
        """
        k = int(np.argmin(cost))
        elite, elite_cost, elite_mad = pop[k].copy(), cost[k], mad[k]
        pool, pool_cost, pool_mad = pop, cost, mad
        if self.uses_sca:
            elite, elite_cost, elite_mad, sca_pop, sca_cost, sca_mad = self._sca_numpy(
                ctx, elite, rng, _sca_half_widths(ctx)
            )
            pool = np.vstack([np.delete(pop, k, axis=0), elite[None], sca_pop])
            pool_cost = np.concatenate([np.delete(cost, k), [elite_cost], sca_cost])
            pool_mad = np.concatenate([np.delete(mad, k), [elite_mad], sca_mad])
        children, source = self._offspring(ctx, pool, pool_cost, rng)
        new_cost, new_mad = pool_cost[source], pool_mad[source]
        fresh = source < 0
        if fresh.any():
            scored = self._evaluate(ctx, children[fresh])
            new_cost[fresh], new_mad[fresh] = scored[0], scored[2]
        archive.append((children, new_mad))
        return (
            np.vstack([elite[None], children]),
            np.concatenate([[elite_cost], new_cost]),
            np.concatenate([[elite_mad], new_mad]),
        )

    # ------------------------------------------------------------------ operators
    def _offspring(self, ctx, pool, pool_cost, rng):
        """``population - 1`` children (tournament, crossover, mutation) and their source.

        ``source`` is, per child, the index in ``pool`` of the parent it copies bit for
        bit (its pair was not crossed and no gene mutated), ``-1`` for a new individual.
        """
        winner = _tournament(pool_cost, 2 * (self.population // 2), rng)
        kids, cross = self._crossover(pool[winner], rng, ctx)
        children, hit = self._mutate(kids, rng, ctx)
        copies = ~np.concatenate([cross, cross]) & ~hit.any(axis=1)
        parent = np.concatenate([winner[0::2], winner[1::2]])
        source = np.where(copies, parent, -1)
        keep = self.population - 1
        return children[:keep], source[:keep]

    def _crossover(self, parents, rng, ctx):
        """Blend crossover (BLX-0.25) of consecutive parent pairs; also which pairs crossed."""
        a, b = parents[0::2], parents[1::2]
        beta = rng.uniform(-0.25, 1.25, size=a.shape)
        cross = rng.random(len(a)) < self.crossover_rate
        beta[~cross] = 1.0
        kids = np.vstack([beta * a + (1 - beta) * b, (1 - beta) * a + beta * b])
        return np.clip(kids, ctx.lower, ctx.upper), cross

    def _mutate(self, kids, rng, ctx):
        """Gaussian mutation of each gene with probability ``mutation_rate``; also the hits."""
        half = 0.5 * (ctx.upper - ctx.lower)
        hit = rng.random(kids.shape) < self.mutation_rate
        step = rng.standard_normal(kids.shape) * self.mutation_scale * half
        return np.clip(kids + hit * step, ctx.lower, ctx.upper), hit

    def _sca_numpy(self, ctx, elite, rng, half):
        """The SCA refinement in numpy (reference of the compiled ``sca_refine``).

        Returns the new elite, its GA cost and mean absolute difference, and the final
        SCA population inside the box with its GA costs and mean absolute differences.
        """
        z = rng.uniform(-1.0, 1.0, size=(self.sca_population, 4))
        z[0] = 0.0
        x = elite + z * half
        cost, sca_cost, mad = self._evaluate(ctx, x)
        best = int(np.argmin(sca_cost))
        p, p_cost, p_ga, p_mad = z[best].copy(), sca_cost[best], cost[best], mad[best]
        for t in range(self.sca_iterations):
            r1 = self.sca_a * (1.0 - t / self.sca_iterations)
            r2 = rng.uniform(0.0, 2 * np.pi, z.shape)
            r3 = rng.uniform(0.0, 2.0, z.shape)
            wave = np.where(rng.random(z.shape) < 0.5, np.sin(r2), np.cos(r2))
            z = np.clip(z + r1 * wave * np.abs(r3 * p - z), -1.0, 1.0)
            x = elite + z * half
            cost, sca_cost, mad = self._evaluate(ctx, x)
            k = int(np.argmin(sca_cost))
            if sca_cost[k] < p_cost:
                p, p_cost, p_ga, p_mad = z[k].copy(), sca_cost[k], cost[k], mad[k]
        inside = np.all((x >= ctx.lower) & (x <= ctx.upper), axis=1)
        new_elite = elite + p * half
        if not np.all((new_elite >= ctx.lower) & (new_elite <= ctx.upper)):
            new_elite = np.clip(new_elite, ctx.lower, ctx.upper)
            clipped = self._evaluate(ctx, new_elite[None])
            p_ga, p_mad = clipped[0][0], clipped[2][0]
        return new_elite, p_ga, p_mad, x[inside], cost[inside], mad[inside]

    # ------------------------------------------------------------------ costs
    def _evaluate(self, ctx: _Context, params: np.ndarray):
        """GA cost, SCA cost and mean absolute difference of every individual."""
        if self.engine == "numpy":
            return self._evaluate_numpy(ctx, params)
        ctx.counter[0] += params.shape[0]
        head, tail = self._fitness_args(ctx)
        return ga_costs(*head, np.ascontiguousarray(params, dtype=float), *tail)  # type: ignore[call-arg]

    def _fitness_args(self, ctx: _Context) -> tuple[_FitnessHead, _FitnessTail]:
        """Arguments of :func:`ga_costs` before and after ``params``."""
        head = (
            ctx.values,
            ctx.geometry,
            ctx.indicated,
            ctx.sin_heading,
            ctx.cos_heading,
            ctx.pivot,
            ctx.offsets,
        )
        tail = (
            ctx.measured,
            ctx.decay,
            ctx.weights,
            self.uses_new_fitness,
            float(self.min_valid_fraction),
            int(ctx.valid.sum()),
        )
        return head, tail

    def _evaluate_numpy(self, ctx: _Context, params: np.ndarray):
        """GA cost, SCA cost and mean absolute difference of every individual (numpy).

        One bilinear look-up for all individuals x samples x sequences.
        """
        problem = ctx.problem
        tracks = transform_tracks(problem.indicated, params, ctx.pivot)
        x, y = beam_positions(problem, tracks, params[:, 3], ctx.beams)
        diff = np.abs(problem.grid.sample(x, y) - ctx.measured)  # (P, n, s)
        ctx.counter[0] += diff.shape[0]
        ok = np.isfinite(diff)
        d = np.where(ok, diff, 0.0)
        count = ok.sum(axis=1)  # (P, s)
        share = ok.sum(axis=(1, 2)) / ctx.valid.sum()
        with np.errstate(invalid="ignore", divide="ignore"):
            if self.uses_new_fitness:
                seq = (d * ctx.decay[None, :, None]).sum(axis=1) / count
                ga = (seq * ctx.weights).sum(axis=1)
            else:
                ga = d.sum(axis=(1, 2)) * ctx.valid.sum() / count.sum(axis=1)
            sca = (d.max(axis=1) * ctx.weights).sum(axis=1)
            mad = d.sum(axis=(1, 2)) / count.sum(axis=1)
        bad = (share < self.min_valid_fraction) | (count == 0).any(axis=1)
        inf = np.inf
        return np.where(bad, inf, ga), np.where(bad, inf, sca), np.where(bad, inf, mad)

    # ------------------------------------------------------------------ set-up, result
    def _context(self, problem: MatchProblem) -> _Context:
        """Search box, sequences, weights and decay for one problem."""
        if problem.n < 2:
            raise MatchError("ga-sca: need at least two samples")
        grid = problem.grid
        eps = (
            self.eps_xy_m
            if self.eps_xy_m > 0
            else self.window_sigma * float(np.max(problem.sigma_position))
        )
        eps = max(eps, problem.grid.cell_size)
        eps_rot = np.radians(self.eps_rotation_deg)
        lower = np.array([-eps, -eps, 1.0 - self.eps_scale, -eps_rot])
        upper = np.array([eps, eps, 1.0 + self.eps_scale, eps_rot])
        spacing = adaptive_spacing(
            window_std(problem, eps), problem.grid.cell_size, self.mu1, self.mu2
        )
        beams = nearest_beams(problem.offsets, spacing)
        w = np.asarray(self.weights, float)[: len(beams)]
        measured = np.ascontiguousarray(problem.measured[:, beams], dtype=float)
        valid = np.isfinite(measured)
        if valid.sum() < 2:
            raise MatchError("ga-sca: fewer than two valid measurements")
        return _Context(
            problem=problem,
            pivot=problem.indicated[0].astype(float),
            beams=beams,
            weights=w / w.sum(),
            decay=self.decay ** np.arange(1, problem.n + 1),
            measured=measured,
            valid=valid,
            lower=lower,
            upper=upper,
            spacing_m=spacing,
            values=np.ascontiguousarray(problem.grid.values),
            geometry=np.array([grid.x0, grid.y0, grid.dx, grid.dy], dtype=float),
            indicated=np.ascontiguousarray(problem.indicated, dtype=float),
            sin_heading=np.sin(np.asarray(problem.heading, dtype=float)),
            cos_heading=np.cos(np.asarray(problem.heading, dtype=float)),
            offsets=np.ascontiguousarray(problem.offsets[beams], dtype=float),
        )

    def _fix(self, ctx, best_x, best_cost, archive, iterations, generations) -> Fix:
        problem = ctx.problem
        track = transform_tracks(problem.indicated, best_x[None], ctx.pivot)[0]
        heading = problem.heading - best_x[3]
        own = translation_covariance(problem, track, heading, ctx.beams)
        check = terrain_integrity(problem, track, own, self.min_terrain_snr, heading, ctx.beams)
        radius = self.exclusion_cells * problem.grid.cell_size
        radius = max(radius, 3.0 * float(np.sqrt(np.linalg.eigvalsh(check.covariance)[-1])))
        ambiguous = check.flat or self._ambiguous(ctx, best_x, archive, radius)
        covariance, drift = with_leg_drift(problem, check.covariance, track, heading, ctx.beams)
        return Fix(
            track=track,
            covariance=covariance,
            cost=best_cost,
            evaluations=int(ctx.counter[0] * ctx.valid.sum()),
            ambiguous=ambiguous,
            diagnostics={
                "iterations": int(iterations),
                "generations": int(generations),
                "candidates": int(ctx.counter[0]),
                "params": {
                    "t_x": float(best_x[0]),
                    "t_y": float(best_x[1]),
                    "alpha": float(best_x[2]),
                    "theta_rad": float(best_x[3]),
                },
                "pivot": ctx.pivot.copy(),
                "spacing_m": ctx.spacing_m,
                "beams": ctx.beams.tolist(),
                "variant": self.variant,
                "terrain_snr": check.snr,
                "drift_covariance": drift,
            },
        )

    def _ambiguous(self, ctx, best_x, archive, radius: float) -> bool:
        """A visited candidate beyond ``radius`` metres scores nearly as well as the fix.

        "Nearly" is judged with a Laplace pseudo-likelihood of the mean absolute
        difference: the rival is within ``ambiguity_mass`` of the fix's likelihood.
        """
        params = np.vstack([a[0] for a in archive])
        mad = np.concatenate([a[1] for a in archive])
        ends = transform_tracks(ctx.problem.indicated[-1:], params, ctx.pivot)[:, 0]
        best_end = transform_tracks(ctx.problem.indicated[-1:], best_x[None], ctx.pivot)[0, 0]
        far = np.hypot(*(ends - best_end).T) > radius
        near_mad = mad[~far]
        if not far.any() or not np.isfinite(mad[far]).any() or not near_mad.size:
            return False
        best_mad = float(np.nanmin(near_mad))
        scale = max(ctx.problem.noise_std * np.sqrt(2 / np.pi), best_mad, 1e-9)
        gap = ctx.valid.sum() * (float(np.nanmin(mad[far])) - best_mad) / scale
        return bool(gap < np.log(1.0 / self.ambiguity_mass))


def _sca_half_widths(ctx: _Context) -> np.ndarray:
    """``(4,)`` half-widths of the SCA box around the elite (0.1 / 0.2 of the search box)."""
    return 0.5 * (ctx.upper - ctx.lower) * np.array([0.1, 0.1, 0.2, 0.2])


def _tournament(cost: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """Indices of ``count`` winners of binary tournaments (lower cost wins)."""
    a = rng.integers(0, len(cost), count)
    b = rng.integers(0, len(cost), count)
    return np.where(cost[a] <= cost[b], a, b)
