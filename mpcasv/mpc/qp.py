"""The QP variant: the OCP linearised along the previous plan, QPs solved by OSQP.

Sequential quadratic programming without line search (a real-time-iteration flavour): at the
warm start ``w`` (the previous plan moved one control period ahead) one compiled call returns
the cost, its gradient, the constraints, their Jacobian and the Hessian of the Lagrangian;
each diagonal block of the Hessian is made positive definite by reflecting its eigenvalues
(``H_k = V max(|Lambda|, eps) V^T``: clipping them at eps instead leaves no curvature along the
negative directions, and the steps then stall at the trust region), and the QP

    min_dw  1/2 dw' H dw + grad_f' dw
    s.t.    g + J dw = 0            (gap closing)
            lbg <= g + J dw <= ubg  (path constraints)
            lbx <= w + dw <= ubx

is solved with OSQP through ``qpsolvers``, the step bounded by a box trust region (``TRUST`` in
scaled units: without it full steps can run away). The step is taken in full; ``qp_iters``
such steps are made per control step (fewer if the step is already small). The QP's
multipliers become the next Lagrangian weights.
"""

from __future__ import annotations

import time
import warnings

import casadi as ca
import numpy as np
import qpsolvers
import scipy.sparse as sps

from mpcasv.mpc.codegen import compiled_library
from mpcasv.mpc.derivatives import nlp_functions
from mpcasv.mpc.problem import OCP
from mpcasv.mpc.solver_params import SolverParams
from mpcasv.mpc.solvers import SolveResult

EIG_MIN = 1e-4  # smallest eigenvalue of a convexified Hessian block
STEP_TOL = 1e-3  # stop iterating when max |dw| is below this
FEAS_TOL = 1e-3  # gap violation accepted as solved (scaled units: 0.1 m, 1e-3 m/s, ...)
TRUST = 1.0  # step bound per SQP iteration, scaled units (100 m, 1 rad, 1 m/s, T_max / 4, ...)
QP_EPS = 1e-5  # OSQP absolute and relative tolerances


class QPSolver:
    """Linearise-and-solve with OSQP (see the module docstring); same interface as
    :class:`mpcasv.mpc.solvers.NLPSolver`."""

    #: the iterate carries over to the next step even when its gaps are not yet closed (as in
    #: a real-time iteration scheme); a non-finite one is replaced by a rollout
    warm_from_failures = True

    def __init__(self, ocp: OCP, sp: SolverParams, log=print):
        self.ocp, self.sp = ocp, sp
        funs = nlp_functions(ocp, "qp")
        if sp.compiled:
            lib = str(compiled_library(funs, "qp", sp.cflags, log=log))
            self.eval = ca.external("qp_eval", lib)
            self.fg = ca.external("qp_fg", lib)
        else:
            self.eval, self.fg = funs["qp_eval"].expand(), funs["qp_fg"].expand()
        d = ocp.dims
        self.is_eq = np.array(ocp.equality, bool)
        self.blocks = [slice(k * d.nb, (k + 1) * d.nb) for k in range(d.N)]
        self.blocks.append(slice(d.N * d.nb, d.nw))

    def _convexify(self, H: sps.csc_matrix) -> sps.csc_matrix:
        Hd = H.toarray()
        out = []
        for b in self.blocks:
            B = Hd[b, b]
            lam, V = np.linalg.eigh(0.5 * (B + B.T))
            out.append((V * np.maximum(np.abs(lam), EIG_MIN)) @ V.T)  # eigenvalues reflected
        return sps.block_diag(out, format="csc")

    def solve(self, p: np.ndarray, w0: np.ndarray, lam_x0: np.ndarray | None = None,
              lam_g0: np.ndarray | None = None, max_iter: int | None = None,
              T_cap: float | None = None) -> SolveResult:  # fmt: skip
        """Up to ``qp_iters`` full SQP steps from ``w0`` (stage 0 set to the initial state;
        ``max_iter``, the NLP solvers' rescue budget, is not used: ``qp_iters`` bounds the
        work; ``T_cap``: the planned thrust's cap, N, as :meth:`NLPSolver.solve`)."""
        ocp, sp = self.ocp, self.sp
        t0 = time.perf_counter()
        lbx, ubx = ocp.bounds(p, T_cap)
        w = np.clip(ocp.scaled(w0), lbx, ubx)  # scaled variables throughout
        lam_g = np.zeros(ocp.dims.ng) if lam_g0 is None else np.asarray(lam_g0, float)
        eq, lbg, ubg = self.is_eq, ocp.lbg, ocp.ubg
        status, its, ok = "max_iter", 0, True
        while its < sp.qp_iters:
            its += 1
            if sp.max_iter == 0:  # forced failure (tests of the fallback)
                status, ok = "max_iter 0", False
                break
            _, gf, g, J, H = self.eval(w, p, lam_g)
            g = np.array(g).ravel()
            if not all(np.all(np.isfinite(np.array(a))) for a in (gf, g, J, H)):
                status, ok = "non-finite linearisation", False
                break
            J = sps.csc_matrix(J.sparse()) if hasattr(J, "sparse") else sps.csc_matrix(J)
            P = self._convexify(sps.csc_matrix(H.sparse()))
            Ji = J[~eq]
            lo, hi = lbg[~eq] - g[~eq], ubg[~eq] - g[~eq]
            fin_lo, fin_hi = np.isfinite(lo), np.isfinite(hi)
            G = sps.vstack([-Ji[fin_lo], Ji[fin_hi]], format="csc")
            h = np.concatenate([-lo[fin_lo], hi[fin_hi]])
            with warnings.catch_warnings():  # OSQP's status is in the result
                warnings.simplefilter("ignore", UserWarning)
                # qpsolvers calls OSQP 1.x's solve() without raise_error (a failure is read
                # from the result below, as OSQP's current default does)
                warnings.filterwarnings("ignore", "The default value of raise_error",
                                        PendingDeprecationWarning)  # fmt: skip
                sol = qpsolvers.solve_problem(
                    qpsolvers.Problem(P, np.array(gf).ravel(), G, h, J[eq], -g[eq],
                                      np.maximum(lbx - w, -TRUST), np.minimum(ubx - w, TRUST)),
                    solver="osqp", eps_abs=QP_EPS, eps_rel=QP_EPS, max_iter=10000, polishing=True,
                    verbose=False,
                )  # fmt: skip
            if sol.x is None or not np.all(np.isfinite(sol.x)):
                status, ok = "qp failed", False
                break
            inaccurate = not sol.found  # e.g. OSQP "solved inaccurate": the step is still used
            dw = sol.x
            w = w + dw
            lam_g = np.zeros(ocp.dims.ng)
            lam_g[eq] = sol.y
            z = sol.z
            ineq = np.zeros(int((~eq).sum()))
            ineq[fin_lo] -= z[: fin_lo.sum()]
            ineq[fin_hi] += z[fin_lo.sum() :]
            lam_g[~eq] = ineq
            if np.max(np.abs(dw)) < STEP_TOL:
                status = "converged"
                break
            status = "inaccurate qp" if inaccurate else "max_iter"
        f, g = self.fg(w, p)
        g = np.array(g).ravel()
        viol = max(np.max(np.abs(g[eq])), np.max(np.maximum(lbg - g, 0)[~eq]),
                   np.max(np.maximum(g - ubg, 0)[~eq]))  # fmt: skip
        if ok and viol > FEAS_TOL:
            status, ok = f"infeasible ({viol:.2g})", False
        ms = (time.perf_counter() - t0) * 1e3
        return SolveResult(ocp.physical(w), None, lam_g, float(f), ok, status, its, ms)
