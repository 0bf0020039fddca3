"""A small blocking client of ``geofix serve`` (newline-delimited JSON over TCP).

>>> with Client("127.0.0.1", 7010) as nav:                      # doctest: +SKIP
...     nav.init(t=0.0, x=100.0, y=200.0, sigma_m=500.0)
...     nav.nav(t=1.0, x=104.0, y=203.0, heading_deg=45.0)
...     reply = nav.ping(t=1.0, beams=[[-50.0, 0.0, -1203.4], [50.0, 0.0, -1199.8]])
...     reply["x"], reply["y"], reply["cov"], reply["status"]

With a gravimeter beside the echosounder (a server started with a gravity map too), a
ping carries its readings as ``fields``::

    nav.ping(t=2.0, beams=[[0.0, 0.0, -1201.0]],
             fields=[{"kind": "gravity", "beams": [[0.0, 0.0, 23.4]], "noise_var": 0.25}])

Every method sends one request and returns its one reply as a dict; a reply with
``"ok": false`` raises :class:`ServerError` unless ``check=False``. Floats are sent with
Python's shortest exact representation, so the server sees the very numbers given.
"""

from __future__ import annotations

import contextlib
import json
import math
import socket

import numpy as np
import orjson

from geofix.errors import GeofixError


class ServerError(GeofixError):
    """The server answered ``{"ok": false, "error": ...}``."""


class Client:
    """One connection (one navigator) to a ``geofix serve`` server.

    Parameters
    ----------
    host : str
        Server address.
    port : int
        Server port.
    timeout : float
        Seconds to wait for a reply.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 7010, timeout: float = 30.0):
        self._sock = socket.create_connection((host, port), timeout=timeout)
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._file = self._sock.makefile("rwb")

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Close the connection (the server drops its navigator)."""
        for part in (self._file, self._sock):
            with contextlib.suppress(OSError):
                part.close()

    def send_line(self, line: bytes) -> dict:
        """Send one raw line (a newline is added) and return the reply.

        Raises
        ------
        ServerError
            The connection is closed or broken (the reply the server sent before closing
            it, if any, is returned instead).
        """
        try:
            self._file.write(line.rstrip(b"\n") + b"\n")
            self._file.flush()
        except OSError as exc:
            with contextlib.suppress(ServerError):
                return self.read_reply()  # e.g. the refusal of an oversized line
            raise ServerError(f"the connection failed: {exc}") from None
        return self.read_reply()

    def read_reply(self) -> dict:
        """Read one reply line.

        Raises
        ------
        ServerError
            The server closed the connection, it broke, or no reply came in time.
        """
        try:
            reply = self._file.readline()
        except TimeoutError:
            raise ServerError("no reply within the client's timeout") from None
        except OSError as exc:
            raise ServerError(f"the connection failed: {exc}") from None
        if not reply:
            raise ServerError("the server closed the connection")
        return orjson.loads(reply)

    def request(self, message: dict, check: bool = True) -> dict:
        """Send one request object and return its reply.

        Raises
        ------
        ValueError
            A number in ``message`` is NaN or infinite (not JSON).
        """
        return self._checked(self.send_line(json.dumps(message, allow_nan=False).encode()), check)

    def _checked(self, reply: dict, check: bool = True) -> dict:
        if check and not reply.get("ok"):
            raise ServerError(str(reply.get("error")))
        return reply

    def init(
        self, t: float, x: float, y: float, sigma_m: float, heading_deg=None, fields=None, **kw
    ):
        """``init``: start the navigator at ``(x, y)`` metres with a prior ``sigma_m``.

        Parameters
        ----------
        t : float
            Time, seconds.
        x, y : float
            Initial position east / north in the map's frame, metres.
        sigma_m : float
            1-sigma of the initial position, metres.
        heading_deg : float, optional
            Heading, degrees clockwise from north (the server assumes 0 without it).
        fields : list of str, optional
            The kinds of the server's further maps this connection weighs (``[]``: the
            primary map alone; the server's every further map without it).
        check : bool, optional
            Keyword; ``False`` returns an ``"ok": false`` reply instead of raising.

        Returns
        -------
        dict
            The reply: the estimate after the request.

        Raises
        ------
        ServerError
            The server refused the request (with ``check``) or the connection failed.
        """
        msg = {"type": "init", "t": float(t), "x": float(x), "y": float(y)}
        msg["sigma_m"] = float(sigma_m)
        if heading_deg is not None:
            msg["heading_deg"] = float(heading_deg)
        if fields is not None:
            msg["fields"] = [str(kind) for kind in fields]
        return self.request(msg, **kw)

    def nav(self, t: float, x: float, y: float, heading_deg: float, **kw) -> dict:
        """``nav``: the INS-indicated position (metres, the map's frame) and heading.

        Parameters
        ----------
        t : float
            Time, seconds.
        x, y : float
            INS-indicated position east / north in the map's frame, metres.
        heading_deg : float
            Heading, degrees clockwise from north.
        check : bool, optional
            Keyword; ``False`` returns an ``"ok": false`` reply instead of raising.

        Returns
        -------
        dict
            The reply: the estimate after the request.

        Raises
        ------
        ServerError
            The server refused the request (with ``check``) or the connection failed.
        """
        msg = {"type": "nav", "t": float(t), "x": float(x), "y": float(y)}
        msg["heading_deg"] = float(heading_deg)
        return self.request(msg, **kw)

    def ping(self, t: float, beams, roll_deg=None, pitch_deg=None, fields=None, **kw) -> dict:
        """``ping``: level beams ``(b, 3)``, or body-frame ``(b, 4)`` with the attitude.

        Parameters
        ----------
        t : float
            Time, seconds.
        beams : array_like
            ``(b, 3)`` rows ``(across_m, along_m, value)`` or ``(b, 4)`` rows
            ``(across_m, along_m, down_m, value)``: offsets in metres, values in map
            units; a NaN value (missing beam) goes as null.
        roll_deg, pitch_deg : float, optional
            Vehicle attitude, degrees.
        fields : list of dict, optional
            The further fields' readings of the ping, each ``{"kind": KIND, "beams":
            rows, "noise_var": var}`` (rows as ``beams``, in that map's units; ``var``
            that map's units squared, a number or one per beam).
        check : bool, optional
            Keyword; ``False`` returns an ``"ok": false`` reply instead of raising.

        Returns
        -------
        dict
            The reply: the estimate after the ping.

        Raises
        ------
        ValueError
            Beams of another shape, or a non-finite time, offset or attitude.
        ServerError
            The server refused the request (with ``check``) or the connection failed.
        """
        message = ping_message(t, beams, roll_deg, pitch_deg, as_array=True, fields=fields)
        # orjson writes the array itself (NaN as null), ten times faster than json on
        # hundreds of beams; ping_message has refused every other non-finite number.
        line = orjson.dumps(message, option=orjson.OPT_SERIALIZE_NUMPY)
        return self._checked(self.send_line(line), **kw)

    def estimate(self, **kw) -> dict:
        """``estimate``: the current estimate."""
        return self.request({"type": "estimate"}, **kw)

    def config(self, method: str | None = None, ins=None, dvl=None, **kw) -> dict:
        """``config``: this connection's own method and INS model (a new navigator).

        Parameters
        ----------
        method : str, optional
            Method specification (e.g. ``"mpf:particles=2000"``); the server's without it.
        ins, dvl : dict, optional
            A scenario's ``ins:`` / ``dvl:`` blocks; keys left out keep the server's.
        check : bool, optional
            Keyword; ``False`` returns an ``"ok": false`` reply instead of raising.

        Returns
        -------
        dict
            The reply, ``{"ok": true, "type": "config", "method": spec}``.

        Raises
        ------
        ServerError
            The server refused the request (with ``check``) or the connection failed.
        """
        message: dict = {"type": "config"}
        for key, value in (("method", method), ("ins", ins), ("dvl", dvl)):
            if value is not None:
                message[key] = value
        return self.request(message, **kw)


