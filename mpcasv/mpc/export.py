"""A hung solve as a standalone reproduction: CasADi and numpy only, no mpcasv
(``mpcasv replay-solve FILE --export DIR``; docs/mpc.md "Known problems").

fatrop can loop for ever in its inertia correction. A report to its authors needs the
problem without this project: :func:`export` writes one recorded :class:`~mpcasv.mpc.hung.
HungSolve` into a folder that holds

- ``nlp.casadi``: the NLP ``nlp(x, p) -> (f, g)`` as an expanded CasADi function (SX),
  saved with ``Function.save``: the MPC's problem in the solvers' scaled variables
  (:class:`~mpcasv.mpc.problem.OCP`), its derivatives left to CasADi (what ``--set
  solver.compiled=false`` solves; the compiled library is the same problem with generated
  derivative code);
- ``problem.npz``: the ``nlpsol`` call's arguments ``x0, p, lbx, ubx, lbg, ubg`` (and
  ``lam_x0, lam_g0`` when recorded), exactly those :class:`~mpcasv.mpc.solvers.NLPSolver`
  passes (:func:`~mpcasv.mpc.solvers.nlpsol_args`);
- ``options.json``: the ``nlpsol`` options of fatrop and of IPOPT for this problem
  (:func:`~mpcasv.mpc.solvers.solver_options`; fatrop's ``equality`` flags its structure);
- ``reproduce.py``: builds the solver from those three files and solves once, printing the
  return status, iterations and cost (``--solver ipopt``, ``--max-iter K``);
- ``README.md``: what it is, where it came from, the versions, how to run it.
"""

from __future__ import annotations

import dataclasses
import json
import platform
from pathlib import Path

import numpy as np

#: the standalone script written beside the problem (no mpcasv import: it must run where
#: only casadi and numpy are installed)
REPRODUCE = '''"""Solve the exported NLP once with CasADi (README.md); needs casadi, numpy."""

import argparse
import json
import time
from pathlib import Path

import casadi as ca
import numpy as np

here = Path(__file__).resolve().parent
ap = argparse.ArgumentParser(description=__doc__)
ap.add_argument("--solver", choices=("fatrop", "ipopt"), default=DEFAULT_SOLVER)
ap.add_argument("--max-iter", type=int, default=None, help="iteration limit (default: recorded)")
ap.add_argument("--print-level", type=int, default=0, help="the solver's print level")
a = ap.parse_args()

F = ca.Function.load(str(here / "nlp.casadi"))
x, p = ca.SX.sym("x", F.size1_in(0)), ca.SX.sym("p", F.size1_in(1))
f, g = F(x, p)
opts = json.loads((here / "options.json").read_text())[a.solver]
opts[a.solver + ".print_level"] = a.print_level
if a.max_iter is not None:
    opts[a.solver + ".max_iter"] = a.max_iter
solver = ca.nlpsol("hung", a.solver, {"x": x, "p": p, "f": f, "g": g}, opts)
data = np.load(here / "problem.npz")
args = {k: data[k] for k in ("x0", "p", "lbx", "ubx", "lbg", "ubg")}
if a.solver == "ipopt" and "lam_x0" in data:  # fatrop's CasADi interface takes no dual start
    args |= {"lam_x0": data["lam_x0"], "lam_g0": data["lam_g0"]}
print(f"casadi {ca.__version__}, {a.solver}, max_iter {opts[a.solver + '.max_iter']}: "
      "solving (a hang spins on a core for ever; stop it with `timeout`) ...", flush=True)
t0 = time.perf_counter()
r = solver(**args)
st = solver.stats()
print(f"returned in {time.perf_counter() - t0:.2f} s: success {st['success']}, "
      f"status {st.get('return_status', '?')}, iterations {st.get('iter_count', '?')}, "
      f"cost {float(r['f'])!r}")
'''


#: the solver settings an export can take instead of the record's (``--set solver.K=V``):
#: those its ``nlpsol`` options carry (its derivatives are always CasADi's own, so the
#: compiled library's settings do not apply)
EXPORT_SETTINGS = ("solver", "tol", "mu_init", "bound_push")


