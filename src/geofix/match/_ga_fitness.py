"""Compiled GA-SCA fitness: transform, footprint, map read and the three costs in one pass.

For each individual ``(t_x, t_y, alpha, theta)`` the indicated track is transformed
(``p' = p_0 + alpha R(theta) (p - p_0) + t``), each chosen beam's footprint is placed
with the heading ``psi - theta``, the map is read with the shared compiled bilinear read
(:func:`geofix.maps.mapread.bilinear_at`), and the absolute differences to the measured
depths are reduced to the GA cost (new fitness, eq. 8 of source 000, or the plain sum),
the SCA cost (eq. 9) and the mean absolute difference -- without the ``(P, n, s)``
temporaries of the numpy formulation, which :meth:`GaSca._evaluate_numpy` keeps as the
reference.
"""

from __future__ import annotations

import numba
import numpy as np

from geofix.maps.mapread import bilinear_at


@numba.njit(cache=True)
def ga_costs(
    values,
    geometry,
    indicated,
    sin_heading,
    cos_heading,
    pivot,
    offsets,
    params,
    measured,
    decay,
    weights,
    new_fitness,
    min_valid_fraction,
    n_valid,
):  # pragma: no cover - compiled
    """``(ga, sca, mad)`` costs of every individual, ``inf`` for discarded ones.

    Parameters
    ----------
    values : numpy.ndarray
        ``(ny, nx)`` map.
    geometry : numpy.ndarray
        ``(4,)`` ``x0, y0, dx, dy`` of the map, metres.
    indicated : numpy.ndarray
        ``(n, 2)`` indicated track, metres.
    sin_heading, cos_heading : numpy.ndarray
        ``(n,)`` sine and cosine of the indicated heading ``psi`` (clockwise from north).
        The footprint heading ``psi - theta`` enters through the angle-difference
        identity, ``sin(psi - theta) = sin psi cos theta - cos psi sin theta`` and
        ``cos(psi - theta) = cos psi cos theta + sin psi sin theta``, in the same order
        of operations as the numpy formulation (:func:`geofix.match._affine.beam_positions`)
        so that both engines round alike (a GA amplifies a last-bit difference into
        another search path); it saves two trigonometric calls per sample.
    pivot : numpy.ndarray
        ``(2,)`` pivot of rotation and scale, metres.
    offsets : numpy.ndarray
        ``(s, 2)`` body-frame offsets of the chosen beams, metres.
    params : numpy.ndarray
        ``(P, 4)`` individuals.
    measured : numpy.ndarray
        ``(n, s)`` measured depths of the chosen beams (NaN = missing).
    decay, weights : numpy.ndarray
        ``(n,)`` ``lambda^j`` and ``(s,)`` sequence weights.
    new_fitness : bool
        Eq. 8 (True) or the plain summed absolute difference (False).
    min_valid_fraction : float
        Share of valid look-ups below which an individual is discarded.
    n_valid : int
        Number of finite measured values.
    """
    x0, y0, dx, dy = geometry[0], geometry[1], geometry[2], geometry[3]
    n, s = measured.shape
    pop = params.shape[0]
    ga = np.empty(pop)
    sca = np.empty(pop)
    mad = np.empty(pop)
    seq = np.empty(s)
    dmax = np.empty(s)
    count = np.empty(s, dtype=np.int64)
    for p in range(pop):
        tx, ty, alpha, theta = params[p, 0], params[p, 1], params[p, 2], params[p, 3]
        c, sn = np.cos(theta), np.sin(theta)
        seq[:] = 0.0
        dmax[:] = 0.0
        count[:] = 0
        total = 0.0
        for i in range(n):
            rx, ry = indicated[i, 0] - pivot[0], indicated[i, 1] - pivot[1]
            px = pivot[0] + alpha * (c * rx - sn * ry) + tx
            py = pivot[1] + alpha * (sn * rx + c * ry) + ty
            ss = sin_heading[i] * c - cos_heading[i] * sn
            cs = cos_heading[i] * c + sin_heading[i] * sn
            for b in range(s):
                h = measured[i, b]
                if h != h:
                    continue
                across, along = offsets[b, 0], offsets[b, 1]
                fx = px + across * cs + along * ss
                fy = py - across * ss + along * cs
                d = abs(bilinear_at(values, (fx - x0) / dx, (fy - y0) / dy) - h)
                if d != d:
                    continue
                count[b] += 1
                seq[b] += d * decay[i]
                total += d
                if d > dmax[b]:
                    dmax[b] = d
        valid = count.sum()
        bad = valid < min_valid_fraction * n_valid
        for b in range(s):
            bad = bad or count[b] == 0
        if bad:
            ga[p] = sca[p] = mad[p] = np.inf
            continue
        sca_p = 0.0
        ga_p = 0.0
        for b in range(s):
            sca_p += dmax[b] * weights[b]
            ga_p += seq[b] / count[b] * weights[b]
        ga[p] = ga_p if new_fitness else total * n_valid / valid
        sca[p] = sca_p
        mad[p] = total / valid
    return ga, sca, mad


