"""Stage-wise derivatives of the OCP, assembled along the horizon (what the solvers evaluate).

CasADi can differentiate the whole NLP, but for this stage-structured problem it is cheaper
to differentiate one stage symbolically (SX: gradient, constraint Jacobian, Hessian of the
stage Lagrangian, sharing the RK4 forward pass) and map it over the horizon: the Jacobian is
block-bidiagonal (the gap-closing ``+I`` on ``z_{k+1}`` is a constant), the Hessian block
diagonal. The resulting functions carry the names and signatures the solver plugins look
for in a compiled library (``nlpsol(name, "fatrop", "lib.so")``).
"""

from __future__ import annotations

import contextlib
import io

import casadi as ca
import numpy as np

from mpcasv.mpc.adjoint import dynamics_derivatives
from mpcasv.mpc.problem import OCP


def _stage_functions(ocp: OCP, stage: ca.Function, tag: str = "") -> dict[str, ca.Function]:
    """One stage's derivative functions (``stage``: :attr:`OCP.stage` or, tagged ``"t"``, the
    coarse tail's :attr:`OCP.stage_tail`) and the terminal cost's."""
    d = ocp.dims
    nx = d.nx
    z, v, z1 = ca.SX.sym("z", nx), ca.SX.sym("v", d.nu), ca.SX.sym("z1", nx)
    sp, sp1 = ca.SX.sym("sp", d.n_stage_par), ca.SX.sym("sp1", d.n_stage_par)
    gp = ca.SX.sym("gp", d.n_global_par)
    lf, lg = ca.SX.sym("lf"), ca.SX.sym("lg", nx + d.nh)
    L, g = stage(z, v, z1, sp, sp1, gp)
    zv = ca.vertcat(z, v)
    if tag or ocp.params.solver.stage_derivatives == "inline":
        H, grad_lag = ca.hessian(lf * L + ca.dot(lg, g), zv)
        g_J, J = g, ca.jacobian(g, zv)
    else:  # the dynamics' rows composed from the sub-steps (mpcasv.mpc.adjoint, D1-D3)
        g_J, J, H, grad_lag = _composed(ocp, L, g, z, v, z1, sp, sp1, gp, lf, lg)
    sp0 = ca.SX.sym("sp0", d.n_stage_par)
    LN = ocp.term(z, sp0, sp, gp)
    HN, dLN = ca.hessian(LN, z)
    a = [z, v, z1, sp, sp1, gp]
    return {
        "grad": ca.Function(f"st{tag}_grad", a, [L, ca.gradient(L, zv)]),
        "jac": ca.Function(f"st{tag}_jac", a, [g_J, J]),
        "hess": ca.Function(f"st{tag}_hess", [*a, lf, lg], [grad_lag, H]),
        "all": ca.Function(
            f"st{tag}_all",
            [*a, lg],
            [L, ca.gradient(L, zv), g_J, J, ca.substitute(H, lf, 1.0)],
        ),  # fmt: skip
        "term_grad": ca.Function("te_grad", [z, sp0, sp, gp], [LN, dLN]),
        "term_hess": ca.Function("te_hess", [z, sp0, sp, gp], [HN]),
    }


