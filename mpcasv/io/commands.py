"""``mpcasv deploy``, ``mpcasv sitl`` and ``mpcasv replay`` (docs/deploy.md)."""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
from pathlib import Path


def _imc_id(text: str) -> int:
    v = int(text, 0)
    if not 0 <= v < 0xFFFF:
        raise argparse.ArgumentTypeError(f"IMC id must be 0..0xFFFE, got {text}")
    return v


def _pair(text: str) -> tuple[float, float]:
    try:
        a, b = (float(x) for x in text.split(":" if ":" in text else ","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected two numbers, got {text!r}") from None
    return a, b


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None


def _positive(text: str) -> float:
    v = _number(text)
    if not 0 < v < math.inf:  # nan fails too
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return v


def _nonneg(text: str) -> float:
    v = _number(text)
    if not 0 <= v < math.inf:
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text}")
    return v


def _count(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {text}")
    return v


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "deploy", help="run a controller on live IMC vehicles (DUNE) or against mpcasv sitl",
        description="Run the configured controller on the vehicles of CONFIG over IMC: "
        "FollowReference on the ASV, one Reference per control period, watchdogs, logs "
        "(imc.lsf + deploy.jsonl in log.dir). Ctrl-C / SIGTERM: standby + MANDONE, exit. "
        "Exit 0: ran and decided; 1: ran without a single decision (no vehicle heard, or "
        "never a state: one line says which); 2: bad input (CONFIG, the log folder, the bind "
        "address), one line.",
    )  # fmt: skip
    p.add_argument("config", type=Path, help="deploy TOML (experiments/deploy/sitl-case3.toml)")
    p.add_argument("--dry-run", action="store_true", help="compute and log, send no commands")
    p.add_argument("--log-dir", type=Path, help="override log.dir of the config")
    p.add_argument("--duration", type=_positive, help="stop after this many clock seconds")
    p.add_argument("--quiet", action="store_true", help="no event lines on stderr")
    p.add_argument("--prepare", action="store_true",
                   help="validate CONFIG and build the controller (compiling an MPC's library "
                   "if it is not cached), then exit without contacting any vehicle (not with "
                   "--dry-run or --duration, which only a run reads)")  # fmt: skip
    p.set_defaults(func=run_deploy_cli)

    s = sub.add_parser(
        "sitl", help="simulated ASV and AUVs as IMC systems on loopback (rehearsal for deploy)",
        description="Run SCENARIO's ASV and AUVs as separate DUNE-like IMC systems (Announce, "
        "Heartbeat-gated EstimatedState at 2 Hz, PlanControl/FollowReference/Reference/"
        "FollowRefState). SIGUSR1 kills the ASV's IMC system, SIGUSR2 restarts it.",
    )  # fmt: skip
    s.add_argument("scenario", type=Path, help="scenario TOML")
    s.add_argument("--seed", type=int, default=0,
                   help="world seed, in [0, 2**32 - 1] (0): the world's acoustic draws and the "
                   "realisation of the scenario's [uncertain] table, as in mpcasv "
                   "simulate")  # fmt: skip
    s.add_argument("--nominal", action="store_true",
                   help="simulate the scenario's nominal values (no draw from [uncertain])")
    s.add_argument("--speedup", type=_positive, default=1.0,
                   help="clock factor in [0.01, 1000] (deploy's clock.speedup must "
                   "match)")  # fmt: skip
    s.add_argument("--bind", default="127.0.0.1",
                   help="local IPv4 address (default 127.0.0.1; not a host name)")
    s.add_argument("--discovery-port", type=int, default=30100,
                   help="port of the discovery socket (0: any free)")  # fmt: skip
    s.add_argument("--base-port", type=int, default=6002,
                   help="vehicle k binds base+k (ASV first); 0: any free ports")  # fmt: skip
    s.add_argument("--origin", type=_pair, default=(63.4406, 10.3530),
                   help="local frame origin 'lat,lon' in degrees (lat in [-90, 90], lon "
                   "in [-180, 180])")  # fmt: skip
    s.add_argument("--duration", type=_positive, help="world seconds (default: the scenario's)")
    s.add_argument("--hold", action="store_true",
                   help="keep the world at t=0 until the first Reference")  # fmt: skip
    s.add_argument(
        "--reaction",
        type=float,
        default=None,
        help="longest wait for the Reference answering a state, in [0, 1) periods (0.9); "
        "not with --lockstep, which waits however long it takes",
    )
    s.add_argument("--lockstep", action="store_true",
                   help="wait for the Reference answering each period's state however long it "
                   "takes (rehearsals compared with 'mpcasv simulate' on a loaded host; a real "
                   "DUNE does not wait)")  # fmt: skip
    s.add_argument("--auv-states", choices=("radio", "acoustic"), default="radio",
                   help="the AUVs' EstimatedStates: 'radio' at 2 Hz (default), or 'acoustic': "
                   "so until the ASV's first Reference, then only the world's status reports "
                   "that got through (AUVs under water: the deploy then needs the positions of "
                   "the ASV's USBL fixes, estimator 'kalman' or 'plan', and watchdog."
                   "auv_stale_s above the gaps between fixes)")  # fmt: skip
    s.add_argument("--usbl-delay", type=float, default=0.0,
                   help="seconds between a USBL fix and the ASV's sending of it, stamped at the "
                   "fix's time (in [0, 60]; default 0): AUV states stamped later then come "
                   "first, as from a real DUNE")  # fmt: skip
    s.add_argument("--reanchor", type=_positive, default=1000.0,
                   help="EstimatedState reference point moves every this many m")  # fmt: skip
    s.add_argument("--asv-name", default="sitl-asv")
    s.add_argument("--asv-id", type=_imc_id, default=0x2801)
    s.add_argument("--auv-id-base", type=_imc_id, default=0x2811)
    s.add_argument("--tcp", action="store_true", help="also serve DUNE-like TCP backseat ports")
    s.add_argument("--asv-outage", type=_pair,
                   help="'T0,T1': kill the ASV at world time T0, restart at T1 > T0 (each "
                   "at the first period start at or after it; T0 within the run)")  # fmt: skip
    s.add_argument("--out", type=Path, default=Path("runs/sitl"))
    s.add_argument("--plots", action="store_true", help="also write the PNG figures")
    s.add_argument("--ready-file", type=Path, help="write the bound ports here (a .json file)")
    s.add_argument("--quiet", action="store_true")
    s.set_defaults(func=run_sitl_cli)

    r = sub.add_parser(
        "replay", help="re-run a controller over a deploy log and show where decisions differ",
        description="Feed the Observations logged in LOG (deploy.jsonl, or its folder) to a "
        "controller (by default the logged one) and compare its commands with the logged ones.",
    )  # fmt: skip
    r.add_argument("log", type=Path)
    r.add_argument("--controller", help="controller name (default: the logged one)")
    r.add_argument("--preset", help="preset name or TOML (default: the logged one; another "
                   "one, or another controller, is replayed without the logged "
                   "controller.overrides, which were written for the logged preset)")
    r.add_argument("--tol", type=_nonneg, default=0.5, help="waypoint tolerance in m (0.5)")
    r.add_argument("--show", type=_count, default=20, help="differing steps to list (20)")
    r.add_argument("--json", type=Path,
                   help="write the comparison table here (JSON lines: a .jsonl file)")
    r.set_defaults(func=run_replay_cli)


class _LevelFormatter(logging.Formatter):
    """``name: message``; a warning or an error says so: ``name: warning: message`` (a
    warning such as ``clock_rate`` had looked like the info lines around it)."""

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record)  # "%(name)s: %(message)s", and a traceback if any
        if record.levelno < logging.WARNING:
            return text
        head = f"{record.name}: "
        return f"{head}{record.levelname.lower()}: {text[len(head):]}"


