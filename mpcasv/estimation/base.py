"""The estimator interface between the AUVs' truth (or the network) and the Observation.

One estimator object per AUV. The simulator and the deploy loop feed it the same events:
``on_fix`` (a USBL fix), ``on_report`` (an acoustic status report) and, in simulation only,
``on_truth`` (ground truth, used by the ``perfect`` estimator alone). ``estimate(t)`` gives
the belief at any time as an :class:`mpcasv.interface.AUVEstimate`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol

from mpcasv.estimation.depth import DepthFilter
from mpcasv.interface import AUVEstimate
from mpcasv.models.acoustics import Fix, Report


class AUVEstimator(Protocol):
    """Belief about one AUV, updated by acoustic events."""

    name: str

    def on_truth(self, t: float, N: float, E: float, depth: float, v_N: float, v_E: float) -> None:
        """Ground truth (simulation only; ignored by every estimator but ``perfect``)."""

    def on_fix(self, fix: Fix) -> None:
        """A USBL position fix measured by the ASV."""

    def on_report(self, report: Report) -> None:
        """An acoustic status report from the AUV (its own navigation estimate)."""

    def estimate(self, t: float) -> AUVEstimate:
        """Belief at time ``t``."""


class PerfectEstimator:
    """The true AUV state (the papers' simulations and field trials with simulated AUVs)."""

    name = "perfect"

    def __init__(self) -> None:
        self._est = AUVEstimate(math.nan, math.nan, 0.0)

    def on_truth(self, t, N, E, depth, v_N, v_E) -> None:
        self._est = AUVEstimate(N, E, depth, v_N, v_E, (0.0, 0.0, 0.0, 0.0), t)

    def on_fix(self, fix: Fix) -> None:
        pass

    def on_report(self, report: Report) -> None:
        pass

    def estimate(self, t: float) -> AUVEstimate:
        return self._est


class StationaryEstimator:
    """The last fix or report, held constant in between (the thesis's field trial, Case 5).

    The covariance is that of the last measurement; it does not grow, which is exactly the
    weakness the Kalman filter addresses. The depth is the Kalman filter's
    (:class:`~mpcasv.estimation.depth.DepthFilter`, default tuning): a fix's USBL depth
    (1.7 m off at 100 m, 7 m at 400 m) is weighed against the reports' pressure depths, not
    copied.
    """

    name = "acoustic"

    def __init__(self, initial: AUVEstimate | None = None) -> None:
        self._est = initial or AUVEstimate(math.nan, math.nan, 0.0)
        self._depth = DepthFilter()
        if initial is not None and math.isfinite(initial.depth):
            t0 = initial.t_last_fix if math.isfinite(initial.t_last_fix) else 0.0
            self._depth.start(t0, initial.depth, self._depth.sigma_report**2)

    def on_truth(self, t, N, E, depth, v_N, v_E) -> None:
        pass

    def on_fix(self, fix: Fix) -> None:
        self._depth.measure(fix.t, fix.depth, fix.depth_var)
        self._est = AUVEstimate(fix.N, fix.E, self._depth.depth, 0.0, 0.0, fix.cov, fix.t)

    def on_report(self, report: Report) -> None:
        s2 = report.nav_sigma**2
        self._depth.report(report.t, report.depth)
        self._est = AUVEstimate(
            report.N, report.E, self._depth.depth, 0.0, 0.0, (s2, 0.0, 0.0, s2), report.t
        )

    def estimate(self, t: float) -> AUVEstimate:
        return self._est


def _kalman(initial=None, kalman=None, **_):
    from mpcasv.estimation.kalman import KalmanEstimator

    return KalmanEstimator(initial, kalman)


def _plan(initial=None, plan=None, plan_params=None, kalman=None, **_):
    from mpcasv.estimation.plan import PlanEstimator

    return PlanEstimator(initial, plan, plan_params, kalman)


#: name -> factory(initial=AUVEstimate or None, **options) -> estimator. Options understood
#: (others are ignored, so every estimator can be built with the same call): ``kalman``
#: (:class:`~mpcasv.estimation.kalman.KalmanParams`), ``plan``
#: (:class:`~mpcasv.estimation.survey_plan.KnownPlan` or None), ``plan_params``
#: (:class:`~mpcasv.estimation.plan.PlanParams`).
ESTIMATORS: dict[str, Callable[..., AUVEstimator]] = {
    "perfect": lambda initial=None, **_: PerfectEstimator(),
    "acoustic": lambda initial=None, **_: StationaryEstimator(initial),
    "kalman": _kalman,
    "plan": _plan,
}


def make_estimator(name: str, initial: AUVEstimate | None = None, **options) -> AUVEstimator:
    """Build an estimator by name (see :data:`ESTIMATORS`).

    Parameters
    ----------
    name : str
        ``"perfect"``, ``"acoustic"`` (stationary), ``"kalman"`` or ``"plan"``.
    initial : AUVEstimate, optional
        The AUV's known initial state.
    **options
        ``kalman=KalmanParams``, ``plan=KnownPlan`` (the AUV's plan as the ASV knows it, see
        :func:`mpcasv.estimation.survey_plan.known_plan`), ``plan_params=PlanParams``; ignored by
        estimators that do not use them.
    """
    try:
        factory = ESTIMATORS[name]
    except KeyError:
        raise ValueError(f"unknown estimator {name!r}; known: {sorted(ESTIMATORS)}") from None
    return factory(initial=initial, **options)
