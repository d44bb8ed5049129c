"""Surge speed loop and surge-speed reference model tuning (``mpcasv tune speed``).

Speed loop (mpcasv/control/execution.py): ``T_cmd = T_ff(u_ref) + Kp e_u + Ki int(e_u)`` with
the model's trim thrust as feed-forward. The surge dynamics linearised about the straight-line
trim (:meth:`VesselModel.linearize`) are ``u_dot = -a u + b T``, ``T_dot = (T_cmd - T)/T_thrust``;
the PI is placed on the first-order part, ``s^2 + (a + b Kp) s + b Ki = s^2 + 2 zeta w s + w^2``,
at one design speed (the execution level has one pair of speed gains), and the margins and step
figures are checked at every speed *with* the thrust lag, continuous and sampled.

Surge-speed reference model, thesis eq. 3.1: ``u_cmd = u_ff + k_u (pi/2 - |psi_e|)``
(``u_ff`` if ``|psi_e| >= pi/2``). It is checked on the nonlinear closed loop: starting at full
speed, turns of 90 and 180 deg towards a waypoint at a fixed distance must reach it without
"pirouettes" (circling the waypoint instead of reaching it: :data:`PIROUETTE_TURN`).
"""

from __future__ import annotations

import dataclasses
import math

import control as ct
import numpy as np

from mpcasv.config import replace
from mpcasv.control.params import ExecutionParams, SpeedLoop, SpeedReference
from mpcasv.control.tuning import run_closed_loop, settling_time
from mpcasv.models.vessel import IX, VesselModel

#: heading band that counts as "on course" (rad)
TURN_BAND = math.radians(10.0)
#: radius of the acceptance circle (m): a turn has reached its waypoint once the boat is this
#: close to it (about one hull length of Gretha, 5.2 m, PAPER-FACTS §1: the scale below which
#: a point is reached; the turn's figures stop there, where the line-of-sight heading to a point
#: under the bow stops meaning anything)
ARRIVAL_RADIUS = 5.0
#: heading change (rad) with the heading error outside :data:`TURN_BAND` (beyond the commanded
#: turn, for the stretch that starts it) that makes a pirouette: one full circle. A boat whose
#: turning circle leaves the waypoint outside points its bow at it within one revolution (its
#: heading sweeps every direction while the line of sight to the waypoint moves less); one that
#: turns a full circle without doing so circles the waypoint instead of reaching it, the
#: pirouettes of thesis §3.4.1 ("pirouettes instead of following its set-point ... not able to
#: achieve its desired heading")
PIROUETTE_TURN = 2 * math.pi
#: size of the speed steps of ``mpcasv tune speed`` (m/s) and length of their nonlinear runs (s)
SPEED_STEP, STEP_T_END = 0.5, 120.0


def surge_plant(model: VesselModel, u0: float) -> ct.StateSpace:
    """Linearised surge dynamics at ``u0``: states ``u, T``; input ``T_cmd`` (N); output ``u``."""
    A, B = model.linearize(*model.trim(u0))
    idx = [IX["u"], IX["T"]]
    return ct.ss(A[np.ix_(idx, idx)], B[np.ix_(idx, [0])], [[1.0, 0.0]], [[0.0]],
                 states=["u", "T"], inputs=["T_cmd"], outputs=["u"])  # fmt: skip


def place_speed_pi(model: VesselModel, u0: float, w: float, zeta: float) -> SpeedLoop:
    """PI gains by pole placement on the first-order surge model at ``u0`` (lag neglected)."""
    A, _ = model.linearize(*model.trim(u0))
    a, b = -A[IX["u"], IX["u"]], A[IX["u"], IX["T"]]
    return SpeedLoop(Kp=max((2 * zeta * w - a) / b, 0.0), Ki=w * w / b)


def pi_tf(g: SpeedLoop, dt: float | None = None) -> ct.TransferFunction:
    """The speed PI as a transfer function: ``Kp + Ki/s``, or with ``dt`` the forward-Euler
    integrator of :func:`mpcasv.control.execution.execution_law`. With ``Kp = 0``
    (:func:`place_speed_pi` clips it) the numerator has no leading zero, which scipy calls
    "badly conditioned" (a BadCoefficients warning per use)."""
    if dt is None:
        return ct.tf(np.trim_zeros([g.Kp, g.Ki], "f"), [1.0, 0.0])
    return ct.tf(np.trim_zeros([g.Kp, g.Ki * dt - g.Kp], "f"), [1.0, -1.0], dt)


