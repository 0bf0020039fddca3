"""The memory a recursive filter will need, from its settings, before it is built.

A grid or particle filter's memory grows with its points (the nodes of ``pmf``, the
particles of ``pf`` and ``mpf``) times the beams of each update: the predicted map
values, their residuals and likelihood terms are ``(points, beams)`` arrays. The
estimate is split in two parts:

- ``state_bytes``, kept between updates (the points, their weights, the map's
  representation-error layer of a filter whose ``map_model`` is not ``exact``);
- ``update_bytes``, the temporaries of one update, freed when it returns.

The constants are measured, not derived: :mod:`tracemalloc` peaks of a navigator's
``init`` and three ``motion`` / ``measure`` steps on a 600 x 600 cell map, at 20 000 and
80 000 particles (101 x 101 to 301 x 301 nodes) and 8 and 64 beams, fitted as
``points * (a + b * beams)`` once the map layer's six copies are taken off (the
process's peak resident size agrees with them). A filter that carries an offset per
hypothesis (``map_model=imperfect``, or a ``depth_bias_std`` other than 0; by default on
every ping) keeps each hypothesis's offset at two walk rates in ``(points, beams)``
arrays, one marginalised over a common offset (``offset_per_hypothesis=false``) half as
many. Otherwise the
likelihood is one compiled pass and the per-beam part is small. Each constant here is
the fit plus a margin, so the estimate is an upper bound at the sizes that matter.

:func:`check_filter_budget` refuses, against :func:`geofix.memory.check_allocation`, a
filter whose peak would exceed the memory budget; :class:`geofix.Navigator` calls it
before its filter holds a point (so every ``geofix replay`` method), and ``geofix serve``
reserves each connection's size in its ledger before a ``config``
(:func:`geofix.navigator.method_size` takes a method spec).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from geofix.maps.grid import Grid
from geofix.memory import check_allocation, format_bytes

OFFSET_BEAM_BYTES = 44.0
"""Bytes per point and beam of one update marginalised over one common offset."""
HYPOTHESIS_OFFSET_BEAM_BYTES = 88.0
"""Bytes per point and beam of one update carrying the offset per hypothesis.

Each hypothesis's own offset at two walk rates (the default on every ping): measured
74 B (``pf``, 80 000 particles) and 82 B (``pmf``, 201 x 201 nodes) per point and beam
at 8 and 64 beams, fitted with the points' own part; ``mpf`` is taken at the same.
"""
BEAM_BYTES = 8.0
"""Bytes per point and beam of one update otherwise."""
UPDATE_POINT_BYTES = {"pf": 96.0, "mpf": 192.0, "pmf": 112.0}
"""Bytes per point of one update beyond the per-beam part, by filter family."""
STATE_POINT_BYTES = {"pf": 48.0, "mpf": 128.0, "pmf": 48.0}
"""Bytes per point kept between updates, by filter family."""
STATE_BEAM_BYTES = {"pf": 0.0, "mpf": 0.0, "pmf": 0.0}
"""Bytes per point and beam kept between updates (none measured once compiled)."""
MAP_LAYER_COPIES = 6
"""Float copies of the map while its representation-error layer is computed (one kept)."""


@dataclass(frozen=True)
class FilterSize:
    """The estimated memory of one navigator's filter.

    Parameters
    ----------
    what : str
        The filter and its size, for messages (``"pf with 2000000 particles x 64 beams"``).
    points : int
        Most points (particles or grid nodes) the filter may hold.
    state_bytes : float
        Bytes kept between updates.
    update_bytes : float
        Bytes of one update's temporaries (freed when it returns).
    """

    what: str
    points: int
    state_bytes: float
    update_bytes: float

    @property
    def peak_bytes(self) -> float:
        """Bytes while an update runs: the state plus the update's temporaries."""
        return self.state_bytes + self.update_bytes


@runtime_checkable
class SizedFilter(Protocol):
    """A filter whose memory this module estimates: it declares its most points."""

    map_model: str

    def memory_points(self) -> tuple[str, int]:
        """``(family, most points)``: ``pf``, ``mpf`` or ``pmf`` and its particles or nodes."""
        ...


