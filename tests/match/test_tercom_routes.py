"""TERCOM cost-surface routes (loop, FFT, direct, branch-and-bound) against brute force."""

import dataclasses

import numpy as np
import pytest

from geofix.errors import ConfigError
from geofix.maps.grid import Grid
from geofix.match.tercom import Tercom, pruning_holds, tercom_cost_surface
from geofix.problem import MatchProblem, footprint_xy

RTOL = 1e-9


def _numpy_bilinear(values, col, row):
    """Plain-numpy bilinear read (NaN off the grid and on no-data), as ``Grid.sample``."""
    ny, nx = values.shape
    inside = (col >= 0) & (col <= nx - 1) & (row >= 0) & (row <= ny - 1)
    c, r = np.where(inside, col, 0.0), np.where(inside, row, 0.0)
    c0 = np.minimum(np.floor(c).astype(int), nx - 2)
    r0 = np.minimum(np.floor(r).astype(int), ny - 2)
    fc, fr = c - c0, r - r0
    top = values[r0, c0] * (1 - fc) + values[r0, c0 + 1] * fc
    bottom = values[r0 + 1, c0] * (1 - fc) + values[r0 + 1, c0 + 1] * fc
    return np.where(inside, top * (1 - fr) + bottom * fr, np.nan)


def brute_force(problem, ox, oy, metric, min_valid_fraction=0.9):
    """Every candidate scored one by one in numpy, each metric from its definition."""
    fx, fy = problem.footprint(problem.indicated)
    h = problem.measured.reshape(-1)
    keep = np.isfinite(h)
    fx, fy, h = fx.reshape(-1)[keep], fy.reshape(-1)[keep], h[keep]
    grid = problem.grid
    out = np.full((oy.size, ox.size), np.nan)
    for j, dy in enumerate(oy):
        for k, dx in enumerate(ox):
            col, row = (fx + dx - grid.x0) / grid.dx, (fy + dy - grid.y0) / grid.dy
            m = _numpy_bilinear(grid.values, col, row)
            ok = np.isfinite(m)
            if ok.sum() == 0 or ok.sum() < min_valid_fraction * h.size:
                continue
            d = h[ok] - m[ok]
            if metric == "msd":
                out[j, k] = np.mean(d**2)
            elif metric == "mad":
                out[j, k] = np.mean(np.abs(d))
            elif metric == "cor":
                out[j, k] = -np.mean(h[ok] * m[ok])
            elif metric == "cmsd":
                out[j, k] = np.mean((d - d.mean()) ** 2)
            else:
                hc = h[ok] - h.mean()
                mc = m[ok] - m[ok].mean()
                out[j, k] = -np.sum(hc * mc) / np.sqrt(np.sum(mc**2) * np.sum(hc**2))
    return out


def _grid(rng, shape=(90, 100), cell=10.0, nan_cells=()):
    ny, nx = shape
    yy, xx = np.mgrid[0:ny, 0:nx] * cell
    z = np.full(shape, -100.0)
    for _ in range(10):
        k = rng.uniform(0.004, 0.03, size=2)
        z += rng.normal(0, 3) * np.sin(k[0] * xx + k[1] * yy + rng.uniform(0, 6.3))
    for r, c in nan_cells:
        z[r, c] = np.nan
    return Grid(z, x0=0.0, y0=0.0, dx=cell, dy=cell)


def _problem(grid, rng, start=(400.0, 380.0), n=18, beams=3, noise=0.4):
    heading = np.full(n, 0.7)
    truth = np.asarray(start) + np.arange(n)[:, None] * 17.0 * np.array([np.sin(0.7), np.cos(0.7)])
    offsets = np.column_stack([np.linspace(-25, 25, beams), np.zeros(beams)])
    fx, fy = footprint_xy(truth, heading, offsets)
    measured = grid.sample(fx, fy) + rng.normal(0, noise, fx.shape)
    measured[3, 0] = np.nan  # a missing beam
    return MatchProblem(
        grid=grid,
        indicated=truth + np.array([23.0, -31.0]),
        heading=heading,
        offsets=offsets,
        measured=measured,
        sigma_position=np.full(n, 40.0),
        times=np.arange(n) * 5.0,
        noise_std=noise,
    )


