"""``geofix serve``: the navigator over TCP, newline-delimited JSON (asyncio).

One :class:`geofix.Navigator` per connection; every request line gets exactly one reply
line, in order. Requests (UTF-8 JSON objects, one per line, at most
:data:`MAX_LINE_BYTES` bytes):

- ``{"type": "init", "t": s, "x": m, "y": m, "sigma_m": m}`` (optional ``heading_deg``);
- ``{"type": "nav", "t": s, "x": m, "y": m, "heading_deg": deg}`` -- the INS-indicated
  position in the map's metric frame (``lon`` / ``lat`` in degrees instead of ``x`` /
  ``y`` when the map was projected from lon/lat);
- ``{"type": "ping", "t": s, "beams": [[across_m, along_m, value], ...]}`` (``value``
  null for a missing beam), or rows ``[across_m, along_m, down_m, value]`` of body-frame
  beam vectors; optional ``roll_deg`` / ``pitch_deg`` (the vehicle attitude, levelling
  body-frame beams and the mounting offset: ``geofix.sensors.attitude``);
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
rules are those of :mod:`geofix.filters.online`;
``{"ok": true, "type": "config", "method": spec}`` to a ``config``), or
``{"ok": false, "error": "one line naming the problem"}`` (a refused ``config`` leaves
the connection's navigator as it was). A malformed, out-of-order or
oversized message gets an error reply and the connection stays usable; a client that
disconnects mid-stream only ends its own connection.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import math
import threading
from collections.abc import Callable

import numpy as np
import orjson

from geofix.errors import GeofixError
from geofix.maps.grid import Grid

MAX_LINE_BYTES = 1 << 20
"""Longest request line, bytes (1 MiB: about 30 000 beams of three numbers)."""
READ_CHUNK = 1 << 16
REQUEST_TYPES = ("init", "nav", "ping", "estimate", "config")


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

    orjson (strict RFC 8259, about ten times faster on a ping of hundreds of beams) reads
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
    if kind not in REQUEST_TYPES:
        raise RequestError(
            f"unknown request type {str(kind)[:40]!r}; use {', '.join(REQUEST_TYPES)}"
        )
    return request


def _number(request: dict, key: str) -> float:
    value = request.get(key)
    if isinstance(value, bool) or not isinstance(value, int | float):
        shown = "missing" if key not in request else type(value).__name__
        raise RequestError(f"{request['type']}: {key} must be a number ({shown})")
    out = float(value)
    if not math.isfinite(out):
        raise RequestError(f"{request['type']}: {key} must be finite")
    return out


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
    """

    def __init__(
        self, grid: Grid, method: str, settings=None, seed: int = 0, map_error=None, ins_model=None
    ):
        from geofix.navigator import Navigator

        self.navigator = Navigator(grid, method, settings, seed, map_error, ins_model)
        self.grid = grid
        self._defaults = (method, settings, seed, map_error, ins_model)
        self._proj: Callable[[float, float], tuple[float, float]] | None = None  # lon, lat -> x, y
        self._line = b""

    def handle(self, line: bytes) -> dict:
        """The reply to one request line (never raises)."""
        try:
            request = parse_request(line)
            self._line = line  # the ping's raw bytes prove plain numbers (_numbers_only)
            if request["type"] == "config":
                return {"ok": True, "type": "config", "method": self._config(request)}
            estimate = getattr(self, f"_{request['type']}")(request)
            return {"ok": True, "type": request["type"], **estimate.to_dict()}
        except GeofixError as exc:
            return {"ok": False, "error": str(exc).splitlines()[0] if str(exc) else "error"}
        except Exception as exc:  # a bug must not end the connection
            return {"ok": False, "error": f"internal error: {type(exc).__name__}: {exc}"[:200]}

    def _position(self, request: dict) -> tuple[float, float]:
        if "x" in request or "y" in request or "lon" not in request:
            return _number(request, "x"), _number(request, "y")
        lon, lat = _number(request, "lon"), _number(request, "lat")
        frame = self.grid.meta.get("projection")
        if not frame:
            raise RequestError(f"{request['type']}: the map is metric; send x and y")
        if self._proj is None:
            from pyproj import Proj

            self._proj = Proj(frame)
        x, y = self._proj(lon, lat)
        return float(x), float(y)

    def _init(self, request: dict):
        t = _number(request, "t")
        xy = self._position(request)
        sigma = _number(request, "sigma_m")
        heading = _number(request, "heading_deg") if "heading_deg" in request else 0.0
        return self.navigator.init(t, xy, sigma, float(np.deg2rad(heading)))

    def _nav(self, request: dict):
        t = _number(request, "t")
        xy = self._position(request)
        heading = float(np.deg2rad(_number(request, "heading_deg")))
        return self.navigator.motion(t, xy, heading)

    def _ping(self, request: dict):
        beams = _beams(request, self.navigator.settings.max_beams, self._line)
        roll, pitch = (
            float(np.deg2rad(_number(request, key))) if key in request else None
            for key in ("roll_deg", "pitch_deg")
        )
        return self.navigator.measure(_number(request, "t"), beams, roll=roll, pitch=pitch)

    def _estimate(self, request: dict):
        return self.navigator.estimate()

    def _config(self, request: dict) -> str:
        """A new navigator with this connection's method and INS model; its spec."""
        from geofix.navigator import Navigator

        unknown = sorted(set(request) - {"type", "method", "ins", "dvl"})
        if unknown:
            raise RequestError(f"config: unknown keys {', '.join(unknown)[:80]}")
        method, settings, seed, map_error, ins_model = self._defaults
        method = request.get("method", method)
        if not isinstance(method, str) or not method:
            raise RequestError("config: method must be a method specification string")
        if "ins" in request or "dvl" in request:
            ins_model = _ins_model(request.get("ins"), request.get("dvl"))
        self.navigator = Navigator(self.grid, method, settings, seed, map_error, ins_model)
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


