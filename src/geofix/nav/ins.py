r"""An inertial navigation (INS) error model driven by datasheet numbers.

The INS is simulated as a free-running (never reset) navigator whose *errors* are
integrated from IMU datasheet numbers; the errors are not additive white noise on the
track.

Level channels (Schuler loop)
-----------------------------
Each horizontal axis (east, north) is an independent three-state error model with the
datasheet terms as constant augmented states::

    dp'  = dv
    dv'  = -g * phi + b_a + w_a
    phi' = k * dv / R + eps + w_g          (k = 1 with the Schuler loop, 0 without)
    b_a' = 0,  eps' = 0

``dp`` position error (m), ``dv`` velocity error (m/s), ``phi`` tilt error (rad),
``b_a`` accelerometer bias (m/s^2), ``eps`` level gyro drift (rad/s) of the gyro that
tilts this channel, ``w_a`` / ``w_g`` white accelerometer / gyro noise of power spectral
density ``(accel_noise_ug_rt_hz * 9.80665e-6)^2`` m^2/s^3 and
``(gyro_noise_deg_rt_h * pi / 180 / 60)^2`` rad^2/s. ``g = 9.80665`` m/s^2,
``R = 6 371 000`` m. With ``k = 1``, ``dv'' = -(g/R) dv + ...``: the loop oscillates at
the Schuler frequency ``omega_s = sqrt(g/R)`` = 1.2407e-3 rad/s (period 84.4 min), and

- a pure accelerometer bias ``b`` gives ``dp(t) = (b / omega_s^2) (1 - cos omega_s t)``
  (:func:`schuler_bias_error`);
- a pure level gyro drift ``eps`` gives ``dp(t) = -R eps (t - sin(omega_s t) / omega_s)``
  (:func:`schuler_gyro_error`): with these signs a positive drift moves the position
  error negative; it grows without bound, like ``-g eps t^3 / 6`` at first;
- an initial velocity error ``dv0`` gives ``dp(t) = dv0 sin(omega_s t) / omega_s``.

``schuler=False`` (``k = 0``) is plain double integration: ``dp = dv0 t + b t^2 / 2``
(and ``-g eps t^3 / 6`` for a gyro drift).

The model is discretised *exactly* over each sampling interval ``dt``: the transition
matrix is ``expm(A dt)`` of the augmented 5-state matrix, and the process-noise
covariance ``Q_d`` comes from Van Loan's method (one ``expm`` of the 10 x 10 block
matrix). Process noise is drawn from ``Q_d`` with the caller's generator.

Heading (azimuth) error
-----------------------
``psi_e(t) = psi_0 + eps_z t + W(t)``, with ``W`` a random walk of the gyro noise
(variance ``N_g^2 t``); the indicated heading is ``true heading + psi_e``. How it moves
the position is stated once, in :mod:`geofix.nav.errstate` (with references): in a free
INS it rotates the *velocity gained since alignment* (the navigator is aligned at rest),
and that velocity error runs through the Schuler loop; with ``ins.latitude_deg`` it also
acts through the Earth rate as a level gyro drift ``Omega cos L psi_e`` of the north
channel. Only without the Schuler loop (``schuler: false``) does a constant heading error
rotate the indicated track rigidly about its start. ``ins.mode: dvl`` replaces the free
INS by DVL dead reckoning, where the heading error rotates every travelled displacement.

The simulation runs the linear recursion of :func:`geofix.nav.errstate.error_state`
along the true track: the same transitions, process noise and prior that the
Cramér–Rao bound and the error-state filters use.

Per-trial draws
---------------
Initial position error ``initial_error_m + N(0, initial_error_std_m)`` per axis; initial
velocity error of magnitude ``velocity_error_m_s`` and accelerometer bias of magnitude
``accel_bias_ug`` (1 ug = 9.80665e-6 m/s^2), each in a uniformly random direction;
gyro bias of magnitude ``gyro_bias_deg_h`` on each of the three axes (the two level
channels and azimuth), each with a random sign; heading error ``|heading_error_deg|``
with a random sign. The initial tilt error is zero. In ``mode: dvl``: the initial
position error as above, then a DVL bias of magnitude ``dvl.bias_m_s`` in a uniformly
random direction, and random signs for the heading error, the azimuth gyro drift and the
DVL scale error ``dvl.scale_error``.

Prior uncertainty
-----------------
:func:`position_sigma` propagates the covariance of the same discrete model with the
variances that match those draws (see its docstring), so the matchers' search windows
follow from the same datasheet numbers.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np
from scipy.linalg import expm

from geofix.errors import ConfigError
from geofix.nav.errstate import (
    EARTH_RATE_RAD_S,
    InsErrorModel,
    error_state,
    propagate,
    propagate_cov,
)

if TYPE_CHECKING:
    from geofix.nav.spec import DvlSpec, InsSpec
    from geofix.nav.trajectory import TrueTrajectory

GRAVITY_M_S2 = 9.80665
"""Standard gravity, m/s^2 (the ``g`` of the Schuler loop and of micro-g)."""
EARTH_RADIUS_M = 6_371_000.0
"""Mean Earth radius, metres."""
SCHULER_OMEGA = float(np.sqrt(GRAVITY_M_S2 / EARTH_RADIUS_M))
"""Schuler angular frequency ``sqrt(g / R)``, rad/s."""
MICRO_G = GRAVITY_M_S2 * 1e-6
DEG_PER_H = np.pi / 180.0 / 3600.0
DEG_PER_RT_H = np.pi / 180.0 / 60.0
_STATES = 5  # dp, dv, phi, b_a, eps


@dataclass(frozen=True, eq=False)
class InsTrack:
    """The INS indication of one trial, with its error terms for diagnostics.

    Parameters
    ----------
    indicated : numpy.ndarray
        ``(n, 2)`` indicated positions, metres.
    heading : numpy.ndarray
        ``(n,)`` indicated heading, radians clockwise from north.
    position_error : numpy.ndarray
        ``(n, 2)`` ``indicated - true``, metres.
    schuler_error : numpy.ndarray
        ``(n, 2)`` level-channel error ``dp`` (includes the initial position error), metres.
    rotation_error : numpy.ndarray
        ``(n, 2)`` error from the mis-rotated displacement (heading error), metres.
    heading_error : numpy.ndarray
        ``(n,)`` heading error ``psi_e``, radians (positive = clockwise).
    initial_error : numpy.ndarray
        ``(2,)`` initial position error drawn for this trial, metres.
    velocity_error : numpy.ndarray
        ``(2,)`` initial velocity error, m/s.
    accel_bias : numpy.ndarray
        ``(2,)`` accelerometer bias (east, north), m/s^2.
    gyro_bias : numpy.ndarray
        ``(3,)`` gyro drift of the east channel, the north channel and azimuth, rad/s.
    """

    indicated: np.ndarray
    heading: np.ndarray
    position_error: np.ndarray
    schuler_error: np.ndarray
    rotation_error: np.ndarray
    heading_error: np.ndarray
    initial_error: np.ndarray
    velocity_error: np.ndarray
    accel_bias: np.ndarray
    gyro_bias: np.ndarray


def schuler_bias_error(b, t) -> np.ndarray:
    """Position error of a pure accelerometer bias in the Schuler loop.

    Parameters
    ----------
    b : float or array_like
        Accelerometer bias, m/s^2.
    t : float or array_like
        Time since the start, seconds.

    Returns
    -------
    numpy.ndarray
        ``(b / omega_s^2) (1 - cos omega_s t)``, metres.
    """
    t = np.asarray(t, dtype=float)
    return np.asarray(b) / SCHULER_OMEGA**2 * (1.0 - np.cos(SCHULER_OMEGA * t))


def schuler_gyro_error(eps, t) -> np.ndarray:
    """Position error of a pure level gyro drift in the Schuler loop.

    Parameters
    ----------
    eps : float or array_like
        Level gyro drift, rad/s.
    t : float or array_like
        Time since the start, seconds.

    Returns
    -------
    numpy.ndarray
        ``-R eps (t - sin(omega_s t) / omega_s)``, metres (sign as in the module model).
    """
    t = np.asarray(t, dtype=float)
    return -EARTH_RADIUS_M * np.asarray(eps) * (t - np.sin(SCHULER_OMEGA * t) / SCHULER_OMEGA)


def discrete_error_model(
    dt: float, schuler: bool = True, accel_psd: float = 0.0, gyro_psd: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Exact discretisation of one level channel over ``dt`` seconds.

    Parameters
    ----------
    dt : float
        Interval, seconds.
    schuler : bool
        Close the Schuler loop (``phi' = dv / R + ...``) or not.
    accel_psd : float
        Accelerometer white-noise power spectral density, m^2/s^3.
    gyro_psd : float
        Gyro white-noise power spectral density, rad^2/s.

    Returns
    -------
    tuple of numpy.ndarray
        ``(Phi, Q)``: ``(5, 5)`` transition matrix and process-noise covariance of the
        state ``[dp (m), dv (m/s), phi (rad), b_a (m/s^2), eps (rad/s)]``.
    """
    phi, q, _ = _discrete_cached(float(dt), bool(schuler), float(accel_psd), float(gyro_psd))
    return phi.copy(), q.copy()


