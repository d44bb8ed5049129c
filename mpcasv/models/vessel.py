"""The one Fossen 3-DOF vessel model, written once, symbolically in CasADi.

State  x = [N, E, psi, u, v, r, T, delta]   (m, m, rad, m/s, m/s, rad/s, N, rad)
Input  u = [T_cmd, delta_cmd]              (N, rad): thrust and steering set-points
Current c = [V_N, V_E]                     (m/s): constant, irrotational, in NED

Gretha has one steerable stern drive at (x_p, 0): its thrust in body axes is
[T cos(delta), -T sin(delta)]; with the propeller stopped (T ~ 0) the drive adds the surge
drag of the locked propeller and its leg (:func:`idle_drag`); its steered underwater leg adds a
lift force Y_uudelta |u_r| u_r delta, so the yaw moment is x_p times the total side force (positive
delta turns the bow to starboard, r > 0). Yaw authority therefore grows with thrust and with
speed, and vanishes at rest. Thrust and steering follow their set-points with first-order
lags, so the actuators are part of the state and every user (simulator, MPC, tuning)
sees the same lag.

Equations (thesis eqs. 2.5-2.6 reduced to 3 DOF; Fossen 2021 ch. 6):
    eta_dot = R(psi) nu                                                     (2.5)
    M_RB nu_dot + M_A nu_r_dot + C_RB(nu) nu + C_A(nu_r) nu_r + D(nu_r) nu_r = tau   (2.6)
with nu_r = nu - nu_c, nu_c = R(psi)^T [V_N, V_E, 0] and, the current being constant in
NED, nu_c_dot = [r v_c, -r u_c, 0].

Argument order, kept everywhere: ``(x, u, c)`` and ``(x, u, c, p)`` with ``p`` the parameter
vector in :data:`mpcasv.models.params.MODEL_COEFFS` order.
"""

from __future__ import annotations

import math
from functools import cached_property

import casadi as ca
import numpy as np

from mpcasv.models.envelope import poles, rk4_sub_steps
from mpcasv.models.params import MODEL_COEFFS, VesselParams

STATE_NAMES = ("N", "E", "psi", "u", "v", "r", "T", "delta")
INPUT_NAMES = ("T_cmd", "delta_cmd")
NX, NU, NC, NP = len(STATE_NAMES), len(INPUT_NAMES), 2, len(MODEL_COEFFS)
IX = {name: i for i, name in enumerate(STATE_NAMES)}


def sabs(x, eps):
    """Smooth |x| = sqrt(x^2 + eps^2) - eps: differentiable, zero at zero, >= 0."""
    return ca.sqrt(x * x + eps * eps) - eps


def idle_weight(T, T_idle):
    """Blend of the idle-drive drag: 1 at zero thrust, ``exp(-(T/T_idle)^2)``, smooth in ``T``.

    At ``T = 2 T_idle`` it is 0.018; at ``3 T_idle`` 1e-4 (the drag is gone while the
    propeller runs).
    """
    return ca.exp(-((T / T_idle) ** 2))


def idle_drag(u_r, T, P):
    """Surge drag of the idle drive (N): ``X_uu_idle |u_r| u_r w(T)``.

    ``X_uu_idle = -rho/2 (C_prop A_E + C_leg A_leg)``: the locked propeller's form drag on its
    expanded blade area ``A_E`` (UFC 4-159-03, 2005, eq. 21: ``C_prop = 1.0``) plus the drive
    leg's on its frontal area. While the propeller runs, ``T`` is the drive unit's net thrust
    (its own drag netted out), so the term is blended out by :func:`idle_weight`.
    See docs/vessel.md for the numbers and their sensitivity.
    """
    return P["X_uu_idle"] * sabs(u_r, P["eps_abs"]) * u_r * idle_weight(T, P["T_idle"])