def ping_message(
    t: float, beams, roll_deg=None, pitch_deg=None, as_array=False, fields=None
) -> dict:
    """The ``ping`` request for beams ``(b, 3)`` or ``(b, 4)`` (NaN values become null).

    Parameters
    ----------
    t : float
        Time, seconds.
    beams : array_like
        ``(b, 3)`` rows ``(across_m, along_m, value)`` or ``(b, 4)`` rows
        ``(across_m, along_m, down_m, value)``: offsets in metres, values in map units.
    roll_deg, pitch_deg : float, optional
        Vehicle attitude, degrees (left out of the request when None).
    as_array : bool
        Keep the beams a C-contiguous float64 array (NaN values kept) for
        ``orjson.dumps(..., option=orjson.OPT_SERIALIZE_NUMPY)``, which writes NaN as
        null; otherwise nested lists with NaN values as None.
    fields : list of dict, optional
        The further fields' readings, each ``{"kind", "beams", "noise_var"}``: their
        beams go as ``beams`` do, ``noise_var`` as a number or a list (map units squared).

    Returns
    -------
    dict
        The request object.

    Raises
    ------
    ValueError
        Beams of another shape, or a non-finite time, offset or attitude (of any field).
    """
    rows = _rows(beams, as_array)
    attitude = {
        k: v for k, v in (("roll_deg", roll_deg), ("pitch_deg", pitch_deg)) if v is not None
    }
    numbers = [float(t), *(float(v) for v in attitude.values())]
    if not all(map(math.isfinite, numbers)):
        raise ValueError("ping: t, the attitude and the beam offsets must be finite")
    message = {
        "type": "ping",
        "t": float(t),
        "beams": rows,
        **{k: float(v) for k, v in attitude.items()},
    }
    if fields is not None:
        message["fields"] = [_field(entry, as_array) for entry in fields]
    return message


def _field(entry: dict, as_array: bool) -> dict:
    """One further field's reading as the request carries it."""
    if not isinstance(entry, dict) or not {"kind", "beams", "noise_var"} <= set(entry):
        raise ValueError("ping: each field must be a dict with kind, beams and noise_var")
    var = entry["noise_var"]
    var = float(var) if np.ndim(var) == 0 else [float(v) for v in np.ravel(var)]
    return {**entry, "beams": _rows(entry["beams"], as_array), "noise_var": var}


def _rows(beams, as_array: bool):
    """Beams ``(b, 3)`` or ``(b, 4)`` as the request carries them (NaN values: null)."""
    array = np.asarray(beams, dtype=float)
    if array.ndim != 2 or array.shape[1] not in (3, 4):
        raise ValueError(
            f"ping: beams must be (b, 3) across_m, along_m, value or (b, 4) across_m, "
            f"along_m, down_m, value; got {array.shape}"
        )
    if not np.isfinite(array[:, :-1]).all():
        raise ValueError("ping: t, the attitude and the beam offsets must be finite")
    if as_array:
        return np.ascontiguousarray(array)
    rows = array.tolist()
    last = array.shape[1] - 1
    for i in np.flatnonzero(~np.isfinite(array[:, last])):
        rows[i][last] = None
    return rows
