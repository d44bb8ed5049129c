"""``mpcasv replay-solve``: the command line of :mod:`mpcasv.mpc.hung` (solve again the MPC
solves a simulated run abandoned as hung, or export them as standalone reproductions)."""

from __future__ import annotations

import argparse
import math
import tomllib
from pathlib import Path

from mpcasv.mpc.hung import (
    FILE_NAME,
    REPLAY_SETTINGS,
    HungSolve,
    idle_limit,
    load,
    replay,
    same_problem,
    verdict,
    with_solver,
)


# ---------------------------------------------------------------------- command line
def _setting(text: str) -> tuple[str, object]:
    """``solver.KEY=VALUE`` -> (KEY, value); the value read as TOML (else a string)."""
    key, sep, value = text.partition("=")
    if not sep or not key.startswith("solver.") or len(key) <= len("solver."):
        raise argparse.ArgumentTypeError(f"{text!r}: expected solver.KEY=VALUE")
    try:
        v = tomllib.loads(f"v = {value}")["v"]
    except tomllib.TOMLDecodeError:
        v = value
    return key.removeprefix("solver."), v


def _folder(text: str) -> Path:
    """A folder name (not empty: ``Path("")`` would be the current folder)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty folder name")
    return Path(text)


#: fatrop's and IPOPT's iteration limit is a C int
MAX_ITER_LIMIT = 2**31 - 1


def register(sub: argparse._SubParsersAction) -> None:
    from mpcasv.mpc.export import EXPORT_SETTINGS

    p = sub.add_parser(
        "replay-solve", help="solve again the MPC solves a run abandoned as hung",
        description="Solve again, each in a fresh worker process under the hang guard's CPU "
        "time limit, the MPC solves a simulated run abandoned as hung (RUN/hung_solves.pkl, "
        "written when the metric solver_hangs is not 0): whether each hangs again, with the "
        "recorded or other solver settings (docs/mpc.md 'Known problems'). The file is a "
        "Python pickle: open only files you trust.",
    )  # fmt: skip
    p.add_argument("file", type=Path, help=f"a run folder's {FILE_NAME}")
    p.add_argument("--index", type=int, action="append",
                   help="replay only this solve (0-based; repeatable; default: all)")
    p.add_argument("--cpu-s", type=float, default=None,
                   help="abandon a solve after this many s of its worker's CPU time "
                        "(default: the solver.hang_s it was given)")
    p.add_argument("--max-iter", type=int, default=None,
                   help="the solve's iteration limit (default: the recorded one, else the "
                        "preset's solver.max_iter)")  # fmt: skip
    p.add_argument("--set", type=_setting, action="append", default=[], metavar="solver.K=V",
                   help="replace a solver setting that reaches the solver, e.g. "
                        f"solver.stage_derivatives=inline ({', '.join(REPLAY_SETTINGS)}; "
                        f"with --export: {', '.join(EXPORT_SETTINGS)}; repeatable)")
    p.add_argument("--export", type=_folder, default=None, metavar="DIR",
                   help="instead of solving, write each solve to DIR/solve-I as a standalone "
                        "reproduction that needs casadi and numpy only (nlp.casadi, "
                        "problem.npz, options.json, reproduce.py, README.md: a report to "
                        "fatrop's authors)")  # fmt: skip
    p.set_defaults(func=run)


def _check_options(args: argparse.Namespace) -> None:
    from mpcasv.config import ConfigError

    if args.cpu_s is not None and not (math.isfinite(args.cpu_s) and args.cpu_s > 0):
        raise ConfigError(f"--cpu-s {args.cpu_s}: must be a finite number > 0 (s)")
    if args.max_iter is not None and not 1 <= args.max_iter <= MAX_ITER_LIMIT:
        raise ConfigError(f"--max-iter {args.max_iter}: must be 1..{MAX_ITER_LIMIT}")
    if args.export is not None:  # a file there, a file-like name (--export e.txt), unwritable
        from mpcasv.outputs import check_output_folder

        check_output_folder(args.export, "--export")


def _library_ready(s: HungSolve) -> None:
    """Compile the solve's library first if it is not in the cache, saying so (the worker
    would compile it silently)."""
    from mpcasv.mpc.prepare import libraries

    for lib in libraries(s.params, s.n_auv, s.multi, s.boat):
        if not lib.cached:
            inline = s.params.solver.stage_derivatives == "inline"
            print(f"compiling {lib.label} (about {lib.estimate_s * (10 if inline else 1):.0f} "
                  "s on an idle machine; cached for the next time) ...", flush=True)
            lib.compile(log=lambda *a: None)


def run(args: argparse.Namespace) -> int:
    from mpcasv.config import ConfigError

    _check_options(args)
    solves = load(args.file)
    if not solves:
        raise ConfigError(f"{args.file}: holds no hung solves")
    picked = list(dict.fromkeys(range(len(solves)) if args.index is None else args.index))
    for i in picked:
        if not 0 <= i < len(solves):
            raise ConfigError(f"--index {i}: {args.file} holds {len(solves)} hung solve"
                              f"{'s' if len(solves) > 1 else ''} (0..{len(solves) - 1})")
    if args.export is None:  # all checked first (an export checks its own settings)
        runs = {i: with_solver(solves[i], dict(args.set)) for i in picked}
        if args.max_iter is not None and any(s.params.solver.solver == "qp"
                                             for s in runs.values()):  # fmt: skip
            raise ConfigError("--max-iter: the qp variant has no iteration limit; its work is "
                              "bounded by solver.qp_iters (--set solver.qp_iters=N)")
    print(f"{args.file}: {len(solves)} hung solve{'s' if len(solves) > 1 else ''}")
    if args.export is not None:
        return _export_all({i: solves[i] for i in picked}, args)
    again = undecided = 0
    for i, s in runs.items():
        sp = s.params.solver
        limit = s.max_iter if args.max_iter is None else args.max_iter  # None: the preset's
        cpu = s.cpu_s if args.cpu_s is None else args.cpu_s
        if sp.solver == "qp":  # its work is bounded by qp_iters, not by an iteration limit
            how = f"qp, qp_iters {sp.qp_iters}"
        else:
            how = (f"{sp.solver} ({sp.stage_derivatives} derivatives), "
                   f"max_iter {sp.max_iter if limit is None else limit}")  # fmt: skip
        _library_ready(s)
        same = same_problem(s)
        if not same:
            print(f"[{i}] note: " + ("recorded without the problem's digest (before session "
                                     "32): the problem rebuilt here may differ from the one "
                                     "that hung" if same is None else "the problem rebuilt "
                                     "here is not the one that hung (another mpcasv version): "
                                     "this replay does not reproduce that solve"))  # fmt: skip
        print(f"[{i}] t = {s.t:g} s, {s.n_auv} AUV{'s' if s.n_auv > 1 else ''}, {how}: ",
              end="", flush=True)
        try:
            r = replay(s, cpu, limit)
        except RuntimeError as exc:
            print("failed")
            raise ConfigError(f"[{i}]: {exc}") from None
        if r.hung and r.by_cpu:
            again += 1
            print(f"hung again (abandoned after {cpu:g} s of CPU time; {r.wall_s:.1f} s wall)")
        elif r.hung:  # a worker stopped or blocked: it used no CPU for that long
            undecided += 1
            print(f"no verdict: the worker used no CPU for {idle_limit(cpu):g} s before "
                  f"spending {cpu:g} s of CPU time (stopped or blocked)")
        else:
            unit = "step" if sp.solver == "qp" else "iteration"
            print(f"returned in {r.wall_s:.2f} s: {verdict(sp.solver, r)}, {r.iters} {unit}"
                  f"{'s' if r.iters != 1 else ''}, cost {r.f:.6g}")
    print(f"{again} of {len(runs)} hung again"
          + (f"; {undecided} without a verdict (raise --cpu-s)" if undecided else ""))
    return 0


def _export_all(records: dict[int, HungSolve], args: argparse.Namespace) -> int:
    """``--export DIR``: each picked solve (``records``, as recorded; ``--set`` applied by the
    export) to ``DIR/solve-I`` (:func:`mpcasv.mpc.export.export`); none is solved."""
    from mpcasv.config import ConfigError
    from mpcasv.mpc.export import export

    if args.max_iter is not None or args.cpu_s is not None:
        raise ConfigError("--export writes the problem without solving it: --max-iter and "
                          "--cpu-s are options of reproduce.py and of a replay")  # fmt: skip
    settings = dict(args.set)
    for i, s in records.items():
        try:
            out = export(s, args.export / f"solve-{i}", f"{args.file} [{i}]", settings)
        except ValueError as exc:
            raise ConfigError(f"[{i}]: {exc}") from None
        print(f"[{i}] t = {s.t:g} s: written to {out} (run: cd {out} && timeout 60 python "
              "reproduce.py)")
    return 0
