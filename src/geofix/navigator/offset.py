"""The navigator's common offset: when a ping teaches it, and what an estimate reports.

The offset itself (measured minus map, a random walk ``N(b, P)``) is a state of the
measurement model the filter loop steps (:class:`geofix.filters.loop.FilterStepper`,
:class:`geofix.filters.nuisance.CommonOffset`), in a campaign trial as on line. What the
navigator adds is when a multibeam ping updates the offset's mean:

A ping of fewer than three beams always does: alone it says nothing of the position's
shape, and the offset is what links it to the next. A ping of several beams tells the
position by its shape whatever the offset (its likelihood is marginalised over the
offset's variance); it updates the offset only while the navigator reports
``converged`` (at the ping before): learning the offset from it while the position is
uncertain along a slope lets the two trade against each other and the covariance claim
what neither has. Where no status is reported (a campaign trial) such pings never update
it: each is marginalised over the offset's prior.
"""

from __future__ import annotations

from geofix.filters.base import Observation
from geofix.filters.loop import FilterStepper


class OffsetEstimator:
    """The common offset of a navigator's filter loop, learnt as the navigator's status allows.

    Parameters
    ----------
    stepper : FilterStepper
        The filter loop that carries the offset.
    """

    def __init__(self, stepper: FilterStepper) -> None:
        self._stepper = stepper
        self.settled = False  # the last ping's status was converged

    def learn(self, relative: Observation, weighed: Observation, prior) -> None:
        """After an accepted ping: the nuisance states, the offset as the status allows.

        Parameters
        ----------
        relative, weighed : Observation
            The ping relative to the offset, and with the residual scale too.
        prior : tuple of numpy.ndarray
            ``(mean (2,), covariance (2, 2))`` before the ping, metres and m^2.
        """
        self._stepper.learn(relative, weighed, prior, settled=self.settled)

    def judged(self, status: str) -> None:
        """The status of the ping just taken (a multibeam ping next learns if converged)."""
        self.settled = status == "converged"

    def fields(self) -> dict:
        """``depth_bias`` and ``depth_bias_std`` of an estimate (none while inactive)."""
        offset = self._stepper.offset
        if not offset.active:
            return {}
        return {"depth_bias": offset.mean, "depth_bias_std": offset.std}


__all__ = ["OffsetEstimator"]
