"""Scenario files: a validated description of a mission family (YAML -> :class:`Scenario`).

The keys below are a public contract relied on by outside scripts: they may be extended,
never renamed. Example::

    name: ioap-south-start
    map: {path: maps/x.nc, variable: z, kind: gravity, region: [-146, -144, 54, 56],
          resample_m: 100}
    track: {start_cell: [1400, 1500], heading_deg: 70, speed_m_s: 10, interval_s: 20,
            samples: 110, legs: 1, turn_std_deg: 0}
    sensor: {type: gravimeter, noise_std: 1.0}
    ins: {initial_error_m: [0, 0], velocity_error_m_s: 0.04, heading_error_deg: 0.05,
          gyro_bias_deg_h: 0.0, gyro_noise_deg_rt_h: 0.0, accel_bias_ug: 102,
          accel_noise_ug_rt_hz: 0}
    trials: 100
    seed: 1
    seabed: {cell_factor: 4, error_rms: 2.0, error_corr_m: 400, misregistration_m: 150}

The sensor, INS and DVL blocks are the specifications of their own layers
(:class:`geofix.sensors.spec.SensorSpec`, :class:`geofix.nav.spec.InsSpec`,
:class:`geofix.nav.spec.DvlSpec`), importable from here too. The optional ``seabed``
block (:class:`geofix.sim.seabed.SeabedSpec`, every key described in
:mod:`geofix.sim.seabed`) makes the map the sensor reads (the scenario's ``map``, the
seabed) differ from the prior map the methods get; a scenario without it is dumped (and
hashed) as before the block existed.

A vehicle with several field sensors lists them under ``sensors:`` instead, one entry
per field, each with its own map, sensor and optional ``seabed`` block
(:class:`FieldSpec`)::

    sensors:
      - {map: {path: "builtin:mb_1km"}, sensor: {type: multibeam, beams: 11, ...}}
      - {map: {path: "builtin:grav_1km"}, sensor: {type: gravimeter, noise_std: 1.0}}

The first entry is the primary field: ``map``, ``sensor`` and ``seabed`` of the scenario
are its blocks (given again at the top level they must be equal to the entry's; a
top-level ``seabed`` applies to the first entry when it has none). The
recursive filters weigh every field (:mod:`geofix.filters.loop`); the batch matchers and
SITAN use the primary field only. A scenario without ``sensors:`` is dumped (and hashed)
as before the key existed.
"""

from __future__ import annotations

import difflib
import typing
from pathlib import Path
from typing import Literal

import yaml
from pydantic import (
    Field,
    SerializerFunctionWrapHandler,
    ValidationError,
    field_validator,
    model_serializer,
    model_validator,
)

from geofix._strict import Strict
from geofix.errors import ConfigError
from geofix.nav.spec import DvlSpec, InsSpec
from geofix.sensors.spec import SensorSpec
from geofix.sim.seabed import HolesSpec, SeabedSpec

__all__ = [
    "DvlSpec",
    "FieldSpec",
    "HolesSpec",
    "InsSpec",
    "MapSpec",
    "Scenario",
    "SeabedSpec",
    "SensorSpec",
    "TrackSpec",
    "builtin_scenario_path",
    "load_scenario",
    "scenario_from_dict",
]


class MapSpec(Strict):
    """Which map, and how to prepare it.

    ``path`` is relative to the scenario file, or ``builtin:NAME`` for a bundled map.
    ``region`` is ``[west, east, south, north]`` in the file's own coordinates, cut before
    projection and resampling; ``resample_m`` resamples (bilinear) to that cell size.
    """

    path: str
    variable: str | None = None
    kind: Literal["depth", "gravity", "magnetic"] | None = None
    region: tuple[float, float, float, float] | None = None
    resample_m: float | None = Field(default=None, gt=0)


class FieldSpec(Strict):
    """One field sensor of a ``sensors:`` list: its map, its sensor, its optional seabed.

    Parameters
    ----------
    map : MapSpec
        The map of this field (its ``kind`` must be the one the sensor reads).
    sensor : SensorSpec
        The sensor of this field and its noise (map units).
    seabed : SeabedSpec, optional
        How this field's prior map differs from the field the sensor reads
        (:mod:`geofix.sim.seabed`; None: the map is the field).
    """

    map: MapSpec
    sensor: SensorSpec
    seabed: SeabedSpec | None = None


