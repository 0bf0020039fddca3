"""Replay a recorded mission through the online navigator, ping by ping.

The INS the navigator corrects:

- a log whose navigation is GNSS (a surface ship's GSF) -- the navigation is the truth
  and an INS drift is simulated on it (:func:`geofix.nav.ins.simulate_ins`) from a
  scenario's ``ins:`` numbers (:data:`DEFAULT_INS` unless given), the initial error
  optionally replaced by ``initial_error_m`` metres in a direction drawn from the seed;
- a log with its own dead-reckoned navigation (a ``geofix export``, a vehicle log) --
  that navigation is the INS, and its truth (if any) judges the estimates.

Each method gets one :class:`geofix.Navigator`; the replay only feeds it, in time order,
one ``motion`` and one ``measure`` per ping -- the same steps a campaign trial and a
server connection take.

A mission of several fields (:attr:`geofix.logs.Mission.fields`: an MGD77T log read with
``--field depth --field gravity``) is replayed with one map per field, each ping's
further readings folded into the same update (``Navigator(..., field_grids=...)``); a
further field's noise 1-sigma is given per field, else :data:`DEFAULT_FIELD_NOISE_STD`.
"""

from __future__ import annotations

import uuid
import warnings
import zlib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from geofix.conventions import PHYSICAL_LIMITS
from geofix.errors import ConfigError, GeofixError, GeofixWarning
from geofix.logs.mission import Mission
from geofix.maps.grid import Grid
from geofix.navigator import Estimate

DEFAULT_INS = {"velocity_error_m_s": 0.05, "heading_error_deg": 0.05, "gyro_bias_deg_h": 0.01}
"""INS numbers simulated on a GNSS track when no scenario is given (a navigation-grade
unit: 5 cm/s velocity error, 0.05 deg heading error, 0.01 deg/h gyro drift)."""
DEFAULT_PRIOR_SIGMA_M = 100.0
"""Prior 1-sigma of a dead-reckoned log that states none, metres."""
OUTPUT_NAMES = ("estimates.csv", "estimates.nc", "replay.png")
"""The files a replay writes in its output folder (each carries the replay's run id)."""
RUN_ID_KEY = "run_id"
"""Column of ``estimates.csv``, attribute of ``estimates.nc`` and text key of
``replay.png`` holding the id of the replay that wrote them."""
NOISE_STD_RANGE = (1e-6, 1e6)
"""Accepted measurement noise 1-sigma per beam, map units (``--noise-std``)."""
MAX_MISSION_SPAN_S = 30 * 86_400.0
"""Pings farther than this from the log's median ping time are dropped, seconds."""
MAX_BEAM_OFFSET_M = 1.0e5
"""Beams farther than this from the vehicle (across or along) are dropped, metres."""
MAX_POSITION_M = 4.0e7
"""Pings whose navigation lies farther than this from the frame's origin are dropped."""
DEFAULT_FIELD_NOISE_STD = {"depth": 2.0, "gravity": 2.0, "magnetic": 20.0}
"""Measurement noise 1-sigma of a further field when none is given, map units: the
navigator's default for depth (m), the upper end of a marine gravimeter's 1-2 mGal for a
free-air anomaly, and 20 nT for a residual magnetic field (a ship's magnetometer reads
to a few nT; the diurnal variation and the map's own error dominate)."""


@dataclass(frozen=True, eq=False)
class ReplayInput:
    """What the navigators are fed.

    ``indicated`` ``(n, 2)`` INS positions (m), ``heading`` ``(n,)`` rad, ``sigma``
    ``(n,)`` per-axis prior sigma (m), ``truth`` ``(n, 2)`` or None, ``ins_model`` the
    :class:`~geofix.nav.errstate.InsErrorModel` of the INS numbers (for ``mpf`` and
    ``pmf:model=errstate``) or None.
    """

    indicated: np.ndarray
    heading: np.ndarray
    sigma: np.ndarray
    truth: np.ndarray | None
    ins_model: object = None


@dataclass(frozen=True, eq=False)
class ReplayResult:
    """Per-ping estimates of every method and their summary."""

    mission: Mission
    inputs: ReplayInput
    estimates: dict[str, list[Estimate]]
    summary: dict = field(default_factory=dict)
    run_id: str = field(default_factory=lambda: uuid.uuid4().hex)


def replay_inputs(mission: Mission, ins=None, initial_error_m=None, seed: int = 0) -> ReplayInput:
    """The INS track to correct and the truth to judge against (see the module text).

    Parameters
    ----------
    mission : Mission
        The log.
    ins : InsSpec or dict, optional
        INS numbers for a GNSS log (default :data:`DEFAULT_INS`).
    initial_error_m : float, optional
        Initial INS position error, metres (at most :data:`MAX_POSITION_M`), in a
        direction drawn from ``seed`` (GNSS logs); for a dead-reckoned log, the prior
        sigma is half of it when the log states none.
    seed : int
        Seed of the INS simulation.
    """
    from geofix.nav.errstate import InsErrorModel
    from geofix.nav.ins import position_sigma, prior_initial_sigma, simulate_ins
    from geofix.nav.spec import InsSpec
    from geofix.nav.trajectory import TrueTrajectory

    if initial_error_m is not None and not 0 <= initial_error_m <= MAX_POSITION_M:
        limit = f"0 .. {MAX_POSITION_M:g} m"
        raise ConfigError(f"--ins-initial-error-m must lie within {limit}, got {initial_error_m}")
    spec = ins if isinstance(ins, InsSpec) else InsSpec(**(DEFAULT_INS if ins is None else ins))
    try:
        model = InsErrorModel.from_specs(spec)
    except ConfigError:  # a dvl-mode INS without its DVL: only error-state filters need it
        model = None
    if mission.nav_source == "ins":
        if mission.sigma_position is not None:
            sigma = np.asarray(mission.sigma_position, dtype=float)
        else:
            s0 = DEFAULT_PRIOR_SIGMA_M if initial_error_m is None else max(initial_error_m / 2, 1)
            sigma = np.full(mission.n, float(s0))
        return ReplayInput(mission.nav, mission.heading, sigma, mission.truth, model)
    rng = np.random.default_rng([int(seed), 0x1175])
    if initial_error_m is not None:
        angle = rng.uniform(0.0, 2.0 * np.pi)
        offset = float(initial_error_m) * np.array([np.cos(angle), np.sin(angle)])
        spec = spec.model_copy(update={"initial_error_m": tuple(offset.tolist())})
    truth = np.asarray(mission.nav, dtype=float)
    times = np.asarray(mission.times, dtype=float)
    velocity = np.gradient(truth, times, axis=0) if mission.n > 1 else np.zeros((1, 2))
    true = TrueTrajectory(times, truth, np.asarray(mission.heading, float), velocity)
    track = simulate_ins(true, spec, rng)
    distance = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(truth, axis=0).T))])
    sigma = position_sigma(spec, times, distance)
    sigma[0] = max(sigma[0], prior_initial_sigma(spec), 1.0)
    sigma = np.maximum.accumulate(sigma)
    return ReplayInput(track.indicated, track.heading, sigma, truth, model)


