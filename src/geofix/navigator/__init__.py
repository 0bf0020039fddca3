"""The online navigator: :class:`Navigator` around any recursive filter.

- :mod:`~geofix.navigator.core` -- :class:`Navigator` (the raw inputs, the two steps,
  statuses, re-initialisation), :func:`method_size`, :func:`check_method_budget`;
- :mod:`~geofix.navigator.settings` -- :class:`NavigatorSettings`, :data:`STATUSES` and
  the constants of the rules;
- :mod:`~geofix.navigator.intake` -- raw pings and navigation records checked;
- :mod:`~geofix.navigator.health` -- NIS, the consistency of ``converged``, the lost
  rules and the INS fallback;
- :mod:`~geofix.navigator.offset` -- when the common offset learns;
- :mod:`~geofix.navigator.estimate` -- :class:`Estimate`, the answer after an input.

The filter, its state and the measurement model's nuisance states are stepped by the
filter loop of the filters layer (:class:`geofix.filters.loop.FilterStepper`), as in
every campaign trial.
"""

from geofix.filters.nuisance import unscented_points
from geofix.navigator.core import Navigator, check_method_budget, method_size, start_problem
from geofix.navigator.estimate import Estimate
from geofix.navigator.health import innovation_nis, nis_limit, normalised_move
from geofix.navigator.settings import STATUSES, NavigatorSettings

__all__ = [
    "STATUSES",
    "Estimate",
    "Navigator",
    "NavigatorSettings",
    "check_method_budget",
    "innovation_nis",
    "method_size",
    "nis_limit",
    "normalised_move",
    "start_problem",
    "unscented_points",
]
