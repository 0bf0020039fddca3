"""The one measurement model: prediction, residuals, likelihood, linearisation, information.

A sensor reading is the map ``h`` read at a beam's footprint plus noise. Everything in
geofix that predicts a reading calls this module: the simulator
(:mod:`geofix.sim.sensing` adds noise and lag to :func:`predict_track`), every batch
matcher (:func:`predict_track`, :func:`residuals`), every recursive filter
(:func:`predict_measurements` on many hypotheses, :func:`log_likelihood`,
:func:`linearise`) and every bound (:func:`beam_gradients`, :func:`sample_information`).

- Prediction: the map read at every footprint (:func:`geofix.problem.footprint_xy`),
  NaN off the map and on no-data: the grid's ``interpolation`` for the recursive filters
  (:func:`predict_measurements`), bilinear unless asked otherwise along a track
  (:func:`predict_track`).
- Likelihood: independent Gaussian beams of variance sensor noise plus map error.
- Linearisation (SITAN): slopes of a least-squares plane fitted over a patch the size of
  the position uncertainty (stochastic terrain linearisation), the patch read with the
  grid's ``interpolation`` like the prediction.
- Sensor lag: :func:`lag_compensated` undoes a gravimeter's declared first-order lag
  (``problem.lag_s``) causally, so that the recursive filters weigh the readings the
  model above describes.
- Information: the Fisher information of a sample about the vehicle position,
  ``sum_b g g^T / var_b`` with ``g`` the map gradient at each footprint (the exact
  gradient of the grid's interpolant, or of the read named).
"""

from __future__ import annotations

import functools
import threading
from dataclasses import dataclass

import numpy as np
from scipy.special import gammaln

from geofix import _likelihood_kernels as kernels
from geofix._measurement_kernels import gaussian_log_likelihood
from geofix.maps.grid import Grid
from geofix.maps.mapread import read_beams
from geofix.maps.terrain import gradient, plane_fit
from geofix.memory import cells_bytes, check_allocation
from geofix.problem import MatchProblem, footprint_xy
from geofix.sensors.gravimeter import compensate_first_order_lag

OFF_MAP_LOG_LIKELIHOOD = -1e6
"""Log-likelihood per beam of a hypothesis whose footprint is off the map (finite, so a
filter whose every hypothesis is off the map stays defined)."""


def predict_measurements(grid: Grid, positions: np.ndarray, heading: float, offsets) -> np.ndarray:
    """Field values every beam would read from ``positions``.

    Parameters
    ----------
    grid : Grid
        The map.
    positions : numpy.ndarray
        ``(..., 2)`` hypothesised vehicle positions, metres.
    heading : float
        Heading, radians clockwise from north.
    offsets : numpy.ndarray
        ``(b, 2)`` body-frame beam offsets, metres.

    Returns
    -------
    numpy.ndarray
        ``(..., b)`` predicted values; NaN off the map and wherever a cell of the
        stencil is NaN (as :meth:`Grid.sample`): the compiled read of
        :mod:`geofix.maps.mapread` the grid's ``interpolation`` names (bilinear unless
        set), beam offsets added in cells.
    """
    positions = np.asarray(positions, dtype=float)
    offsets = np.asarray(offsets, dtype=float)
    # The beam offsets in metres are the same for every hypothesis: add them in cells.
    ox, oy = footprint_xy(np.zeros(2), np.asarray(heading, dtype=float), offsets)
    hypotheses = positions.size // 2
    check_allocation(
        cells_bytes(hypotheses, offsets.shape[0], copies=6),
        f"map prediction of {hypotheses} hypotheses x {offsets.shape[0]} beams",
    )
    col, row = grid.xy_to_cell(positions[..., 0].ravel(), positions[..., 1].ravel())
    out = read_beams(grid.values, col, row, ox / grid.dx, oy / grid.dy, grid.interpolation)
    return out.reshape(*positions.shape[:-1], offsets.shape[0])


def predict_track(grid: Grid, track, heading, offsets, method: str = "bilinear") -> np.ndarray:
    """Field values every beam reads along one or many tracks.

    Parameters
    ----------
    grid : Grid
        The map.
    track : array_like
        ``(..., n, 2)`` vehicle positions, metres.
    heading : array_like
        ``(..., n)`` headings, radians clockwise from north (broadcast against ``track``).
    offsets : array_like
        ``(b, 2)`` body-frame beam offsets ``(across, along)``, metres.
    method : {"bilinear", "nearest"}
        The map read (:meth:`Grid.sample`).

    Returns
    -------
    numpy.ndarray
        ``(..., n, b)`` predicted values, map units; NaN off the map and on no-data.
    """
    x, y = footprint_xy(
        np.asarray(track, dtype=float), np.asarray(heading, dtype=float), np.asarray(offsets)
    )
    return grid.sample(x, y, method=method)


def residuals(grid: Grid, track, heading, offsets, measured, method: str = "bilinear"):
    """Predicted minus measured values along one or many tracks.

    Parameters
    ----------
    grid : Grid
        The map.
    track : array_like
        ``(..., n, 2)`` vehicle positions, metres.
    heading : array_like
        ``(..., n)`` headings, radians clockwise from north (broadcast against ``track``).
    offsets : array_like
        ``(b, 2)`` body-frame beam offsets ``(across, along)``, metres.
    measured : array_like
        ``(n, b)`` measured values, map units (NaN = missing), broadcast against the
        prediction.
    method : {"bilinear", "nearest"}
        The map read (:meth:`Grid.sample`).

    Returns
    -------
    numpy.ndarray
        ``(..., n, b)`` residuals, map units; NaN where a beam is missing or off the map.
    """
    return predict_track(grid, track, heading, offsets, method) - np.asarray(measured)