class TrackSpec(Strict):
    """The true trajectory: ``samples`` per leg, ``legs`` legs, a random turn between legs.

    ``start_cell`` is ``[column, row]`` of the prepared map (row 0 at the south edge);
    ``start_m`` ``[x, y]`` metres may be given instead. ``start_jitter_m`` moves the start
    of each trial by a uniform random offset of up to that many metres per axis.
    """

    start_cell: tuple[float, float] | None = None
    start_m: tuple[float, float] | None = None
    start_jitter_m: float = Field(default=0.0, ge=0)
    heading_deg: float = 0.0
    speed_m_s: float = Field(gt=0)
    interval_s: float = Field(gt=0)
    samples: int = Field(ge=2)
    legs: int = Field(default=1, ge=1)
    turn_std_deg: float = Field(default=0.0, ge=0)


MAX_TRIALS = 1_000_000
"""Most trials a campaign runs (its results table is held in memory at the end)."""


class Scenario(Strict):
    """A validated scenario. Build with :func:`load_scenario` or ``Scenario(**dict)``.

    Parameters
    ----------
    name : str
        The scenario's name (non-blank), used in outputs.
    map : MapSpec
        The map the sensor reads: a file or ``builtin:NAME``, its variable, field kind,
        geographic region cut and resampling to metres (with ``sensors``: the first
        entry's, filled in from it).
    track : TrackSpec
        The true track: start, heading, speed, sampling interval, samples, legs, turns.
    sensor : SensorSpec
        The field sensor (single-beam, multibeam, gravimeter or magnetometer) and its
        noise (with ``sensors``: the first entry's, filled in from it).
    sensors : list of FieldSpec, optional
        Several field sensors, one entry per field kind, the first the primary field
        (None: the one field of ``map`` and ``sensor``).
    ins : InsSpec
        The INS datasheet: initial error, velocity and heading errors, gyro and
        accelerometer biases and noises.
    dvl : DvlSpec, optional
        A Doppler velocity log aiding the INS (None: free inertial).
    trials : int
        Number of Monte Carlo trials (1 to :data:`MAX_TRIALS`).
    seed : int
        Seed of every trial's generator (trial ``i`` draws from ``[seed, i]``).
    seabed : SeabedSpec, optional
        How the prior map the methods get differs from the field the sensor reads
        (:mod:`geofix.sim.seabed`; None: the map is the seabed); with ``sensors``, the
        first entry's.
    base_dir : str
        Folder a relative ``map.path`` is read from (not part of the file).
    """

    name: str
    map: MapSpec
    track: TrackSpec
    sensor: SensorSpec
    sensors: list[FieldSpec] | None = None
    ins: InsSpec = InsSpec()
    dvl: DvlSpec | None = None
    trials: int = Field(default=10, ge=1, le=MAX_TRIALS)
    seed: int = Field(default=0, ge=0)
    seabed: SeabedSpec | None = None
    base_dir: str = Field(default=".", exclude=True)

    @field_validator("name")
    @classmethod
    def _name_not_empty(cls, v: str) -> str:
        if not v.strip():
            raise ValueError("must not be empty")
        return v

    @model_validator(mode="before")
    @classmethod
    def _primary_blocks_from_sensors(cls, data):
        # the first entry of a sensors: list stands for the map: and sensor: blocks when
        # they are not given (given, they must equal it: checked once parsed)
        if not isinstance(data, dict):
            return data
        entries = data.get("sensors")
        if entries is None:
            missing = [k for k in ("map", "sensor") if data.get(k) is None]
            if missing:
                raise ValueError(f"{' and '.join(missing)} required (or a sensors: list of fields)")
            return data
        if isinstance(entries, list) and not entries:
            raise ValueError("sensors: the list is empty; give at least one {map, sensor}")
        if not isinstance(entries, list) or not isinstance(entries[0], dict):
            return data
        filled = dict(data)
        for key in ("map", "sensor"):
            if filled.get(key) is None and key in entries[0]:
                filled[key] = entries[0][key]
        return filled

    @model_validator(mode="after")
    def _sensors_fill_the_primary_field(self) -> Scenario:
        if not self.sensors:
            return self
        first = self.sensors[0]
        for key in ("map", "sensor", "seabed"):
            given, entry = getattr(self, key), getattr(first, key)
            if key == "seabed" and entry is None:
                continue  # a top-level seabed block is the primary field's
            if given is not None and given != entry:
                raise ValueError(
                    f"{key}: conflicts with sensors[0].{key} (with a sensors: list, give "
                    f"{key} in its first entry only)"
                )
            object.__setattr__(self, key, entry)  # the primary field's blocks
        kinds = [entry.sensor.kind for entry in self.sensors]
        for i, kind in enumerate(kinds):
            if kind in kinds[:i]:
                raise ValueError(
                    f"sensors[{i}]: a second {kind} sensor (sensors[{kinds.index(kind)}] "
                    f"is one); one entry per field kind"
                )
        for i, entry in enumerate(self.sensors):
            if entry.map.kind is not None and entry.map.kind != entry.sensor.kind:
                raise ValueError(
                    f"sensors[{i}]: sensor.type {entry.sensor.type} needs a "
                    f"{entry.sensor.kind} map, but map.kind is {entry.map.kind}"
                )
        return self

    @property
    def fields(self) -> list[FieldSpec]:
        """Every field of the scenario, the primary first (one without ``sensors``)."""
        if self.sensors is not None:
            first = self.sensors[0].model_copy(update={"seabed": self.seabed})
            return [first, *self.sensors[1:]]
        return [FieldSpec(map=self.map, sensor=self.sensor, seabed=self.seabed)]

    def field_map_path(self, index: int) -> str:
        """The map path of field ``index`` (0: the primary) resolved as :meth:`map_path`."""
        return self._resolved(self.fields[index].map.path)

    @model_validator(mode="after")
    def _dvl_mode_needs_dvl(self) -> Scenario:
        if self.ins.mode == "dvl" and self.dvl is None:
            raise ValueError("ins.mode: dvl needs a dvl block (noise_std_m_s, bias_m_s, ...)")
        return self

    @model_serializer(mode="wrap")
    def _without_absent_seabed(self, handler: SerializerFunctionWrapHandler) -> dict:
        # a scenario without a seabed block dumps (and so hashes) exactly as before it existed
        data = handler(self)
        if self.seabed is None:
            data.pop("seabed", None)
        if self.sensors is None:
            data.pop("sensors", None)
        else:
            for entry in data["sensors"]:
                if entry.get("seabed") is None:
                    entry.pop("seabed", None)
        return data

    def map_path(self) -> str:
        """The map path as given, resolved against the scenario's folder."""
        assert self.map is not None  # checked on validation
        return self._resolved(self.map.path)

    def _resolved(self, given: str) -> str:
        if given.startswith("builtin:"):
            return given
        path = Path(given)
        return str(path if path.is_absolute() else Path(self.base_dir) / path)