def load_ins_model(path):
    """The :class:`~geofix.nav.errstate.InsErrorModel` of a scenario's ``ins:`` (and ``dvl:``).

    Raises
    ------
    ConfigError
        The file is not a valid scenario (as :func:`geofix.sim.scenario.load_scenario`).
    """
    from geofix.nav.errstate import InsErrorModel
    from geofix.sim.scenario import load_scenario

    scenario = load_scenario(path)
    return InsErrorModel.from_specs(scenario.ins, scenario.dvl)


def load_field_maps(paths, grid: Grid) -> tuple[Grid, ...]:
    """The further fields' maps of ``paths``, each in the frame of the primary ``grid``.

    Parameters
    ----------
    paths : sequence of str
        Map files or ``builtin:NAME`` (:func:`geofix.maps.load_grid`), read with their
        defaults (the only 2-D variable or ``z``; the kind from its names and units).
    grid : Grid
        The primary map: its ``meta["projection"]`` is the frame of every map.

    Returns
    -------
    tuple of Grid
        One map per path, resampled onto the primary's frame where its own differs
        (:func:`map_in_frame`).

    Raises
    ------
    ConfigError
        A map of the primary's kind, two of one kind, or one that cannot be put in the
        primary's frame.
    MapError
        A map that cannot be read.
    """
    from geofix.maps.io import load_grid

    maps, kinds = [], [grid.kind]
    for path in paths:
        further = load_grid(path)
        if further.kind in kinds:
            raise ConfigError(
                f"map {path} is a {further.kind} map like an earlier --map: give one map "
                "per field kind"
            )
        kinds.append(further.kind)
        maps.append(map_in_frame(further, grid.meta.get("projection"), f"map {path}"))
    return tuple(maps)


def map_in_frame(grid: Grid, frame: str | None, where: str = "map") -> Grid:
    """``grid`` in the metric frame ``frame`` (a PROJ string; None: a metric map's own).

    A map projected from lon/lat gets a frame centred on its own region
    (:func:`geofix.maps.project.local_tmerc`), so two maps of different extents do not
    share one. A map in another frame is read (bilinear) at the centres of a grid in
    ``frame`` of the same cell size covering it: values at the same places on Earth.

    Parameters
    ----------
    grid : Grid
        The map.
    frame : str or None
        The target frame (the primary map's ``meta["projection"]``; None for a map in
        metres with no projection, which only a map of no projection shares).
    where : str
        The map named in an error.

    Returns
    -------
    Grid
        ``grid`` itself when its frame is ``frame``; else the resampled map, its
        ``meta["projection"]`` ``frame`` and ``meta["resampled_from"]`` its own.

    Raises
    ------
    ConfigError
        One of the two frames is metric with no projection (no way to relate them), or
        the resampled map would exceed the memory budget.
    """
    from geofix.maps.project import frame_proj
    from geofix.memory import cells_bytes, check_allocation

    own = grid.meta.get("projection")
    if own == frame:
        return grid
    if own is None or frame is None:
        which = "has no projection" if own is None else "is projected from lon/lat"
        raise ConfigError(
            f"{where} {which} and the primary map {'is' if frame else 'is not'}: their "
            "frames cannot be related; give maps of one frame"
        )
    source, target = frame_proj(own, where), frame_proj(frame, "the primary map")
    edge = np.linspace(0.0, 1.0, 65)
    xs = grid.x0 - 0.5 * grid.dx + edge * grid.values.shape[1] * grid.dx
    ys = grid.y0 - 0.5 * grid.dy + edge * grid.values.shape[0] * grid.dy
    ring_x = np.concatenate([xs, xs, np.full_like(ys, xs[0]), np.full_like(ys, xs[-1])])
    ring_y = np.concatenate([np.full_like(xs, ys[0]), np.full_like(xs, ys[-1]), ys, ys])
    x, y = target(*source(ring_x, ring_y, inverse=True))
    cell = float(min(grid.dx, grid.dy))
    nx = int(np.ceil((np.max(x) - np.min(x)) / cell)) + 1
    ny = int(np.ceil((np.max(y) - np.min(y)) / cell)) + 1
    try:
        check_allocation(cells_bytes(ny, nx, copies=4), f"{where} in the primary map's frame")
    except GeofixError as exc:
        raise ConfigError(str(exc).splitlines()[0]) from None
    x0, y0 = float(np.min(x)), float(np.min(y))
    gx, gy = np.meshgrid(x0 + cell * np.arange(nx), y0 + cell * np.arange(ny))
    east, north = source(*target(gx, gy, inverse=True))
    values = grid.sample(east, north, method="bilinear")
    meta = {**grid.meta, "projection": frame, "resampled_from": own}
    return replace(grid, values=values, x0=x0, y0=y0, dx=cell, dy=cell, meta=meta)


def method_seed(seed: int, spec: str) -> np.random.Generator:
    """The generator of one method in a replay (seeded by the seed and the method spec)."""
    return np.random.default_rng([int(seed), zlib.crc32(spec.encode())])


