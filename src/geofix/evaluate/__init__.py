"""Evaluation: run methods on trials, store the results, summarise them.

- :func:`run_trial` runs one method on one trial (leg by leg, or whole-mission for a
  recursive method) and measures its errors against the truth;
- :func:`run_campaign` runs every method on every trial of a scenario, in a local process
  pool or on Dask, storing each result in ``results.sqlite`` as it completes (resumable);
- :func:`summarize` reduces a results table to per-method statistics.
"""

from geofix.evaluate.campaign import CampaignResult, run_campaign
from geofix.evaluate.metrics import summarize
from geofix.evaluate.runner import TrialResult, method_rng, run_trial
from geofix.evaluate.store import ResultStore, scenario_hash

__all__ = [
    "CampaignResult",
    "ResultStore",
    "TrialResult",
    "method_rng",
    "run_campaign",
    "run_trial",
    "scenario_hash",
    "summarize",
]