def _assert_surface(got, expected):
    np.testing.assert_array_equal(np.isnan(got), np.isnan(expected))
    ok = np.isfinite(expected)
    assert ok.sum() > 50
    np.testing.assert_allclose(got[ok], expected[ok], rtol=RTOL, atol=0)


@pytest.fixture(scope="module")
def case():
    rng = np.random.default_rng(7)
    grid = _grid(rng)
    problem = _problem(grid, rng)
    ox = np.arange(-12, 13) * grid.dx
    oy = np.arange(-10, 11) * grid.dy
    return problem, ox, oy


@pytest.mark.parametrize("metric", ["msd", "mad", "cor", "ncor", "cmsd"])
@pytest.mark.parametrize("route", ["loop", "direct", "auto"])
def test_every_route_equals_brute_force(case, metric, route):
    problem, ox, oy = case
    got = tercom_cost_surface(problem, ox, oy, metric, route=route)
    _assert_surface(got, brute_force(problem, ox, oy, metric))


@pytest.mark.parametrize("metric", ["msd", "cor", "ncor", "cmsd"])
def test_fft_route_equals_brute_force(case, metric):
    problem, ox, oy = case
    got = tercom_cost_surface(problem, ox, oy, metric, route="fft")
    _assert_surface(got, brute_force(problem, ox, oy, metric))


def test_mad_has_no_fft_route(case):
    problem, ox, oy = case
    with pytest.raises(ConfigError, match="fft"):
        tercom_cost_surface(problem, ox, oy, "mad", route="fft")


@pytest.mark.parametrize("metric", ["msd", "ncor", "cmsd"])
def test_loop_handles_no_data_cells_and_the_map_edge(metric):
    rng = np.random.default_rng(8)
    grid = _grid(rng, shape=(60, 70), nan_cells=[(30, 30), (31, 41), (12, 50)])
    problem = _problem(grid, rng, start=(330.0, 300.0), n=12)
    ox = np.arange(-40, 31) * grid.dx  # reaches past the western and eastern edges
    oy = np.arange(-35, 28) * grid.dy
    expected = brute_force(problem, ox, oy, metric)
    assert np.isnan(expected).any() and np.isfinite(expected).any()
    _assert_surface(tercom_cost_surface(problem, ox, oy, metric, route="loop"), expected)
    _assert_surface(tercom_cost_surface(problem, ox, oy, metric, route="auto"), expected)
    with pytest.raises(ConfigError, match="fft"):
        tercom_cost_surface(problem, ox, oy, metric, route="fft")


def test_strided_and_fractional_steps(case):
    problem, ox, oy = case
    ox2, oy2 = ox[::2], oy[::3]
    _assert_surface(
        tercom_cost_surface(problem, ox2, oy2, "mad", route="loop"),
        brute_force(problem, ox2, oy2, "mad"),
    )
    _assert_surface(
        tercom_cost_surface(problem, ox2, oy2, "msd", route="fft"),
        brute_force(problem, ox2, oy2, "msd"),
    )
    half = ox * 0.55
    _assert_surface(
        tercom_cost_surface(problem, half, oy, "msd"), brute_force(problem, half, oy, "msd")
    )
    with pytest.raises(ConfigError, match="whole-cell"):
        tercom_cost_surface(problem, half, oy, "msd", route="loop")


