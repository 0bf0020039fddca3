"""``geofix serve``: the navigator over TCP, newline-delimited JSON (asyncio).

One :class:`geofix.Navigator` per connection; every request line gets exactly one reply
line, in order. Requests (UTF-8 JSON objects, one per line, at most
:data:`MAX_LINE_BYTES` bytes):

- ``{"type": "init", "t": s, "x": m, "y": m, "sigma_m": m}`` (optional ``heading_deg``;
  optional ``fields``, a list of the kinds of the server's further maps this connection
  weighs, e.g. ``["gravity"]``: by default every further map the server has, ``[]`` for
  the primary map alone);
- ``{"type": "nav", "t": s, "x": m, "y": m, "heading_deg": deg}`` -- the INS-indicated
  position in the map's metric frame (``lon`` / ``lat`` in degrees instead of ``x`` /
  ``y`` when the map was projected from lon/lat);
- ``{"type": "ping", "t": s, "beams": [[across_m, along_m, value], ...]}`` (``value``
  null for a missing beam), or rows ``[across_m, along_m, down_m, value]`` of body-frame
  beam vectors; optional ``roll_deg`` / ``pitch_deg`` (the vehicle attitude, levelling
  body-frame beams and the mounting offset: ``geofix.sensors.attitude``); optional
  ``fields``, the further fields' readings of the same ping, each ``{"kind": "gravity",
  "beams": [[across_m, along_m, value], ...], "noise_var": var}`` (``var`` in that map's
  units squared, a number or one per beam; a kind of the connection's further maps, each
  at most once). The ping is folded in as one update of every field it carries
  (:class:`geofix.Navigator`); its NIS is the primary field's (null without a valid
  primary beam: send ``[[0, 0, null]]`` for a ping of the further fields alone);
- ``{"type": "estimate"}``;
- ``{"type": "config", "method": "mpf:particles=2000", "ins": {...}, "dvl": {...}}`` --
  this connection's own method and INS error model (every key optional: ``method``
  defaults to the server's, ``ins`` / ``dvl`` are a scenario's ``ins:`` and ``dvl:``
  blocks, :class:`geofix.nav.spec.InsSpec` and :class:`~geofix.nav.spec.DvlSpec`,
  without them the server's model). It starts a new navigator: an ``init`` follows.

Replies: ``{"ok": true, "type": ..., "t", "x", "y", "cov": [[..], [..]], "status", "mle",
"nis", "accepted", "pings", "rejected", "reinits"}`` (the estimate after the request:
``status`` ``converged`` only once the filter's claim is consistent with its pings --
never after one ping -- and, while ``lost``, ``x``, ``y`` and ``cov`` are the INS
fallback, the navigation plus the last good offset with the covariance grown since; the
rules are those of :mod:`geofix.navigator`;
``{"ok": true, "type": "config", "method": spec}`` to a ``config``), or
``{"ok": false, "error": "one line naming the problem"}`` (a refused ``config`` leaves
the connection's navigator as it was). A malformed or out-of-order message, or one
whose numbers lie outside physical ranges (times, positions, angles, beam offsets, a
depth beyond +-12 km or a gravity anomaly beyond +-1000 mGal), gets an error reply and
the connection stays usable; an estimate that is no longer finite is an error reply and
a new navigator (``init`` again). A line longer than ``max_line_bytes`` gets an error
reply and closes its connection; a client that disconnects mid-stream only ends its own
connection.

A server started with further maps (``geofix serve --map DEPTH --map GRAVITY``) keeps
them for every connection; without them a request with ``fields`` naming a kind is an
error reply. Messages without ``fields`` are answered as by a server of one map.

Updates run on worker threads, never on the event loop, within a time budget; the
connections, their buffered bytes, their filters' sizes and the server's memory are
bounded (:class:`geofix.server_limits.ServerLimits`); Ctrl-C and SIGTERM close every
connection and return.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import math
import signal
import threading
from collections.abc import Callable

import numpy as np
import orjson

from geofix.conventions import PHYSICAL_LIMITS
from geofix.errors import ConfigError, GeofixError, MemoryBudgetError
from geofix.maps.grid import Grid
from geofix.server_limits import (
    MAX_LINE_BYTES,
    MemoryLedger,
    RateLog,
    ServerLimits,
    UpdateWorkers,
    describe_os_error,
    descriptor_headroom,
)

READ_CHUNK = 1 << 16
REQUEST_TYPES = ("init", "nav", "ping", "estimate", "config")
MAX_ABS_TIME_S = 1e10
"""Largest ``|t|`` of a request, seconds (about 317 years: Unix and GPS times fit)."""
MAX_MISSION_S = 3.2e7
"""Largest distance of a request's ``t`` from its ``init``'s, seconds (about a year)."""
MAX_COORD_M = 1e8
"""Largest ``|x|``, ``|y|`` and ``sigma_m``, metres (2.5 times the Earth's circumference)."""
MAX_OFFSET_M = 1e5
"""Largest ``|across_m|``, ``|along_m|``, ``|down_m|`` of a beam, metres."""
MAX_ANGLE_DEG = {"heading_deg": 1e6, "roll_deg": 180.0, "pitch_deg": 180.0, "lat": 90.0}
"""Largest ``|angle|`` of each angle key, degrees (``lon``: 360)."""
VALUE_RANGES = PHYSICAL_LIMITS
"""Largest ``|value|`` of a beam on a map of each kind: metres of depth, mGal of gravity
(:data:`geofix.conventions.PHYSICAL_LIMITS`)."""


VALUE_UNITS = {"depth": "m", "gravity": "mGal", "magnetic": "nT"}
"""The unit of a beam's value on a map of each kind (for messages)."""
MAX_NOISE_VAR = 1e12
"""Largest ``noise_var`` of a further field's reading, map units squared."""
FIELD_KEYS = ("kind", "beams", "noise_var")
"""The keys of one further field's reading in a ``ping``."""


class RequestError(GeofixError):
    """A request the server answers with ``{"ok": false, "error": ...}``."""


def _reject_constant(name: str):
    raise RequestError(f"{name} is not valid JSON (use null for a missing value)")


def parse_request(line: bytes) -> dict:
    """Decode one request line into a dict with a known ``type``.

    Raises
    ------
    RequestError
        Not UTF-8, not JSON, not an object, or an unknown ``type``.
    """
    try:
        text = line.decode("utf-8")
    except UnicodeDecodeError:
        raise RequestError("request is not UTF-8 text") from None
    if not text.strip():
        raise RequestError("empty request line")
    try:
        request = orjson.loads(line)
    except orjson.JSONDecodeError:
        request = _loads_strict(text)
    return _typed(request)


def _loads_strict(text: str):
    """``json.loads`` with the server's error messages, for lines orjson refused.

    orjson (strict RFC 8259, the quicker of the two on a ping of hundreds of beams) reads
    every well-formed request; whatever it refuses is decoded again by the standard
    library, so that a ``NaN``, a huge integer or a syntax error gets the same one-line
    reply as before.
    """
    try:
        return json.loads(text, parse_constant=_reject_constant)
    except RequestError:
        raise
    except (ValueError, RecursionError) as exc:
        raise RequestError(f"request is not JSON: {str(exc).splitlines()[0][:120]}") from None


def _typed(request) -> dict:
    """``request`` if it is an object with a known ``type``; else a :class:`RequestError`."""
    if not isinstance(request, dict):
        raise RequestError("request must be a JSON object")
    kind = request.get("type")
    if not isinstance(kind, str):
        shown = "missing" if "type" not in request else f"a {type(kind).__name__}"
        raise RequestError(
            f"request type must be a string ({shown}); use {', '.join(REQUEST_TYPES)}"
        )
    if kind not in REQUEST_TYPES:
        raise RequestError(f"unknown request type {kind[:40]!r}; use {', '.join(REQUEST_TYPES)}")
    return request


def _number(request: dict, key: str, limit: float | None = None) -> float:
    """``request[key]`` as a finite float, at most ``limit`` in magnitude."""
    value = request.get(key)
    if isinstance(value, bool) or not isinstance(value, int | float):
        shown = "missing" if key not in request else type(value).__name__
        raise RequestError(f"{request['type']}: {key} must be a number ({shown})")
    try:
        out = float(value)
    except OverflowError:
        out = math.inf
    if not math.isfinite(out):
        raise RequestError(f"{request['type']}: {key} must be finite")
    if limit is not None and abs(out) > limit:
        raise RequestError(f"{request['type']}: {key} = {out:g} is beyond +-{limit:g}")
    return out


def _angle(request: dict, key: str) -> float:
    """An angle of the request, degrees, within its :data:`MAX_ANGLE_DEG` range."""
    return _number(request, key, MAX_ANGLE_DEG.get(key, 360.0))


def check_beam_ranges(beams: np.ndarray, kind: str) -> None:
    """Refuse beams whose offsets or values lie outside physical ranges.

    Parameters
    ----------
    beams : numpy.ndarray
        ``(b, 3)`` or ``(b, 4)`` beams, offsets in metres, the value last (NaN: missing).
    kind : str
        The map's kind: a depth within +-12 km, a gravity anomaly within +-1000 mGal
        (:data:`VALUE_RANGES`), a magnetic anomaly within +-100000 nT.

    Raises
    ------
    RequestError
        Names the first beam out of range.
    """
    offsets, values = beams[:, :-1], beams[:, -1]
    far = np.flatnonzero(~(np.abs(offsets) <= MAX_OFFSET_M).all(axis=1))
    if far.size:
        raise RequestError(
            f"ping: beam {int(far[0])} offset beyond +-{MAX_OFFSET_M:g} m (or not finite)"
        )
    limit = VALUE_RANGES.get(kind, math.inf)
    wild = np.flatnonzero(np.abs(values) > limit)
    if wild.size:
        unit = VALUE_UNITS.get(kind, "")
        raise RequestError(
            f"ping: beam {int(wild[0])} value {values[wild[0]]:g} is beyond +-{limit:g} {unit} "
            f"for a {kind} map"
        )


_NUMBER_OR_NULL = frozenset({int, float, type(None)})


def _beams(request: dict, max_beams: int, line: bytes | None = None) -> np.ndarray:
    beams = request.get("beams")
    if not isinstance(beams, list) or not beams:
        raise RequestError("ping: beams must be a non-empty list of [across_m, along_m, value]")
    if len(beams) > max_beams:
        raise RequestError(f"ping: {len(beams)} beams, more than max_beams = {max_beams}")
    width = len(beams[0]) if isinstance(beams[0], list) and len(beams[0]) == 4 else 3
    quick = None if line is None else _numbers_only(request, line, beams, width)
    if quick is not None:
        return quick
    try:
        return _checked_beams(beams, width)
    except OverflowError:
        raise RequestError("ping: a beam holds a number beyond the float range") from None


def _checked_beams(beams: list, width: int) -> np.ndarray:
    """``(b, width)`` beams, every row and item checked (null allowed as a value).

    The message names the first row or item that is not a number.
    """
    if (
        all(type(row) is list and len(row) == width for row in beams)
        and {type(v) for row in beams for v in row} <= _NUMBER_OR_NULL
    ):
        out = np.array(beams, dtype=float)  # null becomes NaN (offsets are checked later)
        return out
    out = np.empty((len(beams), width))
    for i, row in enumerate(beams):
        if not isinstance(row, list) or len(row) != width:
            raise RequestError(
                f"ping: beam {i} must be [across_m, along_m, value] "
                "(or [across_m, along_m, down_m, value] in every row)"
            )
        for j, v in enumerate(row):
            if v is None and j == width - 1:
                out[i, j] = np.nan
            elif isinstance(v, bool) or not isinstance(v, int | float):
                raise RequestError(f"ping: beam {i} holds a {type(v).__name__}, not a number")
            else:
                out[i, j] = v
    return out


def _numbers_only(request: dict, line: bytes, beams: list, width: int) -> np.ndarray | None:
    """The beams ``(b, width)`` read in one pass when the raw line proves them plain numbers.

    A line without ``true`` / ``false`` holds no JSON boolean, and one whose only
    quotation marks are those of its keys and of ``"ping"`` holds no other string (every
    key has at least two, so any further string shows as more); then every beam row of
    ``width`` items is numbers or nulls (null: NaN, as the checked path gives), and
    :func:`numpy.fromiter` reads them without a Python loop. Anything else (None here)
    goes through the checked path and its messages.
    """
    if b"true" in line or b"false" in line or line.count(b'"') != 2 * len(request) + 2:
        return None
    try:
        if set(map(len, beams)) != {width}:
            return None
        flat = np.fromiter(itertools.chain.from_iterable(beams), float, len(beams) * width)
    except (TypeError, ValueError, OverflowError):
        return None
    return flat.reshape(len(beams), width)


def field_readings(request: dict, kinds: tuple[str, ...], max_beams: int) -> list[dict]:
    """A ``ping``'s ``fields``: one ``{kind, beams (b, 3|4), noise_var}`` per reading, checked.

    Parameters
    ----------
    request : dict
        The ``ping`` request.
    kinds : tuple of str
        The kinds of the connection's further maps.
    max_beams : int
        Most beams of one reading.

    Returns
    -------
    list of dict
        The readings, beams as float arrays (null: NaN) and ``noise_var`` a float or a
        ``(b,)`` array, map units squared.

    Raises
    ------
    RequestError
        ``fields`` not a list of objects, an unknown key, a kind without a map or given
        twice, malformed beams or values out of range, or a ``noise_var`` that is not a
        number (or one per beam) in ``0 .. 1e12``.
    """
    fields = request["fields"]
    if not isinstance(fields, list):
        raise RequestError("ping: fields must be a list of {kind, beams, noise_var}")
    out: list[dict] = []
    for entry in fields:
        if not isinstance(entry, dict):
            raise RequestError("ping: each of fields must be an object {kind, beams, noise_var}")
        unknown = sorted(set(entry) - set(FIELD_KEYS))
        if unknown:
            raise RequestError(f"ping: a field has unknown key(s) {', '.join(unknown)[:80]}")
        kind = entry.get("kind")
        if not isinstance(kind, str) or kind not in kinds:
            shown = repr(kind[:40]) if isinstance(kind, str) else f"a {type(kind).__name__}"
            known = ", ".join(kinds) if kinds else "none: this connection has one map"
            raise RequestError(f"ping: field kind {shown} has no map here ({known})")
        if any(done["kind"] == kind for done in out):
            raise RequestError(f"ping: field {kind} given twice")
        try:
            beams = _beams({"beams": entry.get("beams")}, max_beams)
            check_beam_ranges(beams, kind)
        except RequestError as exc:
            raise RequestError(f"ping: {kind} field {str(exc).removeprefix('ping: ')}") from None
        out.append({"kind": kind, "beams": beams, "noise_var": _noise_var(entry, kind, beams)})
    return out


def _noise_var(entry: dict, kind: str, beams: np.ndarray):
    """A further field's ``noise_var``: a number or one per beam, finite, in 0 .. 1e12."""
    value = entry.get("noise_var")
    what = f"ping: {kind} field noise_var"
    if "noise_var" not in entry or value is None:
        raise RequestError(f"{what} is missing ({kind} map units squared)")
    items = value if isinstance(value, list) else [value]
    if any(isinstance(v, bool) or not isinstance(v, int | float) for v in items):
        raise RequestError(f"{what} must be a number or a list of numbers")
    if isinstance(value, list) and len(value) != beams.shape[0]:
        raise RequestError(f"{what} has {len(value)} values for {beams.shape[0]} beams")
    try:
        var = np.array(items, dtype=float)
    except OverflowError:
        var = np.array([math.inf])
    if not (np.isfinite(var).all() and (var >= 0).all() and (var <= MAX_NOISE_VAR).all()):
        raise RequestError(f"{what} must lie within 0 .. {MAX_NOISE_VAR:g}")
    return var if isinstance(value, list) else float(var[0])


def _init_kinds(request: dict, available: tuple[str, ...]) -> tuple[str, ...]:
    """The further maps' kinds an ``init`` names (every one the server has by default)."""
    if "fields" not in request:
        return available
    named = request["fields"]
    if not isinstance(named, list) or not all(isinstance(k, str) for k in named):
        raise RequestError('init: fields must be a list of map kinds, e.g. ["gravity"]')
    missing = [k[:40] for k in named if k not in available]
    if missing:
        known = ", ".join(available) if available else "none: the server has one map"
        raise RequestError(f"init: no further map of kind {', '.join(missing)} ({known})")
    if len(set(named)) != len(named):
        raise RequestError("init: fields names a kind twice")
    return tuple(k for k in available if k in named)


class Session:
    """One connection's navigator and the handling of its requests.

    Parameters
    ----------
    grid : Grid
        The map (its ``meta["projection"]`` converts ``lon`` / ``lat`` requests).
    method : str
        Recursive method spec.
    settings : dict or NavigatorSettings, optional
        Navigator settings.
    seed : int
        Seed of the connection's navigator.
    map_error : Grid, optional
        Per-cell map standard deviation.
    ins_model : InsErrorModel, optional
        The INS error model of a filter on the INS error state (``mpf``,
        ``pmf:model=errstate``; ``geofix serve --ins SCENARIO.yaml``).
    limits : ServerLimits, optional
        The server's limits (``max_points``, ``max_line_bytes``); the defaults when None.
    ledger : MemoryLedger, optional
        The server's memory ledger: a ``config`` reserves its filter's memory there
        first. Without one, the filter is checked against the memory budget alone.
    field_grids : sequence of Grid, optional
        The server's further maps (one per kind, in ``grid``'s frame): every connection
        weighs them all unless its ``init`` names fewer (``fields``).
    """

    def __init__(
        self,
        grid: Grid,
        method: str,
        settings=None,
        seed: int = 0,
        map_error=None,
        ins_model=None,
        limits: ServerLimits | None = None,
        ledger: MemoryLedger | None = None,
        field_grids=(),
    ):
        self.grid = grid
        self.limits = limits or ServerLimits()
        self.ledger = ledger
        self.field_grids = tuple(field_grids or ())
        self._defaults = (method, settings, seed, map_error, ins_model)
        self._kinds = tuple(g.kind for g in self.field_grids)  # the connection's further maps
        self._current = (method, ins_model)
        self._reserve(method)
        self.navigator = self._navigator(method, ins_model)
        self._proj: Callable[[float, float], tuple[float, float]] | None = None  # lon, lat -> x, y
        self._line = b""
        self._t0: float | None = None

    def close(self) -> None:
        """Give back this session's memory reservation."""
        if self.ledger is not None:
            self.ledger.release(id(self))

    def handle(self, line: bytes) -> dict:
        """The reply to one request line (never raises)."""
        try:
            request = parse_request(line)
            self._line = line  # the ping's raw bytes prove plain numbers (_numbers_only)
            if request["type"] == "config":
                return {"ok": True, "type": "config", "method": self._config(request)}
            estimate = getattr(self, f"_{request['type']}")(request)
            return self._finite_reply({"ok": True, "type": request["type"], **estimate.to_dict()})
        except GeofixError as exc:
            return {"ok": False, "error": str(exc).splitlines()[0] if str(exc) else "error"}
        except RecursionError:
            return {"ok": False, "error": "request nested too deeply"}
        except Exception as exc:  # a bug must not end the connection
            return {"ok": False, "error": f"internal error: {type(exc).__name__}: {exc}"[:200]}

    def _finite_reply(self, reply: dict) -> dict:
        """``reply`` if JSON can carry it; else an error, and a new navigator (see below).

        A reply with a NaN or an infinity means the navigator's state is no longer
        finite; every later reply would be the same. The connection's navigator is
        built again (same method and INS model), so the next ``init`` starts afresh.
        """
        try:
            _require_finite(reply)
            return reply
        except ValueError:
            self.navigator = self._navigator(*self._current)
            self._t0 = None
        raise RequestError(
            f"{reply['type']}: the estimate is not finite; the navigator starts again (send init)"
        )

    def _navigator(self, method, ins_model):
        from geofix.navigator import Navigator

        _, settings, seed, map_error, _ = self._defaults
        maps = [g for g in self.field_grids if g.kind in self._kinds] or None
        return Navigator(self.grid, method, settings, seed, map_error, ins_model, field_grids=maps)

    def _reserve(self, method) -> None:
        """Reserve (or check against the budget) the memory of ``method``'s filter.

        Raises
        ------
        RequestError
            More points than ``max_points``.
        MemoryBudgetError
            The server's memory budget cannot hold it (the connection keeps its reservation).
        """
        from geofix.navigator import method_size

        size = method_size(method, self._defaults[1], self.grid)
        state, update = (0.0, 0.0) if size is None else (size.state_bytes, size.update_bytes)
        if size is not None and size.points > self.limits.max_points:
            raise RequestError(
                f"{size.what}: {size.points} points, more than the server's max_points = "
                f"{self.limits.max_points}"
            )
        what = "a connection" if size is None else size.what
        if self.ledger is not None:
            self.ledger.reserve(id(self), state + self.limits.max_line_bytes, update, what)
        else:
            from geofix.memory import check_allocation

            check_allocation(state + update, what)
        self.points = 0 if size is None else size.points

    def _time(self, request: dict) -> float:
        """The request's ``t``, within :data:`MAX_ABS_TIME_S` and the mission span."""
        t = _number(request, "t", MAX_ABS_TIME_S)
        if self._t0 is not None and abs(t - self._t0) > MAX_MISSION_S:
            raise RequestError(
                f"{request['type']}: t = {t:g} s is more than {MAX_MISSION_S:g} s from the "
                f"init time {self._t0:g} s"
            )
        return t

    def _position(self, request: dict) -> tuple[float, float]:
        if "x" in request or "y" in request or "lon" not in request:
            return _number(request, "x", MAX_COORD_M), _number(request, "y", MAX_COORD_M)
        lon, lat = _angle(request, "lon"), _angle(request, "lat")
        frame = self.grid.meta.get("projection")
        if not frame:
            raise RequestError(f"{request['type']}: the map is metric; send x and y")
        if self._proj is None:
            from pyproj import Proj

            self._proj = Proj(frame)
        x, y = self._proj(lon, lat)
        return float(x), float(y)

    def _init(self, request: dict):
        t = _number(request, "t", MAX_ABS_TIME_S)
        xy = self._position(request)
        sigma = _number(request, "sigma_m", MAX_COORD_M)
        heading = _angle(request, "heading_deg") if "heading_deg" in request else 0.0
        kinds = _init_kinds(request, tuple(g.kind for g in self.field_grids))
        if kinds != self._kinds:  # another set of further maps: a navigator of those
            previous = self._kinds
            self._kinds = kinds
            try:
                self.navigator = self._navigator(*self._current)
            except BaseException:
                self._kinds = previous
                raise
        estimate = self.navigator.init(t, xy, sigma, float(np.deg2rad(heading)))
        self._t0 = t
        return estimate

    def _nav(self, request: dict):
        t = self._time(request)
        xy = self._position(request)
        heading = float(np.deg2rad(_angle(request, "heading_deg")))
        return self.navigator.motion(t, xy, heading)

    def _ping(self, request: dict):
        beams = _beams(request, self.navigator.settings.max_beams, self._line)
        check_beam_ranges(beams, self.grid.kind)
        fields = None
        if "fields" in request:
            max_beams = self.navigator.settings.max_beams
            fields = field_readings(request, self.navigator.field_kinds, max_beams)
        roll, pitch = (
            float(np.deg2rad(_angle(request, key))) if key in request else None
            for key in ("roll_deg", "pitch_deg")
        )
        t = self._time(request)
        if fields is None:
            return self.navigator.measure(t, beams, roll=roll, pitch=pitch)
        return self.navigator.measure(t, beams, roll=roll, pitch=pitch, fields=fields)

    def _estimate(self, request: dict):
        return self.navigator.estimate()

    def _config(self, request: dict) -> str:
        """A new navigator with this connection's method and INS model; its spec.

        The filter's memory is reserved before it is built: a refused ``config`` leaves
        the connection's navigator, and its reservation, as they were.
        """
        unknown = sorted(set(request) - {"type", "method", "ins", "dvl"})
        if unknown:
            raise RequestError(f"config: unknown keys {', '.join(unknown)[:80]}")
        method, _, _, _, ins_model = self._defaults
        method = request.get("method", method)
        if not isinstance(method, str) or not method:
            raise RequestError("config: method must be a method specification string")
        if "ins" in request or "dvl" in request:
            ins_model = _ins_model(request.get("ins"), request.get("dvl"))
        previous = self._current
        try:
            self._reserve(method)
        except MemoryBudgetError as exc:
            raise RequestError(f"config: {str(exc).splitlines()[0]}") from None
        try:
            self.navigator = self._navigator(method, ins_model)
        except BaseException:
            self._reserve(previous[0])  # the old navigator keeps its reservation
            raise
        self._current = (method, ins_model)
        self._t0 = None
        return method


def _ins_model(ins, dvl):
    """The INS error model of a ``config`` request's ``ins`` and ``dvl`` objects."""
    from pydantic import ValidationError

    from geofix.nav.errstate import InsErrorModel
    from geofix.nav.spec import DvlSpec, InsSpec

    if not isinstance(ins, dict) or not (dvl is None or isinstance(dvl, dict)):
        raise RequestError("config: ins must be an object (and dvl an object or absent)")
    try:
        ins_spec = InsSpec.model_validate(ins)
        dvl_spec = None if dvl is None else DvlSpec.model_validate(dvl)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(part) for part in first["loc"])
        raise RequestError(f"config: {where}: {first['msg']}"[:200]) from None
    return InsErrorModel.from_specs(ins_spec, dvl_spec)


