"""Synthetic maps: fractal terrain by spectral synthesis, and tilted planes."""

from __future__ import annotations

import numpy as np

from geofix.errors import ConfigError
from geofix.maps.grid import Grid

DEFAULT_UNITS = {"depth": "m", "gravity": "mGal"}


def _power_law_noise(shape: tuple[int, int], hurst: float, rng: np.random.Generator) -> np.ndarray:
    """Zero-mean field with amplitude spectrum ``|k|^-(hurst + 1)`` (2-D fBm surface).

    Synthesised on a canvas twice the size and cropped, so that the result is not
    periodic (its opposite edges do not match).
    """
    ny, nx = shape
    white = rng.standard_normal((2 * ny, 2 * nx))
    ky = np.fft.fftfreq(2 * ny)[:, None]
    kx = np.fft.rfftfreq(2 * nx)[None, :]
    k = np.hypot(kx, ky)
    amplitude = np.zeros_like(k)
    amplitude[k > 0] = k[k > 0] ** -(hurst + 1.0)
    field = np.fft.irfft2(np.fft.rfft2(white) * amplitude, white.shape)
    return field[:ny, :nx]


def fractal_terrain(
    shape: tuple[int, int] = (256, 256),
    cell_m: float = 10.0,
    rng: np.random.Generator | None = None,
    hurst: float = 0.8,
    std: float = 5.0,
    mean: float = -100.0,
    kind: str = "depth",
    name: str = "fractal",
) -> Grid:
    """A fractal (fractional-Brownian) terrain by spectral synthesis.

    White Gaussian noise is filtered in the Fourier domain by a power-law amplitude
    ``|k|^-(hurst + 1)`` (power spectrum ``|k|^-(2 hurst + 2)``), then shifted and scaled so
    that its mean and (population) standard deviation are exactly ``mean`` and ``std``.

    Parameters
    ----------
    shape : (int, int)
        ``(ny, nx)`` cells.
    cell_m : float
        Cell size, metres.
    rng : numpy.random.Generator
        Source of randomness (required); the same generator state gives the same map.
    hurst : float
        Hurst exponent in (0, 1): smaller is rougher.
    std : float
        Standard deviation of the values, field units.
    mean : float
        Mean of the values, field units (default a 100 m deep seabed).
    kind : {"depth", "gravity"}
        Field kind; units are "m" or "mGal".
    name : str
        Map name.

    Returns
    -------
    Grid
        Cell ``[0, 0]`` centred at ``(0, 0)`` metres.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError("fractal_terrain needs an explicit numpy.random.Generator as rng")
    if not 0.0 < hurst < 1.0:
        raise ConfigError(f"hurst must be in (0, 1), got {hurst}")
    if not std >= 0:
        raise ConfigError(f"std must be non-negative, got {std}")
    ny, nx = shape
    field = _power_law_noise((int(ny), int(nx)), hurst, rng)
    field = (field - field.mean()) / field.std()
    values = mean + std * field
    meta = {"source": "fractal_terrain", "hurst": hurst, "std": std, "mean": mean}
    return Grid(
        values, 0.0, 0.0, float(cell_m), float(cell_m), kind, DEFAULT_UNITS[kind], name, meta
    )


def planar_grid(
    shape: tuple[int, int] = (64, 64),
    cell_m: float = 10.0,
    slope_x: float = 0.0,
    slope_y: float = 0.0,
    offset: float = -100.0,
    kind: str = "depth",
    x0: float = 0.0,
    y0: float = 0.0,
    name: str = "plane",
) -> Grid:
    """A tilted plane ``offset + slope_x * x + slope_y * y`` sampled at the cell centres.

    Bilinear sampling, gradients and plane fits are exact on it, which makes it the
    reference case for testing filters against a linear Kalman filter.

    Parameters
    ----------
    shape : (int, int)
        ``(ny, nx)`` cells.
    cell_m : float
        Cell size, metres.
    slope_x, slope_y : float
        Field change per metre east and north, field units per metre.
    offset : float
        Field value at ``(x, y) = (0, 0)``, field units.
    kind : {"depth", "gravity"}
        Field kind; units are "m" or "mGal".
    x0, y0 : float
        Centre of cell ``[0, 0]``, metres.
    name : str
        Map name.

    Returns
    -------
    Grid
        The plane.
    """
    ny, nx = (int(n) for n in shape)
    x = x0 + cell_m * np.arange(nx)
    y = y0 + cell_m * np.arange(ny)
    values = offset + slope_x * x[None, :] + slope_y * y[:, None]
    meta = {"source": "planar_grid", "slope_x": slope_x, "slope_y": slope_y, "offset": offset}
    return Grid(
        values,
        float(x0),
        float(y0),
        float(cell_m),
        float(cell_m),
        kind,
        DEFAULT_UNITS[kind],
        name,
        meta,
    )
