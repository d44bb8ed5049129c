"""The MPC's optimal control problem (docs/mpc.md), built once as CasADi SX expressions.

Stage-interleaved layout (what fatrop's structure detection and a Riccati recursion want):

    w = [z_0, v_0, z_1, v_1, ..., z_{N-1}, v_{N-1}, z_N, v_N]
    g = [z_1 - F(z_0, v_0), h_0, z_2 - F(z_1, v_1), h_1, ..., h_N]

- state ``z = [N, E, psi, u, v, r, T, delta, tau_1..tau_K]`` (the vessel with thrust and
  steering as states, plus each AUV's expected fix age; for a course-unstable hull ``delta``
  is replaced by the heading reference ``psi_ref`` of the execution level, whose yaw PD sets
  the steering inside the prediction: M1h, ``horizon.steering``);
- control ``v = [Tdot, deltadot, s_1..s_K, m]`` (command rates, one L1 slack per AUV, the
  worst-age epigraph variable ``m`` when its weight is positive); ``v_N = [s, m]``;
- path constraints ``h_k``: ``d_i + s_i >= r_lo,i`` and (single AUV) ``d_i - s_i <= r_hi,i``,
  ``m >= tau_i`` (at N: ``m >= tau_i + t_go,i``).
- parameters per stage: each AUV's forecast position, depth and range bounds (the radii
  depend on the forecast depth: an AUV rising under the ASV grows its collision domain);
  global: the current, the fix-rate geometry, the target, the acoustic channel
  (:func:`channel_vector`) and the weights.

The rigid-body part of the dynamics is the shared model's :func:`~mpcasv.models.vessel.xdot_expr`
evaluated with the actuators at their set-points (``u = x[6:8]``), i.e. the actuator lags
(0.3 s, 0.5 s) are removed by singular perturbation and the plan drives ``T`` and ``delta``
through their rates; it sees the state through :func:`~mpcasv.mpc.dynamics.water_guard`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from mpcasv.config import ConfigError
from mpcasv.control.params import load_execution
from mpcasv.models.envelope import course_instability
from mpcasv.models.params import load_vessel
from mpcasv.models.vessel import VesselModel
from mpcasv.mpc.dynamics import (  # noqa: F401 (NXV, RK4_LAMBDA_H re-exported)
    NXV,
    R_REF_MAX,
    R_SANE,
    RK4_LAMBDA_H,
    U_ABOVE,
    U_ASTERN,
    V_SANE,
    PlanDynamics,
)
from mpcasv.mpc.layout import (  # the parameter vector's layout (re-exported names)
    NCH,
    NW,
    WEIGHT_NAMES,
    ParamLayout,
    channel_vector,  # noqa: F401
)
from mpcasv.mpc.params import MPCParams
from mpcasv.mpc.smooth import D_EPS, SOFT_T, W_T_OF_T_ON, softplus
from mpcasv.mpc.stage_terms import StageTerms
from mpcasv.mpc.variance import N_NAV, VarianceObjective, n_ext
from mpcasv.mpc.warmstart import WarmStart


@dataclass(frozen=True)
class Dims:
    """Sizes of the stage-interleaved problem."""

    N: int
    n_auv: int
    outer: bool  # single AUV: the donut's outer bound is a (soft) constraint
    epi: bool  # worst-age epigraph variable present
    n_ext: int = 0  # objective "variance": its parameter block (mpcasv.mpc.variance.n_ext)
    n_tail: int = 0  # of the N stages, the last n_tail are coarse (M1t; horizon.tail_N)

    @property
    def nx(self) -> int:
        return NXV + self.n_auv

    @property
    def nu(self) -> int:
        return 2 + self.n_auv + int(self.epi)

    @property
    def nh(self) -> int:
        return self.n_auv * (2 if self.outer else 1) + (self.n_auv if self.epi else 0)

    @property
    def nb(self) -> int:
        return self.nx + self.nu

    @property
    def nw(self) -> int:
        return self.N * self.nb + self.nx

    @property
    def ng(self) -> int:
        return self.N * (self.nx + self.nh)

    @property
    def n_stage_par(self) -> int:
        return 5 * self.n_auv  # AUV position (2), r_lo, r_hi, depth per AUV

    @property
    def npar(self) -> int:
        return (self.nx + 2 + (self.N + 1) * self.n_stage_par + 3 * self.n_auv + NCH + NW
                + self.n_ext)  # fmt: skip

    @property
    def n_global_par(self) -> int:
        return 2 + 3 * self.n_auv + NCH + NW + self.n_ext


class OCP(StageTerms, PlanDynamics, WarmStart, VarianceObjective, ParamLayout):
    """The problem for ``n_auv`` AUVs (built once; every per-step quantity is a parameter).

    Parameters
    ----------
    params : MPCParams
    n_auv : int
    outer : bool
        Whether the outer donut bound applies (single-AUV controller).
    boat : mpcasv.controllers.Boat, optional
        The run's vessel and execution level; None: ``params.vessel`` / ``params.execution``
        (Gretha when None).

    ``params.objective = "variance"`` builds the navigation-variance problem
    (:mod:`mpcasv.mpc.variance`: M2', M4n, M4d, M7c; more parameters, another library); the
    default builds the fix-age problem, unchanged.

    Attributes
    ----------
    nlp : dict
        ``{x, p, f, g}`` of SX expressions.
    lbx, ubx, lbg, ubg : ndarray
        Bounds; ``lbx/ubx`` of stage 0 are set to the initial state per solve.
    equality : list of bool
        Which constraints are equalities (fatrop option).
    """

    def __init__(self, params: MPCParams, n_auv: int, outer: bool, boat=None):
        self.params = params
        hz, wt = params.horizon, params.weights
        if boat is None:
            self.vessel = load_vessel(params.vessel or "gretha")
            ep = load_execution(params.execution or "gretha")
        else:
            self.vessel, ep = boat.vessel, boat.execution
        self.model = VesselModel(self.vessel)
        self.execution = ep
        vp = self.vessel
        self.T_on = ep.propeller_on_threshold * vp.T_max  # execution level's threshold (N)
        self.T_floor = ep.thrust_floor * vp.T_max  # its least thrust in transit (N)
        self.T_quiet = params.fix.T_quiet if params.fix.T_quiet is not None else self.T_on
        #: width (N) of the thrust sigmoids of M3, M4b, M4c: the preset's, at most a third of
        #: the lower of the propeller-on and quiet thresholds (a stopped propeller >= 95 %
        #: quiet and not running on any boat, M3)
        self.w_T = min(params.fix.w_thrust, min(self.T_on, self.T_quiet) / W_T_OF_T_ON)
        self.dT_max = vp.T_max / params.T_ramp
        steering = hz.steering
        if steering == "auto":  # an open-loop plan cannot hold a course-unstable hull
            steering = "heading" if course_instability(self.model) else "rudder"
        #: the plan's eighth state is the heading reference of the execution level (M1h)
        self.heading = steering == "heading"
        if self.heading and params.course_control:  # docs/deploy.md, "Course control"
            raise ConfigError("course_control with M1h steering (horizon.steering 'heading', or "
                              "'auto' on a course-unstable hull): the waypoint's bearing is the "
                              "planned heading, which a vehicle that controls its course would "
                              "correct for the crab angle again; set horizon.steering = 'rudder' "
                              "or the vehicle's Course Control = false")  # fmt: skip
        self.dd_max = R_REF_MAX if self.heading else vp.delta_rate_max
        self.variance = params.objective == "variance"
        self.dims = Dims(hz.N + hz.tail_N, n_auv, outer, wt.worst > 0,
                         n_ext(n_auv) if self.variance else 0, hz.tail_N)  # fmt: skip
        #: the fine stages' length (s); the coarse tail's are ``horizon.tail_m`` times it
        self.dt = hz.dt
        self.tail_m = hz.tail_m
        #: each stage's length (s, shape (N,)) and the stages' times from now (s, (N + 1,));
        #: uniform: ``dt k`` as before (a cumulative sum rounds differently)
        self.dts = np.r_[np.full(hz.N, hz.dt), np.full(hz.tail_N, hz.tail_m * hz.dt)]
        self.t_stage = (hz.dt * np.arange(hz.N + 1) if not hz.tail_N
                        else np.r_[0.0, np.cumsum(self.dts)])  # fmt: skip
        self._build()

    def _build(self) -> None:
        d, hz, wt, vp = self.dims, self.params.horizon, self.params.weights, self.vessel
        K, N, nx, dt = d.n_auv, d.N, d.nx, hz.dt
        nq = 2 + 7 * K + NCH + (N_NAV if self.variance else 0)
        z, wv, qs = ca.SX.sym("z", nx), ca.SX.sym("w", 2), ca.SX.sym("q", nq)
        zn = self.discrete(z, wv, qs, dt, self.n_sub)
        #: discrete plan dynamics F(z, [Tdot, deltadot], q) -> z_next (mpcasv.mpc.dynamics)
        self.F = ca.Function("F", [z, wv, qs], [zn], ["z", "w", "q"], ["z_next"])

        # one stage: L_k and g_k = [z_{k+1} - F(z_k, v_k), h_k]; the terminal stage: L_N, h_N
        v, z1 = ca.SX.sym("v", d.nu), ca.SX.sym("z1", nx)
        sp, sp1 = ca.SX.sym("sp", d.n_stage_par), ca.SX.sym("sp1", d.n_stage_par)
        gp = ca.SX.sym("gp", d.n_global_par)  # current, d_fix, r_t, target, channel, weights
        c, d_fix = gp[0:2], gp[2 : 2 + K]
        o_w = 2 + 3 * K + NCH
        if self.variance:  # the weights, then the variance objective's block
            W = dict(zip(WEIGHT_NAMES, ca.vertsplit(gp[o_w : o_w + NW]), strict=True))
            ext = gp[o_w + NW :]
        else:
            W = dict(zip(WEIGHT_NAMES, ca.vertsplit(gp[o_w:]), strict=True))
        target = gp[2 + 2 * K : 2 + 3 * K]  # one-hot: the AUV the tail visits next
        ch = gp[2 + 3 * K : 2 + 3 * K + NCH]
        def q_of(spa, spb):  # F's parameters over a stage of dt s from spa to spb
            dep, dep1 = spa[4 * K : 5 * K], spb[4 * K : 5 * K]
            q = ca.vertcat(c, spa[0 : 2 * K], (spb[0 : 2 * K] - spa[0 : 2 * K]) / dt, dep,
                           (dep1 - dep) / dt, d_fix, ch)  # fmt: skip
            return ca.vertcat(q, ext[0:N_NAV]) if self.variance else q

        #: F's parameters q over a fine stage: (sp_k, sp_{k+1}, gp) -> q
        self.q_fun = ca.Function("q", [sp, sp1, gp], [q_of(sp, sp1)])
        h, lbh, ubh = self._path(z, v[2 : 2 + K], v[2 + K] if d.epi else None, sp)
        L = self._stage_cost(z, v, sp, W, ext if self.variance else None)
        #: stage k: (z_k, v_k, z_{k+1}, stage params k and k+1, global params) -> (dt L_k, g_k)
        self.stage_phys = ca.Function(
            "stage", [z, v, z1, sp, sp1, gp],
            [dt * L, ca.vertcat(z1 - self.F(z, v[0:2], q_of(sp, sp1)), h)],
            ["z", "v", "z1", "sp", "sp1", "gp"], ["L", "g"],
        )  # fmt: skip
        if d.n_tail:  # (M1t) a coarse stage: tail_m fine stages, the rates held
            m_t = hz.tail_m
            # F as a call, not inlined: its code and derivatives once, not tail_m times (an
            # inlined tail took 5 times as long to compile)
            F_call = ca.Function("F_tail", [z, wv, qs], [zn],
                                 {"never_inline": True})  # fmt: skip
            zj, Lt, spj = z, 0, sp
            for j in range(m_t):
                spn = sp + (j + 1) / m_t * (sp1 - sp)  # stage parameters interpolated
                Lt += dt * self._stage_cost(zj, v, spj, W, ext if self.variance else None)
                zj, spj = F_call(zj, v[0:2], q_of(spj, spn)), spn
            self.stage_tail_phys = ca.Function(
                "stage_tail", [z, v, z1, sp, sp1, gp], [Lt, ca.vertcat(z1 - zj, h)],
                ["z", "v", "z1", "sp", "sp1", "gp"], ["L", "g"],
            )  # fmt: skip
        tau, t_go, T_tail = z[NXV : NXV + K], self._t_go(z, sp, gp), W["tail"]
        if self.variance:  # (M7c) wait or go, the AUVs' variance over the tail
            LN = self._tail_cost(z, gp[2 + K : 2 + 2 * K], d_fix, target, ch, W, ext)
        elif wt.terminal == "projected":  # (M7a) the target's projected fix age tau + t_go
            LN = T_tail * W["age"] * ca.dot(target, tau + t_go)
        elif wt.terminal == "integral":  # (M7i) the age integrated until the target's next fix:
            # M7a + the age accrued on the way, tau t_go + t_go^2 / 2 (its weight "accrue": 1,
            # 0 under a threat), + tail^2 / 2: tau t + t^2 / 2 with t = t_go + tail
            accrued = tau * t_go + t_go**2 / 2
            LN = W["age"] * ca.dot(target, T_tail * (tau + t_go) + W["accrue"] * accrued
                                   + T_tail**2 / 2)  # fmt: skip
        else:  # (M7b) ages grow through the tail, minus what the visit of the target saves
            reach = SOFT_T * softplus((T_tail - t_go) / SOFT_T)  # (T_tail - t_go)+, s
            saved = reach * (tau + t_go)  # fix age-time saved by visiting that AUV, s^2
            LN = W["age"] * (T_tail * ca.sum1(tau) - ca.dot(target, saved))
        sp0 = ca.SX.sym("sp0", d.n_stage_par)  # stage N - 1's parameters: the AUV's velocity
        if d.outer:  # (M7s) one AUV: the standing time the plan's end leaves, short of a horizon
            short = float(self.t_stage[-1]) - self._standing_time(z, sp0, sp, float(self.dts[-1]))
            LN += W["stand"] * W["age"] * SOFT_T * softplus(short / SOFT_T)
        #: terminal stage: (z_N, stage params N - 1 and N, global params) -> L_N
        self.term_phys = ca.Function("term", [z, sp0, sp, gp], [LN], ["z", "sp0", "sp", "gp"],
                                     ["L"])  # fmt: skip

        # the solvers see scaled variables w_s = w / s_w and constraints g_s = g / s_g (M8)
        self.s_z, self.s_v, self.s_h = self._scales()
        zs, vs, z1s = ca.SX.sym("z", nx), ca.SX.sym("v", d.nu), ca.SX.sym("z1", nx)
        Ls, gs = self.stage_phys(self.s_z * zs, self.s_v * vs, self.s_z * z1s, sp, sp1, gp)
        s_g = np.r_[self.s_z, self.s_h]
        #: stage k in scaled variables: (z_k, v_k, z_{k+1}, sp_k, sp_{k+1}, gp) -> (dt L_k, g_k)
        self.stage = ca.Function("stage_s", [zs, vs, z1s, sp, sp1, gp], [Ls, gs / s_g],
                                 ["z", "v", "z1", "sp", "sp1", "gp"], ["L", "g"])  # fmt: skip
        #: a coarse stage (M1t) in scaled variables; None without a tail
        self.stage_tail = None
        if d.n_tail:
            Lt, gt = self.stage_tail_phys(self.s_z * zs, self.s_v * vs, self.s_z * z1s, sp, sp1,
                                          gp)  # fmt: skip
            self.stage_tail = ca.Function("stage_tail_s", [zs, vs, z1s, sp, sp1, gp],
                                          [Lt, gt / s_g], ["z", "v", "z1", "sp", "sp1", "gp"],
                                          ["L", "g"])  # fmt: skip
        #: terminal cost in scaled variables
        self.term = ca.Function("term_s", [zs, sp0, sp, gp],
                                [self.term_phys(self.s_z * zs, sp0, sp, gp)],
                                ["z", "sp0", "sp", "gp"], ["L"])  # fmt: skip
        self.s_w = np.concatenate([np.tile(np.r_[self.s_z, self.s_v], N), self.s_z])

        # the whole NLP: MX over the stage functions mapped along the horizon (compact code)
        p = ca.MX.sym("p", d.npar)
        wx = ca.MX.sym("w", d.nw)
        args, zN, targs = self.horizon_args(wx, p)
        Ls, Gs = self.over_stages(self.stage, self.stage_tail, args)
        self.nlp = {"x": wx, "p": p, "f": ca.sum2(Ls) + self.term(zN, *targs), "g": ca.vec(Gs)}
        self.lbg = np.tile(np.r_[np.zeros(nx), lbh], N)
        self.ubg = np.tile(np.r_[np.zeros(nx), ubh], N)
        self.equality = ([True] * nx + [False] * d.nh) * N

        # loose "sanity" bounds on the velocities and fix ages, never active in a sensible plan:
        # they keep a solver's trial points where the model cannot overflow. u and v are
        # velocities over the ground (body axes): these are their bounds in still water, and
        # :meth:`bounds` widens them by the speed of the current the plan assumes
        zlb = [-math.inf, -math.inf, -math.inf, -U_ASTERN, -V_SANE, -R_SANE, 0, 0] + [0.0] * K
        zub = [math.inf, math.inf, math.inf, vp.u_max + U_ABOVE, V_SANE, R_SANE, 0, 0] + [1e4] * K
        zlb[6], zub[6] = vp.T_min, vp.T_max
        if not self.heading:  # a heading reference (M1h) is unbounded
            zlb[7], zub[7] = -vp.delta_max, vp.delta_max
        else:
            zlb[7], zub[7] = -math.inf, math.inf
        ulb = [-self.dT_max, -self.dd_max] + [0.0] * K + ([-math.inf] if d.epi else [])
        uub = [self.dT_max, self.dd_max] + [math.inf] * K + ([math.inf] if d.epi else [])
        lbx = (zlb + ulb) * N + zlb
        ubx = (zub + uub) * N + zub
        self.lbx, self.ubx = np.array(lbx, float) / self.s_w, np.array(ubx, float) / self.s_w
        #: fix rate at a given vessel state (for the controller's bookkeeping)
        xv, pa1, dep1, df1, ch1 = (ca.SX.sym(n, s) for n, s in (
            ("x", NXV), ("pa", 2), ("depth", 1), ("d_fix", 1), ("channel", NCH)))  # fmt: skip
        dh1 = ca.sqrt(ca.sumsqr(xv[0:2] - pa1) + D_EPS**2)
        rho = self.fix_rate(dh1, dep1, df1, xv[6], ch1)
        self.rho_fun = ca.Function("rho", [xv, pa1, dep1, df1, ch1], [rho])

    def _scales(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Typical magnitudes of the state, control and path-constraint entries (M8)."""
        d, vp, tr = self.dims, self.vessel, self.params.weights.tau_ref
        K = d.n_auv
        s_z = np.r_[100.0, 100.0, 1.0, 1.0, 0.5, 0.2, vp.T_max / 4,
                    1.0 if self.heading else vp.delta_max, [tr] * K]  # fmt: skip
        s_v = np.r_[self.dT_max, self.dd_max, [10.0] * K, [tr] * int(d.epi)]
        s_h = np.r_[[10.0] * (K * (2 if d.outer else 1)), [tr] * (K if d.epi else 0)]
        return s_z, s_v, s_h

    def scaled(self, w: np.ndarray) -> np.ndarray:
        """Primal vector in the solvers' scaled variables."""
        return np.asarray(w, float) / self.s_w

    def physical(self, ws: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`scaled`."""
        return np.asarray(ws, float) * self.s_w

    def horizon_args(self, wx, p):
        """Split the MX primal and parameter vectors into the mapped stage arguments.

        Returns ``(args, z_N, term_args)``: ``self.stage.map(N)(*args)`` evaluates all stages,
        ``self.term(z_N, *term_args)`` the terminal cost.
        """
        d = self.dims
        N, nx, K = d.N, d.nx, d.n_auv
        B = ca.reshape(wx[: N * d.nb], d.nb, N)
        Zs, Vs = B[:nx, :], B[nx:, :]
        zN = wx[N * d.nb :]
        o = nx + 2
        SP = ca.reshape(p[o : o + (N + 1) * d.n_stage_par], d.n_stage_par, N + 1)
        o += (N + 1) * d.n_stage_par
        gpx = ca.vertcat(p[nx : nx + 2], p[o : o + 3 * K + NCH + NW + d.n_ext])
        args = [Zs, Vs, ca.horzcat(Zs[:, 1:], zN), SP[:, :N], SP[:, 1:], ca.repmat(gpx, 1, N)]
        return args, zN, [SP[:, N - 1], SP[:, N], gpx]

    def over_stages(self, fine: ca.Function, tail: ca.Function | None, args: list,
                    mapper=None) -> list:
        """``fine`` evaluated on the fine stages' columns of ``args`` (each with ``N``
        columns) and ``tail`` on the coarse tail's (M1t), the outputs side by side (``N``
        columns). ``mapper(f, n)`` maps a function over ``n`` stages (default ``f.map(n)``)."""
        mapper = mapper or (lambda f, n: f.map(n))
        N, nt = self.dims.N, self.dims.n_tail
        if not nt:
            return mapper(fine, N)(*args)
        out_f = mapper(fine, N - nt)(*[a[:, : N - nt] for a in args])
        out_t = mapper(tail, nt)(*[a[:, N - nt :] for a in args])
        return [ca.horzcat(a, b) for a, b in zip(out_f, out_t, strict=True)]

    def bounds(self, p: np.ndarray, T_cap: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Scaled ``lbx, ubx`` with stage 0 fixed to the initial state in ``p``; with a thrust
        cap ``T_cap`` (N; a speed cap, :meth:`thrust_caps`) the thrust's upper bound of
        stages 1..N lowered to it (None: the vessel's ``T_max``, unchanged).

        The sanity bounds on the surge and sway speeds over the ground (``u``, ``v``) are
        widened by the speed ``|c|`` of the current in ``p``: over the ground a boat at rest in
        the water moves at ``|c|`` in some direction of its body axes, so the still-water
        bounds would forbid headings across a current of 1 m/s (``|v| <= 1``) and drifting
        astern in one above 0.5 m/s (``u >= -0.5``). Before session 26 they did: in 1.0 m/s
        the plans could only point along the current and ran downstream past the AUVs
        (docs/mpc.md, "Known problems")."""
        d = self.dims
        nx = d.nx
        lbx, ubx = self.lbx.copy(), self.ubx.copy()
        lbx[:nx] = ubx[:nx] = p[:nx] / self.s_z
        c = float(np.hypot(p[nx], p[nx + 1]))  # the current the plan assumes (m/s)
        if c > 0:
            for i in (3, 4):  # u, v of stages 1..N
                idx = d.nb * np.arange(1, d.N + 1) + i
                lbx[idx] -= c / self.s_z[i]
                ubx[idx] += c / self.s_z[i]
        if T_cap is not None:
            ubx[d.nb * np.arange(1, d.N + 1) + 6] = self.thrust_caps(p[6], T_cap) / self.s_z[6]
        return lbx, ubx

    def thrust_caps(self, T_0: float, T_cap: float) -> np.ndarray:
        """Upper thrust bound (N, shape (N,)) of stages 1..N under a speed cap (the thrust
        ``T_cap`` that holds the capped speed, :meth:`~mpcasv.models.vessel.VesselModel.
        thrust_for_speed`): ``max(T_cap, T_0 - dT_max t_k)`` with ``t_k`` the stage's time
        from now, within ``[T_min, T_max]``. A thrust ``T_0`` above the cap comes down at the
        plan's rate limit ``dT_max`` (an immediate cap would be infeasible); plus 1e-6 N so
        that the ramp at exactly the rate limit stays inside after rounding."""
        t = self.t_stage[1:]  # stage k's time from now
        ub = np.maximum(T_cap, T_0 - self.dT_max * t + 1e-6)
        return np.clip(ub, self.vessel.T_min, self.vessel.T_max)

    def split(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``Z (N+1, nx), V (N, nu)`` from a primal vector."""
        d = self.dims
        w = np.asarray(w, float).ravel()
        B = w[: d.N * d.nb].reshape(d.N, d.nb)
        return np.vstack([B[:, : d.nx], w[d.N * d.nb :]]), B[:, d.nx :]

    def join(self, Z: np.ndarray, V: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`split`."""
        return np.concatenate([np.hstack([Z[:-1], V]).ravel(), Z[-1]])
