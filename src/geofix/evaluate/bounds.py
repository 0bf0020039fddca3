"""Per-trial bounds of a campaign: the Cramér–Rao bounds and the valid bound.

Every trial of a campaign is stored with its :class:`TrialInfo` (:func:`trial_info`):
the error-state, random-walk and batch Cramér–Rao bounds (:mod:`geofix.evaluate.crlb`)
and the true end point. A campaign asked for the *valid bound* also stores, per trial
and sample, the larger of the error-state CRLB and the Ziv–Zakai bound
(:mod:`geofix.evaluate.zzb`) and the genie's squared error
(:mod:`geofix.evaluate.ambiguity`), all three under the simulator's own prior of the
start error (its spread about the known offset): the bound that holds for any estimator
on the trials. :func:`valid_bound` reduces them over the trials, sample by sample: the
larger of the mean of the CRLB-or-ZZB and the genie's mean squared error (a trial whose
genie grid no longer resolves the posterior counting 0), at the end point and as an RMS
along the track.

:func:`bound_tracks` gives the same terms with either prior, for studies of the bounds
themselves (``benchmarks/sections/_bounds.py``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from geofix.evaluate.ambiguity import genie_track
from geofix.evaluate.crlb import (
    bound_track,
    rms_bound,
    scenario_beam_variance,
    trial_beam_variance,
    trial_crlb,
)
from geofix.evaluate.zzb import combined_track_bound, zzb_track
from geofix.maps.grid import Grid

#: The two priors of the start error, by key suffix: the CRLB's and the filters' (zero
#: mean, the simulator's second moments), and (``_simulator``) the simulator's own.
PRIORS = {"": False, "_simulator": True}
#: The prior of the valid bound: the simulator's own distribution of the start error.
VALID_PRIOR = "_simulator"


@dataclass(frozen=True)
class TrialInfo:
    """Per-trial facts stored beside the results.

    Parameters
    ----------
    index : int
        Trial number.
    crlb_var_m2 : float
        Trace of the error-state CRLB at the last sample, m^2.
    crlb_batch_var_m2 : float
        ``trace(J^-1)`` of the batch CRLB of the last leg, m^2 (``inf`` if singular).
    truth_end : tuple of float
        True position at the last sample, metres.
    crlb_track_var_m2 : float
        Trace of the error-state CRLB averaged along the track, m^2.
    crlb_rw_var_m2 : float
        Trace of the random-walk CRLB at the last sample, m^2.
    valid_track_m2 : numpy.ndarray or None
        ``(n,)`` the larger of the error-state CRLB and the ZZB at every sample, under the
        simulator's prior of the start error, m^2 (None: not computed).
    genie_track_m2 : numpy.ndarray or None
        ``(n,)`` the genie's squared error at every sample under that prior, m^2 (NaN
        where its grid no longer resolves the posterior; None: not computed).
    """

    index: int
    crlb_var_m2: float
    crlb_batch_var_m2: float
    truth_end: tuple[float, float]
    crlb_track_var_m2: float = float("nan")
    crlb_rw_var_m2: float = float("nan")
    valid_track_m2: np.ndarray | None = field(default=None, compare=False)
    genie_track_m2: np.ndarray | None = field(default=None, compare=False)

    @property
    def has_valid_bound(self) -> bool:
        """True when the valid bound's terms were computed for this trial."""
        return self.valid_track_m2 is not None and self.genie_track_m2 is not None


def trial_info(scenario, grid: Grid, trial, valid: bool = False) -> TrialInfo:
    """The CRLBs (per-beam sensor plus map-error variance) and true end point of a trial.

    Parameters
    ----------
    scenario : Scenario
        The trial's scenario (its sensor's per-beam variance).
    grid : Grid
        The map the trial was simulated on.
    trial : Trial
        The simulated trial.
    valid : bool
        Also compute the valid bound's terms (:func:`valid_bound_terms`; the ZZB and the
        genie cost far more than the CRLBs).

    Returns
    -------
    TrialInfo
        Variances in m^2, the end point in metres.
    """
    bound = trial_crlb(trial, grid, scenario_beam_variance(scenario, trial.offsets))
    end = np.asarray(trial.truth[-1], dtype=float)
    terms = valid_bound_terms(trial, grid) if valid else (None, None)
    return TrialInfo(
        trial.index,
        bound.recursive_var_m2,
        bound.batch_var_m2,
        (float(end[0]), float(end[1])),
        bound.track_var_m2,
        bound.rw_var_m2,
        *terms,
    )