@pytest.mark.parametrize("metric", ["msd", "mad"])
def test_branch_and_bound_keeps_the_fix_and_its_integrity(case, metric):
    problem, ox, oy = case
    matcher = Tercom(metric=metric, window_m=12 * 10.0)
    margin = matcher._prune_margin(problem)
    pruned = tercom_cost_surface(problem, ox, oy, metric, route="loop", prune_margin=margin)
    full = brute_force(problem, ox, oy, metric)
    dropped = np.isinf(pruned)
    assert dropped.sum() > 0.1 * pruned.size  # the bound does drop candidates here
    kept = np.isfinite(pruned)
    np.testing.assert_allclose(pruned[kept], full[kept], rtol=RTOL)
    best = np.nanmin(full)
    assert np.all(full[dropped] > best + margin(best))
    fast = matcher.match(problem)
    slow = Tercom(metric=metric, window_m=12 * 10.0, route="direct").match(problem)
    np.testing.assert_allclose(fast.track, slow.track, rtol=0, atol=1e-9)
    np.testing.assert_allclose(fast.covariance, slow.covariance, rtol=1e-9)
    assert fast.ambiguous == slow.ambiguous
    assert fast.diagnostics["route"] == "loop" and slow.diagnostics["route"] == "direct"


def test_unknown_route_is_a_config_error(case):
    problem, ox, oy = case
    with pytest.raises(ConfigError, match="route"):
        Tercom(route="gpu")
    with pytest.raises(ConfigError, match="route"):
        tercom_cost_surface(problem, ox, oy, route="gpu")


def _numpy_integrity(matcher, problem, surface, ox, oy, effect=1.0):
    """The pseudo-likelihood covariance and ambiguity in plain numpy (reference)."""
    samples = int(np.isfinite(problem.measured).sum()) / effect
    best = float(np.nanmin(surface))
    if matcher.metric == "mad":
        scale = max(problem.noise_std / np.sqrt(2.0), best, 1e-12)
    else:
        scale = 2.0 * max(problem.noise_std**2, best, 1e-12)
    w = np.exp(-samples * (np.nan_to_num(surface, nan=np.inf) - best) / scale)
    w /= w.sum()
    j, k = np.unravel_index(np.nanargmin(surface), surface.shape)
    dx, dy = np.meshgrid(ox - ox[k], oy - oy[j])
    cell = problem.grid.cell_size
    mx, my = (w * dx).sum(), (w * dy).sum()
    cov = np.array(
        [
            [(w * (dx - mx) ** 2).sum() + cell**2 / 12, (w * (dx - mx) * (dy - my)).sum()],
            [(w * (dx - mx) * (dy - my)).sum(), (w * (dy - my) ** 2).sum() + cell**2 / 12],
        ]
    )
    far = np.hypot(dx, dy) > matcher.exclusion_cells * cell
    return cov, bool(w[far].sum() > matcher.ambiguity_mass)


@pytest.mark.parametrize("metric", ["msd", "mad", "ncor", "cmsd"])
def test_integrity_equals_the_numpy_pseudo_likelihood(metric):
    rng = np.random.default_rng(9)
    problem = _problem(_grid(rng), rng, n=6, beams=1, noise=2.0)  # a broad likelihood
    # the msd surface's own integrity (offset_std=0; the offset-weighed one below)
    matcher = Tercom(metric=metric, window_m=12 * 10.0, exclusion_cells=1.0, offset_std=0)
    fix = matcher.match(problem)
    ox, oy = matcher.candidate_offsets(problem)
    kind = {"mad": "mad", "cmsd": "cmsd"}.get(metric, "msd")  # cor/ncor: judged by msd
    surface = brute_force(problem, ox, oy, kind)
    effect = fix.diagnostics["design_effect"]
    cov, ambiguous = _numpy_integrity(matcher, problem, surface, ox, oy, effect)
    np.testing.assert_allclose(fix.covariance, cov, rtol=1e-9)
    assert np.linalg.eigvalsh(cov)[-1] > 1.5 * 100.0 / 12  # more than the cell quantisation
    flat = fix.diagnostics["terrain_snr"] < matcher.min_terrain_snr
    assert fix.ambiguous == (ambiguous or flat)


