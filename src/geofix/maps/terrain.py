"""Terrain numerics on a :class:`Grid`: gradients, local plane fits, statistics.

Pure numpy/scipy functions used by the matchers, the filters (SITAN's stochastic terrain
linearisation) and the suitability maps. NaN cells are ignored wherever a statistic is
taken, and propagate where a local value cannot be formed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geofix.maps.grid import Grid

_E_FOLD = float(np.exp(-1.0))


# ---------------------------------------------------------------------- gradient
def gradient(grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    """Field gradient at every cell centre.

    Parameters
    ----------
    grid : Grid
        The map.

    Returns
    -------
    gx, gy : numpy.ndarray
        ``(ny, nx)`` derivatives along x (east) and y (north), field units per metre;
        central differences inside, one-sided on the edges, NaN next to no-data.
    """
    gy, gx = np.gradient(np.asarray(grid.values, dtype=float), grid.dy, grid.dx)
    return gx, gy


# ---------------------------------------------------------------------- plane fit
@dataclass(frozen=True, eq=False)
class PlaneFit:
    """Least-squares planes ``z = value_at_centre + slope_x * u + slope_y * v`` at points.

    ``u, v`` are metric offsets east and north of each point. Every array has the shape
    of the query points; NaN where the patch had too few valid samples.

    Attributes
    ----------
    slope_x, slope_y : numpy.ndarray
        Plane slopes, field units per metre.
    value_at_centre : numpy.ndarray
        Plane value at the point itself, field units.
    residual_std : numpy.ndarray
        Standard deviation of the map about the plane over the patch (``n - 3`` degrees
        of freedom), field units: the linearisation error.
    n_valid : numpy.ndarray
        Number of valid samples used.
    """

    slope_x: np.ndarray
    slope_y: np.ndarray
    value_at_centre: np.ndarray
    residual_std: np.ndarray
    n_valid: np.ndarray


def plane_stencil(grid: Grid, half_width_m: float, max_side: int = 31) -> np.ndarray:
    """Offsets of the plane-fit patch: a square lattice of about one cell spacing.

    Parameters
    ----------
    grid : Grid
        The map (its cell size sets the lattice spacing).
    half_width_m : float
        Half side of the square patch, metres.
    max_side : int
        Largest number of samples per side; wider patches use a coarser lattice.

    Returns
    -------
    numpy.ndarray
        ``(k * k, 2)`` offsets ``(u, v)`` in metres, ``k`` odd, from ``-half_width_m`` to
        ``+half_width_m`` inclusive.
    """
    k = 2 * int(np.ceil(half_width_m / min(grid.dx, grid.dy) - 1e-9)) + 1
    k = int(np.clip(k, 3, max_side if max_side % 2 else max_side - 1))
    side = np.linspace(-half_width_m, half_width_m, k)
    u, v = np.meshgrid(side, side)
    return np.column_stack([u.ravel(), v.ravel()])


def plane_fit(
    grid: Grid,
    x,
    y,
    half_width_m: float,
    min_valid_fraction: float = 0.5,
    max_side: int = 31,
) -> PlaneFit:
    """Fit a plane to the map around each point (stochastic terrain linearisation).

    The patch is the square of half side ``half_width_m`` centred on the point, sampled on
    a fixed ``k x k`` lattice (:func:`plane_stencil`: spacing about one cell, at most
    ``max_side`` per side) read with the grid's interpolation (:meth:`Grid.sample`:
    bilinear unless ``grid.interpolation`` says bicubic). On a point that sits on a cell
    centre this reads the cell centres themselves; elsewhere the interpolated reads keep
    the fit continuous in position, which a recursive filter needs. The fit is vectorised
    over points with per-point NaN masks.

    Parameters
    ----------
    grid : Grid
        The map.
    x, y : array_like
        Point eastings and northings, metres; any (broadcastable) shape.
    half_width_m : float
        Half side of the patch, metres (e.g. the 1-sigma position uncertainty).
    min_valid_fraction : float
        Smallest fraction of valid (on-map, non-NaN) samples for a fit; fewer gives NaN.
    max_side : int
        Largest lattice side, samples.

    Returns
    -------
    PlaneFit
        Slopes (units per metre), centre value, residual std, shape of the points.
    """
    x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    offsets = plane_stencil(grid, half_width_m, max_side)
    u, v = offsets[:, 0], offsets[:, 1]
    z = grid.sample(x.reshape(-1, 1) + u, y.reshape(-1, 1) + v)
    coef, resid_std, n_valid = _masked_plane_lstsq(z, u, v)
    enough = n_valid >= max(4, min_valid_fraction * u.size)
    coef = np.where(enough[:, None], coef, np.nan)
    resid_std = np.where(enough, resid_std, np.nan)
    shape = x.shape
    return PlaneFit(
        slope_x=coef[:, 1].reshape(shape),
        slope_y=coef[:, 2].reshape(shape),
        value_at_centre=coef[:, 0].reshape(shape),
        residual_std=resid_std.reshape(shape),
        n_valid=n_valid.reshape(shape),
    )


def _masked_plane_lstsq(z: np.ndarray, u: np.ndarray, v: np.ndarray):
    """Per-row least squares of ``z ~ a + b u + c v`` ignoring NaN; ``(coef, std, n)``."""
    w = ~np.isnan(z)
    zf = np.where(w, z, 0.0)
    design = np.stack([np.ones_like(u), u, v], axis=1)  # (k, 3)
    products = (design[:, :, None] * design[:, None, :]).reshape(-1, 9)
    normal = (w.astype(float) @ products).reshape(-1, 3, 3)
    rhs = zf @ design
    n = w.sum(axis=1)
    det = np.linalg.det(normal)
    scale = np.maximum(np.einsum("pii->p", normal), 1e-300) ** 3
    solvable = np.abs(det) > 1e-12 * scale
    safe = np.where(solvable[:, None, None], normal, np.eye(3))
    coef = np.linalg.solve(safe, rhs[..., None])[..., 0]
    coef[~solvable] = np.nan
    resid = np.where(w, zf - coef @ design.T, 0.0)
    dof = np.maximum(n - 3, 1)
    return coef, np.sqrt((resid**2).sum(axis=1) / dof), n


# ---------------------------------------------------------------------- statistics
@dataclass(frozen=True)
class TerrainStats:
    """Summary statistics of a field, NaN cells ignored.

    Attributes
    ----------
    std : float
        Standard deviation (population, ``ddof=0``), field units.
    range : float
        Maximum minus minimum, field units.
    mean : float
        Mean, field units.
    roughness : float
        Mean absolute difference between adjacent cells (x and y neighbours pooled),
        field units.
    mean_slope : float
        Mean gradient magnitude, field units per metre.
    correlation_length_x_m, correlation_length_y_m : float
        Lag at which the autocorrelation along x (y) first drops to 1/e, metres;
        ``inf`` if it never does within half the map, NaN for a constant field.
    valid_fraction : float
        Fraction of non-NaN cells.
    """

    std: float
    range: float
    mean: float
    roughness: float
    mean_slope: float
    correlation_length_x_m: float
    correlation_length_y_m: float
    valid_fraction: float

    @property
    def correlation_length_m(self) -> float:
        """Mean of the x and y e-folding correlation lengths, metres."""
        return 0.5 * (self.correlation_length_x_m + self.correlation_length_y_m)


def _values_and_cells(grid_or_values, cell_m) -> tuple[np.ndarray, float, float]:
    if isinstance(grid_or_values, Grid):
        return np.asarray(grid_or_values.values, dtype=float), grid_or_values.dx, grid_or_values.dy
    dx, dy = np.broadcast_to(np.asarray(cell_m, dtype=float), (2,))
    return np.asarray(grid_or_values, dtype=float), float(dx), float(dy)


def terrain_stats(grid_or_values, cell_m: float | tuple[float, float] = 1.0) -> TerrainStats:
    """Statistics of a map: spread, roughness, slope and correlation length.

    Parameters
    ----------
    grid_or_values : Grid or array_like
        A map, or a bare ``(ny, nx)`` array (NaN = no data).
    cell_m : float or (float, float)
        Cell size ``dx`` (or ``(dx, dy)``), metres, used only for a bare array.

    Returns
    -------
    TerrainStats
        See its attributes; slopes in field units per metre, lengths in metres.
    """
    z, dx, dy = _values_and_cells(grid_or_values, cell_m)
    valid = ~np.isnan(z)
    if not valid.any():
        nan = float("nan")
        return TerrainStats(nan, nan, nan, nan, nan, nan, nan, 0.0)
    diffs = np.concatenate([np.diff(z, axis=1).ravel(), np.diff(z, axis=0).ravel()])
    gy, gx = np.gradient(z, dy, dx)
    lx, ly = _correlation_lengths(z, dx, dy)
    return TerrainStats(
        std=float(np.nanstd(z)),
        range=float(np.nanmax(z) - np.nanmin(z)),
        mean=float(np.nanmean(z)),
        roughness=float(np.nanmean(np.abs(diffs))) if np.isfinite(diffs).any() else np.nan,
        mean_slope=float(np.nanmean(np.hypot(gx, gy))) if np.isfinite(gx).any() else np.nan,
        correlation_length_x_m=lx,
        correlation_length_y_m=ly,
        valid_fraction=float(valid.mean()),
    )


def autocorrelation(values: np.ndarray) -> np.ndarray:
    """Normalised 2-D autocorrelation of a field with gaps, by FFT.

    Parameters
    ----------
    values : numpy.ndarray
        ``(ny, nx)`` field, NaN = no data.

    Returns
    -------
    numpy.ndarray
        ``(ny, nx)`` autocorrelation at non-negative lags ``[lag_y, lag_x]`` (1 at lag 0),
        each lag averaged over the valid pairs only (zero-padded FFT, no wrap-around).
    """
    mask = ~np.isnan(values)
    anomaly = np.where(mask, values - np.nanmean(values), 0.0)
    ny, nx = values.shape
    shape = (2 * ny, 2 * nx)

    def corr(a: np.ndarray) -> np.ndarray:
        spectrum = np.fft.rfft2(a, shape)
        return np.fft.irfft2(spectrum * np.conj(spectrum), shape)[:ny, :nx]

    pairs = np.rint(corr(mask.astype(float)))
    cov = np.divide(corr(anomaly), pairs, out=np.full((ny, nx), np.nan), where=pairs > 0)
    if not cov[0, 0] > 0:
        return np.full((ny, nx), np.nan)
    return cov / cov[0, 0]


def _e_folding_lag(acf_line: np.ndarray) -> float:
    """First (linearly interpolated) lag, in cells, at which ``acf_line`` drops to 1/e."""
    below = np.flatnonzero(acf_line <= _E_FOLD)
    if below.size == 0:
        return float("inf")
    k = int(below[0])
    a0, a1 = acf_line[k - 1], acf_line[k]
    return float(k - 1 + (a0 - _E_FOLD) / (a0 - a1))


def _correlation_lengths(z: np.ndarray, dx: float, dy: float) -> tuple[float, float]:
    acf = autocorrelation(z)
    if np.isnan(acf[0, 0]):
        return float("nan"), float("nan")
    ny, nx = z.shape
    return (
        _e_folding_lag(acf[0, : max(nx // 2, 2)]) * dx,
        _e_folding_lag(acf[: max(ny // 2, 2), 0]) * dy,
    )


def local_std(grid_or_values, window_cells: int) -> np.ndarray:
    """Moving-window standard deviation of the field (a terrain-suitability measure).

    Parameters
    ----------
    grid_or_values : Grid or array_like
        The map or a ``(ny, nx)`` array, NaN = no data.
    window_cells : int
        Side of the square window, cells (odd keeps it centred).

    Returns
    -------
    numpy.ndarray
        ``(ny, nx)`` population std of the valid cells in the window (the window is cut at
        the map edges), field units; NaN on no-data cells.
    """
    from scipy.ndimage import uniform_filter

    z, _, _ = _values_and_cells(grid_or_values, 1.0)
    valid = ~np.isnan(z)
    if not valid.any():
        return np.full(z.shape, np.nan)
    centred = np.where(valid, z - np.nanmean(z), 0.0)
    size = int(window_cells)
    count = uniform_filter(valid.astype(float), size, mode="constant")
    s1 = uniform_filter(centred, size, mode="constant")
    s2 = uniform_filter(centred**2, size, mode="constant")
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s1 / count
        var = s2 / count - mean**2
    return np.where(valid, np.sqrt(np.clip(var, 0.0, None)), np.nan)