def actuator_forces(T, delta, u_r, P):
    """Actuator forces and moment ``[X, Y, N]`` (N, N, N m) in body axes.

    - Steerable drive at ``(x_p, 0)`` (``k_diff = 0``): thrust ``[T cos(delta),
      -T sin(delta)]`` plus the steered leg's lift ``Y_uudelta |u_r| u_r delta``; ``N = x_p Y``.
    - Two fixed thrusters at ``(x_p, -+y_thr)`` (``k_diff = 1``, the Otter): ``X = T`` (their
      sum), no side force, ``N = y_thr (T_port - T_stbd) = N_diff delta`` with
      ``N_diff = y_thr T_max / delta_max``: the second input is the differential thrust scaled
      to the steering range, so the execution level, the MPC and the tuning tools keep one
      interface. Yaw authority then does not need speed or total thrust.

    The switch ``k_diff`` is a number of the parameter vector (0 or 1), so both kinds live in
    the one symbolic model.
    """
    k, eps = P["k_diff"], P["eps_abs"]
    Y_steer = -T * ca.sin(delta) + P["Y_uudelta"] * sabs(u_r, eps) * u_r * delta
    return ca.vertcat(
        (1 - k) * T * ca.cos(delta) + k * T,
        (1 - k) * Y_steer,
        (1 - k) * P["x_p"] * Y_steer + P["N_diff"] * delta,
    )


def dune_actuators(vessel, a0, a1=0.0, servo=0.0):
    """The model's ``(T, delta)`` (N, rad) from DUNE's set-points: SetThrusterActuation ids 0
    and 1 (fractions ``a0``, ``a1``) and SetServoPosition id 0 (``servo``, rad). Steerable
    drive: ``T = a0 T_max``, ``delta = servo``; two fixed thrusters (``vessel.actuation =
    "differential"``, id 0 port, 1 starboard): ``T = (a0 + a1) T_max / 2``, ``delta =
    delta_max (a0 - a1) / 2`` (so that ``T_port - T_stbd = T_max delta / delta_max``,
    :func:`mpcasv.models.vessel.actuator_forces`). The thrust is taken as proportional to the
    set-point (no thrust-speed map), as in the identification (:mod:`mpcasv.io.identlog`):
    this is a vessel file's own actuator model (the deploy reads DUNE's set-points with it,
    :mod:`mpcasv.io.asvwatch`; a vessel identified through DUNE's thruster map is replayed
    with it as written, :mod:`mpcasv.models.ident_written`). Numbers or arrays."""
    if vessel.actuation == "differential":
        return (a0 + a1) * vessel.T_max / 2, (a0 - a1) * vessel.delta_max / 2
    return a0 * vessel.T_max, servo


def mass_matrices(P):
    """Rigid-body and added mass matrices ``(M_RB, M_A)`` of the 3-DOF model (kg, kg m,
    kg m^2 entries), ``M = M_RB + M_A`` multiplying ``[u_dot, v_dot, r_dot]`` in (2.6).

    ``M_RB = [[m, 0, 0], [0, m, m x_g], [0, m x_g, I_z]]`` with ``I_z`` about the body origin
    CO and the centre of gravity at ``(x_g, 0)`` (Fossen 2021 §3.3 reduced to surge, sway and
    yaw); ``M_A = -[[X_udot, 0, 0], [0, Y_vdot, Y_rdot], [0, N_vdot, N_rdot]]`` (Fossen 2021
    §6.3; the derivatives are <= 0 on the diagonal in this convention). ``P`` maps the names
    of :data:`~mpcasv.models.params.MODEL_COEFFS` to CasADi symbols or to numbers (then the
    matrices are ``casadi.DM``). The one definition: the equations of motion
    (:func:`xdot_expr`) and the load-time check (:func:`~mpcasv.models.params.check_physics`)
    both use it.
    """
    m, I_z, x_g = P["m"], P["I_z"], P["x_g"]
    Xud, Yvd, Yrd, Nvd, Nrd = P["X_udot"], P["Y_vdot"], P["Y_rdot"], P["N_vdot"], P["N_rdot"]
    M_RB = ca.vertcat(ca.horzcat(m, 0, 0), ca.horzcat(0, m, m * x_g), ca.horzcat(0, m * x_g, I_z))
    M_A = -ca.vertcat(ca.horzcat(Xud, 0, 0), ca.horzcat(0, Yvd, Yrd), ca.horzcat(0, Nvd, Nrd))
    return M_RB, M_A