def log_likelihood(
    predicted: np.ndarray,
    measured: np.ndarray,
    noise_var,
    bias_var: float = 0.0,
    modes=None,
    dof: float = np.inf,
) -> np.ndarray:
    """Gaussian log-likelihood of the measured beams for every hypothesis.

    Parameters
    ----------
    predicted : numpy.ndarray
        ``(..., b)`` predicted values (NaN off the map).
    measured : numpy.ndarray
        ``(b,)`` measured values (NaN = missing beam, ignored).
    noise_var : float or numpy.ndarray
        Measurement variance (sensor + map error), map units squared: one value for
        every beam or ``(b,)`` per beam (each beam's squared residual is divided by its
        own variance).
    bias_var : float
        Variance of an unknown offset common to every beam of the sample (tide, sound
        speed, map datum), map units squared; 0: none. When positive the likelihood is
        marginalised over it (:func:`common_bias_log_likelihood`).
    modes : numpy.ndarray, optional
        ``(b, k)`` shapes of a map error common to the beams of the sample, each column
        one shape times its 1-sigma (map units): the likelihood is marginalised over
        them too (:func:`low_rank_log_likelihood`). None: none.
    dof : float
        Degrees of freedom of a Student-t likelihood of the ping (:func:`student_t`);
        inf: the Gaussian.

    Returns
    -------
    numpy.ndarray
        ``(...)`` log-likelihoods up to a constant; off-map beams cost
        :data:`OFF_MAP_LOG_LIKELIHOOD` each.
    """
    if modes is not None:
        columns = _with_offset(modes, bias_var)
        return low_rank_log_likelihood(predicted, measured, noise_var, columns, dof=dof)
    if bias_var > 0 or np.isfinite(dof):
        return common_bias_log_likelihood(predicted, measured, noise_var, bias_var, dof)
    measured = np.asarray(measured, dtype=float)
    flat = np.asarray(predicted, dtype=float).reshape(-1, measured.shape[0])
    ll = gaussian_log_likelihood(flat, measured, noise_var, OFF_MAP_LOG_LIKELIHOOD)
    return ll.reshape(predicted.shape[:-1])


# --------------------------------------------------------------------------- fused paths
def hypotheses_log_likelihood(
    grid: Grid,
    positions: np.ndarray,
    heading: float,
    offsets,
    measured,
    noise_var,
    bias_var: float = 0.0,
    shift=None,
    modes=None,
    dof: float = np.inf,
) -> np.ndarray:
    """Gaussian log-likelihood of the measured beams from every hypothesised position.

    The numbers of ``log_likelihood(predict_measurements(grid, positions, heading,
    offsets), measured, noise_var)`` (the same reads; the sum over beams reassociated,
    within ~1e-15 relative) in one compiled pass over hypotheses and beams: no
    ``(hypotheses, beams)`` array of predictions is built, and missing beams are not read.

    Parameters
    ----------
    grid : Grid
        The map.
    positions : numpy.ndarray
        ``(..., 2)`` hypothesised vehicle positions, metres.
    heading : float
        Heading, radians clockwise from north.
    offsets : numpy.ndarray
        ``(b, 2)`` body-frame beam offsets, metres.
    measured : numpy.ndarray
        ``(b,)`` measured values (NaN = missing beam).
    noise_var : float or numpy.ndarray
        Measurement variance, map units squared, scalar or ``(b,)``.
    bias_var : float
        Variance of an offset common to every beam, marginalised out
        (:func:`common_bias_log_likelihood`); 0: none. With an offset, or a map read
        other than bilinear (``grid.interpolation``), the numbers come from the
        prediction array instead of the fused pass.
    shift : numpy.ndarray, optional
        ``(...)`` each hypothesis's own offset added to its predictions, map units (a
        per-hypothesis offset state, :mod:`geofix.filters.hypothesis_offset`; through
        the prediction array).
    modes : numpy.ndarray, optional
        ``(b, k)`` map-error shapes marginalised over (:func:`log_likelihood`; through
        the prediction array).
    dof : float
        A Student-t likelihood's degrees of freedom (:func:`student_t`; through the
        prediction array); inf: the Gaussian.

    Returns
    -------
    numpy.ndarray
        ``(...)`` log-likelihoods up to a constant (off-map beams cost
        :data:`OFF_MAP_LOG_LIKELIHOOD` each).
    """
    positions = np.asarray(positions, dtype=float)
    reference = bias_var > 0 or shift is not None or modes is not None or np.isfinite(dof)
    if reference or grid.interpolation != "bilinear":
        predicted = predict_measurements(grid, positions, heading, offsets)
        if shift is not None:
            predicted = predicted + np.asarray(shift, dtype=float)[..., None]
        return log_likelihood(predicted, measured, noise_var, bias_var, modes, dof)
    bcol, brow, y, var = _measured_beams(grid, heading, offsets, measured, noise_var)
    px, py = _flat_xy(positions)
    out = np.empty(px.size)
    origin, cell = _origin_cell(grid)
    kernels.hypotheses_ll(
        _map_values(grid), origin, cell, px, py, bcol, brow, y, var, OFF_MAP_LOG_LIKELIHOOD, out
    )
    return out.reshape(positions.shape[:-1])


