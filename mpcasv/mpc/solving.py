"""Where the MPC's solves run (docs/mpc.md, "Controller"; issue 16). A mixin of
:class:`~mpcasv.mpc.controller.MPCController`.

:class:`Solving` owns the solver-running machinery: the choice between solving in this
process, in the simulation's hang guard's worker (:meth:`Solving.use_hang_guard`: a solve is
abandoned only when hung, judged by its worker's CPU time) and in the field mode's worker
(:meth:`Solving.use_deadline`: a solve is abandoned at the step's wall-time budget, less
:data:`STEP_RESERVE_S`), one solve (:meth:`Solving._solve`), the step's wall-time budget
(:meth:`Solving._over_budget`, :meth:`Solving._left`) and stopping the workers
(:meth:`Solving.close`). What the controller does with a solve's result is elsewhere
(:mod:`mpcasv.mpc.controller`, :mod:`mpcasv.mpc.safety`, :mod:`mpcasv.mpc.carry`).
"""

from __future__ import annotations

import functools
import time

import numpy as np

from mpcasv.mpc.deadline import DeadlineSolver
from mpcasv.mpc.hung import HungSolve, idle_limit, problem_digest
from mpcasv.mpc.solvers import SolveResult

#: field mode: part of the step's budget kept for the fallback and the command after a
#: missed solve deadline (s)
STEP_RESERVE_S = 0.03


class Solving:
    """The solver-running part of :class:`~mpcasv.mpc.controller.MPCController`: where its
    solves run (this process, the hang guard's worker, the field mode's worker), one solve,
    the step's wall-time budget, and stopping the workers. Uses the controller's
    ``params``, ``ocp``, ``solver``, ``multi``, ``boat``, ``T_cap``, ``t_prev``, ``_t_step``,
    ``_hung`` and ``hung_solves``; keeps the workers in ``deadline`` (None: solves in this
    process; the controller's constructor starts with None), with ``_deadline_n`` (the AUVs
    the workers' problem serves) and ``_hang_guard`` (the workers are the hang guard's)."""

    def use_deadline(self, factory=None, start_timeout: float = 600.0,
                     spare: bool = True) -> None:  # fmt: skip
        """Field mode: every step's solves run in a worker process and are abandoned at the
        step's budget ``solver.budget_ms`` (the step then takes the hybrid fallback's command,
        reason ``deadline``; the next step starts warm from the previous plan, on a spare
        worker). Set by the deploy loop; in simulation only through :meth:`use_hang_guard`
        (no spare, a CPU-time limit instead of the budget: iteration limits decide and wall
        time is only measured, ``mpc_over_budget``, so runs are reproducible).

        ``factory`` (tests): builds the worker's solver (default: this controller's problem,
        its compiled library loaded from the cache). Blocks until the first worker is ready.
        ``spare``: keep a spare worker ready (:class:`~mpcasv.mpc.deadline.DeadlineSolver`;
        False for the simulation's hang guard).

        Raises
        ------
        RuntimeError
            The worker could not build the solver within ``start_timeout`` s.
        """
        # the worker's default solver: built like the controller's (its module imports this)
        from mpcasv.mpc.controller import worker_solver

        if self.deadline is not None:
            self.deadline.close()
        factory = factory or functools.partial(worker_solver, self.params, self.ocp.dims.n_auv,
                                               self.multi, self.boat)  # fmt: skip
        self.deadline = DeadlineSolver(factory, start_timeout, spare)
        self._deadline_n = self.ocp.dims.n_auv
        self._hang_guard = False

    def use_hang_guard(self) -> None:
        """Simulation: the solves run in a worker process and only one on which the worker
        has spent ``solver.hang_s`` s of CPU time (or that has used no CPU for
        :func:`~mpcasv.mpc.hung.idle_limit` s: a worker stopped or blocked) is abandoned
        (:class:`~mpcasv.mpc.solver_params.SolverParams`; ``hang_s = 0``: solves stay in this
        process, unguarded)."""
        if not self.params.solver.hang_guard:
            self.close()
            return
        self.use_deadline(spare=False)  # no spare: a hang is rare, and wall time decides nothing
        self._hang_guard = True

    def close(self) -> None:
        """Stop the solver workers (the field mode's or the hang guard's; none: no-op)."""
        if self.deadline is not None:
            self.deadline.close()
            self.deadline = None

    def _solve(self, p: np.ndarray, w0: np.ndarray, lam_x=None, lam_g=None,
               max_iter: int | None = None) -> SolveResult:  # fmt: skip
        """One solve (``max_iter``: this solve's iteration limit, None: ``solver.max_iter``):
        in this process (``hang_s = 0``: only the iteration limit decides), in the hang
        guard's worker (simulation: abandoned only after ``solver.hang_s`` s of its CPU time,
        then kept in :attr:`hung_solves`), or in the field mode's worker with what is left of
        this step's budget."""
        # the speed cap's thrust bound (passed only when set: no cap, the calls as before)
        cap = {} if self.T_cap is None else {"T_cap": self.T_cap}
        if self.deadline is None:
            if max_iter is None and not cap:
                return self.solver.solve(p, w0, lam_x, lam_g)
            return self.solver.solve(p, w0, lam_x, lam_g, max_iter, **cap)
        if self._hang_guard:  # simulation: abandon only a hung solve (SolverParams.hang_s),
            hang_s = self.params.solver.hang_s  # judged by its worker's CPU time, not the load
            res = self.deadline.solve(p, w0, lam_x, lam_g, max_iter, cpu_timeout=hang_s,
                                      timeout=idle_limit(hang_s), **cap)  # fmt: skip
            if not res.ok and res.status == "deadline":  # counted, never hidden, and kept
                self._hung += 1  # for a replay (mpcasv replay-solve)
                self.hung_solves.append(HungSolve(
                    self.t_prev, self.params, self.ocp.dims.n_auv, self.multi, self.boat,
                    *(None if a is None else np.array(a, float) for a in (p, w0, lam_x, lam_g)),
                    max_iter, self.T_cap, hang_s, problem_digest(self.ocp)))  # fmt: skip
            return res
        return self.deadline.solve(p, w0, lam_x, lam_g, max_iter, timeout=self._left(), **cap)

    def _over_budget(self) -> int:
        """1 if more than ``budget_ms`` of wall time has passed since ``_t_step`` (a
        diagnostic in simulation, never a decision), else 0."""
        return int((time.perf_counter() - self._t_step) * 1e3 > self.params.solver.budget_ms)

    def _left(self) -> float:
        """Field mode: seconds left of this step's solve budget."""
        return (self.params.solver.budget_ms / 1e3 - STEP_RESERVE_S
                - (time.perf_counter() - self._t_step))  # fmt: skip