def feed_forward_gain(model: VesselModel, u0: float) -> float:
    """Slope at ``u0`` (N/(m/s)) of the speed loop's feed-forward
    :func:`mpcasv.control.execution.feed_forward_thrust` (central difference)."""
    from mpcasv.control.execution import feed_forward_thrust

    P, h = model.params, 1e-4
    return float(feed_forward_thrust(u0 + h, P) - feed_forward_thrust(u0 - h, P)) / (2 * h)


def trim_integrator(model: VesselModel, u0: float) -> float:
    """The speed integrator's value in trim at ``u0`` (N): the trim thrust
    (:meth:`VesselModel.thrust_for_speed`, idle-drive drag included) less the feed-forward
    :func:`mpcasv.control.execution.feed_forward_thrust`, which leaves that drag out (Gretha:
    +1.24 N at 0.5 m/s, below 1e-4 N from 1 m/s, where the thrust blends the drag out)."""
    from mpcasv.control.execution import feed_forward_thrust

    return model.thrust_for_speed(u0) - float(feed_forward_thrust(u0, model.params))


def speed_figures(P: ct.StateSpace, g: SpeedLoop, dt: float | None = None,
                  step: float = 0.5, ff: float = 0.0) -> dict[str, float]:  # fmt: skip
    """Margins (``stability_margins``, balanced ``disk_margins``) and ``step`` m/s step figures.

    With ``dt`` the plant is sampled (ZOH) and the integrator is forward Euler, as in
    :func:`mpcasv.control.execution.execution_law`. ``ff`` (N/(m/s), :func:`feed_forward_gain`)
    is the execution level's feed-forward of the speed reference, outside the loop: it
    changes the step (``u/u_ref = P (C + ff) / (1 + P C)``), not the margins; 0 gives the
    feedback loop's own step.
    """
    C = pi_tf(g, dt)
    if dt is not None:
        P = ct.c2d(P, dt, "zoh")
    from mpcasv.control.tuning import loop_margins, step_figures

    L = ct.ss(C) * P
    t = np.arange(0.0, 120.0, dt or 0.05)
    cl = ct.feedback(L, 1)
    ref = cl + ct.feedback(P, ct.ss(C)) * ff if ff else cl
    with np.errstate(over="ignore", invalid="ignore"):  # an unstable loop diverges: "inf"
        y = ct.step_response(ref, t).outputs * step
    poles = ct.poles(cl)
    stable = bool(np.all(np.abs(poles) < 1) if dt else np.all(poles.real < 0))
    return loop_margins(L) | step_figures(y, t, step) | {"stable": stable}


def unsettled_steps(loop: dict, steps: dict) -> list[str]:
    """The speed steps that do not settle (2 %) within their run: the linear ones of
    :func:`speed_figures` (``loop``: ``{u0: (continuous, sampled)}``, with the feed-forward)
    and the nonlinear :func:`speed_step` ones that were run (``steps``: ``{u0: [...]}``), as
    "linear at 0.5 m/s" / "0.5->1 m/s". Part of ``tune speed``'s acceptance, as the nonlinear
    heading step is of ``tune yaw``'s: margins alone passed a PI with ``Kp = 0``, ``Ki = 1e-5``
    (``--w 0.0001``, crossover 1e-7 rad/s) whose step from 0.5 to 1 m/s never settled."""
    out = [f"linear at {u:g} m/s" for u, figs in loop.items()
           if not all(math.isfinite(f["settling_s"]) for f in figs)]  # fmt: skip
    out += [f"{st['u0']:g}->{st['u1']:g} m/s" for v in steps.values() for st in v
            if st["reachable"] and not math.isfinite(st["settling_s"])]  # fmt: skip
    return out


def straight_speed_limit(model: VesselModel, ep: ExecutionParams) -> tuple[float, str]:
    """The fastest speed the execution level can hold on a straight course (m/s) and what
    sets it: the vessel's top speed at ``T_max`` (:attr:`VesselModel.top_speed`), its speed
    cap ``u_max``, or eq. 3.1 at zero heading error, ``u_ff + k_u pi/2``."""
    P, ref = model.params, ep.reference
    limits = {f"top speed at T_max = {P.T_max:.4g} N": model.top_speed,
              "speed cap u_max": P.u_max,
              "eq. 3.1's u_ff + k_u pi/2": u_cmd_max(ref.u_ff, ref.k_u)}  # fmt: skip
    why = min(limits, key=limits.get)
    return float(limits[why]), why


