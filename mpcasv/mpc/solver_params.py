"""Parameters of the MPC's solver: which one, its iteration and wall-time budgets, and the
safety check's triggers (frozen, validated from the ``[solver]`` section of the ``mpc-*.toml``
presets; docs/mpc.md "Solvers and speed", "Fallbacks", "Controller step" 3b).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, Strict

from mpcasv.config import Flag, NonNeg, Pos, PosInt, frozen

SolverName = Literal["fatrop", "ipopt", "qp"]


@frozen
class SolverParams:
    """Which solver, its limits, and the safety fallback's triggers.

    Attributes
    ----------
    solver : {"fatrop", "ipopt", "qp"}
        ``fatrop``: CasADi's structure-exploiting interior-point solver (default); ``ipopt``;
        ``qp``: the model linearised along the previous plan, QPs solved by OSQP (qpsolvers).
    compiled : bool
        Generate C code for the NLP functions, compile it once and cache it on disk
        (``$MPCASV_CACHE`` or ``~/.cache/mpcasv``); False evaluates CasADi's SX virtual
        machine (slower, no compiler needed).
    cflags : str
        Compiler flags of the cached library (``-march=native``: the cache key includes the
        CPU model).
    threads : int
        Threads that evaluate the horizon's stages (the functions, their Jacobian and
        Hessian: about three quarters of a solve, docs/mpc.md "Benchmark") in the compiled
        library: 1 (default) a plain loop; more, an OpenMP loop (``-fopenmp``; another
        library). The results are the same bit for bit: each stage is evaluated alone and the
        sums are taken afterwards in the same order. For a field computer with a core to
        spare; in ``simulate`` and ``compare`` parallel runs use the cores better. Needs
        ``compiled`` and ``fatrop`` or ``ipopt``.
    max_iter : int
        Iteration limit of the NLP solver (0 forces a failure: the fallback test).
    tol : float
        Convergence tolerance of the NLP solver.
    mu_init : float
        Initial barrier parameter (warm-started interior point).
    bound_push : float
        How far the interior-point solver moves the start into the interior of the bounds
        (absolute and relative: ``bound_push`` and ``bound_frac``). IPOPT's default 1e-2 pushes a
        warm start off its active bounds (thrust 0, slacks 0) and costs iterations; with
        ``mu_init = 1e-4`` and 1e-6 fatrop needs 5 instead of 9 iterations on the Case 3
        sequence (``mpcasv bench mpc``).
    qp_iters : int
        SQP iterations of the ``qp`` variant per step (1 = real-time iteration).
    budget_ms : float
        Wall-time budget of one control step's solves (ms). In the field
        (:meth:`~mpcasv.mpc.solving.Solving.use_deadline`, set by the deploy loop) a
        hard deadline: the solve runs in a worker process and is abandoned at the budget (the
        hybrid fallback commands that step). In simulation it decides nothing (runs are
        reproduced exactly under any load): a step over it is only counted
        (``mpc_over_budget``); ``max_iter`` bounds the work.
    hang_s : float
        Hang guard in simulation (s of CPU time; 0 = none): the solves run in a worker
        process and one on which the worker has spent ``hang_s`` s of CPU time is abandoned
        as hung (status ``deadline``; the step is then rescued or falls back, docs/mpc.md
        "Fallbacks"). fatrop loops forever in its inertia correction on rare ill-conditioned
        iterates (docs/mpc.md "Known problems"), spinning on a core. CPU time, not wall time:
        a solve slowed by the machine's load is not abandoned, so a run that meets a hang is
        reproduced under load too (the hang itself is deterministic; the limits of this claim:
        :mod:`mpcasv.mpc.deadline`). Normal solves take milliseconds to under a second with
        200 rescue iterations. The limit counts all the worker's threads (``threads``). A
        worker that uses no CPU at all for 20 times ``hang_s`` (at least 30 s) of wall time
        is abandoned as well (one stopped or blocked: :func:`mpcasv.mpc.hung.idle_limit`).
    rescue_iter : int
        Iteration limit of the rescue solves (docs/mpc.md, "Fallbacks"): when the plan of the
        warm-started solve cannot be used (iteration limit, or it goes deeper into an
        anti-collision radius) the MPC solves again from the unconverged iterate, an escape
        guess and the hybrid controller's command, each within this many iterations, before
        it hands the step to the hybrid controller. A work budget, like ``max_iter``: on the
        Case 6 run (seed 0) every one of the 54 solves stopped at 50 iterations converged
        within 200 (median 76). 0 forces failures (tests).
    explore_iter : int or None
        Iteration limit of the exploration solve (docs/mpc.md, "Controller step"; None:
        ``max_iter``): it starts from a guess far from the warm-started plan, and an
        unconverged one is discarded. A third of the explorations stop at 50; 150 was
        measured on the paper suite (session 9) and was no better in the closed loop, with
        longer solves: the default stays ``max_iter``.
    step_iter : int or None
        Iterations the step's warm-started solve may take before the step follows the
        previous plan instead (None or 0, read as None: off, every solve finishes in the
        step; the several-AUV presets set 20, the one-AUV ones none; docs/mpc.md
        "Controller step" 3b; issue 16 item 8). A work budget, not a wall-time one, below
        ``max_iter``. When that solve stops at ``step_iter`` iterations, the step is no
        target change, and the last converged plan moved one period on passes the safety
        check, the step commands that plan (source ``carried``) and the step's whole work
        (the warm-started solve with ``max_iter``, the exploration, any rescue) is done after
        the command (``between_steps``), its plan warm-starting the next step. A solve that
        converges within ``step_iter`` gives the same plan as without the budget.
    check_stages : int
        Stages of the plan checked against r_inner / r_avoid before it is used.
    check_margin : float
        Tolerance of that check (m): the soft constraints may be violated by this much.
    max_violation : float
        The ASV is this far (m) outside the plan's range bounds now (beyond r_outer, or inside
        r_inner / r_avoid, margins included): the bounds of that AUV are relaxed along a
        funnel that closes at ``funnel_speed`` (:func:`mpcasv.mpc.rescue.funnel`) and the
        problem is solved. Before (issue 16 item 7) such a step went to the hybrid controller
        without a solve (Case 5, seed 1: 53 of 57 fallbacks). Unrelaxed, such a gap (an AUV
        estimate that jumped hundreds of metres when a report arrived, Case 5) makes the
        exact-penalty problem badly scaled; fatrop then met NaNs and never returned
        (``mpcasv compare mpc-dT``, Case 5, seed 1: 186 m beyond r_outer). Inside the donut
        the gap cannot exceed r_inner + margin, so for the shipped domains (50 m) the rule
        acts beyond r_outer only.
    funnel_speed : float
        Speed (m/s) at which the relaxed bounds of ``max_violation`` close in over the horizon.
    stage_derivatives : {"composed", "inline"}
        How a fine stage's dynamics are differentiated: ``composed`` (default since session
        20) from each RK4 sub-step's Jacobian and Hessian (:mod:`mpcasv.mpc.adjoint`, eqs.
        D1-D3: a library compiles about ten times faster); ``inline``: the stage as one
        expression (before; the same values to rounding, another compiled library).
    """

    solver: SolverName = "fatrop"
    compiled: Flag = True
    cflags: str = "-O3 -march=native"
    threads: PosInt = 1
    max_iter: Annotated[int, Strict(), Field(ge=0)] = 50
    tol: Pos = 1e-4
    mu_init: Pos = 1e-4
    bound_push: Pos = 1e-6
    qp_iters: PosInt = 10
    budget_ms: Pos = 200.0
    hang_s: NonNeg = 10.0
    rescue_iter: Annotated[int, Strict(), Field(ge=0)] = 200
    explore_iter: Annotated[int, Strict(), Field(ge=0)] | None = None
    step_iter: Annotated[int, Strict(), Field(ge=0)] | None = None
    check_stages: PosInt = 2
    check_margin: NonNeg = 2.0
    max_violation: Pos = 60.0
    funnel_speed: Pos = 1.25
    stage_derivatives: Literal["composed", "inline"] = "composed"

    @property
    def hang_guard(self) -> bool:
        """Whether simulation's solves run in a worker process of their own (``hang_s > 0``):
        a process that may not start one, a daemon such as a Dask worker under its nanny,
        cannot run this MPC (:data:`mpcasv.mpc.deadline.DAEMON_REFUSED`)."""
        return self.hang_s > 0

    def __post_init__(self) -> None:
        if self.step_iter == 0:  # TOML has no null: 0 is how a preset or override says "off"
            object.__setattr__(self, "step_iter", None)
        if self.threads > 1 and not (self.compiled and self.solver in ("fatrop", "ipopt")):
            raise ValueError("threads > 1 needs compiled = true and solver 'fatrop' or 'ipopt' "
                             "(the stages run in parallel in the compiled library only)")
        if self.step_iter is not None and self.step_iter >= self.max_iter:
            raise ValueError(f"step_iter ({self.step_iter}) must be below max_iter "
                             f"({self.max_iter}): a solve stopped there is finished with "
                             "max_iter after the command")
        if self.step_iter is not None and self.solver == "qp":
            raise ValueError("step_iter needs solver 'fatrop' or 'ipopt' (the qp variant's "
                             "work is bounded by qp_iters)")
