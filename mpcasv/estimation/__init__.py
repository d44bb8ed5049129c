"""What the ASV knows about the AUVs: estimators between acoustic fixes and reports."""

from mpcasv.estimation.base import (
    ESTIMATORS,
    AUVEstimator,
    PerfectEstimator,
    StationaryEstimator,
    make_estimator,
)
from mpcasv.estimation.in_order import InOrder
from mpcasv.estimation.kalman import KalmanEstimator, KalmanParams
from mpcasv.estimation.plan import PlanEstimator, PlanParams
from mpcasv.estimation.survey_plan import (
    KnownPlan,
    check_plan_estimator,
    has_plan,
    known_plan,
    scenario_plans,
)

__all__ = [
    "ESTIMATORS",
    "AUVEstimator",
    "InOrder",
    "KalmanEstimator",
    "KalmanParams",
    "KnownPlan",
    "PlanEstimator",
    "PlanParams",
    "PerfectEstimator",
    "StationaryEstimator",
    "check_plan_estimator",
    "has_plan",
    "known_plan",
    "make_estimator",
    "scenario_plans",
]