def speed_step(model: VesselModel, ep: ExecutionParams, u0: float, u1: float,
               t_end: float = STEP_T_END) -> dict:  # fmt: skip
    """Nonlinear speed step ``u0 -> u1`` (m/s) on a straight course, thrust limits included.

    As :func:`mpcasv.control.tuning_yaw.heading_step`: the vessel starts in trim at ``u0``
    heading north (the speed integrator too: :func:`trim_integrator`, so a step to ``u0``
    would hold it), the waypoint is :data:`~mpcasv.control.tuning.FAR` ahead and the command's
    speed is ``u1``, through :func:`~mpcasv.control.tuning.run_closed_loop` (the simulator's
    compiled execution level and vessel model; thrust clipped to ``[T_min, T_max]``).

    Returns ``u0``, ``u1``, ``direction`` ("up"/"down"), ``reachable`` and, if not, ``why``
    (``u1 <= 0``, or above :func:`straight_speed_limit`: no run); else ``rise_s`` (10-90 %),
    ``settling_s`` (2 %), ``overshoot_pct`` (of the step, as :func:`speed_figures`) and
    ``at_T_max``, ``at_T_min``: the fractions of the ``t_end`` s run with the thrust at that
    limit (the linear loop's figures hold only while they are 0), ``t_end`` (s) and ``u_end``
    (m/s). ``why`` starts "UNREACHABLE" for a target above the straight-course limit.
    """
    from mpcasv.control.tuning import FAR, step_figures

    out = {"u0": float(u0), "u1": float(u1), "direction": "up" if u1 > u0 else "down"}
    limit, why = straight_speed_limit(model, ep)
    if u1 <= 0:
        return out | {"reachable": False, "why": f"not run: target {u1:g} m/s is a stop, not "
                      "a forward speed"}  # fmt: skip
    if u1 > limit * (1 + 1e-6):
        return out | {"reachable": False, "why": f"UNREACHABLE: target {u1:g} m/s above the "
                      f"{why} ({limit:.3g} m/s)"}  # fmt: skip
    x0, _ = model.trim(u0)
    run = run_closed_loop(model, ep, x0, (FAR, 0.0), u1, t_end, I_u=trim_integrator(model, u0))
    sign = 1.0 if u1 > u0 else -1.0
    y = (run.X[:, IX["u"]] - u0) * sign
    T = run.U[1:, 0]  # thrust applied over each step
    P = model.params
    tol = 1e-6 * P.T_max
    return out | {"reachable": True} | step_figures(y, run.t, abs(u1 - u0)) | {
        "at_T_max": float(np.mean(T >= P.T_max - tol)),
        "at_T_min": float(np.mean(T <= P.T_min + tol)),
        "u_end": float(run.X[-1, IX["u"]]),
        "t_end": float(run.t[-1]),
    }  # fmt: skip


def arrival(X: np.ndarray, wp, radius: float = ARRIVAL_RADIUS) -> tuple[np.ndarray, int]:
    """The distances (m, shape (n,)) of the states ``X`` (rows ``[N, E, ...]``) from the
    waypoint ``wp`` and the index of the first within ``radius`` m (``n`` if none): the one
    definition of "reached" for the turns, their rule and their plots."""
    dist = np.hypot(X[:, 0] - wp[0], X[:, 1] - wp[1])
    near = dist < radius
    return dist, int(np.argmax(near)) if near.any() else len(dist)


def headed_for(psi_e: np.ndarray, dist: np.ndarray, start: int, radius: float) -> int:
    """The first index from ``start`` at which the boat heads for the waypoint: its heading
    error ``psi_e`` (rad) is within :data:`TURN_BAND` and stays below pi/2 (the boat keeps
    closing on the waypoint, as seen from its bow: eq. 3.1's ``|psi_e| < pi/2``) until it is
    next within ``radius`` m of it (``dist``, m), or to the end of the run; ``len(psi_e)`` if
    never. A heading that only sweeps through the band (a boat spinning through its heading)
    is not heading for the waypoint: the rule cut its stretches there, so 1199 deg of spin
    counted as 339 deg (a review); a boat that heads for it and wobbles out of the band on the
    way (Gretha turning back after passing it: on course, then 16 deg off as she speeds up)
    still is."""
    err = np.abs(psi_e)
    on, closing = err <= TURN_BAND, err < math.pi / 2  # a non-finite error is neither
    m = len(err)
    inside = np.flatnonzero(dist[start:] < radius) + start
    i = start
    while i < m:
        if not on[i]:
            i += 1
            continue
        nxt = inside[inside >= i]
        stop = int(nxt[0]) if len(nxt) else m  # the next arrival (or the end)
        away = np.flatnonzero(~closing[i:stop])
        if not len(away):
            return i
        i += int(away[0])
    return m


