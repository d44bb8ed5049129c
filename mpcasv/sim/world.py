"""The simulated world: the ASV (vessel model + execution level), the AUVs, the acoustic
channel and each AUV's own navigation filter, advanced one supervisory period at a time.

:func:`mpcasv.sim.simulator.simulate` drives it with a controller in-process; the SITL
vehicles (``mpcasv sitl``) drive it with the References that arrive over IMC.

The world also keeps the ground-truth account every controller is judged by (issue 12,
docs/metrics.md): per plant step the geometric classes of :mod:`mpcasv.sim.account` with the
SCENARIO's evaluation domain, and per AUV the fixes and reliable fixes (Paper 2 eq. 9, via
:func:`mpcasv.hybrid.domains.reliable_fix_possible`) that define the fix ages.

Randomness: the acoustic channel and the AUVs' navigation draw from synchronised streams, one
per AUV and kind of event, a fixed number of draws per event (:mod:`mpcasv.sim.streams`,
since session 48), so that two controllers on the same (scenario, seed) meet the same noise
ping for ping (common random numbers); apart from the scenario-realisation streams
(:mod:`mpcasv.sim.distributions`), whose first spawn key is another tag.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from mpcasv.control.execution import NZ, closed_loop, escape_vector
from mpcasv.control.params import ExecutionParams, load_execution
from mpcasv.estimation import check_plan_estimator, known_plan, make_estimator
from mpcasv.hybrid.domains import r_inner, r_outer, r_target
from mpcasv.interface import ASVState, AUVEstimate, Observation
from mpcasv.models.acoustics import Fix, Report, success_probability, usbl_fix
from mpcasv.models.auv import NA, auv_step_function
from mpcasv.models.auv_nav import AUVNavFilter
from mpcasv.models.behaviours import Scripted
from mpcasv.models.frames import ned_to_body
from mpcasv.models.params import load_vessel
from mpcasv.models.vessel import NX, VesselModel
from mpcasv.sim.account import StepAccount, classify, evaluation_domain
from mpcasv.sim.scenario import Scenario
from mpcasv.sim.streams import ChannelStreams

_PLANT_CACHE: dict = {}
#: floor of the 1-sigma a status report gives for the AUV's own navigation (m): the filter's
#: sigma is 0 right after the known start, and a report of zero uncertainty would be trusted
#: absolutely by the ASV's estimators
REPORT_SIGMA_MIN = 1.0


def build_plant(scenario: Scenario):
    """(model, execution params, closed-loop function) for a scenario.

    The compiled closed loop is cached per process, keyed by the parameters' values (not the
    file names), so a changed file is never served stale.
    """
    params = load_vessel(scenario.asv.vessel)
    ep: ExecutionParams = load_execution(scenario.asv.execution)
    key = (params.vector().tobytes(), repr(ep), scenario.sim.dt, scenario.sim.n_sub)
    if key not in _PLANT_CACHE:
        model = VesselModel(params)
        _PLANT_CACHE[key] = (model, ep, closed_loop(model, ep, scenario.sim.dt, scenario.sim.n_sub))
    return _PLANT_CACHE[key]


def _packed(f: ca.Function) -> ca.Function:
    """``f`` with all outputs stacked into one column: one numpy conversion per call instead
    of one per output (the conversions cost more than the evaluation here)."""
    args = [ca.SX.sym(f.name_in(i), f.sparsity_in(i)) for i in range(f.n_in())]
    outs = f(*args)
    outs = outs if isinstance(outs, (list, tuple)) else [outs]
    return ca.Function(f"{f.name()}_packed", args, [ca.vertcat(*[ca.vec(o) for o in outs])])


@dataclass
class Period:
    """What happened during one supervisory period (plant-step resolution where useful)."""

    t0: float
    t1: float
    X: np.ndarray  # ASV states after each plant step (NX x n_sub)
    U: np.ndarray  # actuator set-points during each plant step (2 x n_sub)
    Y: np.ndarray  # [psi_d, u_ref] during each plant step
    ranges: np.ndarray  # horizontal ASV-AUV ranges (n_auv x n_sub)
    slants: np.ndarray
    fixes: np.ndarray  # successful USBL fixes per AUV in this period
    reliable: np.ndarray  # of which reliable (Paper 2 eq. 9)
    visiting: np.ndarray  # per AUV at the period's end: a fix arriving now would be reliable
    prop: np.ndarray  # propeller on at each plant step (n_sub,)
    account: StepAccount | None  # ground-truth classes per plant step (None: no domain)
    auvs: np.ndarray  # AUV states after each plant step (NA x n_auv x n_sub)


class World:
    """ASV, AUVs and acoustics of one scenario; :meth:`advance` moves one period.

    Parameters
    ----------
    scenario : Scenario
    seed : int
        Seed of the random generators (see the module docstring).
    estimator : str, optional
        AUV estimator name (default: the scenario's).

    The evaluation domain (collision / target / outer classes, reliable-fix rule) is the
    scenario's own (:func:`mpcasv.sim.account.evaluation_domain`), never a controller's.
    """

    def __init__(self, scenario: Scenario, seed: int = 0, estimator: str | None = None):
        self.sc, self.ac = scenario, scenario.acoustics
        self.draws = ChannelStreams(seed, len(scenario.auv))  # common random numbers
        self.model, self.ep, self.CL = build_plant(scenario)
        self._CL = _packed(self.CL)
        self.n_auv, self.n_sub = len(scenario.auv), scenario.sim.n_sub
        self.Tc, self.dt = scenario.sim.control_period, scenario.sim.dt
        self.thr_on = self.ep.propeller_on_threshold * self.model.params.T_max
        # the current acting on the ASV during the current period (V_N, V_E), m/s; with a
        # [current_field] also the one carrying each AUV (2 x n_auv), see mpcasv.models.current
        self.current = np.array(scenario.current, float)
        cf = scenario.current_field
        self.flow = None if cf is None else cf.evaluator(scenario.current)
        self._carry = cf is not None and cf.auv_factor > 0.0
        self.C_auv = np.zeros((2, len(scenario.auv)))
        self.domain = evaluation_domain(scenario)
        if self.domain is not None:  # the spheres' radii, once (Paper 1 eqs. 3-4)
            self._r_in, self._r_out = self.domain.r_in, self.domain.r_out
        self.t = 0.0
        self.actuator_samples: tuple[tuple[float, float, float], ...] | None = None

        s0 = scenario.asv.start
        self.x = np.zeros(NX)
        self.x[[0, 1, 2, 3]] = s0.N, s0.E, math.radians(s0.psi_deg), s0.speed
        self.x[6] = self.model.thrust_for_speed(s0.speed) if s0.speed > 0 else 0.0
        # start.speed is through the water and the boat is not held against the current: it
        # starts carried by it (nu = nu_r + R(psi)^T [V_N, V_E], eq. 2.6; nu over ground)
        u_c, v_c = ned_to_body(float(self.x[2]), *self.current_at_asv())
        self.x[3] += u_c
        self.x[4] += v_c
        self.z = np.zeros(NZ)
        self.S = np.array(
            [[a.start.N, a.start.E, a.start.depth, math.radians(a.start.psi_deg), a.start.speed]
             for a in scenario.auv], float,
        ).T  # fmt: skip
        if self._carry:  # the drift before the first period (the perfect estimator's velocity)
            self.C_auv = self.flow.auv_factor * self.flow(0.0, self.S[:2])
        self.LIM = np.array([a.limits.vector() for a in scenario.auv]).T
        self.behaviours = [a.build_behaviour() for a in scenario.auv]
        # AUVs whose limits may change (limit events, an abort's rise rate)
        self._scripted = [k for k, b in enumerate(self.behaviours) if isinstance(b, Scripted)]
        self._auv_step = _packed(auv_step_function(self.dt, self.n_sub, self.n_auv,
                                                   drift=self._carry))  # fmt: skip
        name = estimator or scenario.estimator
        # not the Kalman filter under the name "plan" (the callers refuse it up front)
        check_plan_estimator(scenario, name, f"estimator {name!r}")
        self.estimators = [
            make_estimator(
                name,
                initial=AUVEstimate(*self.S[:3, k], t_last_fix=0.0),
                plan=known_plan(self.behaviours[k]),
            )  # fmt: skip
            for k in range(self.n_auv)
        ]
        self.nav = AUVNavFilter(self.n_auv, scenario.navigation, self.draws.start())
        n, ac = self.n_auv, self.ac
        # USBL polls the AUVs in turn: AUV k pings at k*T0/n + j*T0; reports likewise
        self.next_ping = np.array([k * ac.T0 / n for k in range(n)]) + ac.T0
        self.next_report = np.array([k * ac.T_report / n for k in range(n)]) + ac.T_report
        self.last_fix = np.zeros(n)  # the AUVs start with a known position at t = 0
        self.last_reliable = np.zeros(n)
        self.stay = 0.0  # ongoing continuous stay inside a collision domain (s)
        self.reliable_times: list[list[float]] = [[] for _ in range(n)]
        #: every USBL fix as measured (its times: :attr:`fix_times`; mpcasv sitl's ASV sends
        #: them as DUNE's UsblFixExtended)
        self.fixes: list[list[Fix]] = [[] for _ in range(n)]
        #: every status report that got through (``mpcasv sitl --auv-states acoustic`` sends
        #: them as the AUVs' EstimatedStates)
        self.reports: list[list[Report]] = [[] for _ in range(n)]
        self.energy_J = 0.0
        self.min_range = self.min_slant = math.inf
        #: put the true current into the observations (only for a controller that asks)
        self.oracle_current = False

    @property
    def propeller_on(self) -> bool:
        """n_p != 0: actual thrust above the configured fraction of T_max."""
        return bool(self.x[6] > self.thr_on)

    def asv_state(self) -> ASVState:
        x = self.x
        return ASVState(x[0], x[1], x[2], x[3], x[4], x[5])

    def auv_truth(self, k: int) -> tuple[float, float, float, float, float]:
        """(N, E, depth, v_N, v_E) of AUV ``k`` (velocity over ground: with the current
        carrying it during the last period)."""
        N, E, d, psi, U = self.S[:, k]
        c = self.C_auv[:, k]
        return N, E, d, U * math.cos(psi) + c[0], U * math.sin(psi) + c[1]

    def auv_course_over_ground(self, k: int) -> tuple[float, float]:
        """(course, speed) over ground of AUV ``k`` (rad from north, m/s): what its status
        report carries. The filters' state is the velocity over ground, and an AUV's navigation
        reports it (IMC EstimatedState's ``vx``, ``vy``; ``mpcasv deploy`` reads a report's
        course and speed from them): the heading and the speed through the water plus the
        current carrying the AUV (thesis eq. 2.6). At rest over ground the course is the
        heading (as in the deploy)."""
        _, _, _, v_N, v_E = self.auv_truth(k)
        sog = math.hypot(v_N, v_E)
        return (math.atan2(v_E, v_N) if sog > 0.0 else float(self.S[3, k])), sog

    @property
    def fix_times(self) -> list[list[float]]:
        """The times (s) of every successful USBL fix, per AUV (of :attr:`fixes`)."""
        return [[f.t for f in fk] for fk in self.fixes]

    def current_at_asv(self) -> tuple[float, float]:
        """The true current (V_N, V_E) at the ASV now (m/s): the field at this time and
        position, else the scenario's constant current."""
        if self.flow is None:
            return float(self.current[0]), float(self.current[1])
        V = self.flow(self.t, self.x[:2])
        return float(V[0]), float(V[1])

    def observation(self) -> Observation:
        """What a controller sees now (estimators fed with the truth for ``perfect``): the
        ASV's state and its actuators' (thrust, steering) as the boat knows them (exact:
        the simulator has no navigation or actuator sensor noise), now and through the last
        period (:attr:`actuator_samples`, None before the first); the true current only
        when :attr:`oracle_current` is set (a controller that asked for it, ablations); the
        ASV's own USBL fix times (the last per AUV)."""
        for k, est in enumerate(self.estimators):
            est.on_truth(self.t, *self.auv_truth(k))
        ests = tuple(e.estimate(self.t) for e in self.estimators)
        oracle = self.current_at_asv() if self.oracle_current else None
        return Observation(self.t, self.asv_state(), self.propeller_on, ests,
                           (float(self.x[6]), float(self.x[7])), oracle,
                           tuple(float(t) for t in self.last_fix),
                           self.actuator_samples)  # fmt: skip

    def advance(self, cmd: np.ndarray) -> Period:
        """Move everything one supervisory period under execution-level command ``cmd``
        (see :func:`mpcasv.control.execution.command_vector`). A transit while the ASV is
        inside a collision domain (:attr:`stay` > 0) runs as an escape (``cmd[0]`` = 2, the
        power turn of ``turn_scope = "avoidance"``), whoever sent it: the simulator and the
        SITL's FollowReference maneuver alike (:func:`~mpcasv.control.execution.escape_vector`)."""
        cmd = escape_vector(cmd, self.stay > 0)
        t0, x0 = self.t, self.x
        n, m = self.n_sub, self.n_auv
        if self.flow is not None:  # at the period's middle, at the positions at its start
            t_mid = t0 + 0.5 * self.Tc
            self.current = self.flow(t_mid, x0[:2])
            if self._carry:
                self.C_auv = self.flow.auv_factor * self.flow(t_mid, self.S[:2])
        v = self._CL(x0, self.z, cmd, self.current).full().ravel()
        x_next, z = v[:NX], v[NX : NX + NZ]
        i = NX + NZ
        X = v[i : i + NX * n].reshape(NX, n, order="F")
        if self.sc.sim.actuator_samples:  # the actuators at the plant steps' ends
            ts = t0 + self.dt * np.arange(n + 1)
            A = np.column_stack([x0[6:8], X[6:8]])
            self.actuator_samples = tuple(zip(ts.tolist(), A[0].tolist(), A[1].tolist(),
                                              strict=True))  # fmt: skip
        Uin = v[i + NX * n : i + (NX + 2) * n].reshape(2, n, order="F")
        Y = v[i + (NX + 2) * n :].reshape(2, n, order="F")
        SP = np.array([b.setpoint(t0, self.S[:, k], x0[:2]) for k, b in enumerate(self.behaviours)])
        for k in self._scripted:  # after setpoint(): events up to t0 applied
            lim = self.behaviours[k].limits_now()
            if lim is not None:
                self.LIM[:, k] = lim
        if self._carry:
            w = self._auv_step(self.S, SP.T, self.LIM, self.C_auv).full().ravel()
        else:
            w = self._auv_step(self.S, SP.T, self.LIM).full().ravel()
        S_next = w[: NA * m].reshape(NA, m, order="F")
        # the mapped function stacks the AUVs' (NA x n) trajectories side by side
        ST = w[NA * m :].reshape(NA, n, m, order="F").transpose(0, 2, 1)  # [:, k, j]
        u_c = ned_to_body(X[2], self.current[0], self.current[1])[0]
        self.energy_J += float(np.sum(X[6] * np.abs(X[3] - u_c)) * self.dt)  # thrust x speed
        ranges = np.hypot(X[0][None, :] - ST[0], X[1][None, :] - ST[1])
        slants = np.hypot(ranges, ST[2])
        self.min_range = min(self.min_range, float(ranges.min()))
        self.min_slant = min(self.min_slant, float(slants.min()))
        prop = X[6] > self.thr_on  # n_p != 0 at each plant step
        account = None
        if self.domain is not None:
            account = classify(self.domain, ranges, ST[2], prop, self.dt, self.stay)
            self.stay = float(account.stay[-1])
        self.nav.advance(np.hypot(S_next[0] - self.S[0], S_next[1] - self.S[1]))
        self.x, self.z, self.S = np.array(x_next).ravel(), np.array(z).ravel(), S_next
        self.t = t0 + self.Tc
        visiting = self.visiting()  # at the period's end, when its pings are evaluated
        fixes, reliable = self._acoustics(visiting)
        return Period(t0, self.t, X, Uin, Y, ranges, slants, fixes, reliable, visiting, prop,
                      account, ST)  # fmt: skip

    def _acoustics(self, visiting: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """USBL pings and status reports due in the period just ended (evaluated at its end).

        A successful fix goes to the ASV's estimator; the ASV then sends it to the AUV over
        the same acoustic link (success probability as the ping's), whose navigation filter
        fuses it with the fix's covariance. A fix that arrives while :meth:`visiting` holds
        (``visiting``, per AUV, now) is reliable (Paper 2 eq. 9). At the surface the AUV has
        GPS. Every draw comes from the synchronised streams (:mod:`mpcasv.sim.streams`): each
        ping, report and period draws its values whether or not they are used.
        """
        ac, t1, S, draws = self.ac, self.t, self.S, self.draws
        prop = self.propeller_on
        fixes, reliable = np.zeros(self.n_auv, int), np.zeros(self.n_auv, int)
        for k in range(self.n_auv):
            at_surface = S[2, k] < 0.5
            gps, ins = draws.period(k)
            if at_surface:  # GPS at the surface: R = gps_sigma^2 / 2 per axis
                s2 = ac.gps_sigma**2 / 2
                self.nav.update(k, t1, math.sqrt(s2) * gps, s2 * np.eye(2), ins)
            modem_ok = not (at_surface and not self.sc.auv[k].modem_at_surface)
            r_h = math.hypot(self.x[0] - S[0, k], self.x[1] - S[1, k])
            slant = math.hypot(r_h, S[2, k])
            p_ok = float(success_probability(slant, prop, ac)) if modem_ok else 0.0
            while self.next_ping[k] <= t1 + 1e-9:
                self.next_ping[k] += ac.T0
                ping = draws.ping(k)
                if ac.usbl and ping.u_ok < p_ok:
                    fix = usbl_fix(t1, k, self.x[:2], S[:3, k], ac, ping.z)
                    self.estimators[k].on_fix(fix)
                    if ping.u_reach < p_ok:  # the fix reaches the AUV
                        v = np.array([fix.N - S[0, k], fix.E - S[1, k]])
                        self.nav.update(k, t1, v, np.reshape(fix.cov, (2, 2)), ping.ins)
                    fixes[k] += 1
                    self.fixes[k].append(fix)
                    self.last_fix[k] = t1
                    if visiting[k]:
                        reliable[k] += 1
                        self.reliable_times[k].append(t1)
                        self.last_reliable[k] = t1
            while self.next_report[k] <= t1 + 1e-9:
                self.next_report[k] += ac.T_report
                if draws.report(k) < p_ok:
                    e = self.nav.error(t1)[k]
                    sigma = max(float(self.nav.sigma(t1)[k]), REPORT_SIGMA_MIN)
                    course, sog = self.auv_course_over_ground(k)
                    report = Report(t1, k, S[0, k] + e[0], S[1, k] + e[1], S[2, k], course,
                                    sog, sigma)  # fmt: skip
                    self.estimators[k].on_report(report)
                    self.reports[k].append(report)
        return fixes, reliable

    def visiting(self) -> np.ndarray:
        """Paper 2's reliable-fix rule (eq. 9) per AUV now, with the scenario's domain:
        r_k < r_t,k + eps at the AUV's true range and depth, and the propeller off (shape
        (n_auv,), bool). A fix that arrives while this holds is a reliable fix. Never true
        without an evaluation domain."""
        if self.domain is None:
            return np.zeros(self.n_auv, bool)
        r_h = np.hypot(self.x[0] - self.S[0], self.x[1] - self.S[1])
        r_t = r_target(self.S[2], self._r_in, self.domain.delta_r)  # Paper 2 eq. 6
        return self.domain.reliable_fix_possible(r_h, r_t, self.propeller_on)

    def radii(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(r_inner = r_avoid,k, r_outer, r_t) of each AUV at its true depth now (m, shape
        (n_auv,)), from the scenario's domain; None without one."""
        if self.domain is None:
            return None
        inner = r_inner(self.S[2], self._r_in)
        return inner, r_outer(self.S[2], self._r_out), inner + self.domain.delta_r