@lru_cache(maxsize=64)
def _discrete_cached(dt, schuler, accel_psd, gyro_psd):
    a = np.zeros((_STATES, _STATES))
    a[0, 1] = 1.0
    a[1, 2] = -GRAVITY_M_S2
    a[1, 3] = 1.0
    a[2, 1] = 1.0 / EARTH_RADIUS_M if schuler else 0.0
    a[2, 4] = 1.0
    qc = np.diag([0.0, accel_psd, gyro_psd, 0.0, 0.0])
    block = np.zeros((2 * _STATES, 2 * _STATES))
    block[:_STATES, :_STATES] = -a
    block[:_STATES, _STATES:] = qc
    block[_STATES:, _STATES:] = a.T
    van_loan = expm(block * dt)
    transition = van_loan[_STATES:, _STATES:].T
    q = transition @ van_loan[:_STATES, _STATES:]
    q = 0.5 * (q + q.T)
    factor = _noise_factor(q)
    for array in (transition, q, factor):
        array.flags.writeable = False
    return transition, q, factor


def _noise_factor(q: np.ndarray) -> np.ndarray:
    """A matrix ``L`` with ``L @ L.T == q`` for a (possibly singular) covariance ``q``."""
    values, vectors = np.linalg.eigh(q)
    return vectors * np.sqrt(np.clip(values, 0.0, None))


