"""The method registry and method specifications (``"tercom:metric=mad,window_sigma=3"``).

Every method is a dataclass whose fields are its settings, with defaults from its
source. This module sits above both the batch matchers (:mod:`geofix.match`) and the
recursive filters (:mod:`geofix.filters`) and lists their classes; :func:`register` adds
a method of one's own under its ``name``. A specification string names a method and
optionally overrides settings; values are converted to the type of the default.
"""

from __future__ import annotations

import dataclasses
import difflib
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

#: What each shipped method is, in one plain line (``geofix methods`` shows it). A method
#: registered with :func:`register` is described by its docstring's first line instead.
METHOD_DESCRIPTIONS: dict[str, str] = {
    "tercom": "TERCOM: exhaustive search over rigid shifts of the track (MSD, MAD, COR).",
    "iccp": "ICCP: iterative closest contour point on the nadir beam's depth profile.",
    "iccp-multipath": "Multipath ICCP: three beam paths fitted with one rigid transform.",
    "ga-sca": "Genetic algorithm search for the track's shift, sine-cosine refinement.",
    "icp": "ICP: point-to-point fit of the multibeam cloud onto the map's grid points.",
    "tercom-icp": "TERCOM coarse fix over the 6-sigma window, refined by ICP.",
    "abc-mhd": "Artificial bee colony search with mean-Hausdorff screening.",
    "ioap": "IOAP: ring searches for the track's start and end points, scored by MSD.",
    "sitan": "SITAN: one extended Kalman filter on the linearised terrain (primary field).",
    "sitan-bank": "Parallel SITAN: N x N Kalman filters, the best one kept (primary field).",
    "pmf": "Point-mass filter: Bayes on a grid that follows the posterior (every field).",
    "pf": "Bootstrap particle filter over the horizontal position (every field).",
    "mpf": "Marginalised particle filter: Kalman on INS errors (every field).",
    "ins": "The free INS: the indicated track, never corrected (the yardstick).",
}


def register(cls: _M) -> _M:
    """Class decorator: register a method dataclass of one's own under ``cls.name``.

    The class needs a ``name``, a ``recursive`` flag and ``match(problem, rng) -> Fix``
    (:class:`geofix.problem.Matcher`); its dataclass fields are its settings.

    Parameters
    ----------
    cls : type
        The method's dataclass; ``geofix methods`` describes it by its docstring's first
        line and each setting by its ``Parameters`` entry.

    Returns
    -------
    type
        ``cls`` itself (a decorator).

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
    """What a method is, in one plain-text line.

    Parameters
    ----------
    cls : type
        A method class.

    Returns
    -------
    str
        The line of :data:`METHOD_DESCRIPTIONS` for a shipped method; for another, the
        first line of its docstring without RST markup (``""`` without a docstring).

    Examples
    --------
    >>> import geofix
    >>> method_summary(geofix.Pf)
    'Bootstrap particle filter over the horizontal position (every field).'
    """
    name = getattr(cls, "name", None)
    if name in METHOD_DESCRIPTIONS and _REGISTRY.get(name) is cls:
        return METHOD_DESCRIPTIONS[name]
    lines = inspect.cleandoc(cls.__doc__ or "").splitlines()
    return _plain(lines[0].strip()) if lines else ""


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
    '"msd" (default), "mad", "cor", "ncor" or "cmsd".'
    """
    documented: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        documented.update(_parameter_blocks(klass.__doc__ or ""))
    return {name: documented.get(name, "") for name, *_ in method_settings(cls)}


_SECTIONS = {"Returns", "Raises", "Notes", "References", "Examples", "Attributes", "See Also"}
_ELLIPSIS = "..."


def _parameter_blocks(doc: str) -> dict[str, str]:
    """``{name: one-sentence description}`` from a numpy-style docstring's Parameters.

    An entry may name several settings (``tolerance_m, tolerance_rad : float``); an entry
    whose description goes on from the one before (``... and rotates less than this``) is
    joined to that one's sentence, so it reads on its own.
    """
    lines = inspect.cleandoc(doc).splitlines()
    if "Parameters" not in lines:
        return {}
    entries: list[tuple[list[str], str]] = []
    for line in lines[lines.index("Parameters") + 2 :]:
        if line.strip() in _SECTIONS:
            break
        if line and not line.startswith(" "):
            names = [n.strip() for n in line.split(":")[0].split(",") if n.strip()]
            entries.append((names, ""))
        elif line.strip() and entries:
            names, text = entries[-1]
            entries[-1] = (names, f"{text} {line.strip()}".strip())
    blocks: dict[str, str] = {}
    previous = ""
    for names, text in entries:
        goes_on = text.startswith(_ELLIPSIS) and bool(previous)
        sentence = _first_sentence(text.removeprefix(_ELLIPSIS).strip() if goes_on else text)
        if goes_on:
            sentence = f"{previous}, {sentence}"
        previous = sentence.removesuffix(_ELLIPSIS).rstrip(" .,;")
        if sentence.endswith(_ELLIPSIS):
            sentence = f"{previous}."
        blocks.update(dict.fromkeys(names, sentence))
    return blocks


