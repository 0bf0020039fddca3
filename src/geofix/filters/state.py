"""What every recursive filter's state offers its readers: the typed state protocol.

A filter's state is its own immutable dataclass (a point-mass grid, a particle set, a
marginalised particle set, one or a bank of extended Kalman filters). Readers outside the
filter -- the navigator's estimate and convergence tests, the KL divergence of
:mod:`geofix.filters.convergence` -- see it through :class:`FilterState`:

- ``moments()``: the posterior mean ``(2,)`` and covariance ``(2, 2)``, metres and m^2;
- ``mode()``: the position ``(2,)`` of the highest weight, metres (a Kalman filter's
  mean);
- ``points()``: the weighted posterior points, ``(positions (n, 2), log_weight (n,))``
  (a grid's nodes, the particles), or None for a state without any (a Kalman filter);
- ``node_area()``: the area of one point's cell, m^2, for a grid's nodes, None for a
  random sample (particles) or a state without points.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class FilterState(Protocol):
    """The posterior of a recursive filter as its readers see it."""

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean ``(2,)`` and covariance ``(2, 2)``, metres and m^2."""
        ...

    def mode(self) -> np.ndarray:
        """Position ``(2,)`` of the highest weight, metres."""
        ...

    def points(self) -> tuple[np.ndarray, np.ndarray] | None:
        """``(positions (n, 2), log_weight (n,))`` of the weighted posterior, or None."""
        ...

    def node_area(self) -> float | None:
        """Area of one point's cell, m^2 (a grid's nodes); None for a sample or no points."""
        ...


class SteppedFilter(Protocol):
    """What the plain filter loop reads of a recursive filter besides its steps.

    The steps themselves (``initialize``, ``predict``, ``update``, ``estimate``) differ in
    their state types from filter to filter and are called as they are.

    :class:`geofix.filters.base.RecursiveFilter` declares each with its default.
    """

    map_model: str

    @property
    def fuses_fields(self) -> bool:
        """The filter weighs further fields beside the primary one."""
        ...

    @property
    def carries_offset(self) -> bool:
        """Each point of the state carries its own common offset."""
        ...

    def mode(self, state) -> np.ndarray:
        """The position ``(2,)`` the filter reports as its most likely one, metres."""
        ...


def mode_position(filt, state) -> np.ndarray:
    """MLE position ``(2,)`` of a filter state, metres.

    The filter's own ``mode(state)`` when it defines one
    (:meth:`~geofix.filters.mpf.Mpf.mode`: the weighted mean); else the state's
    :meth:`FilterState.mode`; a state outside the protocol gives the filter's estimated
    mean.

    Parameters
    ----------
    filt : RecursiveFilter
        The filter of the state.
    state : FilterState
        Its current state.
    """
    return np.asarray(filt.mode(state), dtype=float)


def state_mode(filt, state) -> np.ndarray:
    """The state's own :meth:`FilterState.mode`, else the filter's estimated mean (metres).

    Parameters
    ----------
    filt : RecursiveFilter
        The filter of the state.
    state : FilterState
        Its current state.
    """
    if isinstance(state, FilterState):
        return np.asarray(state.mode(), dtype=float)
    return np.asarray(filt.estimate(state)[0], dtype=float)


__all__ = ["FilterState", "SteppedFilter", "mode_position", "state_mode"]