def local_field_log_likelihood(
    grid: Grid,
    positions: np.ndarray,
    heading: float,
    offsets,
    measured,
    noise_var,
    sides,
    bias_var: float = 0.0,
    shift=None,
    modes=None,
    dof: float = np.inf,
) -> np.ndarray:
    r"""Log-likelihood of every hypothesis with the field's variation within its own share.

    A point-mass node or a particle stands for the vehicle anywhere in its share of the
    area, a parallelogram with the two ``sides`` centred on the hypothesis. With the
    position uniform there, the reading of beam ``k`` is, to first order,
    ``f_k + d1_k a + d2_k c``: ``f_k`` the map read from the hypothesis, ``d1_k``, ``d2_k``
    the change of that read when the hypothesis moves by each side, and ``a``, ``c``
    uniform on ``[-1/2, 1/2]`` (variance 1/12), the same two numbers for every beam. The
    residual ``r = y - f`` is then ``N(0, R + D D^T / 12)`` (``R`` the diagonal sensor plus
    map variance, ``D`` the ``(b, 2)`` differences): the discretisation noise of the
    approximation, local to each hypothesis and common to its beams, and

    ``log L = -0.5 (r^T W r - u^T (12 I + D^T W D)^-1 u + log det(I + D^T W D / 12))``

    with ``W = R^-1`` and ``u = D^T W r`` (Woodbury's identity and the matrix determinant
    lemma; the ``log det R`` common to every hypothesis is dropped). On rough terrain the
    residual of a hypothesis a fraction of its share off the truth lies along ``D`` and
    is discounted, while a residual no shift within the share explains is not; the
    log-determinant is the price of the wider density. A hypothesis whose field does not
    change within its share (``D = 0``) has the numbers of
    :func:`hypotheses_log_likelihood`.

    Parameters
    ----------
    grid : Grid
        The map.
    positions : numpy.ndarray
        ``(..., 2)`` hypothesised vehicle positions, metres.
    heading : float
        Heading, radians clockwise from north.
    offsets : numpy.ndarray
        ``(b, 2)`` body-frame beam offsets, metres.
    measured : numpy.ndarray
        ``(b,)`` measured values (NaN = missing beam).
    noise_var : float or numpy.ndarray
        Measurement variance, map units squared, scalar or ``(b,)`` (positive).
    sides : numpy.ndarray
        ``(2, 2)`` the two sides of a hypothesis's share as rows ``(dx, dy)``, metres.
    bias_var : float
        Variance of an offset common to every beam, marginalised out as well (a third
        column ``sqrt(12 bias_var) 1`` of ``D``); with it, or a map read other than
        bilinear, the numbers come from the prediction arrays
        (:func:`local_field_reference`).
    shift : numpy.ndarray, optional
        ``(...)`` each hypothesis's own offset added to its predictions, map units
        (through the prediction arrays too).
    modes : numpy.ndarray, optional
        ``(b, k)`` map-error shapes common to the beams, marginalised over as further
        columns of ``D`` (through the prediction arrays).
    dof : float
        A Student-t likelihood's degrees of freedom (:func:`student_t`; through the
        prediction arrays); inf: the Gaussian.

    Returns
    -------
    numpy.ndarray
        ``(...)`` log-likelihoods up to a constant (off-map beams cost
        :data:`OFF_MAP_LOG_LIKELIHOOD` each; a difference off the map counts 0).
    """
    positions = np.asarray(positions, dtype=float)
    sides = np.asarray(sides, dtype=float).reshape(2, 2)
    reference = bias_var > 0 or shift is not None or modes is not None or np.isfinite(dof)
    if reference or grid.interpolation != "bilinear":
        args = (measured, noise_var, sides, bias_var, shift, modes, dof)
        return local_field_reference(grid, positions, heading, offsets, *args)
    bcol, brow, y, var = _measured_beams(grid, heading, offsets, measured, noise_var)
    px, py = _flat_xy(positions)
    out = np.empty(px.size)
    origin, cell = _origin_cell(grid)
    shifts = np.ascontiguousarray(sides / cell)  # (dcol, drow) per side
    values = _map_values(grid)
    off = OFF_MAP_LOG_LIKELIHOOD
    kernels.hypotheses_ll_local(values, origin, cell, px, py, bcol, brow, shifts, y, var, off, out)
    return out.reshape(positions.shape[:-1])


def node_grid_local_log_likelihood(
    grid: Grid,
    frame: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    spacing,
    heading: float,
    offsets,
    measured,
    noise_var,
) -> np.ndarray:
    """:func:`local_field_log_likelihood` at every node of a regular point-mass grid.

    Node ``[i, j]`` sits at ``centre + u[i] axes[:, 0] + v[j] axes[:, 1]`` and its cell's
    sides are one node step along each axis (``spacing`` ``(2,)``, metres). One compiled
    pass reads the field once from every node and from one more row and column of nodes
    beyond the grid; the next node along each axis gives the field's change over the
    cell (the reads of :func:`local_field_reference` at the moved nodes, to the rounding
    of the node positions). Bilinear map reads; no common offset.

    Parameters
    ----------
    grid : Grid
        The map.
    frame : tuple
        ``(centre (2,), axes (2, 2), u (N0,), v (N1,))``: the grid's middle, its axes as
        columns and the node coordinates along them, metres.
    spacing : array_like
        ``(2,)`` node step along each axis, metres: the sides of a node's cell.
    heading : float
        Heading, radians clockwise from north.
    offsets : numpy.ndarray
        ``(b, 2)`` body-frame beam offsets, metres.
    measured : numpy.ndarray
        ``(b,)`` measured values (NaN = missing beam).
    noise_var : float or numpy.ndarray
        Measurement variance, map units squared, scalar or ``(b,)`` (positive).

    Returns
    -------
    numpy.ndarray
        ``(N0, N1)`` log-likelihoods up to a constant.
    """
    centre, axes, u, v = (np.ascontiguousarray(a, dtype=float) for a in frame)
    spacing = np.asarray(spacing, dtype=float)
    u1 = np.append(u, u[-1] + spacing[0])
    v1 = np.append(v, v[-1] + spacing[1])
    bcol, brow, y, var = _measured_beams(grid, heading, offsets, measured, noise_var)
    out = np.empty((u.size, v.size))
    origin, cell = _origin_cell(grid)
    p = _scratch(u1.size, v1.size, bcol.size)
    off = OFF_MAP_LOG_LIKELIHOOD
    values = _map_values(grid)
    kernels.node_ll_local(
        values, origin, cell, centre, axes, u1, v1, bcol, brow, y, var, off, p, out
    )
    return out


def local_field_reference(
    grid: Grid,
    positions,
    heading: float,
    offsets,
    measured,
    noise_var,
    sides,
    bias_var=0.0,
    shift=None,
    modes=None,
    dof: float = np.inf,
) -> np.ndarray:
    """:func:`local_field_log_likelihood` from the prediction arrays (any map read).

    The reads at the hypotheses and at the hypotheses moved by each side
    (:func:`predict_measurements`), then the Gaussian of covariance ``R + Z Z^T`` per
    hypothesis, ``Z = [D / sqrt(12), sqrt(bias_var) 1]`` (without the last column when
    ``bias_var`` is 0), by a small solve per hypothesis.

    Parameters
    ----------
    grid : Grid
        The map (any ``interpolation``).
    positions : numpy.ndarray
        ``(..., 2)`` hypothesised vehicle positions, metres.
    heading : float
        Heading, radians clockwise from north.
    offsets : numpy.ndarray
        ``(b, 2)`` body-frame beam offsets, metres.
    measured : numpy.ndarray
        ``(b,)`` measured values (NaN = missing beam).
    noise_var : float or numpy.ndarray
        Measurement variance, map units squared, scalar or ``(b,)`` (positive).
    sides : numpy.ndarray
        ``(2, 2)`` the two sides of a hypothesis's share as rows ``(dx, dy)``, metres.
    bias_var : float
        Variance of an offset common to every beam, map units squared (0: none).
    shift : numpy.ndarray, optional
        ``(...)`` each hypothesis's own offset subtracted from its residuals, map units.
    modes : numpy.ndarray, optional
        ``(b, k)`` map-error shapes common to the beams, further columns of ``Z``.
    dof : float
        A Student-t likelihood's degrees of freedom (:func:`student_t`); inf: the
        Gaussian.

    Returns
    -------
    numpy.ndarray
        ``(...)`` log-likelihoods up to a constant (off-map beams cost
        :data:`OFF_MAP_LOG_LIKELIHOOD` each).
    """
    reads = local_field_reads(grid, positions, heading, offsets, sides)
    return local_field_from_reads(reads, measured, noise_var, bias_var, shift, modes, dof)