@numba.njit(cache=True)
def _inside(x, lower, upper):  # pragma: no cover - compiled
    """``(P,)`` True where every parameter of an individual lies inside the box."""
    out = np.ones(x.shape[0], dtype=np.bool_)
    for p in range(x.shape[0]):
        for g in range(x.shape[1]):
            if x[p, g] < lower[g] or x[p, g] > upper[g]:
                out[p] = False
    return out


@numba.njit(cache=True)
def _draw_sca(rng, r2, r3, coin):  # pragma: no cover - compiled
    """One SCA iteration's draws into buffers, in the order of the numpy engine.

    ``r2 ~ U(0, 2 pi)``, then ``r3 ~ U(0, 2)``, then the sine/cosine coin ``U(0, 1)``,
    each array filled row by row -- the draws of ``rng.uniform(..., shape)`` and
    ``rng.random(shape)`` without allocating them.
    """
    flat2, flat3, flatc = r2.reshape(-1), r3.reshape(-1), coin.reshape(-1)
    for q in range(flat2.shape[0]):
        flat2[q] = rng.uniform(0.0, 2 * np.pi)
    for q in range(flat3.shape[0]):
        flat3[q] = rng.uniform(0.0, 2.0)
    for q in range(flatc.shape[0]):
        flatc[q] = rng.random()


@numba.njit(cache=True)
def _sca_step(z, x, elite, half, p, r1, r2, r3, coin):  # pragma: no cover - compiled
    """SCA position update in place: ``z <- clip(z + r1 w |r3 p - z|, -1, 1)``, ``x = e + z h``.

    ``w`` is ``sin r2`` where the coin is below 0.5, else ``cos r2`` (Mirjalili 2016,
    eq. 3.3), in coordinates normalised to the SCA box (``e`` the elite, ``h`` the half-widths).
    """
    for q in range(z.shape[0]):
        for g in range(z.shape[1]):
            wave = np.sin(r2[q, g]) if coin[q, g] < 0.5 else np.cos(r2[q, g])
            step = z[q, g] + r1 * wave * abs(r3[q, g] * p[g] - z[q, g])
            z[q, g] = min(max(step, -1.0), 1.0)
            x[q, g] = elite[g] + z[q, g] * half[g]