async def _lines(reader: asyncio.StreamReader, max_bytes: int = MAX_LINE_BYTES):
    """Yield request lines; a line longer than ``max_bytes`` yields ``None`` and ends.

    No more than ``max_bytes`` plus one read are ever held for the connection: a line
    (with or without its newline) beyond the limit is refused, and the caller closes the
    connection rather than read on.
    """
    buffer = bytearray()
    while True:
        chunk = await reader.read(READ_CHUNK)
        if not chunk:
            return
        buffer += chunk
        while True:
            cut = buffer.find(b"\n")
            if (cut < 0 and len(buffer) > max_bytes) or cut > max_bytes:
                yield None
                return
            if cut < 0:
                break
            line = bytes(buffer[:cut])
            del buffer[: cut + 1]
            yield line


def _encode(reply: dict) -> bytes:
    """One reply line; a reply that is not valid JSON (a NaN) becomes an error reply.

    orjson writes it (it would write a NaN as null, so the numbers are checked first).
    """
    try:
        _require_finite(reply)
        return orjson.dumps(reply, option=orjson.OPT_APPEND_NEWLINE)
    except (TypeError, ValueError, orjson.JSONEncodeError) as exc:
        text = json.dumps({"ok": False, "error": f"internal error: reply not JSON ({exc})"})
    return (text + "\n").encode()


