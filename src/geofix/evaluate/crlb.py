"""Cramér–Rao lower bounds on the position error of terrain / gravity matching.

The measurement of beam ``b`` at sample ``k`` is ``h(p_k + r_kb) + noise`` with the map
``h`` read at the beam footprint ``p_k + r_kb`` and Gaussian noise of variance
``var_b`` (sensor plus map error). Its Fisher information about the vehicle position
``p_k`` is ``g g^T / var_b``, with ``g`` the map gradient at the footprint, so one
sample carries

    I_k = sum_b g_kb g_kb^T / var_b                       (2 x 2, 1/m^2)

read along the *true* track (the bound is a property of the terrain actually crossed).

- **Batch** bound (a rigid translation of a whole track, as TERCOM / ICCP estimate it):
  ``J = sum_k I_k`` and ``cov >= J^-1``; singular (infinite) on a flat or straight-ridge
  track.
- **Error-state** bound (posterior CRLB, Tichavský, Muravchik & Nehorai 1998, of the
  linear INS error state of :mod:`geofix.nav.errstate`, the one the simulator draws): the
  state ``x`` has transitions ``F_k``, process noise ``Q_k`` (singular, often zero: the
  errors are a deterministic function of per-trial constants) and a Gaussian prior whose
  covariance is the simulator's second moments; the position error is ``H x``. With a
  linear-Gaussian motion and a measurement whose information about the position is
  ``I_k``, the recursion ``J_k = (F_k J_{k-1}^-1 F_k^T + Q_k)^-1 + H^T I_k H`` is run in
  covariance form (no inverse of a singular ``Q_k`` or prior is needed)::

      P_k^- = F_k P_{k-1} F_k^T + Q_k
      P_k   = P_k^- - P_k^- G_k^T (I + G_k P_k^- G_k^T)^-1 G_k P_k^-

  with ``G_k^T G_k = H^T I_k H`` (``G_k = Lambda^(1/2) U^T H`` from the eigenvalues of
  ``I_k``), plus the rows ``C / sigma_v`` of a DVL velocity measurement when the trial
  has one. The bound at sample ``k`` is ``H P_k H^T``; ``crlb_m`` is its trace at the last
  sample, ``crlb_track_m`` its trace averaged along the track. This is exactly the
  covariance of a Kalman filter on a linear map (see the tests).
- **Random-walk** bound (the earlier model, ``crlb_rw_m``): the position error as a
  white random walk with per-axis process noise ``Q_k`` (the growth of the INS prior
  variance between samples, as :func:`geofix.filters.base.motions` derives it) and a
  Gaussian prior of variance ``sigma_position[0]^2``::

      J_0 = I / sigma_0^2 + I_0
      J_k = (J_{k-1}^-1 + Q_k I)^-1 + I_k

  It is not the limit of the simulated INS (its errors are far from white), and a
  filter can end below it.

Map gradients are the exact gradient of the interpolant the simulator reads the truth
with (:data:`geofix.sim.sensing.TRUTH_READ`, bilinear, whatever the grid's
``interpolation``: :meth:`geofix.maps.grid.Grid.sample_gradient`) at every true
footprint, so the bound describes the readings actually drawn; a gradient that cannot be
formed (next to no-data) carries no information.
The heading error's rotation of off-nadir footprints is ignored (the bound is then
slightly optimistic).

**Several fields.** A trial with further fields (a scenario's ``sensors:`` list,
:attr:`geofix.sim.trial.Trial.fields`) has independent noise in each, so the fields'
information adds: ``I_k`` is the sum over fields of ``sum_b g g^T / var_b``, each with
its own map's gradients at its own footprints and its own beams' variance, and every
bound above is taken on that sum (:func:`trial_information`, :func:`field_information`).

**The common offset as a state.** The default filters estimate one offset per field
(measured minus map: a tide, a datum, a gravimeter's offset) as a slowly varying state.
:func:`offset_state_crlb` runs the posterior recursion above on the state augmented with
those offsets: each ``N(0, std_f^2)`` at the start and gaining ``walk_f * dt`` per step,
each beam's row ``(g^T H, 1)`` for its own field's offset (:func:`offset_information`,
:func:`offset_state_bound`). It lies between the known-offset bound (``std -> 0``, no
walk) and an offset drawn anew per sample (a single beam then tells nothing).

A gravimeter's first-order lag changes none of these bounds. The simulator adds the
sensor noise and map error *before* the lag (:mod:`geofix.sensors.echosounder`), so the
lagged readings ``y = L x`` are an invertible, known, lower-triangular linear map ``L``
(:mod:`geofix.sensors.gravimeter`) of the unlagged ones ``x``; any estimator of ``y``
is an estimator of ``x = L^-1 y`` and conversely, so both sequences carry the same
Fisher information about the track (the information of ``x`` is invariant under an
invertible transform that does not depend on the state) and the lagged system's bound
is the unlagged one computed here. The recursive filters reach it by undoing the
declared lag causally before their update (:func:`geofix.measurement.lag_compensated`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geofix.maps.grid import Grid
from geofix.measurement import (
    beam_gradients,
    inverse_trace,
    predict_track,
    sample_information,
)
from geofix.sim.sensing import TRUTH_READ

#: Smallest per-step process variance, m^2 (the same floor as the filters' motion model).
MIN_PROCESS_VAR = 1e-6


@dataclass(frozen=True)
class TrialBound:
    """CRLBs of one trial (variances summed over both axes, m^2).

    Attributes
    ----------
    recursive_var_m2 : float
        Trace of the error-state bound at the last sample, m^2 (the random-walk one for a
        trial without an INS error model).
    batch_var_m2 : float
        ``trace(J^-1)`` of the batch bound over the last leg, m^2 (``inf`` if singular).
    track_var_m2 : float
        Trace of the error-state bound averaged over the samples, m^2.
    rw_var_m2 : float
        ``trace(J_n^-1)`` of the random-walk bound at the last sample, m^2.
    """

    recursive_var_m2: float
    batch_var_m2: float
    track_var_m2: float = float("nan")
    rw_var_m2: float = float("nan")

    @property
    def recursive_m(self) -> float:
        """Bound on the end-point RMS error of a recursive filter, metres."""
        return float(np.sqrt(self.recursive_var_m2))

    @property
    def batch_m(self) -> float:
        """Bound on the RMS error of a rigid batch fix of the last leg, metres."""
        return float(np.sqrt(self.batch_var_m2))


def batch_bound(info: np.ndarray) -> np.ndarray:
    """Covariance bound ``J^-1`` of a rigid translation estimated from samples ``info``.

    Parameters
    ----------
    info : numpy.ndarray
        ``(n, 2, 2)`` per-sample information, 1/m^2.

    Returns
    -------
    numpy.ndarray
        ``(2, 2)`` covariance bound, m^2; every entry ``inf`` when ``J`` is singular.
    """
    total = np.asarray(info, float).sum(axis=0)
    if not np.isfinite(inverse_trace(total)):
        return np.full((2, 2), np.inf)
    return np.linalg.inv(total)


def process_variances(sigma_position) -> np.ndarray:
    """Per-axis process variance of each step, m^2: ``max(diff(sigma^2), 1e-6)``.

    Parameters
    ----------
    sigma_position : array_like
        ``(n,)`` prior per-axis 1-sigma of the INS position error, metres.

    Returns
    -------
    numpy.ndarray
        ``(n - 1,)`` variances, m^2 (as :func:`geofix.filters.base.motions`).
    """
    return np.maximum(np.diff(np.asarray(sigma_position, float) ** 2), MIN_PROCESS_VAR)


def recursive_bound(info: np.ndarray, process_var, prior_var: float) -> np.ndarray:
    """Posterior CRLB of a random-walk position error at every sample.

    Parameters
    ----------
    info : numpy.ndarray
        ``(n, 2, 2)`` per-sample measurement information, 1/m^2.
    process_var : array_like
        ``(n - 1,)`` per-axis process variance of each step, m^2.
    prior_var : float
        Per-axis prior variance at the first sample, m^2 (floored at ``1e-6``: a start
        known exactly).

    Returns
    -------
    numpy.ndarray
        ``(n, 2, 2)`` covariance bounds ``J_k^-1``, m^2.
    """
    info = np.asarray(info, float)
    q = np.asarray(process_var, float)
    eye = np.eye(2)
    bounds = np.empty_like(info)
    j = eye / max(float(prior_var), MIN_PROCESS_VAR) + info[0]
    bounds[0] = _inverse_information(j)
    for k in range(1, info.shape[0]):
        j = _inverse_information(bounds[k - 1] + q[k - 1] * eye) + info[k]
        bounds[k] = _inverse_information(j)
    return bounds


def _inverse_information(j: np.ndarray) -> np.ndarray:
    """``inv(j)`` of a symmetric 2x2 information (or covariance) matrix.

    When ``j`` is singular in floating point (a huge prior variance next to a strong
    gradient along one direction leaves the other direction's information below the
    rounding of the first), its eigenvalues are floored at ``1e-15`` of the largest: the
    bound along the direction the data says nothing about is then huge, as it should be.
    """
    try:
        return np.linalg.inv(j)
    except np.linalg.LinAlgError:
        values, vectors = np.linalg.eigh(0.5 * (j + j.T))
        floor = max(float(np.max(np.abs(values))) * 1e-15, np.finfo(float).tiny)
        return (vectors / np.maximum(values, floor)) @ vectors.T


def trial_beam_variance(trial) -> np.ndarray:
    """Per-beam measurement variance a trial declares, field units squared.

    Parameters
    ----------
    trial : Trial
        Its ``beam_noise_std`` ``(b,)`` (or ``noise_std`` for every beam when it has none)
        and ``map_error_std``.

    Returns
    -------
    numpy.ndarray
        ``(b,)`` ``beam_noise_std^2 + map_error_std^2``; for a simulated trial equal to
        :func:`scenario_beam_variance` of its scenario.
    """
    beams = np.asarray(trial.offsets).shape[0]
    std = getattr(trial, "beam_noise_std", None)
    std = np.full(beams, float(trial.noise_std)) if std is None else np.asarray(std, float)
    return std**2 + float(trial.map_error_std) ** 2


def trial_information(trial, grid: Grid, beam_var=None, fields: bool = True) -> np.ndarray:
    """Per-sample information along a trial's true track, 1/m^2, shape ``(n, 2, 2)``.

    Parameters
    ----------
    trial : Trial
        The mission: true track, headings, beam offsets, readings (NaN beams carry no
        information) and its further fields (``trial.fields``).
    grid : Grid
        The map the primary field's readings were drawn from.
    beam_var : float or array_like, optional
        The primary field's measurement variance, its units squared, scalar or ``(b,)``;
        default :func:`trial_beam_variance` (the trial's per-beam noise plus map error).
    fields : bool
        Add every further field's information (:func:`field_information`); False: the
        primary field's alone.

    Returns
    -------
    numpy.ndarray
        ``(n, 2, 2)`` information, 1/m^2, from the gradients of the simulator's read
        (:data:`geofix.sim.sensing.TRUTH_READ`).
    """
    if beam_var is None:
        beam_var = trial_beam_variance(trial)
    beam_var = np.maximum(np.asarray(beam_var, float), 1e-12)
    gx, gy = beam_gradients(grid, trial.truth, trial.true_heading, trial.offsets, TRUTH_READ)
    info = sample_information(gx, gy, beam_var, valid=np.isfinite(trial.measured))
    if fields:
        for field in getattr(trial, "fields", ()):
            info = info + field_information(trial, field)
    return info


def field_information(trial, field, offset_var: float = 0.0, prior: bool = False) -> np.ndarray:
    """Per-sample information of one further field of a trial, 1/m^2, ``(n, 2, 2)``.

    Parameters
    ----------
    trial : Trial
        The mission (true track and headings).
    field : TrialField
        The field: its beams' offsets, readings, noise (``beam_noise_std``, its map units)
        and maps (``sensed``, the field its readings were drawn from, or ``grid``).
    offset_var : float
        Variance of a common offset per sample, the field's units squared (0: none;
        ``inf``: unknown, each sample tells the position by its shape alone).
    prior : bool
        The bound of a vehicle with the prior map (:func:`imperfect_map_crlb`): the
        prior's gradients (bilinear) and the map error's variance at the track added to
        every beam's; False: the gradients of the field the sensor read.

    Returns
    -------
    numpy.ndarray
        ``(n, 2, 2)`` information, 1/m^2.
    """
    gx, gy, var, valid = _field_gradients(trial, field, prior)
    return sample_information(gx, gy, var, valid=valid, offset_var=offset_var)


def _field_gradients(trial, field, prior: bool) -> tuple:
    """``(gx, gy, var, valid)`` of a further field's beams, as :func:`field_information`."""
    sensed = field.grid if field.sensed is None else field.sensed
    var = np.asarray(field.beam_noise_std, float) ** 2
    read, source = TRUTH_READ, sensed
    if prior:
        read, source = "bilinear", field.grid
        var = var + _error_variance(trial, field.offsets, field.measured, sensed, field.grid)
    var = np.maximum(var, 1e-12)
    gx, gy = beam_gradients(source, trial.truth, trial.true_heading, field.offsets, read)
    valid = np.isfinite(field.measured) & np.isfinite(gx) & np.isfinite(gy)
    gx, gy = np.where(valid, gx, 0.0), np.where(valid, gy, 0.0)
    return gx, gy, var, valid


