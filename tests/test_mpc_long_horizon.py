"""The MPC's long horizon (issue 16 item 2, eq. M1t, docs/mpc.md "Long horizon"): ``tail_N``
coarse stages of ``tail_m`` fine ones after the ``N`` fine stages, each a move-blocked run of
the same plan model. Nothing here compiles C code except where said."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from mpcasv.controllers import load_preset, make_controller
from mpcasv.interface import ASVState, AUVEstimate, Observation
from mpcasv.mpc.problem import OCP

TAIL = {"horizon.tail_N": 2, "horizon.tail_m": 3}


@pytest.fixture(scope="module")
def single_tail():
    return OCP(load_preset("mpc-single", "mpc-single", TAIL), 1, outer=True)


@pytest.fixture(scope="module")
def multi_tail():
    return OCP(load_preset("mpc-multi", "mpc-multi", TAIL), 2, outer=False)


def tail_params(ocp: OCP, seed: int = 0) -> np.ndarray:
    """Parameters with the ASV under way and AUVs moving at random over the whole horizon."""
    rng = np.random.default_rng(seed)
    K, N = ocp.dims.n_auv, ocp.dims.N
    T = ocp.model.thrust_for_speed(1.5)
    x0 = np.array([0.0, 0.0, 0.3, 1.5, 0.05, 0.02, T, 0.05])
    pa = rng.uniform(-250, 250, (K, 2))[None] + ocp.t_stage[:, None, None] * rng.uniform(
        -1.0, 1.0, (K, 2))[None]  # fmt: skip
    depth = np.maximum(40.0 - 0.2 * ocp.t_stage[:, None], 0.0) * np.ones(K)
    return ocp.pack(x0, rng.uniform(0, 200, K), (0.1, -0.05), pa, np.full((N + 1, K), 55.0),
                    np.full((N + 1, K), 195.0), depth, np.zeros(K), np.full(K, 80.0),
                    target=K - 1)  # fmt: skip


def test_the_stage_grid_is_fine_then_coarse_and_the_default_is_unchanged(single_tail):
    """15 stages of 4 s, then 2 of 12 s: 84 s. Without a tail the grid is the uniform one."""
    assert single_tail.dims.N == 17 and single_tail.dims.n_tail == 2
    np.testing.assert_array_equal(single_tail.dts, [4.0] * 15 + [12.0] * 2)
    assert single_tail.t_stage[15] == 60.0 and single_tail.t_stage[-1] == 84.0
    plain = OCP(load_preset("mpc-single", "mpc-single"), 1, outer=True)
    assert plain.dims.n_tail == 0 and plain.stage_tail is None
    np.testing.assert_array_equal(plain.t_stage, 4.0 * np.arange(16))


@pytest.mark.parametrize("which", ["single_tail", "multi_tail"])
def test_a_coarse_stage_is_tail_m_fine_stages_with_the_rates_held(request, which):
    """M1t: the coarse stage's end state, cost and path constraints against ``tail_m`` fine
    stages evaluated one after the other under the same rates, on stage parameters
    interpolated linearly across the coarse stage."""
    ocp: OCP = request.getfixturevalue(which)
    d, m = ocp.dims, ocp.tail_m
    rng = np.random.default_rng(3)
    p = tail_params(ocp, seed=1)
    w = ocp.rollout(p, rates=rng.normal(0, 0.2, (d.N, 2)))
    Z, V = ocp.split(w)
    args, _, _ = ocp.horizon_args(ca.DM(ocp.scaled(w)), ca.DM(p))
    SP, GP = np.array(args[3]), np.array(args[5])
    k = d.N - 1  # the last coarse stage
    sp, sp1, gp = SP[:, k], np.array(args[4])[:, k], GP[:, k]
    z, v = Z[k], V[k]
    L_t, g_t = (np.array(a).ravel() for a in ocp.stage_tail_phys(z, v, Z[k + 1], sp, sp1, gp))
    zj, L, h0 = z, 0.0, None
    for j in range(m):
        spj, spn = sp + j / m * (sp1 - sp), sp + (j + 1) / m * (sp1 - sp)
        Lj, gj = (np.array(a).ravel() for a in ocp.stage_phys(zj, v, np.zeros(d.nx), spj, spn,
                                                              gp))  # fmt: skip
        h0 = gj[d.nx :] if j == 0 else h0
        L, zj = L + float(Lj[0]), -gj[: d.nx]  # g = z1 - F(z, v): with z1 = 0, -F
    np.testing.assert_allclose(Z[k + 1] - zj, g_t[: d.nx], rtol=1e-10, atol=1e-8)
    assert abs(g_t[: d.nx]).max() < 1e-8  # the rollout advanced the coarse stage the same way
    assert float(L_t[0]) == pytest.approx(L, rel=1e-12)
    np.testing.assert_allclose(g_t[d.nx :], h0, rtol=1e-12)  # range bounds at its start
    # and it is not one fine stage: the 12-s stage moves the ASV three times as far
    L1, g1 = (np.array(a).ravel() for a in ocp.stage_phys(z, v, np.zeros(d.nx), sp, sp1, gp))
    assert np.hypot(*(zj[0:2] - z[0:2])) > 2.5 * np.hypot(*(-g1[0:2] - z[0:2]))


@pytest.mark.parametrize("which", ["single_tail", "multi_tail"])
@pytest.mark.parametrize("solver", ["fatrop", "qp"])
def test_stagewise_derivatives_with_a_tail_equal_casadis_differentiation(request, which, solver):
    """The derivative functions the compiled library holds (fine and coarse stages mapped
    apart, F called, not inlined, in the coarse ones) against CasADi's differentiation of the
    whole NLP."""
    from test_mpc_problem import check_stagewise_derivatives

    ocp: OCP = request.getfixturevalue(which)
    check_stagewise_derivatives(ocp, tail_params(ocp, seed=2), solver)


def test_a_rollout_with_a_tail_closes_every_gap(multi_tail):
    p = tail_params(multi_tail, seed=4)
    w = multi_tail.rollout(p, rates=np.random.default_rng(0).normal(0, 0.2,
                                                                 (multi_tail.dims.N, 2)))
    g = np.array(ca.Function("g", [multi_tail.nlp["x"], multi_tail.nlp["p"]],
                             [multi_tail.nlp["g"]])(multi_tail.scaled(w), p)).ravel()
    eq = np.array(multi_tail.equality)
    assert np.max(np.abs(g[eq])) < 1e-9


def test_the_warm_start_moves_on_by_time_across_the_coarse_stages(single_tail):
    """A plan whose north position equals its stage time, moved on by 1.5 fine stages (6 s):
    every stage reads the plan 6 s later (12-s stages included), the end held."""
    ocp = single_tail
    Z, V = ocp.split(ocp.rollout(tail_params(ocp)))
    Z[:, 0] = ocp.t_stage
    V[:, 0] = ocp.t_stage[:-1]
    Z1, V1 = ocp.split(ocp.shift(ocp.join(Z, V), 1.5))
    np.testing.assert_allclose(Z1[:, 0], np.minimum(ocp.t_stage + 6.0, ocp.t_stage[-1]))
    np.testing.assert_allclose(V1[:, 0], np.minimum(ocp.t_stage[:-1] + 6.0, ocp.t_stage[-2]))
    lam = np.tile(ocp.t_stage[:-1, None], (1, ocp.dims.nx + ocp.dims.nh)).ravel()
    lam1 = ocp.shift_lam_g(lam, 1.5).reshape(ocp.dims.N, -1)
    np.testing.assert_allclose(lam1[:, 0], np.minimum(ocp.t_stage[:-1] + 6.0, ocp.t_stage[-2]))


def test_a_controller_with_a_tail_plans_three_minutes_and_solves_every_step():
    """Closed loop (CasADi's fatrop on the uncompiled problem): an AUV 300 m off drifting
    away; 20 steps of 1 s. Every step's plan converges (no fallback) and reaches 180 s."""
    ctrl = make_controller("mpc-single", 1, "mpc-single",
                           {"solver.compiled": False, "horizon.tail_N": 6, "horizon.tail_m": 5})
    ctrl.reset(1)
    for k in range(20):
        t = float(k)
        obs = Observation(t, ASVState(0.0, 0.0, 0.0), False,
                          (AUVEstimate(300.0 + 0.5 * t, 0.0, 30.0, 0.5, 0.0),))  # fmt: skip
        ctrl.step(obs)
        assert ctrl.plan.t[-1] - t == pytest.approx(180.0)
    assert not ctrl.fallbacks, ctrl.fallbacks