def _noise_psds(spec: InsSpec) -> tuple[float, float]:
    return (spec.accel_noise_ug_rt_hz * MICRO_G) ** 2, (
        spec.gyro_noise_deg_rt_h * DEG_PER_RT_H
    ) ** 2


def _unit(angle: float) -> np.ndarray:
    return np.array([np.cos(angle), np.sin(angle)])


def _draw_trial_errors(spec: InsSpec, rng: np.random.Generator) -> dict:
    """Per-trial constants (always the same number of draws, whatever the spec)."""
    initial = np.asarray(spec.initial_error_m, dtype=float) + rng.normal(
        0.0, spec.initial_error_std_m, 2
    )
    velocity = spec.velocity_error_m_s * _unit(rng.uniform(0.0, 2.0 * np.pi))
    accel = spec.accel_bias_ug * MICRO_G * _unit(rng.uniform(0.0, 2.0 * np.pi))
    signs = rng.choice([-1.0, 1.0], size=4)
    gyro = spec.gyro_bias_deg_h * DEG_PER_H * signs[:3]
    heading0 = abs(np.radians(spec.heading_error_deg)) * signs[3]
    return dict(initial=initial, velocity=velocity, accel=accel, gyro=gyro, heading0=heading0)


def _draw_values(model: InsErrorModel, spec: InsSpec, rng: np.random.Generator) -> dict:
    """The independent draws ``z`` of the error-state prior, and the named terms."""
    if model.mode == "dvl":
        initial = np.asarray(spec.initial_error_m, dtype=float) + rng.normal(
            0.0, spec.initial_error_std_m, 2
        )
        bias = model.dvl_bias * _unit(rng.uniform(0.0, 2.0 * np.pi))
        signs = rng.choice([-1.0, 1.0], size=3)
        psi0, eps_z, scale = (
            model.heading_error * signs[0],
            model.gyro_bias * signs[1],
            (model.dvl_scale_error * signs[2]),
        )
        z = np.array([*initial, psi0, eps_z, scale, *bias])
        zero = np.zeros(2)
        terms = dict(initial=initial, velocity=zero, accel=zero, gyro=np.array([0, 0, eps_z]))
        return dict(z=z, heading0=psi0, heading_draws=(2, 3), **terms)
    errors = _draw_trial_errors(spec, rng)
    z = np.concatenate(
        [
            errors["initial"],
            errors["velocity"],
            errors["accel"],
            errors["gyro"],
            [errors["heading0"]],
            np.zeros(2 if model.dvl_aiding else 0),
        ]
    )
    return dict(z=z, heading_draws=(8, 9), **errors)


