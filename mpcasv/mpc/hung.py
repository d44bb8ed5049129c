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

The file is a Python pickle: open only files you trust (a pickle can run code when loaded),
and it loads with the mpcasv code that wrote it (its classes; the problem is rebuilt from the
recorded parameters, so a version whose problem differs refuses the record's sizes, and one
whose problem has the same sizes but other equations is named by the replay: each record
keeps the problem's digest, :func:`problem_digest`). The command line is
:mod:`mpcasv.mpc.hung_cli`.
Solves abandoned in a ``falsify`` search's trials are not kept (only its reruns write run
folders), nor those of the field mode (a deadline there is not a hang).
"""

from __future__ import annotations

import dataclasses
import functools
import pickle
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: the file a run folder keeps its hung solves in
FILE_NAME = "hung_solves.pkl"
#: the hang guard (and a replay): a solve's worker that has used no CPU at all for this many
#: times its CPU-time limit (``solver.hang_s``), and at least ``HANG_IDLE_MIN_S``, of wall
#: time is abandoned too (a worker stopped or blocked; a hung fatrop spins and is caught by
#: its CPU time; a starved one still gets some CPU)
HANG_WALL_FACTOR = 20.0
HANG_IDLE_MIN_S = 30.0


def idle_limit(cpu_s: float) -> float:
    """Seconds of wall time without any CPU used after which a solve given ``cpu_s`` s of CPU
    time is abandoned (:meth:`mpcasv.mpc.deadline.DeadlineSolver.solve`)."""
    return max(HANG_WALL_FACTOR * cpu_s, HANG_IDLE_MIN_S)


@dataclass(frozen=True)
class HungSolve:
    """One solve abandoned by the hang guard: what the worker was sent, and its problem.

    Any solve of the step (the warm-started one, an exploration, a rescue: the controller
    solves with the same call). ``p`` (shape (n_p,)) the problem's parameters, ``w0`` (shape
    (n_w,)) the initial guess (physical units), ``lam_x``/``lam_g`` the warm-start multipliers
    of the scaled problem (None: none); ``max_iter``
    the solve's iteration limit (None: ``solver.max_iter``); ``T_cap`` the planned thrust's
    cap (N; None: none); ``cpu_s`` the CPU time it was given (s); ``t`` the step's time (s).
    ``params``, ``n_auv``, ``multi`` and ``boat`` rebuild the same problem
    (:func:`mpcasv.mpc.controller.build_ocp`) if this version's problem is the same:
    ``problem`` is the digest that says so (:func:`same_problem`).
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
    #: :func:`problem_digest` of the problem that hung ("": a record written before session 32)
    problem: str = ""


def problem_digest(ocp) -> str:
    """SHA-256 (hex, 16 characters) of an OCP's NLP (cost and constraints as functions of the
    decision variables and parameters, CasADi's serialisation: a few ms): equal digests, the
    same problem. A change of the problem's equations that keeps its sizes (session 32's
    guard in the plan's dynamics) changes it."""
    import hashlib

    import casadi as ca

    nlp = ocp.nlp
    f = ca.Function("nlp", [nlp["x"], nlp["p"]], [nlp["f"], nlp["g"]])
    return hashlib.sha256(f.serialize().encode()).hexdigest()[:16]


def same_problem(solve: HungSolve) -> bool | None:
    """Whether the problem rebuilt here from ``solve``'s record is the one that hung (None: the
    record has no digest, written before session 32)."""
    if not solve.problem:
        return None
    from mpcasv.mpc.problem import OCP

    ocp = OCP(solve.params, solve.n_auv, outer=not solve.multi, boat=solve.boat)
    return problem_digest(ocp) == solve.problem


