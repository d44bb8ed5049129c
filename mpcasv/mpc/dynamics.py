"""The plan's dynamics (docs/mpc.md, "Variables and dynamics"): the continuous model (M1-M3)
and its discretisation over one stage. A mixin of :class:`~mpcasv.mpc.problem.OCP` (its
vessel, parameters and dimensions live there).

The continuous model, :meth:`PlanDynamics.rhs`, is the definition; :meth:`PlanDynamics.
discrete` is what the solvers differentiate (through its sub-steps, :meth:`PlanDynamics.
sub_step`, one at a time: :mod:`mpcasv.mpc.adjoint`):

- the vessel (M1: the shared model's rigid body with the actuators at their set-points, the
  set-points driven by their rates) by classic RK4 in ``n_sub`` sub-steps of ``h``;
- each AUV's expected fix age (M2: ``tau' = 1 - rho tau``, linear in ``tau`` for a given
  rate) exactly for a rate known at the sub-step's start, middle and end, with Simpson's
  rule for the integrals: over a sub-step, with ``A(s) = int_0^s rho``,
  ``tau(h) = tau(0) e^{-A(h)} + int_0^h e^{-(A(h) - A(s))} ds``, both integrals by
  Simpson's rule on ``rho_0, rho_m, rho_1`` (``A(h/2)`` by the trapezoid). The rates are
  taken at the RK4 sub-step's own points (start, ``x + h/2 k2``, end): 9 fix-rate
  evaluations per AUV and stage where RK4 on the coupled system needs 16. Same accuracy
  against a fine integration of :meth:`rhs` (tests/test_mpc_problem.py), and the stage's
  Hessian is 19 % shorter with three AUVs (issue 16 item 8).
"""

from __future__ import annotations

import functools
import math
import sys
from typing import NamedTuple

import casadi as ca
import numpy as np

from mpcasv.control.execution import pwlinear, wrap
from mpcasv.models.acoustics import AcousticParams
from mpcasv.models.envelope import (
    N_TRIMS,
    RK4_LAMBDA_H,
    RK4_STABLE,
    course_instability,
    envelope_states,
    sub_steps,
)
from mpcasv.models.vessel import rk4_step, xdot_expr
from mpcasv.mpc.layout import NCH, channel_vector
from mpcasv.mpc.smooth import D_EPS, sigmoid
from mpcasv.mpc.variance import N_NAV, fix_gain

NXV = 8  # vessel part of the plan state
#: rate bound (rad/s) of the heading reference with ``steering = "heading"`` (M1h): the plan's
#: sanity bound on the yaw rate
R_REF_MAX = 0.5
#: the plan's sanity bounds on its velocities: surge from ``-U_ASTERN`` to ``U_ABOVE`` above
#: the vessel's top speed, sway within ``+-V_SANE`` (m/s), yaw rate within ``+-R_SANE``
#: (rad/s). The OCP's box puts them on the velocities over the ground (widened there by the
#: current's speed); :func:`water_guard` on those through the water (widened by ``|c|_1``)
U_ASTERN, U_ABOVE, V_SANE, R_SANE = 0.5, 0.5, 1.0, 0.5
#: how far beyond its bounds (m/s, m/s, rad/s) :func:`water_guard` saturates u_r, v_r and r
W_GUARD = (0.5, 0.5, 0.25)
#: largest |lambda h| of the plan's RK4 sub-steps on the closed loop of M1h: its fast poles are
#: everywhere, and near the stability bound a stage is stable but not accurate
RK4_ACCURATE = 2.0


class GuardBounds(NamedTuple):
    """Still-water bounds of :func:`water_guard`: surge through the water from ``u_lo`` to
    ``u_hi``, sway within ``+-v_max`` (m/s), yaw rate within ``+-r_max`` (rad/s)."""

    u_lo: float
    u_hi: float
    v_max: float
    r_max: float


