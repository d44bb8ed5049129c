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
  exceeds ``tau_served`` (none such: the target stays);
  with ``first_tour`` (the default) and at least :data:`FIRST_TOUR_MIN_AUVS` (4) AUVs,
  while some AUV the ASV can reach has not been visited since the run began (``toured``: a
  fix since then, in expectation as above, or ``dwell_max`` in its target domain), the
  target is the first AUV of the path through those, on to the oldest AUV already visited,
  with the least sum of arrival distances (eq. M9t, :func:`first_tour_next`), whatever
  their fix ages (at the
  start every age is below ``tau_served`` only because the run has just begun). With every
  age about the same (the run's start) the projected age is largest for the farthest AUV,
  and the age rule, going next to the AUV visited longest ago, mostly repeats the first
  round's order: four AUVs at the corners of a square were toured along the diagonals for
  the whole run (session 35's sweep: one of them had no reliable fix in 900 s). An AUV
  that could not be reached and becomes reachable later is visited the same way;
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
import itertools
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

#: the first tour's orders are enumerated up to this many AUVs (m! orders), nearest next beyond
FIRST_TOUR_ENUMERATED = 6
#: the first tour (M9t) applies from this many AUVs: with three or fewer every closed tour
#: through the AUVs is the same cycle, so the shortest-path version (session 37) could not
#: shorten it (measured with three: Cases 6-8 and a new layout, no better, docs/mpc.md
#: "Closed loop ... session 37"), nor was the least-waiting version (session 38: Cases 6-8,
#: 30 pairs, fix age p95 +0.3 s, collision domain +7.0 s, p = 0.021)
FIRST_TOUR_MIN_AUVS = 4


def first_tour_next(asv_NE: np.ndarray, pos: np.ndarray, first: list[int],
                    close: int | None) -> int:  # fmt: skip
    """The AUV to visit next on the first tour (eq. M9t): the first of the path from the ASV
    (``asv_NE``, m, shape (2,)) through the AUVs ``first`` (indices into ``pos``, positions
    now, m, shape (K, 2)) and then to AUV ``close`` (the oldest AUV already visited; None:
    no AUV visited yet, the path ends at its last AUV) whose sum of arrival distances is
    least: each AUV on it waits for the ASV as long as the path up to it (the minimum-latency
    or travelling-repairman order), so an AUV on the way is visited on the way. (Until
    session 38 the shortest path closing at ``close``: four AUVs on a line with the ASV at
    one end, out-and-back and "far end first, then sweep back" were as long, and a few
    metres of offset sent the ASV past three AUVs to the far end first.) Up to
    :data:`FIRST_TOUR_ENUMERATED` AUVs every order is tried (the order's first AUV is the
    answer); beyond, the nearest. Sums are compared to the micrometre, ties go to the lower
    index.

    Raises
    ------
    ValueError
        ``first`` is empty.
    """
    if not first:
        raise ValueError("the first tour needs at least one AUV not yet visited")
    P = np.asarray(pos, float)
    to = np.hypot(*(P - np.asarray(asv_NE, float)).T)  # (K,) m from the ASV
    if len(first) > FIRST_TOUR_ENUMERATED:
        return min(sorted(first), key=lambda i: round(float(to[i]), 6))
    D = np.hypot(*(P[:, None, :] - P[None, :, :]).transpose(2, 0, 1))  # (K, K) m

    def latency(order: tuple[int, ...]) -> float:
        stops = order if close is None else (*order, close)
        arrive = np.cumsum([to[stops[0]], *(D[a, b] for a, b in itertools.pairwise(stops))])
        return round(float(arrive.sum()), 6)  # M9t: sum of the arrival distances

    return min(itertools.permutations(sorted(first)), key=latency)[0]


class Targeting:
    """The target AUV's choice (mixin; state in the controller: ``target``, ``t_commit``,
    ``fixes_since``, ``fixes_run``, ``toured``, ``t_run0``, ``dwell``, ``target_switches``,
    ``t_explore``, ``order_plan``)."""

    def _choose_target(self, obs: Observation, elapsed: float) -> None:
        """Keep or change ``self.target`` after ``elapsed`` s (module docstring)."""
        K = len(obs.auvs)
        if K == 1:
            return
        if self.t_run0 is None:
            self.t_run0 = obs.t  # the run's first step (the first tour, M9t)
        pos = np.array([a.position for a in obs.auvs])
        dist, r_t = self._reach_now(obs)
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
        if self.params.first_tour and K >= FIRST_TOUR_MIN_AUVS and self._first_tour(obs, pos, r_t):
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

    def _first_tour(self, obs: Observation, pos: np.ndarray, r_t: np.ndarray) -> bool:
        """(M9t) While some AUV the ASV can reach has not been visited since the run began,
        commit to the first AUV of the path through those on to the oldest AUV already
        visited with the least sum of arrival distances (:func:`first_tour_next`; ``pos``
        the AUVs' positions, m, shape (K, 2), ``r_t`` their target circles, m) and return
        True; else False (the age rule chooses). Visited (``toured``): an expected fix
        since the run began (the fix rate of eq. M3 integrated, ``fixes_run`` >= 1; with
        ``fix_age_source = "estimate"`` a fix time after the run's first step, ``t_run0``,
        whatever the estimator counts as a fix, e.g. an AUV's own status report in the
        field), or ``dwell_max`` in its target domain.
        Not yet visited AUVs are candidates whatever their fix age: at the run's start every
        age is below ``tau_served`` only because the run has just begun (before, the AUV
        nearest the start was left out of the first round)."""
        if self.params.fix_age_source == "estimate":  # a fix time after the run's first step
            self.toured |= np.array([a.t_last_fix > self.t_run0 for a in obs.auvs])
        else:
            self.toured |= self.fixes_run >= 1.0
        if self.dwell >= self.params.dwell_max:  # the current target's (reset on a switch)
            self.toured[self.target] = True
        first = [i for i in range(len(pos)) if not self.toured[i]]
        if first:  # (a committed target not yet visited is here only if it cannot be reached)
            first = [i for i, ok in zip(first, self._reachable(obs, r_t, first), strict=True)
                     if ok]  # fmt: skip
        if not first:
            return False
        oldest = np.flatnonzero(self.toured)
        close = None if len(oldest) == 0 else int(oldest[np.argmax(self.tau[oldest])])
        self._switch_to(first_tour_next(obs.asv.position, pos, first, close), obs.t)
        return True

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