def load(path: str | Path) -> list[HungSolve]:
    """The hung solves in ``path`` (a pickled list of :class:`HungSolve`, written by
    :func:`mpcasv.sim.record.write_run`), each record checked.

    Raises
    ------
    ConfigError
        One line: not such a file (not a pickle, or not a list of well-formed
        :class:`HungSolve`), or one that names mpcasv classes this version does not have.
    OSError
        The file cannot be read.
    """
    from mpcasv.config import ConfigError

    with open(path, "rb") as f:
        try:
            solves = pickle.load(f)
        except (AttributeError, ImportError) as exc:
            if "mpcasv" in str(exc) or "HungSolve" in str(exc):
                raise ConfigError(f"{path}: written by another version of mpcasv, whose "
                                  f"classes do not load here ({exc})") from None  # fmt: skip
            raise ConfigError(f"{path}: not a file of hung solves ({exc})") from None
        except Exception as exc:  # a pickle of garbage fails in many ways
            raise ConfigError(f"{path}: not a file of hung solves ({type(exc).__name__}: "
                              f"{exc}); it is the {FILE_NAME} of a run folder") from None
    if not isinstance(solves, list) or not all(isinstance(s, HungSolve) for s in solves):
        raise ConfigError(f"{path}: not a file of hung solves (a pickle of something else); "
                          f"it is the {FILE_NAME} of a run folder")  # fmt: skip
    for i, s in enumerate(solves):
        problem = _malformed(s)
        if problem:
            raise ConfigError(f"{path}: hung solve {i} is malformed ({problem}): written by "
                              "another version of mpcasv, or not by mpcasv")  # fmt: skip
    return solves


def _malformed(s: HungSolve) -> str | None:
    """What is wrong with record ``s`` (None: nothing)."""
    from mpcasv.mpc.params import MPCParams

    try:
        if not isinstance(s.params, MPCParams):
            return "params is not an MPCParams"
        if not (isinstance(s.n_auv, int) and s.n_auv >= 1 and isinstance(s.multi, bool)):
            return "n_auv or multi"
        for name in ("p", "w0", "lam_x", "lam_g"):
            a = getattr(s, name)
            if (a is not None or name in ("p", "w0")) and not (
                    isinstance(a, np.ndarray) and a.ndim == 1 and a.dtype == float):
                return f"{name} is not a 1-D float array"  # fmt: skip
        if s.max_iter is not None and not isinstance(s.max_iter, int):
            return "max_iter"
        if not (isinstance(s.cpu_s, float | int) and s.cpu_s > 0):
            return "cpu_s"
        if not isinstance(s.problem, str):
            return "problem is not a digest"
    except AttributeError as exc:  # a record of another layout
        return str(exc)
    return None


#: the solver settings a replay may change (``--set solver.K=V``): those that reach the
#: solver's call; the others act in the controller (iteration budgets of other solves, the
#: plan check) or are options of the command (``max_iter``: ``--max-iter``; ``hang_s``:
#: ``--cpu-s``)
REPLAY_SETTINGS = ("solver", "compiled", "cflags", "threads", "tol", "mu_init", "bound_push",
                   "qp_iters", "stage_derivatives")  # fmt: skip


def with_solver(solve: HungSolve, settings: dict) -> HungSolve:
    """``solve`` with ``settings`` (field of ``solver`` -> value, e.g. ``{"stage_derivatives":
    "inline"}``; the fields :data:`REPLAY_SETTINGS`) replacing its preset's solver settings.

    Raises
    ------
    ConfigError
        Another field (one line saying which option sets it, if any), or an invalid value.
    """
    from mpcasv.config import ConfigError, replace

    for key in settings:
        if key in ("max_iter", "hang_s"):
            opt = "--max-iter" if key == "max_iter" else "--cpu-s"
            raise ConfigError(f"--set solver.{key}: use {opt} to replay with another limit")
        if key not in REPLAY_SETTINGS:
            raise ConfigError(f"--set solver.{key}: not a setting a replay can change "
                              f"(these reach the solver: {', '.join(REPLAY_SETTINGS)})")
    try:
        new = replace(solve.params.solver, **settings)
    except ConfigError as exc:
        msg = "; ".join(x.strip() for x in str(exc).splitlines()[1:] if x.strip())
        raise ConfigError(f"--set: {msg}") from None
    return dataclasses.replace(solve, params=dataclasses.replace(solve.params, solver=new))


