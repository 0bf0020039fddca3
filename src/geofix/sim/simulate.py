"""Scenario -> Trial: simulate a mission (true track, INS indication, DVL, measurements).

Trial ``i`` of a scenario uses ``numpy.random.default_rng([seed, i])`` only, so any trial
is reproducible alone and in any process. That generator is split (``Generator.spawn``)
into independent streams for the track (start jitter, turns), the INS, the DVL, the
sensor and the seabed (``spawn(5)``: children are keyed by their index, so the first four
are those of the earlier ``spawn(4)``), so switching the DVL on, changing the sensor or
adding a ``seabed:`` block leaves the track and the INS errors of a trial unchanged.
Each further field of a ``sensors:`` list takes the next two streams (its sensor, its
seabed), so adding a field changes none of the primary field's numbers.

With a ``seabed:`` block (:mod:`geofix.sim.seabed`) the prepared map is the seabed: the
sensor reads it (plus the block's relief), the readings carry its offset, tide and drift,
and the trial carries the prior map its methods get (``Trial.prior_map``).
"""

from __future__ import annotations

import functools
import os
from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np

from geofix.errors import ConfigError, TrackOffMapError
from geofix.maps.grid import Grid
from geofix.memory import cells_bytes, check_allocation
from geofix.nav.dvl import simulate_dvl
from geofix.nav.errstate import InsErrorModel
from geofix.nav.ins import position_sigma, simulate_ins
from geofix.nav.trajectory import TrueTrajectory, true_trajectory
from geofix.problem import footprint_xy
from geofix.sensors.echosounder import beam_noise_std, sensor_offsets
from geofix.sensors.spec import SensorSpec
from geofix.sim.scenario import FieldSpec, MapSpec, Scenario
from geofix.sim.seabed import SeabedDraw, draw_seabed
from geofix.sim.sensing import measure_with_unlagged
from geofix.sim.trial import Trial, TrialField


def prepare_map(scenario: Scenario, float32_within: float | None = None) -> Grid:
    """Load and prepare the scenario's map (cut, project, resample) as a :class:`Grid`.

    Parameters
    ----------
    scenario : Scenario
        Its ``map`` block says which file, variable, kind, region and cell size (metres).
    float32_within : float, optional
        Store the values in float32 when that rounds none by more than this, map units
        (see :func:`geofix.maps.io.load_grid`); default float64.

    Returns
    -------
    Grid
        The prepared map, metric frame.

    Examples
    --------
    >>> import geofix
    >>> grid = geofix.prepare_map(geofix.load_scenario("builtin:azores_demo"))
    >>> grid.cell_size, grid.kind
    (1000.0, 'depth')
    """
    from geofix.maps.io import load_grid

    spec = scenario.map
    # only when given, so that a loader without the keyword (a stand-in) still works
    precision: dict[str, Any] = {}
    if float32_within is not None:
        precision["float32_within"] = float32_within
    return load_grid(
        scenario.map_path(),
        variable=spec.variable,
        kind=spec.kind,
        region=spec.region,
        resample_m=spec.resample_m,
        **precision,
    )


def prepare_field_maps(scenario: Scenario) -> tuple[Grid, ...]:
    """The prepared maps of the scenario's fields after the first (``sensors:``).

    Each entry's ``map`` block loaded, cut, projected and resampled as :func:`prepare_map`
    does the primary's (float64), read once per process and kept.

    Parameters
    ----------
    scenario : Scenario
        The mission family.

    Returns
    -------
    tuple of Grid
        One map per further field, in the ``sensors:`` order (``()`` for one field).
    """
    fields = scenario.fields
    return tuple(
        _prepared_map(scenario.field_map_path(i), fields[i].map, _stamp(scenario, i))
        for i in range(1, len(fields))
    )