def _composed(ocp: OCP, L, g, z, v, z1, sp, sp1, gp, lf, lg):
    """A fine stage's constraints, their Jacobian, the Lagrangian's Hessian and gradient in
    the scaled variables (M8): the dynamics' rows ``(s_z z1 - F(s_z z, s_w w, q)) / s_z`` from
    :func:`mpcasv.mpc.adjoint.dynamics_derivatives` (``F`` too: one forward pass), the rest
    (cost, path constraints, no dynamics) differentiated as it is."""
    nx, nv = ocp.dims.nx, ocp.dims.nu
    zv = ca.vertcat(z, v)
    dyn = dynamics_derivatives(ocp)
    s_u = np.r_[ocp.s_z, ocp.s_v[0:2]]
    D, D_g = ca.DM(ca.diag(s_u)), ca.DM(ca.diag(1 / np.asarray(ocp.s_z)))
    u = ca.mtimes(D, ca.vertcat(z, v[0:2]))  # physical [z, w]
    q = ocp.q_fun(sp, sp1, gp)
    pad = ca.SX(nx, nv - 2)  # the slacks (and the epigraph variable) are not in F
    lam = ca.mtimes(D_g, lg[0:nx])  # the Lagrangian's weight on F (with a minus sign)
    F, J_F, H_F = dyn(u[0:nx], u[nx:], q, lam)
    g_dyn = ca.mtimes(D_g, ca.DM(ocp.s_z) * z1 - F)
    J_dyn = ca.horzcat(-ca.mtimes([D_g, J_F, D]), pad)
    H_u = -ca.mtimes([D, H_F, D])
    H_dyn = ca.diagcat(H_u, ca.SX(nv - 2, nv - 2))
    rest = lf * L + ca.dot(lg[nx:], g[nx:])
    H_rest, grad_rest = ca.hessian(rest, zv)
    J = ca.vertcat(J_dyn, ca.jacobian(g[nx:], zv))
    return (ca.vertcat(g_dyn, g[nx:]), J, H_rest + H_dyn,
            grad_rest + ca.mtimes(J_dyn.T, lg[0:nx]))  # fmt: skip


def _over_horizon(f: ca.Function, N: int, threads: int) -> ca.Function:
    """``f`` mapped over the ``N`` stages: a loop, or with ``threads > 1`` an OpenMP loop in
    the generated C (:func:`mpcasv.mpc.codegen.thread_cflags` sets its threads). CasADi's
    Python build has no OpenMP and warns that its own evaluation of such a map stays serial;
    that is expected (the compiled library is what runs in parallel) and the warning is
    silenced."""
    if threads <= 1:
        return f.map(N)
    with contextlib.redirect_stderr(io.StringIO()):
        return f.map(N, "openmp")