def _require_finite(value) -> None:
    """Raise ValueError on a NaN or infinite float anywhere in a reply."""
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError("Out of range float values are not JSON compliant")
    elif isinstance(value, dict):
        for item in value.values():
            _require_finite(item)
    elif isinstance(value, list | tuple):
        for item in value:
            _require_finite(item)


def _error_line(message: str) -> bytes:
    return orjson.dumps({"ok": False, "error": message}, option=orjson.OPT_APPEND_NEWLINE)


OVERSIZED = {"ok": False, "error": f"request line longer than {MAX_LINE_BYTES} bytes"}


class NavigatorServer:
    """The asyncio TCP server: :meth:`start`, then :meth:`stop` (or ``serve_forever``).

    Every connection's requests are handled one at a time, in order, on
    :class:`~geofix.server_limits.UpdateWorkers` threads, never on the event loop: a
    connection whose update takes seconds holds one worker, and the others keep
    answering. ``limits`` (:class:`~geofix.server_limits.ServerLimits`) bounds the
    connections, each connection's buffered bytes and filter size, the memory of all of
    them together (:class:`~geofix.server_limits.MemoryLedger`) and the time of one
    update. Trouble that is not a client's request (a refused connection, the
    file-descriptor limit) is logged as one line per cause, at most once per
    ``limits.log_interval_s`` (:class:`~geofix.server_limits.RateLog`).

    Parameters
    ----------
    grid : Grid
        The map (its ``meta["projection"]`` converts ``lon`` / ``lat`` requests).
    method : str
        Recursive method spec, every connection's until its ``config``.
    settings : dict or NavigatorSettings, optional
        Navigator settings.
    seed : int
        Seed of the connections' navigators.
    map_error : Grid, optional
        Per-cell map standard deviation, map units.
    ins_model : InsErrorModel, optional
        The INS error model of a filter on the INS error state (``mpf``,
        ``pmf:model=errstate``).
    limits : ServerLimits, optional
        Connections, buffered bytes, filter sizes, memory and update time; the defaults
        when None.
    log : callable, optional
        Called as ``log(cause, detail)`` for trouble that is not a client's request
        (default: a :class:`~geofix.server_limits.RateLog` on standard error).
    field_grids : sequence of Grid, optional
        Further maps (one per kind other than ``grid``'s, in its frame) whose readings a
        ``ping`` may carry (``fields``).
    """

    def __init__(
        self,
        grid,
        method,
        settings=None,
        seed=0,
        map_error=None,
        ins_model=None,
        limits: ServerLimits | None = None,
        log=None,
        field_grids=(),
    ) -> None:
        self.grid, self.method, self.settings = grid, method, settings
        self.field_grids = tuple(field_grids or ())
        self.seed, self.map_error, self.ins_model = seed, map_error, ins_model
        self.limits = limits or ServerLimits()
        self.log = log or RateLog(self.limits.log_interval_s)
        threads = self.limits.workers + self.limits.heavy_workers
        self.ledger = MemoryLedger(float(self.limits.budget()), threads)
        self.max_connections = self._connection_cap()
        # refuse a bad method or setting (or a missing INS model, or a size over the
        # limits) now; its reservation is given back at once
        self._session().close()
        self._server: asyncio.base_events.Server | None = None
        self._workers: UpdateWorkers | None = None
        self._heavy: UpdateWorkers | None = None
        self._tasks: set[asyncio.Task] = set()
        self.connections = 0

    def _connection_cap(self) -> int:
        """``max_connections``, lowered to what the file-descriptor limit allows."""
        headroom = descriptor_headroom()
        cap = self.limits.max_connections
        if headroom is not None and headroom < cap:
            self.log(
                "max_connections lowered by the file-descriptor limit (ulimit -n)",
                f"{cap} -> {headroom}",
            )
            cap = headroom
        return cap

    @property
    def active(self) -> int:
        """Connections open now."""
        return len(self._tasks)

    def _session(self) -> Session:
        return Session(
            self.grid,
            self.method,
            self.settings,
            self.seed,
            self.map_error,
            self.ins_model,
            self.limits,
            self.ledger,
            self.field_grids,
        )

    async def start(self, host: str = "127.0.0.1", port: int = 0) -> int:
        """Listen on ``host:port`` (0: any free port); return the port.

        Raises
        ------
        ConfigError
            An empty host, a port outside 0-65535, or an address that cannot be bound
            (in use, not this machine's).
        """
        check_address(host, port)
        loop = asyncio.get_running_loop()
        loop.set_exception_handler(self._loop_error)
        self._workers = UpdateWorkers(self.limits.workers)
        self._heavy = UpdateWorkers(
            self.limits.heavy_workers, "geofix-heavy-update", self.limits.heavy_nice
        )
        try:
            self._server = await asyncio.start_server(self._serve, host, port)
        except OSError as exc:
            self._workers.shutdown()
            self._heavy.shutdown()
            raise ConfigError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
        return int(self._server.sockets[0].getsockname()[1])

    async def stop(self) -> None:
        """Stop listening, close every connection and stop the update threads."""
        if self._server is not None:
            self._server.close()
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        if self._server is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._server.wait_closed(), 5.0)
        for workers in (self._workers, self._heavy):
            if workers is not None:
                workers.shutdown()

    def _loop_error(self, loop, context: dict) -> None:
        """The event loop's errors (a failed ``accept`` at the descriptor limit): one line."""
        exc = context.get("exception")
        cause = str(context.get("message") or "event loop error").split(";")[0]
        detail = describe_os_error(exc) if exc is not None else ""
        self.log(cause, detail)

    async def _serve(self, reader, writer) -> None:
        task = asyncio.current_task()
        if task is not None:
            self._tasks.add(task)
        try:
            await self._connection(reader, writer)
        except asyncio.CancelledError:
            pass  # the server is stopping: the connection just closes
        except Exception as exc:  # never a traceback: one line per cause
            self.log("connection ended by an error", describe_os_error(exc))
        finally:
            self._tasks.discard(task)  # type: ignore[arg-type]
            writer.close()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(writer.wait_closed(), 1.0)

    async def _connection(self, reader, writer) -> None:
        if self.active > self.max_connections:
            self.log("connection refused", f"max_connections = {self.max_connections}")
            writer.write(_error_line(f"server busy: max_connections = {self.max_connections}"))
            return
        try:
            session = self._session()
        except GeofixError as exc:
            self.log("connection refused", str(exc).splitlines()[0])
            writer.write(_error_line(f"server busy: {str(exc).splitlines()[0]}"))
            return
        self.connections += 1
        try:
            await self._requests(reader, writer, session)
        except (ConnectionError, asyncio.IncompleteReadError):
            pass  # the client went away: only this connection ends
        finally:
            session.close()

    async def _requests(self, reader, writer, session: Session) -> None:
        async for line in _lines(reader, self.limits.max_line_bytes):
            if line is None:
                limit = self.limits.max_line_bytes
                writer.write(_error_line(f"request line longer than {limit} bytes; closing"))
                await _linger(reader, writer)
                return
            reply, session = await self._update(session, line)
            writer.write(_encode(reply))
            await writer.drain()

    async def _update(self, session: Session, line: bytes) -> tuple[dict, Session]:
        """The reply to ``line`` from a worker thread, within the update time budget.

        An update still running after ``update_timeout_s`` gets an error reply; it is
        left to finish on its own (its memory stays reserved until then) and the
        connection goes on with a new navigator.
        """
        lane = self._heavy if session.points > self.limits.heavy_points else self._workers
        assert lane is not None
        future = lane.submit(session.handle, line)
        try:
            reply = await asyncio.wait_for(
                asyncio.shield(asyncio.wrap_future(future)), self.limits.update_timeout_s
            )
            return reply, session
        except TimeoutError:
            future.add_done_callback(lambda _: session.close())
        budget = self.limits.update_timeout_s
        message = f"update took longer than update_timeout_s = {budget:g} s"
        try:
            fresh = self._session()
        except GeofixError as exc:
            raise ConnectionError(str(exc)) from None  # closes this connection
        return {"ok": False, "error": f"{message}; the navigator starts again (send init)"}, fresh