@numba.njit(cache=True)
def sca_refine(
    rng, elite, half, lower, upper, population, iterations, a, fitness
):  # pragma: no cover - compiled
    """Sine-cosine refinement of the elite (Mirjalili 2016), compiled end to end.

    The same steps, random draws (same order and shapes) and selection as the numpy
    formulation in :meth:`GaSca._sca_numpy`.

    Parameters
    ----------
    rng : numpy.random.Generator
        The match's random source (advanced in place).
    elite : numpy.ndarray
        ``(4,)`` the GA's best individual ``(t_x, t_y, alpha, theta)``: metres, metres,
        scale, radians.
    half : numpy.ndarray
        ``(4,)`` half-widths of the SCA box around the elite, same units.
    lower, upper : numpy.ndarray
        ``(4,)`` bounds of the search box, same units.
    population : int
        SCA population (the first member is the elite itself).
    iterations : int
        SCA iterations.
    a : float
        SCA constant: the step amplitude ``r1`` falls linearly from ``a`` to 0.
    fitness : tuple
        ``(head, tail)`` arguments of :func:`ga_costs` before and after ``params``.

    Returns
    -------
    tuple
        ``(new_elite, its GA cost, its mean absolute difference, final SCA population
        inside the box, their GA costs, their mean absolute differences, number of
        individuals scored)``.
    """
    head, tail = fitness
    scored = population * (iterations + 1)
    z = rng.uniform(-1.0, 1.0, (population, 4))
    z[0] = 0.0
    x = elite + z * half
    cost, sca_cost, mad = ga_costs(*head, x, *tail)
    best = int(np.argmin(sca_cost))
    p, p_cost, p_ga, p_mad = z[best].copy(), sca_cost[best], cost[best], mad[best]
    r2, r3, coin = np.empty(z.shape), np.empty(z.shape), np.empty(z.shape)
    for t in range(iterations):
        r1 = a * (1.0 - t / iterations)
        _draw_sca(rng, r2, r3, coin)
        _sca_step(z, x, elite, half, p, r1, r2, r3, coin)
        cost, sca_cost, mad = ga_costs(*head, x, *tail)
        k = int(np.argmin(sca_cost))
        if sca_cost[k] < p_cost:
            p, p_cost, p_ga, p_mad = z[k].copy(), sca_cost[k], cost[k], mad[k]
    inside = _inside(x, lower, upper)
    new_elite = elite + p * half
    if not _inside(new_elite.reshape(1, 4), lower, upper)[0]:
        new_elite = np.minimum(np.maximum(new_elite, lower), upper)
        clipped = ga_costs(*head, new_elite.reshape(1, 4), *tail)
        p_ga, p_mad = clipped[0][0], clipped[2][0]
        scored += 1
    return new_elite, p_ga, p_mad, x[inside], cost[inside], mad[inside], scored