@dataclass(frozen=True)
class Replayed:
    """The outcome of :func:`replay`: ``hung`` (abandoned again; ``by_cpu``: after its CPU-time
    limit, else because it used no CPU for :func:`idle_limit` s), else the solver's
    ``status`` (as the solver names it: fatrop's return code, IPOPT's or the QP variant's
    word), ``iters``, cost ``f`` and ``ok`` (the solver's: an NLP solver's convergence, the QP
    variant's feasible plan, :func:`verdict`); ``wall_s`` the wall time of the solve alone
    (s)."""

    hung: bool
    by_cpu: bool
    status: str
    iters: int
    f: float
    ok: bool
    wall_s: float


def replay(solve: HungSolve, cpu_s: float | None = None, max_iter: int | None = None,
           factory=None) -> Replayed:  # fmt: skip
    """Solve ``solve`` again in a fresh worker process (its compiled library loaded from the
    cache, compiled first if missing) and abandon it, as the hang guard does, after ``cpu_s``
    s of the worker's CPU time (None: the time it was given, ``solve.cpu_s``), or once it has
    used no CPU for :func:`idle_limit` s. ``max_iter``: another iteration
    limit (None: the recorded one). ``factory`` (tests): builds the worker's solver (default:
    the recorded problem's).

    Raises
    ------
    RuntimeError
        The worker could not build the solver, or the solve failed in it (an exception, e.g.
        parameters of another size than the problem's; or the worker died).
    """
    from mpcasv.mpc.controller import worker_solver
    from mpcasv.mpc.deadline import DeadlineSolver

    cpu_s = solve.cpu_s if cpu_s is None else cpu_s
    factory = factory or functools.partial(worker_solver, solve.params, solve.n_auv,
                                           solve.multi, solve.boat)  # fmt: skip
    ds = DeadlineSolver(factory, start_timeout=1800.0, spare=False)
    try:
        cap = {} if solve.T_cap is None else {"T_cap": solve.T_cap}
        res = ds.solve(solve.p, solve.w0, solve.lam_x, solve.lam_g,
                       solve.max_iter if max_iter is None else max_iter,
                       cpu_timeout=cpu_s, timeout=idle_limit(cpu_s), **cap)  # fmt: skip
        error, abandon = ds.last_error, ds.last_abandon
    finally:
        ds.close()
    if error is not None:
        raise RuntimeError(f"the solve failed in the worker: {(error.splitlines() or ['?'])[0]}")
    wall = res.ms / 1e3  # the solve alone (not the successor worker started after a hang)
    hung = not res.ok and res.status == "deadline"
    by_cpu = hung and abandon == "cpu"
    return Replayed(hung, by_cpu, res.status, res.iters, float(res.f), bool(res.ok), wall)


def verdict(solver: str, r: Replayed) -> str:
    """What a returned replay ``r`` of a solve by ``solver`` (``solver.solver``) says, in its
    variant's terms: an NLP solver's (fatrop's, IPOPT's) ``ok`` is convergence; the QP
    variant's (:meth:`mpcasv.mpc.qp.QPSolver.solve`) is a feasible plan (its gaps closed to
    ``FEAS_TOL``), converged only if its last step was below ``STEP_TOL`` (status
    "converged"), else its ``qp_iters`` steps were all made (status "max_iter", "inaccurate
    qp": the last QP solved inaccurately)."""
    if solver != "qp":
        return f"{'converged' if r.ok else 'not converged'} (status {r.status})"
    if not r.ok:
        return f"no feasible plan (status {r.status})"
    if r.status == "converged":
        return "feasible, converged (status converged: its last step below tolerance)"
    why = {"max_iter": ": its qp_iters steps made",
           "inaccurate qp": ": its qp_iters steps made, the last QP solved inaccurately"}
    return f"feasible, not converged (status {r.status}{why.get(r.status, '')})"