def local_field_reads(grid: Grid, positions, heading: float, offsets, sides, predicted=None):
    """The map reads of :func:`local_field_reference`, for several likelihoods of one ping.

    Parameters
    ----------
    grid : Grid
        The map (any ``interpolation``).
    positions : numpy.ndarray
        ``(..., 2)`` the hypotheses, metres.
    heading : float
        Radians clockwise from north.
    offsets : numpy.ndarray
        ``(b, 2)`` body-frame beam offsets, metres.
    sides : numpy.ndarray
        ``(2, 2)`` the sides of a hypothesis's share as rows, metres.
    predicted : numpy.ndarray, optional
        ``(..., b)`` the reads at ``positions`` when the caller has them, map units.

    Returns
    -------
    tuple
        ``(f0 (m, b), own (m, b, 2), shape)``: the reads at the ``m`` flattened
        hypotheses (map units), the change of each when the hypothesis moves by each side
        over ``sqrt(12)`` (0 where either read is off the map), and the hypotheses' shape.
    """
    positions = np.asarray(positions, dtype=float)
    sides = np.asarray(sides, dtype=float).reshape(2, 2)
    beams = np.asarray(offsets).reshape(-1, 2).shape[0]
    if predicted is None:
        predicted = predict_measurements(grid, positions, heading, offsets)
    f0 = np.asarray(predicted, dtype=float).reshape(-1, beams)
    columns = []
    for side in sides:
        moved = predict_measurements(grid, positions + side, heading, offsets)
        d = moved.reshape(f0.shape) - f0
        columns.append(np.where(np.isfinite(d), d, 0.0) / np.sqrt(12.0))
    return f0, np.stack(columns, axis=-1), positions.shape[:-1]


def local_field_from_reads(
    reads, measured, noise_var, bias_var=0.0, shift=None, modes=None, dof: float = np.inf
) -> np.ndarray:
    """:func:`local_field_reference` from its reads (:func:`local_field_reads`).

    Parameters
    ----------
    reads : tuple
        What :func:`local_field_reads` returns for the ping.
    measured : numpy.ndarray
        ``(b,)`` measured values (NaN = missing beam), map units.
    noise_var : float or numpy.ndarray
        Per-beam variance, map units squared.
    bias_var : float
        Variance of an offset common to every beam (0: none), map units squared.
    shift : numpy.ndarray, optional
        ``(...)`` each hypothesis's own offset added to its reads, map units.
    modes : numpy.ndarray, optional
        ``(b, k)`` map-error shapes common to the beams.
    dof : float
        A Student-t likelihood's degrees of freedom (:func:`student_t`); inf: the
        Gaussian.

    Returns
    -------
    numpy.ndarray
        ``(...)`` log-likelihoods up to a constant, as :func:`local_field_reference`.
    """
    f0, own, shape = reads
    measured = np.asarray(measured, dtype=float)
    if shift is not None:
        f0 = f0 + np.asarray(shift, dtype=float).reshape(-1, 1)
    common = _with_offset(modes, bias_var, measured.shape[0])
    return low_rank_log_likelihood(f0, measured, noise_var, common, own, dof).reshape(shape)


def shift_field_variance(
    grid: Grid, positions: np.ndarray, heading: float, offsets, measured, spacing: float
) -> float:
    """Field variance within a square of side ``spacing`` around each position, units^2.

    ``(mean(d_x^2) + mean(d_y^2)) / 12`` over the measured beams of every position, with
    ``d_x``, ``d_y`` the change of each beam's read when the vehicle moves by ``spacing``
    metres along x and along y (finite changes only; 0 when none is). Bilinear maps in one
    compiled pass, with no ``(positions, beams)`` array; other reads through
    :func:`predict_measurements`. The sums are plain running sums (numpy's ``mean``
    pairs its terms: the two differ in the last digits).

    Parameters
    ----------
    grid : Grid
        The map.
    positions : numpy.ndarray
        ``(..., 2)`` vehicle positions, metres.
    heading : float
        Heading, radians clockwise from north.
    offsets : numpy.ndarray
        ``(b, 2)`` body-frame beam offsets, metres.
    measured : numpy.ndarray
        ``(b,)`` measured values; only the beams with a finite value count.
    spacing : float
        Side of the square, metres.

    Returns
    -------
    float
        The field variance, map units squared.
    """
    positions = np.asarray(positions, dtype=float).reshape(-1, 2)
    offsets = np.asarray(offsets, dtype=float)[np.isfinite(np.asarray(measured, dtype=float))]
    if grid.interpolation != "bilinear":
        read = [
            predict_measurements(grid, positions + shift, heading, offsets)
            for shift in ((0.0, 0.0), (spacing, 0.0), (0.0, spacing))
        ]
        squares = [(moved - read[0]) ** 2 for moved in read[1:]]
        sums = [(float(np.nansum(q)), float(np.count_nonzero(~np.isnan(q)))) for q in squares]
    else:
        bcol, brow = _beam_cells(grid, heading, offsets)
        origin, cell = _origin_cell(grid)
        out = np.zeros(4)
        px, py = _flat_xy(positions)
        kernels.shift_squares(_map_values(grid), origin, cell, px, py, bcol, brow, spacing, out)
        sums = [(out[0], out[1]), (out[2], out[3])]
    return sum(total / count for total, count in sums if count > 0) / 12.0