@numba.njit(cache=True)
def ga_offspring(
    rng, pool, pool_cost, population, crossover_rate, mutation_rate, mutation_scale, lower, upper
):  # pragma: no cover - compiled
    """Tournament selection, BLX-0.25 crossover and Gaussian mutation, compiled.

    The same random draws, in the same order and shapes, as the numpy operators of
    :class:`GaSca` (``_tournament``, ``_crossover``, ``_mutate``).

    Parameters
    ----------
    rng : numpy.random.Generator
        The match's random source (advanced in place).
    pool : numpy.ndarray
        ``(m, 4)`` selection pool ``(t_x, t_y, alpha, theta)``: metres, metres, scale,
        radians.
    pool_cost : numpy.ndarray
        ``(m,)`` GA costs of the pool (lower wins a tournament).
    population : int
        GA population size ``P``; ``P - 1`` children are returned.
    crossover_rate : float
        Probability that a pair of parents is crossed.
    mutation_rate : float
        Probability that one gene mutates.
    mutation_scale : float
        Mutation standard deviation as a share of the box half-width.
    lower, upper : numpy.ndarray
        ``(4,)`` bounds of the search box; children are clipped to it.

    Returns
    -------
    tuple
        ``(children, source)``: the ``(population - 1, 4)`` children and, for each, the
        index in ``pool`` of the parent it is a bit-for-bit copy of (its pair was not
        crossed and none of its genes mutated), ``-1`` for a new individual.
    """
    count = 2 * (population // 2)
    a = rng.integers(0, pool_cost.shape[0], count)
    b = rng.integers(0, pool_cost.shape[0], count)
    winner = np.empty(count, dtype=np.int64)
    for q in range(count):
        winner[q] = a[q] if pool_cost[a[q]] <= pool_cost[b[q]] else b[q]
    pairs = count // 2
    beta = rng.uniform(-0.25, 1.25, (pairs, 4))
    cross = rng.random(pairs) < crossover_rate
    kids = np.empty((count, 4))
    for q in range(pairs):
        first, second = pool[winner[2 * q]], pool[winner[2 * q + 1]]
        for g in range(4):
            w = beta[q, g] if cross[q] else 1.0
            kids[q, g] = min(max(w * first[g] + (1 - w) * second[g], lower[g]), upper[g])
            kids[pairs + q, g] = min(max((1 - w) * first[g] + w * second[g], lower[g]), upper[g])
    hit = rng.random(kids.shape) < mutation_rate
    step = rng.standard_normal(kids.shape)
    source = np.full(count, -1, dtype=np.int64)
    for q in range(count):
        mutated = False
        for g in range(4):
            if hit[q, g]:
                mutated = True
                jump = step[q, g] * mutation_scale * (0.5 * (upper[g] - lower[g]))
                kids[q, g] = min(max(kids[q, g] + jump, lower[g]), upper[g])
        if not mutated and not cross[q % pairs]:
            source[q] = winner[2 * (q % pairs) + q // pairs]
    return kids[: population - 1].copy(), source[: population - 1].copy()


@numba.njit(cache=True)
def score_children(children, source, pool_cost, pool_mad, fitness):  # pragma: no cover
    """GA costs and mean absolute differences of the children, each new one scored once.

    A child that copies a pool member (``source >= 0``, see :func:`ga_offspring`) takes
    that member's numbers; the others go through :func:`ga_costs` in one call.

    Parameters
    ----------
    children : numpy.ndarray
        ``(P, 4)`` children.
    source : numpy.ndarray
        ``(P,)`` index in the pool of the member each child copies, ``-1`` for a new one.
    pool_cost, pool_mad : numpy.ndarray
        GA costs and mean absolute differences (map units) of the pool.
    fitness : tuple
        ``(head, tail)`` arguments of :func:`ga_costs` before and after ``params``.

    Returns
    -------
    tuple
        ``(cost, mad, scored)``: ``(P,)`` arrays and the number of children scored.
    """
    head, tail = fitness
    fresh = np.nonzero(source < 0)[0]
    new_cost, _, new_mad = ga_costs(*head, children[fresh], *tail)
    cost = np.empty(children.shape[0])
    mad = np.empty(children.shape[0])
    for q in range(children.shape[0]):
        if source[q] >= 0:
            cost[q] = pool_cost[source[q]]
            mad[q] = pool_mad[source[q]]
    cost[fresh] = new_cost
    mad[fresh] = new_mad
    return cost, mad, fresh.shape[0]


@numba.njit(cache=True)
def _merge_pool(
    pop, cost, mad, k, elite, elite_numbers, sca_pop, sca_cost, sca_mad
):  # pragma: no cover
    """The selection pool: population without its elite, refined elite, SCA population.

    The order of ``vstack([delete(pop, k), elite, sca_pop])`` in the numpy engine;
    ``elite_numbers`` is the elite's ``(GA cost, mean absolute difference)``. Returns
    the pool and its GA costs and mean absolute differences.
    """
    n, m = pop.shape[0], sca_pop.shape[0]
    pool = np.empty((n + m, 4))
    pool_cost = np.empty(n + m)
    pool_mad = np.empty(n + m)
    j = 0
    for p in range(n):
        if p != k:
            pool[j] = pop[p]
            pool_cost[j] = cost[p]
            pool_mad[j] = mad[p]
            j += 1
    pool[j] = elite
    pool_cost[j], pool_mad[j] = elite_numbers
    pool[j + 1 :] = sca_pop
    pool_cost[j + 1 :] = sca_cost
    pool_mad[j + 1 :] = sca_mad
    return pool, pool_cost, pool_mad


@numba.njit(cache=True)
def ga_search(rng, pop, cost, mad, fitness, box, ga_settings, sca_settings):  # pragma: no cover
    """The whole GA-SCA generation loop, compiled (one call per match).

    The same steps and random draws, in the same order, as the generation loop of
    :meth:`geofix.match.ga_sca.GaSca.match` with ``engine="numpy"``: SCA refinement of the
    elite, selection pool, offspring, scoring (children that copy a pool member keep its
    numbers, :func:`score_children`), stop rule.

    Parameters
    ----------
    rng : numpy.random.Generator
        The match's random source (advanced in place).
    pop, cost, mad : numpy.ndarray
        ``(P, 4)`` initial population, its ``(P,)`` GA costs and mean absolute differences.
    fitness : tuple
        ``(head, tail)`` arguments of :func:`ga_costs` around ``params``.
    box : tuple
        ``(lower, upper, sca_half)``: ``(4,)`` search box and SCA half-widths.
    ga_settings : tuple
        ``(max_generations, stall_generations, tolerance, crossover_rate, mutation_rate,
        mutation_scale)``.
    sca_settings : tuple
        ``(uses_sca, sca_population, sca_iterations, sca_a)``.

    Returns
    -------
    tuple
        ``(best_x, best_cost, archive_params, archive_mad, last_gain, generations,
        scored)``: the archive holds the initial population and every generation's
        children; ``scored`` counts the individuals passed to :func:`ga_costs` after the
        initial population.
    """
    lower, upper, half = box
    max_gen, stall, tolerance, crossover, mutation_rate, mutation_scale = ga_settings
    uses_sca, sca_population, sca_iterations, sca_a = sca_settings
    population = pop.shape[0]
    archive = np.empty(((max_gen + 1) * population, 4))
    archive_mad = np.empty((max_gen + 1) * population)
    archive[:population] = pop
    archive_mad[:population] = mad
    used = population
    scored = 0
    k = int(np.argmin(cost))
    best_x, best_cost = pop[k].copy(), cost[k]
    last_gain, generation = 0, 0
    for generation in range(1, max_gen + 1):
        k = int(np.argmin(cost))
        elite, elite_cost, elite_mad = pop[k].copy(), cost[k], mad[k]
        pool, pool_cost, pool_mad = pop, cost, mad
        if uses_sca:
            elite, elite_cost, elite_mad, sca_pop, sca_cost, sca_mad, sca_scored = sca_refine(
                rng, elite, half, lower, upper, sca_population, sca_iterations, sca_a, fitness
            )
            scored += sca_scored
            pool, pool_cost, pool_mad = _merge_pool(
                pop, cost, mad, k, elite, (elite_cost, elite_mad), sca_pop, sca_cost, sca_mad
            )
        children, source = ga_offspring(
            rng, pool, pool_cost, population, crossover, mutation_rate, mutation_scale, lower, upper
        )
        new_cost, new_mad, fresh = score_children(children, source, pool_cost, pool_mad, fitness)
        scored += fresh
        archive[used : used + children.shape[0]] = children
        archive_mad[used : used + children.shape[0]] = new_mad
        used += children.shape[0]
        pop = np.empty((population, 4))
        pop[0] = elite
        pop[1:] = children
        cost = np.empty(population)
        cost[0] = elite_cost
        cost[1:] = new_cost
        mad = np.empty(population)
        mad[0] = elite_mad
        mad[1:] = new_mad
        k = int(np.argmin(cost))
        if cost[k] < best_cost * (1 - tolerance):
            last_gain = generation
        if cost[k] < best_cost:
            best_x, best_cost = pop[k].copy(), cost[k]
        if generation - last_gain >= stall:
            break
    return best_x, best_cost, archive[:used], archive_mad[:used], last_gain, generation, scored
