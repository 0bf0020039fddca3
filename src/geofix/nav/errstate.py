r"""The INS error state: one linear model for the simulator, the bound and the filters.

The navigation error of a trial is a linear function of a small state vector ``x``::

    x_0 = T_0 z,            z ~ the per-trial draws (independent components)
    x_k = F_k x_{k-1} + w_k,  w_k ~ N(0, Q_k)
    position error  e_k = H x_k  (indicated - true, metres)

:func:`error_state` builds ``F_k``, ``Q_k``, the prior ``P_0 = T_0 diag(E[z^2]) T_0^T``
(the simulator's second moments) and ``H`` along a reference track;
:func:`geofix.nav.ins.simulate_ins` draws ``z`` and runs the same recursion, the
Cramér–Rao bound (:mod:`geofix.evaluate.crlb`) and the marginalised particle filter
(:mod:`geofix.filters.mpf`) use the same matrices.

``mode: free`` -- a free inertial navigator (12 states)
---------------------------------------------------------
``[dp_x, dp_y, dv_x, dv_y, phi_x, phi_y, ba_x, ba_y, eps_x, eps_y, psi, eps_z]``: per
level channel the Schuler loop of :mod:`geofix.nav.ins` (position, velocity, tilt,
accelerometer bias, level gyro drift), plus the azimuth error ``psi`` (positive =
indicated heading clockwise of the true one) and the azimuth gyro drift ``eps_z``
(``psi' = eps_z + w_g``). In a free INS the azimuth error acts in two ways (Titterton &
Weston, *Strapdown Inertial Navigation Technology*, 2nd ed., 2004, sections 12.3-12.4;
Britting, *Inertial Navigation Systems Analysis*, 1971, ch. 6):

- it mis-resolves the specific force: the horizontal acceleration ``a`` is integrated
  rotated by ``psi``, so the velocity error gains ``psi J a`` with ``J (u, v) = (v, -u)``
  (the derivative of a clockwise rotation). Integrated, the INS velocity carries the
  *velocity gained since alignment* rotated by ``psi``; that velocity error then runs
  through the Schuler loop like any other (``dp = dv0 sin(omega_s t) / omega_s`` for a
  constant velocity), it does not rotate the distance travelled (that is the DVL dead
  reckoning below, and the free INS only without the Schuler loop, ``schuler: false``).
  The navigator is taken as aligned at rest: at the first sample the whole velocity
  ``v_0`` was gained since alignment (``dv_0`` contains ``psi_0 J v_0``), and each change
  of the step velocity ``u_k - u_{k-1}`` adds ``psi J (u_k - u_{k-1})`` to ``dv``;
- through the Earth rate: the misalignment vector obeys ``phi' = -omega_ie x phi + ...``,
  whose east component holds ``-Omega cos L psi``: a level gyro drift of ``Omega cos L
  psi`` on the tilt that drives the *north* channel (``Omega`` = 7.292115e-5 rad/s, ``L``
  the latitude, ``ins.latitude_deg``; without a latitude this coupling is left out, as at
  a pole). Over a mission of tens of minutes it is the larger of the two.

The slower cross-couplings (``Omega sin L`` between the tilts, ``Omega cos L phi_e`` on
``psi``) are left out.

``mode: dvl`` -- DVL-aided dead reckoning (7 states)
------------------------------------------------------
``[dp_x, dp_y, psi, eps_z, s, b_x, b_y]``: the position is the integral of the DVL
velocity over ground, with a scale-factor error ``s`` (dimensionless, ``dvl.scale_error``)
and a constant bias ``b`` (m/s, ``dvl.bias_m_s``), rotated into the local frame by the
attitude sensor's heading, whose error is ``psi + eps_z t``. Over a step of displacement
``d`` (metres) and duration ``dt``, to first order in the errors::

    dp_k = dp_{k-1} + psi J d + eps_z (dt / 2) J d + s d + b dt + n_k

``n_k`` the DVL's white noise integrated over the step (per-axis variance
``(noise_std_m_s dt)^2``, one velocity sample per interval). The position error grows
with the distance travelled (heading and scale) and with time (bias); ``psi`` also walks
with the gyro noise.

DVL aiding of a free INS
------------------------
With a ``dvl`` block and ``mode: free`` the DVL is a separate velocity measurement: the
state gains the DVL bias ``[bd_x, bd_y]`` and :attr:`ErrorState.velocity_map` gives the
measurement ``v_INS - v_DVL = dv - bd + noise`` (noise variance
:attr:`ErrorState.velocity_noise_var`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from functools import lru_cache

import numpy as np
from scipy.linalg import expm

from geofix.errors import ConfigError

GRAVITY_M_S2 = 9.80665
EARTH_RADIUS_M = 6_371_000.0
EARTH_RATE_RAD_S = 7.292115e-5
MICRO_G = GRAVITY_M_S2 * 1e-6
DEG_PER_H = np.pi / 180.0 / 3600.0
DEG_PER_RT_H = np.pi / 180.0 / 60.0

FREE_STATES: tuple[str, ...] = ("dp_x", "dp_y", "dv_x", "dv_y", "phi_x", "phi_y", "ba_x", "ba_y")
FREE_STATES += ("eps_x", "eps_y", "psi", "eps_z")
DVL_STATES = ("dp_x", "dp_y", "psi", "eps_z", "s", "b_x", "b_y")
AIDING_STATES = ("bd_x", "bd_y")


@dataclass(frozen=True)
class InsErrorModel:
    """The datasheet numbers of one navigator in SI units (built by :meth:`from_specs`).

    Attributes
    ----------
    mode : str
        ``"free"`` or ``"dvl"``.
    schuler : bool
        Close the Schuler loop (free mode).
    latitude_rad : float or None
        Latitude for the Earth-rate coupling of the azimuth error, radians (None: none).
    initial_offset : tuple of float
        Fixed ``(east, north)`` initial position error, metres.
    initial_std : float
        Random per-axis initial position error, metres.
    velocity_error : float
        Magnitude of the initial velocity error, m/s (uniform direction).
    accel_bias : float
        Magnitude of the accelerometer bias, m/s^2 (uniform direction).
    gyro_bias : float
        Gyro drift of each axis, rad/s (random sign).
    heading_error : float
        Magnitude of the initial heading error, radians (random sign).
    accel_psd, gyro_psd : float
        White accelerometer / gyro noise, m^2/s^3 and rad^2/s.
    dvl_noise_std, dvl_bias, dvl_scale_error : float
        The DVL's white noise (m/s), bias magnitude (m/s, uniform direction) and scale
        error magnitude (dimensionless, random sign).
    dvl_aiding : bool
        Free mode with a DVL velocity measurement (adds the DVL bias states).
    """

    mode: str = "free"
    schuler: bool = True
    latitude_rad: float | None = None
    initial_offset: tuple[float, float] = (0.0, 0.0)
    initial_std: float = 0.0
    velocity_error: float = 0.0
    accel_bias: float = 0.0
    gyro_bias: float = 0.0
    heading_error: float = 0.0
    accel_psd: float = 0.0
    gyro_psd: float = 0.0
    dvl_noise_std: float = 0.0
    dvl_bias: float = 0.0
    dvl_scale_error: float = 0.0
    dvl_aiding: bool = False

    @classmethod
    def from_specs(cls, ins, dvl=None) -> InsErrorModel:
        """The model of an ``InsSpec`` and an optional ``DvlSpec`` (datasheet units).

        Raises
        ------
        ConfigError
            ``ins.mode`` is ``dvl`` without a DVL.
        """
        mode = getattr(ins, "mode", "free")
        if mode == "dvl" and dvl is None:
            raise ConfigError("ins.mode: dvl needs a dvl block (noise, bias, scale error)")
        lat = getattr(ins, "latitude_deg", None)
        return cls(
            mode=mode,
            schuler=bool(ins.schuler),
            latitude_rad=None if lat is None else float(np.radians(lat)),
            initial_offset=(float(ins.initial_error_m[0]), float(ins.initial_error_m[1])),
            initial_std=float(ins.initial_error_std_m),
            velocity_error=float(ins.velocity_error_m_s),
            accel_bias=float(ins.accel_bias_ug) * MICRO_G,
            gyro_bias=float(ins.gyro_bias_deg_h) * DEG_PER_H,
            heading_error=abs(float(np.radians(ins.heading_error_deg))),
            accel_psd=(float(ins.accel_noise_ug_rt_hz) * MICRO_G) ** 2,
            gyro_psd=(float(ins.gyro_noise_deg_rt_h) * DEG_PER_RT_H) ** 2,
            dvl_noise_std=0.0 if dvl is None else float(dvl.noise_std_m_s),
            dvl_bias=0.0 if dvl is None else float(dvl.bias_m_s),
            dvl_scale_error=0.0 if dvl is None else abs(float(getattr(dvl, "scale_error", 0.0))),
            dvl_aiding=mode == "free" and dvl is not None,
        )

    def to_dict(self) -> dict:
        """The datasheet numbers as a JSON-ready mapping (SI units, field names as keys)."""
        out = asdict(self)
        out["initial_offset"] = [float(v) for v in self.initial_offset]
        return out

    @classmethod
    def from_dict(cls, data: dict) -> InsErrorModel:
        """The model back from :meth:`to_dict` (keys this version does not know are skipped).

        Raises
        ------
        ConfigError
            ``data`` is not a mapping, or a value has the wrong type.
        """
        if not isinstance(data, dict):
            raise ConfigError(f"INS error model: expected a mapping, got {type(data).__name__}")
        known = {f.name for f in fields(cls)}
        values = {k: v for k, v in data.items() if k in known}
        try:
            if "initial_offset" in values:
                east, north = values["initial_offset"]
                values["initial_offset"] = (float(east), float(north))
            for key in ("mode",):
                if key in values:
                    values[key] = str(values[key])
            for key in ("schuler", "dvl_aiding"):
                if key in values:
                    values[key] = bool(values[key])
            for key in known - {"mode", "schuler", "dvl_aiding", "initial_offset"}:
                if key in values and values[key] is not None:
                    values[key] = float(values[key])
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"INS error model: bad value ({exc})") from None
        if values.get("mode", "free") not in ("free", "dvl"):
            raise ConfigError(f"INS error model: mode must be free or dvl, got {values['mode']!r}")
        return cls(**values)

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the state components, in order."""
        if self.mode == "dvl":
            return DVL_STATES
        return FREE_STATES + (AIDING_STATES if self.dvl_aiding else ())

    @property
    def dim(self) -> int:
        """Number of states ``d``."""
        return len(self.names)


