"""``mpcasv paper-table``: Cases 1-8 with their presets, our numbers next to the published."""

from __future__ import annotations

import argparse
from pathlib import Path

CASES = tuple(f"case{i}" for i in range(1, 9))


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "paper-table", help="run Cases 1-8 and write our numbers next to the published ones",
        description="Run the papers' Cases 1-8 (experiments/scenarios/caseN.toml) with their own "
        "controller and preset, write each run folder and paper_table.md into --out.",
    )  # fmt: skip
    p.add_argument("--out", type=Path, default=Path("runs/paper-table"),
                   help="output folder (default runs/paper-table)")
    p.add_argument("--scenarios", type=Path, default=None,
                   help="folder with all eight of case1.toml ... case8.toml (default: the "
                   "shipped experiments/scenarios, from any working folder)")  # fmt: skip
    p.add_argument("--seed", type=int, default=0,
                   help="random seed of the world's acoustic draws (default 0)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import pandas as pd
    from tqdm import tqdm

    from mpcasv.config import ConfigError, check_seed
    from mpcasv.controllers import Boat, make_controller, preset_used
    from mpcasv.experiments.metrics import compute_metrics
    from mpcasv.hybrid.paper import metrics_of, write_table
    from mpcasv.outputs import check_output_folder
    from mpcasv.sim.record import write_run
    from mpcasv.sim.scenario import load_scenario
    from mpcasv.sim.simulator import simulate

    check_seed(args.seed)  # -1 was a numpy traceback
    from mpcasv.experiments.suite_file import SCENARIOS_DIR

    folder = SCENARIOS_DIR if args.scenarios is None else args.scenarios
    paths = [folder / f"{c}.toml" for c in CASES]
    missing = [p.name for p in paths if not p.exists()]
    if missing:  # it said "run from the repository root" though --scenarios was given
        raise ConfigError(f"--scenarios {folder}: no {', '.join(missing)} there (the table "
                          "needs all eight, case1.toml ... case8.toml)")  # fmt: skip
    scenarios = [load_scenario(p) for p in paths]  # validate all before running any
    check_output_folder(args.out)
    results = {}
    for sc in tqdm(scenarios, desc="paper cases", unit="case"):
        boat = Boat.of_scenario(sc)
        ctrl = make_controller(sc.controller, len(sc.auv), sc.preset, boat=boat)
        res = simulate(sc, ctrl, args.seed)
        preset = preset_used(sc.controller, sc.preset)
        out = args.out / sc.name
        write_run(
            res, out, compute_metrics(res), extra={"preset": preset, "boat": boat.describe()}
        )
        results[sc.name] = (metrics_of(out), pd.read_parquet(out / "timeseries.parquet"),
                            f"{sc.controller} / {preset}")  # fmt: skip
    path = write_table(results, args.out / "paper_table.md")
    print(f"wrote {path} and the run folders in {args.out}/")
    return 0