async def _linger(reader, writer, seconds: float = 1.0) -> None:
    """Send what is written, then read and drop input for up to ``seconds``.

    Closing a socket with unread input resets it, and the client may lose the reply
    still on its way; reading on a little first lets the last reply arrive.
    """
    await writer.drain()
    with contextlib.suppress(OSError, RuntimeError):
        if writer.can_write_eof():
            writer.write_eof()
    deadline = asyncio.get_running_loop().time() + seconds
    with contextlib.suppress(TimeoutError, OSError):
        while (left := deadline - asyncio.get_running_loop().time()) > 0:
            if not await asyncio.wait_for(reader.read(READ_CHUNK), left):
                return


def check_address(host, port) -> None:
    """Refuse a host that would silently mean every interface, or a port out of range.

    Raises
    ------
    ConfigError
        ``host`` empty (give ``0.0.0.0`` or ``::`` to listen on every interface), or
        ``port`` not an integer in 0-65535.
    """
    if not isinstance(host, str) or not host.strip():
        raise ConfigError(
            f"host {host!r} would listen on every interface; give 0.0.0.0 (or ::) to mean "
            "that, or an address such as 127.0.0.1"
        )
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
        raise ConfigError(f"port {port!r} is not a TCP port (0 to 65535; 0: any free port)")


