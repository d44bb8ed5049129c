"""The MPC as a supervisory :class:`~mpcasv.interface.Controller` (``mpc-single``, ``mpc-multi``).

Every step (docs/mpc.md, "Controller"):

1. fix-age bookkeeping: each AUV's expected fix age ``tau_i`` is propagated over the elapsed
   period with the same fix-rate model the plan uses (or read from the estimate);
2. the parameters: the ASV state (thrust and steering estimated: the observation carries
   only whether the propeller runs), the AUVs' positions over the horizon (the estimator's
   forecast: along the known plan with the plan-aware estimator, else constant velocity),
   their anti-collision radii along the planned bearing (the hybrid controllers' domain
   functions, :func:`~mpcasv.hybrid.avoidance.estimate_shape`);
3. a warm-started solve from the previous plan moved one control period ahead;
   while the plan stands still, every ``explore_every`` s a second solve starts from a guess
   heading for the AUV with the largest projected fix age (standing still is a local minimum:
   at rest the rudder has no authority, so the gradient cannot say "turn and go");
4. the safety check and, when the plan cannot be used (a failed solve, or a plan entering
   r_inner / r_avoid within its first ``check_stages`` stages, or, already inside, closing
   the range further), the rescue: solves from the unconverged iterate, an escape guess and
   the hybrid's command with a larger iteration budget; a plan no deeper than the escape
   manoeuvre, else the escape manoeuvre itself; only with no AUV near does the hybrid
   controller take the step (stepped on every observation so that its state is current),
   counted in ``fallbacks`` (docs/mpc.md, "Fallbacks"). Far outside the range bounds the
   bounds are relaxed along a funnel (:func:`~mpcasv.mpc.rescue.funnel`) and the problem is
   solved;
5. the command: STANDBY while the plan keeps the thrust below the propeller-on threshold for
   ``standby_time``, else TRANSIT to the planned position ``lookahead`` seconds ahead (pushed
   out to ``min_carrot`` m) at the planned speed, labelled AVOIDANCE or TRACKING (its reason).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from dataclasses import dataclass

import numpy as np

from mpcasv.controllers import Boat, ControllerKind
from mpcasv.estimation.current import CurrentObserver, measurement
from mpcasv.hybrid.avoidance import estimate_shape
from mpcasv.hybrid.multi import HybridMulti, HybridMultiParams
from mpcasv.hybrid.single import HybridSingle, HybridSingleParams
from mpcasv.interface import Command, Mode, Observation, PlannedTrajectory, Reason
from mpcasv.models.acoustics import AcousticParams
from mpcasv.mpc.deadline import DeadlineSolver
from mpcasv.mpc.params import MPCParams
from mpcasv.mpc.plan_check import PLAN_CHECK_S, plan_energy, planned_standby
from mpcasv.mpc.problem import NXV, OCP, channel_vector
from mpcasv.mpc.rescue import command_guess, escape_guess, funnel
from mpcasv.mpc.solvers import SolveResult, make_solver

R_HI_NONE = 1.0e5  # "no outer bound" (m)
TAU_UNKNOWN = 600.0  # fix age used for an AUV never fixed (s)
W_MAX_DEPTH = 2.0  # bound on the estimated vertical speed of an AUV (m/s)
#: field mode: part of the step's budget kept for the fallback and the command after a
#: missed solve deadline (s)
STEP_RESERVE_S = 0.03

_OCP_CACHE: dict = {}


@dataclass(frozen=True, slots=True)
class FallbackEvent:
    """One step handed to the hybrid controller, and why."""

    t: float
    reason: str
    status: str
    solve_ms: float


def build_ocp(params: MPCParams, n_auv: int, multi: bool, log=print, boat: Boat | None = None):
    """(OCP, solver) for ``n_auv`` AUVs planning on ``boat`` (None: the preset's, see
    :class:`MPCParams`), shared by controllers with the same parameters in one process (the
    compiled library is also cached on disk)."""
    key = (repr(params), n_auv, multi, repr(boat))
    if key not in _OCP_CACHE:
        ocp = OCP(params, n_auv, outer=not multi, boat=boat)
        _OCP_CACHE[key] = (ocp, make_solver(ocp, params.solver, log=log))
    return _OCP_CACHE[key]


def _worker_solver(params: MPCParams, n_auv: int, multi: bool, boat):
    """The solver of a field-mode worker process (:class:`~mpcasv.mpc.deadline.DeadlineSolver`):
    the same problem as the controller's, its library loaded from the cache."""
    return build_ocp(params, n_auv, multi, log=lambda *a: None, boat=boat)[1]


def ranges(asv_NE: np.ndarray, pa: np.ndarray) -> np.ndarray:
    """Horizontal ranges (m) from ASV positions ``(..., 2)`` to AUV positions ``(..., K, 2)``
    (shape ``(..., K)``)."""
    return np.linalg.norm(np.asarray(asv_NE, float)[..., None, :] - pa, axis=-1)