def circling(run, wp, angle: float, radius: float = ARRIVAL_RADIUS) -> float:
    """The heading change (rad) the boat of ``run`` turned without heading for the waypoint
    ``wp`` (:func:`headed_for`: on course, ``|psi_e| <= TURN_BAND``, and staying so until it
    is next within ``radius`` m of it), the larger of two parts:

    * the approach, until the first arrival within ``radius`` (the line of sight to a
      waypoint under the bow swings round as the boat passes it): every heading change made
      off course before the boat heads for it, less the commanded turn ``|angle|``;
    * after the arrival, until the boat heads back for the waypoint: the heading change made
      off course outside the circle. A boat that has reached the waypoint and turned back
      towards it is not circling it, nor one that orbits inside the circle (a small hull that
      passed it: every dune-otter turn read as a pirouette, a review), while one that loops
      round it, passing near it each time (Gretha without eq. 3.1), is.

    More than :data:`PIROUETTE_TURN` is a pirouette. (Until a review each stretch off course
    was counted alone, cut wherever the heading error swept through the band: a boat spinning
    in place, its bow crossing the waypoint's bearing once a turn, was never flagged.)"""
    dist, n = arrival(run.X, wp, radius)
    out = ~(np.abs(run.psi_error) <= TURN_BAND)  # a non-finite error is outside
    dpsi = np.abs(np.diff(np.unwrap(run.X[:, 2])))  # dpsi[k]: from sample k to k + 1
    k = np.arange(len(dpsi))
    j = headed_for(run.psi_error[:n], dist[:n], 0, radius)
    worst = float(np.sum(dpsi[(k < j) & out[:-1]])) - abs(angle)
    if n < len(out):  # after the arrival: off course until it heads back, outside the circle
        back = headed_for(run.psi_error, dist, n, radius)
        sel = (k >= n) & (k < back) & out[:-1] & (dist[:-1] >= radius)
        worst = max(worst, float(np.sum(dpsi[sel])))
    return max(worst, 0.0)


def turn(model: VesselModel, ep: ExecutionParams, angle: float, distance: float,
         t_end: float = 150.0, u0: float | None = None):  # fmt: skip
    """Turn by ``angle`` (rad) from full speed (or trim at ``u0``; the speed integrator at its
    trim value, :func:`trim_integrator`) towards a waypoint ``distance`` m away.

    Returns the run and ``{"turn_s", "turn_m", "reached", "reach_s", "pirouette",
    "circling_deg", "total_turn_deg", "min_u"}``: time (s) and path length (m) until the turn
    is done, i.e. the heading error stays within :data:`TURN_BAND` until the arrival, or the
    boat is within :data:`ARRIVAL_RADIUS` of the waypoint, whichever comes first (``inf`` if
    neither within ``t_end``); whether and when (s) it reached that circle; the heading change
    (deg) until the turn was done; :func:`circling` (deg) and whether it pirouetted (more than
    :data:`PIROUETTE_TURN`); the least surge speed (m/s) until the turn was done.
    """
    if u0 is None:
        u0 = min(model.top_speed, model.params.u_max)
    x0, _ = model.trim(u0)
    wp = (distance * math.cos(angle), distance * math.sin(angle))
    run = run_closed_loop(model, ep, x0, wp, model.params.u_max, t_end,
                          I_u=trim_integrator(model, u0))
    _, n = arrival(run.X, wp)
    reached = n < len(run.t)
    ts = settling_time(run.t[:n], run.psi_error[:n], TURN_BAND)  # on course until the arrival
    if reached and not ts < run.t[n]:
        ts = float(run.t[n])
    i = int(round(ts / (run.t[1] - run.t[0]))) if math.isfinite(ts) else len(run.t) - 1
    total = float(np.sum(np.abs(np.diff(np.unwrap(run.X[: i + 1, 2])))))
    circ = circling(run, wp, angle)
    return run, {
        "turn_s": ts,
        "turn_m": float(run.distance[i]) if math.isfinite(ts) else math.inf,
        "reached": reached,
        "reach_s": float(run.t[n]) if reached else math.inf,
        "pirouette": bool(circ > PIROUETTE_TURN),
        "circling_deg": float(np.degrees(circ)),
        "total_turn_deg": float(np.degrees(total)),
        "min_u": float(run.X[: i + 1, 3].min()),
    }