def guard_bounds(model) -> GuardBounds:
    """:class:`GuardBounds` of ``model`` (a :class:`~mpcasv.models.vessel.VesselModel`): the
    OCP's still-water sanity box (``-U_ASTERN .. u_max + U_ABOVE``, ``V_SANE``, ``R_SANE``),
    widened to 1.1 times the extremes of the vessel's manoeuvring envelope where those reach
    further (its full-steering turns: dune-otter 1.18 rad/s, the shipped Otter 0.67 rad/s;
    Gretha's stay inside the box), so that a sub-step's state in such a turn is not
    saturated. (The OCP's box still bounds the stages' yaw rate to ``R_SANE`` for every
    vessel: a plan's nodes cannot turn as fast as those hulls can.)"""
    X, u_max = envelope_states(model), model.params.u_max
    return GuardBounds(min(-U_ASTERN, 1.1 * float(X[:, 3].min())),
                       max(u_max + U_ABOVE, 1.1 * float(X[:, 3].max())),
                       max(V_SANE, 1.1 * float(np.abs(X[:, 4]).max())),
                       max(R_SANE, 1.1 * float(np.abs(X[:, 5]).max())))  # fmt: skip


def water_guard(x, c, bounds: GuardBounds):
    """The plan state ``x`` (``(8,)``, SX/MX) as the shared model sees it inside the plan's
    integration: its surge and sway speeds through the water and its yaw rate kept within
    ``bounds`` (:func:`guard_bounds`) widened by the current ``c = [V_N, V_E]`` (m/s).

    Why. The OCP's sanity bounds are a box on the velocities over the ground, widened by the
    current's speed ``|c|`` (a box cannot know the heading): heading upstream in 2 m/s its
    corner is ``u_max + 0.5 + 2|c|`` = 7.0 m/s through the water for Gretha. The hull's
    sway-yaw mode is faster the faster it goes through the water: 3.9 1/s at the still-water
    box's corner, 7.1 at the 2-m/s one, 4.0-4.1 at top speed against 2 m/s, where her 1-s RK4
    sub-steps hold 2.8. A sub-step amplifies that mode, the quadratic sway and yaw damping
    runs away, and the surge rows (``m v r``) overflowed to Inf: fatrop hung on such trial
    points (docs/mpc.md, "Known problems": strong currents), which also leave the box.

    What. ``u_r = u - u_c``, ``v_r = v - v_c`` (``[u_c, v_c] = R(psi)^T c``, eq. 2.6) are kept
    in ``[u_lo - |c|_1, max(u_hi, |c|_1 + U_ABOVE)]`` and ``+-(v_max + |c|_1)`` (``|c|_1 =
    |V_N| + |V_E| >= |c|``: a boat at rest over the ground is inside), the yaw rate in
    ``+-r_max``; beyond, a component is saturated smoothly, ``b + W tanh((a - b) / W)`` (``W``
    of :data:`W_GUARD`; continuous to the second derivative), so the derivatives stay bounded
    and every stage finite. Inside, each component is returned unchanged (the value exactly;
    CasADi's derivatives of the longer expression agree to rounding, 1e-14), so a stage whose
    RK4 points stay inside is the shared model's. It is not the true motion when the plan's
    current is wrong by more than the bounds' margins (``current = "zero"`` in a strong
    current, an estimate not yet settled): the model's unguarded RK4 is not either there."""
    cs, sn = ca.cos(x[2]), ca.sin(x[2])
    u_c, v_c = cs * c[0] + sn * c[1], -sn * c[0] + cs * c[1]  # (2.6): R(psi)^T [V_N, V_E]
    c1 = ca.fabs(c[0]) + ca.fabs(c[1])
    b = bounds
    u = _kept(x[3], u_c, b.u_lo - c1, ca.fmax(b.u_hi, c1 + U_ABOVE), W_GUARD[0])
    v = _kept(x[4], v_c, -b.v_max - c1, b.v_max + c1, W_GUARD[1])
    r = _kept(x[5], 0.0, -b.r_max, b.r_max, W_GUARD[2])
    return ca.vertcat(x[0:3], u, v, r, x[6:])


def _kept(a, a_c, lo, hi, w):
    """``a`` (over the ground) whose part through the water ``a - a_c`` is saturated smoothly
    within ``w`` beyond ``[lo, hi]``: ``a`` itself inside (no rounding, no cancellation)."""
    a_r = a - a_c
    return ca.if_else(a_r > hi, a_c + hi + w * ca.tanh((a_r - hi) / w),
                      ca.if_else(a_r < lo, a_c + lo + w * ca.tanh((a_r - lo) / w), a))


