"""The compiled libraries an MPC needs, listed before it is built (issue 12 item 8).

A sweep or a simulation asks :func:`libraries` what an MPC with these parameters will load
(the cache path, from the same functions and key as :func:`mpcasv.mpc.codegen.compiled_library`)
so that it can say which are missing, how long compiling them takes, and compile them with a
progress line before the workers start (:mod:`mpcasv.controllers.prepare`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

from mpcasv.mpc.codegen import cache_dir, compiled_library, library_path, thread_cflags
from mpcasv.mpc.derivatives import nlp_functions
from mpcasv.mpc.params import MPCParams
from mpcasv.mpc.problem import OCP

#: measured cold compile time (s) of one library on an idle machine by number of AUVs
#: (fatrop, -O3 -march=native, gcc 12 on the project's 2-core machine, session 20, the two
#: compiled side by side: 17.5 s and 27.5 s with the composed stage derivatives; 232 s and
#: 267 s differentiated inline, where gcc's register allocation of one 1.5-1.9 MB function
#: took 80 % of it; docs/mpc.md, "Known problems"): interpolated between
COLD_COMPILE_S = {1: 18.0, 3: 28.0}

#: weights that enter the problem as parameters (mpcasv.mpc.layout.WEIGHT_NAMES), not compiled
#: in: presets differing only in these share a library (tests/test_first_run.py checks it)
RUNTIME_WEIGHTS = ("age", "thrust", "power", "dT", "ddelta", "slack", "tail", "U_go",
                   "deadband", "running", "stand")  # fmt: skip
# ("accrue", the last parameter weight, is not a preset field: 1, or 0 for a step under threat)

_MEMO: dict = {}


def structure_key(params: MPCParams) -> str:
    """``params`` with the runtime weights set to fixed values (``worst`` kept only as
    whether it is positive: it adds a variable): equal keys, equal compiled library."""
    wt = params.weights
    fixed = dict.fromkeys(RUNTIME_WEIGHTS, 1.0) | {"worst": 1.0 if wt.worst > 0 else 0.0}
    return repr(dataclasses.replace(params, weights=dataclasses.replace(wt, **fixed)))


def compile_estimate(n_auv: int, n_sub: int = 4) -> float:
    """Seconds a cold compile takes on an idle machine (linear in the AUVs through the two
    points measured with 4 RK4 sub-steps per stage, and proportional to the sub-steps: a stiff
    hull's plan takes more, :attr:`~mpcasv.mpc.problem.OCP.n_sub`; a busy or slower machine
    takes longer, a faster one less; the coarse tail of M1t is not counted, nor
    ``solver.stage_derivatives = "inline"``, which takes about ten times as long)."""
    (n0, t0), (n1, t1) = sorted(COLD_COMPILE_S.items())
    return max(t0, t0 + (t1 - t0) * (n_auv - n0) / (n1 - n0)) * max(n_sub, 4) / 4


@dataclass(frozen=True)
class Library:
    """One compiled library of an MPC: where it is cached and how to build it."""

    path: Path
    label: str
    n_auv: int
    solver: str
    cflags: str
    functions: dict = field(repr=False, compare=False)
    n_sub: int = 4

    @property
    def cached(self) -> bool:
        return self.path.exists()

    @property
    def estimate_s(self) -> float:
        return compile_estimate(self.n_auv, self.n_sub)

    def compile(self, log=print) -> Path:
        """Compile (or load, if another process did meanwhile) under the cache's lock."""
        return compiled_library(self.functions, self.solver, self.cflags, log=log)


def libraries(params: MPCParams, n_auv: int, multi: bool, boat=None) -> list[Library]:
    """The libraries an :class:`~mpcasv.mpc.controller.MPCController` with these arguments
    loads (none when ``solver.compiled`` is false). Builds the OCP (a few seconds), no solver."""
    sp = params.solver
    if not sp.compiled:
        return []
    memo = (structure_key(params), n_auv, multi, repr(boat), cache_dir())
    if memo not in _MEMO:
        _MEMO[memo] = _libraries(params, n_auv, multi, boat)
    return _MEMO[memo]


def _libraries(params: MPCParams, n_auv: int, multi: bool, boat) -> list[Library]:
    sp = params.solver
    ocp = OCP(params, n_auv, outer=not multi, boat=boat)
    funs = nlp_functions(ocp, sp.solver, sp.threads)
    cflags = thread_cflags(sp.cflags, sp.threads)
    name = "mpc-multi" if multi else "mpc-single"
    label = f"{name}, {n_auv} AUV{'s' if n_auv > 1 else ''}, {sp.solver}, vessel {ocp.vessel.name}"
    return [Library(library_path(funs, sp.solver, cflags), label, n_auv, sp.solver, cflags,
                    funs, ocp.n_sub)]  # fmt: skip