def export(solve, folder: str | Path, source: str = "", settings: dict | None = None) -> Path:
    """Write ``solve`` (a :class:`~mpcasv.mpc.hung.HungSolve` as recorded) into ``folder``
    (created; files of the same names replaced) as a reproduction that needs casadi and numpy
    only (module docstring). ``settings``: solver settings (field -> value, the fields
    :data:`EXPORT_SETTINGS`) that the exported options and ``reproduce.py``'s default solver
    take instead of the record's (its README names them). ``source``: where the record came
    from (the README says it). Returns the folder.

    Raises
    ------
    ValueError
        A setting an export cannot take, the QP variant's record or setting (no NLP to
        export), or a record whose sizes are not this version's problem's.
    ConfigError
        An invalid setting's value.
    OSError
        The folder or a file in it cannot be written.
    """
    import casadi as ca

    from mpcasv.mpc.hung import with_solver
    from mpcasv.mpc.problem import OCP
    from mpcasv.mpc.solvers import UNCOMPILED, nlpsol_args, solver_options

    settings = settings or {}
    for key in settings:
        if key not in EXPORT_SETTINGS:
            raise ValueError(f"--set solver.{key}: does not apply to an export (its "
                             "derivatives are CasADi's own; these do: "
                             f"{', '.join(EXPORT_SETTINGS)})")  # fmt: skip
    sp = with_solver(solve, settings).params.solver
    if sp.solver not in ("fatrop", "ipopt"):
        raise ValueError(f"solver {sp.solver!r}: only an NLP solver's problem (fatrop, ipopt) "
                         "can be exported")  # fmt: skip
    ocp = OCP(solve.params, solve.n_auv, outer=not solve.multi, boat=solve.boat)
    n_p, n_w = ocp.nlp["p"].numel(), ocp.nlp["x"].numel()
    if solve.p.shape != (n_p,) or solve.w0.shape != (n_w,):
        raise ValueError(f"the record's p {solve.p.shape} or w0 {solve.w0.shape} is not this "
                         f"problem's ({n_p},) and ({n_w},): written by another version")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    nlp = ca.Function("nlp", [ocp.nlp["x"], ocp.nlp["p"]], [ocp.nlp["f"], ocp.nlp["g"]],
                      ["x", "p"], ["f", "g"]).expand()  # fmt: skip
    try:
        nlp.save(str(folder / "nlp.casadi"))
    except RuntimeError as exc:  # CasADi's error: the file could not be opened
        raise OSError(f"{folder / 'nlp.casadi'}: cannot be written "
                      f"({str(exc).strip().splitlines()[-1]})") from None  # fmt: skip
    args = nlpsol_args(ocp, solve.p, solve.w0, solve.lam_x, solve.lam_g, solve.T_cap)
    np.savez(folder / "problem.npz", **{k: np.asarray(v, float).ravel() for k, v in args.items()})
    max_iter = sp.max_iter if solve.max_iter is None else solve.max_iter
    opts = {name: solver_options(ocp, dataclasses.replace(sp, solver=name, max_iter=max_iter,
                                                        step_iter=None))
            | UNCOMPILED for name in ("fatrop", "ipopt")}  # fmt: skip
    (folder / "options.json").write_text(json.dumps(opts, indent=1) + "\n")
    (folder / "reproduce.py").write_text(
        REPRODUCE.replace("DEFAULT_SOLVER", repr(sp.solver), 1))
    sizes = (n_w, int(ocp.lbg.size), n_p)
    (folder / "README.md").write_text(_readme(solve, sp, settings, source, sizes, max_iter))
    return folder


def _readme(solve, sp, settings: dict, source: str, sizes: tuple[int, int, int],
            max_iter: int) -> str:  # fmt: skip
    """The export's README: ``solve`` as recorded, ``sp`` the solver settings exported (the
    record's with ``settings``), ``sizes`` (n_x, n_g, n_p)."""
    import casadi as ca

    n_w, n_g, n_p = sizes
    rec = solve.params.solver
    other = "ipopt" if sp.solver == "fatrop" else "fatrop"
    changed = "".join(f"\n  - `{k}` = {getattr(sp, k)!r} (recorded: {getattr(rec, k)!r})"
                      for k in settings)  # fmt: skip
    note = (f"\n- Exported with other solver settings than the record's (`options.json`\n"
            f"  and `reproduce.py`'s default solver have these):{changed}\n" if changed else "")
    duals = ("(and the dual start `lam_x0, lam_g0`, passed to IPOPT only)"
             if solve.lam_x is not None and solve.lam_g is not None
             else "(no dual start was recorded)")  # fmt: skip
    return f"""# A solve that hung: a standalone reproduction

One nonlinear program of mpcasv's model-predictive controller (an autonomous surface
vehicle's plan: {solve.n_auv} AUV{'s' if solve.n_auv > 1 else ''}, a multiple-shooting
horizon of RK4 stages), exported from a run's record of a solve that was abandoned as hung
({source + ', ' if source else ''}t = {solve.t:g} s): it hung with {rec.solver} (max_iter
{max_iter}, tol {rec.tol:g}), abandoned after {solve.cpu_s:g} s of CPU time.
{note}
- `nlp.casadi`: `nlp(x[{n_w}], p[{n_p}]) -> (f, g[{n_g}])`, an SX function saved with
  CasADi's `Function.save`; derivatives are left to CasADi.
- `problem.npz`: the `nlpsol` arguments `x0, p, lbx, ubx, lbg, ubg`
  {duals}.
- `options.json`: the `nlpsol` options for fatrop (with its structure flags, `equality`)
  and for IPOPT.
- `reproduce.py`: needs only casadi and numpy; solves with {sp.solver} unless told
  otherwise.

Run it (a hung solve spins on one core and cannot be interrupted from Python; exit
status 124 means `timeout` had to stop it):

    timeout 60 python reproduce.py; echo "exit $?"
    timeout 60 python reproduce.py --max-iter {max(1, max_iter // 2)}       # fewer iterations
    timeout 60 python reproduce.py --solver {other}      # the same problem with {other}
    timeout 60 python reproduce.py --print-level 10    # the solver's iteration log

Exported with casadi {ca.__version__}, numpy {np.__version__}, Python
{platform.python_version()} on {platform.machine()} {platform.system()}. The suspected
cause in fatrop (not confirmed in its own build): `compute_search_dir` raises the Hessian
regularisation `delta_w` by `kappa_wplus` while the linear solver reports the system
indefinite, with no upper bound (IPOPT stops at `max_hessian_perturbation`), and sets the
same `delta_c` again and again while it reports the system rank-deficient.
"""