def node_grid_log_likelihood(
    grid: Grid,
    frame: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    heading: float,
    offsets,
    measured,
    noise_var,
    field_variance: bool,
) -> tuple[np.ndarray, float]:
    """Log-likelihood of the measured beams at every node of a regular point-mass grid.

    Node ``[i, j]`` sits at ``centre + u[i] axes[:, 0] + v[j] axes[:, 1]``. The numbers are
    those of the reference path (node positions, :func:`predict_measurements`, then
    :func:`log_likelihood`; the same reads, the sums reassociated, within ~1e-15
    relative) from one compiled pass.

    Parameters
    ----------
    grid : Grid
        The map.
    frame : tuple
        ``(centre (2,), axes (2, 2), u (N0,), v (N1,))``: the grid's middle, its axes as
        columns and the node coordinates along them, metres.
    heading : float
        Heading, radians clockwise from north.
    offsets : numpy.ndarray
        ``(b, 2)`` body-frame beam offsets, metres.
    measured : numpy.ndarray
        ``(b,)`` measured values (NaN = missing beam).
    noise_var : float or numpy.ndarray
        Measurement variance, map units squared, scalar or ``(b,)``.
    field_variance : bool
        Add to every beam's variance the field variance within one node (the PMF's
        discretisation noise: ``(mean(d0^2) + mean(d1^2)) / 12`` over the neighbour
        differences of the measured beams). The predictions are then held in a scratch
        array reused from call to call (sized and checked against the memory budget).

    Returns
    -------
    tuple
        ``(log_likelihood (N0, N1), field_var)``: log-likelihoods up to a constant and the
        field variance added (0 when ``field_variance`` is False), map units squared.
    """
    centre, axes, u, v = (np.ascontiguousarray(a, dtype=float) for a in frame)
    bcol, brow, y, var = _measured_beams(grid, heading, offsets, measured, noise_var)
    out = np.empty((u.size, v.size))
    origin, cell = _origin_cell(grid)
    values = _map_values(grid)
    off = OFF_MAP_LOG_LIKELIHOOD
    if not field_variance:
        kernels.node_ll(values, origin, cell, centre, axes, u, v, bcol, brow, y, var, off, out)
        return out, 0.0
    p = _scratch(u.size, v.size, bcol.size)
    args = (values, origin, cell, centre, axes, u, v, bcol, brow, y, var, off, p, out)
    return out, float(kernels.node_ll_flattened(*args))


def _measured_beams(grid: Grid, heading: float, offsets, measured, noise_var) -> tuple:
    """``(beam_col, beam_row, measured, var)`` of the measured beams, contiguous float64.

    The beam offsets are in map cells, as :func:`predict_measurements` adds them.
    """
    measured = np.asarray(measured, dtype=float)
    bcol, brow = _beam_cells(grid, heading, offsets)
    use = ~np.isnan(measured)
    var = np.broadcast_to(np.asarray(noise_var, dtype=float), measured.shape)
    return bcol[use], brow[use], np.ascontiguousarray(measured[use]), np.ascontiguousarray(var[use])


def _beam_cells(grid: Grid, heading: float, offsets) -> tuple[np.ndarray, np.ndarray]:
    """``(beam_col, beam_row)``: every beam's offset in map cells, contiguous float64."""
    offsets = np.asarray(offsets, dtype=float)
    ox, oy = footprint_xy(np.zeros(2), np.asarray(heading, dtype=float), offsets)
    return np.ascontiguousarray(ox / grid.dx), np.ascontiguousarray(oy / grid.dy)