@pytest.mark.parametrize("metric", ["msd", "mad"])
def test_a_large_design_effect_scores_the_pruned_candidates_again(metric):
    """Readings with an error persisting along the track: counted as fewer samples, the
    candidates branch-and-bound dropped could carry weight, so the loop route scores
    them all again and the integrity is the brute-force surface's."""
    rng = np.random.default_rng(11)
    problem = _problem(_grid(rng), rng, n=40, beams=5, noise=0.5)
    drift = np.cumsum(rng.normal(0.0, 1.0, problem.measured.shape[0]))
    problem = dataclasses.replace(problem, measured=problem.measured + drift[:, None])
    matcher = Tercom(metric=metric, window_m=25 * 10.0, route="loop", offset_std=0)
    fix = matcher.match(problem)
    effect = fix.diagnostics["design_effect"]
    ox, oy = matcher.candidate_offsets(problem)
    assert not pruning_holds(effect, ox.size * oy.size)  # the case the test is about
    surface = brute_force(problem, ox, oy, metric)
    cov, _ = _numpy_integrity(matcher, problem, surface, ox, oy, effect)
    np.testing.assert_allclose(fix.covariance, cov, rtol=1e-9)
    independent = Tercom(
        metric=metric, window_m=25 * 10.0, correlated_residuals=False, offset_std=0
    )
    narrow = independent.match(problem)
    np.testing.assert_allclose(narrow.track, fix.track)
    assert np.trace(fix.covariance) > 2.0 * np.trace(narrow.covariance)


def _numpy_offset_mixture(matcher, problem, ox, oy, effect, offset_std):
    """The offset-weighed covariance in plain numpy from brute-force surfaces (reference)."""
    msd = brute_force(problem, ox, oy, "msd")
    cmsd = brute_force(problem, ox, oy, "cmsd")
    n = int(np.isfinite(problem.measured).sum())
    samples = n / effect
    weight = offset_std**2 / (offset_std**2 + problem.noise_std**2 / n)
    marginal = (1 - weight) * msd + weight * cmsd
    j, k = np.unravel_index(np.nanargmin(msd), msd.shape)
    var = max(problem.noise_std**2, cmsd[j, k])
    se2 = var / samples
    ref = np.nanmin(marginal)
    w0 = np.exp(-samples * (np.nan_to_num(msd, nan=np.inf) - ref) / (2 * var))
    w1 = np.exp(-samples * (np.nan_to_num(marginal, nan=np.inf) - ref) / (2 * var))
    w1 *= np.sqrt(se2 / (se2 + offset_std**2))
    p_offset = w1.sum() / (w0.sum() + w1.sum())
    cell = problem.grid.cell_size
    plain, _ = _numpy_integrity(matcher, problem, msd, ox, oy, effect)
    dx, dy = np.meshgrid(ox - ox[k], oy - oy[j])
    low = np.nanmin(msd)
    v0 = np.exp(
        -samples * (np.nan_to_num(msd, nan=np.inf) - low) / (2 * max(problem.noise_std**2, low))
    )
    mean0 = np.array([(v0 * dx).sum(), (v0 * dy).sum()]) / v0.sum()
    w1 = w1 / w1.sum()
    d = np.stack([dx - mean0[0], dy - mean0[1]])
    second1 = np.einsum("ajk,bjk,jk->ab", d, d, w1)
    spread = (1 - p_offset) * (plain - np.eye(2) * cell**2 / 12) + p_offset * second1
    return spread + np.eye(2) * cell**2 / 12, p_offset


@pytest.mark.parametrize("route", ["loop", "fft", "direct"])
def test_offset_weighed_integrity_equals_the_numpy_mixture(route):
    rng = np.random.default_rng(9)
    problem = _problem(_grid(rng), rng, n=12, beams=1, noise=0.5)
    problem = dataclasses.replace(problem, measured=problem.measured + 1.5)  # a tide
    matcher = Tercom(window_m=12 * 10.0, route=route, offset_std=2.0)
    fix = matcher.match(problem)
    ox, oy = matcher.candidate_offsets(problem)
    cov, p_offset = _numpy_offset_mixture(
        matcher, problem, ox, oy, fix.diagnostics["design_effect"], 2.0
    )
    assert 0.01 < p_offset < 0.99  # both models carry weight: the mixture is tested
    assert fix.diagnostics["offset_probability"] == pytest.approx(p_offset, rel=1e-6)
    np.testing.assert_allclose(fix.covariance, cov, rtol=1e-6)
