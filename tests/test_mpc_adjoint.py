"""The stage dynamics' derivatives composed from the RK4 sub-steps (mpcasv.mpc.adjoint, eqs.
D1-D3) against CasADi's differentiation of the stage as one expression, and what the
composition is for: far less C to compile."""

from __future__ import annotations

import dataclasses
import os

import casadi as ca
import numpy as np
import pytest
from test_mpc_problem import params_for

from mpcasv.controllers import load_preset
from mpcasv.mpc.adjoint import dynamics_derivatives
from mpcasv.mpc.derivatives import _stage_functions
from mpcasv.mpc.problem import OCP

CASES = {  # (controller, preset, AUVs, overrides)
    "single": ("mpc-single", "mpc-single", 1, None),
    "multi": ("mpc-multi", "mpc-multi", 3, None),
    "variance": ("mpc-multi", "mpc-multi-variance", 2, None),  # rates depend on the ages (M2')
    "heading": ("mpc-single", "mpc-single", 1, {"horizon.steering": "heading"}),  # M1h
}


def _ocp(case: str, kind: str = "composed") -> OCP:
    name, preset, K, over = CASES[case]
    prm = load_preset(name, preset, over)
    prm = dataclasses.replace(prm, solver=dataclasses.replace(prm.solver, stage_derivatives=kind))
    return OCP(prm, K, outer=name == "mpc-single")


def _stage_point(ocp: OCP, seed: int):
    """A physical (z, w, q) at stage 3 of a perturbed rollout, and multipliers."""
    rng = np.random.default_rng(seed)
    p = params_for(ocp, seed=seed)
    W = ocp.rollout(p, rates=rng.normal(0, 0.2, (ocp.dims.N, 2)))
    W = W + rng.normal(0, 0.01, W.size) * ocp.s_w
    nb, nx, k = ocp.dims.nb, ocp.dims.nx, 3
    z, w = W[k * nb : k * nb + nx], W[k * nb + nx : k * nb + nx + 2]
    args, _, _ = ocp.horizon_args(ca.DM(ocp.scaled(W)), ca.DM(p))
    sp, sp1, gp = (np.array(ca.evalf(a[:, k])).ravel() for a in args[3:6])
    q = np.array(ocp.q_fun(sp, sp1, gp)).ravel()
    return z, w, q, rng.normal(0, 1, nx)


@pytest.mark.parametrize("case", list(CASES))
def test_composed_dynamics_derivatives_equal_casadis_of_the_stage(case):
    ocp = _ocp(case)
    dyn = dynamics_derivatives(ocp)
    nx, nq = ocp.dims.nx, ocp.F.size1_in(2)
    z, w, q, lam = (ca.SX.sym(n, m) for n, m in (("z", nx), ("w", 2), ("q", nq), ("lam", nx)))
    F = ocp.F(z, w, q)
    u = ca.vertcat(z, w)
    H = ca.hessian(ca.dot(lam, F), u)[0]
    ref = ca.Function("ref", [z, w, q, lam], [F, ca.jacobian(F, u), H])
    for seed in (0, 1):
        pt = _stage_point(ocp, seed)
        F0, J0, H0 = (np.array(a) for a in ref(*pt))
        F1, J1, H1 = (np.array(a) for a in dyn(*pt))
        np.testing.assert_allclose(F1, F0, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(J1, J0, rtol=1e-9, atol=1e-9 * np.abs(J0).max())
        np.testing.assert_allclose(H1, H0, rtol=1e-9, atol=1e-9 * np.abs(H0).max())
        assert np.abs(H0).max() > 0  # the test compares something


@pytest.mark.parametrize("case", ["single", "variance"])
def test_the_composed_stage_functions_have_the_inline_ones_values_and_structure(case):
    """What fatrop sees: the same sparsity (its structure) and the same numbers."""
    comp, inl = (_stage_functions(o, o.stage) for o in (_ocp(case), _ocp(case, "inline")))
    rng = np.random.default_rng(3)
    for key in ("jac", "hess"):
        fc, fi = comp[key], inl[key]
        for i in range(fi.n_out()):
            assert fc.sparsity_out(i) == fi.sparsity_out(i)
        args = [rng.uniform(-1, 1, fi.size_in(i)) for i in range(fi.n_in())]
        for a, b in zip(fc(*args), fi(*args), strict=True):
            np.testing.assert_allclose(np.array(a), np.array(b), rtol=1e-12, atol=1e-12)


def test_the_composed_stage_hessian_is_a_fraction_of_the_c_to_compile(tmp_path):
    """The compile time is gcc's register allocation of the stage Hessian, one straight-line
    function (docs/mpc.md, "Known problems"): composed, its generated C is far smaller."""
    sizes = {}
    for kind in ("composed", "inline"):
        ocp = _ocp("single", kind)
        gen = ca.CodeGenerator(f"st_{kind}.c")
        gen.add(_stage_functions(ocp, ocp.stage)["hess"])
        gen.generate(str(tmp_path) + os.sep)
        sizes[kind] = (tmp_path / f"st_{kind}.c").stat().st_size
    assert sizes["composed"] < sizes["inline"] / 2.5, sizes
