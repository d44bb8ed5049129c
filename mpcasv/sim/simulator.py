"""The closed-loop simulator.

Per supervisory period (1 s by default): the estimators turn the AUVs' truth and the acoustic
events into an :class:`~mpcasv.interface.Observation`; the controller returns a
:class:`~mpcasv.interface.Command`; the execution level and the vessel model run together for
the period in one compiled call (plant step 0.1 s by default); the AUVs move; USBL pings and
status reports due in the period are drawn. Everything random comes from one seeded
generator, so (scenario, controller, preset, seed) reproduce a run exactly.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from mpcasv.control.execution import NZ, closed_loop, command_vector
from mpcasv.control.params import ExecutionParams, load_execution
from mpcasv.estimation import make_estimator
from mpcasv.interface import ASVState, AUVEstimate, Controller, Mode, Observation
from mpcasv.models.acoustics import INSDrift, Report, success_probability, usbl_fix
from mpcasv.models.auv import NA, auv_step_function
from mpcasv.models.params import load_vessel
from mpcasv.models.vessel import NX, VesselModel
from mpcasv.sim.scenario import Scenario

_MODEL_CACHE: dict = {}


def build_plant(scenario: Scenario):
    """(model, execution params, closed-loop function) for a scenario, cached per process."""
    key = (scenario.asv.vessel, scenario.asv.execution, scenario.sim.dt, scenario.sim.n_sub)
    if key not in _MODEL_CACHE:
        model = VesselModel(load_vessel(scenario.asv.vessel))
        ep: ExecutionParams = load_execution(scenario.asv.execution)
        _MODEL_CACHE[key] = (model, ep, closed_loop(model, ep, scenario.sim.dt, scenario.sim.n_sub))
    return _MODEL_CACHE[key]


@dataclass
class RunResult:
    """What a simulation produced: the time series and what the metrics need besides it."""

    scenario: Scenario
    controller: str
    seed: int
    timeseries: pd.DataFrame
    step_ms: np.ndarray
    fix_times: list[list[float]]  # successful USBL fixes per AUV
    reliable_fix_times: list[list[float]]
    fallbacks: int = 0
    jumps: pd.DataFrame | None = None
    plans: list = field(default_factory=list)  # (t, PlannedTrajectory) of an MPC, sampled
    energy_J: float = 0.0
    min_range_m: float = math.inf
    min_slant_range_m: float = math.inf
    wall_s: float = 0.0
    domain: object = None  # the controller's DomainParams, if it has one


def simulate(
    scenario: Scenario, controller: Controller, seed: int = 0, estimator: str | None = None,
    progress: bool = False, plan_every: float = 30.0,
) -> RunResult:  # fmt: skip
    """Run ``controller`` on ``scenario`` with ``seed``; return the :class:`RunResult`."""
    wall0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    sc, ac = scenario, scenario.acoustics
    model, ep, CL = build_plant(sc)
    n_auv, n_sub, Tc = len(sc.auv), sc.sim.n_sub, sc.sim.control_period
    dt = sc.sim.dt
    P = model.params
    thr_on = ep.propeller_on_threshold * P.T_max
    current = np.array(sc.current, float)
    domain = getattr(controller, "domain", None)

    # initial states
    s0 = sc.asv.start
    x = np.zeros(NX)
    x[[0, 1, 2, 3]] = s0.N, s0.E, math.radians(s0.psi_deg), s0.speed
    x[6] = model.thrust_for_speed(s0.speed) if s0.speed > 0 else 0.0
    z = np.zeros(NZ)
    S = np.array(
        [[a.start.N, a.start.E, a.start.depth, math.radians(a.start.psi_deg), a.start.speed]
         for a in sc.auv], float,
    ).T  # fmt: skip
    LIM = np.array([a.limits.vector() for a in sc.auv]).T
    behaviours = [a.build_behaviour() for a in sc.auv]
    auv_step = auv_step_function(dt, n_sub, n_auv)
    est_name = estimator or sc.estimator
    estimators = [
        make_estimator(est_name, initial=AUVEstimate(S[0, k], S[1, k], S[2, k], t_last_fix=0.0))
        for k in range(n_auv)
    ]
    ins = INSDrift(n_auv, sc.navigation, rng)
    # USBL polls the AUVs in turn: AUV k pings at k*T0/n_auv + j*T0; reports likewise
    next_ping = np.array([k * ac.T0 / n_auv for k in range(n_auv)]) + ac.T0
    next_report = np.array([k * ac.T_report / n_auv for k in range(n_auv)]) + ac.T_report
    last_fix = np.zeros(n_auv)
    fix_times: list[list[float]] = [[] for _ in range(n_auv)]
    reliable_times: list[list[float]] = [[] for _ in range(n_auv)]
    controller.reset(n_auv)

    rows, step_ms, plans = [], [], []
    energy, min_r, min_s = 0.0, math.inf, math.inf
    next_plan_t = 0.0
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=sc.n_steps, desc=f"{sc.name} [{controller.name}]", unit="s", leave=False)

    for step in range(sc.n_steps):
        t = step * Tc
        prop_on = bool(x[6] > thr_on)
        for k in range(n_auv):
            U, psi = S[4, k], S[3, k]
            estimators[k].on_truth(t, S[0, k], S[1, k], S[2, k], U * math.cos(psi),
                                   U * math.sin(psi))  # fmt: skip
        ests = tuple(e.estimate(t) for e in estimators)
        obs = Observation(t, ASVState(x[0], x[1], x[2], x[3], x[4], x[5]), prop_on, ests)
        c0 = time.perf_counter()
        cmd = controller.step(obs)
        step_ms.append((time.perf_counter() - c0) * 1e3)
        plan = getattr(controller, "plan", None)
        if plan is not None and t >= next_plan_t:
            plans.append((t, plan))
            next_plan_t = t + plan_every

        # ASV with the execution level, and the AUVs, over one supervisory period
        x_next, z, X, Uin, Y = CL(x, z, command_vector(cmd), current)
        X, Uin, Y = np.array(X), np.array(Uin), np.array(Y)
        SP = np.array([b.setpoint(t, S[:, k], x[:2]) for k, b in enumerate(behaviours)]).T
        S_next, ST = auv_step(S, SP, LIM)
        S_next, ST = np.array(S_next), np.array(ST).reshape(NA, n_auv, n_sub, order="F")
        # ST[:, k, j]: AUV k after sub-step j (map stacks the AUVs' outputs side by side)
        U_w = np.hypot(X[3] - 0, X[4])  # speed through water ~ over ground (no current term)
        energy += float(np.sum(X[6] * np.abs(X[3] - _surge_current(X[2], current))) * dt)
        dN = X[0][None, :] - ST[0]
        dE = X[1][None, :] - ST[1]
        rng_h = np.hypot(dN, dE)  # (n_auv, n_sub)
        rng_s = np.hypot(rng_h, ST[2])
        min_r, min_s = min(min_r, float(rng_h.min())), min(min_s, float(rng_s.min()))
        ins.advance(np.hypot(S_next[0] - S[0], S_next[1] - S[1]))
        x_prev, x, S = x, np.array(x_next).ravel(), S_next
        t1 = t + Tc
        prop_end = bool(x[6] > thr_on)

        # acoustics due in (t, t1]: evaluated at the end of the period
        fix_flag = np.zeros(n_auv, int)
        rel_flag = np.zeros(n_auv, int)
        nav_err = np.hypot(*ins.error(t1).T)
        for k in range(n_auv):
            at_surface = S[2, k] < 0.5
            if at_surface:  # GPS at the surface
                ins.reset(k, t1, ac.gps_sigma * rng.standard_normal(2) / math.sqrt(2))
            modem_ok = not (at_surface and not sc.auv[k].modem_at_surface)
            r_h = math.hypot(x[0] - S[0, k], x[1] - S[1, k])
            slant = math.hypot(r_h, S[2, k])
            while next_ping[k] <= t1 + 1e-9:
                next_ping[k] += ac.T0
                if not (ac.usbl and modem_ok):
                    continue
                if rng.random() < success_probability(slant, prop_end, ac):
                    fix = usbl_fix(t1, k, x[:2], S[:3, k], ac, rng)
                    estimators[k].on_fix(fix)
                    ins.reset(k, t1, np.array([fix.N - S[0, k], fix.E - S[1, k]]))
                    fix_flag[k] += 1
                    fix_times[k].append(t1)
                    last_fix[k] = t1
                    if _reliable(domain, r_h, S[2, k], prop_end, ac):
                        rel_flag[k] += 1
                        reliable_times[k].append(t1)
            while next_report[k] <= t1 + 1e-9:
                next_report[k] += ac.T_report
                if modem_ok and rng.random() < success_probability(slant, prop_end, ac):
                    e = ins.error(t1)[k]
                    estimators[k].on_report(Report(
                        t1, k, S[0, k] + e[0], S[1, k] + e[1], S[2, k], S[3, k], S[4, k],
                        float(np.hypot(*e)) + 1.0,
                    ))  # fmt: skip

        row = {
            "t": t1, "N": x[0], "E": x[1], "psi": x[2], "u": x[3], "v": x[4], "r": x[5],
            "thrust": x[6], "delta": x[7], "propeller_on": prop_end,
            "mode": str(cmd.mode), "reason": str(cmd.reason),
            "auv_served": -1 if cmd.auv is None else cmd.auv,
            "wp_N": cmd.waypoint[0] if cmd.mode is Mode.TRANSIT else math.nan,
            "wp_E": cmd.waypoint[1] if cmd.mode is Mode.TRANSIT else math.nan,
            "cmd_speed": cmd.speed, "psi_d": Y[0, -1], "u_ref": Y[1, -1],
            "step_ms": step_ms[-1],
        }  # fmt: skip
        for k in range(n_auv):
            e = ests[k]
            row |= {
                f"auv{k}_N": S[0, k], f"auv{k}_E": S[1, k], f"auv{k}_depth": S[2, k],
                f"auv{k}_psi": S[3, k], f"auv{k}_U": S[4, k],
                f"est{k}_N": e.N, f"est{k}_E": e.E, f"est{k}_depth": e.depth,
                f"est{k}_sigma": e.sigma,
                f"range{k}": math.hypot(x[0] - S[0, k], x[1] - S[1, k]),
                f"range_min{k}": float(rng_h[k].min()),
                f"slant{k}": math.hypot(math.hypot(x[0] - S[0, k], x[1] - S[1, k]), S[2, k]),
                f"est_range{k}": math.hypot(x[0] - e.N, x[1] - e.E),
                f"fixes{k}": fix_flag[k], f"reliable{k}": rel_flag[k],
                f"fix_age{k}": t1 - last_fix[k], f"nav_err{k}": nav_err[k],
            }  # fmt: skip
            if domain is not None:
                d = S[2, k]
                row |= {
                    f"r_inner{k}": float(domain.inner(d)), f"r_outer{k}": float(domain.outer(d)),
                    f"r_t{k}": float(domain.target(d)),
                }  # fmt: skip
        diag = getattr(controller, "diagnostics", None)
        if diag is not None:
            row |= diag()
        if sc.sim.log_every_step:
            rows.extend(_substep_rows(row, t, dt, X, Uin))
        else:
            rows.append(row)
        del x_prev, U_w
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()

    jumps = getattr(controller, "jump_log", None)
    return RunResult(
        sc, controller.name, seed, pd.DataFrame(rows), np.array(step_ms), fix_times,
        reliable_times, int(getattr(controller, "fallbacks", 0)),
        jumps() if callable(jumps) else None, plans, energy, min_r, min_s,
        time.perf_counter() - wall0, domain,
    )  # fmt: skip


def _surge_current(psi, current):
    return current[0] * np.cos(psi) + current[1] * np.sin(psi)


def _reliable(domain, r_h, depth, propeller_on, ac) -> bool:
    """Paper 2's reliable-fix rule for a fix that got through (r < r_t + eps, propeller off);
    without a domain (e.g. the trivial controller): propeller off and within d1."""
    if propeller_on:
        return False
    if domain is None:
        return r_h <= ac.d1
    return r_h < float(domain.target(depth)) + domain.eps_plus


def _substep_rows(row, t, dt, X, Uin):
    """Expand one period's row into one row per plant step (identification data)."""
    out = []
    for j in range(X.shape[1]):
        r = dict(row)
        r.update(
            t=t + (j + 1) * dt,
            N=X[0, j],
            E=X[1, j],
            psi=X[2, j],
            u=X[3, j],
            v=X[4, j],
            r=X[5, j],
            thrust=X[6, j],
            delta=X[7, j],
            T_cmd=Uin[0, j],
            delta_cmd=Uin[1, j],
        )
        out.append(r)
    return out
