"""The plan dynamics' first and second derivatives over one stage, composed from its RK4
sub-steps (a second-order adjoint; docs/mpc.md "Solvers and speed", eqs. D1-D3).

A stage ``F(z, w, q)`` (:meth:`~mpcasv.mpc.dynamics.PlanDynamics.discrete`) is ``n_sub``
sub-steps ``y_j = s(y_{j-1}, w, q, t_j)`` of ``y = [x, tau, r]`` (vessel state, fix ages and
the fix rates at the sub-step's start) from ``y_0 = [z, r(z)]``. Differentiated as one
expression, the stage's Hessian is one straight-line C function of 1.5-1.9 MB, and gcc spends
minutes allocating its registers. Here the sub-step's Jacobian and its weighted Hessian are
one inlined function each, called once per sub-step (CasADi calls, ``never_inline``), and the
stage's derivatives are their products, with ``u = [z, w]``:

    S_0 = dy_0/du,  S_j = A_j S_{j-1} + B_j E_w,  A_j = ds/dy,  B_j = ds/dw            (D1)
    mu_n = P^T lam,  mu_{j-1} = A_j^T mu_j                                            (D2)
    H = sum_j T_j^T [d2 (mu_j . s) / d(y, w)^2] T_j + E_z^T [d2 (mu_0 . y_0) / dz^2] E_z,
    T_j = [S_{j-1}; E_w]                                                              (D3)

(``P`` picks ``[x, tau]`` out of ``y``; ``E_w``, ``E_z`` pick ``w`` and ``z`` out of ``u``).
Same values as differentiating the inlined stage (to rounding), about as fast to evaluate,
and an order of magnitude faster to compile.
"""

from __future__ import annotations

import casadi as ca

from mpcasv.mpc.dynamics import NXV


def dynamics_derivatives(ocp) -> ca.Function:
    """The fine stages' dynamics of ``ocp`` (an :class:`~mpcasv.mpc.problem.OCP`) and their
    derivatives, in physical units: ``(z, w, q, lam) -> (F, J, H)`` with ``F`` the state after
    the stage ``(nx,)``, ``J = dF/d[z, w]`` ``(nx, nx + 2)`` (eq. D1) and ``H = d2 (lam . F) /
    d[z, w]^2`` ``(nx + 2, nx + 2)`` (D2-D3).

    ``z`` the plan state ``(nx,)``, ``w = [Tdot, deltadot]``, ``q`` the stage's parameters
    (:class:`~mpcasv.mpc.dynamics.PlanDynamics`), ``lam`` ``(nx,)``. One function, so that a
    caller's expression has one forward sweep (and, inlined, only the outputs it uses: a
    Jacobian alone calls no sub-step Hessian).
    """
    K, nz, n_sub = ocp.dims.n_auv, ocp.dims.nx, ocp.n_sub
    h, nq, ny = ocp.dt / n_sub, ocp.F.size1_in(2), NXV + 2 * K
    sym = ca.SX.sym
    call = {"never_inline": True}  # one body in the C, called per sub-step

    y, w, q, t0, mu = sym("y", ny), sym("w", 2), sym("q", nq), sym("t0"), sym("mu", ny)
    x1, tau1, r1 = ocp.sub_step(y[0:NXV], y[NXV : NXV + K], y[NXV + K :], w, q, t0 + h / 2,
                                t0 + h, h)  # fmt: skip
    y1 = ca.vertcat(x1, tau1, r1)
    sub_jac = ca.Function("sub_jac", [y, w, q, t0],
                          [y1, ca.jacobian(y1, y), ca.jacobian(y1, w)], call)  # fmt: skip
    sub_hess = ca.Function("sub_hess", [y, w, q, t0, mu],
                           [ca.hessian(ca.dot(mu, y1), ca.vertcat(y, w))[0]], call)  # fmt: skip
    z = sym("z", nz)
    y0 = ca.vertcat(z, ocp.start_rates(z, q))
    start_jac = ca.Function("start_jac", [z, q], [y0, ca.jacobian(y0, z)], call)
    start_hess = ca.Function("start_hess", [z, q, mu],
                             [ca.hessian(ca.dot(mu, y0), z)[0]], call)  # fmt: skip

    z, w, q, lam = sym("z", nz), sym("w", 2), sym("q", nq), sym("lam", nz)
    E_w = ca.horzcat(ca.SX(2, nz), ca.SX.eye(2))
    yj, S_z = start_jac(z, q)
    S = ca.horzcat(S_z, ca.SX(ny, 2))
    ys, Ss, As = [yj], [S], []
    for j in range(n_sub):  # (D1)
        yj, A, B = sub_jac(yj, w, q, j * h)
        S = ca.mtimes(A, S) + ca.mtimes(B, E_w)
        ys.append(yj)
        Ss.append(S)
        As.append(A)

    mu = ca.vertcat(lam, ca.SX(K, 1))  # the rates at the stage's end are not in F
    H = ca.SX(nz + 2, nz + 2)  # its upper triangle; the lower one is never computed
    for j in reversed(range(n_sub)):  # (D2-D3)
        T = ca.vertcat(Ss[j], E_w)
        H += ca.triu(ca.mtimes(T.T, ca.mtimes(sub_hess(ys[j], w, q, j * h, mu), T)))
        mu = ca.mtimes(As[j].T, mu)
    H[0:nz, 0:nz] = H[0:nz, 0:nz] + ca.triu(start_hess(z, q, mu))
    H = H + ca.triu(H, False).T
    return ca.Function("dyn", [z, w, q, lam], [yj[0:nz], S[0:nz, :], H],
                       ["z", "w", "q", "lam"], ["F", "J", "H"])  # fmt: skip