def _stamp(scenario: Scenario, index: int) -> float:
    """Modification time of a field's map file (0 for a bundled one): part of the cache key."""
    path = scenario.field_map_path(index)
    if path.startswith("builtin:"):
        return 0.0
    try:
        return os.stat(path).st_mtime
    except OSError:
        return 0.0  # load_grid says what is wrong with it


@functools.lru_cache(maxsize=8)
def _prepared_map(path: str, spec: MapSpec, stamp: float) -> Grid:
    from geofix.maps.io import load_grid

    return load_grid(
        path,
        variable=spec.variable,
        kind=spec.kind,
        region=spec.region,
        resample_m=spec.resample_m,
    )


def start_position(scenario: Scenario, grid: Grid) -> tuple[float, float]:
    """The nominal start ``(x, y)`` of the true track, metres (before any jitter).

    ``track.start_m`` as given, or ``track.start_cell`` ``[column, row]`` converted with
    :meth:`Grid.cell_to_xy`.

    Raises
    ------
    ConfigError
        Neither or both of ``track.start_cell`` and ``track.start_m`` are given.
    """
    track = scenario.track
    if (track.start_cell is None) == (track.start_m is None):
        raise ConfigError(
            f"{scenario.name}: give exactly one of track.start_cell and track.start_m"
        )
    if track.start_m is not None:
        return float(track.start_m[0]), float(track.start_m[1])
    assert track.start_cell is not None  # exactly one of the two is given (checked above)
    x, y = grid.cell_to_xy(track.start_cell[0], track.start_cell[1])
    return float(x), float(y)


def check_track_on_map(grid: Grid, positions, what: str = "track") -> None:
    """Raise if any position lies off the map or on no-data.

    Parameters
    ----------
    grid : Grid
        The map.
    positions : array_like
        ``(n, 2)`` positions, or ``(n, b, 2)`` beam footprints, metres; axis 0 is the
        sample.
    what : str
        Name of the track for the message (e.g. ``"true track"``).

    Raises
    ------
    TrackOffMapError
        Naming the first bad sample, its position and the map's extent.
    """
    pos = np.asarray(positions, dtype=float)
    bad = np.isnan(grid.sample(pos[..., 0], pos[..., 1]))
    if not bad.any():
        return
    flat = bad.reshape(bad.shape[0], -1)
    k = int(np.argmax(flat.any(axis=1)))
    beam = int(np.argmax(flat[k]))
    x, y = pos.reshape(pos.shape[0], -1, 2)[k, beam]
    west, east, south, north = grid.extent
    where = f" beam {beam}" if flat.shape[1] > 1 else ""
    raise TrackOffMapError(
        f"{what} leaves the map (or no-data) at sample {k} of {pos.shape[0]}{where}, "
        f"({_metres(x)}, {_metres(y)}) m; map covers x {west:.1f}..{east:.1f}, "
        f"y {south:.1f}..{north:.1f} m"
    )


def _metres(value: float) -> str:
    """A coordinate for a message: ``1234.5``, or ``1.2e+300`` when far too large."""
    return f"{value:.1f}" if abs(value) < 1e9 else f"{value:.3g}"


#: Float arrays of ``samples x beams`` a trial holds at once while it is simulated
#: (footprints, readings, noise, measured, unlagged, offsets into the map).
_TRIAL_COPIES = 12


def check_trial_size(scenario: Scenario) -> None:
    """Refuse a mission whose per-sample arrays would not fit the memory budget.

    Raises
    ------
    MemoryBudgetError
        ``track.samples * track.legs`` samples times ``sensor.beams`` beams, with the
        estimate and the budget.
    """
    n = float(scenario.track.samples) * float(scenario.track.legs)
    beams = sum(f.sensor.beams if f.sensor.type == "multibeam" else 1 for f in scenario.fields)
    check_allocation(
        cells_bytes(n, beams, copies=_TRIAL_COPIES) + cells_bytes(n, copies=40),
        f"trial of {n:.0f} samples x {beams} beams (track.samples, track.legs, sensor.beams)",
    )


