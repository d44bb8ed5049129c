"""The straightforward formulation: the same OCP written with ``casadi.Opti``, solved by IPOPT.

What one would write first: one Opti variable per stage state and control, the stage functions
of :class:`~mpcasv.mpc.problem.OCP` called per stage, constraints added one by one, IPOPT with
its default settings (exact Hessian from CasADi's own differentiation of the MX graph, no code
generation), warm-started from the previous solution through ``set_initial``. It is the
benchmark's reference for cost (tight default tolerance) and speed.
"""

from __future__ import annotations

import math
import time

import casadi as ca
import numpy as np

from mpcasv.mpc.problem import OCP
from mpcasv.mpc.solvers import SolveResult


class OptiReference:
    """Opti + IPOPT on the problem of ``ocp`` (same interface as the other solvers)."""

    def __init__(self, ocp: OCP, ipopt_options: dict | None = None):
        self.ocp = ocp
        d = ocp.dims
        N, nx = d.N, d.nx
        opti = ca.Opti()
        Z = [opti.variable(nx) for _ in range(N + 1)]
        V = [opti.variable(d.nu) for _ in range(N)]
        P = opti.parameter(d.npar)
        o = nx + 2
        SP = ca.reshape(P[o : o + (N + 1) * d.n_stage_par], d.n_stage_par, N + 1)
        o += (N + 1) * d.n_stage_par
        gp = ca.vertcat(P[nx : nx + 2], P[o : o + d.n_global_par - 2])
        lb, ub = ocp.lbx, ocp.ubx  # scaled, stage-interleaved
        # the ground speeds' bounds widened by the current's speed, as OCP.bounds does
        widen = ca.sqrt(P[nx] ** 2 + P[nx + 1] ** 2) / ocp.s_z
        J = 0
        opti.subject_to(Z[0] == P[:nx] / ocp.s_z)
        for k in range(N):
            stage = ocp.stage if k < N - d.n_tail else ocp.stage_tail  # (M1t) coarse tail
            L, g = stage(Z[k], V[k], Z[k + 1], SP[:, k], SP[:, k + 1], gp)
            J += L
            opti.subject_to(g[:nx] == 0)
            h, lo, hi = g[nx:], ocp.lbg[nx : nx + d.nh], ocp.ubg[nx : nx + d.nh]
            for i in range(d.nh):
                if math.isfinite(lo[i]):
                    opti.subject_to(h[i] >= lo[i])
                if math.isfinite(hi[i]):
                    opti.subject_to(h[i] <= hi[i])
            base = k * d.nb
            self._bounds(opti, V[k], lb[base + nx : base + d.nb], ub[base + nx : base + d.nb])
            if k > 0:
                self._bounds(opti, Z[k], lb[base : base + nx], ub[base : base + nx], widen)
        self._bounds(opti, Z[N], lb[N * d.nb :], ub[N * d.nb :], widen)
        J += ocp.term(Z[N], SP[:, N - 1], SP[:, N], gp)
        opti.minimize(J)
        opts = {"print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes"}
        opti.solver("ipopt", opts | (ipopt_options or {}))
        parts = []
        for k in range(N):
            parts += [Z[k], V[k]]
        self.w = ca.vertcat(*parts, Z[N])
        self.opti, self.P, self.J = opti, P, J

    @staticmethod
    def _bounds(opti, x, lo, hi, widen=None) -> None:
        """``lo <= x <= hi``; with ``widen`` (a state's: MX, scaled) the ground speeds u and v
        (entries 3 and 4) by that much more on each side (:meth:`OCP.bounds`)."""
        for i in range(x.numel()):
            if widen is not None and i in (3, 4):
                opti.subject_to(opti.bounded(lo[i] - widen[i], x[i], hi[i] + widen[i]))
                continue
            if math.isfinite(lo[i]) and math.isfinite(hi[i]):
                opti.subject_to(opti.bounded(lo[i], x[i], hi[i]))
            elif math.isfinite(lo[i]):
                opti.subject_to(x[i] >= lo[i])
            elif math.isfinite(hi[i]):
                opti.subject_to(x[i] <= hi[i])

    def solve(self, p: np.ndarray, w0: np.ndarray, lam_x0=None, lam_g0=None) -> SolveResult:
        """Solve for parameters ``p`` from the primal start ``w0`` (physical units)."""
        self.opti.set_value(self.P, p)
        self.opti.set_initial(self.w, self.ocp.scaled(w0))
        t0 = time.perf_counter()
        sol = self.opti.solve_limited()
        ms = (time.perf_counter() - t0) * 1e3
        st = sol.stats()
        w = self.ocp.physical(np.array(sol.value(self.w)).ravel())
        return SolveResult(w, None, None, float(sol.value(self.J)), bool(st["success"]),
                           str(st["return_status"]), int(st["iter_count"]), ms)  # fmt: skip
