"""Summary statistics of a results table: errors, success rates, timing, integrity.

The table has one row per (method, trial) with the columns written by
:class:`geofix.evaluate.store.ResultStore`: ``method``, ``trial``, ``end_error_m``,
``mean_track_error_m``, ``max_track_error_m``, ``leg_errors_m`` (a list per row),
``time_s``, ``n_calls``, ``evaluations``, ``ambiguous`` and ``failed``, and optionally
``end_mahalanobis`` (the end error measured against the method's own last covariance, NaN
where it gives none) for the false-fix rule.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from geofix.evaluate.summary import MethodStats

#: Success thresholds in metres (key -> metres).
SUCCESS_METRES = {"20": 20.0, "40": 40.0, "60": 60.0, "80": 80.0, "100": 100.0}
#: Success thresholds in map cells (key -> cells).
SUCCESS_CELLS = {"0.5c": 0.5, "1c": 1.0, "2c": 2.0, "3c": 3.0}
#: An unflagged fix farther than this many cells from the truth is a false fix...
FALSE_FIX_CELLS = 3.0
#: ... unless its end error lies inside this many sigmas of the method's own covariance.
FALSE_FIX_SIGMAS = 3.0


def summarize(results_df: pd.DataFrame, cell_m: float) -> dict[str, MethodStats]:
    """Per-method statistics of a campaign.

    Failed trials (the method raised an error) are left out of every error statistic but
    count in ``trials`` and as *not* successful in the success rates; ``failures`` counts
    them. Error statistics are over end-point errors (the error at the last sample), with
    the population standard deviation (``ddof=0``).

    Parameters
    ----------
    results_df : pandas.DataFrame
        One row per (method, trial); see the module docstring for the columns.
    cell_m : float
        Map cell size, metres, for the success rates in cells and the false-fix rule.

    Returns
    -------
    dict
        ``{method: MethodStats}`` in order of first appearance; each holds plain Python
        numbers (``None`` where undefined, e.g. no successful trial):
        ``trials``, ``mean_error_m``, ``std_error_m``, ``median_error_m``, ``max_error_m``
        (metres), ``mean_track_error_m`` (mean over trials of the mean along-track error,
        metres), ``max_track_error_m`` (metres), ``success_rate`` (share of trials with an
        end-point error <= threshold, keys ``"20"`` ... ``"100"`` metres and ``"0.5c"`` ...
        ``"3c"`` cells), ``mean_time_s`` (seconds per ``match`` call), ``failures``,
        ``false_fix_rate`` (share of trials ending more than 3 cells off, not flagged
        ambiguous, and outside the method's 3-sigma ellipse or without a covariance; see
        :func:`false_fix_rate`), ``ambiguous_rate``, ``mean_evaluations`` (per trial) and
        ``leg_mean_errors_m`` (mean end error of every leg, metres), ``rms_error_m``
        (end-point RMS error ``sqrt(mean(e^2))`` over the trials that did not fail,
        metres) and ``nees`` (mean normalised estimation error squared of the end point,
        ``e^T C^-1 e`` with the method's own last covariance ``C``, over the trials that
        give one: about 2 for a consistent 2-D estimate; None without covariances) and
        ``track_rms_error_m`` (RMS of the error over every sample of every trial that did
        not fail, metres, from the column ``track_ms_m2``; None without it).
    """
    methods = list(dict.fromkeys(results_df["method"]))
    return {m: method_stats(results_df[results_df["method"] == m], cell_m) for m in methods}


def method_stats(rows: pd.DataFrame, cell_m: float) -> MethodStats:
    """Statistics of one method's rows (see :func:`summarize`); ``cell_m`` in metres."""
    failed = rows["failed"].to_numpy(dtype=bool)
    ok = rows[~failed]
    end = ok["end_error_m"].to_numpy(dtype=float)
    n_calls = int(rows["n_calls"].sum())
    return MethodStats(
        trials=len(rows),
        mean_error_m=_num(np.mean(end) if end.size else math.nan),
        std_error_m=_num(np.std(end) if end.size else math.nan),
        median_error_m=_num(np.median(end) if end.size else math.nan),
        max_error_m=_num(np.max(end) if end.size else math.nan),
        mean_track_error_m=_num(ok["mean_track_error_m"].mean()),
        max_track_error_m=_num(ok["max_track_error_m"].max()),
        success_rate=success_rates(end, len(rows), cell_m),
        mean_time_s=_num(rows["time_s"].sum() / n_calls if n_calls else math.nan),
        failures=int(failed.sum()),
        false_fix_rate=_num(false_fix_rate(ok, len(rows), cell_m)),
        ambiguous_rate=_num(rows["ambiguous"].astype(bool).mean() if len(rows) else math.nan),
        mean_evaluations=_num(rows["evaluations"].mean() if len(rows) else math.nan),
        leg_mean_errors_m=leg_mean_errors(ok["leg_errors_m"]),
        rms_error_m=_num(np.sqrt(np.mean(end**2)) if end.size else math.nan),
        nees=_num(mean_nees(ok)),
        track_rms_error_m=_num(
            np.sqrt(ok["track_ms_m2"].mean()) if "track_ms_m2" in ok and len(ok) else math.nan
        ),
    )