def serve(
    grid,
    method,
    host="127.0.0.1",
    port=7010,
    settings=None,
    seed=0,
    map_error=None,
    ins_model=None,
    limits: ServerLimits | None = None,
    announce: Callable[[str, int], None] | None = None,
    field_grids=(),
) -> None:
    """Run the server until Ctrl-C or SIGTERM (``geofix serve``); prints nothing itself.

    A bad method or setting (or ``mpf`` without ``ins_model``), a bad address or one
    that cannot be bound raises before ``announce(host, port)`` is called with the port
    actually bound (a port of 0 picks a free one). A Ctrl-C or SIGTERM closes every
    connection and returns normally.

    Parameters
    ----------
    grid : Grid
        The map (its ``meta["projection"]`` converts ``lon`` / ``lat`` requests).
    method : str
        Recursive method spec, every connection's until its ``config``.
    host : str
        Address to listen on (``0.0.0.0`` or ``::`` for every interface).
    port : int
        TCP port, 0 to 65535 (0: any free port).
    settings : dict or NavigatorSettings, optional
        Navigator settings.
    seed : int
        Seed of the connections' navigators.
    map_error : Grid, optional
        Per-cell map standard deviation, map units.
    ins_model : InsErrorModel, optional
        The INS error model of a filter on the INS error state (``mpf``,
        ``pmf:model=errstate``).
    limits : ServerLimits, optional
        Connections, buffered bytes, filter sizes, memory and update time; the defaults
        when None.
    announce : callable, optional
        Called as ``announce(host, port)`` once the server listens, with the port bound.
    field_grids : sequence of Grid, optional
        Further maps (one per kind other than ``grid``'s, in its frame) whose readings a
        ``ping`` may carry (``fields``).

    Raises
    ------
    ConfigError
        A bad method or setting (or ``mpf`` without ``ins_model``), a bad address or one
        that cannot be bound.
    MemoryBudgetError
        A filter larger than the memory budget.
    """
    check_address(host, port)
    server = NavigatorServer(
        grid, method, settings, seed, map_error, ins_model, limits, field_grids=field_grids
    )

    async def main():
        bound = await server.start(host, port)
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
                loop.add_signal_handler(sig, stop.set)
        if announce is not None:
            announce(host, bound)
        try:
            await stop.wait()
        finally:
            await server.stop()

    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(main())


