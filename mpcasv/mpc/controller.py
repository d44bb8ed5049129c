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
   at rest the rudder has no authority, so the gradient cannot say "turn and go"); that
   periodic one runs after the command (:meth:`between_steps`) and warm-starts the next step
   when cheaper (a late standby's, with several AUVs: when converged within the bounds);
   after a target change, with a threat, or before a rescue it runs in the step;
   with ``solver.step_iter`` a warm solve that stops there is finished after the command and
   the step follows the last converged plan instead (:mod:`mpcasv.mpc.carry`);
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
   ``standby_time``, else TRANSIT to the planned position ``lookahead`` seconds ahead, less
   the planned current's drift over that time unless the vehicle controls its course
   (``course_control``; :mod:`~mpcasv.mpc.plan_output`), pushed out to ``min_carrot`` m, at a
   speed from the plan (``speed_rule``: a cap over the
   lookahead, or the planned speed one period ahead), labelled AVOIDANCE or TRACKING.

Where the solves run (in this process, in the simulation's hang guard's worker, or in the
field mode's worker against the step's deadline) is :mod:`mpcasv.mpc.solving`; the other
mixins: :mod:`~mpcasv.mpc.worldview`, :mod:`~mpcasv.mpc.safety`,
:mod:`~mpcasv.mpc.plan_output`, :mod:`~mpcasv.mpc.target`, :mod:`~mpcasv.mpc.speedcap`,
:mod:`~mpcasv.mpc.carry`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np

from mpcasv.controllers import Boat, ControllerKind
from mpcasv.estimation.current import CurrentObserver
from mpcasv.hybrid.multi import HybridMulti, HybridMultiParams
from mpcasv.hybrid.single import HybridSingle, HybridSingleParams
from mpcasv.interface import Command, Mode, Observation, PlannedTrajectory, Reason
from mpcasv.models.acoustics import AcousticParams
from mpcasv.mpc.carry import Carry, Deferred
from mpcasv.mpc.deadline import DeadlineSolver
from mpcasv.mpc.dynamics import warn_course_unstable
from mpcasv.mpc.hung import HungSolve
from mpcasv.mpc.order import auv_limit
from mpcasv.mpc.params import MPCParams
from mpcasv.mpc.plan_check import PLAN_CHECK_S, plan_energy
from mpcasv.mpc.plan_output import PlanOutput
from mpcasv.mpc.problem import OCP, channel_vector
from mpcasv.mpc.rescue import funnel
from mpcasv.mpc.safety import Safety
from mpcasv.mpc.solvers import make_solver
from mpcasv.mpc.solving import Solving
from mpcasv.mpc.speedcap import SpeedCap
from mpcasv.mpc.target import Targeting
from mpcasv.mpc.worldview import WorldView, untested_current

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


def worker_solver(params: MPCParams, n_auv: int, multi: bool, boat):
    """The solver of a worker process (:class:`~mpcasv.mpc.deadline.DeadlineSolver`: the field
    mode, the hang guard, :func:`mpcasv.mpc.hung.replay`): the same problem as the
    controller's, its library loaded from the cache."""
    return build_ocp(params, n_auv, multi, log=lambda *a: None, boat=boat)[1]


class MPCController(WorldView, Safety, PlanOutput, Targeting, SpeedCap, Carry, Solving):
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
    u_cap : float or None
        The plan's speed cap (m/s; :meth:`set_speed_cap`, docs/mpc.md "Variables and
        dynamics"); None: none (the default). ``u_plan`` / ``T_cap``: the cap (m/s) and its
        thrust (N) the current step plans with.
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
        #: solves in a worker process: the field mode's deadline (:meth:`use_deadline`) or
        #: simulation's hang guard (:meth:`use_hang_guard`); None: in this process
        self.deadline: DeadlineSolver | None = None
        self._hang_guard = False
        self._setup(n_auv)
        self.reset(n_auv)
        warn_course_unstable(self.ocp)

    # ------------------------------------------------------------------ set-up
    def _setup(self, n_auv: int) -> None:
        P = self.params
        self.ocp, self.solver = build_ocp(P, n_auv, self.multi, boat=self.boat)
        self.observer = CurrentObserver(self.ocp.model, P.observer)
        self._take_speed_cap(rebuilt=True)  # the speed cap's thrust on this problem's vessel
        if self.deadline is not None and getattr(self, "_deadline_n", n_auv) != n_auv:
            guard = self._hang_guard  # another number of AUVs: workers for the new problem,
            self.use_deadline(spare=not guard)  # in the same mode (field or hang guard)
            self._hang_guard = guard
        if self.multi:
            self.hybrid = HybridMulti(HybridMultiParams(P.domain, P.T_standby, P.speed,
                                                        avoidance=P.avoidance))  # fmt: skip
        else:
            self.hybrid = HybridSingle(HybridSingleParams(P.domain, P.speed, P.avoidance))

    @property
    def needs_current_oracle(self) -> bool:
        """``current = "oracle"``: the simulator puts the true current into the observations
        (:attr:`MPCParams.needs_current_oracle`)."""
        return self.params.needs_current_oracle

    @property
    def needs_usbl_fixes(self) -> bool:
        """The ASV's own USBL fix times in every observation (``fix_age_source =
        "observed"``, M2o; the simulator's and, from DUNE's UsblFixExtended, the deploy's;
        not an older deploy log's, which ``mpcasv replay`` then refuses)."""
        return self.params.needs_usbl_fixes

    def reset(self, n_auv: int) -> None:
        if not self.multi and n_auv != 1:
            raise ValueError(f"{self.name} serves one AUV, got {n_auv}")
        limit = auv_limit(self.params)  # before a problem for n_auv is built
        if limit is not None and n_auv > limit[0]:
            raise ValueError(f"{self.name} serves at most {limit[0]} AUVs with these "
                             f"parameters, got {n_auv} ({limit[1]})")  # fmt: skip
        if n_auv != self.ocp.dims.n_auv:
            self._setup(n_auv)
        self.hybrid.reset(n_auv)
        self.observer.reset()
        #: the current the plan assumes (V_N, V_E), m/s (``params.current``; set each step)
        self.current = np.zeros(2)
        self.current_noted = False  # said once that the current is stronger than tested
        self.tau = np.zeros(n_auv)  # expected fix ages (s)
        self.stand_off = False  # M7s and M7i's accrual off this step: a threat (worldview)
        self.t_prev: float | None = None
        self.w_prev: np.ndarray | None = None
        self.w_ok = False  # w_prev is a converged plan the check let through (mpc/carry.py)
        #: a carried step's work, done after its command (mpc/carry.py; between_steps)
        self.deferred: Deferred | None = None
        self.lam_prev: tuple | None = None
        self.plan: PlannedTrajectory | None = None
        #: the previous plan start's heading (rad, unwrapped; worldview._x0)
        self.psi_prev: float | None = None
        self.fallbacks = 0
        self.fallback_log: list[FallbackEvent] = []
        #: steps per plan source: "plan" (warm-started or exploration solve), "rescue" (a
        #: rescue solve), "as-escape" (a refused plan no deeper than the escape manoeuvre),
        #: "escape" (the escape manoeuvre), "fallback" (the hybrid's command)
        self.sources: dict[str, int] = {}
        #: steps whose solves (or the exploration solve after them) took longer than
        #: ``budget_ms`` of wall time: a diagnostic in simulation (never a decision); in the
        #: field such a solve is cut at the deadline
        self.over_budget = 0
        self._t_step = 0.0
        self._hung = 0
        #: solves abandoned as hung this run, kept for a replay (:mod:`mpcasv.mpc.hung`)
        self.hung_solves: list[HungSolve] = []
        self.t_explore: float | None = None
        #: when the first plan of the present standby streak meant to move off (s; None: the
        #: plan commanded was no standby); a later plan still standing by past it is late
        #: (:meth:`Safety._late`)
        self.t_depart: float | None = None
        self._reset_dwell()
        self.explored = 0  # exploration solves run (in a step or between steps)
        self.explore_adopted = 0  # exploration plans that warm-started the next step
        #: (observation, solved parameters, result) of a step whose exploration is due
        #: (between_steps)
        self._pending: tuple | None = None
        #: an in-step exploration's unconverged, cheaper iterate: the next step's start
        self._alt_start: np.ndarray | None = None
        self.rescues = 0  # steps that needed rescue solves (docs/mpc.md, "Fallbacks")
        self.target = 0  # the AUV the terminal cost visits next
        #: when the target was chosen by the rule (s; -inf: not yet, ``committed``)
        self.t_commit = -math.inf
        #: per AUV: expected fixes since then (the fix rate of eq. M3 integrated; mpc/target.py)
        self.fixes_since = np.zeros(n_auv)
        #: per AUV: expected fixes since the run began, and visited once since then (the
        #: first tour, M9t; mpc/target.py)
        self.fixes_run = np.zeros(n_auv)
        #: the ASV's USBL fix times seen at the previous step (``fix_age_source =
        #: "observed"``, M2o; None: no step yet)
        self._seen_fix: np.ndarray | None = None
        self.toured = np.zeros(n_auv, bool)
        self.t_run0: float | None = None  # the run's first step (s; mpc/target.py)
        self.target_switches = 0  # changes of target this run (diagnostic, issue 16 item 6)
        #: per AUV: the last two distinct depth estimates (t, depth) and the vertical speed
        self._depth_hist: list[list[tuple[float, float]]] = [[] for _ in range(n_auv)]
        self.w_depth = np.zeros(n_auv)  # estimated vertical speed, positive down (m/s)
        self.dwell = 0.0  # time spent in the target AUV's target domain (s)
        self.order_plan = None  # target_rule "order": the last cheapest order (mpc/order.py)
        #: if a list: (parameters, elapsed stages) of every step's main solve (benchmarks)
        self.recorder: list | None = getattr(self, "recorder", None)
        self._diag: dict = {}
        #: the plan whose command the previous step handed over (None: a fallback step)
        self._used_plan: PlannedTrajectory | None = None

    # ------------------------------------------------------------------ per step
    def step(self, obs: Observation) -> Command:
        self._hung = 0  # solves abandoned as hung this step (simulation's hang guard)
        self.between_steps()  # the previous step's exploration, if nobody ran it yet
        ocp = self.ocp
        self._t_step = time.perf_counter()  # wall time: the field deadline and diagnostics only
        self._take_speed_cap()  # one speed cap for the whole step (set_speed_cap)
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
        cap = self._step_limit()  # the step's iteration budget (None: none)
        res = self._solve(p_s, w0, *lam, max_iter=cap)
        carried = self._carried(res, cap, w0, p)
        if carried is not None:  # the previous plan this step; the work after the command
            self._defer(Deferred(obs, p_s, p, w0, lam, hybrid_cmd))
            res, reason, source = carried, None, "carried"
        else:  # as without a budget (a solve stopped at it: solved again in full)
            full = self._solve(p_s, w0, *lam) if self._stopped(res, cap) else None
            res = res if full is None else dataclasses.replace(
                full, ms=res.ms + full.ms, iters=res.iters + full.iters)
            res, reason, source = self._work(obs, p_s, p, res, hybrid_cmd)
            self._keep_start(res, source)
        over = self._over_budget()
        self.over_budget += over  # measured, never a decision in simulation
        self.sources[source] = self.sources.get(source, 0) + 1
        self._diag = {"mpc_ok": int(res.ok), "mpc_iter": res.iters, "mpc_ms": res.ms,
                      "mpc_cost": res.f, "mpc_status": res.status,
                      "mpc_fallback": int(reason is not None),
                      "mpc_fallback_reason": reason or "", "mpc_over_budget": over,
                      "mpc_source": source, "mpc_funnel": int(p_s is not p),
                      "mpc_hung": self._hung, "mpc_explore_ms": math.nan,
                      "mpc_explore_iter": 0, "mpc_explore_cost": math.nan,
                      "mpc_explore_adopted": 0, "mpc_deferred_iter": 0,
                      "mpc_deferred_ms": math.nan, "mpc_deferred_source": ""}  # fmt: skip
        self._diag |= {f"mpc_tau{i}": float(v) for i, v in enumerate(self.tau)}
        self._diag |= {"mpc_plan_E_J": e_plan, "mpc_plan_E_t0": t_used, "mpc_plan_E_t1": obs.t,
                       "mpc_plan_t": math.nan}  # fmt: skip
        self._diag |= {f"mpc_plan_{q}{h}": math.nan for h in PLAN_CHECK_S for q in "NET"}
        self._diag["mpc_target"] = self.target
        self._diag["mpc_stand_off"] = int(self.stand_off)  # M7s, M7i accrual off: a threat
        c_est = self.observer.current
        self._diag |= {"mpc_cur_N": float(self.current[0]), "mpc_cur_E": float(self.current[1]),
                       "mpc_est_cur_N": float(c_est[0]), "mpc_est_cur_E": float(c_est[1])}
        # 1.0: the current planned with is above the tested one (metric current_untested_s)
        self._diag["mpc_cur_untested"] = float(untested_current(self.current))
        self._diag["mpc_target_switches"] = self.target_switches  # cumulative
        self._diag["mpc_dwell_held"] = 0  # 1: the dwell rule held the plan's mode back
        if reason is not None:
            self.t_depart = None  # the hybrid's step: no standby promise of the plan
            self.fallbacks += 1
            self.fallback_log.append(FallbackEvent(obs.t, reason, res.status, res.ms))
            if hybrid_cmd.mode is Mode.STANDBY:
                return self._issued(obs.t, Command.standby(hybrid_cmd.auv, Reason.FALLBACK))
            return self._issued(obs.t, Command(Mode.TRANSIT, hybrid_cmd.waypoint,
                                               hybrid_cmd.speed, hybrid_cmd.auv,
                                               Reason.FALLBACK))  # fmt: skip
        # the plan commanded (solved, rescued, or the escape manoeuvre) is the one stored:
        # the plan-tracking metrics compare the boat with what it was told to do
        self._store_plan(obs.t, res.w)
        return self._issued(obs.t, self._command(obs, res.w, p, source))

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
                            libraries=_libraries(True), auv_limit=auv_limit)  # fmt: skip
