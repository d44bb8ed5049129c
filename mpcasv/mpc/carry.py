"""A bounded step: a slow solve is finished after the command (docs/mpc.md, "Controller
step" 3b; issue 16 item 8). A mixin of :class:`~mpcasv.mpc.controller.MPCController`.

With ``solver.step_iter`` set, the step's warm-started solve may take that many iterations.
Most solves converge well within it (the same plan as without the budget: the solver's
iterates do not depend on its iteration limit). One that stops there (the arrival at an AUV,
where the plan turns from transit to standby and the warm start needs 17 to more than 50
iterations; stretches of transit) is not waited for when the last converged plan, moved
one control period on (its first stage the state now), may still be followed: it passes the
safety check
(:meth:`~mpcasv.mpc.safety.Safety._check`, which looks at it against the AUVs' present
forecast, so it is allowed under a threat too), and the step is no target change (whose
exploration belongs in the step: deferring it cost Case 8 39 s of fix age, docs/mpc.md
"Controller step" 3). The step then commands that plan (source
``carried``), and everything the step would have done without the budget (the warm-started
solve with ``max_iter``, the exploration, any rescue) runs after the command
(:meth:`~mpcasv.mpc.safety.Safety.between_steps`, in the idle part of the control period),
its plan warm-starting the next step. Only iteration counts decide, never wall time: the
runs are reproduced exactly.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from mpcasv.interface import Observation
from mpcasv.mpc.solvers import SolveResult


@dataclasses.dataclass(frozen=True, slots=True)
class Deferred:
    """The work a carried step left for after its command: its observation, the parameters
    solved (``p_s``, funnel) and checked (``p``), the warm start ``w0`` and its duals
    ``lam``, and the hybrid controller's command of that step (the rescue's last guess)."""

    obs: Observation
    p_s: np.ndarray
    p: np.ndarray
    w0: np.ndarray
    lam: tuple
    hybrid_cmd: object


class Carry:
    """The step's iteration budget and the previous plan carried (mixin; state in the
    controller: ``w_ok``, whether ``w_prev`` is a converged plan; ``deferred``)."""

    def _step_limit(self) -> int | None:
        """``solver.step_iter`` when this step may carry the previous plan (a converged plan
        the safety check let through, and no target change: ``t_explore`` None), else None
        (the step's solves finish in it)."""
        cap = self.params.solver.step_iter
        if cap is None or self.w_prev is None or not self.w_ok or self.t_explore is None:
            return None
        return cap

    @staticmethod
    def _stopped(res: SolveResult, cap: int | None) -> bool:
        """Whether the solve ``res`` stopped at the step's budget ``cap`` (None: no budget;
        a missed field deadline is no stop at the budget)."""
        return (cap is not None and not res.ok and res.status != "deadline"
                and res.iters >= cap)  # fmt: skip

    def _carried(self, res: SolveResult, cap: int | None, w0: np.ndarray,
                 p: np.ndarray) -> SolveResult | None:  # fmt: skip
        """The previous plan ``w0`` (moved one period on), its first stage set to the state
        now, as this step's plan when the warm solve ``res`` stopped at the step's budget
        ``cap`` and that plan passes the safety check; else None (the step's work goes on as
        without a budget)."""
        if not self._stopped(res, cap):
            return None
        Z, V = self.ocp.split(w0)
        Z = Z.copy()
        Z[0] = self.ocp.unpack_par(p)["z0"]  # a solved plan's first stage is the state now
        carried = SolveResult(self.ocp.join(Z, V), None, None, float("nan"), True, "carried",
                              res.iters, res.ms)  # fmt: skip
        return carried if self._check(carried, p) is None else None

    def _defer(self, deferred: Deferred) -> None:
        """Leave ``deferred`` for after the command. Until it is done the next step starts
        from the carried plan, and may not carry it again (the work may be cut short: an
        exception in the deploy loop's ``between_steps``)."""
        self.deferred = deferred
        self.w_prev, self.lam_prev, self.w_ok = deferred.w0, deferred.lam, False

    def _finish_deferred(self) -> None:
        """After a carried step's command: the step's whole work without the budget; its
        plan (or unconverged iterate) warm-starts the next step, as it would have in the
        step. Its source says what the step would have done (``fallback``, ``escape``: the
        hybrid's command or the escape manoeuvre, one step later if the next step needs them
        too)."""
        d, self.deferred = self.deferred, None
        res = self._solve(d.p_s, d.w0, *d.lam)
        res, _, source = self._work(d.obs, d.p_s, d.p, res, d.hybrid_cmd)
        self._keep_start(res, source)
        self._diag |= {"mpc_deferred_iter": res.iters, "mpc_deferred_ms": res.ms,
                       "mpc_deferred_source": source, "mpc_hung": self._hung}  # fmt: skip

    def _keep_start(self, res: SolveResult, source: str) -> None:
        """The next step's warm start from this step's result (``w_ok``: a converged plan the
        safety check let through, which a later step may carry)."""
        if source == "escape":  # the escape manoeuvre's rollout: warm-starts the next step
            self.w_prev, self.lam_prev = res.w, None
        elif res.ok or (np.all(np.isfinite(res.w))
                        and getattr(self.solver, "warm_from_failures", False)):  # fmt: skip
            self.w_prev = res.w  # an unconverged NLP iterate warm-starts too
            self.lam_prev = (res.lam_x, res.lam_g) if res.ok else None
        else:
            self.w_prev, self.lam_prev = None, None  # next step starts from a rollout
        self.w_ok = bool(res.ok) and source in ("plan", "rescue", "as-escape")
        start, self._alt_start = self._alt_start, None
        if start is not None and source == "plan":  # an in-step exploration's cheaper
            self.w_prev, self.lam_prev, self.w_ok = start, None, False  # iterate (safety.py)
