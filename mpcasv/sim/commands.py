"""``mpcasv simulate``: run one scenario with one controller and write the run folder."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from mpcasv.config import ConfigError, check_seed


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate", help="simulate a scenario with a controller; write time series, metrics, plots",
        description="Simulate SCENARIO (a TOML file) and write timeseries.parquet, metrics.json, "
        "run.json and PNG plots (paths, range, fix age) into --out.",
    )  # fmt: skip
    p.add_argument(
        "scenario", type=Path, nargs="?",
        help="scenario TOML (e.g. experiments/scenarios/case1.toml); omit with --manoeuvre",
    )  # fmt: skip
    p.add_argument("--controller", help="controller name (default: the scenario's)")
    p.add_argument("--params", help="controller preset: shipped name or TOML path")
    p.add_argument("--seed", type=int, default=None,
                   help="random seed (default 0): the world's acoustic draws and the realisation "
                   "of the scenario's [uncertain] table; with --manoeuvre the measurement "
                   "noise, so only with --noise")  # fmt: skip
    p.add_argument("--nominal", action="store_true",
                   help="simulate the scenario's nominal values (no draw from [uncertain])")
    p.add_argument("--estimator", help="AUV estimator (default: the scenario's)")
    p.add_argument(
        "--out", type=Path, help="output folder (default runs/<scenario>-<controller>-<seed>)"
    )
    p.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    from mpcasv.control.manoeuvres import add_arguments  # identification manoeuvres (issue 6)

    add_arguments(p)
    p.set_defaults(func=run)


#: options that only a scenario run reads (a manoeuvre refuses them rather than ignore them)
SCENARIO_ONLY = ("scenario", "controller", "params", "nominal", "estimator", "no_plots")


def run(args: argparse.Namespace) -> int:
    if args.manoeuvre:  # open-loop identification manoeuvre instead of a scenario
        from mpcasv.control.manoeuvres import run_cli

        given = [k for k in SCENARIO_ONLY if getattr(args, k) not in (None, False)]
        if given:
            names = ["SCENARIO" if k == "scenario" else "--" + k.replace("_", "-") for k in given]
            raise ConfigError(f"{', '.join(names)}: not with --manoeuvre (an open-loop "
                              "manoeuvre has no scenario, controller or estimator)")  # fmt: skip
        return run_cli(args)
    if args.scenario is None:
        raise ConfigError("give a SCENARIO (TOML file) or --manoeuvre")
    if args.seed is None:
        args.seed = 0
    from mpcasv.control.manoeuvres import MANOEUVRE_ONLY

    given = [f"--{k}" for k in MANOEUVRE_ONLY
             if getattr(args, k) is not None and getattr(args, k) is not False]  # 0 is given
    if given:
        raise ConfigError(f"{', '.join(given)}: only with --manoeuvre (a scenario names its own "
                          "vessel, current and noise)")  # fmt: skip
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise ConfigError(f"--duration {args.duration:g}: a duration is a number of seconds > 0")
    from mpcasv.controllers import Boat, make_controller, preset_used
    from mpcasv.controllers.prepare import needed_libraries, prepare
    from mpcasv.controllers.registry import DEFAULT_PRESET, check_controller_flag
    from mpcasv.estimation import ESTIMATORS, check_plan_estimator
    from mpcasv.experiments.metrics import compute_metrics
    from mpcasv.outputs import check_output_folder
    from mpcasv.sim.record import check_run_dir, params_record, write_run
    from mpcasv.sim.scenario import load_scenario, past_the_end
    from mpcasv.sim.simulator import simulate
    from mpcasv.sim.uncertainty import run_scenario

    if args.controller is not None:  # named as the flag, before the scenario is read
        check_controller_flag(args.controller)
    if args.estimator and args.estimator not in ESTIMATORS:
        raise ConfigError(f"unknown estimator {args.estimator!r}; known: {sorted(ESTIMATORS)}")
    scenario = load_scenario(args.scenario)
    if args.estimator:
        check_plan_estimator(scenario, args.estimator, f"--estimator {args.estimator}",
                             "--estimator kalman")  # fmt: skip
    else:
        check_plan_estimator(scenario, None, f"{args.scenario}: estimator = 'plan'",
                             "estimator = 'kalman' or --estimator kalman")  # fmt: skip
    if args.duration is not None:  # the first DURATION s: part of the realised scenario
        if not scenario.sim.control_period <= args.duration <= scenario.duration:
            raise ConfigError(f"--duration {args.duration:g}: between one control period "
                              f"({scenario.sim.control_period:g} s) and the scenario's "
                              f"{scenario.duration:g} s")  # fmt: skip
    check_seed(args.seed)
    scenario, real = run_scenario(scenario, args.seed, args.nominal, args.duration)
    # (drawn event times included; not after --duration, which cuts the run short on purpose)
    for line in past_the_end(scenario) if args.duration is None else ():
        print(f"warning: {args.scenario}: {line}", file=sys.stderr)
    name = args.controller or scenario.controller
    # the scenario's preset runs with its own controller ("default", a file without a preset:
    # that controller's default preset, controllers.preset_used)
    preset = args.params or (scenario.preset if name == scenario.controller else None)
    boat = Boat.of_scenario(scenario)  # one vessel per run: the simulator's and the MPC's
    out = check_output_folder(args.out or Path("runs") / f"{scenario.name}-{name}-{args.seed}")
    check_run_dir(out)  # before the run (and before compiling an MPC), not after it
    try:
        prepare(needed_libraries([(name, len(scenario.auv), preset, None, boat)]), args.quiet)
        controller = make_controller(name, len(scenario.auv), preset, boat=boat)
    except ConfigError as exc:
        # a name taken from the scenario file: say which file and where each name came from
        # (it read "unknown controller 'x'" as if --controller had been given, and blamed
        # the scenario for a bad --params)
        if args.controller and (args.params or name != scenario.controller):
            raise  # both from the command line: its message as it is
        said = [f"controller {name!r} from " + ("--controller" if args.controller
                                                else "this scenario")]  # fmt: skip
        if preset is not None:
            said.append("preset from " + ("--params" if args.params else "this scenario"))
        raise ConfigError(f"{args.scenario} ({', '.join(said)}): {exc}") from None
    result = simulate(scenario, controller, args.seed, args.estimator, progress=not args.quiet)
    extra = {"preset": preset_used(name, preset), "estimator": args.estimator or scenario.estimator,
             "realisation": real.as_dict(), "boat": boat.describe(),
             "params": params_record(controller)}  # fmt: skip
    metrics = write_run(result, out, compute_metrics(result), plots=not args.no_plots,
                        extra=extra)  # fmt: skip
    keys = ("duration_s", "asv_distance_m", "min_range_m", "collision_domain_s",
            "reliable_fix_age_max_s", "reliable_fix_age_p95_s", "nav_error_rms_m",
            "nav_error_p95_m", "propeller_on_s", "energy_J", "fallbacks")  # fmt: skip
    files = "timeseries.parquet, metrics.json" + ("" if args.no_plots else ", plots")
    print(f"wrote {out}/ ({files}) in {result.wall_s:.2f} s")
    print(f"  controller {name}, preset {extra['preset']}" + (
        f" (its default: the scenario's preset {scenario.preset!r} is for its controller "
        f"{scenario.controller!r})" if preset is None and name != scenario.controller
        and scenario.preset != DEFAULT_PRESET else ""))  # fmt: skip
    print(f"  realisation {real.id}: {len(real.values)} drawn values (run.json)")
    for k in keys:
        v = metrics[k]
        print(f"  {k:24s} {v:.3f}" if isinstance(v, float) else f"  {k:24s} {v}")
    if metrics.get("solver_hangs"):  # solves abandoned by the hang guard: say so
        print(f"  {'solver_hangs':24s} {metrics['solver_hangs']} (solves abandoned after "
              "solver.hang_s s of the solver's CPU time: docs/mpc.md 'Known problems'; solve "
              f"them again: mpcasv replay-solve {out / 'hung_solves.pkl'})")
    if metrics.get("current_untested_s"):  # an MPC planning in a current it is untested in
        print(f"  {'current_untested_s':24s} {metrics['current_untested_s']:.3f} (its plan's "
              "current above the tested one: docs/mpc.md 'Known problems', strong currents)")
    for line in too_deep(result):
        print(line)
    return 0


def too_deep(result) -> list[str]:
    """One line per AUV whose depth left no target domain inside the evaluation domain's
    donut for some of the run: ``r_outer <= r_t - eps_minus`` (Paper 1 eqs. 3-5, 10; with
    ``r_outer = 0`` below the outer sphere ``r_out``), with the time (s). There the ASV
    counts as beyond r_outer wherever it is farther than ``r_outer``, and hybrid-single
    run with this domain never stands by (its jump to STANDBY needs ``r_t - eps_minus < r
    <= r_outer``). A controller run with another preset decides on its own domain. Empty
    without a domain."""
    ts, dom, sc = result.timeseries, result.domain, result.scenario
    if dom is None or ts.empty:
        return []
    out = []
    for k, a in enumerate(sc.auv):
        if f"r_outer{k}" not in ts:
            continue
        n = int((ts[f"r_outer{k}"] <= ts[f"r_t{k}"] - dom.eps_minus).sum())
        if n:
            s = n * sc.sim.row_period
            out.append(f"  AUV {a.name!r}: too deep for the evaluation domain for {s:g} s "
                       f"(r_outer <= r_t - eps_minus: no target domain inside the donut; r_out "
                       f"= {dom.r_out:.0f} m): hybrid-single with this domain does not stand by "
                       "there; docs/metrics.md")
    return out