def simulate_ins(
    true: TrueTrajectory, spec: InsSpec, rng: np.random.Generator, dvl: DvlSpec | None = None
) -> InsTrack:
    """Integrate the INS errors along a true trajectory.

    Parameters
    ----------
    true : TrueTrajectory
        The true track (its ``times``, ``positions`` and ``heading`` are used).
    spec : InsSpec
        Datasheet numbers (see the module docstring for how each enters).
    rng : numpy.random.Generator
        Source of every random draw: the per-trial constants, then the process noise.
    dvl : DvlSpec, optional
        The DVL of a ``mode: dvl`` navigator (required there, unused by a free INS).

    Returns
    -------
    InsTrack
        Indicated positions (m) and heading (rad), and the error terms;
        ``rotation_error`` is the part of the position error due to the initial heading
        error and the azimuth drift (no noise), ``schuler_error`` the rest.
    """
    model = InsErrorModel.from_specs(spec, dvl if getattr(spec, "mode", "free") == "dvl" else None)
    times = np.asarray(true.times, dtype=float)
    es = error_state(model, times, true.positions)
    draws = _draw_values(model, spec, rng)
    x0 = es.prior_factor @ draws["z"]
    white = rng.standard_normal((times.size - 1, es.dim))
    states = propagate(es, x0, white)
    heading_z = np.zeros_like(draws["z"])
    heading_z[list(draws["heading_draws"])] = draws["z"][list(draws["heading_draws"])]
    rotation = propagate(es, es.prior_factor @ heading_z) @ es.position_map.T
    position_error = states @ es.position_map.T
    heading_error = states[:, model.names.index("psi")]
    return InsTrack(
        indicated=true.positions + position_error,
        heading=true.heading + heading_error,
        position_error=position_error,
        schuler_error=position_error - rotation,
        rotation_error=rotation,
        heading_error=heading_error,
        initial_error=draws["initial"],
        velocity_error=draws["velocity"],
        accel_bias=draws["accel"],
        gyro_bias=draws["gyro"],
    )


def prior_initial_sigma(spec: InsSpec) -> float:
    """Prior 1-sigma of the initial position error per axis, metres.

    ``prior_sigma_m`` if given, else ``sqrt(initial_error_std_m^2 + (max|initial_error_m|
    / 2)^2)``: a fixed offset counts as 2 sigma, so a 3-sigma window contains it.
    """
    if spec.prior_sigma_m is not None:
        return float(spec.prior_sigma_m)
    fixed = max(abs(float(e)) for e in spec.initial_error_m)
    return float(np.hypot(spec.initial_error_std_m, fixed / 2.0))


def _level_variance(spec: InsSpec, times: np.ndarray) -> np.ndarray:
    """Per-axis position variance of the Schuler channel, m^2."""
    accel_psd, gyro_psd = _noise_psds(spec)
    cov = np.diag(
        [
            prior_initial_sigma(spec) ** 2,
            spec.velocity_error_m_s**2 / 2.0,
            0.0,
            (spec.accel_bias_ug * MICRO_G) ** 2 / 2.0,
            (spec.gyro_bias_deg_h * DEG_PER_H) ** 2,
        ]
    )
    out = np.empty(times.size)
    out[0] = cov[0, 0]
    for k, dt in enumerate(np.diff(times)):
        transition, q, _ = _discrete_cached(float(dt), spec.schuler, accel_psd, gyro_psd)
        cov = transition @ cov @ transition.T + q
        out[k + 1] = cov[0, 0]
    return out


def _heading_variance(spec: InsSpec, times: np.ndarray, distance: np.ndarray) -> np.ndarray:
    """Variance of the cross-track error from the heading error, m^2 (straight track)."""
    dt = np.diff(times)
    step = np.diff(distance)
    mid_t = 0.5 * (times[1:] + times[:-1]) - times[0]
    mid_d = 0.5 * (distance[1:] + distance[:-1])
    zero = np.zeros(1)
    drift_sum = np.concatenate([zero, np.cumsum(mid_t * step)])
    s0 = np.concatenate([zero, np.cumsum(dt)])
    s1 = np.concatenate([zero, np.cumsum(dt * mid_d)])
    s2 = np.concatenate([zero, np.cumsum(dt * mid_d**2)])
    walk = np.clip(distance**2 * s0 - 2.0 * distance * s1 + s2, 0.0, None)
    psi0 = np.radians(spec.heading_error_deg)
    eps_z = spec.gyro_bias_deg_h * DEG_PER_H
    noise = spec.gyro_noise_deg_rt_h * DEG_PER_RT_H
    return psi0**2 * distance**2 + eps_z**2 * drift_sum**2 + noise**2 * walk