@contextlib.contextmanager
def serve_in_thread(
    grid,
    method,
    host="127.0.0.1",
    settings=None,
    seed=0,
    map_error=None,
    ins_model=None,
    limits: ServerLimits | None = None,
    log=None,
    field_grids=(),
):
    """Run a server on a free port in a background thread; yields ``(host, port)``.

    The server and its thread stop when the ``with`` block ends.

    Parameters
    ----------
    grid : Grid
        The map (its ``meta["projection"]`` converts ``lon`` / ``lat`` requests).
    method : str
        Recursive method spec, every connection's until its ``config``.
    host : str
        Address to listen on.
    settings : dict or NavigatorSettings, optional
        Navigator settings.
    seed : int
        Seed of the connections' navigators.
    map_error : Grid, optional
        Per-cell map standard deviation, map units.
    ins_model : InsErrorModel, optional
        The INS error model of a filter on the INS error state (``mpf``,
        ``pmf:model=errstate``).
    limits : ServerLimits, optional
        Connections, buffered bytes, filter sizes, memory and update time; the defaults
        when None.
    log : callable, optional
        Called as ``log(cause, detail)`` for trouble that is not a client's request
        (default: a :class:`~geofix.server_limits.RateLog` on standard error).
    field_grids : sequence of Grid, optional
        Further maps (one per kind other than ``grid``'s, in its frame) whose readings a
        ``ping`` may carry (``fields``).

    Yields
    ------
    tuple of (str, int)
        ``(host, port)`` the server listens on.
    """
    loop = asyncio.new_event_loop()
    server = NavigatorServer(
        grid, method, settings, seed, map_error, ins_model, limits, log, field_grids
    )
    port = loop.run_until_complete(server.start(host, 0))
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    try:
        yield host, port
    finally:
        asyncio.run_coroutine_threadsafe(server.stop(), loop).result(timeout=10)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(timeout=10)
        loop.close()