def error_state_bound(es, info: np.ndarray, dvl: bool = True) -> np.ndarray:
    """Posterior CRLB of the INS error state along a track, in covariance form.

    Parameters
    ----------
    es : ErrorState
        The linear error model (:func:`geofix.nav.errstate.error_state` along the truth).
    info : numpy.ndarray
        ``(n, 2, 2)`` per-sample information about the position, 1/m^2.
    dvl : bool
        Fold in the DVL velocity measurement when ``es.velocity_map`` is given.

    Returns
    -------
    numpy.ndarray
        ``(n, d, d)`` state covariance bounds (state units squared); the position block
        is ``es.position_cov(...)``.
    """
    info = np.asarray(info, float)
    n, d = info.shape[0], es.dim
    velocity_rows = None
    if dvl and es.velocity_map is not None and es.velocity_noise_var > 0:
        velocity_rows = es.velocity_map / np.sqrt(es.velocity_noise_var)
    out = np.empty((n, d, d))
    p = es.prior_cov
    for k in range(n):
        if k:
            f = es.transitions[k - 1]
            p = f @ p @ f.T + es.process_cov[k - 1]
        p = information_update(p, measurement_rows(info[k], es.position_map, velocity_rows))
        out[k] = p
    return out


def measurement_rows(info_k: np.ndarray, position_map: np.ndarray, extra=None) -> np.ndarray:
    """Rows ``G`` with ``G^T G = H^T I_k H`` (plus ``extra`` rows), ``(r, d)``."""
    values, vectors = np.linalg.eigh(0.5 * (info_k + info_k.T))
    rows = np.sqrt(np.clip(values, 0.0, None))[:, None] * (vectors.T @ position_map)
    return rows if extra is None else np.vstack([rows, extra])


