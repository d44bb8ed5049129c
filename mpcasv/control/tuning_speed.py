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
"pirouettes" (circling the waypoint instead of reaching it): :mod:`mpcasv.control.tuning_turns`,
whose names are re-exported here.
"""

from __future__ import annotations

import math

import control as ct
import numpy as np

from mpcasv.control.params import ExecutionParams, SpeedLoop
from mpcasv.control.tuning import run_closed_loop
from mpcasv.control.tuning_turns import (  # noqa: F401  (re-exported: one place to import)
    ARRIVAL_RADIUS,
    PIROUETTE_CASE,
    PIROUETTE_TURN,
    TURN_BAND,
    TURN_RUN_MAX,
    TURN_T_END,
    U_CMD_MAX_RTOL,
    TurnRow,
    admitted,
    arrival,
    circling,
    distance_refusal,
    edge_notes,
    headed_for,
    in_circle,
    merge_grids,
    pirouette_check,
    recommend,
    turn,
    turn_grid,
    turn_time,
    u_cmd_max,
    why_none,
    within,
    without_reference,
)
from mpcasv.models.vessel import IX, VesselModel

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