class PlanDynamics:
    """Continuous and discrete plan dynamics (mixin of the OCP; state there).

    ``q = [c (2), pa_k (2K), va (2K), depth_k (K), depth rate (K), d_fix (K), channel (NCH),
    navigation block (N_NAV, objective "variance" only)]``: the current, each AUV's position
    and depth at the stage's start with their rates over the stage, the reliable-fix radius
    and the acoustic channel (:func:`~mpcasv.mpc.layout.channel_vector`).
    """

    def rhs(self, z, w, q):
        """Continuous dynamics of the augmented state ``[z; s]`` (``s``: time into the stage),
        eqs. M1-M3: the definition the discretisation :meth:`discrete` is tested against."""
        K = self.dims.n_auv
        x, tau, s = z[0:NXV], z[NXV : NXV + K], z[NXV + K]
        rho = self._rates(x, tau, s, q)
        rows = [self._vessel_rhs(x, w, q)]
        rows += [1 - rho[i] * tau[i] for i in range(K)]  # (M2)
        rows.append(ca.DM(1.0))
        return ca.vertcat(*rows)

    def discrete(self, z, w, q, dt: float, n_sub: int):
        """State after one stage of ``dt`` s (``n_sub`` sub-steps) from ``z`` with the command
        rates ``w = [Tdot, deltadot]`` held: RK4 for the vessel, the fix ages exactly for a
        rate interpolated by Simpson's rule (module docstring). SX or MX, shape ``(nx,)``."""
        K, h = self.dims.n_auv, dt / n_sub
        x, tau = z[0:NXV], z[NXV : NXV + K]
        r = self.start_rates(z, q)
        for j in range(n_sub):
            x, tau, r = self.sub_step(x, tau, r, w, q, (j + 0.5) * h, (j + 1) * h, h)
        return ca.vertcat(x, tau)

    def start_rates(self, z, q):
        """The fix rates (1/s, shape ``(K,)``) at the stage's start, where its first sub-step
        begins (eq. M3)."""
        K = self.dims.n_auv
        return ca.vertcat(*self._rates(z[0:NXV], [z[NXV + i] for i in range(K)], 0.0, q))

    def sub_step(self, x, tau, r0, w, q, s_m, s_1, h):
        """One sub-step of :meth:`discrete`: ``(x, tau, r0) -> (x1, tau1, r1)`` over ``h`` s,
        ``r0`` the fix rates at its start, ``s_m`` and ``s_1`` its middle and end in the stage
        (s; numbers or symbols). RK4 for the vessel (M1), the fix ages by Simpson's rule (M2);
        ``r1`` the rates at its end, where the next sub-step starts."""
        K = self.dims.n_auv
        tau = [tau[i] for i in range(K)]
        x1, xm = rk4_step(self._vessel_rhs, x, w, q, h)
        rm = self._rates(xm, tau, s_m, q)
        r1 = self._rates(x1, tau, s_1, q)
        for i in range(K):
            A = h / 6 * (r0[i] + 4 * rm[i] + r1[i])  # int_0^h rho
            A_m = h / 4 * (r0[i] + rm[i])  # int_0^{h/2} rho
            e = ca.exp(-A)
            tau[i] = tau[i] * e + h / 6 * (e + 4 * ca.exp(A_m - A) + 1)  # (M2)
        # the rate at the sub-step's end starts the next one (with "variance" it depends on
        # tau, so it is taken again at the new tau)
        r1 = self._rates(x1, tau, s_1, q) if self.variance else r1
        return x1, ca.vertcat(*tau), ca.vertcat(*r1)

    def _vessel_rhs(self, x, w, q):
        """The vessel part of M1: the shared model's rigid body (actuators at their set-points)
        and the set-points' rates; with ``steering = "heading"`` the steering angle from the
        heading reference ``x[7]`` (M1h, :meth:`steering_angle`). The model sees the state
        through :func:`water_guard` (its velocities kept where a boat can go)."""
        xa = ca.vertcat(x[0:7], self.steering_angle(x)) if self.heading else x
        xa = water_guard(xa, q[0:2], self.guard)
        xd = xdot_expr(xa, xa[6:8], q[0:2], self.model.p)
        return ca.vertcat(xd[0:6], w[0], w[1])

    @functools.cached_property
    def guard(self) -> GuardBounds:
        """The plan vessel's :func:`guard_bounds`."""
        return guard_bounds(self.model)

    def steering_angle(self, x):
        """The steering angle (rad) of plan state ``x`` (SX/MX/DM, ``x[0:8]``): ``x[7]`` with
        ``steering = "rudder"``; with ``"heading"`` the execution level's yaw PD on the
        heading reference ``psi_ref = x[7]`` (eq. M1h, the run's gains scheduled on the surge
        speed as in :func:`~mpcasv.control.execution.execution_law`, without its integral and
        rate filter, saturated smoothly, and zero while the propeller is off (STANDBY: the
        execution level centres the steering):
        ``delta = delta_max tanh((Kp(u) wrap(psi_ref - psi) - Kd(u) r) / delta_max)
        sig(4 (T - T_on) / T_on)`` (the width scaled to the vessel's propeller-on threshold:
        2 % at rest, 98 % at twice the threshold; M4c's absolute 4 N halved a 2-N model
        ship's PD at every trim), the heading error wrapped to (-pi, pi] as the execution level
        wraps it (a reference more than pi ahead turns the boat the shorter way round)."""
        if not self.heading:
            return x[7]
        ys, dm = self.execution.yaw, self.vessel.delta_max
        Kp, Kd = (pwlinear(x[3], ys.speeds, g) for g in (ys.Kp, ys.Kd))
        running = sigmoid(4 * (x[6] - self.T_on) / self.T_on)  # width T_on / 4
        e = wrap(x[7] - x[2])  # as the execution level: the shorter way round
        return dm * ca.tanh((Kp * e - Kd * x[5]) / dm) * running  # (M1h)

    def pd_gains(self, u: float) -> tuple[float, float]:
        """The execution level's yaw gains ``(Kp, Kd)`` at surge speed ``u`` (m/s), scheduled
        and clamped as :func:`~mpcasv.control.execution.pwlinear` does (numbers)."""
        ys = self.execution.yaw
        return float(np.interp(u, ys.speeds, ys.Kp)), float(np.interp(u, ys.speeds, ys.Kd))

    @functools.cached_property
    def plan_steering(self) -> ca.Function:
        """:meth:`steering_angle` along a plan: vessel states ``(8, N + 1)`` -> ``(1, N + 1)``
        (rad)."""
        x = ca.SX.sym("x", NXV)
        return ca.Function("steering", [x], [self.steering_angle(x)]).map(self.dims.N + 1)

    def heading_reference(self, x: np.ndarray, delta: float) -> float:
        """Inverse of M1h's PD: the heading reference (rad) whose yaw PD gives the steering
        angle ``delta`` (rad, clipped to 0.99 ``delta_max``) at vessel state ``x`` (``x[0:6]``)
        with the propeller running (with it off M1h's steering is zero whatever the
        reference: then ``psi + Kd r / Kp`` for ``delta = 0``)."""
        dm = self.vessel.delta_max
        Kp, Kd = self.pd_gains(x[3])
        a = dm * math.atanh(float(np.clip(delta / dm, -0.99, 0.99)))
        return float(x[2] + (a + Kd * x[5]) / max(Kp, 1e-6))

    def _rates(self, x, tau, s, q):
        """Each AUV's expected fix rate (1/s, M3; with "variance" times the fix's gain M2' at
        fix age ``tau``) with the vessel at ``x``, ``s`` s into the stage."""
        K = self.dims.n_auv
        ch = q[2 + 7 * K : 2 + 7 * K + NCH]
        quiet = self._quiet(x[6])
        out = []
        for i in range(K):
            pa = q[2 + 2 * i : 4 + 2 * i] + s * q[2 + 2 * K + 2 * i : 4 + 2 * K + 2 * i]
            depth = q[2 + 4 * K + i] + s * q[2 + 5 * K + i]  # linear within the stage
            dh = ca.sqrt((x[0] - pa[0]) ** 2 + (x[1] - pa[1]) ** 2 + D_EPS**2)
            rho = self.fix_rate(dh, depth, q[2 + 6 * K + i], x[6], ch, quiet)  # (M3)
            if self.variance:  # (M2') a far fix of a fresh AUV removes little
                nav = ca.vertsplit(q[2 + 7 * K + NCH : 2 + 7 * K + NCH + N_NAV])
                rho = rho * fix_gain(tau[i], ca.sqrt(dh**2 + depth**2), *nav)
            out.append(rho)
        return out

    def _quiet(self, T):
        """``sig((T_quiet - T) / w_T)``: ~1 with the propeller off (M3)."""
        return sigmoid((self.T_quiet - T) / self.w_T)

    def fix_rate(self, dh, depth, d_fix, T, ch, quiet=None):
        """Smooth expected fix rate (1/s, eq. M3) of one AUV at horizontal range ``dh`` and
        depth ``depth`` (m) with thrust ``T`` (N), channel ``ch`` (:func:`channel_vector`):

        ``rate * P(slant) * prop(T)`` with ``P = p_good sig((d1 - slant) / w) + p_sporadic
        (sig((d2 - slant) / w) - sig((d1 - slant) / w))`` (the simulator's success against
        slant range, smoothed); ``acoustic``: ``prop = quiet + f_prop (1 - quiet)`` (with
        ``noisy_fixes`` the propeller's noise scales the success, else ``f_prop = 0``: only
        quiet fixes count); ``target``: ``prop = quiet``
        times ``sig((d_fix - dh) / w)``, Paper 2's reliable fix (eq. 9: within
        ``r_t + eps_plus`` with the propeller off). ``quiet = sig((T_quiet - T) / w_T)``
        (pass it when several AUVs share one thrust).
        """
        fp = self.params.fix
        rate, p_good, p_spor, d1, d2, f_prop = (ch[j] for j in range(NCH))
        slant = ca.sqrt(dh**2 + depth**2)
        s1 = sigmoid((d1 - slant) / fp.w_range)
        s2 = sigmoid((d2 - slant) / fp.w_range)
        P = p_good * s1 + p_spor * (s2 - s1)
        if quiet is None:
            quiet = self._quiet(T)
        if fp.range_kind == "acoustic":
            return rate * P * (quiet + f_prop * (1 - quiet))
        return rate * P * quiet * sigmoid((d_fix - dh) / fp.w_range)

    @property
    def rho0(self) -> float:
        """Fix rate with the propeller off in range, ``p_good / T0`` (1/s) of the default
        channel (the run's: :func:`channel_vector`)."""
        ch = channel_vector(AcousticParams())
        return float(ch[0] * ch[1])

    @functools.cached_property
    def n_sub(self) -> int:
        """RK4 sub-steps per stage: the horizon's ``n_sub``, more if the vessel needs them.

        Steering angle planned (``"rudder"``): two bounds on the sub-step ``h = dt / n_sub``:
        RK4 stable on every rigid-body pole of the manoeuvring envelope, turns included
        (``|lambda|max h < RK4_STABLE``, 2.785), and with a margin on the straight-line trims,
        where the plan spends most of its time (``|lambda|max h <= RK4_LAMBDA_H``, 2.5).
        Gretha: 4 (2.72 1/s in a full-rudder turn from top speed, 2.38 straight ahead).
        Fossen's Otter: 24, the case's 26 (16.5-18 1/s in a full-steering turn: with 6, the
        sub-steps of the straight-line bound, a turning stage returned NaN and fatrop hung
        on it).

        Heading reference planned (``"heading"``, M1h): the margin on the closed loop's
        fastest pole over the whole envelope (the PD's fast poles are everywhere, not only in
        hard turns: the shipped Otter's 13.9 1/s straight ahead, 16.7 in a turn; 0.43 m off
        in a 4-s stage at the stability bound's 24 sub-steps), ``|lambda|max h <= 2.0``
        (:data:`RK4_ACCURATE`): the shipped Otter 34 (1e-3 m), the case's Otter 38 (0.02 m),
        dune-otter 12."""
        hz, m = self.params.horizon, self.model
        if self.heading:
            return max(hz.n_sub, sub_steps(hz.dt, self._closed_loop_pole(), RK4_ACCURATE))
        return max(hz.n_sub, sub_steps(hz.dt, m.fastest_pole, RK4_STABLE),
                   sub_steps(hz.dt, m.fastest_trim_pole, RK4_LAMBDA_H))

    def closed_loop_instability(self) -> tuple[float, float] | None:
        """``(u, lambda)``: with M1h, the straight-line trim speed (m/s) where the loop closed
        by the execution level's yaw PD has its largest eigenvalue real part (1/s, heading,
        surge, sway and yaw rate), if positive; None when the PD holds every trim (Fossen's
        Otter under Gretha's gains; not CyberShip II, up to +0.47 1/s)."""
        J, worst = self._vessel_jacobian, None
        for s in envelope_states(self.model)[1:N_TRIMS]:  # the trims above rest
            s = np.r_[s[:7], self.heading_reference(s, s[7])]
            lam = float(np.linalg.eigvals(np.asarray(J(s))[2:6, 2:6]).real.max())
            if lam > 1e-6 and (worst is None or lam > worst[1]):  # (structural zeros: 1e-17)
                worst = (float(s[3]), lam)
        return worst

    def _closed_loop_pole(self) -> float:
        """Fastest rigid-body pole (1/s) of M1h's closed loop over the manoeuvring envelope
        (:func:`~mpcasv.models.envelope.envelope_states`), the heading reference at each state
        the one whose PD gives the state's steering angle."""
        X = envelope_states(self.model).copy()
        X[:, 7] = [self.heading_reference(x, x[7]) for x in X]
        A = np.asarray(self._vessel_jacobian.map(len(X))(X.T))
        A = A.reshape(NXV, len(X), NXV).transpose(1, 0, 2)  # (m, 8, 8): the blocks side by side
        return float(np.abs(np.linalg.eigvals(A[:, :6, :6])).max())

    @functools.cached_property
    def _vessel_jacobian(self) -> ca.Function:
        """``J(x) -> d(vessel rhs)/dx`` (8 x 8) of the plan's vessel part, rates zero and
        still water (M1 or M1h)."""
        x = ca.SX.sym("x", NXV)
        return ca.Function("J", [x], [ca.jacobian(self._vessel_rhs(x, ca.DM.zeros(2),
                                                                   ca.DM.zeros(2)), x)])


