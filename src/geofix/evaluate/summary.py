"""Typed campaign results: :class:`MethodStats` per method and the :class:`CampaignSummary`.

Both are frozen values with ``to_json()`` giving exactly the objects of the public JSON
contract (``geofix run --json`` and ``summary.json``): the keys below are relied on by
outside scripts and are only ever extended. ``from_json`` reads them back (unknown keys
are kept in ``more``, so a summary written by a newer geofix still loads).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class MethodStats:
    """Statistics of one method over a campaign's trials (errors in metres).

    Failed trials (the method raised) are left out of every error statistic but count in
    ``trials`` and as not successful in ``success_rate``. ``None`` marks a value that is
    undefined (no successful trial, say).

    Parameters
    ----------
    trials : int
        Trials run, failed ones included.
    mean_error_m, std_error_m, median_error_m, max_error_m : float or None
        End-point error statistics (population std), metres.
    mean_track_error_m, max_track_error_m : float or None
        Mean over trials of the mean along-track error, and its maximum, metres.
    success_rate : dict
        Share of trials with an end error within ``"20"`` ... ``"100"`` metres and
        ``"0.5c"`` ... ``"3c"`` map cells.
    mean_time_s : float or None
        Seconds per ``match`` call.
    failures : int
        Trials on which the method raised.
    false_fix_rate : float or None
        Share of trials ending more than 3 cells off, not flagged and outside the
        method's own 3-sigma ellipse.
    ambiguous_rate : float or None
        Share of trials the method flagged ambiguous.
    mean_evaluations : float or None
        Map look-ups or candidate scores per trial.
    leg_mean_errors_m : list
        Mean end error of every leg, metres.
    rms_error_m : float or None
        End-point RMS error over the trials that did not fail, metres (to compare with
        the campaign's ``crlb_m``).
    nees : float or None
        Mean normalised estimation error squared of the end point against the method's
        own covariance (about 2 for a consistent 2-D estimate).
    track_rms_error_m : float or None
        RMS error along the track, over samples and trials, metres (to compare with
        ``crlb_track_m``).
    more : dict
        Keys this version does not know (read back from a newer file).
    """

    trials: int
    mean_error_m: float | None = None
    std_error_m: float | None = None
    median_error_m: float | None = None
    max_error_m: float | None = None
    mean_track_error_m: float | None = None
    max_track_error_m: float | None = None
    success_rate: dict[str, float | None] = field(default_factory=dict)
    mean_time_s: float | None = None
    failures: int = 0
    false_fix_rate: float | None = None
    ambiguous_rate: float | None = None
    mean_evaluations: float | None = None
    leg_mean_errors_m: list[float | None] = field(default_factory=list)
    rms_error_m: float | None = None
    nees: float | None = None
    track_rms_error_m: float | None = None
    more: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """The contract's JSON object of this method (plain Python values)."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "more"}
        out["success_rate"] = dict(self.success_rate)
        out["leg_mean_errors_m"] = list(self.leg_mean_errors_m)
        return {**out, **self.more}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> MethodStats:
        """Read :meth:`to_json`'s object back."""
        return _from_json(cls, data)


@dataclass(frozen=True)
class CampaignSummary:
    """The summary of a campaign: its bounds and every method's statistics.

    Parameters
    ----------
    scenario : str
        Scenario name.
    trials : int
        Number of trials.
    crlb_m : float or None
        Cramér–Rao bound on the end-point RMS error, metres (see
        :mod:`geofix.evaluate.crlb`).
    crlb_batch_m : float or None
        The same for a rigid batch fix of the last leg (None where singular).
    crlb_track_m : float or None
        The bound on the RMS error along the track (over samples and trials), metres.
    crlb_rw_m : float or None
        The bound of a random-walk position error on the end-point RMS error, metres.
    valid_bound_m, valid_bound_track_m : float or None
        The valid bound on the end-point RMS error and on the RMS error along the track,
        metres (:func:`geofix.evaluate.bounds.valid_bound`): in the JSON object only for a
        campaign that computed it (``run_campaign(..., valid_bound=True)``).
    methods : dict
        ``{spec: MethodStats}`` in the order the methods were given.
    more : dict
        Keys this version does not know (read back from a newer file).

    Examples
    --------
    >>> s = CampaignSummary("demo", 2, crlb_m=10.0, methods={"tercom": MethodStats(trials=2)})
    >>> s.to_json()["methods"]["tercom"]["trials"]
    2
    >>> CampaignSummary.from_json(s.to_json()) == s
    True
    """

    scenario: str
    trials: int
    crlb_m: float | None = None
    crlb_batch_m: float | None = None
    crlb_track_m: float | None = None
    crlb_rw_m: float | None = None
    valid_bound_m: float | None = None
    valid_bound_track_m: float | None = None
    methods: dict[str, MethodStats] = field(default_factory=dict)
    more: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """The contract's JSON object (``geofix run --json``, ``summary.json``)."""
        head = {
            "scenario": self.scenario,
            "trials": self.trials,
            "crlb_m": self.crlb_m,
            "crlb_track_m": self.crlb_track_m,
            "crlb_rw_m": self.crlb_rw_m,
            "crlb_batch_m": self.crlb_batch_m,
        }
        for key in ("valid_bound_m", "valid_bound_track_m"):
            if getattr(self, key) is not None:
                head[key] = getattr(self, key)
        methods = {spec: stats.to_json() for spec, stats in self.methods.items()}
        return {**head, **self.more, "methods": methods}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> CampaignSummary:
        """Read :meth:`to_json`'s object back."""
        methods = {k: MethodStats.from_json(v) for k, v in data.get("methods", {}).items()}
        return _from_json(cls, {**data, "methods": methods})


def _from_json(cls, data: dict[str, Any]):
    known = {f.name for f in dataclasses.fields(cls)} - {"more"}
    kwargs = {k: v for k, v in data.items() if k in known}
    more = {k: v for k, v in data.items() if k not in known}
    return cls(**kwargs, more=more)