@dataclass(frozen=True, eq=False)
class ErrorState:
    """The linear error model of one trial along a reference track.

    Attributes
    ----------
    model : InsErrorModel
        Its datasheet numbers.
    transitions : numpy.ndarray
        ``(n - 1, d, d)`` ``F_k``: ``x_k = F_k x_{k-1} + w_k``.
    process_cov : numpy.ndarray
        ``(n - 1, d, d)`` ``Q_k`` (may be singular, or zero), state units squared.
    prior_factor : numpy.ndarray
        ``(d, m)`` ``T_0`` with ``x_0 = T_0 z``.
    prior_moments : numpy.ndarray
        ``(m,)`` second moments ``E[z_j^2]`` of the independent draws ``z``.
    position_map : numpy.ndarray
        ``(2, d)`` ``H``: position error ``e = H x``, metres.
    velocity_map : numpy.ndarray or None
        ``(2, d)`` map to ``v_INS - v_DVL`` when a DVL aids a free INS, m/s.
    velocity_noise_var : float
        Per-axis variance of that measurement, m^2/s^2.
    online_velocity : numpy.ndarray or None
        ``(2,)`` step velocity of the last step built online (:func:`step_matrices`), m/s.
    """

    model: InsErrorModel
    transitions: np.ndarray
    process_cov: np.ndarray
    prior_factor: np.ndarray
    prior_moments: np.ndarray
    position_map: np.ndarray
    velocity_map: np.ndarray | None = None
    velocity_noise_var: float = 0.0
    online_velocity: np.ndarray | None = None

    @property
    def dim(self) -> int:
        """Number of states ``d``."""
        return self.position_map.shape[1]

    @property
    def prior_cov(self) -> np.ndarray:
        """``(d, d)`` prior covariance ``T_0 diag(E[z^2]) T_0^T``."""
        return (self.prior_factor * self.prior_moments) @ self.prior_factor.T

    def with_simulator_position_prior(self) -> ErrorState:
        """The same model whose start position prior is the simulator's own spread.

        The simulator draws the start position error as ``initial_offset`` plus a normal
        spread of ``initial_std`` per axis: an estimator told that distribution holds the
        offset as known and the spread as its only uncertainty. The second moments of the
        draws ``p_x, p_y`` become ``initial_std^2`` (0 for a fixed offset); every other
        draw keeps its second moment.
        """
        moments = self.prior_moments.copy()
        moments[:2] = self.model.initial_std**2
        return replace(self, prior_moments=moments)

    def position_cov(self, cov: np.ndarray) -> np.ndarray:
        """``H P H^T`` of ``(..., d, d)`` state covariances, m^2."""
        h = self.position_map
        return h @ cov @ h.T