def bound_tracks(
    trial, grid: Grid, genie: Iterable[str] = (), priors: Iterable[str] = tuple(PRIORS)
) -> dict[str, np.ndarray]:
    """The bound terms of one trial at every sample, m^2, by name.

    Parameters
    ----------
    trial : Trial
        The simulated trial (its own per-beam variance,
        :func:`geofix.evaluate.crlb.trial_beam_variance`).
    grid : Grid
        The map it was simulated on.
    genie : iterable of str
        Prior suffixes (keys of :data:`PRIORS`) for which to run the genie too.
    priors : iterable of str
        Prior suffixes of the CRLB and ZZB terms (default: both).

    Returns
    -------
    dict
        ``crlb<suffix>`` (squared error-state CRLB) and ``zzb<suffix>`` for each prior,
        ``genie<suffix>`` (the genie's squared error, NaN where its grid no longer
        resolves the posterior) for each suffix of ``genie``; each ``(n,)``, m^2.
    """
    genie = tuple(genie)
    beam_var = trial_beam_variance(trial)
    out: dict[str, np.ndarray] = {}
    for suffix in priors:
        prior = PRIORS[suffix]
        out[f"crlb{suffix}"] = bound_track(trial, grid, beam_var, simulator_prior=prior) ** 2
        out[f"zzb{suffix}"] = zzb_track(trial, grid, beam_var, simulator_prior=prior)
        if suffix in genie:
            track = genie_track(trial, grid, beam_var, simulator_prior=prior)
            out[f"genie{suffix}"] = track.squared_error
    return out


def scenario_bound_tracks(
    scenario, trials: int, genie: Iterable[str] = (), mapper: Callable = map
) -> dict:
    """:func:`bound_tracks` of trials ``0 .. trials-1`` as a campaign simulates them.

    Parameters
    ----------
    scenario : Scenario
        The scenario.
    trials : int
        Number of trials.
    genie : iterable of str
        Prior suffixes for which to run the genie too.
    mapper : callable
        ``mapper(function, indices)`` computes each trial's terms, in order: the builtin
        ``map`` (in this process) or a process pool's ``map``. Each trial's terms are the
        same whichever process computes them.

    Returns
    -------
    dict
        ``{name: (trials, n) array}``, m^2.
    """
    from geofix.evaluate._shared_map import campaign_map

    grid = campaign_map(scenario)
    terms = mapper(partial(_trial_bound_tracks, scenario, grid, tuple(genie)), range(trials))
    rows: dict[str, list] = {}
    for each in terms:
        for key, value in each.items():
            rows.setdefault(key, []).append(value)
    return {key: np.asarray(value, float) for key, value in rows.items()}


def _trial_bound_tracks(scenario, grid: Grid, genie: tuple, index: int) -> dict:
    """:func:`bound_tracks` of one trial, simulated on ``grid``."""
    from geofix.sim.simulate import simulate_trial

    return bound_tracks(simulate_trial(scenario, grid, index), grid, genie)