def _plain(text: str) -> str:
    """``text`` without RST roles (``:class:`~a.B```) and literals (````x````)."""
    text = re.sub(r":\w+:`~?([^`]+)`", r"\1", text)
    return re.sub(r"``([^`]*)``", r"\1", text)


def _first_sentence(text: str) -> str:
    """The text up to its first full stop, without RST roles and literals."""
    text = _plain(text)
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
        raise ConfigError(unknown_method_message(name, methods))
    cls = methods[name]
    settings = {s[0]: s for s in method_settings(cls)}
    kwargs = {}
    for item in filter(None, (p.strip() for p in rest.split(","))):
        key, eq, raw = item.partition("=")
        key = key.strip()
        if key not in settings:
            raise ConfigError(
                f"method {name!r}: unknown setting {key!r} in {spec!r}"
                f"{did_you_mean(key, settings)} (settings: {', '.join(settings)})"
            )
        if not eq:
            raise ConfigError(
                f"method {name!r}: setting {key!r} in {spec!r} has no value; "
                f"write {key}=VALUE (default {settings[key][1]!r})"
            )
        if key in kwargs:
            raise ConfigError(f"method {name!r}: setting {key!r} given twice in {spec!r}")
        kwargs[key] = _convert(raw.strip(), settings[key][1], f"{name}:{key}", settings[key][2])
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"method {spec!r}: {exc}") from None


def did_you_mean(word: str, known: typing.Iterable[str]) -> str:
    """``"; did you mean 'pmf'?"`` for the known name closest to ``word``, else ``""``.

    Examples
    --------
    >>> did_you_mean("pfm", ["pmf", "pf", "tercom"])
    "; did you mean 'pmf'?"
    >>> did_you_mean("zzz", ["pmf"])
    ''
    """
    by_lower = {k.lower(): k for k in known}
    word = word.lower()
    close = difflib.get_close_matches(word, list(by_lower), n=3, cutoff=0.6)
    if not close:
        return ""
    # a swapped pair of letters ("pfm") is one edit, as close as a dropped letter ("pf")
    best = min(close, key=lambda k: (_edit_distance(word, k), abs(len(k) - len(word))))
    return f"; did you mean {by_lower[best]!r}?"


def _edit_distance(a: str, b: str) -> int:
    """Edits (insert, delete, replace, swap two neighbours) turning ``a`` into ``b``."""
    rows = [list(range(len(b) + 1))]
    for i, ca in enumerate(a, 1):
        row = [i]
        for j, cb in enumerate(b, 1):
            row.append(min(rows[-1][j] + 1, row[j - 1] + 1, rows[-1][j - 1] + (ca != cb)))
            if i > 1 and j > 1 and ca == b[j - 2] and a[i - 2] == cb:
                row[j] = min(row[j], rows[-2][j - 2] + 1)
        rows.append(row)
    return rows[-1][-1]


def unknown_method_message(name: str, known: typing.Iterable[str]) -> str:
    """The error line of an unknown method name: the closest name, then every name.

    Examples
    --------
    >>> unknown_method_message("pfm", ["pf", "pmf"])
    "unknown method 'pfm'; did you mean 'pmf'? (known: pf, pmf)"
    """
    names = list(known)
    listing = ", ".join(names) or "none"
    return f"unknown method {name!r}{did_you_mean(name, names)} (known: {listing})"


def _convert(raw: str, default: object, where: str, kind: str = ""):
    value = _convert_raw(raw, default, where, kind)
    numbers = value if isinstance(value, tuple) else (value,)
    if any(isinstance(v, float) and not math.isfinite(v) for v in numbers):
        raise ConfigError(f"{where}: value must be a finite number, got {raw!r}")
    return value


#: Words read as a bool: by a bool setting (and ``1``, ``0``), and by one whose default is None.
_BOOL_WORDS = {"true": True, "yes": True, "on": True, "false": False, "no": False, "off": False}


def _convert_raw(raw: str, default: object, where: str, kind: str = ""):
    if default is None:
        default = _optional_example(kind)
    try:
        if isinstance(default, bool):
            word = {"1": "true", "0": "false"}.get(raw, raw.lower())
            if word in _BOOL_WORDS:
                return _BOOL_WORDS[word]
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


def _optional_example(kind: str) -> object:
    """A value of the type an optional setting's annotation names (``float | None``: 0.0).

    None where the annotation names no single number type: the value is then guessed
    (an optional bool's word is checked by the method itself, which names the words).
    """
    names = {part.strip() for part in kind.split("|")} - {"None", "NoneType"}
    if len(names) != 1:
        return None
    return {"float": 0.0, "int": 0}.get(names.pop())


def _guess(raw: str):
    if raw.lower() in _BOOL_WORDS:
        return _BOOL_WORDS[raw.lower()]
    for kind in (int, float):
        try:
            return kind(raw)
        except ValueError:
            pass
    return raw