class MPCController:
    """Fix-age NMPC with donut constraints and a hybrid safety fallback.

    Parameters
    ----------
    params : MPCParams
    n_auv : int
        AUVs served (the problem is built for this number; :meth:`reset` rebuilds if needed).
    multi : bool
        ``mpc-multi``: anti-collision radius only (Paper 2); else ``mpc-single`` with the donut
        ``r_inner <= r <= r_outer``.
    boat : Boat, optional
        The run's vessel and execution level, the ones the simulator integrates (one vessel
        per run); None: the preset's ``vessel`` / ``execution`` (Gretha when it names none).

    Attributes
    ----------
    plan : PlannedTrajectory or None
        The current plan (stage times, positions; ``extra`` holds thrust, speed, fix ages).
    domain : DomainParams
    fallbacks : int
        Steps whose command came from the hybrid controller.
    fallback_log : list of FallbackEvent
    """

    def __init__(self, params: MPCParams, n_auv: int = 1, multi: bool = False,
                 boat: Boat | None = None):  # fmt: skip
        self.params = params
        self.boat = boat
        self.domain = params.domain
        self.multi = multi
        self.name = "mpc-multi" if multi else "mpc-single"
        # the run's acoustic channel (the scenario's or the deploy configuration's), as the
        # vessel comes: with the Boat (default channel outside a run)
        self.acoustics = getattr(boat, "acoustics", None) or AcousticParams()
        self.channel = channel_vector(self.acoustics, params.fix.noisy_fixes)
        #: field mode (:meth:`use_deadline`): solves in a worker process with a deadline
        self.deadline: DeadlineSolver | None = None
        self._hang_guard = False
        #: ``current = "oracle"``: the simulator puts the true current into the observations
        self.needs_current_oracle = params.current == "oracle"
        self._setup(n_auv)
        self.reset(n_auv)

    def use_deadline(self, factory=None, start_timeout: float = 600.0) -> None:
        """Field mode: every step's solves run in a worker process and are abandoned at the
        step's budget ``solver.budget_ms`` (the step then takes the hybrid fallback's command,
        reason ``deadline``; the next step starts warm from the previous plan, on a spare
        worker). Set by the deploy loop; never in simulation, where only iteration limits
        decide and wall time is measured (``mpc_over_budget``), so runs are reproducible.

        ``factory`` (tests): builds the worker's solver (default: this controller's problem,
        its compiled library loaded from the cache). Blocks until the first worker is ready.

        Raises
        ------
        RuntimeError
            The worker could not build the solver within ``start_timeout`` s.
        """
        if self.deadline is not None:
            self.deadline.close()
        factory = factory or functools.partial(_worker_solver, self.params, self.ocp.dims.n_auv,
                                               self.multi, self.boat)  # fmt: skip
        self.deadline = DeadlineSolver(factory, start_timeout)
        self._deadline_n = self.ocp.dims.n_auv
        self._hang_guard = False

    def use_hang_guard(self) -> None:
        """Simulation: the solves run in a worker process and only one that has not answered
        after ``solver.hang_s`` s is abandoned (:class:`~mpcasv.mpc.params.SolverParams`;
        ``hang_s = 0``: solves stay in this process, unguarded)."""
        if self.params.solver.hang_s <= 0:
            self.close()
            return
        self.use_deadline()
        self._hang_guard = True

    def close(self) -> None:
        """Stop the field mode's solver workers (no-op in simulation)."""
        if self.deadline is not None:
            self.deadline.close()
            self.deadline = None

    # ------------------------------------------------------------------ set-up
    def _setup(self, n_auv: int) -> None:
        P = self.params
        self.ocp, self.solver = build_ocp(P, n_auv, self.multi, boat=self.boat)
        self.observer = CurrentObserver(self.ocp.model, P.observer)
        if self.deadline is not None and getattr(self, "_deadline_n", n_auv) != n_auv:
            self.use_deadline()  # another number of AUVs: workers for the new problem
        if self.multi:
            self.hybrid = HybridMulti(HybridMultiParams(P.domain, P.T_standby, P.speed,
                                                        avoidance=P.avoidance))  # fmt: skip
        else:
            self.hybrid = HybridSingle(HybridSingleParams(P.domain, P.speed, P.avoidance))

    def reset(self, n_auv: int) -> None:
        if not self.multi and n_auv != 1:
            raise ValueError(f"{self.name} serves one AUV, got {n_auv}")
        if n_auv != self.ocp.dims.n_auv:
            self._setup(n_auv)
        self.hybrid.reset(n_auv)
        self.observer.reset()
        #: the current the plan assumes (V_N, V_E), m/s (``params.current``; set each step)
        self.current = np.zeros(2)
        self.tau = np.zeros(n_auv)  # expected fix ages (s)
        self.t_prev: float | None = None
        self.w_prev: np.ndarray | None = None
        self.lam_prev: tuple | None = None
        self.plan: PlannedTrajectory | None = None
        self.fallbacks = 0
        self.fallback_log: list[FallbackEvent] = []
        #: steps per plan source: "plan" (warm-started or exploration solve), "rescue" (a
        #: rescue solve), "as-escape" (a refused plan no deeper than the escape manoeuvre),
        #: "escape" (the escape manoeuvre), "fallback" (the hybrid's command)
        self.sources: dict[str, int] = {}
        #: steps whose solves took longer than ``budget_ms`` of wall time: a diagnostic in
        #: simulation (never a decision); in the field such a step is cut at the deadline
        self.over_budget = 0
        self._t_step = 0.0
        self.t_explore: float | None = None
        self.explored = 0
        self.rescues = 0  # steps that needed rescue solves (docs/mpc.md, "Fallbacks")
        self.target = 0  # the AUV the terminal cost visits next
        self.target_switches = 0  # changes of target this run (diagnostic, issue 16 item 6)
        #: per AUV: the last two distinct depth estimates (t, depth) and the vertical speed
        self._depth_hist: list[list[tuple[float, float]]] = [[] for _ in range(n_auv)]
        self.w_depth = np.zeros(n_auv)  # estimated vertical speed, positive down (m/s)
        self.dwell = 0.0  # time spent in the target AUV's target domain (s)
        #: if a list: (parameters, elapsed stages) of every step's main solve (benchmarks)
        self.recorder: list | None = getattr(self, "recorder", None)
        self._diag: dict = {}
        #: the plan whose command the previous step handed over (None: a fallback step)
        self._used_plan: PlannedTrajectory | None = None

    # ------------------------------------------------------------------ per step
    def _fix_ages(self, obs: Observation, elapsed: float) -> np.ndarray:
        """Propagate (or read) the expected fix ages over ``elapsed`` s (eq. M2, exact for a
        constant rate)."""
        if self.params.fix_age_source == "estimate":
            ages = np.array([obs.t - a.t_last_fix for a in obs.auvs])
            return np.where(np.isfinite(ages), np.maximum(ages, 0.0), TAU_UNKNOWN)
        if elapsed <= 0:
            return self.tau
        rho = self._rates(obs)
        decay = np.exp(-rho * elapsed)
        with np.errstate(divide="ignore", invalid="ignore"):
            relaxed = 1 / rho + (self.tau - 1 / rho) * decay
        return np.where(rho > 1e-9, relaxed, self.tau + elapsed)

    def _fix_geometry(self, obs: Observation, r_lo0: np.ndarray):
        """(depth now, d_fix) per AUV: ``d_fix`` is the reliable-fix range of the ``target``
        fix model (M3; unused by the ``acoustic`` one, whose range is the channel's)."""
        K = len(obs.auvs)
        if self.params.fix.range_kind == "acoustic":
            depth = np.array([a.depth for a in obs.auvs])
            return depth, np.full(K, self.acoustics.d1)
        return np.zeros(K), self.domain.reliable_limit(r_lo0 + self.domain.delta_r)

    def _rates(self, obs: Observation) -> np.ndarray:
        """Fix rates now (1/s): propeller state as observed, geometry and channel as in the
        plan (eq. M3)."""
        r_lo = self._radii(obs, 0.0, obs.asv.position)
        _, d_fix = self._fix_geometry(obs, r_lo)
        T = self.ocp.vessel.T_max if obs.propeller_on else 0.0
        x = np.array([obs.asv.N, obs.asv.E, 0, 0, 0, 0, T, 0])
        return np.array([float(self.ocp.rho_fun(x, a.position, a.depth, d_fix[i], self.channel))
                         for i, a in enumerate(obs.auvs)])  # fmt: skip

    def _track_depth(self, obs: Observation) -> None:
        """Vertical speed of each AUV from its last two distinct depth estimates (exact for a
        steady climb under the perfect estimator; the mean rate between reports under the
        acoustic one); back to 0 once the estimate has held longer than twice that interval
        (the AUV levelled off); bounded by ``W_MAX_DEPTH``."""
        for i, a in enumerate(obs.auvs):
            h = self._depth_hist[i]
            if not math.isfinite(a.depth):
                continue
            if not h or abs(a.depth - h[-1][1]) > 1e-6:
                h.append((obs.t, a.depth))
                del h[:-2]
            if len(h) == 2 and h[1][0] > h[0][0]:
                gap = h[1][0] - h[0][0]
                w = (h[1][1] - h[0][1]) / gap
                held = obs.t - h[1][0]
                self.w_depth[i] = 0.0 if held > 2 * gap + 1e-9 else np.clip(w, -W_MAX_DEPTH,
                                                                              W_MAX_DEPTH)
            else:
                self.w_depth[i] = 0.0

    def depth_forecast(self, obs: Observation, ts: np.ndarray) -> np.ndarray:
        """Each AUV's depth at offsets ``ts`` (s) from now: the estimate moved at the tracked
        vertical speed, not above the surface (m, shape ``(len(ts), K)``)."""
        d0 = np.array([a.depth for a in obs.auvs], float)
        return np.maximum(d0[None, :] + np.asarray(ts, float)[:, None] * self.w_depth[None, :],
                          0.0)  # fmt: skip

    def _radii(self, obs: Observation, lookahead: float, asv_NE, depth=None) -> np.ndarray:
        """Anti-collision radius (r_inner / r_avoid) of each AUV ``lookahead`` s ahead, along
        the bearing from the AUV to ``asv_NE``, at the AUVs' ``depth`` (forecast; None: the
        estimates')."""
        auvs = obs.auvs
        if depth is not None:
            auvs = tuple(dataclasses.replace(a, depth=float(d))
                         for a, d in zip(auvs, depth, strict=True))  # fmt: skip
        shape = estimate_shape(self.params.avoidance, self.domain, auvs, obs.t, lookahead)
        rel = np.asarray(asv_NE, float) - shape.center
        return np.asarray(shape.radius(np.arctan2(rel[..., 1], rel[..., 0])), float)

    def _plan_current(self, obs: Observation) -> np.ndarray:
        """The current the plan assumes (``params.current``), after the observer has taken
        this observation: its estimate, the true current the simulator put in the
        observation (oracle), or zero (m/s, shape (2,)).

        Raises
        ------
        ValueError
            ``current = "oracle"`` and the observation carries no true current (only the
            simulator provides it, and only to a controller that asks).
        """
        est = self.observer.update(measurement(obs))
        mode = self.params.current
        if mode == "estimated":
            return est
        if mode == "zero":
            return np.zeros(2)
        if obs.current_oracle is None:
            raise ValueError("MPC current = 'oracle': the observation carries no true current "
                             "(only the simulator provides it, for ablations); use "
                             "current = 'estimated'")  # fmt: skip
        return np.asarray(obs.current_oracle, float)

    def _x0(self, obs: Observation) -> np.ndarray:
        """Plan initial state: the observed thrust and steering (``obs.actuators``) when the
        observation carries them; else trim thrust for the current speed through the water
        (ground surge speed less the planned current along the heading) while the propeller
        runs (at least the on-threshold), else 0, and steering from the previous plan."""
        a, ocp = obs.asv, self.ocp
        vp = ocp.vessel
        T0, d0 = 0.0, 0.0
        if obs.actuators is not None and self.params.initial_actuators == "observed":
            # the boat knows its actuators (simulation; deploy with feedback): plan from them
            T0, d0 = obs.actuators
            return np.array([a.N, a.E, a.psi, a.u, a.v, a.r, float(np.clip(T0, vp.T_min, vp.T_max)),
                             float(np.clip(d0, -vp.delta_max, vp.delta_max))])  # fmt: skip
        if obs.propeller_on:
            u_c = self.current[0] * math.cos(a.psi) + self.current[1] * math.sin(a.psi)
            T0 = max(ocp.model.thrust_for_speed(max(a.u - u_c, 0.0)), 1.2 * ocp.T_on)
            if self.plan is not None:
                d0 = float(np.interp(obs.t, self.plan.t, self.plan.extra["delta"]))
        return np.array([a.N, a.E, a.psi, a.u, a.v, a.r, min(T0, ocp.vessel.T_max), d0])

    def parameters(self, obs: Observation) -> np.ndarray:
        """The parameter vector of the OCP for this observation (after fix-age bookkeeping)."""
        d, dt = self.ocp.dims, self.ocp.dt
        K, N = d.n_auv, d.N
        ts = dt * np.arange(N + 1)
        # the estimator's forecast (along the known plan) or constant velocity
        pa = np.stack([a.predict(ts) for a in obs.auvs], axis=1)  # (N+1, K, 2)
        # bearing of each stage from the previous plan (or the current position)
        if self.w_prev is not None:
            Z, _ = self.ocp.split(self.w_prev)
            asv = Z[:, None, 0:2]
        else:
            asv = np.broadcast_to(obs.asv.position, (N + 1, 1, 2))
        # each AUV's depth over the horizon, and with it the radii: the collision domain of an
        # AUV rising towards the surface grows (r_inner / r_avoid from 0 below r_in)
        depth = self.depth_forecast(obs, ts)
        if self.params.avoidance.kind == "fixed":
            r_lo = np.stack([self._radii(obs, 0.0, obs.asv.position, depth[k])
                             for k in range(N + 1)])  # fmt: skip
        else:
            r_lo = np.stack([self._radii(obs, float(ts[k]), asv[k], depth[k])
                             for k in range(N + 1)])  # fmt: skip
        if self.multi:
            r_hi = np.full((N + 1, K), R_HI_NONE)
        else:
            r_hi = np.asarray(self.domain.outer(depth), float)
        _, d_fix = self._fix_geometry(obs, r_lo[0])
        r_t = r_lo[-1] + self.domain.delta_r
        m = self.params.margin  # the plan keeps this far off the anti-collision radius
        return self.ocp.pack(self._x0(obs), self.tau, self.current, pa, r_lo + m, r_hi - m,
                             depth, d_fix, r_t, self.target, self.channel)  # fmt: skip

    def _solve(self, p: np.ndarray, w0: np.ndarray, lam_x=None, lam_g=None,
               max_iter: int | None = None) -> SolveResult:  # fmt: skip
        """One solve (``max_iter``: this solve's iteration limit, None: ``solver.max_iter``):
        in this process (simulation: only the iteration limit decides), or in the field
        mode's worker with what is left of this step's budget."""
        if self.deadline is None:
            if max_iter is None:
                return self.solver.solve(p, w0, lam_x, lam_g)
            return self.solver.solve(p, w0, lam_x, lam_g, max_iter)
        if self._hang_guard:  # simulation: abandon only a hung solve (SolverParams.hang_s)
            return self.deadline.solve(p, w0, lam_x, lam_g, max_iter,
                                       timeout=self.params.solver.hang_s)  # fmt: skip
        return self.deadline.solve(p, w0, lam_x, lam_g, max_iter, timeout=self._left())

    def _left(self) -> float:
        """Field mode: seconds left of this step's solve budget."""
        return (self.params.solver.budget_ms / 1e3 - STEP_RESERVE_S
                - (time.perf_counter() - self._t_step))  # fmt: skip

    def step(self, obs: Observation) -> Command:
        ocp = self.ocp
        self._t_step = time.perf_counter()  # wall time: the field deadline and diagnostics only
        elapsed = 0.0 if self.t_prev is None else obs.t - self.t_prev
        self.t_prev = obs.t
        self._track_depth(obs)
        self.current = self._plan_current(obs)
        self.tau = self._fix_ages(obs, elapsed)
        self._choose_target(obs, elapsed)
        hybrid_cmd = self.hybrid.step(obs)  # always stepped: its state stays current
        # the energy the previous step's plan meant to spend until now (item 4)
        e_plan = math.nan if self._used_plan is None else plan_energy(self._used_plan, obs.t)
        t_used = math.nan if self._used_plan is None else float(self._used_plan.t[0])
        self._used_plan = None
        p = self.parameters(obs)
        if self.recorder is not None:
            self.recorder.append((p.copy(), elapsed / ocp.dt))
        if self.w_prev is None:
            w0, lam = ocp.rollout(p), (None, None)
        else:
            frac = elapsed / ocp.dt
            Z, V = ocp.split(ocp.shift(self.w_prev, frac))
            w0 = ocp.fill_slacks(Z, V, p)
            lx, lg = self.lam_prev or (None, None)
            lam = (None if lx is None else ocp.shift_lam_x(lx, frac),
                   None if lg is None else ocp.shift_lam_g(lg, frac))  # fmt: skip
        gap = self._violation_now(p)
        # far outside the range bounds: the bounds relaxed along a funnel (well scaled)
        sp = self.params.solver
        p_s = p if gap <= sp.max_violation else funnel(ocp, p, sp.max_violation,
                                                       sp.funnel_speed)  # fmt: skip
        if p_s is not p:
            Z, V = ocp.split(w0)
            w0 = ocp.fill_slacks(Z, V, p_s)
        res = self._solve(p_s, w0, *lam)
        res = self._explore(obs, p_s, res)
        reason = self._check(res, p)
        source = "plan" if reason is None else "fallback"
        # rescue, except after a missed field deadline (no time left); after a hang in
        # simulation too (the Case 4 problem that hangs fatrop converges from the escape guess)
        if reason is not None and (res.status != "deadline" or self._hang_guard):
            res, reason, source = self._rescue(obs, p_s, p, res, reason, hybrid_cmd)
        if source == "escape":  # the escape manoeuvre's rollout: warm-starts the next step
            self.w_prev, self.lam_prev = res.w, None
        elif res.ok or (np.all(np.isfinite(res.w))
                        and getattr(self.solver, "warm_from_failures", False)):  # fmt: skip
            self.w_prev = res.w  # an unconverged NLP iterate warm-starts too
            self.lam_prev = (res.lam_x, res.lam_g) if res.ok else None
        else:
            self.w_prev, self.lam_prev = None, None  # next step starts from a rollout
        over = int((time.perf_counter() - self._t_step) * 1e3 > self.params.solver.budget_ms)
        self.over_budget += over  # measured, never a decision in simulation
        self.sources[source] = self.sources.get(source, 0) + 1
        self._diag = {"mpc_ok": int(res.ok), "mpc_iter": res.iters, "mpc_ms": res.ms,
                      "mpc_cost": res.f, "mpc_status": res.status,
                      "mpc_fallback": int(reason is not None),
                      "mpc_fallback_reason": reason or "", "mpc_over_budget": over,
                      "mpc_source": source, "mpc_funnel": int(p_s is not p)}  # fmt: skip
        self._diag |= {f"mpc_tau{i}": float(v) for i, v in enumerate(self.tau)}
        self._diag |= {"mpc_plan_E_J": e_plan, "mpc_plan_E_t0": t_used, "mpc_plan_E_t1": obs.t,
                       "mpc_plan_t": math.nan}  # fmt: skip
        self._diag |= {f"mpc_plan_{q}{h}": math.nan for h in PLAN_CHECK_S for q in "NET"}
        self._diag["mpc_target"] = self.target
        c_est = self.observer.current
        self._diag |= {"mpc_cur_N": float(self.current[0]), "mpc_cur_E": float(self.current[1]),
                       "mpc_est_cur_N": float(c_est[0]), "mpc_est_cur_E": float(c_est[1])}
        self._diag["mpc_target_switches"] = self.target_switches  # cumulative
        if reason is not None:
            self.fallbacks += 1
            self.fallback_log.append(FallbackEvent(obs.t, reason, res.status, res.ms))
            if hybrid_cmd.mode is Mode.STANDBY:
                return Command.standby(hybrid_cmd.auv, Reason.FALLBACK)
            return Command(Mode.TRANSIT, hybrid_cmd.waypoint, hybrid_cmd.speed, hybrid_cmd.auv,
                           Reason.FALLBACK)  # fmt: skip
        # the plan commanded (solved, rescued, or the escape manoeuvre) is the one stored:
        # the plan-tracking metrics compare the boat with what it was told to do
        self._store_plan(obs.t, res.w)
        return self._command(obs, res.w, p)

    def _choose_target(self, obs: Observation, elapsed: float) -> None:
        """The AUV the terminal cost sends the ASV to (M9): kept until it is served (its
        expected fix age below ``tau_served``, or the ASV has been within its target domain for
        ``dwell_max``), then the one with the largest projected fix age ``tau_i + t_go,i``
        (Paper 2's eq. 8 on projected ages) among those whose projected age exceeds
        ``tau_served``; none such: the target stays (no switching between served AUVs)."""
        K = len(obs.auvs)
        if K == 1:
            return
        pos = np.array([a.position for a in obs.auvs])
        r_t = self._radii(obs, 0.0, obs.asv.position) + self.domain.delta_r
        dist = np.hypot(*(pos - obs.asv.position).T)
        if self.domain.in_reliable_range(dist[self.target], r_t[self.target]):
            self.dwell += elapsed
        served = self.tau[self.target] <= self.params.tau_served
        if not (served or self.dwell >= self.params.dwell_max):
            return
        t_go = np.maximum(dist - r_t, 0.0) / self.params.weights.U_go
        proj = self.tau + t_go
        # commitment (issue 16 item 6): leave the target only for an AUV that needs a visit
        # itself (projected fix age above tau_served); with every other AUV served the target
        # stays (before, two served AUVs swapped the target every step for a whole run)
        proj[(np.arange(K) == self.target) | (proj <= self.params.tau_served)] = -np.inf
        if not np.isfinite(proj).any():
            return
        self.dwell = 0.0
        self.target = int(np.argmax(proj))
        self.target_switches += 1
        self.t_explore = None  # new target: also try a guess heading there (_explore)

    def _explore(self, obs: Observation, p: np.ndarray, res):
        """Right after a target change, and while the plan stands still every ``explore_every``
        s, also solve from a guess that heads for the target AUV's circle (standing still is a
        local minimum: at rest the rudder has no authority); keep the cheaper plan."""
        P, ocp = self.params, self.ocp
        if P.explore_every <= 0:
            return res
        if self.t_explore is not None and obs.t - self.t_explore < P.explore_every - 1e-9:
            return res
        Z, _ = ocp.split(res.w)
        if self.t_explore is not None and res.ok and np.max(Z[1:, 6]) >= ocp.T_on:
            return res  # the plan moves already
        self.t_explore = obs.t
        par = ocp.unpack_par(p)
        j = self.target
        still = ranges(obs.asv.position, par["pa"])[:, j]  # the ASV held where it is
        # already there; but inside the anti-collision radius (plus margin) at some stage, as
        # when an AUV rises under the ASV, the guess heading out to the target circle is needed
        if np.all(still >= par["r_lo"][:, j]) and self.domain.in_reliable_range(still[0],
                                                                             par["r_t"][j]):
            return res
        if self.deadline is not None and not self._hang_guard and res.status == "deadline":
            return res  # the field budget is spent
        alt = self._solve(p, ocp.guided_rollout(p, j, P.speed))
        self.explored += 1
        best = alt if alt.ok and (not res.ok or alt.f < res.f) else res
        return dataclasses.replace(best, ms=res.ms + alt.ms, iters=res.iters + alt.iters)

    def _violation_now(self, p: np.ndarray) -> float:
        """How far (m) the ASV is outside the plan's range bounds now (0 inside)."""
        par = self.ocp.unpack_par(p)
        z0 = par["z0"]
        d = ranges(z0[0:2], par["pa"][0])
        gap = np.maximum(par["r_lo"][0] - d, 0.0)
        if not self.multi:
            gap = np.maximum(gap, d - par["r_hi"][0])
        return float(np.max(gap))

    def _check(self, res, p) -> str | None:
        """Why this step's plan may not be used (None: it may)."""
        sp = self.params.solver
        if not res.ok and res.status == "deadline" and self._hang_guard:
            return f"solver hung: no answer within {sp.hang_s:g} s (hang guard)"
        if not res.ok and res.status == "deadline":
            return f"deadline: no plan within the step's {sp.budget_ms:g} ms (field mode)"
        if not res.ok:
            return f"solver: {res.status}"
        # already inside (a pursuer caught up): a plan that gets out of the way is the best
        # there is; one that goes deeper is not
        if self._depth(res.w, p) > sp.check_margin:
            return "plan enters the anti-collision radius"
        return None

    def _depth(self, w: np.ndarray, p: np.ndarray) -> float:
        """How far (m) the plan ``w`` goes both inside an anti-collision radius (r_lo without
        the margin) and deeper than the ASV is now, within its first ``check_stages`` stages
        (0: nowhere). The safety check refuses a plan when this exceeds ``check_margin``."""
        Z, _ = self.ocp.split(w)
        par = self.ocp.unpack_par(p)
        n = min(self.params.solver.check_stages, self.ocp.dims.N) + 1
        dist = ranges(Z[:n, 0:2], par["pa"][:n])
        inside = par["r_lo"][1:n] - self.params.margin - dist[1:]
        deeper = dist[0] - dist[1:]
        return float(max(np.max(np.minimum(inside, deeper)), 0.0))

    def _rescue(self, obs: Observation, p_s: np.ndarray, p: np.ndarray, res: SolveResult,
                reason: str, hybrid_cmd: Command):  # fmt: skip
        """The warm-started plan cannot be used (``reason``): solve again, within
        ``solver.rescue_iter`` iterations each, from the unconverged iterate (solver failure),
        from the escape guess (full thrust away from the AUVs near the ASV, when there are
        any) and from the hybrid controller's command, in this order; the first plan that
        passes the check is used. None passes: a converged plan that goes no deeper than the
        escape manoeuvre's rollout (within ``check_margin``) is used (the hybrid controller
        could not do better: source ``as-escape``); else the escape manoeuvre itself (source
        ``escape``); with no AUV near, the hybrid controller's command (``fallback``).

        Returns ``(result, reason or None, source)``; ``p_s`` the solved parameters (funnel),
        ``p`` those the check uses. docs/mpc.md, "Fallbacks"."""
        P, ocp = self.params, self.ocp
        esc = escape_guess(ocp, p_s, P.margin)
        starts = []
        if not res.ok and res.status != "deadline" and np.all(np.isfinite(res.w)):
            starts.append(res.w)  # (a hung solve's "iterate" is its start: not again)
        if esc is not None:
            starts.append(esc)
        wp = None if hybrid_cmd.mode is Mode.STANDBY else hybrid_cmd.waypoint
        starts.append(command_guess(ocp, p_s, wp, hybrid_cmd.speed or P.speed))
        tried, ms, iters = [], res.ms, res.iters
        for w0 in starts:
            if self.deadline is not None and not self._hang_guard and self._left() <= 0.0:
                break  # the field budget is spent
            r = self._solve(p_s, w0, max_iter=P.solver.rescue_iter)
            ms, iters = ms + r.ms, iters + r.iters
            if r.status == "deadline" and not self._hang_guard:
                break  # field budget spent (a hang in simulation: try the next start)
            if r.ok:
                tried.append(r)
                if self._check(r, p) is None:  # the first usable plan ends the rescue
                    self.rescues += 1
                    return dataclasses.replace(r, ms=ms, iters=iters), None, "rescue"
        self.rescues += 1
        if esc is not None:
            d_esc = self._depth(esc, p)
            if tried:
                best = min(tried, key=lambda r: self._depth(r.w, p))
                if self._depth(best.w, p) <= d_esc + P.solver.check_margin:
                    return dataclasses.replace(best, ms=ms, iters=iters), None, "as-escape"
            return (SolveResult(esc, None, None, math.nan, False, "escape", iters, ms), None,
                    "escape")  # fmt: skip
        if tried:  # converged, but into the radius, with no AUV near: cannot happen often
            res = min(tried, key=lambda r: self._depth(r.w, p))
            reason = self._check(res, p) or reason
        return dataclasses.replace(res, ms=ms, iters=iters), reason, "fallback"

    def _store_plan(self, t: float, w: np.ndarray) -> None:
        Z, V = self.ocp.split(w)
        ts = t + self.ocp.dt * np.arange(Z.shape[0])
        K = self.ocp.dims.n_auv
        self.plan = PlannedTrajectory(ts, Z[:, 0].copy(), Z[:, 1].copy(), {
            "T": Z[:, 6].copy(), "u": Z[:, 3].copy(), "delta": Z[:, 7].copy(),
            "psi": Z[:, 2].copy(), "tau": Z[:, NXV:NXV + K].copy(),
            "current": self.current.copy(),
        })  # fmt: skip

    def _command(self, obs: Observation, w: np.ndarray, p: np.ndarray) -> Command:
        """STANDBY or TRANSIT from the plan (see the module docstring)."""
        P, ocp = self.params, self.ocp
        Z, _ = ocp.split(w)
        ts = ocp.dt * np.arange(Z.shape[0])
        par = ocp.unpack_par(p)
        dist = ranges(Z[:, 0:2], par["pa"])
        served = int(np.argmin(dist[-1] - par["r_t"]))
        self._log_plan(obs.t)
        m = max(1, math.ceil(P.standby_time / ocp.dt - 1e-9))
        if np.max(Z[1 : m + 1, 6]) < ocp.T_on:
            return Command.standby(auv=served, standby_time=planned_standby(ts, Z[:, 6],
                                                                            ocp.T_on))
        look = min(P.lookahead, ts[-1])
        target = np.array([np.interp(look, ts, Z[:, 0]), np.interp(look, ts, Z[:, 1])])
        here = obs.asv.position
        delta = target - here
        dn = float(np.hypot(*delta))
        if dn < 1e-6:  # plan does not move: head along the current heading
            delta, dn = np.array([math.cos(obs.asv.psi), math.sin(obs.asv.psi)]), 1.0
        wp = here + delta / dn * max(dn, P.min_carrot)
        if P.speed_rule == "max":
            u_cap = np.max(Z[ts <= look + 1e-9, 3])
        else:  # the time average of the planned speed over the lookahead
            u_cap = np.mean(np.interp(np.linspace(0.0, look, 31), ts, Z[:, 3]))
        speed = float(np.clip(u_cap, P.speed_min, ocp.vessel.u_max))
        reason = self._transit_reason(here, par)
        return Command(Mode.TRANSIT, (float(wp[0]), float(wp[1])), speed, served, reason)

    def _log_plan(self, t: float) -> None:
        """This step's command comes from :attr:`plan`: log its near-horizon predictions
        (``PLAN_CHECK_S``) for the plan-tracking metrics, and keep it for the energy check of
        the next step."""
        plan = self._used_plan = self.plan
        self._diag["mpc_plan_t"] = t
        for h in PLAN_CHECK_S:
            th = t + h
            self._diag |= {f"mpc_plan_N{h}": float(np.interp(th, plan.t, plan.N)),
                           f"mpc_plan_E{h}": float(np.interp(th, plan.t, plan.E)),
                           f"mpc_plan_T{h}": float(np.interp(th, plan.t, plan.extra["T"]))}

    def _transit_reason(self, here: np.ndarray, par: dict) -> Reason:
        """Why the plan moves: AVOIDANCE when an AUV would come within its anti-collision
        radius plus ``eps_minus`` of the ASV held where it is, at some stage of the horizon
        (the predicted AUV positions); else TRACKING (following the AUV served, or going to
        the next one: the MPC has no other reason to run the propeller)."""
        still = ranges(here, par["pa"])
        r_avoid = par["r_lo"] - self.params.margin + self.domain.eps_minus
        return Reason.AVOIDANCE if np.any(still < r_avoid) else Reason.TRACKING

    def diagnostics(self) -> dict:
        """Flat per-step record: solver status, iterations, solve time, cost, fallback."""
        return dict(self._diag)


def _build_single(params: MPCParams, n_auv: int, boat: Boat | None) -> MPCController:
    return MPCController(params, n_auv, multi=False, boat=boat)


def _build_multi(params: MPCParams, n_auv: int, boat: Boat | None) -> MPCController:
    return MPCController(params, n_auv, multi=True, boat=boat)


def _libraries(multi: bool):
    def needed(params: MPCParams, n_auv: int, boat: Boat | None) -> list:
        from mpcasv.mpc.prepare import libraries

        return libraries(params, n_auv, multi, boat)

    return needed


KIND_SINGLE = ControllerKind("mpc-single", MPCParams, _build_single, "mpc-single",
                             libraries=_libraries(False))  # fmt: skip
KIND_MULTI = ControllerKind("mpc-multi", MPCParams, _build_multi, "mpc-multi", multi=True,
                            libraries=_libraries(True))  # fmt: skip