@dataclasses.dataclass(frozen=True)
class TurnRow:
    """One (u_ff, k_u) pair of the reference-model grid."""

    u_ff: float
    k_u: float
    figures: dict  # angle_deg -> turn() figures

    @property
    def ok(self) -> bool:
        """Every turn reached its waypoint (within :data:`ARRIVAL_RADIUS`) without a
        pirouette (:data:`PIROUETTE_TURN`)."""
        return all(f["reached"] and not f["pirouette"] for f in self.figures.values())

    @property
    def cost(self) -> float:
        """Sum of the turn times (s): :func:`recommend` minimises it among the rows that are
        :attr:`ok` and within the ``u_cmd,max`` bound."""
        return float(sum(f["turn_s"] for f in self.figures.values()))


def turn_grid(model: VesselModel, ep: ExecutionParams, pairs, angles_deg=(90.0, 180.0),
              distance: float = 50.0, progress: bool = False):  # fmt: skip
    """Run :func:`turn` for each (u_ff, k_u) pair and angle; returns rows and runs."""
    from tqdm import tqdm

    rows, runs = [], {}
    for u_ff, k_u in tqdm(list(pairs), desc="turn grid", disable=not progress):
        epi = replace(ep, reference=SpeedReference(u_ff=u_ff, k_u=k_u))
        figs = {}
        for a in angles_deg:
            runs[(u_ff, k_u, a)], figs[a] = turn(model, epi, math.radians(a), distance)
        rows.append(TurnRow(u_ff=u_ff, k_u=k_u, figures=figs))
    return rows, runs


def merge_grids(grids: dict) -> list[TurnRow]:
    """One row per (u_ff, k_u) with the turns of every distance of ``grids`` (``{distance:
    (rows, runs)}`` of :func:`turn_grid`; the last row of each, the baseline without the
    reference model, left out), figures keyed ``"<distance>m/<angle>"``."""
    by_pair: dict = {}
    for d, (rows, _) in grids.items():
        for r in rows[:-1]:
            figs = by_pair.setdefault((r.u_ff, r.k_u), {})
            figs.update({f"{d}m/{a}": f for a, f in r.figures.items()})
    return [TurnRow(u_ff=a, k_u=b, figures=f) for (a, b), f in by_pair.items()]


def u_cmd_max(u_ff: float, k_u: float) -> float:
    """Eq. 3.1's largest speed command, at zero heading error: ``u_ff + k_u pi/2`` (m/s)."""
    return u_ff + k_u * math.pi / 2


#: relative slack of the ``u_cmd,max`` bound, so that the bound a pair itself sets admits it
U_CMD_MAX_RTOL = 1e-6


def within(u_ff: float, k_u: float, bound: float) -> bool:
    """Whether eq. 3.1's largest command :func:`u_cmd_max` is at most ``bound`` (m/s), with
    :data:`U_CMD_MAX_RTOL` of slack (the bound a pair itself sets admits it)."""
    return u_cmd_max(u_ff, k_u) <= bound * (1 + U_CMD_MAX_RTOL)


def admitted(rows: list[TurnRow], bound: float) -> list[TurnRow]:
    """The rows whose :func:`u_cmd_max` is at most ``bound`` (m/s). The thesis chose ``k_u``
    for a given ``u_ff`` to hold ``u_cmd,max`` at the boat's rated maximum speed (§3.4.1:
    ``u_ff`` 0.4 -> 0.6 m/s with ``k_u`` 1.72 -> 1.59 m/s "to maintain the maximum commanded
    speed", 3.1 m/s), and found lower ``k_u`` more stable: the turn times alone only fall as
    ``k_u`` grows, so without the bound the grid's largest ``k_u`` always won."""
    return [r for r in rows if within(r.u_ff, r.k_u, bound)]


