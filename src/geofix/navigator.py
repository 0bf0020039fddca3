"""``geofix.Navigator``: an online terrain-aided navigator around any recursive filter.

Usage (``grid`` a :class:`~geofix.maps.grid.Grid`; positions in metres, headings in
radians)::

    nav = Navigator(grid, method="pmf", settings={"noise_std": 2.0}, seed=1)
    nav.init(t=0.0, position=(x0, y0), sigma_m=500.0)
    nav.motion(t, position=(x, y), heading=psi)       # the INS pose
    est = nav.measure(t, beams)                       # (b, 3) across_m, along_m, value
    est.position, est.covariance, est.mle, est.status, est.nis

The method is any registered recursive filter by name or spec (``"pmf"``, ``"pf"``,
``"sitan"``, ``"pmf:points=41"``, and every filter added to the registry later on the
same per-step protocol). The filters on the INS error state (``"mpf"``,
``"pmf:model=errstate"``) also need the INS error model, ``ins_model`` (an
:class:`~geofix.nav.errstate.InsErrorModel`, e.g. ``InsErrorModel.from_specs(spec)`` of
a scenario's ``ins:`` block); its position prior is replaced by ``init``'s sigma.

The time step itself, gating, statuses and re-initialisation live in
:class:`geofix.filters.online.OnlineFilter`, which also runs every campaign trial
(:func:`geofix.filters.base.run_filter`). ``est.status`` is ``converged`` only when the
filter's own consistency supports its covariance (several pings, their NIS in range, a
steady fix, a resolved posterior: :meth:`~geofix.filters.online.OnlineFilter.consistency`);
while ``lost`` the estimate is the INS fallback (:meth:`~Navigator.fallback`), the
navigation plus the last good offset with the covariance grown since.
"""

from __future__ import annotations

import numpy as np

from geofix.errors import ConfigError
from geofix.filters.online import STATUSES, Estimate, NavigatorSettings, OnlineFilter
from geofix.filters.sizing import FilterSize, check_filter_budget, filter_size
from geofix.maps.grid import Grid


class Navigator(OnlineFilter):
    """An online navigator on ``grid`` with a named recursive filter.

    Parameters
    ----------
    grid : Grid
        The map (metric frame).
    method : str or filter
        A registered recursive method name or spec (``"pmf"``, ``"pf:particles=2000"``,
        ``"sitan"``, ...), or a filter instance.
    settings : NavigatorSettings or dict, optional
        The navigator's rules (:class:`~geofix.filters.online.NavigatorSettings`).
    seed : int or numpy.random.Generator
        Seed of the generator behind every random draw (same seed, same inputs: the
        same estimates, bit for bit).
    map_error : Grid, optional
        Per-cell map standard deviation (the ``z_std`` layer of ``geofix grid``).
    ins_model : InsErrorModel, optional
        The INS error model (:mod:`geofix.nav.errstate`): required by a filter on the INS
        error state (``mpf``, ``pmf:model=errstate``), ignored by the others.

    Raises
    ------
    ConfigError
        Unknown method or setting, a batch matcher instead of a recursive filter, or a
        filter that needs an INS error model without one.
    """

    def __init__(
        self, grid: Grid, method="pmf", settings=None, seed=0, map_error=None, ins_model=None
    ) -> None:
        from geofix.methods import parse_method_spec

        filt = parse_method_spec(method) if isinstance(method, str) else method
        if not getattr(filt, "recursive", False):
            raise ConfigError(
                f"navigator: method {getattr(filt, 'name', method)!r} is a batch matcher; "
                "use a recursive filter (pmf, pf, sitan, ...)"
            )
        if getattr(filt, "needs_ins_model", False) and ins_model is None:
            raise ConfigError(
                f"navigator: method {method if isinstance(method, str) else filt.name!r} "
                "needs an INS error model (ins_model; for geofix replay / serve: "
                "--ins SCENARIO.yaml with an ins: block)"
            )
        if not isinstance(settings, NavigatorSettings):
            settings = NavigatorSettings.from_dict(settings)
        check_filter_budget(filt, settings, grid)  # before the filter holds a point
        rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        super().__init__(filt, grid, settings, rng, map_error, ins_model)
        self.method = method if isinstance(method, str) else filt.name


def method_size(method, settings=None, grid: Grid | None = None, beams=None) -> FilterSize | None:
    """:func:`geofix.filters.sizing.filter_size` of a method spec or filter instance.

    Parameters
    ----------
    method : str or filter
        ``"pf:particles=2000"``, or a filter.
    settings : NavigatorSettings or dict, optional
        The navigator's settings.
    grid : Grid, optional
        The map (for the representation-error layer of ``map_model`` other than exact).
    beams : int, optional
        Most beams of a ping.

    Raises
    ------
    ConfigError
        An unknown method or setting.
    """
    from geofix.methods import parse_method_spec

    filt = parse_method_spec(method) if isinstance(method, str) else method
    return filter_size(filt, settings, grid, beams)


def check_method_budget(method, settings=None, grid: Grid | None = None, beams=None):
    """:func:`geofix.filters.sizing.check_filter_budget` of a method spec or filter.

    Raises
    ------
    ConfigError
        An unknown method or setting.
    MemoryBudgetError
        The filter would exceed the memory budget (the message gives the estimate).
    """
    from geofix.methods import parse_method_spec

    filt = parse_method_spec(method) if isinstance(method, str) else method
    return check_filter_budget(filt, settings, grid, beams)


__all__ = ["STATUSES", "Estimate", "Navigator", "NavigatorSettings"]
