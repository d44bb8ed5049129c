"""Solving the OCP: a warm-started NLP solver (fatrop or IPOPT) behind one small interface.

:class:`NLPSolver` is built once per problem (compiled functions loaded from the disk cache)
and called every step with the parameter vector and the previous solution moved one control
period ahead (:meth:`mpcasv.mpc.problem.OCP.shift`): primal for fatrop (its CasADi interface
takes no dual start), primal and dual for IPOPT (``warm_start_init_point``). The QP variant
(:class:`mpcasv.mpc.qp.QPSolver`) has the same interface.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from mpcasv.mpc.codegen import compiled_library, thread_cflags
from mpcasv.mpc.derivatives import nlp_functions
from mpcasv.mpc.problem import OCP
from mpcasv.mpc.solver_params import SolverParams


@dataclass(frozen=True)
class SolveResult:
    """One solve: primal solution (physical units), multipliers (of the scaled problem),
    cost, status, iterations and wall time."""

    w: np.ndarray
    lam_x: np.ndarray | None
    lam_g: np.ndarray | None
    f: float
    ok: bool
    status: str
    iters: int
    ms: float


#: the options an uncompiled solver adds to :func:`solver_options`
UNCOMPILED = {"expand": True}


def solver_options(ocp: OCP, sp: SolverParams) -> dict:
    """CasADi ``nlpsol`` options of the configured solver."""
    base = {"print_time": False, "error_on_fail": False, "calc_lam_p": False}
    if sp.solver == "fatrop":
        return base | {
            "structure_detection": "auto", "equality": ocp.equality,
            "fatrop.print_level": 0, "fatrop.max_iter": sp.max_iter, "fatrop.tol": sp.tol,
            "fatrop.mu_init": sp.mu_init, "fatrop.bound_push": sp.bound_push,
            "fatrop.bound_frac": sp.bound_push,
        }  # fmt: skip
    if sp.solver == "ipopt":
        return base | {
            "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.max_iter": sp.max_iter,
            "ipopt.tol": sp.tol, "ipopt.warm_start_init_point": "yes",
            "ipopt.mu_init": sp.mu_init, "ipopt.warm_start_bound_push": sp.bound_push,
            "ipopt.warm_start_mult_bound_push": sp.bound_push, "ipopt.bound_push": sp.bound_push,
            "ipopt.bound_frac": sp.bound_push,
        }  # fmt: skip
    raise ValueError(f"not an NLP solver: {sp.solver!r}")


def nlpsol_args(ocp: OCP, p: np.ndarray, w0: np.ndarray, lam_x0: np.ndarray | None = None,
                lam_g0: np.ndarray | None = None, T_cap: float | None = None) -> dict:
    """The arguments of the CasADi ``nlpsol`` call for parameters ``p`` (shape (n_p,)) from
    the primal start ``w0`` (shape (n_w,), physical units; clipped into the bounds, scaled)
    and, when both given, the dual start (scaled multipliers); ``T_cap`` as
    :meth:`~mpcasv.mpc.problem.OCP.bounds`. One definition for :class:`NLPSolver` and the
    standalone export of a hung solve (:mod:`mpcasv.mpc.export`)."""
    lbx, ubx = ocp.bounds(p, T_cap)
    args = {"x0": np.clip(ocp.scaled(w0), lbx, ubx), "p": np.asarray(p, float), "lbx": lbx,
            "ubx": ubx, "lbg": ocp.lbg, "ubg": ocp.ubg}  # fmt: skip
    if lam_x0 is not None and lam_g0 is not None:
        args |= {"lam_x0": lam_x0, "lam_g0": lam_g0}
    return args


class NLPSolver:
    """fatrop or IPOPT on the OCP, warm-started.

    An unconverged iterate (iteration limit) still warm-starts the next solve
    (``warm_from_failures``): its gaps are small and it is closer than a rollout.

    Parameters
    ----------
    ocp : OCP
    sp : SolverParams
    log : callable
        Where the one-line compile notice goes.
    """

    warm_from_failures = True

    def __init__(self, ocp: OCP, sp: SolverParams, log=print):
        self.ocp, self.sp = ocp, sp
        self._lib = None
        if sp.compiled:
            self._lib = compiled_library(nlp_functions(ocp, sp.solver, sp.threads), sp.solver,
                                         thread_cflags(sp.cflags, sp.threads), log=log)  # fmt: skip
        #: one CasADi solver per iteration limit (the rescue solves' larger budget)
        self._solvers: dict[int, ca.Function] = {}
        self.solver = self._nlpsol(sp.max_iter)
        self.duals = sp.solver == "ipopt"
        self.last_stats: dict | None = None

    def _nlpsol(self, max_iter: int) -> ca.Function:
        if max_iter not in self._solvers:
            sp = dataclasses.replace(self.sp, max_iter=max_iter, step_iter=None)
            opts = solver_options(self.ocp, sp)
            if self._lib is not None:
                s = ca.nlpsol("mpc", sp.solver, str(self._lib), opts)
            else:  # CasADi's own derivatives of the expanded problem
                s = ca.nlpsol("mpc", sp.solver, self.ocp.nlp, opts | UNCOMPILED)
            self._solvers[max_iter] = s
        return self._solvers[max_iter]

    def solve(self, p: np.ndarray, w0: np.ndarray, lam_x0: np.ndarray | None = None,
              lam_g0: np.ndarray | None = None, max_iter: int | None = None,
              T_cap: float | None = None) -> SolveResult:  # fmt: skip
        """Solve for parameters ``p`` from the primal start ``w0`` (physical units) and the
        dual start (the solver's scaled multipliers of a previous result), within ``max_iter``
        iterations (None: ``SolverParams.max_iter``; a work budget, never a wall-time one),
        with the planned thrust capped at ``T_cap`` (N, :meth:`~mpcasv.mpc.problem.OCP.bounds`;
        None: no cap)."""
        args = nlpsol_args(self.ocp, p, w0, lam_x0 if self.duals else None,
                           lam_g0 if self.duals else None, T_cap)  # fmt: skip
        solver = self.solver if max_iter is None else self._nlpsol(max_iter)
        t0 = time.perf_counter()
        r = solver(**args)
        ms = (time.perf_counter() - t0) * 1e3
        st = solver.stats()
        self.last_stats = st  # this solve's statistics (fatrop: its timers in st["fatrop"])
        return SolveResult(
            self.ocp.physical(np.array(r["x"]).ravel()), np.array(r["lam_x"]).ravel(),
            np.array(r["lam_g"]).ravel(), float(r["f"]), bool(st["success"]),
            str(st.get("return_status", st.get("unified_return_status", "?"))),
            int(st.get("iter_count", -1)), ms,
        )  # fmt: skip


def make_solver(ocp: OCP, sp: SolverParams, log=print):
    """The configured solver: :class:`NLPSolver` or :class:`mpcasv.mpc.qp.QPSolver`."""
    if sp.solver == "qp":
        from mpcasv.mpc.qp import QPSolver

        return QPSolver(ocp, sp, log=log)
    return NLPSolver(ocp, sp, log=log)