def _clockwise_derivative(vector) -> np.ndarray:
    """``J v = (v_y, -v_x)``: the change of ``v`` rotated clockwise by a small angle (per rad)."""
    v = np.asarray(vector, dtype=float)
    return np.stack([v[..., 1], -v[..., 0]], axis=-1)


def step_velocities(times, positions) -> np.ndarray:
    """``(n, 2)`` reference velocity: ``u_k`` the mean over step ``k`` (``u_0 = u_1``), m/s."""
    times = np.asarray(times, dtype=float)
    positions = np.asarray(positions, dtype=float)
    if times.size < 2:
        return np.zeros((times.size, 2))
    u = np.diff(positions, axis=0) / np.diff(times)[:, None]
    return np.vstack([u[:1], u])


def error_state(model: InsErrorModel, times, positions) -> ErrorState:
    """The linear error model along a reference track.

    Parameters
    ----------
    model : InsErrorModel
        Datasheet numbers.
    times : array_like
        ``(n,)`` sample times, seconds.
    positions : array_like
        ``(n, 2)`` reference positions, metres (the true track for the simulator and the
        bound, the indicated track for a filter); only their steps are used.

    Returns
    -------
    ErrorState
        Transitions, process noise, prior and maps (see the module docstring).
    """
    times = np.asarray(times, dtype=float)
    u = step_velocities(times, positions)
    dts = np.diff(times)
    build = _dvl_steps if model.mode == "dvl" else _free_steps
    transitions, process = build(model, dts, u)
    factor, moments = _prior(model, u[0])
    d = model.dim
    h = np.zeros((2, d))
    h[0, 0] = h[1, 1] = 1.0
    vmap = None
    if model.dvl_aiding:
        vmap = np.zeros((2, d))
        vmap[0, 2] = vmap[1, 3] = 1.0
        vmap[0, 12] = vmap[1, 13] = -1.0
    return ErrorState(
        model=model,
        transitions=transitions,
        process_cov=process,
        prior_factor=factor,
        prior_moments=moments,
        position_map=h,
        velocity_map=vmap,
        velocity_noise_var=model.dvl_noise_std**2,
    )