def _flat_xy(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Contiguous ``(x, y)`` of ``(..., 2)`` positions, flattened, metres."""
    return (
        np.ascontiguousarray(positions[..., 0].ravel()),
        np.ascontiguousarray(positions[..., 1].ravel()),
    )


def _origin_cell(grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    return np.array([grid.x0, grid.y0], dtype=float), np.array([grid.dx, grid.dy], dtype=float)


def _map_values(grid: Grid) -> np.ndarray:
    values = grid.values
    if values.dtype not in (np.float32, np.float64) or not values.flags.c_contiguous:
        values = np.ascontiguousarray(values, dtype=np.float64)
    return values


_SCRATCH = threading.local()
SCRATCH_KEEP_BYTES = 64 * 2**20
"""Largest scratch array kept for the next call (a bigger one is allocated each time)."""


def _scratch(n0: int, n1: int, beams: int) -> np.ndarray:
    """A ``(n0, beams, n1)`` float64 scratch array, reused by later calls of this thread.

    Node rows beam by beam: ``p[i, k, j]`` is beam ``k``'s read from node ``[i, j]``.
    """
    check_allocation(
        cells_bytes(n0, n1, beams), f"node predictions of {n0} x {n1} nodes x {beams} beams"
    )
    size = n0 * n1 * beams
    buffer = getattr(_SCRATCH, "buffer", None)
    if buffer is None or buffer.size < size:
        buffer = np.empty(max(size, 1))
        if 8 * size <= SCRATCH_KEEP_BYTES:
            _SCRATCH.buffer = buffer
    return buffer[:size].reshape(n0, beams, n1)


def map_error_variance(error_std: Grid | None, position, heading: float, offsets) -> np.ndarray:
    """Per-cell map-error variance at every beam's footprint, map units squared.

    Parameters
    ----------
    error_std : Grid or None
        The map's uncertainty layer (per-cell standard deviation, e.g.
        :class:`geofix.maps.gridding.GriddedMap`); None gives zeros.
    position : array_like
        ``(2,)`` vehicle position the footprints are taken from (the current estimate),
        metres.
    heading : float
        Heading, radians clockwise from north.
    offsets : numpy.ndarray
        ``(b, 2)`` body-frame beam offsets, metres.

    Returns
    -------
    numpy.ndarray
        ``(b,)`` ``std^2`` of the cell under each beam (nearest cell), 0 where the layer
        has no value; added to the measurement variance of that beam.
    """
    offsets = np.asarray(offsets, dtype=float)
    if error_std is None:
        return np.zeros(offsets.shape[0])
    x, y = footprint_xy(np.asarray(position, dtype=float), np.asarray(heading, float), offsets)
    std = error_std.sample(x, y, method="nearest")
    return np.where(np.isfinite(std), std**2, 0.0)


@dataclass(frozen=True)
class Linearisation:
    """Local linear model of the field around an estimate, one row per beam.

    ``predicted`` ``(b,)`` values read at the estimate; ``slopes`` ``(b, 2)`` field units
    per metre along x and y; ``fit_var`` ``(b,)`` residual variance of the plane fits
    (added to the measurement noise as linearisation error).
    """

    predicted: np.ndarray
    slopes: np.ndarray
    fit_var: np.ndarray


def linearise(grid: Grid, position, heading: float, offsets, half_width_m: float) -> Linearisation:
    """Stochastic terrain linearisation at every beam's footprint.

    A least-squares plane is fitted to the map over a square patch of half-width
    ``half_width_m`` (the position uncertainty, metres; at least one cell) around each
    footprint; its slopes form the rows of the measurement Jacobian. The patch and the
    predicted values are read with the grid's ``interpolation``
    (:func:`geofix.maps.terrain.plane_fit`), so the filter linearises the interpolant it
    predicts with.

    ``position`` is ``(2,)`` (one estimate: arrays ``(b,)`` / ``(b, 2)``) or ``(..., 2)``
    (several estimates at once, same heading and patch: arrays ``(..., b)`` / ``(..., b, 2)``).

    Parameters
    ----------
    grid : Grid
        The map.
    position : array_like
        ``(2,)`` or ``(..., 2)`` estimated vehicle position(s), metres.
    heading : float
        Heading, radians clockwise from north.
    offsets : array_like
        ``(b, 2)`` body-frame beam offsets, metres.
    half_width_m : float
        Half-width of the fitted patch, metres (raised to one cell at least).

    Returns
    -------
    Linearisation
        Predicted values, slopes (map units per metre) and fit variances per beam.
    """
    pos = np.asarray(position, dtype=float)[..., None, :]
    x, y = footprint_xy(pos, np.full(pos.shape[:-1], heading), np.asarray(offsets, dtype=float))
    x, y = x[..., 0, :], y[..., 0, :]
    fit = plane_fit(grid, x, y, max(half_width_m, grid.cell_size))
    slopes = np.stack([fit.slope_x, fit.slope_y], axis=-1)
    return Linearisation(
        predicted=grid.sample(x, y),
        slopes=slopes,
        fit_var=np.asarray(fit.residual_std, dtype=float) ** 2,
    )


# --------------------------------------------------------------------------- information
@functools.lru_cache(maxsize=4)
def gradient_grids(grid: Grid) -> tuple[Grid, Grid]:
    """The map's central-difference gradient along x and y as two grids (NaN where none).

    Used by the suitability maps; the bounds use the exact interpolant gradient
    (:func:`beam_gradients`).

    Parameters
    ----------
    grid : Grid
        The map (cached by identity: a campaign worker computes it once).

    Returns
    -------
    tuple of Grid
        ``(gx, gy)`` in field units per metre, on the map's cells (central differences,
        :func:`geofix.maps.terrain.gradient`).
    """
    gx, gy = gradient(grid)
    return grid.with_values(gx), grid.with_values(gy)


def beam_gradients(
    grid: Grid, track, heading, offsets, method: str | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Exact gradient of the map read at every beam footprint of a track.

    Parameters
    ----------
    grid : Grid
        The map.
    track : array_like
        ``(n, 2)`` vehicle positions, metres.
    heading : array_like
        ``(n,)`` headings, radians clockwise from north.
    offsets : array_like
        ``(b, 2)`` body-frame beam offsets ``(across, along)``, metres.
    method : {"bilinear", "bicubic"}, optional
        The read whose gradient is taken (default: the grid's ``interpolation``,
        :meth:`Grid.sample_gradient`).

    Returns
    -------
    tuple of numpy.ndarray
        ``(gx, gy)`` each ``(n, b)``, field units per metre; 0 where no gradient exists.
    """
    x, y = footprint_xy(
        np.asarray(track, float), np.asarray(heading, float), np.asarray(offsets, float)
    )
    _, gx, gy = grid.sample_gradient(x, y, method)
    return np.nan_to_num(gx, nan=0.0), np.nan_to_num(gy, nan=0.0)


