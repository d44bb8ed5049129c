"""The execution level, written symbolically (CasADi) so that it runs inside the plant step.

Between two supervisory decisions the command is constant, so guidance, the surge-speed
reference model, the yaw PID, the speed loop and the vessel model are unrolled together into
one compiled CasADi function per supervisory period (:func:`closed_loop`). That keeps the
simulator fast (one call per second of simulated time) while the code below reads as plain
control law. The same laws run in the tuning tools' nonlinear checks.

Command vector ``cmd = [transit, N_wp, E_wp, U_cap]`` with ``transit`` 0 (standby), 1 (transit)
or 2 (transit for collision avoidance: only the optional power turn tells it apart);
controller state ``z = [I_psi, I_u, r_f]`` (yaw integrator output in rad, speed integrator
output in N, filtered yaw rate in rad/s). Standby (transit = 0) commands zero thrust and
zero steering and resets the integrators.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

from mpcasv.control.params import ExecutionParams
from mpcasv.models.envelope import rk4_sub_steps
from mpcasv.models.vessel import NC, NX, VesselModel, rk4_expr, sabs

NZ = 3
NCMD = 4
Z_NAMES = ("I_psi", "I_u", "r_f")


def wrap(a):
    """Wrap an angle to (-pi, pi] (works on numbers and CasADi expressions)."""
    return ca.atan2(ca.sin(a), ca.cos(a))


def pwlinear(x, xs, ys):
    """Piecewise-linear interpolation through (xs, ys), clamped outside [xs[0], xs[-1]]."""
    if len(xs) == 1:
        return ys[0]
    xc = ca.fmin(ca.fmax(x, xs[0]), xs[-1])
    y = ys[0]
    for i in range(1, len(xs)):
        slope = (ys[i] - ys[i - 1]) / (xs[i] - xs[i - 1])
        y = y + slope * (ca.fmin(xc, xs[i]) - ca.fmin(xc, xs[i - 1]))
    return y


def _integrate(I, dI, out_unsat, limit):
    """Anti-windup by conditional integration (clamping): integrate unless the output is
    saturated and the increment would push it further; keep |I| <= limit.

    (Back-calculation was tried first: with heading errors near pi the proportional term
    alone saturates, the tracking term then drives the integrator far negative, and the
    rudder reverses as soon as the error shrinks.)
    """
    saturated = ca.fabs(out_unsat) >= limit
    pushing = ca.sign(dI) == ca.sign(out_unsat)
    I_next = ca.if_else(ca.logic_and(saturated, pushing), I, I + dI)
    return ca.fmin(ca.fmax(I_next, -limit), limit)


def guidance(x, wp):
    """Desired heading: straight at the waypoint (line of sight)."""
    return ca.atan2(wp[1] - x[1], wp[0] - x[0])


def speed_reference(psi_e, u_ff, k_u):
    """Thesis eq. 3.1: u_cmd = u_ff + k_u (pi/2 - |psi_e|) if |psi_e| < pi/2, else u_ff."""
    return u_ff + k_u * ca.fmax(math.pi / 2 - ca.fabs(psi_e), 0)


def feed_forward_thrust(u_ref, P):
    """The speed loop's feed-forward (N): the trim thrust of eq. 2.6 without the idle-drive
    drag, ``T_ff(u_ref) = -(X_u u_ref + X_uu |u_ref| u_ref)`` (``|.|`` smoothed by
    :func:`~mpcasv.models.vessel.sabs`; ``u_ref`` in m/s, ``P`` the vessel's parameters).
    The idle-drive drag is left to the integrator: below 3 % of the trim thrust at
    ``u_ref >= u_ff``. Works on numbers and CasADi expressions."""
    return -(P.X_u * u_ref + P.X_uu * sabs(u_ref, P.eps_abs) * u_ref)


def steering_floor(u_ref, delta, model: VesselModel, ep: ExecutionParams):
    """Least thrust in transit (N): what a helmsman gives a steerable drive at full lock.

    ``T_floor = T_lock |delta| / delta_max * min(1, (u_ref / u_ff)^2)`` with ``delta`` the
    steering angle (rad) and ``T_lock`` from :func:`mpcasv.control.steering.lock_thrust`: the
    least thrust whose steady full-lock turn reaches the yaw rate ``r_steer``, but no more than
    the thrust whose steady full-lock turn runs at eq. 3.1's ``u_ff``. In a hard turn
    (``|psi_e| >= pi/2``: ``u_ref = u_ff``, the yaw PID at full lock) it can therefore hold at
    most ``u_ff``; it vanishes on a straight course, and for a command slower than ``u_ff`` it
    shrinks with ``u_ref^2`` (a turn's thrust grows at least as fast as ``u^2``). Zero for
    differential thrust (``k_diff = 1``), whose yaw authority needs no total thrust.
    docs/tuning.md, "Thrust floor and eq. 3.1".
    """
    from mpcasv.control.steering import lock_thrust

    P = model.params
    u_ff = ep.reference.u_ff
    if P.k_diff or u_ff <= 0:
        return ca.DM(P.T_min)
    T_lock = lock_thrust(model, ep)["T_lock"]
    slow = ca.fmin(1.0, (u_ref / u_ff) ** 2)
    return ca.fmax(T_lock * ca.fabs(delta) / P.delta_max * slow, P.T_min)


def execution_law(x, z, cmd, model: VesselModel, ep: ExecutionParams, dt: float):
    """One sample of the execution level.

    Returns ``(u, z_next, y)`` with ``u = [T_cmd, delta_cmd]`` for the plant and
    ``y = [psi_d, u_ref]`` for logging.
    """
    P, ys = model.params, ep.yaw
    transit = cmd[0]
    psi, u_s, r = x[2], x[3], x[5]
    I_psi, I_u, r_f = z[0], z[1], z[2]

    psi_d = guidance(x, cmd[1:3])
    e_psi = wrap(psi_d - psi)
    # (3.1) with psi_e = psi_asv - psi_wp; capped by the command and the vessel's top speed
    # (a command above u_max is clipped here: the autopilot's saturation, docs/vessel.md)
    u_cap = ca.fmin(cmd[3], P.u_max)
    u_ref = ca.fmin(speed_reference(e_psi, ep.reference.u_ff, ep.reference.k_u), u_cap)

    # yaw PID, gains scheduled on measured surge speed, derivative on filtered yaw rate
    Kp, Ki, Kd = (pwlinear(u_s, ys.speeds, g) for g in (ys.Kp, ys.Ki, ys.Kd))
    d_unsat = Kp * e_psi + I_psi - Kd * r_f
    d_sat = ca.fmin(ca.fmax(d_unsat, -P.delta_max), P.delta_max)
    I_psi_next = _integrate(I_psi, dt * Ki * e_psi, d_unsat, P.delta_max)

    # surge speed loop with model-based feed-forward
    T_ff = feed_forward_thrust(u_ref, P)
    e_u = u_ref - u_s
    T_unsat = T_ff + ep.speed.Kp * e_u + I_u
    T_floor = steering_floor(u_ref, x[7], model, ep)  # actual steering angle (lagged)
    if ep.turn_thrust > 0:  # the optional power turn: overrides eq. 3.1 (params.py)
        turn = ca.fmin(ca.fmax((ca.fabs(e_psi) - math.pi / 4) / (math.pi / 4), 0), 1)
        if ep.turn_scope == "avoidance":  # only in collision-avoidance transits (cmd[0] = 2)
            turn = ca.if_else(transit > 1.5, turn, 0)
        T_floor = ca.fmax(T_floor, P.T_max * ep.turn_thrust * turn)
    T_sat = ca.fmin(ca.fmax(T_unsat, T_floor), P.T_max)
    I_u_next = _integrate(I_u, dt * ep.speed.Ki * e_u, T_unsat - (P.T_max + T_floor) / 2,
                          (P.T_max - T_floor) / 2)  # fmt: skip

    r_f_next = r_f + dt / ys.T_f * (r - r_f)
    on = transit > 0.5
    u = ca.vertcat(ca.if_else(on, T_sat, 0), ca.if_else(on, d_sat, 0))
    z_next = ca.vertcat(ca.if_else(on, I_psi_next, 0), ca.if_else(on, I_u_next, 0), r_f_next)
    return u, z_next, ca.vertcat(psi_d, ca.if_else(on, u_ref, 0))


def closed_loop(model: VesselModel, ep: ExecutionParams, dt: float, n_sub: int) -> ca.Function:
    """Compile ``n_sub`` plant steps of ``dt`` with the execution level in the loop.

    ``CL(x, z, cmd, c) -> (x_next, z_next, X, U, Y)`` where ``X`` (NX x n_sub), ``U``
    (NU x n_sub) and ``Y`` (2 x n_sub) hold the state after, and the input and guidance
    outputs during, each plant step. Inputs are held over each plant step (ZOH) and the
    plant is integrated by RK4, in as many sub-steps as the vessel's fastest pole over its
    manoeuvring envelope needs (:func:`~mpcasv.models.envelope.rk4_sub_steps`; 1 for the
    shipped vessels at 0.1 s).
    """
    k = rk4_sub_steps(model, dt)
    x0, z0 = ca.SX.sym("x", NX), ca.SX.sym("z", NZ)
    cmd, c = ca.SX.sym("cmd", NCMD), ca.SX.sym("c", NC)
    x, z, Xs, Us, Ys = x0, z0, [], [], []
    for _ in range(n_sub):
        u, z, y = execution_law(x, z, cmd, model, ep, dt)
        x = rk4_expr(model.f, x, u, c, dt, k)
        Xs.append(x)
        Us.append(u)
        Ys.append(y)
    return ca.Function(
        "closed_loop", [x0, z0, cmd, c], [x, z, ca.horzcat(*Xs), ca.horzcat(*Us), ca.horzcat(*Ys)],
        ["x", "z", "cmd", "c"], ["x_next", "z_next", "X", "U", "Y"],
    )  # fmt: skip


def command_vector(command, asv_NE=None, lead: float = 0.0) -> np.ndarray:
    """Turn a :class:`mpcasv.interface.Command` into the ``cmd`` vector of :func:`closed_loop`:
    ``transit`` 1 for a transit, 0 for standby; a transit's waypoint pushed ``lead`` m on
    from the ASV at ``asv_NE`` (:func:`pushed_waypoint`; ``[sim] reference_lead_m``). Whether
    a transit is an escape (``transit`` = 2, the power turn's ``turn_scope = "avoidance"``)
    is decided from geometry by the world that runs it (:func:`escape_vector`, called by
    :meth:`mpcasv.sim.world.World.advance`), never from the controller's reason."""
    from mpcasv.interface import Mode, pushed_waypoint

    if command.mode is Mode.STANDBY:
        return np.zeros(NCMD)
    N, E = command.waypoint if asv_NE is None else pushed_waypoint(command.waypoint, asv_NE,
                                                                     lead)  # fmt: skip
    return np.array([1.0, N, E, command.speed])


def escape_vector(cmd, escaping: bool) -> np.ndarray:
    """``cmd`` with a transit marked as an escape (``cmd[0]`` = 2) while ``escaping``: the
    ASV inside a collision domain now (true ranges). The one rule of the power turn's
    ``turn_scope = "avoidance"``, for every controller and for every source of ``cmd`` (the
    simulator's Command, the SITL's FollowReference maneuver): World.advance applies it."""
    cmd = np.array(cmd, dtype=float).ravel()
    if escaping and cmd[0] > 0.5:
        cmd[0] = 2.0
    return cmd
