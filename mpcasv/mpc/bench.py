"""``mpcasv bench mpc``: the same receding-horizon problems solved three ways.

The sequences are recorded from closed-loop MPC runs (Case 3 with one AUV, Case 6 with three;
the parameters of every step's main solve). Each solver then replays a sequence on its own,
warm-started from its own previous solution moved one control period ahead (as in the
controller): the straightforward Opti + IPOPT formulation (:mod:`mpcasv.mpc.reference`, the
cost reference), the default (the preset's solver: fatrop on compiled, cached functions), and
the QP variant (linearised, OSQP). Figures: median and p99 wall time per solve, iterations,
failures, and the cost relative to the reference. The problem is not convex and the solvers'
warm-started sequences may follow different local minima, so two cost figures are given:

- *sequences*: each solver on its own receding-horizon sequence, cost relative to the
  reference's on the same problem (``<= +1 %``: the default is no worse than the reference);
- *local*: the default's cost relative to IPOPT polishing the default's own solution
  (tolerance 1e-8, warm-start settings that keep the start: IPOPT's default ``bound_push``
  of 1e-2 moves a start off its active bounds, and from there it often finds another local
  minimum, higher or lower, which says nothing about the default's accuracy).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from mpcasv.controllers import Boat, load_preset
from mpcasv.mpc.controller import MPCController, build_ocp
from mpcasv.mpc.qp import QPSolver
from mpcasv.mpc.reference import OptiReference
from mpcasv.sim.scenario import load_scenario, scenario_with
from mpcasv.sim.simulator import simulate

SCENARIOS = Path(__file__).resolve().parents[2] / "experiments" / "scenarios"
CASES = (("case3", "mpc-single", False), ("case6", "mpc-multi", True))
STEPS = 300  # control steps (s) per sequence
#: IPOPT polishing a given solution: tight tolerance, the start kept where it is
POLISH = {
    "ipopt.tol": 1e-8, "ipopt.mu_init": 1e-6, "ipopt.bound_push": 1e-9, "ipopt.bound_frac": 1e-9,
    "ipopt.warm_start_init_point": "yes", "ipopt.warm_start_bound_push": 1e-9,
    "ipopt.warm_start_mult_bound_push": 1e-9,
}  # fmt: skip


def record(case: str, preset: str, multi: bool, steps: int = STEPS,
           overrides: dict | None = None):  # fmt: skip
    """(params, controller, [(p, elapsed stages)]) of a closed-loop MPC run of ``case``;
    ``overrides``: preset fields (dotted names) changed."""
    return record_run(case, preset, multi, steps, overrides=overrides)[:3]


def record_run(case: str, preset: str, multi: bool, steps: int = STEPS,
               threads: int | None = None, step_iter: int | None = None,
               overrides: dict | None = None):  # fmt: skip
    """:func:`record` plus the run's whole controller step times: wall and CPU time (ms) of
    each ``step`` (solves, rescues, the fallback's bookkeeping). The solves run in this
    process (``hang_s = 0``; no decision depends on it), so the CPU time is the step's own
    work, which a loaded machine stretches far less than the wall time. ``threads``: the
    solver's ``threads`` (None: the preset's); the run is the same, only faster.
    ``step_iter``: the solver's ``step_iter`` (None: the preset's; 0: none); the run
    changes where a step carries its plan (docs/mpc.md, "Controller step" 3b)."""
    sc = load_scenario(SCENARIOS / f"{case}.toml")
    sc = scenario_with(sc, duration=float(steps))
    params = load_preset(preset, preset, overrides)
    sp = dataclasses.replace(params.solver, hang_s=0.0)
    if threads is not None:
        sp = dataclasses.replace(sp, threads=threads)
    if step_iter is not None:
        sp = dataclasses.replace(sp, step_iter=step_iter or None)
    params = dataclasses.replace(params, solver=sp)
    ctrl = MPCController(params, len(sc.auv), multi, boat=Boat.of_scenario(sc))
    ctrl.recorder = []
    step, between, cpu, kinds, sources, idle = ctrl.step, ctrl.between_steps, [], [], [], []

    def timed_step(obs):
        explored = ctrl.explored
        c0 = time.process_time()
        cmd = step(obs)
        cpu.append((time.process_time() - c0) * 1e3)
        source = ctrl.diagnostics()["mpc_source"]  # else: rescue, escape or fallback
        sources.append(source)
        kinds.append("carried" if source == "carried" else
                     "rescue" if source != "plan" else
                     "explore" if ctrl.explored > explored else "solve")  # fmt: skip
        return cmd

    def timed_between():
        explored, deferred, c0 = ctrl.explored, ctrl.deferred, time.perf_counter()
        between()
        if ctrl.explored > explored or deferred is not None:  # solves ran after the step
            idle.append((time.perf_counter() - c0) * 1e3)

    ctrl.step, ctrl.between_steps = timed_step, timed_between
    result = simulate(sc, ctrl, seed=0)
    times = {"wall": np.asarray(result.step_ms, float), "cpu": np.asarray(cpu, float),
             "kind": np.asarray(kinds), "source": np.asarray(sources),
             "between": np.asarray(idle, float)}  # fmt: skip
    return params, ctrl, list(ctrl.recorder), times


def step_summary(times: dict, ctrl: MPCController) -> dict:
    """Median / p99 / max of the whole controller step, wall and CPU time (ms; the first
    step, cold, left out), and the run's plan sources (docs/mpc.md, "Fallbacks"); what the
    steps were: the warm-started solve alone (``solve``), with the exploration solve
    (``explore``: only when the warm-started plan may not be used) or with rescue solves
    (``rescue``), or the previous plan carried (``carried``: ``solver.step_iter``): their
    counts and wall p99 / max; and the solves run between steps, after the command (the
    periodic exploration, a carried step's work; ``between``: count, wall p99 / max)."""
    out = {"steps": int(len(times["wall"])), "fallbacks": int(ctrl.fallbacks),
           "sources": dict(ctrl.sources)}  # fmt: skip
    for kind in ("wall", "cpu"):
        ms = times[kind][1:]
        out |= {f"{kind}_median_ms": round(float(np.median(ms)), 3),
                f"{kind}_p99_ms": round(float(np.percentile(ms, 99)), 3),
                f"{kind}_max_ms": round(float(np.max(ms)), 2)}  # fmt: skip
    if "kind" in times:
        wall, kinds = times["wall"][1:], times["kind"][1:]
        out["by_kind"] = {}
        for k in ("solve", "explore", "rescue", "carried"):
            ms = wall[kinds == k]
            if len(ms):
                out["by_kind"][k] = {"steps": len(ms),
                                     "wall_p99_ms": round(float(np.percentile(ms, 99)), 2),
                                     "wall_max_ms": round(float(np.max(ms)), 2)}  # fmt: skip
    ms = times.get("between", np.zeros(0))
    if len(ms):
        out["between"] = {"solves": len(ms), "wall_p99_ms": round(float(np.percentile(ms, 99)), 2),
                          "wall_max_ms": round(float(np.max(ms)), 2)}  # fmt: skip
    return out


def qp_params(sp):
    """The QP variant's solver parameters beside the default's ``sp``: one thread, and no
    step budget (``step_iter`` is fatrop's and IPOPT's; the QP's work is bounded by
    ``qp_iters``). Until session 40 the several-AUV presets' ``step_iter = 20`` (session 16)
    made the full benchmark stop at Case 6 with a validation error."""
    return dataclasses.replace(sp, solver="qp", threads=1, step_iter=None)


def replay(solver, ocp, seq, desc: str) -> dict[str, np.ndarray]:
    """Solve the sequence with ``solver``, each step warm-started from its previous solution."""
    out = {k: [] for k in ("ms", "cpu_ms", "iters", "f", "ok", "w")}
    timers: dict[str, float] = {}
    w_prev, lam = None, (None, None)
    for p, frac in tqdm(seq, desc=desc, leave=False):
        if w_prev is None:
            w0, lam0 = ocp.rollout(p), (None, None)
        else:
            Z, V = ocp.split(ocp.shift(w_prev, frac))
            w0 = ocp.fill_slacks(Z, V, p)
            lam0 = (None if lam[0] is None else ocp.shift_lam_x(lam[0], frac),
                    None if lam[1] is None else ocp.shift_lam_g(lam[1], frac))  # fmt: skip
        c0 = time.process_time()
        r = solver.solve(p, w0, *lam0)
        cpu = (time.process_time() - c0) * 1e3  # this process's CPU time (loaded machines)
        for k, v in (("ms", r.ms), ("cpu_ms", cpu), ("iters", r.iters), ("f", r.f),
                     ("ok", r.ok), ("w", r.w)):  # fmt: skip
            out[k].append(v)
        for k, v in (getattr(solver, "last_stats", None) or {}).get("fatrop", {}).items():
            if k.endswith("_time") or k == "time_total":
                timers[k] = timers.get(k, 0.0) + float(v)
        finite = np.all(np.isfinite(r.w))
        keep = r.ok or getattr(solver, "warm_from_failures", False)
        w_prev = r.w if (finite and keep) else None
        lam = (r.lam_x, r.lam_g) if (finite and r.ok) else (None, None)
    res = {k: np.array(v) for k, v in out.items()}
    if timers:
        res["timers"] = timers
    return res


#: fatrop's timers (``stats()["fatrop"]``) and what they time
TIMERS = {"eval_hess_time": "Hessian", "eval_jac_time": "constraint Jacobian",
          "compute_sd_time": "search direction (Riccati)", "eval_cv_time": "constraints",
          "eval_obj_time": "objective", "eval_grad_time": "gradient",
          "initialization_time": "initialisation"}  # fmt: skip


def time_shares(timers: dict[str, float]) -> dict[str, float]:
    """Share (%) of fatrop's total time in each of its timers over a replayed sequence:
    where a solve's time goes (function evaluations against the linear algebra)."""
    total = timers.get("time_total", 0.0)
    if total <= 0:
        return {}
    shares = {name: round(100 * timers.get(k, 0.0) / total, 1) for k, name in TIMERS.items()}
    shares["other"] = round(100 - sum(shares.values()), 1)
    return shares


def summary(res: dict, ref: dict | None) -> dict:
    """Median / p99 ms, iterations, failures and cost agreement with ``ref``."""
    ms = res["ms"][1:]  # the first solve starts cold
    cpu = res["cpu_ms"][1:]
    row = {
        "median_ms": round(float(np.median(ms)), 3),
        "p99_ms": round(float(np.percentile(ms, 99)), 3),
        "max_ms": round(float(np.max(ms)), 2),
        "cpu_median_ms": round(float(np.median(cpu)), 3),
        "cpu_p99_ms": round(float(np.percentile(cpu, 99)), 3),
        "iters_median": float(np.median(res["iters"])),
        "iters_max": int(np.max(res["iters"])),
        "failures": int(np.sum(~res["ok"].astype(bool))),
        "solves": int(len(res["ms"])),
    }
    if "timers" in res:
        row["time_shares_pct"] = time_shares(res["timers"])
    if ref is not None:
        both = res["ok"].astype(bool) & ref["ok"].astype(bool)
        if not np.any(both):
            return row | {"cost_rel_median": float("nan"), "cost_rel_p95_abs": float("nan"),
                          "cost_rel_max_abs": float("nan"), "within_1pct": 0.0,
                          "not_worse_1pct": 0.0}  # fmt: skip
        rel = (res["f"][both] - ref["f"][both]) / np.abs(ref["f"][both])
        row |= {
            "cost_rel_median": float(np.median(rel)),
            "cost_rel_p95_abs": float(np.percentile(np.abs(rel), 95)),
            "cost_rel_max_abs": float(np.max(np.abs(rel))),
            "within_1pct": round(float(np.mean(np.abs(rel) <= 0.01)), 4),
            "not_worse_1pct": round(float(np.mean(rel <= 0.01)), 4),
        }
    return row


def polish(ref, seq, res: dict) -> dict:
    """Cost of ``res`` relative to ``ref`` (IPOPT with :data:`POLISH` settings) started from
    ``res``'s own solution of the same problem: about 0 when ``res`` is a local optimum the
    reference agrees with, > 0 when the reference finds a lower cost nearby."""
    rel = []
    for (p, _), w, f, ok in tqdm(list(zip(seq, res["w"], res["f"], res["ok"], strict=True)),
                                 desc="polish", leave=False):  # fmt: skip
        if not ok:
            continue
        r = ref.solve(p, w)
        if r.ok:
            rel.append((f - r.f) / abs(r.f))
    rel = np.array(rel)
    return {"polished_rel_median": float(np.median(rel)),
            "polished_rel_p95_abs": float(np.percentile(np.abs(rel), 95)),
            "polished_rel_max_abs": float(np.max(np.abs(rel))),
            "polished_within_1pct": round(float(np.mean(np.abs(rel) <= 0.01)), 4)}  # fmt: skip


def bench_mpc(args: argparse.Namespace) -> dict:
    """Record the Case 3 / Case 6 sequences, replay them three ways, print and return figures."""
    steps = getattr(args, "steps", STEPS) or STEPS
    quick = getattr(args, "quick", False)
    figures: dict = {"machine": platform.processor() or platform.machine(), "steps": steps,
                     "load_average": [round(x, 2) for x in os.getloadavg()],
                     "cases": {}}  # fmt: skip
    for case, preset, multi in CASES:
        t0 = time.perf_counter()
        params, ctrl, seq, step_ms = record_run(case, preset, multi, steps,
                                                getattr(args, "threads", None),
                                                getattr(args, "step_iter", None))  # fmt: skip
        step = step_summary(step_ms, ctrl)
        figures["threads"] = params.solver.threads  # the recorded run's and the replay's
        ocp, default = build_ocp(params, ctrl.ocp.dims.n_auv, multi, boat=ctrl.boat)
        ref = OptiReference(ocp)
        n = ocp.dims.n_auv
        res_ref = replay(ref, ocp, seq, f"{case} opti+ipopt")
        res_def = replay(default, ocp, seq, f"{case} {params.solver.solver}")
        rows = {"opti_ipopt": summary(res_ref, None),
                f"default_{params.solver.solver}": summary(res_def, res_ref)}  # fmt: skip
        if params.solver.threads > 1:  # the same solver on one thread, same sequence and run
            one = dataclasses.replace(params, solver=dataclasses.replace(params.solver,
                                                                         threads=1))  # fmt: skip
            _, serial = build_ocp(one, n, multi, boat=ctrl.boat)
            rows["default_1_thread"] = summary(replay(serial, ocp, seq, f"{case} 1 thread"),
                                               res_ref)  # fmt: skip
        if not quick:
            qp = QPSolver(ocp, qp_params(params.solver))
            rows["qp_osqp"] = summary(replay(qp, ocp, seq, f"{case} qp/osqp"), res_ref)
            rows[f"default_{params.solver.solver}"] |= polish(OptiReference(ocp, POLISH), seq,
                                                              res_def)  # fmt: skip
        speedup = rows["opti_ipopt"]["median_ms"] / rows[f"default_{params.solver.solver}"][
            "median_ms"]  # fmt: skip
        speedup_cpu = rows["opti_ipopt"]["cpu_median_ms"] / rows[
            f"default_{params.solver.solver}"]["cpu_median_ms"]  # fmt: skip
        figures["cases"][f"{case}_{n}auv"] = {
            "solvers": rows, "speedup_median": round(speedup, 1),
            "speedup_cpu_median": round(speedup_cpu, 1), "controller_step": step,
            "step_iter": params.solver.step_iter,
            "wall_s": round(time.perf_counter() - t0, 1),
        }  # fmt: skip
        _print(case, n, rows, speedup, len(seq), params.solver.threads)
        print(f"whole controller step in the recorded run: wall median {step['wall_median_ms']:.2f}"
              f" / p99 {step['wall_p99_ms']:.2f} ms, CPU median {step['cpu_median_ms']:.2f} / "
              f"p99 {step['cpu_p99_ms']:.2f} ms; plan sources {step['sources']}")
        print("  by what the step did (wall p99 / max ms): " + ", ".join(
            f"{k} {v['steps']} steps {v['wall_p99_ms']:.1f} / {v['wall_max_ms']:.1f}"
            for k, v in step.get("by_kind", {}).items()))  # fmt: skip
        b = step.get("between")
        print("  between steps, after the command: " + (
            "no solve" if b is None else f"solves after {b['solves']} steps (explorations, "
            f"carried steps' work), wall p99 {b['wall_p99_ms']:.1f} / max "
            f"{b['wall_max_ms']:.1f} ms"
        ) + f"; solver.step_iter {params.solver.step_iter}")  # fmt: skip
    figures["load_average_end"] = [round(x, 2) for x in os.getloadavg()]
    print(f"load average at the end: {figures['load_average_end'][0]:.2f} on "
          f"{os.cpu_count()} cores (wall times from a loaded machine are not comparable; "
          f"compare the ratios within one run)")  # fmt: skip
    return figures


def _speed(ratio: float) -> str:
    """A time ratio (other / this) as 'N.NNx faster' or 'N.NNx slower'."""
    return f"{ratio:.2f}x faster" if ratio >= 1.0 else f"{1.0 / ratio:.2f}x slower"


def _print(case: str, n: int, rows: dict, speedup: float, steps: int = STEPS,
           threads: int = 1) -> None:  # fmt: skip
    print(f"\n{case}: {n} AUV(s), {steps} receding-horizon problems; default solver on "
          f"{threads} thread(s) (solver.threads)")
    head = f"{'solver':<16}{'median ms':>10}{'p99 ms':>9}{'CPU med':>9}{'CPU p99':>9}{'iters':>7}"
    head += f"{'fail':>6}"
    print(head + f"{'cost vs ref (median / p95 |rel|)':>36}{'<=+1 %':>8}")
    for name, r in rows.items():
        line = f"{name:<16}{r['median_ms']:>10.2f}{r['p99_ms']:>9.2f}{r['cpu_median_ms']:>9.2f}"
        line += f"{r['cpu_p99_ms']:>9.2f}{r['iters_median']:>7.0f}"
        line += f"{r['failures']:>6d}"
        if "cost_rel_median" in r:
            line += f"{r['cost_rel_median']:>+20.2e} / {r['cost_rel_p95_abs']:<13.2e}"
            line += f"{100 * r['not_worse_1pct']:>7.1f}%"
        print(line)
    print(f"default vs Opti + IPOPT: {speedup:.1f}x faster (median)")
    d = next(r for k, r in rows.items() if k.startswith("default"))
    if "default_1_thread" in rows:
        one = rows["default_1_thread"]
        print(f"{threads} threads against 1 on the same sequence: median "
              f"{_speed(one['median_ms'] / d['median_ms'])}, p99 "
              f"{_speed(one['p99_ms'] / d['p99_ms'])}")
    if d.get("time_shares_pct"):
        print("where the default's time goes (fatrop's timers): " + ", ".join(
            f"{k} {v:.0f} %" for k, v in d["time_shares_pct"].items()))  # fmt: skip
    if "polished_rel_median" not in d:
        return
    print(
        f"local: default's cost vs IPOPT polishing the default's solution: median "
        f"{d['polished_rel_median']:+.2e}, p95 |rel| {d['polished_rel_p95_abs']:.2e}, max "
        f"{d['polished_rel_max_abs']:.2e}, {100 * d['polished_within_1pct']:.1f}% within 1 %"
    )
