"""Track bounds of a scenario's trials, shared by the filters and integrity sections.

Per trial and sample, each with the CRLB's prior of the start error (zero mean, the
simulator's second moments) and with the simulator's own (its spread about the known
offset): the error-state CRLB, the Ziv–Zakai bound and optionally the genie's squared
errors, as :mod:`geofix.evaluate.bounds` computes them (the valid bound of a campaign
run with ``valid_bound=True`` is :func:`end_bound_rms` and :func:`track_bound_rms` with
the suffix ``_simulator``).
"""

from __future__ import annotations

from contextlib import contextmanager

from geofix.evaluate.bounds import (
    PRIORS,
    end_bound_rms,
    per_sample_bound,
    resolved_share,
    scenario_bound_tracks,
    track_bound_rms,
)

__all__ = [
    "PRIORS",
    "end_bound_rms",
    "per_sample_bound",
    "pooled_trials",
    "resolved_share",
    "track_bound_rms",
    "trial_bounds",
]


#: Processes the bounds of a scenario's trials are computed in.
BOUND_JOBS = 2


@contextmanager
def pooled_trials(trials: int):
    """A ``mapper(function, indices)`` over :data:`BOUND_JOBS` processes, results in order.

    Each process takes one contiguous block of the ``trials`` indices; a trial's result
    is the same whichever process computes it.
    """
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    from geofix.evaluate._pool import worker_start_method

    workers = max(1, min(BOUND_JOBS, trials))
    context = get_context(worker_start_method())
    with ProcessPoolExecutor(workers, mp_context=context) as pool:

        def mapper(function, indices):
            return list(pool.map(function, indices, chunksize=-(-trials // workers)))

        yield mapper


def trial_bounds(scen, trials: int, genie: tuple[str, ...] = ()) -> dict:
    """``{name: (trials, n) array}``, m^2, for trials ``0 .. trials-1`` as simulated.

    Keys ``crlb`` and ``zzb``, each also with the suffix ``_simulator``; ``genie`` plus
    each suffix named in ``genie`` (NaN where its grid no longer resolves the posterior).
    """
    with pooled_trials(trials) as mapper:
        return scenario_bound_tracks(scen, trials, genie, mapper=mapper)