def xdot_expr(x, u, c, p):
    """Right-hand side of the model as a CasADi expression (SX or MX).

    This is the single definition of the vessel's equations of motion in mpcasv.
    """
    P = {name: p[i] for i, name in enumerate(MODEL_COEFFS)}
    psi, uu, v, r, T, delta = x[2], x[3], x[4], x[5], x[6], x[7]
    T_cmd, delta_cmd = u[0], u[1]
    cpsi, spsi = ca.cos(psi), ca.sin(psi)

    # current in body axes and relative velocity
    u_c = c[0] * cpsi + c[1] * spsi
    v_c = -c[0] * spsi + c[1] * cpsi
    u_r, v_r = uu - u_c, v - v_c
    nu = ca.vertcat(uu, v, r)

    m, x_g = P["m"], P["x_g"]
    Xud, Yvd, Yrd = P["X_udot"], P["Y_vdot"], P["Y_rdot"]
    eps = P["eps_abs"]
    M_RB, M_A = mass_matrices(P)

    # Coriolis-centripetal forces (Fossen 2021 eqs. 6.43 and 6.52 in 3 DOF)
    C_RB_nu = ca.vertcat(-m * (x_g * r + v) * r, m * uu * r, m * x_g * uu * r)
    C_A_nur = ca.vertcat(
        (Yvd * v_r + Yrd * r) * r,
        -Xud * u_r * r,
        (Xud - Yvd) * u_r * v_r - Yrd * u_r * r,
    )

    # damping: linear (constant + proportional to speed, Clarke 1982) and quadratic
    U = sabs(u_r, eps)
    f_Y, f_N = ca.exp(-P["alpha_Y"] * U), ca.exp(-P["alpha_N"] * U)  # low-speed terms fade
    D_nur = -ca.vertcat(
        P["X_u"] * u_r + P["X_uu"] * sabs(u_r, eps) * u_r,
        (f_Y * P["Y_v"] + P["Y_uv"] * U) * v_r
        + (f_Y * P["Y_r"] + P["Y_ur"] * U) * r
        + P["Y_vv"] * sabs(v_r, eps) * v_r,
        (f_N * P["N_v"] + P["N_uv"] * U) * v_r
        + (f_N * P["N_r"] + P["N_ur"] * U) * r
        + P["N_rr"] * sabs(r, eps) * r,
    )

    # actuation: steerable stern drive (k_diff = 0) or two fixed thrusters (k_diff = 1)
    tau = actuator_forces(T, delta, u_r, P) + ca.vertcat(idle_drag(u_r, T, P), 0, 0)

    # (2.6): M_RB nu_dot + M_A (nu_dot - nu_c_dot) + ... = tau
    nu_c_dot = ca.vertcat(r * v_c, -r * u_c, 0)
    rhs = tau - C_RB_nu - C_A_nur - D_nur + ca.mtimes(M_A, nu_c_dot)
    nu_dot = ca.solve(M_RB + M_A, rhs)

    eta_dot = ca.vertcat(uu * cpsi - v * spsi, uu * spsi + v * cpsi, r)  # (2.5)
    act_dot = ca.vertcat((T_cmd - T) / P["T_thrust"], (delta_cmd - delta) / P["T_delta"])
    del nu
    return ca.vertcat(eta_dot, nu_dot, act_dot)


def rk4_step(f, x, u, c, h):
    """One classic Runge-Kutta 4 step of ``h``, input held: ``(x_next, x_mid)`` with
    ``x_mid = x + h/2 k2``, the step's own estimate of the state at ``h/2`` (the point its
    third stage is evaluated at)."""
    k1 = f(x, u, c)
    k2 = f(x + h / 2 * k1, u, c)
    x_mid = x + h / 2 * k2
    k3 = f(x_mid, u, c)
    k4 = f(x + h * k3, u, c)
    return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4), x_mid


def rk4_expr(f, x, u, c, dt, n_sub=1):
    """Classic Runge-Kutta 4 over ``dt`` in ``n_sub`` equal sub-steps, input held (ZOH)."""
    h = dt / n_sub
    for _ in range(n_sub):
        x = rk4_step(f, x, u, c, h)[0]
    return x


