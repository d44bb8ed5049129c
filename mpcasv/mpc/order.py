"""The MPC's top level: the order in which to visit the AUVs (issue 16 item 2; opt-in,
``target_rule = "order"``, preset ``mpc-multi-order``).

The OCP's horizon (a minute) does not reach an AUV 300-600 m away, so which AUV the plan
heads for is chosen here, over a window of ten minutes: every order of visiting the
``K <= MAX_ENUMERATED`` AUVs is enumerated (``K!`` <= 24 orders) and valued by what the AUVs
need and what the boat spends (docs/mpc.md, "Visiting order"):

    J(order) = nav / V_ref * sum_i integral_0^W V_i(t) dt + e_go * (transit time within W)   (O1)

- the ASV tours the AUVs in that order, again and again until ``W`` (a continuing service;
  with single visits an AUV visited early would regrow all window long and the order would
  favour visiting the oldest AUV last);
- ``V_i(t)``, AUV ``i``'s navigation variance per axis (m^2): from its fix age ``tau_i`` it
  grows as ``eps_a^2 / 8 (tau_i + t)^4`` (:func:`~mpcasv.models.auv_nav.dr_variance`, thesis
  eq. 2.7) until the ASV reaches it; the first fix there leaves the filter's posterior ``P+``
  (:func:`~mpcasv.models.auv_nav.fix_posterior_variance`, the USBL's variances at the target
  circle's slant range, :func:`~mpcasv.models.auv_nav.fix_variance`, thesis eq. 2.9), held
  while the ASV stands by ``T_stay``, then ``P+ + eps_a^2 / 8 (t - t_leave)^4``;
- the ASV moves at ``U`` and meets each AUV on its target circle ``r_t`` where the AUV will
  be then (:func:`meet_time`, the AUV's forecast: along its plan, else constant velocity);
- ``e_go``: the OCP's cost per second of a transit at ``U`` (thrust, power and running terms
  of eq. M4 at the thrust holding ``U``; :func:`transit_cost`).

The first AUV of the cheapest order is the OCP's target (:func:`committed_target`: a served
target gives way only to an order ``hysteresis`` cheaper). Source: the branch ``mpcorder``
of session 4 (docs/mpc.md has its measured closed loop).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from mpcasv.models.auv_nav import (
    dr_variance,
    dr_variance_integral,
    fix_posterior_variance,
    fix_variance,
)

#: enumerating K! orders is cheap up to here (24 orders); a run with more AUVs is refused
#: before it starts (:func:`auv_limit`, read by the registry's ``check_auv_count``)
MAX_ENUMERATED = 4
MEET_ITERATIONS = 40
MEET_TOL = 0.01  # s
MEET_MAX = 3600.0  # s: an AUV faster than the ASV and going away is met "never"

Forecast = Callable[[np.ndarray], np.ndarray]  # offsets (n,) s -> positions (n, 2) m


@dataclass(frozen=True)
class OrderModel:
    """What the top level assumes (SI units).

    Attributes
    ----------
    eps_a : float
        The AUVs' accelerometer error (m/s^2; thesis eq. 2.7).
    sigma_range, sigma_bearing : float
        USBL range noise (m) and bearing error (rad): the fix's variances (thesis eq. 2.9).
    U : float
        Transit speed (m/s).
    T_stay : float
        Standby at each AUV visited (s): the fixes hold its variance at ``P+``.
    window : float
        Window ``W`` over which orders are compared (s).
    nav : float
        Cost per second of one ``V_ref`` of variance (the OCP's ``nav`` weight).
    V_ref : float
        Reference variance (m^2): ``dr_variance(eps_a, tau_ref)``.
    e_go : float
        Cost per second of transit (:meth:`mpcasv.mpc.problem.OCP.transit_cost`).
    """

    eps_a: float
    sigma_range: float
    sigma_bearing: float
    U: float
    T_stay: float
    window: float
    nav: float
    V_ref: float
    e_go: float


@dataclass(frozen=True)
class OrderPlan:
    """The cheapest order and what it costs.

    Attributes
    ----------
    order : tuple of int
        AUV indices in the order of visits; ``order[0]`` is the OCP's target.
    cost : float
        J of eq. O1.
    arrive : ndarray (K,)
        When the ASV meets each AUV under this order (s from now).
    costs : dict
        J of every order enumerated.
    """

    order: tuple[int, ...]
    cost: float
    arrive: np.ndarray
    costs: dict


def meet_time(start: np.ndarray, forecast: Forecast, r_t: float, U: float,
              t0: float = 0.0) -> float:  # fmt: skip
    """Time (s after ``t0``) for the ASV leaving ``start`` (N, E; m) at ``t0`` at speed ``U``
    (m/s) to reach the target circle ``r_t`` (m) of an AUV moving along ``forecast`` (offsets
    from now -> positions): the fixed point ``s = max(|p(t0 + s) - start| - r_t, 0) / U``,
    iterated from ``s = 0`` to ``MEET_TOL`` (a contraction while the AUV is slower than the
    ASV; at most ``MEET_ITERATIONS``, capped at ``MEET_MAX``). An AUV coming towards the ASV
    is met sooner than its present distance says."""
    s = 0.0
    start = np.asarray(start, float)
    for _ in range(MEET_ITERATIONS):
        p = np.asarray(forecast(np.array([t0 + s])), float).reshape(2)
        s_new = min(max(float(np.hypot(*(p - start))) - r_t, 0.0) / U, MEET_MAX)
        if abs(s_new - s) < MEET_TOL:
            return s_new
        s = s_new
    return s


def order_cost(order: Sequence[int], asv_NE: np.ndarray, forecasts: Sequence[Forecast],
               depth: np.ndarray, tau: np.ndarray, r_t: np.ndarray,
               m: OrderModel) -> tuple[float, np.ndarray]:  # fmt: skip
    """J of eq. O1 for one order and the meeting times (s, ``inf`` beyond the window).

    Parameters
    ----------
    order : sequence of int
    asv_NE : array (2,)
        The ASV's position (m).
    forecasts : K callables
        Each AUV's forecast position at offsets from now.
    depth, tau, r_t : arrays (K,)
        Depth (m), equivalent fix age (s), target-circle radius (m) of each AUV.
    m : OrderModel
    """
    K, W = len(forecasts), m.window
    arrive = np.full(K, math.inf)
    # each AUV's variance is P + dr_variance(t - t_ref): before any visit P = 0 and the
    # growth started tau ago; after a visit P = P+ from the moment the ASV leaves
    P, t_ref, t_done = np.zeros(K), -np.asarray(tau, float), np.zeros(K)
    nav = 0.0
    t, pos, transit = 0.0, np.asarray(asv_NE, float), 0.0
    for i in itertools.cycle(order):  # the tour repeats until the window is over
        if t >= W or not order:
            break
        s = meet_time(pos, forecasts[i], float(r_t[i]), m.U, t)
        transit += min(s, W - t)
        t += s
        if t >= W:
            break
        arrive[i] = min(arrive[i], t)
        nav += P[i] * (t - t_done[i]) + dr_variance_integral(m.eps_a, t_done[i] - t_ref[i],
                                                             t - t_ref[i])  # fmt: skip
        slant = math.hypot(float(r_t[i]), float(depth[i]))
        V = P[i] + dr_variance(m.eps_a, t - t_ref[i])
        P[i] = fix_posterior_variance(V, *fix_variance(slant, m.sigma_range, m.sigma_bearing))
        held = min(m.T_stay, W - t)  # fixes while standing by hold it at P+
        nav += P[i] * held
        t += held
        t_ref[i] = t_done[i] = t
        p_i = np.asarray(forecasts[i](np.array([t])), float).reshape(2)
        rel = pos - p_i
        d = float(np.hypot(*rel))
        pos = p_i + (rel / d * r_t[i] if d > 1e-9 else np.array([r_t[i], 0.0]))
    for i in range(K):  # from each AUV's last visit (or now) to the window's end
        nav += P[i] * (W - t_done[i]) + dr_variance_integral(m.eps_a, t_done[i] - t_ref[i],
                                                             W - t_ref[i])  # fmt: skip
    return m.nav / m.V_ref * nav + m.e_go * transit, arrive


def auv_limit(params) -> tuple[int, str] | None:
    """The most AUVs controller parameters ``params`` can serve, with the reason, if the
    visiting order limits them (``target_rule = "order"``: ``MAX_ENUMERATED``); else None.

    The ``mpc-multi`` kind's ``auv_limit``, read by
    :func:`mpcasv.controllers.registry.check_auv_count`, so that such a run is
    refused before it compiles or runs (rather than by :func:`best_order` at its first step).
    """
    if getattr(params, "target_rule", None) != "order":
        return None
    return MAX_ENUMERATED, ('target_rule = "order" enumerates the K! visiting orders; '
                            "preset mpc-multi has no limit")


def best_order(asv_NE: np.ndarray, forecasts: Sequence[Forecast], depth: np.ndarray,
               tau: np.ndarray, r_t: np.ndarray, m: OrderModel) -> OrderPlan:  # fmt: skip
    """The cheapest order of visiting every AUV (eq. O1), by enumeration.

    Raises
    ------
    ValueError
        More than ``MAX_ENUMERATED`` AUVs (the enumeration grows as K!).
    """
    K = len(forecasts)
    if K > MAX_ENUMERATED:
        raise ValueError(f"visiting orders are enumerated for at most {MAX_ENUMERATED} AUVs,"
                         f" got {K}")  # fmt: skip
    costs, arrivals = {}, {}
    for order in itertools.permutations(range(K)):
        costs[order], arrivals[order] = order_cost(order, asv_NE, forecasts, depth, tau, r_t, m)
    best = min(costs, key=costs.__getitem__)
    return OrderPlan(best, costs[best], arrivals[best], costs)


def transit_cost(weights, T_go: float, T_max: float, u_max: float) -> float:
    """Cost per second of a transit at ``weights.U_go`` (the ``e_go`` of eq. O1): the thrust,
    power and running terms of eq. M4 at the thrust ``T_go`` (N) holding that speed, with
    the vessel's ``T_max`` (N) and ``u_max`` (m/s) as the OCP normalises them.

    ``weights`` is a :class:`~mpcasv.mpc.params.WeightParams`."""
    T = min(T_go, T_max)
    return (weights.thrust * T / T_max + weights.power * T * weights.U_go / (T_max * u_max)
            + weights.running)  # fmt: skip


def committed_target(plan: OrderPlan, current: int, hysteresis: float,
                     served: bool = False) -> int:  # fmt: skip
    """The target after a re-plan with commitment (issue 16 item 6): the first AUV of the
    cheapest order, unless the cheapest order that starts with the ``current`` target is
    within ``hysteresis`` (a fraction) of it, in which case the target stays. A ``served``
    target (committed, then served: the re-plan comes because it was) is left: the first AUV
    of the cheapest order that starts elsewhere (with one AUV: it stays). Staying would
    commit to it anew, for another whole visit: the order model values a stay at the served
    AUV as holding its variance at ``P+`` for ``T_stay``, so with a 2 % band the ASV stood
    by a served AUV a second time (session 16)."""
    if served and len(plan.order) > 1:
        return min((o for o in plan.costs if o[0] != current), key=plan.costs.__getitem__)[0]
    keep = min(c for o, c in plan.costs.items() if o[0] == current)
    if plan.order[0] != current and keep <= (1.0 + hysteresis) * plan.cost:
        return current
    return plan.order[0]
