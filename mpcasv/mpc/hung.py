"""Solves abandoned as hung, kept so that they can be solved again (``mpcasv replay-solve``).

fatrop 1.1.x can loop for ever in its inertia correction (docs/mpc.md "Known problems"):
simulation's hang guard abandons such a solve after ``solver.hang_s`` s of its worker's CPU
time (:mod:`mpcasv.mpc.deadline`). The controller keeps each abandoned solve as a
:class:`HungSolve` (``MPCController.hung_solves``): the problem's parameters and everything
sent to the worker. A simulated run writes them to ``hung_solves.pkl`` in its run folder
(:func:`mpcasv.sim.record.write_run`), and :func:`replay` solves one again in a fresh worker
process, under the same CPU-time guard, with the same or other solver settings: the
reproduction a report to fatrop's authors needs, and a way to try settings on the very
problems that hung.

The file is a Python pickle: open only files you trust (a pickle can run code when loaded).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import pickle
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mpcasv import __version__

#: the file a run folder keeps its hung solves in
FILE_NAME = "hung_solves.pkl"
#: the hang guard (and a replay): a solve whose worker has not answered after this many times
#: its CPU-time limit (``solver.hang_s``) of wall time is abandoned even without spending that
#: CPU time (a worker stopped or blocked; a hung fatrop spins and is caught by its CPU time)
HANG_WALL_FACTOR = 20.0


@dataclass(frozen=True)
class HungSolve:
    """One solve abandoned by the hang guard: what the worker was sent, and its problem.

    ``p`` (shape (n_p,)) the problem's parameters, ``w0`` (shape (n_w,)) the initial guess
    (physical units), ``lam_x``/``lam_g`` the warm-start multipliers (None: none); ``max_iter``
    the solve's iteration limit (None: ``solver.max_iter``); ``T_cap`` the planned thrust's
    cap (N; None: none); ``cpu_s`` the CPU time it was given (s); ``t`` the step's time (s).
    ``params``, ``n_auv``, ``multi`` and ``boat`` rebuild the same problem
    (:func:`mpcasv.mpc.controller.build_ocp`).
    """

    t: float
    params: object  # MPCParams
    n_auv: int
    multi: bool
    boat: object  # Boat | None
    p: np.ndarray
    w0: np.ndarray
    lam_x: np.ndarray | None
    lam_g: np.ndarray | None
    max_iter: int | None
    T_cap: float | None
    cpu_s: float
    version: str = __version__  # mpcasv's version that recorded it


def save(solves: list[HungSolve], path: str | Path) -> None:
    """Write ``solves`` to ``path`` (a pickle of the list)."""
    with open(path, "wb") as f:
        pickle.dump(list(solves), f, protocol=pickle.HIGHEST_PROTOCOL)


def load(path: str | Path) -> list[HungSolve]:
    """The hung solves in ``path`` (written by :func:`save`).

    Raises
    ------
    ConfigError
        One line: not such a file (not a pickle, or not a list of :class:`HungSolve`), or
        written by a version of mpcasv whose classes no longer load.
    OSError
        The file cannot be read.
    """
    from mpcasv.config import ConfigError

    with open(path, "rb") as f:
        try:
            solves = pickle.load(f)
        except (pickle.UnpicklingError, EOFError, ValueError) as exc:
            raise ConfigError(f"{path}: not a file of hung solves ({exc}); it is the "
                              f"{FILE_NAME} of a run folder") from None  # fmt: skip
        except (AttributeError, ImportError, TypeError) as exc:
            raise ConfigError(f"{path}: written by another version of mpcasv, whose classes "
                              f"do not load here ({exc})") from None  # fmt: skip
    if not isinstance(solves, list) or not all(isinstance(s, HungSolve) for s in solves):
        raise ConfigError(f"{path}: not a file of hung solves (a pickle of something else); "
                          f"it is the {FILE_NAME} of a run folder")  # fmt: skip
    return solves


def with_solver(solve: HungSolve, settings: dict) -> HungSolve:
    """``solve`` with ``settings`` (field of ``solver`` -> value, e.g. ``{"stage_derivatives":
    "inline"}``) replacing its preset's solver settings.

    Raises
    ------
    ConfigError
        A field that ``SolverParams`` does not have, or an invalid value.
    """
    from mpcasv.config import ConfigError

    sp = solve.params.solver
    names = {f.name for f in dataclasses.fields(sp)}
    unknown = sorted(set(settings) - names)
    if unknown:
        raise ConfigError(f"--set solver.{unknown[0]}: no such solver setting (SolverParams: "
                          f"{', '.join(sorted(names))})")  # fmt: skip
    try:
        new = dataclasses.replace(sp, **settings)
    except (TypeError, ValueError) as exc:
        msg = " ".join(str(exc).split())
        raise ConfigError(f"--set: invalid solver setting: {msg}") from None
    return dataclasses.replace(solve, params=dataclasses.replace(solve.params, solver=new))


@dataclass(frozen=True)
class Replayed:
    """The outcome of :func:`replay`: ``hung`` (abandoned again after ``cpu_s`` s of CPU
    time), else the solver's ``status``, ``iters``, cost ``f`` and ``ok``; ``wall_s`` the wall
    time of the solve (s)."""

    hung: bool
    status: str
    iters: int
    f: float
    ok: bool
    wall_s: float


def replay(solve: HungSolve, cpu_s: float | None = None, max_iter: int | None = None,
           factory=None) -> Replayed:  # fmt: skip
    """Solve ``solve`` again in a fresh worker process (its compiled library loaded from the
    cache, compiled first if missing) and abandon it, as the hang guard did, after ``cpu_s``
    s of the worker's CPU time (None: the time it was given, ``solve.cpu_s``).
    ``max_iter``: another iteration limit (None: the recorded one). ``factory`` (tests): builds
    the worker's solver (default: the recorded problem's).

    Raises
    ------
    RuntimeError
        The worker could not build the solver.
    """
    from mpcasv.mpc.controller import worker_solver
    from mpcasv.mpc.deadline import DeadlineSolver

    cpu_s = solve.cpu_s if cpu_s is None else cpu_s
    factory = factory or functools.partial(worker_solver, solve.params, solve.n_auv,
                                           solve.multi, solve.boat)  # fmt: skip
    ds = DeadlineSolver(factory, start_timeout=1800.0, spare=False)
    try:
        cap = {} if solve.T_cap is None else {"T_cap": solve.T_cap}
        t0 = time.perf_counter()
        res = ds.solve(solve.p, solve.w0, solve.lam_x, solve.lam_g,
                       solve.max_iter if max_iter is None else max_iter,
                       cpu_timeout=cpu_s, timeout=HANG_WALL_FACTOR * cpu_s, **cap)  # fmt: skip
        wall = time.perf_counter() - t0
    finally:
        ds.close()
    hung = not res.ok and res.status == "deadline"
    return Replayed(hung, res.status, res.iters, float(res.f), bool(res.ok), wall)


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


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "replay-solve", help="solve again the MPC solves a run abandoned as hung",
        description="Solve again, each in a fresh worker process under the hang guard's CPU "
        "time limit, the MPC solves a simulated run abandoned as hung (RUN/hung_solves.pkl, "
        "written when the metric solver_hangs is not 0): whether each hangs again, with the "
        "recorded or other solver settings (docs/mpc.md 'Known problems').",
    )  # fmt: skip
    p.add_argument("file", type=Path, help=f"a run folder's {FILE_NAME}")
    p.add_argument("--index", type=int, action="append",
                   help="replay only this solve (0-based; repeatable; default: all)")
    p.add_argument("--cpu-s", type=float, default=None,
                   help="abandon a solve after this many s of CPU time (default: the "
                        "solver.hang_s it was given)")  # fmt: skip
    p.add_argument("--max-iter", type=int, default=None,
                   help="the solve's iteration limit (default: the recorded one)")
    p.add_argument("--set", type=_setting, action="append", default=[], metavar="solver.K=V",
                   help="replace a solver setting, e.g. solver.stage_derivatives=\"inline\" "
                        "(repeatable; settings that change the problem's size are refused)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mpcasv.config import ConfigError

    if args.cpu_s is not None and not args.cpu_s > 0:
        raise ConfigError(f"--cpu-s {args.cpu_s}: must be > 0 s")
    if args.max_iter is not None and args.max_iter < 1:
        raise ConfigError(f"--max-iter {args.max_iter}: must be >= 1")
    solves = load(args.file)
    picked = range(len(solves)) if args.index is None else args.index
    for i in picked:
        if not 0 <= i < len(solves):
            raise ConfigError(f"--index {i}: {args.file} holds {len(solves)} solves "
                              f"(0..{len(solves) - 1})")  # fmt: skip
    print(f"{args.file}: {len(solves)} hung solves (recorded by mpcasv "
          f"{solves[0].version if solves else '?'})")  # fmt: skip
    again = 0
    for i in picked:
        s = with_solver(solves[i], dict(args.set))
        sp = s.params.solver
        print(f"[{i}] t = {s.t:g} s, {s.n_auv} AUV(s), {sp.solver} "
              f"({sp.stage_derivatives} derivatives), max_iter "
              f"{s.max_iter if args.max_iter is None else args.max_iter}: ", end="", flush=True)
        try:
            r = replay(s, args.cpu_s, args.max_iter)
        except RuntimeError as exc:
            raise ConfigError(f"[{i}]: {exc}") from None
        again += r.hung
        cpu = s.cpu_s if args.cpu_s is None else args.cpu_s
        print(f"hung again (abandoned after {cpu:g} s of CPU time, {r.wall_s:.1f} s wall)"
              if r.hung else f"returned in {r.wall_s:.2f} s: "
              f"{'converged' if r.ok else 'not converged'} (status {r.status}), {r.iters} "
              f"iterations, cost {r.f:.6g}")  # fmt: skip
    print(f"{again} of {len(picked)} hung again")
    return 0