# --------------------------------------------------------------------------- free INS
def _free_steps(model: InsErrorModel, dts, u) -> tuple[np.ndarray, np.ndarray]:
    d = model.dim
    transitions = np.empty((dts.size, d, d))
    process = np.empty((dts.size, d, d))
    for k, dt in enumerate(dts):
        phi, q = _free_cached(
            float(dt), model.schuler, model.latitude_rad, model.accel_psd, model.gyro_psd, d
        )
        jump = np.eye(d)
        jump[2:4, 10] = _clockwise_derivative(u[k + 1] - u[k])
        transitions[k] = phi @ jump
        process[k] = q
    return transitions, process


@lru_cache(maxsize=64)
def _free_cached(dt, schuler, latitude, accel_psd, gyro_psd, d):
    a = np.zeros((d, d))
    for axis in (0, 1):
        p, v, t, b, e = axis, 2 + axis, 4 + axis, 6 + axis, 8 + axis
        a[p, v] = 1.0
        a[v, t] = -GRAVITY_M_S2
        a[v, b] = 1.0
        a[t, v] = 1.0 / EARTH_RADIUS_M if schuler else 0.0
        a[t, e] = 1.0
    if latitude is not None:
        a[5, 10] = EARTH_RATE_RAD_S * np.cos(latitude)  # north channel's tilt
    a[10, 11] = 1.0
    qc = np.zeros(d)
    qc[2:4] = accel_psd
    qc[4:6] = gyro_psd
    qc[10] = gyro_psd
    transition, q = van_loan(a, np.diag(qc), dt)
    transition.flags.writeable = False
    q.flags.writeable = False
    return transition, q