def sample_information(gx, gy, beam_var, valid=None, offset_var: float = 0.0) -> np.ndarray:
    """Fisher information of each sample about the vehicle position.

    Parameters
    ----------
    gx, gy : array_like
        ``(n, b)`` map gradients at the footprints, field units per metre.
    beam_var : float or array_like
        Measurement variance, field units squared: a scalar or ``(b,)`` per beam.
    valid : array_like of bool, optional
        ``(n, b)``; False for a missing measurement (it carries no information).
    offset_var : float
        Variance ``P`` of an offset common to the beams of each sample, a nuisance drawn
        anew per sample, field units squared (0: none; ``inf``: unknown). The residual's
        covariance is then ``R + P 1 1^T`` and the information
        ``sum w g g^T - P u u^T / (1 + P S)`` with ``u = sum w g``, ``S = sum w``
        (``w = 1 / R_b``; Sherman-Morrison): what the sample's shape tells, its level
        not.

    Returns
    -------
    numpy.ndarray
        ``(n, 2, 2)`` information matrices, 1/m^2.
    """
    gx = np.asarray(gx, float)
    gy = np.asarray(gy, float)
    w = np.broadcast_to(1.0 / np.asarray(beam_var, float), gx.shape)
    if valid is not None:
        w = np.where(valid, w, 0.0)
    sxx = (w * gx * gx).sum(axis=-1)
    sxy = (w * gx * gy).sum(axis=-1)
    syy = (w * gy * gy).sum(axis=-1)
    if offset_var > 0:
        total = w.sum(axis=-1)
        ux, uy = (w * gx).sum(axis=-1), (w * gy).sum(axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            if np.isinf(offset_var):
                c = np.where(total > 0, 1.0 / total, 0.0)
            else:
                c = offset_var / (1.0 + offset_var * total)
        sxx, sxy, syy = sxx - c * ux * ux, sxy - c * ux * uy, syy - c * uy * uy
    return np.stack([np.stack([sxx, sxy], -1), np.stack([sxy, syy], -1)], -2)


def inverse_trace(info: np.ndarray) -> np.ndarray:
    """``trace(J^-1)`` of 2 x 2 information matrices, ``inf`` where singular.

    Parameters
    ----------
    info : numpy.ndarray
        ``(..., 2, 2)`` symmetric positive semi-definite matrices, 1/m^2.

    Returns
    -------
    numpy.ndarray
        ``(...)`` traces of the inverses, m^2 (``trace / det``).
    """
    info = np.asarray(info, float)
    trace = info[..., 0, 0] + info[..., 1, 1]
    det = info[..., 0, 0] * info[..., 1, 1] - info[..., 0, 1] * info[..., 1, 0]
    singular = det <= 1e-12 * np.maximum(trace, 1e-300) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(singular, np.inf, trace / np.where(singular, 1.0, det))


def common_bias_log_likelihood(
    predicted, measured, noise_var, bias_var: float, dof: float = np.inf
) -> np.ndarray:
    r"""Log-likelihood marginalised over a Gaussian offset common to every beam.

    With ``y = h(x) + beta 1 + e``, ``beta ~ N(0, P)``, ``e ~ N(0, R)`` (``R`` diagonal,
    ``v_i``), the residual ``r = y - h(x)`` of a hypothesis is ``N(0, R + P 1 1^T)``.
    The rank-one covariance has a closed-form inverse and determinant
    (Sherman-Morrison, matrix determinant lemma): with ``S = sum 1 / v_i`` and
    ``T = sum r_i / v_i`` over the hypothesis's valid beams,

    ``log L = -0.5 (sum r_i^2 / v_i - P T^2 / (1 + P S)) - 0.5 log(1 + P S)``

    (the ``sum log v_i`` term is the same for every hypothesis and dropped, as in
    :func:`log_likelihood`). A beam predicted off the map costs
    :data:`OFF_MAP_LOG_LIKELIHOOD`.

    Parameters
    ----------
    predicted : numpy.ndarray
        ``(..., b)`` predicted values.
    measured : numpy.ndarray
        ``(b,)`` measured values (NaN = missing beam, ignored).
    noise_var : float or numpy.ndarray
        Per-beam variance, scalar, ``(b,)`` or per hypothesis ``(..., b)``, map units
        squared.
    bias_var : float
        ``P``, variance of the common offset, map units squared.
    dof : float
        A Student-t likelihood's degrees of freedom (:func:`student_t`); inf: the
        Gaussian.

    Returns
    -------
    numpy.ndarray
        ``(...)`` log-likelihoods up to a constant.
    """
    measured = np.asarray(measured, dtype=float)
    predicted = np.asarray(predicted, dtype=float)
    inv_var = 1.0 / np.asarray(noise_var, dtype=float)  # scalar, (b,) or (..., b)
    residual = measured - predicted
    valid = np.isfinite(residual)
    off_map = (~valid & np.isfinite(measured)).sum(axis=-1)
    r = np.where(valid, residual, 0.0)
    w = np.where(valid, inv_var, 0.0)
    s = w.sum(axis=-1)
    t = (r * w).sum(axis=-1)
    quad = (r * r * w).sum(axis=-1) - bias_var * t * t / (1.0 + bias_var * s)
    if np.isinf(dof):  # the Gaussian's own expression: its numbers to the last bit
        ll = -0.5 * quad - 0.5 * np.log1p(bias_var * s)
    else:
        ll = student_t(quad, np.log1p(bias_var * s), valid.sum(axis=-1), dof)
    return ll + OFF_MAP_LOG_LIKELIHOOD * off_map


def low_rank_log_likelihood(
    predicted, measured, noise_var, common=None, own=None, dof: float = np.inf
) -> np.ndarray:
    r"""Log-likelihood with a residual covariance ``R + Z Z^T`` of low rank beyond ``R``.

    ``Z = [own_i, common]``: ``(b, c)`` columns common to every hypothesis (an offset
    ``sqrt(P) 1``, shapes of a map error across the beams) and ``(b, c')`` columns of
    each hypothesis's own (its field's change within its share). With ``W = R^-1`` (0 for
    a missing or off-map beam), ``u = Z^T W r``, by Woodbury's identity and the matrix
    determinant lemma,

    ``log L = -0.5 (r^T W r - u^T (I + Z^T W Z)^-1 u + log det(I + Z^T W Z))``

    (the ``log det R`` common to every hypothesis is dropped). With the one column
    ``sqrt(P) 1`` it is :func:`common_bias_log_likelihood`.

    Parameters
    ----------
    predicted : numpy.ndarray
        ``(..., b)`` predicted values (NaN off the map).
    measured : numpy.ndarray
        ``(b,)`` measured values (NaN = missing beam).
    noise_var : float or numpy.ndarray
        Per-beam variance, scalar, ``(b,)`` or per hypothesis ``(..., b)``, map units
        squared.
    common : numpy.ndarray, optional
        ``(b, c)`` columns common to every hypothesis, map units.
    own : numpy.ndarray, optional
        ``(m, b, c')`` columns of each of the ``m`` flattened hypotheses, map units.
    dof : float
        A Student-t likelihood's degrees of freedom (:func:`student_t`); inf: the
        Gaussian.

    Returns
    -------
    numpy.ndarray
        ``(...)`` log-likelihoods up to a constant; off-map beams cost
        :data:`OFF_MAP_LOG_LIKELIHOOD` each.
    """
    measured = np.asarray(measured, dtype=float)
    predicted = np.asarray(predicted, dtype=float)
    shape = predicted.shape[:-1]
    beams = measured.shape[0]
    residual = measured - predicted.reshape(-1, beams)
    valid = np.isfinite(residual)
    off_map = (~valid & np.isfinite(measured)).sum(axis=-1)
    inv_var = 1.0 / np.asarray(noise_var, dtype=float)
    if inv_var.ndim == predicted.ndim and inv_var.ndim > 1:
        inv_var = inv_var.reshape(-1, beams)
    w = np.where(valid, inv_var, 0.0)
    r = np.where(valid, residual, 0.0)
    parts_u = []
    if own is not None:
        own = np.asarray(own, dtype=float)
        weighted = (own * w[..., None]).transpose(0, 2, 1)  # (m, c', b): Z_own^T W
        parts_u.append((weighted @ r[..., None])[..., 0])
    if common is not None:
        common = np.asarray(common, dtype=float).reshape(beams, -1)
        parts_u.append((w * r) @ common)
    quad = (w * r * r).sum(axis=-1)
    count = valid.sum(axis=-1)
    if not parts_u:
        ll = student_t(quad, 0.0, count, dof)
        return (ll + OFF_MAP_LOG_LIKELIHOOD * off_map).reshape(shape)
    u = np.concatenate(parts_u, axis=-1)
    if own is not None:
        gram = weighted @ own
        if common is not None:
            own_common = weighted @ common
            top = np.concatenate([gram, own_common], axis=2)
            bottom = np.concatenate(
                [own_common.transpose(0, 2, 1), weighted_gram(w, common)], axis=2
            )
            gram = np.concatenate([top, bottom], axis=1)
    else:
        gram = weighted_gram(w, common)
    inner = np.eye(u.shape[-1]) + gram
    explained = np.einsum("mc,mc->m", u, np.linalg.solve(inner, u[..., None])[..., 0])
    ll = student_t(quad - explained, np.linalg.slogdet(inner)[1], count, dof)
    return (ll + OFF_MAP_LOG_LIKELIHOOD * off_map).reshape(shape)


def student_t(quad, logdet, count, dof: float) -> np.ndarray:
    r"""A ping's log-likelihood from its Mahalanobis form: Gaussian or Student-t.

    With ``q`` the residuals' quadratic form in their covariance ``C`` and ``log det``
    the part of ``log det C`` that differs between hypotheses, the Gaussian's
    ``-0.5 (q + log det)``; with ``dof`` ``nu`` finite, the multivariate Student-t of
    the same scale matrix, the Gaussian whose variance is scaled by one inverse-gamma
    factor per ping (a ping whose beams are all off together, as a wrong sound speed or
    a spike of the gravimeter makes them, is not weighed as many sigmas of evidence):

    ``ln G((nu + n) / 2) - ln G(nu / 2) - (n / 2) ln(nu / 2) - ((nu + n) / 2) ln(1 + q / nu)
    - 0.5 log det``

    over the ``n`` valid beams; its constant is the t's less the Gaussian's dropped
    ``-(n / 2) ln(2 pi)``, so that it tends to the Gaussian's number as ``nu`` grows
    (hypotheses with different counts of valid beams stay comparable).

    Parameters
    ----------
    quad : numpy.ndarray
        ``q``, dimensionless.
    logdet : numpy.ndarray or float
        The log-determinant part, nats.
    count : numpy.ndarray or int
        Valid beams of each hypothesis.
    dof : float
        ``nu`` (inf: the Gaussian).

    Returns
    -------
    numpy.ndarray
        Log-likelihoods up to a constant common to the hypotheses, nats.
    """
    quad = np.asarray(quad, dtype=float)
    if not np.isfinite(dof):
        return -0.5 * (quad + logdet)
    n = np.asarray(count, dtype=float)
    half = 0.5 * (dof + n)
    constant = gammaln(half) - gammaln(0.5 * dof) - 0.5 * n * np.log(0.5 * dof)
    return constant - half * np.log1p(np.maximum(quad, 0.0) / dof) - 0.5 * np.asarray(logdet)


def weighted_gram(w: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """``(m, c, c)`` ``Z^T W_i Z`` of common columns ``Z`` for every row of ``w``.

    Parameters
    ----------
    w : numpy.ndarray
        ``(m, b)`` each hypothesis's per-beam weights ``W_i`` (inverse variances, 0 for a
        beam not used), map units^-2.
    columns : numpy.ndarray
        ``(b, c)`` columns ``Z`` common to every hypothesis, map units.
    """
    products = (columns[:, :, None] * columns[:, None, :]).reshape(columns.shape[0], -1)
    c = columns.shape[1]
    return (w @ products).reshape(-1, c, c)


def _with_offset(modes, bias_var: float, beams: int | None = None) -> np.ndarray | None:
    """The common columns: ``sqrt(bias_var) 1`` (when positive) beside ``modes``."""
    columns = [] if modes is None else [np.asarray(modes, dtype=float)]
    if bias_var > 0:
        size = int(columns[0].shape[0] if columns else beams or 0)
        columns.insert(0, np.full((size, 1), np.sqrt(bias_var)))
    return np.concatenate(columns, axis=1) if columns else None


def common_bias_posterior(residual, noise_var, bias_var: float) -> tuple[float, float]:
    """Posterior mean and variance of the common offset given one sample's residuals.

    Parameters
    ----------
    residual : numpy.ndarray
        ``(b,)`` measured minus predicted values (NaN beams ignored), map units.
    noise_var : float or numpy.ndarray
        Per-beam variance, map units squared.
    bias_var : float
        Prior variance ``P`` of the offset (prior mean 0), map units squared.

    Returns
    -------
    tuple of float
        ``(P T / (1 + P S), P / (1 + P S))`` with ``S``, ``T`` as in
        :func:`common_bias_log_likelihood`: map units and map units squared.
    """
    residual = np.asarray(residual, dtype=float)
    inv_var = np.broadcast_to(1.0 / np.asarray(noise_var, dtype=float), residual.shape)
    valid = np.isfinite(residual)
    s = float(inv_var[valid].sum())
    t = float((residual[valid] * inv_var[valid]).sum())
    return bias_var * t / (1.0 + bias_var * s), bias_var / (1.0 + bias_var * s)


# --------------------------------------------------------------------------- sensor lag
def lag_compensated(problem: MatchProblem) -> np.ndarray:
    """The problem's readings with the sensor's declared first-order lag undone.

    ``x_k = (y_k - a_k y_{k-1}) / (1 - a_k)``, ``a_k = exp(-(t_k - t_{k-1}) / lag_s)``
    (:func:`geofix.sensors.gravimeter.compensate_first_order_lag`): causal, each
    reading needs only the one before it, so a filter may apply it sample by sample.
    Noise and map error enter before the lag (:mod:`geofix.sensors.echosounder`), so the
    compensated readings are the map value plus the white errors the likelihood assumes.
    A missing reading (NaN) also spoils the next compensated one.

    Parameters
    ----------
    problem : MatchProblem
        Its ``measured`` ``(n, b)`` (map units), ``times`` ``(n,)`` seconds and ``lag_s``
        seconds.

    Returns
    -------
    numpy.ndarray
        ``(n, b)`` compensated readings, map units; ``problem.measured`` itself when
        ``lag_s`` is 0.
    """
    if problem.lag_s <= 0:
        return problem.measured
    return compensate_first_order_lag(problem.measured, problem.times, float(problem.lag_s))
