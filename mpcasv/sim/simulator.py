"""The closed-loop simulator: a controller driving the simulated :class:`World`.

Per supervisory period (1 s by default): the estimators turn the AUVs' truth and the acoustic
events into an :class:`~mpcasv.interface.Observation`; the controller returns a
:class:`~mpcasv.interface.Command`; the world advances (execution level and vessel model in
one compiled call, AUVs, USBL pings and reports); one row of the time series is logged.
(scenario, controller, preset, seed) reproduce a run exactly.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from mpcasv.control.execution import command_vector
from mpcasv.interface import Controller, Mode
from mpcasv.sim.account import unknown_seconds
from mpcasv.sim.scenario import Scenario
from mpcasv.sim.world import World, build_plant

__all__ = ["RunResult", "build_plant", "simulate"]


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
    domain: object = None  # the scenario's evaluation DomainParams (None: it has none)
    #: an MPC's solves abandoned as hung (mpcasv.mpc.hung.HungSolve; written to the run folder)
    hung_solves: list = field(default_factory=list)


def simulate(
    scenario: Scenario, controller: Controller, seed: int = 0, estimator: str | None = None,
    progress: bool = False, plan_every: float = 30.0,
) -> RunResult:  # fmt: skip
    """Run ``controller`` on ``scenario`` with ``seed``; return the :class:`RunResult`.

    ``plan_every`` (s): how often an MPC's planned trajectory is kept for the plots.
    """
    wall0 = time.perf_counter()
    world = World(scenario, seed, estimator)
    # the true current reaches a controller only if it asks (an MPC's current = "oracle")
    world.oracle_current = bool(getattr(controller, "needs_current_oracle", False))
    controller.reset(world.n_auv)
    guard = getattr(controller, "use_hang_guard", None)  # an MPC: a hung solve must not
    if guard is not None:  # stall the run (mpcasv.mpc.solver_params.SolverParams.hang_s)
        guard()
    between = getattr(controller, "between_steps", None)  # (timed by the controller)
    rows, step_ms, plans = [], [], []
    next_plan_t = 0.0
    bar = None
    if progress:
        from tqdm import tqdm

        desc = f"{scenario.name} [{controller.name}]"
        bar = tqdm(total=scenario.n_steps, desc=desc, unit="s", leave=False)
    obs = world.observation()
    for k in range(scenario.n_steps):
        c0 = time.perf_counter()
        cmd = controller.step(obs)
        step_ms.append((time.perf_counter() - c0) * 1e3)
        if between is not None and k < scenario.n_steps - 1:  # an MPC's work for the next
            between()  # step, after the command (none after the last)
        plan = getattr(controller, "plan", None)
        if plan is not None and obs.t >= next_plan_t:
            plans.append((obs.t, plan))
            next_plan_t = obs.t + plan_every
        # the power turn of an escape (turn_scope "avoidance"): World.advance's one rule for
        # every controller, the ASV inside a collision domain now (true ranges), not its labels
        period = world.advance(command_vector(cmd, obs.asv.position,
                                              scenario.sim.reference_lead_m))  # fmt: skip
        obs = world.observation()  # at the end of the period: logged, and used next step
        row = timeseries_row(world, obs, cmd, period, step_ms[-1])
        diag = getattr(controller, "diagnostics", None)
        if diag is not None:
            row |= diag()
        if scenario.sim.log_every_step:
            rows.extend(_substep_rows(row, period))
        else:
            rows.append(row)
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    close = getattr(controller, "close", None)  # stops an MPC's solver workers
    if close is not None:
        close()
    jumps = getattr(controller, "jump_log", None)
    return RunResult(
        scenario, controller.name, seed, pd.DataFrame(rows), np.array(step_ms),
        world.fix_times, world.reliable_times, int(getattr(controller, "fallbacks", 0)),
        jumps() if callable(jumps) else None, plans, world.energy_J, world.min_range,
        world.min_slant, time.perf_counter() - wall0, world.domain,
        list(getattr(controller, "hung_solves", ())),
    )  # fmt: skip


def timeseries_row(world: World, obs, cmd, period, step_ms: float) -> dict:
    """One row of the time series at the end of a period: ASV state, the command that acted
    during the period, each AUV's truth and the belief ``obs`` at the same time."""
    x, S = world.x, world.S
    transit = cmd.mode is Mode.TRANSIT
    row = {
        "t": period.t1, "N": x[0], "E": x[1], "psi": x[2], "u": x[3], "v": x[4], "r": x[5],
        "thrust": x[6], "delta": x[7], "propeller_on": world.propeller_on,
        "mode": str(cmd.mode), "reason": str(cmd.reason),
        "auv_served": -1 if cmd.auv is None else cmd.auv,
        "wp_N": cmd.waypoint[0] if transit else math.nan,
        "wp_E": cmd.waypoint[1] if transit else math.nan,
        "cmd_speed": cmd.speed, "psi_d": period.Y[0, -1], "u_ref": period.Y[1, -1],
        "step_ms": step_ms, "energy_cum_J": world.energy_J,
    }  # fmt: skip
    nav_err = np.hypot(*world.nav.error(period.t1).T)
    nav_sigma = world.nav.sigma(period.t1)
    acc = period.account
    row |= acc.step_seconds() if acc is not None else unknown_seconds(world.n_auv)
    row["prop_on_s"] = float(period.prop.sum() * world.dt)
    radii = world.radii()
    for k, e in enumerate(obs.auvs):
        r = math.hypot(x[0] - S[0, k], x[1] - S[1, k])
        row |= {
            f"auv{k}_N": S[0, k], f"auv{k}_E": S[1, k], f"auv{k}_depth": S[2, k],
            f"auv{k}_psi": S[3, k], f"auv{k}_U": S[4, k],
            f"est{k}_N": e.N, f"est{k}_E": e.E, f"est{k}_depth": e.depth,
            f"est{k}_sigma": e.sigma,
            f"range{k}": r, f"range_min{k}": float(period.ranges[k].min()),
            f"slant{k}": math.hypot(r, S[2, k]),
            f"est_range{k}": math.hypot(x[0] - e.N, x[1] - e.E),
            f"est{k}_t_fix": e.t_last_fix,
            f"fixes{k}": int(period.fixes[k]), f"reliable{k}": int(period.reliable[k]),
            f"visit{k}": bool(period.visiting[k]),
            f"fix_age{k}": period.t1 - world.last_fix[k],
            f"rfix_age{k}": period.t1 - world.last_reliable[k],
            f"nav_err{k}": nav_err[k], f"nav_sigma{k}": nav_sigma[k],
        }  # fmt: skip
        if radii is not None:
            row |= {f"r_inner{k}": float(radii[0][k]), f"r_outer{k}": float(radii[1][k]),
                    f"r_t{k}": float(radii[2][k])}  # fmt: skip
    return row