_WARNED: set[bytes] = set()  # (vessel, execution, steering) warned about


def warn_course_unstable(ocp, file=None) -> None:
    """One line on stderr (once per vessel, execution level, steering and process) when the
    plan cannot hold a straight-line (course) unstable vessel:

    - planned with its steering angle (``steering = "rudder"``): the plan steers it open loop
      over stages of ``dt`` s, where its yaw diverges within a fraction of a second (Fossen's
      Otter on case3-otter, session 9: the plan stood still for minutes beyond r_outer);
    - planned with the heading reference (M1h), when the execution level's yaw PD does not
      stabilise it either (:meth:`PlanDynamics.closed_loop_instability`; CyberShip II under
      Gretha's gains, +0.47 1/s): the plan predicts, and the plant
      runs, a loop that diverges; the vessel needs its own execution level (``mpcasv tune
      yaw`` refuses this one: its first-order Nomoto design does not stabilise it).

    docs/mpc.md, "Known problems"."""
    unstable = course_instability(ocp.model)
    key = ocp.model.p.tobytes() + repr((ocp.execution.yaw, ocp.heading)).encode()
    if unstable is None or key in _WARNED:
        return
    name = ocp.vessel.name
    if ocp.heading:
        loop = ocp.closed_loop_instability()
        if loop is None:
            return
        u, lam = loop
        msg = (f"vessel {name!r} is straight-line unstable and its execution level's yaw PD "
               f"does not stabilise it (a pole at +{lam:.2f} 1/s with the PD, at {u:.2f} m/s): "
               "no controller holds it well; it needs an execution level tuned for it "
               "(docs/mpc.md, Known problems)")  # fmt: skip
    else:
        u, lam = unstable
        msg = (f"vessel {name!r} is straight-line unstable (a sway-yaw pole up to +{lam:.1f} "
               f"1/s, from {u:.2f} m/s): the MPC steers it open loop over {ocp.dt:g}-s stages "
               "and does not hold it well (docs/mpc.md, Known problems); the hybrid "
               "controllers close the yaw loop, and so does horizon.steering = 'heading'")
    _WARNED.add(key)
    print(f"mpcasv: warning: {msg}", file=file or sys.stderr)