def _earth_rate_variance(spec: InsSpec, times: np.ndarray) -> np.ndarray:
    """Variance of the north error from ``Omega cos L psi_0`` acting as a level drift, m^2."""
    lat = getattr(spec, "latitude_deg", None)
    if lat is None:
        return np.zeros_like(times)
    drift = EARTH_RATE_RAD_S * np.cos(np.radians(lat)) * np.radians(spec.heading_error_deg)
    return schuler_gyro_error(drift, times - times[0]) ** 2


def _dvl_variance(spec: InsSpec, dvl: DvlSpec, times, distance) -> np.ndarray:
    """Largest eigenvalue of the DVL dead-reckoning position covariance, m^2 (straight)."""
    track = np.column_stack([np.zeros_like(distance), distance])
    es = error_state(InsErrorModel.from_specs(spec, dvl), times, track)
    cov = es.position_cov(propagate_cov(es))
    return np.linalg.eigvalsh(cov)[:, -1]


def position_sigma(spec: InsSpec, times, distance_m=None, dvl: DvlSpec | None = None) -> np.ndarray:
    """Prior per-axis 1-sigma of the indicated position error at each time.

    The covariance of the level-channel state is propagated with the same exact
    discretisation as :func:`simulate_ins`, from ``diag(sigma0^2, v^2/2, 0, b^2/2,
    eps^2)``: ``sigma0`` from :func:`prior_initial_sigma`, ``v^2/2`` and ``b^2/2`` the
    per-axis variance of a velocity error / accelerometer bias of fixed magnitude in a
    uniformly random direction, ``eps^2`` that of a gyro drift of random sign. The
    heading error adds the variance of ``sum_j psi_e(t_j) * (distance step j)``, the
    cross-track error of a straight track, with ``psi_e`` as in the module docstring
    (initial error, azimuth drift, random walk); it is added in full to *each* axis
    (conservative: its direction depends on the track heading, which this prior ignores;
    on a curved track ``distance * psi`` bounds the chord error from above). This
    rotation-of-distance term is the no-Schuler limit of the free INS and bounds the
    Schuler-loop response from above (``sin(omega_s t) / omega_s <= t``). With
    ``ins.latitude_deg`` the Earth-rate coupling of ``psi_0`` (see
    :mod:`geofix.nav.errstate`) adds its squared north error.

    In ``mode: dvl`` the variance is the largest eigenvalue of the position block of the
    error-state covariance propagated along a straight track of the given distance (the
    initial error, heading, azimuth drift, scale factor, bias and noise of the DVL).

    Parameters
    ----------
    spec : InsSpec
        Datasheet numbers.
    times : array_like
        ``(n,)`` sample times, seconds (increasing); the prior starts at ``times[0]``.
    distance_m : array_like, optional
        ``(n,)`` distance travelled at each time, metres (e.g. nominal speed * time).
        Without it the heading-error term is left out.
    dvl : DvlSpec, optional
        The DVL of a ``mode: dvl`` navigator.

    Returns
    -------
    numpy.ndarray
        ``(n,)`` 1-sigma per axis, metres.
    """
    times = np.atleast_1d(np.asarray(times, dtype=float))
    if getattr(spec, "mode", "free") == "dvl":
        if dvl is None:
            raise ConfigError("ins.mode: dvl needs a dvl block (noise_std_m_s, bias_m_s, ...)")
        distance = np.zeros_like(times) if distance_m is None else distance_m
        distance = np.broadcast_to(np.asarray(distance, dtype=float), times.shape)
        sigma0 = prior_initial_sigma(spec)
        variance = _dvl_variance(spec, dvl, times, distance - distance[0])
        initial = np.max(np.asarray(spec.initial_error_m, float) ** 2) + spec.initial_error_std_m**2
        return np.sqrt(np.maximum(variance - initial + sigma0**2, sigma0**2))
    variance = _level_variance(spec, times) + _earth_rate_variance(spec, times)
    if distance_m is not None:
        distance = np.broadcast_to(np.asarray(distance_m, dtype=float), times.shape)
        variance = variance + _heading_variance(spec, times, distance - distance[0])
    return np.sqrt(variance)