def filter_points(filt) -> tuple[str, int] | None:
    """The family (``pf``, ``mpf``, ``pmf``) and most points of a filter; None if neither.

    ``pf`` and ``mpf`` hold at most ``max_particles`` particles, ``pmf`` at most
    ``max_points`` x ``max_points`` nodes (after any regrid): each declares it
    (:class:`SizedFilter`). Filters of another family (``sitan``, a bank of EKFs) are not
    sized here.
    """
    if not isinstance(filt, SizedFilter):
        return None
    kind, points = filt.memory_points()
    return (kind, int(points)) if kind in UPDATE_POINT_BYTES else None


def update_beams(settings, beams: int | None = None) -> int:
    """Beams of one update: ``max_update_beams`` (at most ``max_beams``), at most ``beams``.

    Without ``max_update_beams`` (every beam of a ping, a campaign's filter) and without
    ``beams`` the filter is sized for one beam: a ping's own beams are checked when it
    arrives (:func:`geofix.measurement` checks its hypotheses times beams).
    """
    limit = settings.max_update_beams
    if limit is None and beams is None:
        return 1
    most = int(settings.max_beams if limit is None else min(limit, settings.max_beams))
    return most if beams is None else max(1, min(most, int(beams)))


def filter_size(filt, settings=None, grid: Grid | None = None, beams: int | None = None):
    """The :class:`FilterSize` of a filter under navigator settings; None if not sized.

    Parameters
    ----------
    filt : RecursiveFilter
        The filter (its settings: ``max_particles`` or ``max_points``, ``map_model``).
    settings : NavigatorSettings or dict, optional
        The navigator's settings (``max_update_beams``, ``max_beams``, and
        ``representation_error``); the defaults when None.
    grid : Grid, optional
        The map: with it, a filter whose ``map_model`` is not ``exact`` (or settings with
        ``representation_error``) also counts the map's representation-error layer.
    beams : int, optional
        Most beams of a ping (a log's widest ping); None: as many as the settings allow.

    Returns
    -------
    FilterSize or None
    """
    from geofix.filters.loop import FilterSettings as NavigatorSettings
    from geofix.filters.loop import offset_per_hypothesis

    family = filter_points(filt)
    if family is None:
        return None
    kind, points = family
    if not isinstance(settings, NavigatorSettings):
        settings = NavigatorSettings.from_dict(settings)
    b = update_beams(settings, beams)
    map_model = str(filt.map_model)
    offset = map_model == "imperfect" or settings.depth_bias_std != 0
    per_beam = BEAM_BYTES
    if offset:
        per_beam = (
            HYPOTHESIS_OFFSET_BEAM_BYTES
            if offset_per_hypothesis(filt, settings)
            else OFFSET_BEAM_BYTES
        )
    state = float(points) * (STATE_POINT_BYTES[kind] + STATE_BEAM_BYTES[kind] * b)
    update = float(points) * (UPDATE_POINT_BYTES[kind] + per_beam * b)
    if grid is not None and (map_model != "exact" or settings.representation_error):
        cells = float(grid.values.size) * 8.0
        state += cells
        update = max(update, cells * (MAP_LAYER_COPIES - 1))
    unit = "particles" if kind in ("pf", "mpf") else "nodes"
    return FilterSize(f"{kind} with {points} {unit} x {b} beams", points, state, update)


def check_filter_budget(filt, settings=None, grid: Grid | None = None, beams=None):
    """Refuse a filter that would exceed the memory budget; its size otherwise.

    Called before a navigator's filter holds any point (:class:`geofix.Navigator` at
    construction, so ``geofix replay`` and ``geofix serve``), so nothing of the filter is
    allocated when it is refused; :func:`geofix.navigator.check_method_budget` takes a
    method spec.

    Parameters
    ----------
    filt : RecursiveFilter
        The filter (:class:`SizedFilter` to be sized).
    settings : FilterSettings or dict, optional
        The navigator's filter settings; the defaults when None.
    grid : Grid, optional
        The map (for the representation-error layer).
    beams : int, optional
        Most beams of a ping; None: as many as the settings allow.

    Returns
    -------
    FilterSize or None
        None for a filter that is not sized here (``sitan``, ``sitan-bank``).

    Raises
    ------
    MemoryBudgetError
        ``"pf with 2000000 particles x 64 beams would need 5.2 GiB; memory budget ..."``.
    """
    size = filter_size(filt, settings, grid, beams)
    if size is not None:
        check_allocation(size.peak_bytes, size.what)
    return size


def describe(size: FilterSize) -> str:
    """``"pf with 5000 particles x 64 beams (12.3 MiB)"``, for logs and messages."""
    return f"{size.what} ({format_bytes(size.peak_bytes)})"