def scenario_from_dict(
    data: dict, base_dir: str | Path = ".", source: str = "scenario"
) -> Scenario:
    """Validate a scenario mapping; errors name the bad key.

    Parameters
    ----------
    data : dict
        The scenario's keys (those of a scenario file, :mod:`geofix.sim.scenario`).
    base_dir : str or pathlib.Path
        Folder a relative ``map.path`` is read from.
    source : str
        What the mapping came from, the prefix of every error message.

    Returns
    -------
    Scenario
        The validated scenario.

    Raises
    ------
    ConfigError
        ``data`` is not a mapping, or a key is unknown (with the closest known key when
        one is close) or has a bad value; one line naming every bad key.
    """
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping at the top level")
    try:
        return Scenario(**data, base_dir=str(base_dir))
    except ValidationError as exc:
        raise ConfigError(f"{source}: {_describe(exc)}") from None


def with_overrides(scenario: Scenario, trials: int | None = None, seed: int | None = None):
    """The scenario with ``trials`` and/or ``seed`` replaced (the CLI's ``--trials``/``--seed``).

    Parameters
    ----------
    scenario : Scenario
        The scenario to change.
    trials : int, optional
        Number of trials (None: keep the scenario's).
    seed : int, optional
        Seed of every trial's generator (None: keep the scenario's).

    Returns
    -------
    Scenario
        A new scenario; ``scenario`` itself is unchanged.

    Raises
    ------
    ConfigError
        ``trials`` below 1 or above :data:`MAX_TRIALS`, or ``seed`` negative (the message
        names the option).
    """
    update = {}
    if trials is not None:
        if int(trials) < 1:
            raise ConfigError(f"trials (--trials) must be at least 1, got {trials}")
        if int(trials) > MAX_TRIALS:
            raise ConfigError(f"trials (--trials) must be at most {MAX_TRIALS}, got {trials}")
        update["trials"] = int(trials)
    if seed is not None:
        if int(seed) < 0:
            raise ConfigError(f"seed (--seed) must be a non-negative integer, got {seed}")
        update["seed"] = int(seed)
    return scenario.model_copy(update=update) if update else scenario


