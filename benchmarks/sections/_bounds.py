"""Track bounds of a scenario's trials, shared by the filters and integrity sections.

Per trial and sample, each with the CRLB's prior of the start error (zero mean, the
simulator's second moments) and with the simulator's own (its spread about the known
offset): the error-state CRLB (``crlb_track_m``'s terms with the first), the Ziv–Zakai
bound (:mod:`geofix.evaluate.zzb`), and optionally the genie's squared errors
(:mod:`geofix.evaluate.ambiguity`).
"""

from __future__ import annotations

import numpy as np

#: The two priors of the start error: the CRLB's and the filters' (zero mean, the
#: simulator's second moments), and the simulator's own distribution.
PRIORS = {"": False, "_simulator": True}


def trial_bounds(scen, trials: int, genie: tuple[str, ...] = ()) -> dict:
    """``{name: (trials, n) array}``, m^2, for trials ``0 .. trials-1`` as simulated.

    Keys ``crlb`` and ``zzb``, each also with the suffix ``_simulator``; ``genie`` plus
    each suffix named in ``genie`` (NaN where its grid no longer resolves the posterior).
    """
    from geofix.evaluate.ambiguity import genie_track
    from geofix.evaluate.campaign import campaign_map
    from geofix.evaluate.crlb import bound_track, trial_beam_variance
    from geofix.evaluate.zzb import zzb_track
    from geofix.sim.simulate import simulate_trial

    grid = campaign_map(scen)
    rows: dict[str, list] = {}
    for index in range(trials):
        trial = simulate_trial(scen, grid, index)
        beam_var = trial_beam_variance(trial)
        for suffix, prior in PRIORS.items():
            rows.setdefault(f"crlb{suffix}", []).append(
                bound_track(trial, grid, beam_var, simulator_prior=prior) ** 2
            )
            rows.setdefault(f"zzb{suffix}", []).append(
                zzb_track(trial, grid, beam_var, simulator_prior=prior)
            )
            if suffix in genie:
                rows.setdefault(f"genie{suffix}", []).append(
                    genie_track(trial, grid, beam_var, simulator_prior=prior).squared_error
                )
    return {key: np.asarray(value, float) for key, value in rows.items()}


def per_sample_bound(bounds: dict, suffix: str = "", genie: bool = True) -> np.ndarray:
    """``(n,)`` the bound on the mean-square error at every sample, m^2.

    The mean over trials of the larger of the CRLB and the ZZB (both with the prior
    ``suffix``), and with ``genie`` the larger of that and the genie's mean squared error
    where it was computed (a trial it no longer resolves counting 0).
    """
    from geofix.evaluate.zzb import combined_track_bound

    per_sample = combined_track_bound(bounds[f"crlb{suffix}"], bounds[f"zzb{suffix}"])
    if genie and f"genie{suffix}" in bounds:
        mmse = np.nan_to_num(bounds[f"genie{suffix}"], nan=0.0).mean(axis=0)
        per_sample = np.maximum(per_sample, mmse)
    return per_sample


def track_bound_rms(bounds: dict, suffix: str = "", genie: bool = True) -> float:
    """RMS along the track of :func:`per_sample_bound`, metres."""
    return float(np.sqrt(per_sample_bound(bounds, suffix, genie).mean()))


def end_bound_rms(bounds: dict, suffix: str = "") -> float:
    """:func:`per_sample_bound` at the last sample, as an RMS, metres."""
    return float(np.sqrt(per_sample_bound(bounds, suffix)[-1]))


def resolved_share(bounds: dict, suffix: str = "") -> float:
    """Share of the trials' samples where the genie's grid resolves the posterior."""
    return float(np.isfinite(bounds[f"genie{suffix}"]).mean())