def check_sensor_fits_map(scenario: Scenario, grid: Grid) -> None:
    """Refuse a sensor that cannot read the map's field (a gravimeter on a depth map).

    The map's kind is detected from its variable name and units, or set by ``map.kind``;
    a map mislabelled by the detection is accepted once ``map.kind`` says what it holds.

    Raises
    ------
    ConfigError
        A gravimeter on a map other than gravity, an echosounder on one other than
        depth, a magnetometer on one other than magnetic.
    """
    _check_kind(scenario.sensor, grid, "sensor.type", "map.kind")


def _check_kind(sensor: SensorSpec, grid: Grid, key: str, kind_key: str) -> None:
    """Raise ConfigError unless ``sensor`` reads the field of ``grid`` (keys for the message)."""
    name, needs = sensor.type, sensor.kind
    if grid.kind != needs:
        raise ConfigError(
            f"{key} {name} needs a {needs} map, but map {grid.name!r} is a "
            f"{grid.kind} map; set {kind_key}: {needs} if the file holds {needs}"
        )


def _sense(grid: Grid, draw, true, offsets, sensor: SensorSpec, rng, what: str):
    """``(measured, unlagged)`` of one field along the true track, map units.

    Read on the drawn seabed when there is one (with its per-reading offsets), else on
    ``grid``; a reading that is not finite is a :class:`TrackOffMapError` naming ``what``.
    """
    measured, unlagged = measure_with_unlagged(
        grid if draw is None else draw.sensed,
        true.positions,
        true.heading,
        offsets,
        sensor,
        rng,
        true.times,
    )
    if draw is not None:
        measured = measured + draw.reading_offsets[:, None]
        unlagged = unlagged + draw.reading_offsets[:, None]
    if not np.all(np.isfinite(measured)):
        k = int(np.argmax(~np.isfinite(measured).all(axis=1)))
        raise TrackOffMapError(f"true track: {what} not finite at sample {k}")
    return measured, unlagged


def _true_track(scenario: Scenario, grid: Grid, rng: np.random.Generator) -> TrueTrajectory:
    track = scenario.track
    jitter = rng.uniform(-track.start_jitter_m, track.start_jitter_m, 2)
    start = np.asarray(start_position(scenario, grid)) + jitter
    return true_trajectory(
        start,
        track.heading_deg,
        track.speed_m_s,
        track.interval_s,
        track.samples,
        legs=track.legs,
        turn_std_deg=track.turn_std_deg,
        rng=rng,
    )


def _aiding(scenario: Scenario, true: TrueTrajectory, unlagged, dvl_rng) -> dict:
    """The trial's optional fields: DVL, true velocity, the gravimeter's unlagged readings."""
    out: dict = {"true_velocity": true.velocity}
    if scenario.dvl is not None and scenario.ins.mode == "free":
        out["dvl_velocity"] = simulate_dvl(true, scenario.dvl, dvl_rng)
    if scenario.sensor.type == "gravimeter":
        out["unlagged_measured"] = unlagged
        out["lag_s"] = float(scenario.sensor.lag_s)
    return out


