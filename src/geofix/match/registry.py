"""Method registry and method specifications (``"tercom:metric=mad,window_sigma=3"``).

Every method is a dataclass whose fields are its settings, with defaults from its
source; ``register`` adds it under its ``name``. A specification string names a method
and optionally overrides settings; values are converted to the type of the default.
"""

from __future__ import annotations

import dataclasses
import importlib
import typing

from geofix.errors import ConfigError

_REGISTRY: dict[str, type] = {}

# Modules that register methods when imported; later issues add theirs here.
_METHOD_MODULES = (
    "geofix.match.tercom",
    "geofix.match.iccp",
    "geofix.match.ga_sca",
    "geofix.match.icp",
    "geofix.match.abc",
    "geofix.match.ioap",
    "geofix.filters.sitan",
    "geofix.filters.pmf",
    "geofix.filters.pf",
    "geofix.filters.mpf",
)


def register(cls: type) -> type:
    """Class decorator: register a method dataclass under ``cls.name``."""
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls.__name__} must be a dataclass to be registered")
    _REGISTRY[cls.name] = cls
    return cls


def available_methods() -> dict[str, type]:
    """All registered methods, by name (importing the method modules that exist)."""
    for module in _METHOD_MODULES:
        try:
            importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise
    return dict(sorted(_REGISTRY.items()))


def method_settings(cls: type) -> list[tuple[str, object, str]]:
    """``(name, default, type name)`` of every setting of a method class."""
    hints = typing.get_type_hints(cls)
    rows = []
    for f in dataclasses.fields(cls):
        if not f.init or f.name.startswith("_"):
            continue
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        rows.append(
            (f.name, default, getattr(hints.get(f.name), "__name__", str(hints.get(f.name))))
        )
    return rows


def parse_method_spec(spec: str):
    """Build a method from ``"name"`` or ``"name:key=value,key=value"``.

    Raises
    ------
    ConfigError
        Unknown method, unknown setting, or a value of the wrong type.
    """
    name, _, rest = spec.strip().partition(":")
    methods = available_methods()
    if name not in methods:
        known = ", ".join(methods) or "none"
        raise ConfigError(f"unknown method {name!r} (known: {known})")
    cls = methods[name]
    settings = {s[0]: s for s in method_settings(cls)}
    kwargs = {}
    for item in filter(None, (p.strip() for p in rest.split(","))):
        key, eq, raw = item.partition("=")
        key = key.strip()
        if not eq or key not in settings:
            raise ConfigError(
                f"method {name!r}: unknown setting {key!r} in {spec!r} "
                f"(settings: {', '.join(settings)})"
            )
        kwargs[key] = _convert(raw.strip(), settings[key][1], f"{name}:{key}")
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"method {spec!r}: {exc}") from None


def _convert(raw: str, default: object, where: str):
    try:
        if isinstance(default, bool):
            if raw.lower() in ("1", "true", "yes", "on"):
                return True
            if raw.lower() in ("0", "false", "no", "off"):
                return False
            raise ValueError(raw)
        if isinstance(default, int):
            return int(raw)
        if isinstance(default, float):
            return float(raw)
        if isinstance(default, tuple):
            return tuple(type(default[0])(v) for v in raw.split("/")) if default else ()
        if default is None:
            return _guess(raw)
        return raw
    except ValueError:
        raise ConfigError(f"{where}: cannot read {raw!r} as {type(default).__name__}") from None


def _guess(raw: str):
    for kind in (int, float):
        try:
            return kind(raw)
        except ValueError:
            pass
    return raw
