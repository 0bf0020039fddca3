"""The method registry and method specifications (``"tercom:metric=mad,window_sigma=3"``).

Every method is a dataclass whose fields are its settings, with defaults from its
source. This module sits above both the batch matchers (:mod:`geofix.match`) and the
recursive filters (:mod:`geofix.filters`) and lists their classes; :func:`register` adds
a method of one's own under its ``name``. A specification string names a method and
optionally overrides settings; values are converted to the type of the default.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import re
import typing

from geofix.errors import ConfigError
from geofix.filters.mpf import Mpf
from geofix.filters.pf import Pf
from geofix.filters.pmf import Pmf
from geofix.filters.sitan import Sitan, SitanBank
from geofix.match.abc import AbcMhd
from geofix.match.free_ins import FreeIns
from geofix.match.ga_sca import GaSca
from geofix.match.iccp import Iccp, MultipathIccp
from geofix.match.icp import Icp, TercomIcp
from geofix.match.ioap import Ioap
from geofix.match.tercom import Tercom
from geofix.problem import Matcher

_M = typing.TypeVar("_M", bound=type[Matcher])

#: The methods geofix ships: batch matchers first, then the recursive filters, then the
#: free INS (no matching) as the yardstick.
BUILTIN_METHODS: tuple[type[Matcher], ...] = (
    Tercom,
    Iccp,
    MultipathIccp,
    GaSca,
    Icp,
    TercomIcp,
    AbcMhd,
    Ioap,
    Sitan,
    SitanBank,
    Pmf,
    Pf,
    Mpf,
    FreeIns,
)

_REGISTRY: dict[str, type[Matcher]] = {cls.name: cls for cls in BUILTIN_METHODS}


def register(cls: _M) -> _M:
    """Class decorator: register a method dataclass of one's own under ``cls.name``.

    The class needs a ``name``, a ``recursive`` flag and ``match(problem, rng) -> Fix``
    (:class:`geofix.problem.Matcher`); its dataclass fields are its settings.

    Raises
    ------
    TypeError
        ``cls`` is not a dataclass.
    """
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls.__name__} must be a dataclass to be registered")
    _REGISTRY[cls.name] = cls
    return cls


def available_methods() -> dict[str, type[Matcher]]:
    """All registered methods, by name.

    Examples
    --------
    >>> import geofix
    >>> list(geofix.available_methods())[:3]
    ['abc-mhd', 'ga-sca', 'iccp']
    """
    return dict(sorted(_REGISTRY.items()))


def method_settings(cls: type) -> list[tuple[str, object, str]]:
    """``(name, default, type name)`` of every setting of a method class."""
    hints = typing.get_type_hints(cls)
    rows = []
    for f in dataclasses.fields(cls):
        if not f.init or f.name.startswith("_"):
            continue
        rows.append(
            (
                f.name,
                _field_default(f),
                getattr(hints.get(f.name), "__name__", str(hints.get(f.name))),
            )
        )
    return rows


def _field_default(f: dataclasses.Field[typing.Any]) -> object:
    """A setting's default value (``default_factory()`` when it has a factory)."""
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is dataclasses.MISSING:
        raise TypeError(f"setting {f.name!r} has no default")
    return f.default_factory()


def method_summary(cls: type) -> str:
    """The first line of a method class's docstring (what it is, in a few words)."""
    return (cls.__doc__ or "").strip().splitlines()[0].strip() if cls.__doc__ else ""


def setting_descriptions(cls: type) -> dict[str, str]:
    """One line describing every setting, from the docstring's ``Parameters`` section.

    Parameters
    ----------
    cls : type
        A method class whose numpy-style docstring (or a base class's) documents its
        settings (fields).

    Returns
    -------
    dict
        ``{setting: first sentence of its description}`` for every setting (``""`` for
        an undocumented one); RST markup is dropped.

    Examples
    --------
    >>> import geofix
    >>> setting_descriptions(geofix.Tercom)["metric"]
    '"msd" (default), "mad", "cor" or "ncor".'
    """
    documented: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        documented.update(_parameter_blocks(klass.__doc__ or ""))
    return {name: _first_sentence(documented.get(name, "")) for name, *_ in method_settings(cls)}


_SECTIONS = {"Returns", "Raises", "Notes", "References", "Examples", "Attributes", "See Also"}


def _parameter_blocks(doc: str) -> dict[str, str]:
    """``{name: description}`` from a numpy-style docstring's Parameters section."""
    lines = inspect.cleandoc(doc).splitlines()
    if "Parameters" not in lines:
        return {}
    blocks: dict[str, str] = {}
    names: list[str] = []
    for line in lines[lines.index("Parameters") + 2 :]:
        if line.strip() in _SECTIONS:
            break
        if line and not line.startswith(" "):
            names = [n.strip() for n in line.split(" : ")[0].split(",")]
            blocks.update(dict.fromkeys(names, ""))
        elif line.strip():
            for n in names:
                blocks[n] = f"{blocks[n]} {line.strip()}".strip()
    return blocks


def _first_sentence(text: str) -> str:
    """The text up to its first full stop, without RST roles and literals."""
    text = re.sub(r":\w+:`~?([^`]+)`", r"\1", text)
    text = re.sub(r"``([^`]*)``", r"\1", text)
    match = re.match(r"(.+?\.)(\s|$)", text)
    return match.group(1) if match else text


def parse_method_spec(spec: str):
    """Build a method from ``"name"`` or ``"name:key=value,key=value"``.

    Parameters
    ----------
    spec : str
        The method's registered name, optionally followed by ``:`` and comma-separated
        ``key=value`` settings (values read as the type of the setting's default).

    Returns
    -------
    object
        The method (a frozen dataclass with ``match(problem, rng) -> Fix``).

    Raises
    ------
    ConfigError
        Unknown method, unknown setting, or a value of the wrong type.

    Examples
    --------
    >>> import geofix
    >>> method = geofix.parse_method_spec("tercom:metric=mad,window_sigma=2")
    >>> method.name, method.metric, method.window_sigma
    ('tercom', 'mad', 2.0)
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
        if key not in settings:
            raise ConfigError(
                f"method {name!r}: unknown setting {key!r} in {spec!r} "
                f"(settings: {', '.join(settings)})"
            )
        if not eq:
            raise ConfigError(
                f"method {name!r}: setting {key!r} in {spec!r} has no value; "
                f"write {key}=VALUE (default {settings[key][1]!r})"
            )
        if key in kwargs:
            raise ConfigError(f"method {name!r}: setting {key!r} given twice in {spec!r}")
        kwargs[key] = _convert(raw.strip(), settings[key][1], f"{name}:{key}")
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"method {spec!r}: {exc}") from None


def _convert(raw: str, default: object, where: str):
    value = _convert_raw(raw, default, where)
    numbers = value if isinstance(value, tuple) else (value,)
    if any(isinstance(v, float) and not math.isfinite(v) for v in numbers):
        raise ConfigError(f"{where}: value must be a finite number, got {raw!r}")
    return value


def _convert_raw(raw: str, default: object, where: str):
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
