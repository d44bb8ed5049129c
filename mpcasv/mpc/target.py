"""Which AUV the MPC's terminal cost sends the ASV to (eq. M9; mixin of
:class:`~mpcasv.mpc.controller.MPCController`, state in the controller).

Two rules (``MPCParams.target_rule``), both with commitment (issue 16 item 6): a target chosen
by the rule is kept until it is served: it has had a fix since it was chosen (in expectation,
``fixes_since``: the fix rate of eq. M3 integrated since the choice reaches 1; with
``fix_age_source = "estimate"``, a fix time after the choice) and its expected fix age is
below ``tau_served``; or the ASV has spent ``dwell_max`` within its target domain. (A fix age
below ``tau_served`` alone is not enough: when a run starts every age is 0, and each newly
chosen AUV counted as served at once, so the target swapped between two AUVs every step
until the first fix ages grew past ``tau_served``: 25 switches in the first 26 s of Case 6.)
The target the run starts with (AUV 0) is not committed: it is served as soon as its fix age
is below ``tau_served``. With the ``age`` rule a committed target that the ASV cannot reach
(going away faster than ``U_go``: :meth:`Targeting._reachable`) is left for a reachable AUV
that needs a visit, and AUVs that cannot be reached are chosen only when none can (before,
such an AUV kept the target for good, its age growing). Then

- ``age`` (default, the shipped presets): the AUV with the largest projected fix age
  ``tau_i + t_go,i`` (Paper 2's eq. 8 on projected ages) among those whose projected age
  exceeds ``tau_served``; none such: the target stays;
- ``order`` (opt-in, preset ``mpc-multi-order``): a served committed target is left, as with
  the age rule only when another AUV's projected fix age exceeds ``tau_served``, for the
  first AUV of the cheapest visiting order over ``order.window`` that starts elsewhere
  (:mod:`mpcasv.mpc.order`, eq. O1; since session 16); the run's first target (not
  committed) gives way only to an order ``order.hysteresis`` cheaper than the best one that
  stays.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from mpcasv.interface import AUVEstimate, Observation
from mpcasv.models.auv_nav import dr_variance
from mpcasv.mpc.order import (
    MEET_MAX,
    Forecast,
    OrderModel,
    best_order,
    committed_target,
    meet_time,
    transit_cost,
)


class Targeting:
    """The target AUV's choice (mixin; state in the controller: ``target``,
    ``t_commit``, ``fixes_since``, ``dwell``, ``target_switches``, ``t_explore``,
    ``order_plan``)."""

    def _choose_target(self, obs: Observation, elapsed: float) -> None:
        """Keep or change ``self.target`` after ``elapsed`` s (module docstring)."""
        K = len(obs.auvs)
        if K == 1:
            return
        pos = np.array([a.position for a in obs.auvs])
        r_t = self._radii(obs, 0.0, obs.asv.position) + self.domain.delta_r
        dist = np.hypot(*(pos - obs.asv.position).T)
        if self.domain.in_reliable_range(dist[self.target], r_t[self.target]):
            self.dwell += elapsed
        j = self.target
        if self.params.fix_age_source == "estimate":
            fixed = obs.auvs[j].t_last_fix > self.t_commit
        else:
            fixed = self.fixes_since[j] >= 1.0
        served = (fixed or not self.committed) and self.tau[j] <= self.params.tau_served
        order = self.params.target_rule == "order"
        if not (served or self.dwell >= self.params.dwell_max):
            # a committed target the ASV cannot reach (going away faster than U_go) is left
            # for a reachable AUV that needs a visit; before, it kept the target for good
            if order or self._reachable(obs, r_t, [j])[0]:
                return
            if not self._reachable(obs, r_t, [i for i in range(K) if i != j]).any():
                return
        t_go = np.maximum(dist - r_t, 0.0) / self.U_go  # U_go, at most the speed cap
        proj = self.tau + t_go
        if order:
            others = np.arange(K) != j
            if not self.committed or np.any(proj[others] > self.params.tau_served):
                self._choose_by_order(obs, r_t)  # else (every other AUV served) it stays
            return
        # commitment (issue 16 item 6): leave the target only for an AUV that needs a visit
        # itself (projected fix age above tau_served); with every other AUV served the target
        # stays (before, two served AUVs swapped the target every step for a whole run)
        proj[proj <= self.params.tau_served] = -np.inf
        if self.committed:
            proj[self.target] = -np.inf
        cand = np.flatnonzero(np.isfinite(proj))
        if len(cand) == 0:
            return
        reach = self._reachable(obs, r_t, cand)
        if reach.any():  # the largest projected age among the candidates the ASV can reach
            proj[cand[~reach]] = -np.inf
        elif self._reachable(obs, r_t, np.setdiff1d(np.arange(K), cand)).any():
            return  # an unreachable AUV only when no AUV can be reached
        self._switch_to(int(np.argmax(proj)), obs.t)

    def _reachable(self, obs: Observation, r_t: np.ndarray, which) -> np.ndarray:
        """Whether the ASV, leaving now at ``U_go`` (m/s, at most the speed cap), meets the
        target circle ``r_t`` (m, shape (K,)) of each AUV in ``which`` (indices) along its
        estimate's forecast (:func:`~mpcasv.mpc.order.meet_time` below ``MEET_MAX``): an AUV
        going away faster than that is met "never" (shape (len(which),), bool). Evaluated
        only where the choice needs it (a step's hot path: about 0.1 ms per AUV)."""
        here, auvs = obs.asv.position, obs.auvs
        return np.array([meet_time(here, auvs[i].predict, float(r_t[i]), self.U_go) < MEET_MAX
                         for i in which], dtype=bool)  # fmt: skip

    def _switch_to(self, new: int, t: float) -> None:
        """Commit to ``new`` at time ``t`` (a switch, counted, if it is not the target
        already)."""
        self.t_commit = t
        self.fixes_since[:] = 0.0
        if new == self.target:
            return
        self.dwell = 0.0
        self.target = new
        self.target_switches += 1
        self.t_explore = None  # new target: also try a guess heading there (_explore)

    def _choose_by_order(self, obs: Observation, r_t: np.ndarray) -> None:
        """``target_rule = "order"``: the cheapest visiting order's first AUV, with the
        commitment of :func:`~mpcasv.mpc.order.committed_target`."""
        plan = best_order(obs.asv.position, [self.forecast(a) for a in obs.auvs],
                          np.array([a.depth for a in obs.auvs]), self.tau, r_t,
                          self.order_model)  # fmt: skip
        self.order_plan = plan
        self._switch_to(committed_target(plan, self.target, self.params.order.hysteresis,
                                         served=self.committed), obs.t)  # fmt: skip

    @property
    def committed(self) -> bool:
        """Whether the target was chosen by the rule (kept until served; module docstring)."""
        return self.t_commit > -math.inf

    def forecast(self, a: AUVEstimate) -> Forecast:
        """An AUV's forecast for the visiting order (offsets from now, s, shape (n,) ->
        positions (n, 2), m): the estimator's own (along the AUV's plan) as far as it goes;
        a constant-velocity extrapolation only up to ``cv_forecast_max`` s, then held
        (an AUV on a lawn-mower pattern turns every minute or two: extrapolated over ten
        minutes it would be hundreds of metres off)."""
        if a.forecast is not None:
            return a.predict
        cap = self.params.cv_forecast_max
        return lambda dt: a.predict(np.minimum(np.asarray(dt, float), cap))

    @functools.cached_property
    def order_model(self) -> OrderModel:
        """The top level's model (:mod:`mpcasv.mpc.order`) in the OCP's cost units: the run's
        USBL noise (``self.acoustics``), the preset's ``navigation.eps_a``, the weights'
        ``U_go`` (at most the speed cap, :attr:`U_go`) and ``tau_ref``, the energy terms at the
        thrust holding ``U_go`` (M4)."""
        P, ac, ocp = self.params, self.acoustics, self.ocp
        wt, o, eps_a = P.weights, P.order, P.navigation.eps_a
        vp = ocp.vessel
        U = self.U_go
        if U != wt.U_go:  # the speed cap's transit speed
            wt = dataclasses.replace(wt, U_go=U)
        e_go = transit_cost(wt, ocp.model.thrust_for_speed(U), vp.T_max, vp.u_max)
        return OrderModel(eps_a=eps_a, sigma_range=ac.sigma_range,
                          sigma_bearing=math.radians(ac.sigma_bearing_deg), U=U,
                          T_stay=o.stay, window=o.window, nav=o.nav,
                          V_ref=dr_variance(eps_a, wt.tau_ref), e_go=e_go)  # fmt: skip
