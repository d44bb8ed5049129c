"""``mpcasv tune yaw|speed`` and ``mpcasv identify``: tuning and identification on the shared model.

The command line (the options and their help) is here; the tuning runs behind it are in
:mod:`mpcasv.control.tune_cli`, the identification's in :mod:`mpcasv.control.identify_cli`.

Exact commands that produced the shipped ``mpcasv/data/execution/gretha.toml``::

    mpcasv tune yaw --out runs/tune-yaw --toml mpcasv/data/execution/gretha.toml
    mpcasv tune speed --out runs/tune-speed --toml mpcasv/data/execution/gretha.toml
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mpcasv.control.tune_cli import (
    BASE_DEFAULT,
    DEFAULT_SPEEDS,
    WN_LAG_FRACTION,
    WN_PER_SPEED,
    run_tune_speed,
    run_tune_yaw,
)


def _floats(text: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        msg = f"not a comma-separated list of numbers: {text!r}"
        raise argparse.ArgumentTypeError(msg) from None
    if not values:  # ",," was a pydantic traceback (an empty schedule)
        raise argparse.ArgumentTypeError(f"no numbers in {text!r}")
    return values


class _Speeds(argparse.Action):
    """``--speeds``: a comma-separated list of m/s (:func:`_floats`). argparse reads a value
    that starts with '-' and is not one plain number (``-1,1``) as an option and said only
    "expected one argument"; the value is optional to argparse (``nargs="?"``) so that this
    says, in one line, how to give it: joined, ``--speeds=-1,1``."""

    def __call__(self, parser, namespace, values, option_string=None):
        if values is None:
            parser.error(f"argument {option_string}: expected a comma-separated list of m/s "
                         "(one that starts with '-' is read as an option: join it, "
                         f"{option_string}=-1,1)")  # fmt: skip
        setattr(namespace, self.dest, values)


def register(sub: argparse._SubParsersAction) -> None:
    tune = sub.add_parser("tune", help="tune the execution level (yaw PID, speed loop)",
                          description="Linearise the shared vessel model and tune the execution "
                          "level; write figures, plots and the execution TOML.")  # fmt: skip
    tsub = tune.add_subparsers(dest="tune_what", metavar="LOOP", required=True)

    y = tsub.add_parser("yaw", help="yaw PID gain schedule (Nomoto, pole placement, margins)")
    y.add_argument(
        "--speeds",
        type=_floats,
        nargs="?",
        action=_Speeds,
        metavar="U,...",
        help="surge speeds of the schedule, m/s (default 0.2, 0.4, ... 1.0 times the vessel's "
        f"u_max: {DEFAULT_SPEEDS} for Gretha)",
    )
    y.add_argument(
        "--wn",
        type=_floats,
        help="closed-loop natural frequency, rad/s: one value for all speeds or one "
        "per speed (default: --wn-per-speed times the speed; for a differential-thrust "
        f"vessel, whose yaw dynamics do not change with speed, {WN_LAG_FRACTION}/T_delta at "
        "every speed)",
    )
    y.add_argument(
        "--wn-per-speed",
        type=float,
        default=None,
        help=f"wn = this * u0, rad/m, instead of --wn (not with it; default {WN_PER_SPEED} for a "
        "steered drive: about the same Kp at every speed and the same turn length scale)",
    )
    y.add_argument("--zeta", type=float, default=1.0, help="damping ratio (default 1.0)")
    y.add_argument(
        "--integral-ratio",
        type=float,
        default=0.5,
        help="integral pole / wn (default 0.5; Fossen's textbook value is 0.1)",
    )
    y.add_argument(
        "--T-f",
        dest="T_f",
        type=float,
        default=0.2,
        help="yaw-rate filter time constant, s (default 0.2)",
    )
    _common(y)
    y.set_defaults(func=run_tune_yaw)

    s = tsub.add_parser("speed", help="speed loop PI and surge-speed reference model (eq. 3.1)")
    s.add_argument("--w", type=float, default=0.3, help="speed loop natural frequency, rad/s")
    s.add_argument("--zeta", type=float, default=1.0, help="speed loop damping ratio")
    s.add_argument(
        "--design-speed",
        type=float,
        help="design speed, m/s (default 0.4 times the vessel's top speed: 1 for Gretha)",
    )
    s.add_argument(
        "--speeds",
        type=_floats,
        nargs="?",
        action=_Speeds,
        metavar="U,...",
        help="speeds where the margins are checked, m/s (default 0.2 ... 1.0 u_max)",
    )
    s.add_argument(
        "--u-ff",
        type=_floats,
        default=_floats("0.4,0.6,0.8"),
        help="u_ff values of the turn grid, m/s (default 0.4,0.6,0.8)",
    )
    s.add_argument(
        "--k-u",
        type=_floats,
        default=_floats("1.2,1.59,2.0"),
        help="k_u values of the turn grid, m/s (default 1.2,1.59,2.0)",
    )
    s.add_argument(
        "--distance",
        type=_floats,
        default=_floats("10,20,50"),
        help="waypoint distances of the turns, m (default 10,20,50: 10 m is inside the "
        "full-power turning circle, where turning while accelerating pirouettes); each must "
        "exceed the 5 m arrival radius, and a turn may run at most 1800 s (150 s + distance / "
        "min(u_ff, u_max))",
    )
    s.add_argument(
        "--u-cmd-max",
        type=float,
        help="bound on eq. 3.1's largest command u_ff + k_u pi/2 for the recommendation, m/s "
        "(default: the --base file's own u_ff + k_u pi/2, 3.0976 for Gretha's shipped file: "
        "the thesis held it at the rated maximum speed, section 3.4.1; the same for every "
        "--vessel: for another hull pass it); grid pairs above it are not recommended",
    )
    s.add_argument(
        "--set-reference",
        action="store_true",
        help="write the recommended (u_ff, k_u) into the TOML (default: keep the "
        "base file's: for the shipped one, the field tuning)",
    )
    _common(s)
    s.set_defaults(func=run_tune_speed)

    i = sub.add_parser("identify", help="identify the 3-DOF model from logs (CSV or DUNE LSF)",
                       description="Identify vessel parameters from logged manoeuvres: "
                       "equation-error start, simulation-error refinement, held-out validation."
                       " See mpcasv/models/identify.py for the CSV columns and "
                       "mpcasv/io/identlog.py for DUNE logs.")  # fmt: skip
    i.add_argument(
        "logs", nargs="+", type=Path, help="CSV/parquet identification logs or .lsf(.gz)"
    )
    i.add_argument("--out", type=Path, required=True, help="identified parameters TOML")
    i.add_argument("--vessel", default="gretha", help="prior parameters (name or TOML)")
    i.add_argument(
        "--vehicle",
        dest="vehicle_pick",
        metavar="NAME|ID",
        help="DUNE logs with several vehicles: the one to identify (Announce name or IMC id, "
        "e.g. 0x2801); default: the one that carries the actuator set-points (refused "
        "without a DUNE log)",
    )
    i.add_argument(
        "--coeffs", help="comma-separated coefficients to identify (default: the documented subset)"
    )
    i.add_argument(
        "--validation",
        type=float,
        default=0.25,
        help="fraction of each log held out for validation (default 0.25, the end)",
    )
    i.add_argument("--no-current", action="store_true", help="assume no current")
    i.add_argument("--quiet", action="store_true", help="no progress output")
    i.set_defaults(func=run_identify)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--vessel", default="gretha", help="vessel parameters: name or TOML")
    p.add_argument(
        "--base",
        default=BASE_DEFAULT,
        help=f"execution parameters to start from: name or TOML (default {BASE_DEFAULT}: "
        "Gretha's; for another vessel the loop not tuned stays Gretha's, said in a warning)",
    )
    p.add_argument("--out", type=Path, required=True, help="output folder (figures, plots)")
    p.add_argument(
        "--toml", type=Path, help="where to write the execution TOML (default OUT/execution.toml)"
    )
    p.add_argument("--dt", type=float, default=0.1,
                   help="step of the sampled-loop analysis, s (default 0.1; the nonlinear "
                   "checks run at the simulator's own 0.1 s)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run_identify(args: argparse.Namespace) -> int:
    from mpcasv.control.identify_cli import run_identify as run

    return run(args)