def builtin_scenario_path(name: str) -> Path:
    """Path of a scenario shipped with geofix (``src/geofix/scenarios/NAME.yaml``)."""
    from importlib import resources

    path = Path(str(resources.files("geofix") / "scenarios" / f"{name}.yaml"))
    if not path.exists():
        known = sorted(p.stem for p in path.parent.glob("*.yaml"))
        raise ConfigError(f"no bundled scenario {name!r} (bundled: {', '.join(known)})")
    return path


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario YAML file.

    Parameters
    ----------
    path : str or pathlib.Path
        A YAML file, or ``"builtin:NAME"`` for a scenario shipped with geofix
        (``azores_demo``, ``navo_flat_singlebeam``, ``navo_flat_multibeam``).

    Returns
    -------
    Scenario
        The validated scenario; its map path is resolved against the file's folder.

    Raises
    ------
    ConfigError
        The file is missing, is not YAML, or has a wrong key or value (the message names
        the key, e.g. ``track.speed_m_s: Input should be greater than 0``).

    Examples
    --------
    >>> import geofix
    >>> scen = geofix.load_scenario("builtin:azores_demo")
    >>> scen.name, scen.sensor.type, scen.trials
    ('azores-demo', 'singlebeam', 100)
    """
    if str(path).startswith("builtin:"):
        path = builtin_scenario_path(str(path).removeprefix("builtin:"))
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f"cannot read scenario {path}: {exc.strerror or exc}") from None
    data = _parse_yaml(text, path)
    try:
        return scenario_from_dict(data, base_dir=path.parent, source=str(path))
    except RecursionError:
        raise ConfigError(f"scenario {path}: nested too deeply to be a scenario") from None


def _parse_yaml(text: str, path: Path):
    """The YAML document of a scenario file, or a ConfigError naming the file.

    Beyond syntax errors, a document nested thousands of levels deep and an integer of
    more digits than Python converts (4300) are refused in one line.
    """
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"scenario {path}{_yaml_problem(exc)}") from None
    except RecursionError:
        raise ConfigError(f"scenario {path}: not valid YAML: nested too deeply") from None
    except ValueError as exc:  # an integer of thousands of digits
        what = "a number has too many digits" if "digits" in str(exc) else str(exc)[:80]
        raise ConfigError(f"scenario {path}: not valid YAML: {what}") from None


def _yaml_problem(exc: yaml.YAMLError) -> str:
    """``":LINE:COLUMN: not valid YAML: what"`` (1-based) from a YAML parser error."""
    mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
    where = "" if mark is None else f":{mark.line + 1}:{mark.column + 1}"
    what = getattr(exc, "problem", None) or str(exc).splitlines()[0]
    context = getattr(exc, "context", None)
    what = f"{context}, {what}" if context else what
    return f"{where}: not valid YAML: {' '.join(str(what).split())}"


def _unknown_key(loc: tuple) -> str:
    """``"unknown key"``, with the closest known key of its block when one is close."""
    known = _known_keys(loc[:-1])
    close = difflib.get_close_matches(str(loc[-1]), known, n=1, cutoff=0.6)
    return f"unknown key (did you mean {close[0]!r}?)" if close else "unknown key"


def _known_keys(path: tuple) -> list[str]:
    """The keys a scenario accepts in the block at ``path`` (``()``: the top level)."""
    model: object = Scenario
    for part in path:
        fields = getattr(model, "model_fields", {})
        if part not in fields:
            return []
        model = _model_of(fields[part].annotation)
    return [k for k, f in getattr(model, "model_fields", {}).items() if not f.exclude]


def _model_of(annotation) -> object:
    """The pydantic model inside ``annotation`` (``X | None`` -> ``X``), else the annotation."""
    for arg in typing.get_args(annotation) or (annotation,):
        if hasattr(arg, "model_fields"):
            return arg
    return annotation


def _describe(exc: ValidationError) -> str:
    parts = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in err["loc"]) or "(top level)"
        msg = _unknown_key(err["loc"]) if err["type"] == "extra_forbidden" else err["msg"]
        if err["type"] == "finite_number":
            msg = f"must be a finite number, got {err.get('input')!r}"
        parts.append(f"{loc}: {' '.join(str(msg).split())}")
    return "; ".join(parts)
