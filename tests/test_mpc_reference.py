"""``mpcasv bench mpc``'s yardstick, the straightforward Opti + IPOPT formulation
(:mod:`mpcasv.mpc.reference`), is the same problem as the one the default solver minimises:
its objective and its constraint rows equal those of the functions compiled for fatrop
(:func:`mpcasv.mpc.derivatives.nlp_functions`) at the same scaled variables and parameters.
Issue 16 item 8 compares their speeds, and the benchmark their costs: session 40 found the
default's receding-horizon costs 27 % below the reference's own (median, Case 3), which is a
comparison of local minima only if both evaluate one objective. (Its bounds on the variables
are tested in ``tests/test_mpc_current.py``, the current's widening included.)"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from mpcasv.controllers import load_preset, make_controller
from mpcasv.interface import ASVState, AUVEstimate, Observation
from mpcasv.mpc import bench
from mpcasv.mpc.derivatives import nlp_functions
from mpcasv.mpc.reference import OptiReference

#: (preset, AUVs at (N, E, depth) m): one AUV (the integral terminal M7i) and three (M7a)
CASES = {
    "mpc-single": ((60.0, 140.0, 20.0),),
    "mpc-multi": ((95.0, -75.0, 0.0), (-160.0, 72.0, 0.0), (-160.0, -222.0, 0.0)),
}


@pytest.mark.parametrize("preset", sorted(CASES))
def test_the_opti_reference_evaluates_the_compiled_problem(preset):
    auvs = tuple(AUVEstimate(*a) for a in CASES[preset])
    # the SX virtual machine instead of a compiled library: the functions are what counts
    ctrl = make_controller(preset, len(auvs), preset, overrides={"solver.compiled": False})
    ocp = ctrl.ocp
    ctrl.tau = np.linspace(40.0, 160.0, len(auvs))
    obs = Observation(30.0, ASVState(5.0, -10.0, 0.3, u=1.2), True, auvs)
    p = ctrl.parameters(obs)
    ref = OptiReference(ocp)
    o = ref.opti
    n = o.nx
    # the Opti variables in the OCP's stage-interleaved order (ref.w) are a permutation
    perm = np.array(ca.Function("perm", [o.x], [ref.w])(np.arange(n))).ravel().astype(int)
    assert sorted(perm) == list(range(n))
    opti_f = ca.Function("f", [o.x, o.p], [ref.J])
    opti_g = ca.Function("g", [o.x, o.p], [o.g])
    fns = nlp_functions(ocp, "fatrop")
    rng = np.random.default_rng(0)
    w0 = ocp.scaled(ocp.rollout(p))
    for k in range(3):
        w = w0 * (1 + 0.05 * k * rng.standard_normal(w0.shape)) + 0.01 * k
        x = np.empty(n)
        x[perm] = w
        f_ref, f = float(opti_f(x, p)), float(fns["nlp_f"](w, p))
        assert np.isfinite(f) and f_ref == pytest.approx(f, rel=1e-10, abs=1e-9), (k, f_ref, f)
        # every constraint row of the default's problem appears among the reference's
        g = np.array(fns["nlp_g"](w, p)).ravel()
        g_ref = np.array(opti_g(x, p)).ravel()
        gaps = np.min(np.abs(g[:, None] - g_ref[None, :]), axis=1)
        assert gaps.max() <= 1e-9 * (1 + np.abs(g).max()), (k, gaps.max())


@pytest.mark.parametrize("case,preset,multi", bench.CASES)
def test_the_full_benchmark_builds_its_qp_variant_for_every_case(case, preset, multi):
    """`mpcasv bench mpc` without --quick replays the QP variant too, with the preset's solver
    parameters but solver "qp". The several-AUV presets' step budget (``step_iter = 20``,
    session 16) is refused with the QP (its work is bounded by ``qp_iters``), so until session
    40 the full benchmark stopped at Case 6 with a validation error."""
    sp = bench.qp_params(load_preset(preset, preset).solver)
    assert (sp.solver, sp.threads, sp.step_iter) == ("qp", 1, None)
    assert sp.qp_iters == load_preset(preset, preset).solver.qp_iters