def replay(
    mission: Mission,
    grid: Grid,
    methods: list[str],
    ins=None,
    initial_error_m=None,
    seed: int = 0,
    settings=None,
    map_error: Grid | None = None,
    field_grids=(),
    field_noise_std=None,
) -> ReplayResult:
    """Run every method's navigator over the mission, one ping at a time.

    Parameters
    ----------
    mission : Mission
        The log (with :attr:`~geofix.logs.Mission.fields` for several fields).
    grid : Grid
        The primary field's map.
    methods : list of str
        Recursive method specs.
    ins : InsSpec or dict, optional
        INS numbers for a GNSS log (:func:`replay_inputs`).
    initial_error_m : float, optional
        Initial INS position error, metres (:func:`replay_inputs`).
    seed : int
        Seed of the INS simulation and of every method's generator.
    settings : dict, optional
        Navigator settings (``noise_std`` the primary field's, map units).
    map_error : Grid, optional
        The primary map's per-cell standard deviation, map units.
    field_grids : sequence of Grid
        One map per further field of the mission (any order; matched by kind), in the
        primary map's frame.
    field_noise_std : dict, optional
        Kind -> measurement noise 1-sigma of a further field, its map's units (default
        :data:`DEFAULT_FIELD_NOISE_STD`).

    Returns
    -------
    ReplayResult
        ``estimates[method]`` one :class:`Estimate` per ping; ``summary`` the JSON of
        ``geofix replay --json``.

    Raises
    ------
    ConfigError
        No method, a bad seed or setting, a method that cannot run ping by ping, a further
        field without its map or a map without its field, or a noise 1-sigma outside
        :data:`NOISE_STD_RANGE`.
    """
    from geofix.navigator import Navigator, check_method_budget

    if not methods:
        raise ConfigError("replay: give at least one --method")
    check_seed(seed)
    check_settings(settings)
    for spec in methods:
        check_online_method(spec)
    maps = _field_maps(mission, field_grids)
    field_vars = _field_vars(maps, field_noise_std)
    mission = screen_mission(mission, grid.kind)
    inputs = replay_inputs(mission, ins, initial_error_m, seed)
    noise_var = _noise_var(mission)
    estimates = {}
    for spec in methods:
        rng = method_seed(seed, spec)
        check_method_budget(spec, settings, grid)  # refused before the filter is built
        nav = Navigator(
            grid, spec, settings, rng, map_error, ins_model=inputs.ins_model, field_grids=maps
        )
        estimates[spec] = drive(nav, mission, inputs, noise_var, field_vars)
    summary = summarise(mission, inputs, estimates)
    return ReplayResult(mission, inputs, estimates, summary)


def _field_maps(mission: Mission, field_grids) -> tuple[Grid, ...]:
    """The maps of the mission's further fields in its order; ConfigError unless one each."""
    by_kind = {g.kind: g for g in field_grids or ()}
    if len(by_kind) != len(tuple(field_grids or ())):
        raise ConfigError("replay: give one map per further field kind")
    kinds = list(mission.fields)
    lacking = [k for k in kinds if k not in by_kind]
    if lacking:
        raise ConfigError(
            f"replay: the log's {', '.join(lacking)} field has no map: give a --map for each "
            "--field"
        )
    idle = [k for k in by_kind if k not in kinds]
    if idle:
        raise ConfigError(
            f"replay: a {', '.join(idle)} map but no {', '.join(idle)} field in the log "
            "(--field names the log's channels)"
        )
    return tuple(by_kind[k] for k in kinds)


def _field_vars(maps: tuple[Grid, ...], field_noise_std) -> dict[str, float]:
    """Kind -> measurement variance of every further field, map units squared."""
    given = dict(field_noise_std or {})
    out = {}
    low, high = NOISE_STD_RANGE
    for g in maps:
        std = given.get(g.kind, DEFAULT_FIELD_NOISE_STD.get(g.kind, 1.0))
        try:
            number = float(std)
        except (TypeError, ValueError):
            raise ConfigError(f"--noise-std of the {g.kind} field must be a number") from None
        if not low <= number <= high:
            raise ConfigError(
                f"--noise-std of the {g.kind} field must lie within {low:g} .. {high:g} "
                f"{g.units}, got {std}"
            )
        out[g.kind] = number**2
    return out


def check_seed(seed) -> None:
    """Refuse a seed that is not a non-negative integer (ConfigError naming ``--seed``)."""
    if isinstance(seed, np.random.Generator):
        return
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ConfigError(f"--seed must be an integer >= 0, got {seed!r}")


def check_settings(settings) -> None:
    """Refuse a ``noise_std`` outside :data:`NOISE_STD_RANGE` (ConfigError naming it).

    Its square is the measurement variance: 1e300 would overflow, 1e-300 vanish.
    """
    if not isinstance(settings, dict) or "noise_std" not in settings:
        return
    value = settings["noise_std"]
    low, high = NOISE_STD_RANGE
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"--noise-std must be a number, got {value!r}") from None
    if not low <= number <= high:
        raise ConfigError(f"--noise-std must lie within {low:g} .. {high:g} map units, got {value}")


def check_online_method(spec: str, who: str = "replay") -> None:
    """Refuse a method the online navigator cannot run ping by ping (ConfigError).

    A batch matcher, and the free INS (``ins``, a yardstick with no filter steps), are
    named with the recursive filters that can be replayed.
    """
    from geofix.filters.base import RecursiveFilter
    from geofix.methods import available_methods, parse_method_spec

    method = parse_method_spec(spec)
    if isinstance(method, RecursiveFilter) and hasattr(method, "initialize"):
        return
    known = [
        name
        for name, cls in available_methods().items()
        if issubclass(cls, RecursiveFilter) and hasattr(cls, "initialize")
    ]
    what = (
        "cannot run ping by ping" if getattr(method, "recursive", False) else "is a batch matcher"
    )
    raise ConfigError(f"{who}: method {spec!r} {what}; use a recursive filter ({', '.join(known)})")