async def _lines(reader: asyncio.StreamReader):
    """Yield request lines; an oversized line yields ``None`` once (its bytes dropped)."""
    buffer = bytearray()
    dropping = False
    while True:
        chunk = await reader.read(READ_CHUNK)
        if not chunk:
            return
        buffer += chunk
        while True:
            cut = buffer.find(b"\n")
            if cut < 0:
                if len(buffer) > MAX_LINE_BYTES:
                    dropping = True
                    buffer.clear()
                break
            line = bytes(buffer[:cut])
            del buffer[: cut + 1]
            if dropping or len(line) > MAX_LINE_BYTES:
                dropping = False
                yield None
            else:
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


OVERSIZED = {"ok": False, "error": f"request line longer than {MAX_LINE_BYTES} bytes"}


class NavigatorServer:
    """The asyncio TCP server: :meth:`start`, then :meth:`stop` (or ``serve_forever``)."""

    def __init__(self, grid, method, settings=None, seed=0, map_error=None, ins_model=None) -> None:
        self.grid, self.method, self.settings = grid, method, settings
        self.seed, self.map_error, self.ins_model = seed, map_error, ins_model
        # refuse a bad method or setting (or a missing INS model) now
        Session(grid, method, settings, seed, map_error, ins_model)
        self._server: asyncio.base_events.Server | None = None
        self.connections = 0

    async def start(self, host: str = "127.0.0.1", port: int = 0) -> int:
        """Listen on ``host:port`` (0: any free port); return the port."""
        self._server = await asyncio.start_server(self._serve, host, port)
        return int(self._server.sockets[0].getsockname()[1])

    async def stop(self) -> None:
        """Stop listening and close the server."""
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()

    async def _serve(self, reader, writer) -> None:
        self.connections += 1
        session = Session(
            self.grid, self.method, self.settings, self.seed, self.map_error, self.ins_model
        )
        try:
            async for line in _lines(reader):
                reply = OVERSIZED if line is None else session.handle(line)
                writer.write(_encode(reply))
                await writer.drain()
        except (ConnectionError, asyncio.IncompleteReadError):
            pass  # the client went away: only this connection ends
        finally:
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()


def serve(
    grid, method, host="127.0.0.1", port=7010, settings=None, seed=0, map_error=None, ins_model=None
):
    """Run the server until interrupted (``geofix serve``); prints nothing itself.

    A bad method or setting (or ``mpf`` without ``ins_model``) raises before listening.
    """
    server = NavigatorServer(grid, method, settings, seed, map_error, ins_model)

    async def main():
        await server.start(host, port)
        await asyncio.Event().wait()

    asyncio.run(main())


@contextlib.contextmanager
def serve_in_thread(
    grid, method, host="127.0.0.1", settings=None, seed=0, map_error=None, ins_model=None
):
    """Run a server on a free port in a background thread; yields ``(host, port)``.

    The server and its thread stop when the ``with`` block ends.
    """
    loop = asyncio.new_event_loop()
    server = NavigatorServer(grid, method, settings, seed, map_error, ins_model)
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
