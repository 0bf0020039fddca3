"""The further fields of a particle set: their hypothesis offsets and their summed update.

Shared by the particle and the marginalised particle filters, whose states differ only in
where they keep their points (``particles`` or ``positions``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from geofix.filters.base import Observation
from geofix.filters.hypothesis_offset import shared_offsets
from geofix.maps.grid import Grid


def field_offset(state, field: int):
    """Further field ``field``'s hypothesis offsets of a state (None without any)."""
    return state.field_offsets[field] if field < len(state.field_offsets) else None


def taken_offsets(field_offsets: tuple, index) -> tuple:
    """Every further field's hypothesis offsets of the hypotheses ``index``."""
    return tuple(None if o is None else o.take(index) for o in field_offsets)


def started_offsets(filt, state, fields) -> tuple:
    """Every further field's hypothesis offsets, started at its first ping that asks for one.

    A field's offset is carried per hypothesis when the filter carries offsets and its
    ping says so (``bias_per_hypothesis``, the stepper's choice for pings of fewer than
    three beams); None otherwise.
    """
    out = list(state.field_offsets) + [None] * (len(fields) - len(state.field_offsets))
    for i, (field_obs, _) in enumerate(fields):
        if out[i] is None and filt.carries_offset and np.isfinite(field_obs.values).any():
            out[i] = filt.started_offset(state.log_weight.shape, field_obs)
    return tuple(out)


def update_particle_fields(
    filt, state, obs: Observation, grid: Grid, rng, fields, points: Callable
):
    """The primary ping (when it has a value) and every further field's, summed.

    Parameters
    ----------
    filt
        The particle or marginalised particle filter (its ``likelihood``,
        ``progressive`` correction, ``carries_offset`` and ``_spread_copies``).
    state
        Its state (``log_weight``, ``spacing``, ``cell``, ``offset``, ``field_offsets``).
    obs : Observation
        The primary field's ping.
    grid : Grid
        The primary field's map.
    rng : numpy.random.Generator
        Draws of the progressive correction.
    fields : sequence of (Observation, Grid)
        Every further field's ping and map.
    points : callable
        ``points(state)``: the ``(M, 2)`` positions of the set, metres.

    Returns
    -------
    state
        The updated state, with every field's hypothesis offsets learnt.
    """
    primary = bool(np.isfinite(obs.values).any())
    valid = [bool(np.isfinite(o.values).any()) for o, _ in fields]
    if not (primary or any(valid)):
        return state
    if primary and filt.carries_offset and state.offset is None:
        state = replace(
            state,
            offset=filt.started_offset(state.log_weight.shape, obs),
        )
    state = replace(state, field_offsets=started_offsets(filt, state, fields))
    model = filt.likelihood

    def likelihood(current) -> np.ndarray:
        total = np.zeros(current.log_weight.shape)
        at = points(current)
        if primary:
            total = total + model.particles(
                grid, obs, at, current.spacing, current.cell, current.offset, rng
            )
        for i, (field_obs, field_grid) in enumerate(fields):
            if valid[i]:
                total = total + model.particles(
                    field_grid,
                    field_obs,
                    at,
                    current.spacing,
                    field_grid.cell_size,
                    current.field_offsets[i],
                    rng,
                )
        return total

    state, reads = filt.progressive.apply(state, likelihood, filt._spread_copies, rng)
    at = points(state)
    if primary and state.offset is not None:
        state = replace(state, offset=state.offset.updated(grid, at, obs))
    learnt = tuple(
        o if o is None or not ok else o.updated(g, at, fo)
        for o, ok, (fo, g) in zip(state.field_offsets, valid, fields, strict=True)
    )
    return shared_offsets(
        replace(state, evaluations=state.evaluations + reads, field_offsets=learnt)
    )