def screen_mission(mission: Mission, kind: str) -> Mission:
    """The mission without poisoned records, with one warning counting them.

    A ping is dropped when its time lies more than :data:`MAX_MISSION_SPAN_S` from the
    log's median ping time or its navigation more than :data:`MAX_POSITION_M` from the
    frame's origin, or when its time is not after the pings before it (a repeated
    record); a beam is dropped when an offset exceeds :data:`MAX_BEAM_OFFSET_M`,
    and a value beyond the physical range of the map's ``kind``
    (:data:`geofix.conventions.PHYSICAL_LIMITS`; each further field's by its own kind) is
    blanked (NaN, as a missing beam).

    Raises
    ------
    ConfigError
        Every ping is dropped, or all share one time.
    """
    times = np.asarray(mission.times, dtype=float)
    nav = np.asarray(mission.nav, dtype=float)
    keep = np.abs(times - np.median(times)) <= MAX_MISSION_SPAN_S
    keep &= (np.abs(nav) <= MAX_POSITION_M).all(axis=1)
    if not keep.any():
        raise ConfigError(f"replay: every ping of {mission.name!r} has a time or position off")
    if mission.n > 1 and np.ptp(times[keep]) == 0:
        raise ConfigError(
            f"replay: the {mission.n} pings of {mission.name!r} share one time "
            f"({times[keep][0]:g} s): a log with no time between its pings cannot be replayed"
        )
    keep &= _after_previous(times)
    beams, blanked = _screen_beams(np.asarray(mission.beams, dtype=float), kind)
    fields = {}
    for other, extra in mission.fields.items():
        fields[other], more = _screen_beams(np.asarray(extra, dtype=float), other)
        blanked = blanked | more
    dropped = int((~keep).sum())
    poisoned = int((blanked & keep).sum())
    if dropped == 0 and poisoned == 0:
        return mission
    _warn_poisoned(mission, kind, dropped, poisoned)
    screened = replace(mission, beams=beams, fields=fields)
    return screened if keep.all() else _kept(screened, keep)


def _after_previous(times: np.ndarray) -> np.ndarray:
    """``(n,)`` True for a ping later than every ping before it (a repeated time: False)."""
    latest = np.maximum.accumulate(times)
    return np.r_[True, times[1:] > latest[:-1]]


def _screen_beams(beams: np.ndarray, kind: str) -> tuple[np.ndarray, np.ndarray]:
    """``(beams, poisoned)``: far beams dropped, impossible values blanked; ``(n,)`` flags."""
    limit = PHYSICAL_LIMITS.get(kind, PHYSICAL_LIMITS["depth"])
    with np.errstate(invalid="ignore"):
        far = (np.abs(beams[..., :2]) > MAX_BEAM_OFFSET_M).any(axis=-1)
        impossible = np.abs(beams[..., 2]) > limit
    bad = far | impossible
    if not bad.any():
        return beams, bad.any(axis=1)
    beams = beams.copy()
    beams[far] = np.nan
    beams[..., 2][impossible] = np.nan
    return beams, bad.any(axis=1)


def _warn_poisoned(mission: Mission, kind: str, dropped: int, poisoned: int) -> None:
    limit = PHYSICAL_LIMITS.get(kind, PHYSICAL_LIMITS["depth"])
    parts = []
    if dropped:
        parts.append(
            f"{dropped} pings dropped (time or position out of range, or a time not after "
            "the ping before)"
        )
    if poisoned:
        parts.append(
            f"{poisoned} pings with beams dropped (a value beyond +-{limit:g} for a {kind} "
            f"map, or an offset beyond {MAX_BEAM_OFFSET_M:g} m)"
        )
    warnings.warn(
        f"replay: {mission.name}: {' and '.join(parts)} of {mission.n}",
        GeofixWarning,
        stacklevel=3,
    )


def _kept(mission: Mission, keep: np.ndarray) -> Mission:
    """The pings of ``mission`` where ``keep`` is true (times rebased on the first kept)."""
    index = np.flatnonzero(keep)

    def cut(values):
        return None if values is None else np.asarray(values)[index]

    times = np.asarray(mission.times, dtype=float)[index]
    return replace(
        mission,
        times=times - times[0],
        nav=cut(mission.nav),
        heading=cut(mission.heading),
        beams=cut(mission.beams),
        truth=cut(mission.truth),
        roll=cut(mission.roll),
        pitch=cut(mission.pitch),
        velocity=cut(mission.velocity),
        sigma_position=cut(mission.sigma_position),
        start_utc=None if mission.start_utc is None else mission.start_utc + float(times[0]),
        fields={kind: cut(extra) for kind, extra in mission.fields.items()},
    )


def window_mission(mission: Mission, start_h: float | None = None, hours: float | None = None):
    """The pings of ``mission`` from ``start_h`` hours after its start, ``hours`` long.

    Times are rebased on the window's first ping (``start_utc`` moves with them); per-ping
    arrays of ``meta`` (an MGD77T mission's ``records``, ``lon``, ``lat``, ``placed``) are
    cut alike, and ``meta["window_h"]`` records ``(start_h, hours)``.

    Parameters
    ----------
    mission : Mission
        The log (one segment of a trackline, or any mission).
    start_h : float, optional
        Start of the window, hours after the mission's first ping (default 0).
    hours : float, optional
        Length of the window, hours (default: to the mission's end).

    Returns
    -------
    Mission
        The window (the mission itself when neither is given).

    Raises
    ------
    ConfigError
        A negative or non-finite start, a length that is not positive, a window that does
        not lie within the mission (the message gives its length in hours), or one with
        fewer than two pings.
    """
    if start_h is None and hours is None:
        return mission
    start = 0.0 if start_h is None else float(start_h)
    if not (np.isfinite(start) and start >= 0):
        raise ConfigError(f"--start-h must be a finite number of hours >= 0, got {start_h}")
    if hours is not None and not (np.isfinite(hours) and hours > 0):
        raise ConfigError(f"--hours must be a finite number of hours > 0, got {hours}")
    times = np.asarray(mission.times, dtype=float)
    span_h = (times[-1] - times[0]) / 3600.0
    stop = span_h if hours is None else start + float(hours)
    if start >= span_h or stop > span_h + _WINDOW_SLACK_H:
        raise ConfigError(
            f"window {start:g} .. {stop:g} h lies outside {mission.name!r}, which is "
            f"{span_h:.2f} h long: choose --start-h and --hours within it"
        )
    rel = (times - times[0]) / 3600.0
    index = np.flatnonzero((rel >= start) & (rel <= stop + 1e-9))
    if index.size < 2:
        raise ConfigError(f"window {start:g} .. {stop:g} h of {mission.name!r} holds < 2 pings")
    return _rebased(mission, index, (start, stop - start))


_WINDOW_SLACK_H = 1.0 / 3600.0
"""A window may end this much (one second, in hours) after the mission's last ping."""