def simulate_trial(scenario: Scenario, grid: Grid, index: int) -> Trial:
    """Simulate trial ``index`` of a scenario on a prepared map.

    Parameters
    ----------
    scenario : Scenario
        The mission family.
    grid : Grid
        The prepared map (see :func:`prepare_map`); the sensor reads it along the truth
        (with a ``seabed`` block: the seabed, plus its relief, and the trial's prior map
        is derived from it, see :mod:`geofix.sim.seabed`).
    index : int
        Trial number; the random generator is ``default_rng([scenario.seed, index])``.

    Returns
    -------
    Trial
        ``noise_std`` is ``hypot(sensor.noise_std, sensor.map_error_std)`` (nadir value
        for a multibeam) and ``beam_noise_std`` ``(b,)`` likewise
        ``hypot(beam_noise_std(offsets, sensor), sensor.map_error_std)`` (every beam's
        noise, growing towards a multibeam's swath edges; see
        :func:`geofix.sensors.echosounder.beam_noise_std`); ``map_error_std`` is left at 0
        as both already hold the map error. ``sigma_position`` is
        :func:`geofix.nav.ins.position_sigma` with the nominal distance ``speed * t``.
        ``true_velocity`` is ``(n, 2)`` m/s; ``dvl_velocity`` ``(n, 2)`` m/s with a DVL
        aiding a free INS (None in ``ins.mode: dvl``, where the DVL is the navigator
        itself); for a gravimeter ``unlagged_measured`` ``(n, 1)`` and ``lag_s``.
        ``ins_model`` is the navigator's :class:`~geofix.nav.errstate.InsErrorModel`
        (handed to the problems). With a ``seabed`` block, ``prior_map`` is the trial's
        prior map (handed to the problems instead of ``grid``) and ``prior_shift_m`` its
        drawn misregistration; the readings carry the block's offset, tide and drift.

    Raises
    ------
    TrackOffMapError
        A beam footprint of the true track is off the map or on no-data (with a
        ``seabed`` block: off the seabed or off the prior map).
    ConfigError
        The start position or the sensor geometry is not given properly, or the
        ``seabed`` block does not fit the map.

    Examples
    --------
    >>> import geofix
    >>> scen = geofix.load_scenario("builtin:azores_demo")
    >>> grid = geofix.prepare_map(scen)
    >>> trial = geofix.simulate_trial(scen, grid, 3)
    >>> trial.index, trial.measured.shape
    (3, (80, 1))
    >>> bool((trial.indicated != trial.truth).any())  # the INS has drifted
    True
    """
    check_trial_size(scenario)
    check_sensor_fits_map(scenario, grid)
    extra_maps = prepare_field_maps(scenario)
    streams = np.random.default_rng([scenario.seed, index]).spawn(5 + 2 * len(extra_maps))
    track_rng, ins_rng, dvl_rng, sensor_rng, seabed_rng = streams[:5]
    true = _true_track(scenario, grid, track_rng)
    offsets = sensor_offsets(scenario.sensor)
    x, y = footprint_xy(true.positions, true.heading, offsets)
    footprints = np.stack([x, y], axis=-1)
    check_track_on_map(grid, footprints, "true track")
    ins = simulate_ins(true, scenario.ins, ins_rng, scenario.dvl)
    draw = _draw_seabed(scenario, grid, seabed_rng, footprints, true.times)
    measured, unlagged = _sense(
        grid, draw, true, offsets, scenario.sensor, sensor_rng, "measurement"
    )
    sensor = scenario.sensor
    return Trial(
        truth=true.positions,
        true_heading=true.heading,
        indicated=ins.indicated,
        indicated_heading=ins.heading,
        times=true.times,
        measured=measured,
        offsets=offsets,
        sigma_position=position_sigma(
            scenario.ins,
            true.times,
            distance_m=scenario.track.speed_m_s * true.times,
            dvl=scenario.dvl,
        ),
        leg_starts=true.leg_starts,
        noise_std=float(np.hypot(sensor.noise_std, sensor.map_error_std)),
        beam_noise_std=np.hypot(beam_noise_std(offsets, sensor), sensor.map_error_std),
        sensor=sensor.type,
        index=int(index),
        **_aiding(scenario, true, unlagged, dvl_rng),
        ins_model=InsErrorModel.from_specs(scenario.ins, scenario.dvl),
        **_prior_fields(draw),
        fields=tuple(
            _simulate_field(
                spec, f"sensors[{i}]", field_grid, true, *streams[3 + 2 * i : 5 + 2 * i]
            )
            for i, (spec, field_grid) in enumerate(
                zip(scenario.fields[1:], extra_maps, strict=True), start=1
            )
        ),
    )


