"""Recursive estimators: one loop (:func:`run_filter`), pure predict / update steps.

SITAN (a single extended Kalman filter with stochastic terrain linearisation) and the SITAN
bank (source 002) live in :mod:`geofix.filters.sitan`; the point-mass and particle filters
in their own modules. Every filter is also a registered method (``geofix methods``).
"""

from geofix.filters.base import (
    Motion,
    Observation,
    RecursiveFilter,
    motions,
    observations,
    run_filter,
)
from geofix.filters.sitan import BankState, Sitan, SitanBank, SitanState
from geofix.measurement import (
    Linearisation,
    linearise,
    log_likelihood,
    predict_measurements,
)

__all__ = [
    "BankState",
    "Linearisation",
    "Motion",
    "Observation",
    "RecursiveFilter",
    "Sitan",
    "SitanBank",
    "SitanState",
    "linearise",
    "log_likelihood",
    "motions",
    "observations",
    "predict_measurements",
    "run_filter",
]