def _substep_rows(row: dict, period) -> list[dict]:
    """Expand one period's row into one row per plant step (identification data): the ASV's
    state, its actuators, the propeller, each AUV's truth (position, depth, heading, speed),
    range and slant range at each plant step, and the account's seconds as each plant
    step's own; the command, the belief, the fixes and the fix ages stay the period's (at
    its end: decided and evaluated once per period). Before session 46 the AUVs' columns,
    the ranges and the propeller also stayed the period end's (an auditor recomputing the
    time inside the collision domain from them got 70.0 s where the plant steps gave 70.1)."""
    X, U, S = period.X, period.U, period.auvs
    dt = (period.t1 - period.t0) / X.shape[1]
    out = []
    for j in range(X.shape[1]):
        r = dict(row)
        if period.account is not None:
            r.update(period.account.step_seconds(slice(j, j + 1)))
        r["prop_on_s"] = float(period.prop[j] * dt)
        r.update(
            t=period.t0 + (j + 1) * dt, N=X[0, j], E=X[1, j], psi=X[2, j], u=X[3, j],
            v=X[4, j], r=X[5, j], thrust=X[6, j], delta=X[7, j], T_cmd=U[0, j],
            delta_cmd=U[1, j], propeller_on=bool(period.prop[j]),
        )  # fmt: skip
        for k in range(period.ranges.shape[0]):
            r |= {f"range{k}": period.ranges[k, j], f"slant{k}": period.slants[k, j],
                  f"auv{k}_N": S[0, k, j], f"auv{k}_E": S[1, k, j], f"auv{k}_depth": S[2, k, j],
                  f"auv{k}_psi": S[3, k, j], f"auv{k}_U": S[4, k, j]}  # fmt: skip
        out.append(r)
    return out
