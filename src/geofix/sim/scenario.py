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
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from geofix.errors import ConfigError


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class MapSpec(_Strict):
    """Which map, and how to prepare it.

    ``path`` is relative to the scenario file, or ``builtin:NAME`` for a bundled map.
    ``region`` is ``[west, east, south, north]`` in the file's own coordinates, cut before
    projection and resampling; ``resample_m`` resamples (bilinear) to that cell size.
    """

    path: str
    variable: str | None = None
    kind: Literal["depth", "gravity"] | None = None
    region: tuple[float, float, float, float] | None = None
    resample_m: float | None = Field(default=None, gt=0)


class TrackSpec(_Strict):
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


class SensorSpec(_Strict):
    """The field sensor.

    ``singlebeam``: depth under the vehicle. ``multibeam``: ``beams`` beams across a swath
    of ``swath_width_m`` metres (or ``swath_angle_deg`` with ``altitude_m``), noise growing
    to ``edge_noise_factor`` times ``noise_std`` at the outer beams. ``gravimeter``: a
    first-order lag of ``lag_s`` seconds (0 = none).
    """

    type: Literal["singlebeam", "multibeam", "gravimeter"]
    noise_std: float = Field(default=0.0, ge=0)
    beams: int = Field(default=1, ge=1)
    swath_width_m: float | None = Field(default=None, gt=0)
    swath_angle_deg: float | None = Field(default=None, gt=0, lt=180)
    altitude_m: float | None = Field(default=None, gt=0)
    edge_noise_factor: float = Field(default=2.0, ge=1)
    lag_s: float = Field(default=0.0, ge=0)
    map_error_std: float = Field(default=0.0, ge=0)


class InsSpec(_Strict):
    """INS datasheet numbers (see :mod:`geofix.nav.ins` for how they are integrated).

    ``initial_error_m`` is a fixed ``[east, north]`` offset of the indicated start;
    ``initial_error_std_m`` adds a random per-axis Gaussian offset per trial.
    ``prior_sigma_m`` overrides the prior 1-sigma handed to the matchers.
    ``mode`` is ``free`` (a free inertial navigator, the default: every other key as
    above) or ``dvl`` (DVL-aided dead reckoning: the position integrates the ``dvl``
    block's velocity, with its bias, noise and ``scale_error``, rotated by a heading of
    error ``heading_error_deg`` drifting at ``gyro_bias_deg_h`` with noise
    ``gyro_noise_deg_rt_h``; the accelerometer, velocity-error and Schuler keys are then
    unused). ``latitude_deg`` (degrees, optional) switches on the Earth-rate coupling of
    the heading error of a free INS (see :mod:`geofix.nav.errstate`).
    """

    initial_error_m: tuple[float, float] = (0.0, 0.0)
    initial_error_std_m: float = Field(default=0.0, ge=0)
    velocity_error_m_s: float = Field(default=0.0, ge=0)
    heading_error_deg: float = 0.0
    gyro_bias_deg_h: float = Field(default=0.0, ge=0)
    gyro_noise_deg_rt_h: float = Field(default=0.0, ge=0)
    accel_bias_ug: float = Field(default=0.0, ge=0)
    accel_noise_ug_rt_hz: float = Field(default=0.0, ge=0)
    schuler: bool = True
    prior_sigma_m: float | None = Field(default=None, gt=0)
    mode: Literal["free", "dvl"] = "free"
    latitude_deg: float | None = Field(default=None, ge=-90, le=90)


class DvlSpec(_Strict):
    """Doppler velocity log: per-axis white noise and a constant bias, m/s.

    ``scale_error`` (dimensionless, e.g. 0.002 for 0.2 %) is the magnitude of a scale-factor
    error of random sign; it is used by ``ins.mode: dvl`` (dead reckoning on the DVL).
    """

    noise_std_m_s: float = Field(default=0.01, ge=0)
    bias_m_s: float = Field(default=0.0, ge=0)
    scale_error: float = Field(default=0.0, ge=0)


class Scenario(_Strict):
    """A validated scenario. Build with :func:`load_scenario` or ``Scenario(**dict)``."""

    name: str
    map: MapSpec
    track: TrackSpec
    sensor: SensorSpec
    ins: InsSpec = InsSpec()
    dvl: DvlSpec | None = None
    trials: int = Field(default=10, ge=1)
    seed: int = 0
    base_dir: str = Field(default=".", exclude=True)

    @field_validator("name")
    @classmethod
    def _name_not_empty(cls, v: str) -> str:
        if not v.strip():
            raise ValueError("must not be empty")
        return v

    @model_validator(mode="after")
    def _dvl_mode_needs_dvl(self) -> Scenario:
        if self.ins.mode == "dvl" and self.dvl is None:
            raise ValueError("ins.mode: dvl needs a dvl block (noise_std_m_s, bias_m_s, ...)")
        return self

    def map_path(self) -> str:
        """The map path as given, resolved against the scenario's folder."""
        if self.map.path.startswith("builtin:"):
            return self.map.path
        path = Path(self.map.path)
        return str(path if path.is_absolute() else Path(self.base_dir) / path)


def scenario_from_dict(
    data: dict, base_dir: str | Path = ".", source: str = "scenario"
) -> Scenario:
    """Validate a scenario mapping; errors name the bad key."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping at the top level")
    try:
        return Scenario(**data, base_dir=str(base_dir))
    except ValidationError as exc:
        raise ConfigError(f"{source}: {_describe(exc)}") from None


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

    Raises
    ------
    ConfigError
        The file is missing, is not YAML, or has a wrong key or value (the message names
        the key, e.g. ``track.speed_m_s: Input should be greater than 0``).
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f"cannot read scenario {path}: {exc.strerror or exc}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"scenario {path} is not valid YAML: {exc}") from None
    return scenario_from_dict(data, base_dir=path.parent, source=str(path))


def _describe(exc: ValidationError) -> str:
    parts = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in err["loc"]) or "(top level)"
        msg = "unknown key" if err["type"] == "extra_forbidden" else err["msg"]
        parts.append(f"{loc}: {msg}")
    return "; ".join(parts)