def valid_bound_terms(trial, grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    """``(max(CRLB, ZZB), genie)`` of one trial at every sample, m^2 (simulator's prior).

    Parameters
    ----------
    trial : Trial
        The simulated trial.
    grid : Grid
        The map it was simulated on.

    Returns
    -------
    tuple of numpy.ndarray
        ``(n,)`` the larger of the squared error-state CRLB and the ZZB, and ``(n,)`` the
        genie's squared error (NaN where unresolved), m^2.
    """
    terms = bound_tracks(trial, grid, genie=(VALID_PRIOR,), priors=(VALID_PRIOR,))
    crlb, zzb = terms[f"crlb{VALID_PRIOR}"], terms[f"zzb{VALID_PRIOR}"]
    return np.maximum(crlb, zzb), terms[f"genie{VALID_PRIOR}"]


def per_sample_bound(bounds: Mapping, suffix: str = "", genie: bool = True) -> np.ndarray:
    """``(n,)`` the bound on the mean-square error at every sample, m^2.

    Parameters
    ----------
    bounds : mapping
        :func:`scenario_bound_tracks`'s arrays.
    suffix : str
        The prior (a key of :data:`PRIORS`).
    genie : bool
        Include the genie's mean squared error where it was computed.

    Returns
    -------
    numpy.ndarray
        The mean over trials of the larger of the CRLB and the ZZB, and with ``genie`` the
        larger of that and the genie's mean squared error (a trial it no longer resolves
        counting 0), m^2.
    """
    per_sample = combined_track_bound(bounds[f"crlb{suffix}"], bounds[f"zzb{suffix}"])
    if genie and f"genie{suffix}" in bounds:
        per_sample = np.maximum(per_sample, _genie_mean(bounds[f"genie{suffix}"]))
    return per_sample


def _genie_mean(squared_error) -> np.ndarray:
    """The genie's mean squared error over trials, an unresolved sample counting 0, m^2."""
    return np.nan_to_num(np.asarray(squared_error, float), nan=0.0).mean(axis=0)


def track_bound_rms(bounds: Mapping, suffix: str = "", genie: bool = True) -> float:
    """RMS along the track of :func:`per_sample_bound`, metres.

    Parameters
    ----------
    bounds : mapping
        :func:`scenario_bound_tracks`'s arrays, m^2.
    suffix : str
        The prior (a key of :data:`PRIORS`).
    genie : bool
        Include the genie's mean squared error where it was computed.
    """
    return float(np.sqrt(per_sample_bound(bounds, suffix, genie).mean()))


def end_bound_rms(bounds: Mapping, suffix: str = "") -> float:
    """:func:`per_sample_bound` at the last sample, as an RMS, metres."""
    return float(np.sqrt(per_sample_bound(bounds, suffix)[-1]))


def resolved_share(bounds: Mapping, suffix: str = "") -> float:
    """Share of the trials' samples where the genie's grid resolves the posterior."""
    return float(np.isfinite(bounds[f"genie{suffix}"]).mean())


def valid_bound(infos: list[TrialInfo]) -> tuple[float | None, float | None]:
    """The valid bound of a campaign's trials: ``(end point, along the track)``, metres.

    The larger, sample by sample, of the mean over the trials of ``max(CRLB, ZZB)`` and of
    the genie's squared error, under the simulator's prior (what :func:`end_bound_rms`
    and :func:`track_bound_rms` give with the suffix ``_simulator``). ``(None, None)``
    when a trial lacks the terms or the trials' tracks differ in length.
    """
    if not infos or not all(i.has_valid_bound for i in infos):
        return None, None
    if len({np.asarray(i.valid_track_m2).shape for i in infos}) != 1:
        return None, None
    per_sample = np.maximum(
        np.asarray([i.valid_track_m2 for i in infos], float).mean(axis=0),
        _genie_mean([i.genie_track_m2 for i in infos]),
    )
    return float(np.sqrt(per_sample[-1])), float(np.sqrt(per_sample.mean()))


def crlb_summary(infos: list[TrialInfo]) -> dict[str, float | None]:
    """The campaign's RMS Cramér–Rao bounds over its trials, metres, by summary key."""
    return {
        "crlb_m": rms_bound([i.crlb_var_m2 for i in infos]),
        "crlb_batch_m": rms_bound([i.crlb_batch_var_m2 for i in infos]),
        "crlb_track_m": rms_bound([i.crlb_track_var_m2 for i in infos]),
        "crlb_rw_m": rms_bound([i.crlb_rw_var_m2 for i in infos]),
    }
