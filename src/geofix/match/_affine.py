"""Helpers shared by ICCP and GA-SCA: beam sequences, track transforms, fix covariance.

Private to :mod:`geofix.match`; the public matchers are :mod:`geofix.match.iccp` and
:mod:`geofix.match.ga_sca`.
"""

from __future__ import annotations

import numpy as np

from geofix.errors import MatchError
from geofix.measurement import residuals
from geofix.problem import MatchProblem


def adaptive_spacing(depth_std: float, cell_m: float, mu1: float, mu2: float) -> float:
    """Across-track spacing of the side sequences, eq. (6) of source 000.

    Parameters
    ----------
    depth_std : float
        Standard deviation of the map values over the matching area, map units (metres).
    cell_m : float
        Map cell size ``C``, metres.
    mu1 : float
        Constant term, metres.
    mu2 : float
        Gain on the standard deviation, metres of spacing per map unit.

    Returns
    -------
    float
        ``mu1 + mu2 * depth_std`` when that exceeds ``cell_m``, else ``cell_m`` (metres).
    """
    spacing = mu1 + mu2 * depth_std
    return float(spacing) if spacing > cell_m else float(cell_m)


def window_std(problem: MatchProblem, half_m: float) -> float:
    """Standard deviation of the valid map values in the box around the indicated track.

    Parameters
    ----------
    problem : MatchProblem
        Map and indicated track.
    half_m : float
        Margin added on every side of the track's bounding box, metres.

    Returns
    -------
    float
        Population standard deviation of the map values, map units (NaN cells ignored).
    """
    window = map_window(problem, half_m)
    values = window[2]
    if not np.isfinite(values).any():
        raise MatchError("no valid map data around the indicated track")
    return float(np.nanstd(values))


def map_window(problem: MatchProblem, half_m: float) -> tuple[float, float, np.ndarray]:
    """The map cells within ``half_m`` metres of the indicated track's bounding box.

    Returns
    -------
    tuple
        ``(x0, y0, values)``: centre of the window's cell ``[0, 0]`` (metres) and the
        ``(rows, cols)`` values (row 0 south).

    Raises
    ------
    MatchError
        The box does not overlap the map.
    """
    grid = problem.grid
    lo = problem.indicated.min(axis=0) - half_m
    hi = problem.indicated.max(axis=0) + half_m
    c0, r0 = np.floor(grid.xy_to_cell(lo[0], lo[1])).astype(int)
    c1, r1 = np.ceil(grid.xy_to_cell(hi[0], hi[1])).astype(int) + 1
    ny, nx = grid.shape
    c0, r0 = max(c0, 0), max(r0, 0)
    c1, r1 = min(c1, nx), min(r1, ny)
    if c1 - c0 < 2 or r1 - r0 < 2:
        raise MatchError("the search window around the indicated track is off the map")
    x0, y0 = grid.cell_to_xy(c0, r0)
    return float(x0), float(y0), grid.values[r0:r1, c0:c1]


def nearest_beams(offsets: np.ndarray, spacing_m: float) -> np.ndarray:
    """Indices of the beams nearest to across-track ``0``, ``+spacing_m`` and ``-spacing_m``.

    Parameters
    ----------
    offsets : numpy.ndarray
        ``(b, 2)`` body-frame beam offsets ``(across, along)``, metres.
    spacing_m : float
        Wanted across-track distance of the side beams, metres.

    Returns
    -------
    numpy.ndarray
        ``(3,)`` beam indices ``[centre, starboard, port]``; a single-beam sensor gives
        ``[0]`` only (one sequence).
    """
    across = np.asarray(offsets, dtype=float)[:, 0]
    centre = int(np.argmin(np.abs(across)))
    if len(across) == 1:
        return np.array([centre])
    starboard = int(np.argmin(np.abs(across - spacing_m)))
    port = int(np.argmin(np.abs(across + spacing_m)))
    return np.array([centre, starboard, port])


def transform_tracks(track: np.ndarray, params: np.ndarray, pivot: np.ndarray) -> np.ndarray:
    """Apply four-parameter transforms ``(t_x, t_y, alpha, theta)`` to a track.

    ``p' = pivot + alpha * R(theta) (p - pivot) + (t_x, t_y)``, with ``R`` the
    counter-clockwise rotation in the (east, north) plane.

    Parameters
    ----------
    track : numpy.ndarray
        ``(n, 2)`` positions, metres.
    params : numpy.ndarray
        ``(P, 4)`` transforms: metres, metres, scale (1 = none), radians.
    pivot : numpy.ndarray
        ``(2,)`` fixed point of rotation and scale, metres.

    Returns
    -------
    numpy.ndarray
        ``(P, n, 2)`` transformed tracks, metres.
    """
    rel = np.asarray(track, dtype=float) - pivot
    c = np.cos(params[:, 3])[:, None]
    s = np.sin(params[:, 3])[:, None]
    a = params[:, 2][:, None]
    x = pivot[0] + a * (c * rel[:, 0] - s * rel[:, 1]) + params[:, 0][:, None]
    y = pivot[1] + a * (s * rel[:, 0] + c * rel[:, 1]) + params[:, 1][:, None]
    return np.stack([x, y], axis=-1)


