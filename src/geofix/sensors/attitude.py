"""Beam geometry under vehicle attitude: body-frame beam vectors to level footprint offsets.

A beam (or the sensor's mounting point) is a body-frame vector ``(across, along, down)``
metres: starboard, forward, down (:mod:`geofix.conventions`). The vehicle's roll ``phi``
(positive starboard down) and pitch ``theta`` (positive bow up), radians, turn it into
the level frame by the aerospace rotation sequence (heading, then pitch, then roll, from
level to body; Titterton & Weston, *Strapdown Inertial Navigation Technology*, 2nd ed.,
2004, section 3.6): in forward-starboard-down axes ``v_level = R_y(theta) R_x(phi)
v_body``. Heading is applied afterwards to the level ``(across, along)`` by the
measurement model (:func:`geofix.problem.footprint_xy`), as for every other offset.

Examples: a nadir beam of slant range ``r`` under a roll ``phi`` lands ``r sin phi`` to
*port* (``-r sin phi`` across) at depth ``r cos phi``; under a pitch ``theta`` it lands
``r sin theta`` ahead.
"""

from __future__ import annotations

import numpy as np


def attitude_matrix(roll: float, pitch: float) -> np.ndarray:
    """``(3, 3)`` rotation of body ``(across, along, down)`` vectors to the level frame.

    Parameters
    ----------
    roll, pitch : float
        Radians; roll positive starboard down, pitch positive bow up.

    Returns
    -------
    numpy.ndarray
        ``M`` with ``level = M @ body``, both ordered ``(across, along, down)``.
    """
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    # forward-starboard-down: R_y(pitch) @ R_x(roll)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    fsd = ry @ rx
    order = [1, 0, 2]  # (across, along, down) <-> (forward, starboard, down)
    return fsd[np.ix_(order, order)]


def level_offsets(body, roll: float = 0.0, pitch: float = 0.0, mount=None) -> np.ndarray:
    """Level-frame ``(across, along, down)`` of body-frame beam vectors, metres.

    Parameters
    ----------
    body : array_like
        ``(b, 3)`` beam vectors ``(across, along, down)`` from the sensor, metres.
    roll, pitch : float
        Vehicle attitude, radians (see :func:`attitude_matrix`).
    mount : array_like, optional
        The sensor's position on the vehicle, body ``(across, along[, down])`` metres from
        the navigation reference point; rotated with the beams and added to them.

    Returns
    -------
    numpy.ndarray
        ``(b, 3)`` level-frame offsets from the navigation reference point (the first two
        columns are the horizontal footprint offsets, before heading).
    """
    body = np.asarray(body, dtype=float).reshape(-1, 3)
    if mount is not None:
        lever = np.zeros(3)
        m = np.asarray(mount, dtype=float).ravel()
        lever[: m.size] = m
        body = body + lever
    return body @ attitude_matrix(float(roll), float(pitch)).T


__all__ = ["attitude_matrix", "level_offsets"]
