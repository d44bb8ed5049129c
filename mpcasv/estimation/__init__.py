"""What the ASV knows about the AUVs: estimators between acoustic fixes and reports."""

from mpcasv.estimation.base import (
    ESTIMATORS,
    AUVEstimator,
    PerfectEstimator,
    StationaryEstimator,
    make_estimator,
)

__all__ = [
    "ESTIMATORS",
    "AUVEstimator",
    "PerfectEstimator",
    "StationaryEstimator",
    "make_estimator",
]
