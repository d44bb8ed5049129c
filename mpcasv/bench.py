"""``mpcasv bench``: benchmarks that print figures (speed targets live here, not in tests)."""

from __future__ import annotations

import argparse
import importlib
import json
from pathlib import Path

#: benchmark name -> "module:function"; each function takes the parsed args, returns a dict
BENCHES = {
    "sim": "mpcasv.sim.bench:bench_sim",
    "mpc": "mpcasv.mpc.bench:bench_mpc",
    "compare": "mpcasv.experiments.bench:bench_compare",
}
#: the options each benchmark reads (another's option is refused, not ignored: ``bench mpc
#: --suite quick`` ran the whole MPC benchmark as if the suite had been read)
OPTIONS = {
    "sim": ("repeat",),
    "mpc": ("steps", "quick", "threads", "step_iter"),
    "compare": ("suite", "repeat"),
}
DEFAULTS = {"repeat": 3, "steps": 300}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="benchmarks that print timing figures",
                       description="Run a benchmark and print its figures.")  # fmt: skip
    p.add_argument("which", choices=sorted(BENCHES), help="what to benchmark")
    p.add_argument("--json", type=Path, help="also write the figures to this .json file")
    p.add_argument("--repeat", type=int, default=None,
                   help="'sim', 'compare': repetitions (best/median reported; default 3)")
    p.add_argument("--suite", help="'compare': the suite to time (default bench)")
    p.add_argument("--steps", type=int, default=None,
                   help="'mpc': receding-horizon problems per recorded sequence (default 300)")
    p.add_argument("--quick", action="store_true",
                   help="'mpc': only Opti + IPOPT and the default solver (no QP variant, no "
                        "IPOPT polish of the default's solutions)")  # fmt: skip
    p.add_argument("--threads", type=int, default=None,
                   help="'mpc': the default solver's stage-evaluation threads (solver.threads) "
                        "in the recorded run and its replay (default: the presets', 1)")
    p.add_argument("--step-iter", type=int, default=None,
                   help="'mpc': the recorded run's step iteration budget (solver.step_iter; "
                        "0: none; default: the presets')")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mpcasv.config import ConfigError
    from mpcasv.outputs import check_output_file

    given = [k for k in ("repeat", "suite", "steps", "quick", "threads", "step_iter")
             if getattr(args, k) is not None and getattr(args, k) is not False]  # 0 is given
    foreign = [k for k in given if k not in OPTIONS[args.which]]
    if foreign:
        opts = ", ".join("--" + k.replace("_", "-") for k in foreign)
        raise ConfigError(f"{opts}: not read by 'bench {args.which}' (it reads "
                          f"{', '.join('--' + k.replace('_', '-') for k in OPTIONS[args.which])})")
    for k, v in DEFAULTS.items():
        if getattr(args, k) is None:
            setattr(args, k, v)
    # --repeat 0 / -1 ran once and said "over 1 runs"; --steps -1 blamed "case3 (modified):
    # duration"; an unwritable --json was found only after the whole benchmark
    for flag in ("repeat", "steps", "threads"):
        if getattr(args, flag) is not None and getattr(args, flag) < 1:
            raise ConfigError(f"--{flag} {getattr(args, flag)}: must be >= 1")
    if args.step_iter is not None and args.step_iter < 0:
        raise ConfigError(f"--step-iter {args.step_iter}: must be >= 0 (0: no budget)")
    if args.which == "mpc" and args.steps < 2:  # (--steps 1 crashed in the step summary)
        raise ConfigError(f"--steps {args.steps}: 'mpc' needs >= 2 (the first, cold step is "
                          "left out of the figures)")
    if args.json is not None:
        check_output_file(args.json, "--json", (".json",))
    module, func = BENCHES[args.which].split(":")
    figures = getattr(importlib.import_module(module), func)(args)
    if args.json:
        args.json.write_text(json.dumps(figures, indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0