def _simulate_field(
    spec: FieldSpec, which: str, grid: Grid, true: TrueTrajectory, sensor_rng, seabed_rng
) -> TrialField:
    """One further field's readings along the true track (its own noise, seabed, lag).

    Raises
    ------
    ConfigError
        The sensor cannot read the map's kind, or the map lies wholly off the track.
    TrackOffMapError
        A footprint of the true track is off this map (or its prior map) or on no-data.
    """
    _check_kind(spec.sensor, grid, f"{which}.sensor.type", f"{which}.map.kind")
    offsets = sensor_offsets(spec.sensor)
    x, y = footprint_xy(true.positions, true.heading, offsets)
    footprints = np.stack([x, y], axis=-1)
    west, east, south, north = grid.extent
    if x.max() < west or x.min() > east or y.max() < south or y.min() > north:
        raise ConfigError(
            f"{which}: map {grid.name!r} (x {west:.0f}..{east:.0f}, y {south:.0f}..{north:.0f}"
            f" m) does not overlap the true track (x {x.min():.0f}..{x.max():.0f}, "
            f"y {y.min():.0f}..{y.max():.0f} m)"
        )
    check_track_on_map(grid, footprints, f"true track on the {which} map")
    draw = _draw(spec.seabed, grid, seabed_rng, footprints, true.times)
    measured, unlagged = _sense(
        grid, draw, true, offsets, spec.sensor, sensor_rng, f"{which} measurement"
    )
    sensor = spec.sensor
    lagged = sensor.lag_s > 0
    return TrialField(
        kind=sensor.kind,
        sensor=sensor.type,
        measured=measured,
        offsets=offsets,
        noise_std=float(np.hypot(sensor.noise_std, sensor.map_error_std)),
        beam_noise_std=np.hypot(beam_noise_std(offsets, sensor), sensor.map_error_std),
        grid=grid if draw is None else draw.prior,
        lag_s=float(sensor.lag_s),
        unlagged_measured=unlagged if lagged else None,
        sensed=None if draw is None else draw.sensed,
        prior_shift_m=None if draw is None else draw.shift_m,
    )


def _draw_seabed(
    scenario: Scenario, grid: Grid, rng: np.random.Generator, footprints, times
) -> SeabedDraw | None:
    """The trial's draw of the ``seabed`` block (None without one).

    Raises
    ------
    TrackOffMapError
        The prior map does not cover the true track's footprints.
    """
    return _draw(scenario.seabed, grid, rng, footprints, times)


def _draw(seabed, grid: Grid, rng, footprints, times) -> SeabedDraw | None:
    """A draw of one ``seabed`` block (None without one); see :func:`_draw_seabed`."""
    if seabed is None:
        return None
    draw = draw_seabed(grid, seabed, rng, footprints, times)
    try:
        check_track_on_map(draw.prior, footprints, "true track on the prior map")
    except TrackOffMapError as exc:
        k = seabed.cell_factor
        hint = "" if k == 1 else f" (seabed.cell_factor {k} cuts the seabed's ragged edge)"
        raise TrackOffMapError(f"{exc}{hint}") from None
    return draw


def _prior_fields(draw: SeabedDraw | None) -> dict:
    """The trial's prior map and its drawn misregistration (none without a seabed block)."""
    if draw is None:
        return {}
    return {"prior_map": draw.prior, "prior_shift_m": draw.shift_m}


def simulate_trials(
    scenario: Scenario, grid: Grid, indices: Iterable[int] | None = None
) -> Iterator[Trial]:
    """Simulate several trials, one at a time.

    Parameters
    ----------
    scenario : Scenario
        The mission family.
    grid : Grid
        The prepared map.
    indices : iterable of int, optional
        Trial numbers; ``range(scenario.trials)`` by default.

    Yields
    ------
    Trial
        ``simulate_trial(scenario, grid, i)`` for each ``i``.
    """
    for index in range(scenario.trials) if indices is None else indices:
        yield simulate_trial(scenario, grid, index)
