"""The ``mpcasv`` command line: one sub-command per workflow.

Each sub-command lives beside the code it drives (``mpcasv/<package>/commands.py``) and
registers itself through ``register(subparsers)``; this module only assembles them and turns
configuration errors into one clear message and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from mpcasv import __version__
from mpcasv.config import ConfigError
from mpcasv.errors import LogError

COMMAND_MODULES = (
    "mpcasv.sim.commands",  # simulate
    "mpcasv.hybrid.commands",  # paper-table
    "mpcasv.experiments.commands",  # compare
    "mpcasv.control.commands",  # tune, identify
    "mpcasv.experiments.tune_commands",  # tune controller (extends "tune": after the above)
    "mpcasv.io.commands",  # deploy, sitl, replay, log
    "mpcasv.bench",  # bench
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mpcasv",
        description="ASV support of AUVs: hybrid and MPC controllers, experiments, tuning, "
        "IMC deployment. Run 'mpcasv COMMAND --help' for each command.",
    )
    parser.add_argument("--version", action="version", version=f"mpcasv {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ConfigError, LogError) as exc:  # bad input: one line, exit 2
        print(f"mpcasv {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"mpcasv {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