def van_loan(a: np.ndarray, qc: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact discretisation ``(expm(A dt), Q_d)`` of ``x' = A x + w``, ``E[w w^T] = Qc``.

    Van Loan (1978): one ``expm`` of the ``2d x 2d`` block matrix ``[[-A, Qc], [0, A^T]]``.

    Parameters
    ----------
    a : numpy.ndarray
        ``(d, d)`` continuous-time system matrix ``A``, per second.
    qc : numpy.ndarray
        ``(d, d)`` power spectral density ``Qc`` of the white noise ``w``, state units
        squared per second.
    dt : float
        Step, seconds.

    Returns
    -------
    tuple of numpy.ndarray
        ``(F, Q_d)``: the ``(d, d)`` transition over ``dt`` and the symmetric ``(d, d)``
        covariance of the noise accumulated over it, state units squared.
    """
    d = a.shape[0]
    block = np.zeros((2 * d, 2 * d))
    block[:d, :d] = -a
    block[:d, d:] = qc
    block[d:, d:] = a.T
    e = expm(block * dt)
    transition = e[d:, d:].T
    q = transition @ e[:d, d:]
    return transition, 0.5 * (q + q.T)


# --------------------------------------------------------------------------- DVL DR
def _dvl_steps(model: InsErrorModel, dts, u) -> tuple[np.ndarray, np.ndarray]:
    d = model.dim
    transitions = np.tile(np.eye(d), (dts.size, 1, 1))
    process = np.zeros((dts.size, d, d))
    for k, dt in enumerate(dts):
        step = u[k + 1] * dt
        rot = _clockwise_derivative(step)
        transitions[k, 0:2, 2] = rot
        transitions[k, 0:2, 3] = 0.5 * dt * rot
        transitions[k, 0:2, 4] = step
        transitions[k, 0, 5] = transitions[k, 1, 6] = dt
        transitions[k, 2, 3] = dt
        process[k, 0, 0] = process[k, 1, 1] = (model.dvl_noise_std * dt) ** 2
        process[k, 2, 2] = model.gyro_psd * dt
    return transitions, process


# --------------------------------------------------------------------------- prior
#: Names of the independent per-trial draws ``z`` (free mode; the DVL mode uses the
#: first two, then heading, azimuth drift, scale, bias).
FREE_DRAWS: tuple[str, ...] = (
    "p_x",
    "p_y",
    "v_x",
    "v_y",
    "b_x",
    "b_y",
    "e_x",
    "e_y",
    "e_z",
    "psi0",
)
FREE_DRAWS += ("bd_x", "bd_y")
DVL_DRAWS = ("p_x", "p_y", "psi0", "e_z", "s", "b_x", "b_y")


def _prior(model: InsErrorModel, v0) -> tuple[np.ndarray, np.ndarray]:
    """``T_0`` ``(d, m)`` and the second moments ``(m,)`` of the draws ``z``."""
    off = np.asarray(model.initial_offset, dtype=float)
    pos = off**2 + model.initial_std**2
    if model.mode == "dvl":
        factor = np.eye(len(DVL_DRAWS))
        moments = np.array(
            [
                *pos,
                model.heading_error**2,
                model.gyro_bias**2,
                model.dvl_scale_error**2,
                model.dvl_bias**2 / 2.0,
                model.dvl_bias**2 / 2.0,
            ]
        )
        return factor, moments
    d = model.dim
    m = 10 + (2 if model.dvl_aiding else 0)
    factor = np.zeros((d, m))
    # p -> dp, v -> dv, b -> ba, e_x/e_y -> eps, e_z -> eps_z, psi0 -> psi and dv
    for src, dst in ((0, 0), (1, 1), (2, 2), (3, 3), (4, 6), (5, 7), (6, 8), (7, 9), (8, 11)):
        factor[dst, src] = 1.0
    factor[10, 9] = 1.0
    factor[2:4, 9] = _clockwise_derivative(v0)
    if model.dvl_aiding:
        factor[12, 10] = factor[13, 11] = 1.0
    vel, acc, bd = model.velocity_error**2 / 2.0, model.accel_bias**2 / 2.0, model.dvl_bias**2 / 2
    terms = [*pos, vel, vel, acc, acc, *[model.gyro_bias**2] * 3, model.heading_error**2]
    terms += [bd, bd] if model.dvl_aiding else []
    return factor, np.asarray(terms, dtype=float)


def noise_factor(q: np.ndarray) -> np.ndarray:
    """A matrix ``L`` with ``L @ L.T == q`` for a (possibly singular) covariance ``q``."""
    values, vectors = np.linalg.eigh(q)
    return vectors * np.sqrt(np.clip(values, 0.0, None))


def propagate(es: ErrorState, x0: np.ndarray, white=None) -> np.ndarray:
    """Run ``x_k = F_k x_{k-1} + L_k white_k`` from ``x0``; ``(n, d)`` states.

    Parameters
    ----------
    es : ErrorState
        The error model: transitions ``F_k`` and process covariances ``Q_k``.
    x0 : numpy.ndarray
        ``(d,)`` initial error state, state units (metres, m/s, radians, ...).
    white : numpy.ndarray, optional
        ``(n - 1, d)`` standard normals (None: no process noise); ``L_k`` is
        :func:`noise_factor` of ``Q_k``.

    Returns
    -------
    numpy.ndarray
        ``(n, d)`` error states, ``x_0`` first.
    """
    n = es.transitions.shape[0] + 1
    out = np.empty((n, es.dim))
    out[0] = x = np.asarray(x0, dtype=float)
    q_last, factor = None, None
    for k in range(n - 1):
        x = es.transitions[k] @ x
        q = es.process_cov[k]
        if white is not None and np.any(q):
            if q_last is None or not np.array_equal(q, q_last):  # steps of equal dt share Q
                q_last, factor = q, noise_factor(q)
            x = x + factor @ white[k]
        out[k + 1] = x
    return out


def propagate_cov(es: ErrorState) -> np.ndarray:
    """``(n, d, d)`` state covariance of the free-running navigator (no aiding)."""
    n = es.transitions.shape[0] + 1
    out = np.empty((n, es.dim, es.dim))
    out[0] = p = es.prior_cov
    for k in range(n - 1):
        p = es.transitions[k] @ p @ es.transitions[k].T + es.process_cov[k]
        out[k + 1] = p
    return out


# --------------------------------------------------------------------------- online steps
def step_matrices(es: ErrorState, k: int, displacement, dt: float, position_var=0.0) -> tuple:
    """``(es, F_k, Q_k)`` of step ``k``: the precomputed ones, or built from the motion.

    A filter that runs beyond the track its error state was built on (an online
    navigator starts on a one-sample track) gets the step from the indicated
    ``displacement`` (metres) over ``dt`` (seconds), as :func:`error_state` would have
    built it: the step velocity ``u = displacement / dt`` and, in free mode, the
    velocity change since the previous online step (zero at the first one, as
    ``u_0 = u_1`` in :func:`step_velocities`). The returned error state carries that
    velocity for the next step (:attr:`ErrorState.online_velocity`). An online step's
    process noise also gains ``position_var`` on each position axis: the navigator's
    per-step position noise (``Motion.process_var``), which stands for what the linear
    model leaves out (unmodelled motion, the map's and the interpolation's error).

    Parameters
    ----------
    es : ErrorState
        The error model.
    k : int
        Step index (``x_{k+1} = F_k x_k + w_k``).
    displacement : array_like
        ``(2,)`` indicated displacement over the step, metres.
    dt : float
        Step duration, seconds (0: no motion, ``F = I``, ``Q = 0``).
    position_var : float
        Per-axis position variance added to an online step's ``Q``, m^2.

    Returns
    -------
    tuple
        ``(ErrorState, (d, d) F_k, (d, d) Q_k)``.
    """
    if k < es.transitions.shape[0]:
        return es, es.transitions[k], es.process_cov[k]
    dt = float(dt)
    d = es.dim
    extra = np.zeros((d, d))
    extra[0, 0] = extra[1, 1] = max(float(position_var), 0.0)
    if dt <= 0.0:
        return es, np.eye(d), extra
    u = np.asarray(displacement, dtype=float) / dt
    previous = u if es.online_velocity is None else es.online_velocity
    build = _dvl_steps if es.model.mode == "dvl" else _free_steps
    transitions, process = build(es.model, np.array([dt]), np.vstack([previous, u]))
    return replace(es, online_velocity=u), transitions[0], process[0] + extra
