"""The free INS as a method: no matching at all, the yardstick every method must beat."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from geofix.problem import Fix, MatchProblem


@dataclass(frozen=True)
class FreeIns:
    """The INS alone: the estimate is the indicated track, never corrected.

    Run over the whole mission (``recursive``), it gives the error a vehicle would have
    without any map matching, with the INS model's own prior as its covariance, so a
    campaign can put every method beside it.

    Examples
    --------
    >>> import geofix
    >>> scen = geofix.load_scenario("builtin:azores_demo")
    >>> grid = geofix.prepare_map(scen)
    >>> trial = geofix.simulate_trial(scen, grid, 0)
    >>> fix = geofix.FreeIns().match(trial.problem(grid), np.random.default_rng(0))
    >>> bool((fix.track == trial.indicated).all())
    True
    """

    name: ClassVar[str] = "ins"
    recursive: ClassVar[bool] = True

    def match(self, problem: MatchProblem, rng: np.random.Generator | None = None) -> Fix:
        """Return the indicated track with the prior ``sigma_position`` as covariance."""
        sigma = float(problem.sigma_position[-1])
        return Fix(
            track=np.array(problem.indicated, dtype=float),
            covariance=np.eye(2) * sigma**2,
            diagnostics={"sigma_m": np.asarray(problem.sigma_position, float)},
        )