def information_update(p: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``P - P G^T (I + G P G^T)^-1 G P``: ``(P^-1 + G^T G)^-1`` without inverting ``P``."""
    pg = p @ rows.T
    s = np.eye(rows.shape[0]) + rows @ pg
    p = p - pg @ np.linalg.solve(s, pg.T)
    return 0.5 * (p + p.T)


def trial_error_state(trial, simulator_prior: bool = False):
    """The trial's :class:`~geofix.nav.errstate.ErrorState` along its truth (None without).

    With ``simulator_prior`` the start position's prior is the simulator's own spread
    about its known offset (:meth:`~geofix.nav.errstate.ErrorState.with_simulator_position_prior`)
    instead of the zero-mean second moments.
    """
    from geofix.nav.errstate import error_state

    model = getattr(trial, "ins_model", None)
    if model is None:
        return None
    es = error_state(model, trial.times, trial.truth)
    return es.with_simulator_position_prior() if simulator_prior else es


def trial_crlb(trial, grid: Grid, beam_var=None) -> TrialBound:
    """Error-state, random-walk (whole mission) and batch (last leg) CRLBs of one trial.

    Parameters
    ----------
    trial : Trial
        The mission; its true track, headings, beam offsets, measurements (NaN beams carry
        no information), prior ``sigma_position`` and ``ins_model`` (the error-state
        bound needs it; without one the random-walk bound stands in).
    grid : Grid
        The map the measurements were drawn from.
    beam_var : float or array_like, optional
        Measurement variance, field units squared, scalar or ``(b,)`` per beam; default
        :func:`trial_beam_variance` (the trial's per-beam noise plus map error).

    Returns
    -------
    TrialBound
        ``trace`` of the bounds, m^2.
    """
    info = trial_information(trial, grid, beam_var)
    rw = _random_walk_traces(trial, info)
    last = trial.leg_slices()[-1]
    batch = float(inverse_trace(info[last].sum(axis=0)))
    traces = _bound_traces(trial, info, rw)
    return TrialBound(float(traces[-1]), batch, float(np.mean(traces)), float(rw[-1]))


def map_error_variance_at_track(trial, grid: Grid, prior: Grid) -> float:
    """Mean square of the prior map's error at a trial's footprints, less its mean.

    ``seabed - prior`` read at every valid footprint of the true track (the seabed with the
    simulator's read, the prior bilinear), its mean (a common offset, which the bound
    treats as a nuisance of its own) removed, field units squared; 0 when the prior is the
    seabed.
    """
    return _error_variance(trial, trial.offsets, trial.measured, grid, prior)


def _error_variance(trial, offsets, measured, grid: Grid, prior: Grid) -> float:
    """:func:`map_error_variance_at_track` for beams ``offsets`` and readings ``measured``."""
    if prior is grid:
        return 0.0
    truth = predict_track(grid, trial.truth, trial.true_heading, offsets, TRUTH_READ)
    read = predict_track(prior, trial.truth, trial.true_heading, offsets, "bilinear")
    error = (truth - read)[np.isfinite(measured)]
    error = error[np.isfinite(error)]
    return float(np.var(error)) if error.size else 0.0


def imperfect_map_crlb(trial, grid: Grid, beam_var=None, offset_var=np.inf) -> TrialBound:
    """The bounds of :func:`trial_crlb` for the problem a vehicle with the prior map has.

    The readings are the seabed's (``grid``) plus noise; the vehicle knows the prior map
    (``trial.prior_map``) only. To it the readings are the prior plus the map's error plus
    noise: the information is taken from the prior's gradients at the true footprints,
    each beam's variance is the declared one plus the map error's variance at the track
    (:func:`map_error_variance_at_track`, a diagonal approximation: the error's
    correlation across a swath is not counted, so the bound is optimistic there), and a
    common offset per sample is a nuisance of variance ``offset_var`` (default unknown:
    each sample tells the position by its shape alone,
    :func:`geofix.measurement.sample_information`). A misregistration is a bias no
    estimator sees and is not in it. With no prior map (the prior is the seabed) and
    ``offset_var=0`` it is :func:`trial_crlb`. Every further field of the trial adds its
    information on the same footing (its own prior map, map error and beams; its offset
    unknown per sample unless ``offset_var`` is 0, :func:`field_information`).

    Returns
    -------
    TrialBound
        ``trace`` of the bounds, m^2.
    """
    prior = getattr(trial, "prior_map", None)
    prior = grid if prior is None else prior
    if beam_var is None:
        beam_var = trial_beam_variance(trial)
    var = np.asarray(beam_var, float) + map_error_variance_at_track(trial, grid, prior)
    var = np.maximum(var, 1e-12)
    gx, gy = beam_gradients(prior, trial.truth, trial.true_heading, trial.offsets, "bilinear")
    valid = np.isfinite(trial.measured) & np.isfinite(gx) & np.isfinite(gy)
    gx, gy = np.where(valid, gx, 0.0), np.where(valid, gy, 0.0)
    info = sample_information(gx, gy, var, valid=valid, offset_var=offset_var)
    field_offset_var = 0.0 if offset_var == 0 else np.inf  # units of their own
    for field in getattr(trial, "fields", ()):
        info = info + field_information(trial, field, field_offset_var, prior=True)
    rw = _random_walk_traces(trial, info)
    last = trial.leg_slices()[-1]
    batch = float(inverse_trace(info[last].sum(axis=0)))
    traces = _bound_traces(trial, info, rw)
    return TrialBound(float(traces[-1]), batch, float(np.mean(traces)), float(rw[-1]))


# ------------------------------------------------------------ the offset as a state


@dataclass(frozen=True)
class LinearMotion:
    """A linear-Gaussian model of the vehicle's error state, the base of a posterior bound.

    Attributes
    ----------
    prior_cov : numpy.ndarray
        ``(d, d)`` prior covariance, state units squared.
    transitions : numpy.ndarray
        ``(n - 1, d, d)`` ``F_k``.
    process_cov : numpy.ndarray
        ``(n - 1, d, d)`` ``Q_k`` (may be singular), state units squared.
    position_map : numpy.ndarray
        ``(2, d)`` ``H``: the position error is ``H x``, metres.
    extra_rows : numpy.ndarray or None
        ``(r, d)`` whitened rows of a measurement folded in at every sample (a DVL's
        velocity), or None.
    """

    prior_cov: np.ndarray
    transitions: np.ndarray
    process_cov: np.ndarray
    position_map: np.ndarray
    extra_rows: np.ndarray | None = None

    @property
    def dim(self) -> int:
        """Number of states ``d``."""
        return self.position_map.shape[1]


def random_walk_motion(sigma_position) -> LinearMotion:
    """The random-walk position model of :func:`recursive_bound` as a :class:`LinearMotion`.

    Parameters
    ----------
    sigma_position : array_like
        ``(n,)`` prior per-axis 1-sigma of the INS position error, metres: the prior
        variance is the first's square (floored at ``1e-6`` m^2), the process variance of
        each step :func:`process_variances`.

    Returns
    -------
    LinearMotion
        Two states (east, north position error, metres).
    """
    sigma = np.asarray(sigma_position, float)
    eye = np.eye(2)
    q = process_variances(sigma)
    return LinearMotion(
        prior_cov=eye * max(float(sigma[0]) ** 2, MIN_PROCESS_VAR),
        transitions=np.broadcast_to(eye, (q.size, 2, 2)),
        process_cov=q[:, None, None] * eye,
        position_map=eye,
    )


def error_state_motion(es, dvl: bool = True) -> LinearMotion:
    """The INS error state of :func:`error_state_bound` as a :class:`LinearMotion`.

    Parameters
    ----------
    es : ErrorState
        The linear error model (:func:`geofix.nav.errstate.error_state`).
    dvl : bool
        Fold in the DVL velocity measurement when ``es.velocity_map`` is given.

    Returns
    -------
    LinearMotion
        ``es.dim`` states.
    """
    rows = None
    if dvl and es.velocity_map is not None and es.velocity_noise_var > 0:
        rows = es.velocity_map / np.sqrt(es.velocity_noise_var)
    return LinearMotion(es.prior_cov, es.transitions, es.process_cov, es.position_map, rows)


def offset_information(gx, gy, beam_var, valid=None) -> np.ndarray:
    """Fisher information of each sample about the position and the field's offset.

    A beam reads ``h(p + r_b) + c + noise`` with ``c`` the field's common offset; its
    linearised row is ``(g_x, g_y, 1)``, so a sample carries ``sum_b a_b a_b^T / R_b``
    with ``a_b = (g_x, g_y, 1)``. The upper-left block is
    :func:`geofix.measurement.sample_information`; its Schur complement on the offset is
    that function's ``offset_var=inf``.

    Parameters
    ----------
    gx, gy : array_like
        ``(n, b)`` map gradients at the footprints, field units per metre.
    beam_var : float or array_like
        Measurement variance, field units squared: a scalar or ``(b,)`` per beam.
    valid : array_like of bool, optional
        ``(n, b)``; False for a missing measurement.

    Returns
    -------
    numpy.ndarray
        ``(n, 3, 3)`` information about ``(x, y, c)``: 1/m^2, 1/(m field unit), 1/field
        unit^2.
    """
    gx = np.asarray(gx, float)
    gy = np.asarray(gy, float)
    w = np.broadcast_to(1.0 / np.asarray(beam_var, float), gx.shape)
    if valid is not None:
        w = np.where(valid, w, 0.0)
    a = np.stack([gx, gy, np.ones_like(gx)], axis=-1)
    return np.einsum("nb,nbi,nbj->nij", w, a, a)


def offset_state_bound(motion: LinearMotion, info, offset_var, offset_process_var) -> np.ndarray:
    """Posterior CRLB of a state augmented with one random-walk offset per field.

    The state is the motion's ``x`` (``d``) and the fields' offsets ``c_f`` (``F``), with
    ``c_f ~ N(0, offset_var_f)`` at the first sample, independent of ``x``, and gaining
    ``offset_process_var[k - 1, f]`` at step ``k``. Each beam of field ``f`` is a row
    ``(g^T H, e_f)``. The recursion is :func:`error_state_bound`'s covariance form
    (Tichavský et al. 1998) on the augmented state; a zero prior and no walk leave the
    offsets known and the bound is that of the motion alone.

    Parameters
    ----------
    motion : LinearMotion
        The vehicle's error state.
    info : array_like
        ``(F, n, 3, 3)`` every field's :func:`offset_information` per sample.
    offset_var : array_like
        ``(F,)`` prior variance of every field's offset, its units squared (0: known).
    offset_process_var : array_like
        ``(n - 1, F)`` variance each offset gains per step, its units squared.

    Returns
    -------
    numpy.ndarray
        ``(n, d + F, d + F)`` covariance bounds; the position block is
        ``H P[:d, :d] H^T``.
    """
    info = np.asarray(info, float)
    fields, n = info.shape[0], info.shape[1]
    d = motion.dim
    q_offset = np.asarray(offset_process_var, float).reshape(max(n - 1, 0), fields)
    p = np.zeros((d + fields, d + fields))
    p[:d, :d] = motion.prior_cov
    p[d:, d:] = np.diag(np.asarray(offset_var, float).reshape(fields))
    maps = []
    for f in range(fields):
        m = np.zeros((3, d + fields))
        m[:2, :d] = motion.position_map
        m[2, d + f] = 1.0
        maps.append(m)
    extra = None
    if motion.extra_rows is not None:
        extra = np.hstack([motion.extra_rows, np.zeros((motion.extra_rows.shape[0], fields))])
    out = np.empty((n, d + fields, d + fields))
    for k in range(n):
        if k:
            p = _offset_predict(p, motion, k - 1, q_offset[k - 1])
        rows = [measurement_rows(info[f, k], maps[f]) for f in range(fields)]
        if extra is not None:
            rows.append(extra)
        p = information_update(p, np.vstack(rows)) if rows else p
        out[k] = p
    return out


def _offset_predict(p: np.ndarray, motion: LinearMotion, step: int, q_offset) -> np.ndarray:
    """``A P A^T + Q`` of the augmented state: the motion's ``F``, the offsets unchanged."""
    d = motion.dim
    f = motion.transitions[step]
    out = p.copy()
    out[:d, :d] = f @ p[:d, :d] @ f.T + motion.process_cov[step]
    out[:d, d:] = f @ p[:d, d:]
    out[d:, :d] = out[:d, d:].T
    out[d:, d:] += np.diag(q_offset)
    return out


def trial_offset_information(trial, grid: Grid, beam_var=None, prior_map: bool = False):
    """Every field's :func:`offset_information` along a trial's true track.

    Parameters
    ----------
    trial : Trial
        The mission, its primary field first, then ``trial.fields``.
    grid : Grid
        The map the primary field's readings were drawn from (the seabed).
    beam_var : float or array_like, optional
        The primary field's measurement variance, its units squared; default
        :func:`trial_beam_variance`.
    prior_map : bool
        The problem of a vehicle with the prior maps (as :func:`imperfect_map_crlb`): every
        field's prior's gradients (bilinear) and its map error's variance at the track
        added to its beams'; False: the gradients of the fields the sensors read (as
        :func:`trial_crlb`).

    Returns
    -------
    numpy.ndarray
        ``(F, n, 3, 3)`` information about ``(x, y, c_f)``.
    """
    if beam_var is None:
        beam_var = trial_beam_variance(trial)
    var = np.asarray(beam_var, float)
    source, read = grid, TRUTH_READ
    if prior_map:
        source, read = _prior_of(trial, grid), "bilinear"
        var = var + map_error_variance_at_track(trial, grid, source)
    gx, gy = beam_gradients(source, trial.truth, trial.true_heading, trial.offsets, read)
    valid = np.isfinite(trial.measured)
    if prior_map:
        valid = valid & np.isfinite(gx) & np.isfinite(gy)
        gx, gy = np.where(valid, gx, 0.0), np.where(valid, gy, 0.0)
    out = [offset_information(gx, gy, np.maximum(var, 1e-12), valid)]
    for field in getattr(trial, "fields", ()):
        out.append(offset_information(*_field_gradients(trial, field, prior_map)))
    return np.stack(out)


def _prior_of(trial, grid: Grid) -> Grid:
    """The primary field's prior map: the trial's ``prior_map``, else the seabed ``grid``."""
    prior = getattr(trial, "prior_map", None)
    return grid if prior is None else prior


def trial_offset_model(trial, grid: Grid, offset_std=None, offset_walk=None) -> tuple:
    """Every field's offset prior 1-sigma and walk rate, the filters' defaults if not given.

    Parameters
    ----------
    trial : Trial
        The mission: its primary field, then ``trial.fields``.
    grid : Grid
        The primary field's seabed (its prior map is ``trial.prior_map`` when set).
    offset_std : float or array_like, optional
        Prior 1-sigma, map units: one for every field or ``(F,)``; None: each field's
        :func:`geofix.maps.offset.default_offset_std` of its prior map.
    offset_walk : float or array_like, optional
        Variance gained per second, map units squared per second: one for every field or
        ``(F,)``; None: the filters' default ``depth_bias_walk``
        (:class:`geofix.filters.loop.FilterSettings`).

    Returns
    -------
    tuple of numpy.ndarray
        ``(std (F,), walk (F,))``.
    """
    from geofix.filters.loop import FilterSettings
    from geofix.maps.offset import default_offset_std

    priors = [_prior_of(trial, grid)] + [f.grid for f in getattr(trial, "fields", ())]
    count = len(priors)
    if offset_std is None:
        std = np.array([default_offset_std(g) for g in priors], float)
    else:
        std = np.broadcast_to(np.asarray(offset_std, float), (count,)).copy()
    if offset_walk is None:
        offset_walk = FilterSettings().depth_bias_walk
    walk = np.broadcast_to(np.asarray(offset_walk, float), (count,)).copy()
    return std, walk


def offset_state_crlb(
    trial,
    grid: Grid,
    offset_std=None,
    offset_walk=None,
    prior_map: bool = False,
    beam_var=None,
) -> TrialBound:
    """The bounds of :func:`trial_crlb` with every field's common offset a random-walk state.

    The default filters estimate one offset per field (measured minus map) as a slowly
    varying state (:class:`geofix.filters.nuisance.CommonOffset`). Their bound is the
    posterior CRLB of the state augmented with those offsets
    (:func:`offset_state_bound`): each offset ``N(0, offset_std^2)`` at the start, gaining
    ``offset_walk * dt`` per step, and each beam's row ``(g^T H, 1)`` for its own field's
    offset. It lies between the known-offset bound (:func:`trial_crlb`, the limit
    ``offset_std -> 0`` with no walk) and the bound of an offset drawn anew per sample
    (``offset_var=inf`` of :func:`imperfect_map_crlb`, the limit of a fast walk): a
    profile of samples on different gradients tells the offset apart from the position,
    one sample of a single beam does not.

    Parameters
    ----------
    trial : Trial
        The mission (true track, headings, beams, readings, ``sigma_position``,
        ``ins_model``, ``times``, further fields).
    grid : Grid
        The map the primary field's readings were drawn from.
    offset_std : float or array_like, optional
        Every field's offset prior 1-sigma, map units (see :func:`trial_offset_model`;
        default the filters' own, from each field's prior map).
    offset_walk : float or array_like, optional
        Every field's offset walk, map units squared per second (default the filters').
    prior_map : bool
        The problem of a vehicle with the prior maps (the information of
        :func:`imperfect_map_crlb`); False: the sensed fields' (:func:`trial_crlb`).
    beam_var : float or array_like, optional
        The primary field's measurement variance, its units squared.

    Returns
    -------
    TrialBound
        ``trace`` of the position bounds, m^2: the error-state one (the random-walk one
        without an INS model), the random-walk one, and the batch one of the last leg
        (one constant offset per field with the same prior, a rigid translation).
    """
    info = trial_offset_information(trial, grid, beam_var, prior_map)
    std, walk = trial_offset_model(trial, grid, offset_std, offset_walk)
    dt = np.clip(np.diff(np.asarray(trial.times, float)), 0.0, None)
    q_offset = dt[:, None] * walk[None, :]
    rw_motion = random_walk_motion(trial.sigma_position)
    rw = _position_traces(rw_motion, offset_state_bound(rw_motion, info, std**2, q_offset))
    es = trial_error_state(trial)
    traces = rw
    if es is not None:
        motion = error_state_motion(es)
        traces = _position_traces(motion, offset_state_bound(motion, info, std**2, q_offset))
    batch = _offset_batch_trace(info[:, trial.leg_slices()[-1]], std**2)
    return TrialBound(float(traces[-1]), batch, float(np.mean(traces)), float(rw[-1]))


def _position_traces(motion: LinearMotion, cov: np.ndarray) -> np.ndarray:
    """``(n,)`` ``trace(H P H^T)`` of augmented covariances, m^2."""
    d, h = motion.dim, motion.position_map
    block = cov[:, :d, :d]
    return np.einsum("ij,njk,ik->n", h, block, h)


def _offset_batch_trace(info: np.ndarray, offset_var) -> float:
    """``trace`` of the batch position bound with one constant offset per field, m^2.

    ``info`` is ``(F, m, 3, 3)`` over the leg's samples; each offset has the prior
    variance ``offset_var`` (0: known), and is eliminated by its Schur complement.
    """
    total = info.sum(axis=1)
    j = total[:, :2, :2].sum(axis=0)
    for f, var in enumerate(np.asarray(offset_var, float)):
        if var <= 0:
            continue
        u = total[f, :2, 2]
        s = total[f, 2, 2] + (0.0 if np.isinf(var) else 1.0 / var)
        if s > 0:
            j = j - np.outer(u, u) / s
    return float(inverse_trace(j))


def _random_walk_traces(trial, info: np.ndarray) -> np.ndarray:
    """``(n,)`` ``trace(J_k^-1)`` of the random-walk bound, m^2."""
    sigma = np.asarray(trial.sigma_position, float)
    rec = recursive_bound(info, process_variances(sigma), float(sigma[0]) ** 2)
    return np.trace(rec, axis1=-2, axis2=-1)


def _bound_traces(
    trial, info: np.ndarray, rw: np.ndarray, simulator_prior: bool = False
) -> np.ndarray:
    """``(n,)`` traces of the error-state bound, m^2 (``rw`` without an INS model)."""
    es = trial_error_state(trial, simulator_prior)
    if es is None:
        return rw
    return np.trace(es.position_cov(error_state_bound(es, info)), axis1=-2, axis2=-1)


def bound_track(trial, grid: Grid, beam_var=None, simulator_prior: bool = False) -> np.ndarray:
    """The bound on the RMS position error at every sample of a trial, metres.

    The error-state bound of :func:`trial_crlb` (the random-walk one for a trial without
    an INS error model). Parameters are those of :func:`trial_crlb`; with
    ``simulator_prior`` the start position's prior is the simulator's own spread about its
    known offset (the bound for an estimator told the distribution the simulator draws
    the start error from; 0 at the start of a fixed-offset trial), the other error
    constants keeping their second moments.

    Returns
    -------
    numpy.ndarray
        ``(n,)`` ``sqrt(trace(J_k^-1))``, metres.
    """
    info = trial_information(trial, grid, beam_var)
    return np.sqrt(_bound_traces(trial, info, _random_walk_traces(trial, info), simulator_prior))


def scenario_beam_variance(scenario, offsets) -> np.ndarray:
    """Per-beam measurement variance of a scenario's sensor, field units squared.

    Parameters
    ----------
    scenario : Scenario
        Its ``sensor`` block (noise growing towards the swath edges, map error).
    offsets : numpy.ndarray
        ``(b, 2)`` beam offsets, metres.

    Returns
    -------
    numpy.ndarray
        ``(b,)`` sensor noise variance plus map-error variance.
    """
    from geofix.sensors.echosounder import beam_noise_std

    return beam_noise_std(offsets, scenario.sensor) ** 2 + scenario.sensor.map_error_std**2


def rms_bound(variances) -> float | None:
    """The RMS bound over trials, ``sqrt(mean(trace J^-1))``, metres (None if undefined).

    Parameters
    ----------
    variances : array_like
        Per-trial ``trace(J^-1)``, m^2 (NaN entries are skipped).

    Returns
    -------
    float or None
        Metres; None when no finite-or-infinite value is given or the mean is infinite.
    """
    v = np.asarray(variances, float)
    v = v[~np.isnan(v)]
    if v.size == 0:
        return None
    mean = float(v.mean())
    return float(np.sqrt(mean)) if np.isfinite(mean) else None