def resistance(P: VesselParams, u: float) -> float:
    """Hull resistance (N) at surge speed ``u`` straight ahead in still water, drive running:
    ``-(X_u u + X_uu |u| u)`` with the model's smooth ``|u|`` (eq. 2.6 in trim)."""
    su = math.sqrt(u * u + P.eps_abs**2) - P.eps_abs
    return float(-(P.X_u * u + P.X_uu * su * u))


def trim_thrust(P: VesselParams, u: float) -> float:
    """Thrust (N) that holds surge speed ``u`` straight ahead in still water (trim, eq. 2.6).

    Solves ``T + X_idle(u, T) = R(u)`` (:func:`idle_drag`; unique for ``u >= 0``: the left
    side grows with ``T``). Astern (``u < 0``) the idle drag is not included.
    """
    R = resistance(P, u)
    if P.X_uu_idle == 0.0 or u <= 0.0:
        return R
    su = math.sqrt(u * u + P.eps_abs**2) - P.eps_abs
    D = -P.X_uu_idle * su * u  # full idle drag at u (N), >= 0
    T_idle = P.T_idle

    def net(T):
        return T - D * math.exp(-((T / T_idle) ** 2)) - R

    return _bisect(net, R, R + D)


def _bisect(f, lo: float, hi: float, tol: float = 1e-10) -> float:
    """Root of an increasing scalar ``f`` on ``[lo, hi]`` (``f(lo) <= 0 <= f(hi)``) by
    bisection. (Plain Python on purpose: ``scipy.optimize`` costs ~0.6 s of import in every
    simulator process for a one-dimensional monotonic root.)"""
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if hi - lo <= tol * max(1.0, abs(mid)):
            break
        if f(mid) > 0:
            hi = mid
        else:
            lo = mid
    return 0.5 * (lo + hi)


def top_speed(P: VesselParams) -> float:
    """Straight-line speed (m/s) at ``T_max`` in still water, solved on the model's trim."""
    hi = 1.0
    while trim_thrust(P, hi) < P.T_max:
        hi *= 2
        if hi > 1e3:
            raise ValueError(f"{P.name}: no top speed below 1000 m/s at T_max = {P.T_max:g} N")
    return _bisect(lambda u: trim_thrust(P, u) - P.T_max, 0.0, hi)


#: tolerance of the load-time check of a vessel file's declared ``u_max`` against the model's
#: top speed at ``T_max`` (relative)
U_MAX_TOLERANCE = 0.05