def _rebased(mission: Mission, index: np.ndarray, window: tuple[float, float]) -> Mission:
    """Pings ``index`` (consecutive) with times rebased and per-ping meta cut."""
    part = mission.subset(slice(int(index[0]), int(index[-1]) + 1))
    first = float(part.times[0])
    meta = {
        key: value[index[0] : index[-1] + 1]
        if isinstance(value, np.ndarray) and value.shape[:1] == (mission.n,)
        else value
        for key, value in mission.meta.items()
    }
    meta["window_h"] = window
    start_utc = None if mission.start_utc is None else mission.start_utc + first
    return replace(part, times=part.times - first, start_utc=start_utc, meta=meta)


def drive(
    nav, mission: Mission, inputs: ReplayInput, noise_var=None, field_vars=None
) -> list[Estimate]:
    """Feed one navigator the mission: init, then per ping ``motion`` and ``measure``.

    The log's roll and pitch (where it has them) go with every ping: they level the
    sensor's mounting offset (the beams of a log are level-frame offsets already).

    Parameters
    ----------
    nav : Navigator
        The navigator (with ``field_grids`` for the further fields it is to weigh).
    mission : Mission
        The log.
    inputs : ReplayInput
        The INS track and prior sigmas.
    noise_var : float or numpy.ndarray, optional
        The primary field's measurement variance, map units squared (None: the
        navigator's ``noise_std``).
    field_vars : dict, optional
        Kind -> measurement variance of each further field the navigator has a map of,
        that map's units squared (default :data:`DEFAULT_FIELD_NOISE_STD` squared); a
        ping carries every such field's reading.
    """
    t = np.asarray(mission.times, dtype=float)
    sigma = inputs.sigma
    roll, pitch = (_attitude(angles, mission.n) for angles in (mission.roll, mission.pitch))
    nav.init(t[0], inputs.indicated[0], float(sigma[0]), float(inputs.heading[0]))
    field_vars = field_vars or {}
    kinds = [
        (kind, field_vars.get(kind, DEFAULT_FIELD_NOISE_STD.get(kind, 1.0) ** 2))
        for kind in nav.field_kinds
        if kind in mission.fields
    ]
    out = []
    for k in range(mission.n):
        if k > 0:
            process_var = max(float(sigma[k] ** 2 - sigma[k - 1] ** 2), 1e-6)
            nav.motion(t[k], inputs.indicated[k], float(inputs.heading[k]), process_var)
        beams = np.asarray(mission.beams[k], dtype=float)
        keep = np.isfinite(beams[:, :2]).all(axis=1)
        var = noise_var if np.ndim(noise_var) == 0 else np.asarray(noise_var)[keep]
        if not kinds:
            out.append(nav.measure(t[k], beams[keep], var, roll[k], pitch[k]))
            continue
        fields = [
            {"kind": kind, "beams": _level_rows(mission.fields[kind][k]), "noise_var": v}
            for kind, v in kinds
        ]
        out.append(nav.measure(t[k], beams[keep], var, roll[k], pitch[k], fields=fields))
    return out


def _level_rows(beams: np.ndarray) -> np.ndarray:
    """A further field's beams of one ping, rows without an offset dropped (one kept)."""
    beams = np.asarray(beams, dtype=float)
    keep = np.isfinite(beams[:, :2]).all(axis=1)
    return beams[keep] if keep.any() else np.array([[0.0, 0.0, np.nan]])


def _attitude(angles, n: int) -> list:
    """Per-ping angles (radians) or None where the log has none (or a NaN)."""
    if angles is None:
        return [None] * n
    return [float(a) if np.isfinite(a) else None for a in np.asarray(angles, dtype=float)]


def _noise_var(mission: Mission):
    """Per-beam (or one) measurement variance from the log's own numbers, else None."""
    meta = mission.meta
    if meta.get("beam_noise_std") is not None:
        return np.asarray(meta["beam_noise_std"], float) ** 2 + meta.get("map_error_std", 0) ** 2
    if "noise_std" in meta:
        return max(meta["noise_std"] ** 2 + meta.get("map_error_std", 0.0) ** 2, 1e-12)
    return None


def summarise(mission: Mission, inputs: ReplayInput, estimates: dict) -> dict:
    """The replay's JSON summary.

    ``{"pings", "methods": {NAME: {end_error_m, mean_error_m, max_error_m,
    converged_at_s, reinits, converged_pings, converged_nees, ins_end_error_m}}}``:
    ``converged_pings`` the pings reported ``converged``, ``converged_nees`` the mean NEES
    ``e^T C^-1 e`` over them (about 2 when the reported covariance is honest; None when
    none converged), ``ins_end_error_m`` the INS's own end error (the yardstick); errors
    and NEES None without a truth.
    """
    methods: dict[str, dict[str, float | int | None]] = {}
    t0 = float(mission.times[0])
    for spec, ests in estimates.items():
        track = np.array([e.position for e in ests])
        row: dict[str, float | int | None] = {
            "end_error_m": None,
            "mean_error_m": None,
            "max_error_m": None,
        }
        if inputs.truth is not None:
            err = np.hypot(*(track - inputs.truth).T)
            row = {
                "end_error_m": float(err[-1]),
                "mean_error_m": float(err.mean()),
                "max_error_m": float(err.max()),
            }
        converged = [e.t - t0 for e in ests if e.status == "converged"]
        row["converged_at_s"] = float(converged[0]) if converged else None
        row["reinits"] = int(ests[-1].reinits) if ests else 0
        row["converged_pings"] = len(converged)
        row["converged_nees"] = converged_nees(ests, inputs.truth)
        row["ins_end_error_m"] = (
            None
            if inputs.truth is None
            else float(np.hypot(*(inputs.indicated[-1] - inputs.truth[-1])))
        )
        methods[spec] = row
    return {"pings": int(mission.n), "methods": methods}


def nees(estimates: list[Estimate], truth) -> np.ndarray:
    """``(n,)`` NEES ``e^T C^-1 e`` of every estimate against the truth ``(n, 2)`` metres.

    Raises
    ------
    ConfigError
        ``truth`` does not have one row per estimate.
    """
    truth = np.asarray(truth, dtype=float)
    if truth.shape != (len(estimates), 2):
        raise ConfigError(f"nees: truth has shape {truth.shape}, expected ({len(estimates)}, 2)")
    out = np.empty(len(estimates))
    for k, (est, true) in enumerate(zip(estimates, truth, strict=True)):
        error = est.position - true
        cov = 0.5 * (est.covariance + est.covariance.T)
        try:
            out[k] = float(error @ np.linalg.solve(cov, error))
        except np.linalg.LinAlgError:
            out[k] = float("inf")
    return out