def mean_nees(ok: pd.DataFrame) -> float:
    """Mean of ``end_mahalanobis^2`` over the rows that have one (NaN without)."""
    if "end_mahalanobis" not in ok:
        return math.nan
    d = ok["end_mahalanobis"].to_numpy(dtype=float)
    d = d[np.isfinite(d)]
    return float(np.mean(d**2)) if d.size else math.nan


def success_rates(end_errors: np.ndarray, trials: int, cell_m: float) -> dict:
    """Share of ``trials`` whose end error (metres) is within each threshold.

    Parameters
    ----------
    end_errors : numpy.ndarray
        End-point errors of the successful (not failed) trials, metres.
    trials : int
        Number of trials, failed ones included (they count as not successful).
    cell_m : float
        Cell size, metres, for the thresholds in cells.

    Returns
    -------
    dict
        ``{"20": share, ..., "100": share, "0.5c": share, ..., "3c": share}``, shares in
        ``[0, 1]`` (``None`` when ``trials`` is 0).
    """
    limits = dict(SUCCESS_METRES)
    limits.update({k: v * cell_m for k, v in SUCCESS_CELLS.items()})
    errors = np.asarray(end_errors, dtype=float)
    return {
        key: (float(np.count_nonzero(errors <= lim) / trials) if trials else None)
        for key, lim in limits.items()
    }


def false_fix_rate(ok: pd.DataFrame, trials: int, cell_m: float) -> float:
    """Share of ``trials`` that are confident wrong fixes.

    A false fix ends farther than 3 cells (``cell_m`` metres each) from the truth, was not
    flagged ambiguous, and either gives no covariance or lies outside its 3-sigma ellipse
    (Mahalanobis distance > 3, column ``end_mahalanobis``; NaN = no covariance; without
    the column every row counts as giving none).

    Parameters
    ----------
    ok : pandas.DataFrame
        The rows of the trials that did not fail (``end_error_m`` metres, ``ambiguous``,
        optionally ``end_mahalanobis``).
    trials : int
        Number of trials, failed ones included.
    cell_m : float
        Map cell size, metres.
    """
    if not trials:
        return math.nan
    far = ok["end_error_m"].to_numpy(dtype=float) > FALSE_FIX_CELLS * cell_m
    unflagged = ~ok["ambiguous"].to_numpy(dtype=bool)
    if "end_mahalanobis" in ok:
        distance = ok["end_mahalanobis"].to_numpy(dtype=float)
        outside = ~(distance <= FALSE_FIX_SIGMAS)
    else:
        outside = np.ones(len(ok), dtype=bool)
    return float(np.count_nonzero(far & unflagged & outside) / trials)


def end_mahalanobis(error_xy, covariance) -> float:
    """Mahalanobis distance ``sqrt(e^T C^-1 e)`` of an end error against a covariance.

    Parameters
    ----------
    error_xy : array_like
        ``(2,)`` estimate minus truth, metres.
    covariance : array_like or None
        ``(2, 2)`` covariance of the estimate, m^2.

    Returns
    -------
    float
        Dimensionless distance; NaN without a usable (finite, positive-definite)
        covariance or with a non-finite error.
    """
    if covariance is None:
        return math.nan
    cov = np.asarray(covariance, dtype=float).reshape(-1)
    e = np.asarray(error_xy, dtype=float).reshape(-1)
    if cov.size != 4 or e.size != 2 or not (np.isfinite(cov).all() and np.isfinite(e).all()):
        return math.nan
    c = cov.reshape(2, 2)
    det = c[0, 0] * c[1, 1] - c[0, 1] * c[1, 0]
    if not (c[0, 0] > 0 and det > 0):
        return math.nan
    quad = (c[1, 1] * e[0] ** 2 - (c[0, 1] + c[1, 0]) * e[0] * e[1] + c[0, 0] * e[1] ** 2) / det
    return float(np.sqrt(max(quad, 0.0)))


def leg_mean_errors(leg_errors: pd.Series) -> list:
    """Mean end error of each leg, metres, over rows holding one list of leg errors each."""
    if leg_errors.empty:
        return []
    legs = np.array([np.asarray(v, dtype=float) for v in leg_errors], dtype=float)
    finite = np.isfinite(legs)
    counts = finite.sum(axis=0)
    sums = np.where(finite, legs, 0.0).sum(axis=0)
    return [_num(s / c) if c else None for s, c in zip(sums, counts, strict=True)]


def _num(value) -> float | None:
    """A plain float, or None for NaN."""
    value = float(value)
    return None if math.isnan(value) else value