class VesselModel:
    """The shared vessel model: continuous dynamics, RK4 step, linearisation, trim.

    Parameters
    ----------
    params : VesselParams
        Numeric parameters; baked into the fast functions :attr:`f` and :meth:`rk4`.
        :attr:`f_param` keeps them symbolic (for identification).
    """

    def __init__(self, params: VesselParams):
        self.params = params
        self.p = params.vector()
        x, u = ca.SX.sym("x", NX), ca.SX.sym("u", NU)
        c, p = ca.SX.sym("c", NC), ca.SX.sym("p", NP)
        self.f_param = ca.Function(
            "f_param", [x, u, c, p], [xdot_expr(x, u, c, p)], ["x", "u", "c", "p"], ["xdot"]
        )
        #: continuous dynamics x_dot = f(x, u, c) with the numeric parameters
        self.f = ca.Function(
            "f", [x, u, c], [xdot_expr(x, u, c, self.p)], ["x", "u", "c"], ["xdot"]
        )
        self._jac = ca.Function(
            "jacobians",
            [x, u, c],
            [ca.jacobian(self.f(x, u, c), x), ca.jacobian(self.f(x, u, c), u)],
        )

    def rk4(self, dt: float, n_sub: int | None = None) -> ca.Function:
        """Discrete step ``F(x, u, c) -> x_next`` by RK4 over ``dt`` in ``n_sub`` sub-steps;
        None (default): as many as the vessel's fastest pole over its manoeuvring envelope
        needs (:func:`~mpcasv.models.envelope.rk4_sub_steps`: 1 for Gretha up to 0.75 s, more
        for a stiff hull in a turn; the first call per vessel and process takes about 0.1 s).
        Raises ValueError if the envelope cannot be integrated
        (:func:`~mpcasv.models.envelope.poles`)."""
        n = rk4_sub_steps(self, dt) if n_sub is None else n_sub
        x, u, c = ca.SX.sym("x", NX), ca.SX.sym("u", NU), ca.SX.sym("c", NC)
        return ca.Function(
            "F_rk4", [x, u, c], [rk4_expr(self.f, x, u, c, dt, n)],
            ["x", "u", "c"], ["x_next"],
        )  # fmt: skip

    @property
    def jacobians(self) -> ca.Function:
        """``(x, u, c) -> (df/dx, df/du)``, exact by AD (CasADi; ``.map(m)`` evaluates ``m``
        points in one call)."""
        return self._jac

    def linearize(self, x0, u0, c0=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
        """Jacobians ``A = df/dx``, ``B = df/du`` at an operating point (exact, by AD)."""
        A, B = self._jac(np.asarray(x0, float), np.asarray(u0, float), np.asarray(c0, float))
        return np.array(A), np.array(B)

    def resistance(self, u: float) -> float:
        """Hull resistance (N) at surge speed ``u`` straight ahead in still water, drive running."""
        return resistance(self.params, u)

    def thrust_for_speed(self, u: float) -> float:
        """Thrust that holds surge speed ``u`` straight ahead, still water (:func:`trim_thrust`)."""
        return trim_thrust(self.params, u)

    def trim(self, u: float) -> tuple[np.ndarray, np.ndarray]:
        """Straight-line equilibrium at surge speed ``u`` heading north: (x0, u0)."""
        T = self.thrust_for_speed(u)
        x0 = np.array([0.0, 0.0, 0.0, u, 0.0, 0.0, T, 0.0])
        return x0, np.array([T, 0.0])

    @property
    def fastest_trim_pole(self) -> float:
        """Largest |eigenvalue| (1/s) of the rigid-body dynamics (N..r, the actuators held)
        at straight-line trims from rest to ``u_max`` (:mod:`mpcasv.models.envelope`)."""
        return poles(self).trim

    @property
    def fastest_pole(self) -> float:
        """Largest |eigenvalue| (1/s) of the rigid-body dynamics (N..r, the actuators held)
        over the manoeuvring envelope, straight-line trims and full-steering turns
        (:mod:`mpcasv.models.envelope`): what bounds an explicit integrator's step (RK4 on a
        real pole: ``|lambda h| < 2.785``). Gretha 2.7 1/s (2.4 straight ahead), Fossen's
        Otter 16.5 in a full-steering turn (3.6 straight ahead)."""
        return poles(self).envelope

    @property
    def fastest_plant_pole(self) -> float:
        """As :attr:`fastest_pole` with the actuators' lags (all eight states): what bounds
        the simulator's plant step, which integrates the lags too."""
        return poles(self).plant

    @cached_property
    def top_speed(self) -> float:
        """Straight-line speed at full thrust in still water (:func:`top_speed`)."""
        return top_speed(self.params)

    def stopping(self, u0: float, u_stop: float = 0.2, dt: float = 0.05,
                 t_end: float = 600.0) -> tuple[float, float]:  # fmt: skip
        """Distance (m) and time (s) to coast from trim at ``u0`` below ``u_stop`` (propeller off).

        Straight ahead in still water: the vessel starts in trim at ``u0`` and the thrust
        set-point drops to zero at t = 0 (the thrust follows its lag ``T_thrust``). Returns
        ``(inf, inf)`` if the speed does not fall below ``u_stop`` within ``t_end``.
        """
        F = self.rk4(dt)
        x, _ = self.trim(u0)
        zero, c = np.zeros(NU), np.zeros(NC)
        dist, t = 0.0, 0.0
        while x[IX["u"]] >= u_stop:
            if t >= t_end:
                return math.inf, math.inf
            x_next = np.array(F(x, zero, c)).ravel()
            dist += math.hypot(x_next[0] - x[0], x_next[1] - x[1])
            x, t = x_next, t + dt
        return dist, t

    def sway_yaw_eigenvalues(self, u: float) -> np.ndarray:
        """Eigenvalues of the linearised sway-yaw subsystem at straight-line speed ``u``.

        All real parts negative means the hull is straight-line (course) stable there.
        """
        A, _ = self.linearize(*self.trim(u))
        idx = [IX["v"], IX["r"]]
        return np.linalg.eigvals(A[np.ix_(idx, idx)])