def converged_nees(estimates: list[Estimate], truth) -> float | None:
    """Mean NEES over the estimates reported ``converged`` (None: no truth or none).

    About 2 (two degrees of freedom) when the covariance the navigator reports with
    ``converged`` is honest.
    """
    if truth is None:
        return None
    values = nees(estimates, truth)
    picked = np.array([e.status == "converged" for e in estimates], dtype=bool)
    return float(values[picked].mean()) if picked.any() else None


# ---------------------------------------------------------------------- outputs
def estimates_frame(result: ReplayResult):
    """One row per method and ping: estimate, MLE, covariance, status, NIS, truth, error.

    With a truth, ``error_m`` (metres) and ``nees`` (``e^T C^-1 e`` of the reported
    covariance) too.
    """
    import pandas as pd

    rows = []
    truth = result.inputs.truth
    for spec, ests in result.estimates.items():
        scores = nees(ests, truth) if truth is not None else None
        for k, e in enumerate(ests):
            row = {
                "method": spec,
                "ping": k,
                "t": e.t,
                "x": e.position[0],
                "y": e.position[1],
                "mle_x": e.mle[0],
                "mle_y": e.mle[1],
                "cov_xx": e.covariance[0, 0],
                "cov_xy": e.covariance[0, 1],
                "cov_yy": e.covariance[1, 1],
                "status": e.status,
                "nis": e.nis,
                "accepted": e.accepted,
                "reinits": e.reinits,
                "indicated_x": result.inputs.indicated[k, 0],
                "indicated_y": result.inputs.indicated[k, 1],
            }
            if truth is not None:
                row["truth_x"], row["truth_y"] = truth[k]
                row["error_m"] = float(np.hypot(*(e.position - truth[k])))
                row["nees"] = float(scores[k]) if scores is not None else float("nan")
            row[RUN_ID_KEY] = result.run_id
            rows.append(row)
    return pd.DataFrame(rows)


def prepare_out_dir(out_dir: str | Path) -> Path:
    """Create the output folder and remove an earlier replay's outputs from it.

    Done before the replay starts, so that the folder never holds the files of two
    replays side by side: after a kill or a failure it holds this replay's finished
    files, whole, or none (each file is renamed into place when complete).

    Raises
    ------
    OutputError
        The folder cannot be created or is not a folder, or an old output cannot be
        removed.
    """
    from geofix._atomic import check_target, output_error, remove_parts
    from geofix.errors import OutputError

    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise OutputError(f"cannot write in {out_dir}: it is not a folder")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise output_error(out_dir, exc) from None
    remove_parts(out_dir, OUTPUT_NAMES)
    for name in OUTPUT_NAMES:
        path = check_target(out_dir / name)
        try:
            path.unlink(missing_ok=True)
        except OSError as exc:
            raise output_error(path, exc) from None
    return out_dir


def write_outputs(result: ReplayResult, grid: Grid, out_dir: str | Path) -> dict[str, Path]:
    """``estimates.csv``, ``estimates.nc`` (dims ``method, ping``) and ``replay.png``.

    Each file is written whole or not at all (:mod:`geofix._atomic`) and carries the
    replay's ``run_id`` (:data:`RUN_ID_KEY`); see :func:`prepare_out_dir` and
    :func:`output_run_ids`.
    """
    from geofix._atomic import write_atomic

    out_dir = prepare_out_dir(out_dir)
    frame = estimates_frame(result)
    paths = {"estimates (csv)": out_dir / "estimates.csv"}
    write_atomic(paths["estimates (csv)"], lambda part: frame.to_csv(part, index=False))
    paths["estimates (netCDF)"] = _write_netcdf(frame, result, out_dir / "estimates.nc")
    paths["figure"] = replay_figure(result, grid, out_dir / "replay.png")
    return paths


def output_run_ids(out_dir: str | Path) -> dict[str, str | None]:
    """The run id each replay output in ``out_dir`` carries (None: unreadable or none).

    Files of one replay share one id; outputs of different replays side by side (a
    folder written to by hand) show different ids.
    """
    import pandas as pd
    from PIL import Image

    out_dir = Path(out_dir)
    ids: dict[str, str | None] = {}
    for name in OUTPUT_NAMES:
        path = out_dir / name
        if not path.is_file():
            continue
        try:
            if name.endswith(".csv"):
                column = pd.read_csv(path, usecols=[RUN_ID_KEY])[RUN_ID_KEY]
                ids[name] = str(column.iloc[0]) if len(column) else None
            elif name.endswith(".nc"):
                ids[name] = _netcdf_run_id(path)
            else:
                with Image.open(path) as image:
                    ids[name] = image.info.get(RUN_ID_KEY)
        except (OSError, ValueError, KeyError):
            ids[name] = None
    return ids


def _netcdf_run_id(path: Path) -> str | None:
    import netCDF4

    with netCDF4.Dataset(path, "r") as ds:
        return str(ds.getncattr(RUN_ID_KEY)) if RUN_ID_KEY in ds.ncattrs() else None


def _write_netcdf(frame, result: ReplayResult, path: Path) -> Path:
    import xarray as xr

    from geofix._atomic import write_atomic

    methods = list(result.estimates)
    n = result.mission.n
    data = {}
    columns = ("t", "x", "y", "mle_x", "mle_y", "cov_xx", "cov_xy", "cov_yy", "nis", "error_m")
    for col in (*columns, "nees"):
        if col in frame:
            data[col] = (("method", "ping"), frame[col].to_numpy(float).reshape(len(methods), n))
    status = frame["status"].to_numpy(str).reshape(len(methods), n)
    data["status"] = (("method", "ping"), status.astype("U12"))
    data["accepted"] = (("method", "ping"), frame["accepted"].to_numpy(np.int8).reshape(-1, n))
    ds = xr.Dataset(data, coords={"method": methods, "ping": np.arange(n)})
    ds.attrs["summary_json"] = __import__("json").dumps(result.summary)
    ds.attrs["Conventions"] = "x east, y north (metres, the map's frame); cov in m^2; t in s"
    ds.attrs[RUN_ID_KEY] = result.run_id
    return write_atomic(path, ds.to_netcdf)