def _logging(quiet: bool) -> None:
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_LevelFormatter("%(name)s: %(message)s"))
    logging.basicConfig(level=logging.WARNING if quiet else logging.INFO, handlers=[handler])


def run_deploy_cli(args: argparse.Namespace) -> int:
    from mpcasv.io.deploy import run_deploy

    _logging(args.quiet)
    summary = run_deploy(args.config, args.dry_run, args.log_dir, args.duration, args.prepare)
    print(json.dumps({"prepared" if args.prepare else "summary": summary}), flush=True)
    if "plan_ended" in summary:  # DUNE ended our plan (an operator's stop?): not a success
        print(f"mpcasv deploy: stopped: {summary['plan_ended']}", file=sys.stderr)
        return 1
    if "no_decision" in summary:  # ran, and never decided: exit 1 (the CLI's "check failed")
        print(f"mpcasv deploy: failed: {summary['no_decision']}", file=sys.stderr)
        return 1
    return 0


def run_sitl_cli(args: argparse.Namespace) -> int:
    from mpcasv.io.sitl import SitlOptions, run_sitl
    from mpcasv.outputs import check_output_file, check_output_folder
    from mpcasv.sim.scenario import load_scenario

    _logging(args.quiet)
    sc = load_scenario(args.scenario)
    opt = SitlOptions(
        seed=args.seed, nominal=args.nominal, speedup=args.speedup, bind=args.bind,
        discovery_port=args.discovery_port, base_port=args.base_port, origin=args.origin,
        duration=args.duration, hold=args.hold, reaction=args.reaction, lockstep=args.lockstep,
        reanchor_m=args.reanchor, asv_name=args.asv_name, asv_id=args.asv_id,
        auv_id_base=args.auv_id_base, tcp=args.tcp, asv_outage=args.asv_outage,
        out=args.out, plots=args.plots, ready_file=args.ready_file, auv_states=args.auv_states,
        usbl_delay=args.usbl_delay,
    ).check(sc)  # fmt: skip
    check_output_folder(args.out)
    if args.ready_file is not None:
        check_output_file(args.ready_file, "--ready-file", (".json",))
    opt.check_binds(len(sc.auv))  # before --out is written
    info = run_sitl(sc, opt)
    print(json.dumps({"finished": {k: v for k, v in info.items() if k != "metrics"}}),
          flush=True)  # fmt: skip
    if "no_run" in info:  # nothing to compare: exit 1, as a deploy that never decided
        print(f"mpcasv sitl: no run written to {opt.out / 'run'}: {info['no_run']}",
              file=sys.stderr)  # fmt: skip
        return 1
    return 0


def run_replay_cli(args: argparse.Namespace) -> int:
    from mpcasv.io.replay import print_replay, replay
    from mpcasv.outputs import check_output_file

    if args.json is not None:
        check_output_file(args.json, "--json", (".jsonl",))  # JSON lines, not one JSON
    rep = replay(args.log, args.controller, args.preset, args.tol)
    print_replay(rep, args.show)
    if args.json:
        rep.table.to_json(args.json, orient="records", lines=True)
    return 0