def recommend(rows: list[TurnRow], bound: float = math.inf) -> TurnRow:
    """Among the rows :func:`admitted` under ``bound`` (m/s) whose turns all reached the
    waypoint without a pirouette (:attr:`TurnRow.ok`), the one with the least total turn
    time; ValueError if none."""
    good = [r for r in admitted(rows, bound) if r.ok]
    if not good:
        raise ValueError(why_none(rows, bound))
    return min(good, key=lambda r: r.cost)


def why_none(rows: list[TurnRow], bound: float) -> str:
    """Why :func:`recommend` found no pair: of the rows :func:`admitted` under ``bound``
    (m/s), how many pirouetted in some turn (P) and how many missed a waypoint in the run (NR).
    The summary said "no pair of the grid reached every waypoint" when every pair had reached
    every waypoint and pirouetted (a review)."""
    ok = admitted(rows, bound)
    pir = sum(any(f["pirouette"] for f in r.figures.values()) for r in ok)
    nr = sum(any(not f["reached"] for f in r.figures.values()) for r in ok)
    parts = [f"{pir} pirouetted in a turn (P)"] if pir else []
    parts += [f"{nr} did not reach a waypoint within the run (NR)"] if nr else []
    return (f"of the {len(ok)} (u_ff, k_u) pairs of the grid with u_ff + k_u pi/2 <= "
            f"{bound:.4g} m/s, {' and '.join(parts) or 'none passed'}: no recommendation")


def edge_notes(best: TurnRow, rows: list[TurnRow], bound: float) -> list[str]:
    """Where the recommendation ``best`` sits on the grid ``rows``: on its edge (the largest
    or smallest ``u_ff`` or ``k_u`` given: the optimum may lie beyond, a warning), or with
    ``k_u`` set by the ``u_cmd,max`` ``bound`` (a larger ``k_u`` of the grid at that ``u_ff``
    was excluded by it: the rule at work)."""
    out = []
    for name, values, v in (("u_ff", {r.u_ff for r in rows}, best.u_ff),
                            ("k_u", {r.k_u for r in rows}, best.k_u)):  # fmt: skip
        if len(values) < 2:
            continue
        ok = admitted(rows, bound)
        larger = [r for r in rows if r.u_ff == best.u_ff and r.k_u > best.k_u]
        # the bound sets k_u only when every larger k_u at this u_ff is above it (one within
        # it lost on time or on a pirouette: then the note was false, a review)
        larger_cut = name == "k_u" and bool(larger) and not any(r in ok for r in larger)
        if larger_cut:
            out.append(f"k_u = {v:g} is the largest of the grid at u_ff = {best.u_ff:g} with "
                       f"u_ff + k_u pi/2 <= {bound:.4g} m/s (--u-cmd-max): the bound sets it")
        elif v in (max(values), min(values)):
            end = "largest" if v == max(values) else "smallest"
            out.append(f"{name} = {v:g} is the grid's {end}: the least turn time may lie "
                       f"beyond it (extend --{name.replace('_', '-')})")
    return out


def without_reference(ep: ExecutionParams, model: VesselModel) -> ExecutionParams:
    """``ep`` with eq. 3.1 switched off: the speed reference is the command at every heading
    error (``u_ff = u_max``, ``k_u = 0``)."""
    return replace(ep, reference=SpeedReference(u_ff=model.params.u_max, k_u=0.0))


#: the pirouette check of docs/tuning.md: (angle deg, distance m, start speed m/s)
PIROUETTE_CASE = (90.0, 10.0, 0.6)


def pirouette_check(model: VesselModel, ep: ExecutionParams, angle_deg: float = 150.0,
                    distance: float = 25.0, u0: float = 0.6, t_end: float = 120.0):  # fmt: skip
    """Hard turn while accelerating (thesis §3.4.1), with and without eq. 3.1.

    From trim at ``u0`` (slow, e.g. leaving standby) the waypoint is ``distance`` m away at
    ``angle_deg`` off the bow and the command asks for ``u_max``. Returns
    ``{"with": (run, figures), "without": (run, figures)}`` with :func:`turn`'s figures.
    """
    a = math.radians(angle_deg)
    return {
        "with": turn(model, ep, a, distance, t_end, u0=u0),
        "without": turn(model, without_reference(ep, model), a, distance, t_end, u0=u0),
    }