def replay_figure(result: ReplayResult, grid: Grid, path: Path) -> Path:
    """Write ``replay.png``: the tracks on the map, and the error against time.

    Left panel: the map around the tracks (:func:`geofix.plot.figures.draw_track_map`)
    with the truth (when the log has one), the INS-indicated track and every method's
    track, each its own colour, line style and end marker. Right panel, against time
    since the first ping: the position error of the INS and of every method (when the
    truth is known), and every method's 3-sigma band -- shaded up to three times the
    square root of the largest eigenvalue of its covariance, which a consistent filter's
    error stays below -- with two map cells for scale.

    Parameters
    ----------
    result : ReplayResult
        The replay.
    grid : Grid
        The map it ran on.
    path : pathlib.Path
        The PNG to write (whole or absent), tagged with the replay's ``run_id``.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    from geofix.plot.figures import draw_track_map, pyplot, save_figure, track_style

    plt = pyplot()
    fig, (ax_map, ax_err) = plt.subplots(
        1, 2, figsize=(14, 5.8), width_ratios=[1.15, 1], constrained_layout=True
    )
    truth = result.inputs.truth
    indicated = np.asarray(result.inputs.indicated, dtype=float)
    tracks = {
        spec: np.array([e.position for e in ests], dtype=float).reshape(-1, 2)
        for spec, ests in result.estimates.items()
    }
    draw_track_map(ax_map, grid, truth, indicated, tracks)
    ax_map.set_title("tracks")
    times = np.asarray(result.mission.times, dtype=float)
    start = times[0] if times.size else 0.0
    scale, unit = (3600.0, "h") if times.size and times[-1] - start > 7200.0 else (60.0, "min")
    curves: list[np.ndarray] = []
    if truth is not None and len(truth) == len(indicated) == times.size:
        ins_error = np.hypot(*(indicated - truth).T)
        ax_err.plot((times - start) / scale, ins_error, color="tab:red", ls="--", label="INS")
        curves.append(ins_error)
    bands = []
    for k, (spec, ests) in enumerate(result.estimates.items()):
        colour, style, _ = track_style(k)
        t = (np.array([e.t for e in ests], dtype=float) - start) / scale
        sigma3 = 3.0 * np.sqrt(_largest_eigenvalue(np.array([e.covariance for e in ests])))
        bands.append((t, sigma3, colour, spec))
        curves.append(sigma3)
        if truth is not None and len(truth) == len(ests):
            error = np.hypot(*(tracks[spec] - truth).T)
            ax_err.plot(t, error, color=colour, ls=style, lw=1.6, label=f"{spec} error")
            curves.append(error)
    floor = _log_floor(curves)
    for t, sigma3, colour, spec in bands:
        ax_err.fill_between(t, floor, sigma3, color=colour, alpha=0.15, lw=0)
        ax_err.plot(t, sigma3, color=colour, lw=0.8, alpha=0.8, label=f"{spec} 3σ")
    ax_err.axhline(2 * grid.cell_size, color="grey", ls=":", label="2 map cells")
    ax_err.set_yscale("log")
    ax_err.set_ylim(bottom=floor)
    ax_err.set_xlabel(f"time since the first ping ({unit})")
    ax_err.set_ylabel("position error (m)")
    ax_err.grid(True, which="both", alpha=0.3)
    ax_err.legend(loc="best", fontsize=8)
    known = "error and 3σ" if truth is not None else "3σ (no truth in the log)"
    ax_err.set_title(f"{known} against time")
    fig.suptitle(f"replay of {result.mission.name}")
    return save_figure(fig, path, metadata={RUN_ID_KEY: result.run_id})


def _largest_eigenvalue(cov: np.ndarray) -> np.ndarray:
    """``(n,)`` largest eigenvalue of ``(n, 2, 2)`` symmetric matrices (NaN stays NaN), m^2."""
    cov = np.asarray(cov, dtype=float).reshape(-1, 2, 2)
    a, b, d = cov[:, 0, 0], 0.5 * (cov[:, 0, 1] + cov[:, 1, 0]), cov[:, 1, 1]
    return 0.5 * (a + d) + np.sqrt((0.5 * (a - d)) ** 2 + b**2)


def _log_floor(curves: list[np.ndarray]) -> float:
    """The bottom of a log axis a little under the smallest positive value drawn, metres."""
    values = np.concatenate([np.ravel(c) for c in curves]) if curves else np.empty(0)
    positive = values[np.isfinite(values) & (values > 0)]
    return float(0.5 * positive.min()) if positive.size else 1.0


def stated_levels(grids, stds, command: str = "replay") -> list:
    """``grids`` with the first ``len(stds)`` stating those levels' 1-sigma (map units).

    ``command`` names the command in the message.

    Raises
    ------
    ConfigError
        More values than maps.
    MapError
        A value that is not a number at least 0.
    """
    grids, stds = list(grids), [float(v) for v in stds]
    if len(stds) > len(grids):
        raise ConfigError(
            f"{command}: {len(stds)} --offset-std values for {len(grids)} maps: give one per "
            "map, in the order of --map"
        )
    return [g.with_offset_std(v) for g, v in zip(grids, stds, strict=False)] + grids[len(stds) :]


def replay_log(
    log,
    map_path,
    methods: list[str],
    ins_path=None,
    initial_error_m=None,
    seed: int = 0,
    out_dir=None,
    settings: dict | None = None,
    trial: int = 0,
    field_name=None,
    segment: int | None = None,
    start_h: float | None = None,
    hours: float | None = None,
    field_noise_std=None,
    registration_std_m: float | None = None,
    offset_std=None,
) -> tuple[ReplayResult, dict]:
    """``geofix replay``: read the log and the map, replay, write the outputs.

    Parameters
    ----------
    log : str or pathlib.Path
        Any log :func:`geofix.logs.read_mission` reads.
    map_path : str or list of str or None
        Any map :func:`geofix.maps.load_grid` reads (its ``z_std`` layer, if any, is the
        per-cell map error); None for a ``geofix export`` log, whose own map is used. A
        list: one map per field of ``field_name``, in its order (the first the primary;
        the others put in its frame, :func:`load_field_maps`).
    ins_path : str or pathlib.Path, optional
        Scenario YAML whose ``ins:`` numbers drive the INS simulated on a GNSS log.
    out_dir : str or pathlib.Path, optional
        Folder for ``estimates.csv``, ``estimates.nc`` and ``replay.png`` (none if None).
    field_name : str or list of str, optional
        Channel of an MGD77T log (``--field``: ``depth``, ``gravity`` or ``magnetic``;
        default ``depth``, ``gravity`` for a file without depths); a field needs a map of
        its kind. Several (``["depth", "gravity"]``): one mission of them all, the first
        the primary (:func:`geofix.logs.mgd77.joint_segments`), each with its own map.
    segment : int, optional
        0-based continuous segment of that field in an MGD77T log
        (:func:`geofix.logs.mgd77.field_segments`); default the longest.
    start_h, hours : float, optional
        Replay only the window from ``start_h`` hours after the mission's (segment's)
        start, ``hours`` long (:func:`window_mission`); any log.
    field_noise_std : dict, optional
        Kind -> measurement noise 1-sigma of each further field, its map's units
        (default :data:`DEFAULT_FIELD_NOISE_STD`).
    registration_std_m : float, optional
        How well the primary map is registered, metres (1-sigma per axis;
        ``--registration-std``), over what the map file states
        (:meth:`geofix.maps.grid.Grid.with_registration`).
    offset_std : sequence of float, optional
        The 1-sigma of each map's level against its field's readings, map units
        (``--offset-std``): one per map in the order of ``map_path``, or fewer (the first
        maps'), over what the map files state (:meth:`geofix.maps.grid.Grid.with_offset_std`).

    Returns
    -------
    tuple
        ``(ReplayResult, {label: path})``.
    """
    from geofix.logs.exported import read_exported
    from geofix.maps.gridding import load_map_error
    from geofix.maps.io import load_grid
    from geofix.maps.project import frame_proj

    check_seed(seed)
    check_settings(settings)
    for spec in methods:
        check_online_method(spec)
    ins = None
    if ins_path is not None:
        from geofix.sim.scenario import load_scenario

        ins = load_scenario(ins_path).ins
    if out_dir is not None:
        prepare_out_dir(out_dir)
    map_error = None
    names = _names(field_name)
    maps = _names(map_path)
    if len(names) > 1 and len(maps) != len(names):
        raise ConfigError(
            f"replay: give one --map per --field, in the same order (got {len(names)} --field "
            f"and {len(maps)} --map)"
        )
    if len(set(names)) != len(names):
        raise ConfigError(f"replay: --field names a channel twice: {', '.join(names)}")
    if len(maps) > 1 and len(names) < 2:
        raise ConfigError(
            "replay: several --map need an MGD77T log and one --field per map, in the same "
            "order (the first the primary)"
        )
    field_grids: tuple[Grid, ...] = ()
    if not maps:
        if not str(log).lower().endswith((".nc", ".nc4")):
            raise ConfigError("replay: --map is required unless the log is a geofix export")
        mission, grid = read_exported(log, trial=trial)
    else:
        primary = maps[0]
        grid = load_grid(primary)
        map_error = load_map_error(primary) if not str(primary).startswith("builtin:") else None
        frame = grid.meta.get("projection")
        if frame is not None:
            frame_proj(frame, f"map {primary}")
        field_grids = load_field_maps(maps[1:], grid)
        for name, path, further in zip(names[1:], maps[1:], field_grids, strict=True):
            if further.kind != name:
                raise ConfigError(
                    f"replay: --field {name} needs a {name} map; map {path} is a {further.kind} map"
                )
        mission = _read_log(log, frame, trial, names, segment)
        _check_field_map(mission, grid, primary)
        if mission.frame is not None and frame is None:
            raise ConfigError(
                f"replay: the log is in lon/lat but map {map_path} has no projection; "
                "grid it with geofix grid or load a lon/lat map"
            )
    mission = window_mission(mission, start_h, hours)
    if registration_std_m is not None:
        grid = grid.with_registration(registration_std_m)
    if offset_std:
        levelled = stated_levels([grid, *field_grids], offset_std)
        grid, field_grids = levelled[0], tuple(levelled[1:])
    result = replay(
        mission,
        grid,
        methods,
        ins,
        initial_error_m,
        seed,
        settings,
        map_error,
        field_grids,
        field_noise_std,
    )
    paths = {} if out_dir is None else write_outputs(result, grid, out_dir)
    return result, paths


def _is_mgd77(log) -> bool:
    from geofix.logs.mgd77 import MGD77T_SUFFIXES

    return not str(log).startswith("builtin:") and Path(log).suffix.lower() in MGD77T_SUFFIXES


def _names(value) -> list[str]:
    """A ``--field`` or ``--map`` value as a list (None: none; a string: that one)."""
    if value is None:
        return []
    if isinstance(value, str | Path):
        return [str(value)]
    return [str(v) for v in value]


def _read_log(log, frame, trial: int, fields: list[str], segment: int | None) -> Mission:
    """The mission to replay: an MGD77T log's segment of ``fields``, else the log's mission."""
    from geofix.logs.mgd77 import field_segments, joint_segments, pick_segment
    from geofix.logs.read import read_mission

    if not _is_mgd77(log):
        if fields or segment is not None:
            raise ConfigError("replay: --field and --segment apply to MGD77T logs (.m77t) only")
        return read_mission(log, frame=frame, trial=trial)
    if len(fields) > 1:
        name, missions = joint_segments(log, fields, frame=frame)
    else:
        name, missions = field_segments(log, fields[0] if fields else None, frame=frame)
    return pick_segment(missions, segment, f"{Path(log).name} ({name})")


def _check_field_map(mission: Mission, grid: Grid, map_path) -> None:
    """Refuse a depth or gravity mission on a map of the other kind (ConfigError)."""
    from geofix.maps.grid import KINDS

    if mission.meta.get("reader") != "mgd77" or mission.kind not in KINDS:
        return
    if grid.kind != mission.kind:
        raise ConfigError(
            f"replay: --field {mission.kind} needs a {mission.kind} map; "
            f"map {map_path} is a {grid.kind} map"
        )