def nlp_functions(ocp: OCP, solver: str, threads: int = 1) -> dict[str, ca.Function]:
    """The functions a compiled library for ``solver`` must contain.

    ``fatrop`` and ``ipopt``: ``nlp`` and the ``nlp_*`` oracle functions of their CasADi
    plugins; ``qp``: ``qp_eval(x, p, lam_g) -> (f, grad_f, g, jac_g, hess_l)`` for the
    linearise-and-solve variant (:mod:`mpcasv.mpc.qp`). ``threads > 1`` (fatrop, ipopt):
    the stages as OpenMP loops (``SolverParams.threads``).
    """
    d = ocp.dims
    N, nx, nb, nw = d.N, d.nx, d.nb, d.nw
    ngk = nx + d.nh
    S = _stage_functions(ocp, ocp.stage)
    # the coarse tail's stages (M1t): their own functions, else the fine ones (not used)
    St = _stage_functions(ocp, ocp.stage_tail, "t") if d.n_tail else S
    x, p = ca.MX.sym("x", nw), ca.MX.sym("p", d.npar)
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", d.ng)
    args, zN, targs = ocp.horizon_args(x, p)

    def mapped(f, n):
        return _over_horizon(f, n, threads)

    def over(key, extra=(), mapper=mapped):
        """Stage derivative function ``key`` over the horizon (fine and coarse stages)."""
        return ocp.over_stages(S[key], St[key], [*args, *extra], mapper)

    Ls, Gs = ocp.over_stages(ocp.stage, ocp.stage_tail, args, mapped)
    f = ca.sum2(Ls) + ocp.term(zN, *targs)
    g = ca.vec(Gs)
    # +I on z_{k+1} in the gap-closing rows: a constant block
    rows = [k * ngk + i for k in range(N) for i in range(nx)]
    cols = [(k + 1) * nb + i for k in range(N) for i in range(nx)]
    E = ca.DM(ca.Sparsity.triplet(d.ng, nw, rows, cols), 1.0)

    def jac_of(Js):
        J = ca.diagcat(*[Js[:, k * nb : (k + 1) * nb] for k in range(N)])
        return ca.horzcat(J, ca.MX(d.ng, nx)) + E

    def hess_of(Hs, HN):
        H = ca.diagcat(*[Hs[:, k * nb : (k + 1) * nb] for k in range(N)], HN)
        return H + ca.DM(ca.Sparsity.diag(nw), 0.0)  # structural diagonal

    LG = ca.reshape(lam_g, ngk, N)
    out: dict[str, ca.Function] = {}
    xp, xpl = ["x", "p"], ["x", "p", "lam_f", "lam_g"]
    if solver in ("fatrop", "ipopt"):
        _, dLs = over("grad")
        LN, dLN = S["term_grad"](zN, *targs)
        grad_f = ca.vertcat(ca.vec(dLs), dLN)
        g2, Js = over("jac")
        gls, Hs = over("hess", (ca.repmat(lam_f, 1, N), LG))
        grad_lag = ca.vertcat(ca.vec(gls), lam_f * dLN) + ca.mtimes(E.T, lam_g)
        H = hess_of(Hs, lam_f * S["term_hess"](zN, *targs))
        out["nlp"] = ca.Function("nlp", [x, p], [f, g], xp, ["f", "g"])
        out["nlp_f"] = ca.Function("nlp_f", [x, p], [f], xp, ["f"])
        out["nlp_g"] = ca.Function("nlp_g", [x, p], [g], xp, ["g"])
        out["nlp_jac_g"] = ca.Function("nlp_jac_g", [x, p], [ca.vec(g2), jac_of(Js)], xp,
                                       ["g", "jac_g_x"])  # fmt: skip
        # parameter sensitivities are not used (calc_lam_p = False): a zero placeholder
        out["nlp_grad"] = ca.Function(
            "nlp_grad", [x, p, lam_f, lam_g], [f, g, grad_lag, ca.MX(d.npar, 1)], xpl,
            ["f", "g", "grad_gamma_x", "grad_gamma_p"],
        )  # fmt: skip
        if solver == "fatrop":
            out["nlp_grad_f"] = ca.Function("nlp_grad_f", [x, p], [grad_f], xp, ["grad_f_x"])
            out["nlp_hess_l"] = ca.Function("nlp_hess_l", [x, p, lam_f, lam_g], [grad_lag, H],
                                            xpl, ["grad_gamma_x", "hess_gamma_x_x"])  # fmt: skip
        else:
            out["nlp_grad_f"] = ca.Function("nlp_grad_f", [x, p], [f, grad_f], xp,
                                            ["f", "grad_f_x"])  # fmt: skip
            out["nlp_hess_l"] = ca.Function("nlp_hess_l", [x, p, lam_f, lam_g], [ca.triu(H)],
                                            xpl, ["triu_hess_gamma_x_x"])  # fmt: skip
    elif solver == "qp":
        Ls2, dLs, g2, Js, Hs = over("all", (LG,), lambda f, n: f.map(n))
        LN, dLN = S["term_grad"](zN, *targs)
        out["qp_eval"] = ca.Function(
            "qp_eval", [x, p, lam_g],
            [ca.sum2(Ls2) + LN, ca.vertcat(ca.vec(dLs), dLN), ca.vec(g2), jac_of(Js),
             hess_of(Hs, S["term_hess"](zN, *targs))],
            ["x", "p", "lam_g"], ["f", "grad_f", "g", "jac_g", "hess_l"],
        )  # fmt: skip
        out["qp_fg"] = ca.Function("qp_fg", [x, p], [f, g], xp, ["f", "g"])
    else:
        raise ValueError(f"no compiled functions for solver {solver!r}")
    return out