def beam_positions(
    problem: MatchProblem, tracks: np.ndarray, theta: np.ndarray, beams: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Footprints of the chosen beams for transformed tracks.

    The heading of a track rotated counter-clockwise by ``theta`` is the indicated
    heading minus ``theta`` (headings are clockwise from north); its sine and cosine
    come from the angle-difference identity (``sin(psi - theta) = sin psi cos theta -
    cos psi sin theta``, ``cos(psi - theta) = cos psi cos theta + sin psi sin theta``),
    the operations in the order of the compiled GA-SCA fitness.

    Parameters
    ----------
    problem : MatchProblem
        Indicated heading and beam offsets.
    tracks : numpy.ndarray
        ``(P, n, 2)`` vehicle positions, metres.
    theta : numpy.ndarray
        ``(P,)`` rotation of each track, radians counter-clockwise.
    beams : numpy.ndarray
        ``(s,)`` beam indices.

    Returns
    -------
    tuple of numpy.ndarray
        ``(x, y)`` each ``(P, n, s)``, metres.
    """
    theta = np.asarray(theta, dtype=float)[:, None]
    c, sn = np.cos(theta), np.sin(theta)
    sin_h, cos_h = np.sin(problem.heading)[None, :], np.cos(problem.heading)[None, :]
    ss = (sin_h * c - cos_h * sn)[..., None]
    cs = (cos_h * c + sin_h * sn)[..., None]
    offsets = problem.offsets[beams]
    across, along = offsets[:, 0], offsets[:, 1]
    x = tracks[..., 0:1] + across * cs + along * ss
    y = tracks[..., 1:2] - across * ss + along * cs
    return x, y


def translation_covariance(
    problem: MatchProblem, track: np.ndarray, heading: np.ndarray, beams: np.ndarray
) -> np.ndarray | None:
    """Laplace approximation of the covariance of a fix's translation.

    The sum of squared differences between measured and map values (chosen beams) is
    evaluated on a 3 x 3 stencil of translations one cell apart around ``track``; its
    Hessian divided by ``2 sigma^2`` (``sigma`` the declared sensor noise plus map error,
    floored at a tenth of the residual RMS) is the information matrix of the translation.

    Parameters
    ----------
    problem : MatchProblem
        Map, beams, measurements, noise.
    track : numpy.ndarray
        ``(n, 2)`` matched vehicle positions, metres.
    heading : numpy.ndarray
        ``(n,)`` headings of the matched track, radians clockwise from north.
    beams : numpy.ndarray
        Beam indices used.

    Returns
    -------
    numpy.ndarray or None
        ``(2, 2)`` covariance, m^2, or None when the cost surface is not convex there.
    """
    h = problem.grid.cell_size
    steps = np.array([-h, 0.0, h])
    dx, dy = np.meshgrid(steps, steps)
    shifts = np.column_stack([dx.ravel(), dy.ravel()])
    tracks = track[None, :, :] + shifts[:, None, :]
    d = residuals(problem.grid, tracks, heading, problem.offsets[beams], problem.measured[:, beams])
    keep = np.isfinite(d).all(axis=0)
    if keep.sum() < 3:
        return None
    ssd = (d[:, keep] ** 2).sum(axis=1).reshape(3, 3)
    rms = np.sqrt(ssd[1, 1] / keep.sum())
    sigma = max(float(np.hypot(problem.noise_std, problem.map_error_std)), 0.1 * rms, 1e-9)
    hxx = (ssd[1, 2] - 2 * ssd[1, 1] + ssd[1, 0]) / h**2
    hyy = (ssd[2, 1] - 2 * ssd[1, 1] + ssd[0, 1]) / h**2
    hxy = (ssd[2, 2] - ssd[2, 0] - ssd[0, 2] + ssd[0, 0]) / (4 * h**2)
    info = np.array([[hxx, hxy], [hxy, hyy]]) / (2 * sigma**2)
    if np.linalg.det(info) <= 0 or info[0, 0] <= 0:
        return None
    return np.linalg.inv(info) + np.eye(2) * h**2 / 12
