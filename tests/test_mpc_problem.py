"""The MPC's optimal control problem: shared dynamics, fix-age model, derivatives, layout.

Nothing here compiles C code: the derivative functions are evaluated by CasADi's virtual
machine and compared with CasADi's own differentiation of the whole NLP.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from mpcasv.controllers import load_preset
from mpcasv.models.acoustics import AcousticParams
from mpcasv.mpc.codegen import library_key
from mpcasv.mpc.derivatives import nlp_functions
from mpcasv.mpc.problem import NXV, OCP, channel_vector
from mpcasv.mpc.smooth import sigmoid


@pytest.fixture(scope="module")
def single():
    return OCP(load_preset("mpc-single", "mpc-single"), 1, outer=True)


@pytest.fixture(scope="module")
def multi():
    return OCP(load_preset("mpc-multi", "mpc-multi"), 3, outer=False)


def params_for(ocp: OCP, seed: int = 0, speed: float = 1.5, T: float | None = None):
    """A parameter vector with the ASV under way and AUVs at random places."""
    rng = np.random.default_rng(seed)
    d = ocp.dims
    K, N = d.n_auv, d.N
    T = ocp.model.thrust_for_speed(speed) if T is None else T
    x0 = np.array([0.0, 0.0, 0.3, speed, 0.05, 0.02, T, 0.05])
    pa0 = rng.uniform(-250, 250, (K, 2))
    va = rng.uniform(-1.5, 1.5, (K, 2))
    pa = pa0[None] + ocp.dt * np.arange(N + 1)[:, None, None] * va[None]
    return ocp.pack(x0, rng.uniform(0, 200, K), (0.1, -0.05), pa, np.full((N + 1, K), 55.0),
                    np.full((N + 1, K), 195.0), np.zeros(K), np.full(K, 80.0),
                    np.full(K, 70.0), target=K - 1)  # fmt: skip


def test_plan_dynamics_are_the_shared_model_with_actuators_at_their_set_points(single):
    """No second copy of the equations: with zero rates the plan's vessel part is the shared
    model's RK4 with the input held at the current thrust and steering."""
    p = params_for(single)
    z0 = single.unpack_par(p)["z0"]
    q = single._q(single.unpack_par(p), 0)
    hz = single.params.horizon
    shared = single.model.rk4(hz.dt, hz.n_sub)(z0[:NXV], z0[6:8], q[0:2])
    plan = single.F(z0, [0.0, 0.0], q)
    np.testing.assert_allclose(np.array(plan).ravel()[:NXV], np.array(shared).ravel(),
                               rtol=1e-12, atol=1e-12)  # fmt: skip


@pytest.mark.parametrize("which", ["single", "multi", "variance"])
def test_fix_age_discretisation_matches_a_fine_integration_of_the_continuous_model(request, which):
    """``OCP.F`` (RK4 for the vessel, the fix ages by exponential Simpson quadrature of the
    rate) against 64 RK4 sub-steps of the continuous model ``OCP.rhs`` (M1-M3), at random
    states, rates, currents and AUV tracks within 60 m (where the fix rate changes): the
    vessel is the same RK4 to rounding, and the fix ages agree as closely as RK4 on the
    coupled system with the stage's sub-steps did (its p99 error here: 4.5-5.2 s)."""
    from mpcasv.models.vessel import rk4_expr

    if which == "variance":
        params = load_preset("mpc-multi", "mpc-multi-variance")
        ocp = OCP(params, 3, outer=False)
    else:
        ocp = request.getfixturevalue(which)
    d, K, vp = ocp.dims, ocp.dims.n_auv, ocp.vessel
    z, w, q = ca.SX.sym("z", d.nx), ca.SX.sym("w", 2), ca.SX.sym("q", ocp.F.size1_in(2))
    za = ca.SX.sym("za", d.nx + 1)
    f = ca.Function("f", [za, w, q], [ocp.rhs(za, w, q)])
    fine = ca.Function("fine", [z, w, q], [rk4_expr(f, ca.vertcat(z, 0), w, q, ocp.dt, 64)[:d.nx]])
    coarse = ca.Function("coarse", [z, w, q],
                         [rk4_expr(f, ca.vertcat(z, 0), w, q, ocp.dt, ocp.n_sub)[:d.nx]])
    rng = np.random.default_rng(1)
    ch = channel_vector(AcousticParams())
    nav = q.numel() - (2 + 7 * K + len(ch))
    err, err_coupled, vessel = [], [], []
    for _ in range(400):
        zz = np.r_[rng.uniform(-60, 60, 2), rng.uniform(-3, 3), rng.uniform(0, vp.u_max),
                   rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2),
                   rng.uniform(vp.T_min, vp.T_max), rng.uniform(-1, 1) * vp.delta_max,
                   rng.uniform(0, 600, K)]  # fmt: skip
        ww = rng.uniform(-1, 1, 2) * [ocp.dT_max, ocp.dd_max]
        qq = np.r_[rng.uniform(-0.15, 0.15, 2), rng.uniform(-60, 60, 2 * K),
                   rng.uniform(-1, 1, 2 * K), rng.uniform(0, 60, K), rng.uniform(-0.5, 0.5, K),
                   rng.uniform(20, 100, K), ch, [1.0, 0.02, 0.05][:nav]]  # fmt: skip
        ref = np.asarray(fine(zz, ww, qq)).ravel()
        got = np.asarray(ocp.F(zz, ww, qq)).ravel()
        err.append(np.abs(got - ref)[NXV:])
        err_coupled.append(np.abs(np.asarray(coarse(zz, ww, qq)).ravel() - ref)[NXV:])
        vessel.append(np.abs(got - np.asarray(coarse(zz, ww, qq)).ravel())[:NXV].max())
    assert max(vessel) < 1e-9
    p99, p99_coupled = np.percentile(err, 99), np.percentile(err_coupled, 99)
    assert p99 < 1.25 * p99_coupled + 0.1, (p99, p99_coupled)
    assert np.median(err) < 1e-6


def test_thrust_and_steering_follow_their_rates(single):
    p = params_for(single)
    par = single.unpack_par(p)
    z1 = np.array(single.F(par["z0"], [10.0, -0.02], single._q(par, 0))).ravel()
    assert z1[6] == pytest.approx(par["z0"][6] + 10.0 * single.dt)
    assert z1[7] == pytest.approx(par["z0"][7] - 0.02 * single.dt)


def test_expected_fix_age_relaxes_when_quiet_in_range_and_grows_otherwise(single, multi):
    """Eq. M2-M3 with the channel's numbers: propeller off next to the AUV, tau tends to
    1 / (p_good / T0); at full thrust it grows by the elapsed time (only quiet fixes count:
    the presets, and Paper 2 eq. 9's reliable fix), or with noisy fixes counted tends to
    1 / (propeller_factor p_good / T0); beyond d2 nothing gets through."""
    ac = AcousticParams()
    N = single.dims.N
    x0 = np.zeros(NXV)
    pa = np.tile([[[60.0, 0.0]]], (N + 1, 1, 1))

    def ages(ocp, x0, pa, d_fix=70.0, channel=None):
        K = ocp.dims.n_auv
        p = ocp.pack(x0, np.full(K, 300.0), (0, 0), np.repeat(pa, K, axis=1),
                     np.full((N + 1, K), 50.0), np.full((N + 1, K), 2000.0), np.full(K, 20.0),
                     np.full(K, d_fix), np.full(K, 70.0), channel=channel)  # fmt: skip
        return ocp.split(ocp.rollout(p))[0]

    Z = ages(single, x0, pa)
    assert Z[-1, NXV] == pytest.approx(ac.T0 / ac.p_good, rel=0.05)
    assert np.all(np.diff(Z[:, NXV]) < 0)
    loud = x0.copy()
    loud[6] = single.vessel.T_max
    np.testing.assert_allclose(np.diff(ages(single, loud, pa)[:, NXV]), single.dt, rtol=0.02)
    Z = ages(single, loud, pa, channel=channel_vector(ac, noisy=True))
    assert Z[-1, NXV] == pytest.approx(ac.T0 / (ac.p_good * ac.propeller_factor), rel=0.1)
    Zm = ages(multi, loud, pa)
    np.testing.assert_allclose(np.diff(Zm[:, NXV]), multi.dt, rtol=0.02)
    far = np.tile([[[ac.d2 + 200.0, 0.0]]], (N + 1, 1, 1))
    np.testing.assert_allclose(np.diff(ages(single, x0, far)[:, NXV]), single.dt, rtol=0.02)
    # another channel (status reports only, every 60 s): the exact relaxation from 300 s
    slow = channel_vector(AcousticParams(usbl=False, T_report=60.0))
    Z = ages(single, x0, pa, channel=slow)
    rho = ac.p_good / 60.0 * sigmoid(single.T_quiet / single.w_T)  # T = 0
    horizon = N * single.dt
    expected = 1 / rho + (300.0 - 1 / rho) * np.exp(-rho * horizon)
    assert Z[-1, NXV] == pytest.approx(expected, rel=0.005)


@pytest.mark.parametrize("which", ["single", "multi"])
@pytest.mark.parametrize("solver", ["fatrop", "ipopt", "qp"])
def test_stagewise_derivatives_equal_casadis_differentiation_of_the_nlp(request, which, solver):
    ocp: OCP = request.getfixturevalue(which)
    check_stagewise_derivatives(ocp, params_for(ocp, seed=2), solver)


def check_stagewise_derivatives(ocp: OCP, p: np.ndarray, solver: str) -> None:
    """The compiled library's functions for ``solver`` (evaluated by CasADi's virtual machine)
    against CasADi's differentiation of the whole NLP, at a perturbed rollout for ``p``."""
    rng = np.random.default_rng(1)
    w = ocp.scaled(ocp.rollout(p, rates=rng.normal(0, 0.2, (ocp.dims.N, 2))))
    w += rng.normal(0, 0.01, w.size)
    lam = rng.normal(0, 1, ocp.dims.ng)
    x, pp = ocp.nlp["x"], ocp.nlp["p"]
    lag = 0.7 * ocp.nlp["f"] + ca.dot(ca.DM(lam), ocp.nlp["g"])
    H_ref, g_ref = ca.hessian(lag, x)
    ref = ca.Function("ref", [x, pp], [ocp.nlp["f"], ca.gradient(ocp.nlp["f"], x), ocp.nlp["g"],
                                       ca.jacobian(ocp.nlp["g"], x), g_ref, H_ref])  # fmt: skip
    f0, gf0, g0, J0, gl0, H0 = (np.array(a.full()) for a in ref(w, p))
    funs = nlp_functions(ocp, solver)
    if solver == "qp":
        f, gf, g, J, H = funs["qp_eval"](w, p, lam)
        H_lam1 = ca.Function(
            "h", [x, pp], [ca.hessian(ocp.nlp["f"] + ca.dot(ca.DM(lam), ocp.nlp["g"]), x)[0]]
        )
        np.testing.assert_allclose(np.array(H.full()), np.array(H_lam1(w, p).full()),
                                   rtol=1e-9, atol=1e-9)  # fmt: skip
        np.testing.assert_allclose(float(f), f0.item(), rtol=1e-12)
        np.testing.assert_allclose(np.array(gf.full()), gf0, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(np.array(g.full()), g0, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(np.array(J.full()), J0, rtol=1e-9, atol=1e-9)
        return
    g, J = funs["nlp_jac_g"](w, p)
    np.testing.assert_allclose(np.array(g.full()), g0, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(np.array(J.full()), J0, rtol=1e-9, atol=1e-9)
    out = funs["nlp_hess_l"](w, p, 0.7, lam)
    if solver == "fatrop":
        gl, H = out
        np.testing.assert_allclose(np.array(gl.full()), gl0, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(np.array(H.full()), H0, rtol=1e-9, atol=1e-9)
        gf = funs["nlp_grad_f"](w, p)
    else:
        np.testing.assert_allclose(np.array(out.full()), np.triu(H0), rtol=1e-9, atol=1e-9)
        _, gf = funs["nlp_grad_f"](w, p)
    np.testing.assert_allclose(np.array(gf.full()), gf0, rtol=1e-9, atol=1e-9)


def test_layout_roundtrips(multi):
    p = params_for(multi, seed=3)
    w = multi.rollout(p)
    np.testing.assert_allclose(multi.physical(multi.scaled(w)), w)
    np.testing.assert_allclose(multi.join(*multi.split(w)), w)
    np.testing.assert_allclose(multi.shift(w, 0.0), w)
    Z, V = multi.split(w)
    Z1, V1 = multi.split(multi.shift(w, 1.0))
    np.testing.assert_allclose(Z1[:-1], Z[1:])
    np.testing.assert_allclose(V1[:-1], V[1:])
    assert multi.unpack_par(p)["target"] == multi.dims.n_auv - 1


def test_rollout_slacks_make_every_path_constraint_hold(single):
    p = params_for(single, seed=4)
    w = single.rollout(p)
    g = np.array(ca.Function("g", [single.nlp["x"], single.nlp["p"]], [single.nlp["g"]])(
        single.scaled(w), p)).ravel()  # fmt: skip
    ineq = ~np.array(single.equality)
    assert np.all(g[ineq] >= single.lbg[ineq] - 1e-9)
    assert np.all(g[ineq] <= single.ubg[ineq] + 1e-9)
    assert np.max(np.abs(g[~ineq])) < 1e-9  # a rollout closes every gap


def test_cache_key_ignores_weights_but_not_the_horizon():
    P = load_preset("mpc-single", "mpc-single")
    a = nlp_functions(OCP(P, 1, True), "fatrop")
    b = nlp_functions(OCP(load_preset("mpc-single", "mpc-single", {"weights.thrust": 0.9}),
                          1, True), "fatrop")  # fmt: skip
    c = nlp_functions(OCP(load_preset("mpc-single", "mpc-single", {"horizon.N": 14}), 1, True),
                      "fatrop")  # fmt: skip
    assert library_key(a, "fatrop", "-O1") == library_key(b, "fatrop", "-O1")
    assert library_key(a, "fatrop", "-O1") != library_key(c, "fatrop", "-O1")
    assert library_key(a, "fatrop", "-O1") != library_key(a, "fatrop", "-O2")


_COMPILE_ONE = """
import sys, casadi as ca
from mpcasv.mpc.codegen import compiled_library
x = ca.SX.sym("x")
compiled_library({"sq": ca.Function("sq", [x], [x * x])}, "locktest", "-O0",
                 log=lambda m: print("COMPILED", m))
"""


def test_parallel_processes_compile_a_library_once(tmp_path):
    """Two workers needing the same library at once: one compiles, the other waits and loads."""
    import os
    import subprocess
    import sys

    env = os.environ | {"MPCASV_CACHE": str(tmp_path)}
    procs = [subprocess.Popen([sys.executable, "-c", _COMPILE_ONE], env=env,
                              stdout=subprocess.PIPE, text=True) for _ in range(3)]  # fmt: skip
    outs = [p.communicate(timeout=120)[0] for p in procs]
    assert all(p.returncode == 0 for p in procs)
    assert sum(o.count("COMPILED") for o in outs) == 1
    assert len(list((tmp_path / "mpc").glob("mpc_locktest_*.so"))) == 1


def test_a_compile_killed_by_a_signal_leaves_no_folder_behind(tmp_path):
    """A compile ended by SIGKILL/SIGTERM runs no cleanup: its temporary folder (the C, some
    MB) stayed in the cache for ever. The next compile removes it, and any other library's
    whose lock is free, but not the folder of a compile in progress."""
    import os
    import subprocess
    import sys
    import time

    env = os.environ | {"MPCASV_CACHE": str(tmp_path)}
    slow = _COMPILE_ONE.replace('"-O0"', '"-O0 -DSLEEP"').replace(
        "compiled_library(", "import mpcasv.mpc.codegen as cg, time\n"
        "cg.subprocess.run = lambda *a, **k: time.sleep(3600)\ncompiled_library(")
    p = subprocess.Popen([sys.executable, "-c", slow], env=env)
    folder = tmp_path / "mpc"
    deadline = time.monotonic() + 60
    while not list(folder.glob("mpc_locktest_*.tmp*")) and time.monotonic() < deadline:
        time.sleep(0.1)
    p.kill()  # inside the (stand-in) compiler call
    p.wait()
    left = list(folder.glob("mpc_locktest_*.tmp*"))
    assert len(left) == 1 and left[0].is_dir()  # what a killed compile leaves
    stem = left[0].name.split(".tmp")[0]
    # another library's killed compile (its lock free) and one being compiled now (held)
    (folder / "mpc_fatrop_killed.tmpab12").mkdir()
    (folder / "mpc_fatrop_busy.tmpcd34").mkdir()
    import fcntl

    with open(folder / "mpc_fatrop_busy.so.lock", "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        out = subprocess.run([sys.executable, "-c",
                              _COMPILE_ONE.replace('"-O0"', '"-O0 -DSLEEP"')],
                             env=env, capture_output=True, text=True, timeout=120)  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert (folder / f"{stem}.so").exists()  # the same library, compiled now
    assert not list(folder.glob("mpc_locktest_*.tmp*"))
    assert not (folder / "mpc_fatrop_killed.tmpab12").exists()  # removed: nobody compiles it
    assert (folder / "mpc_fatrop_busy.tmpcd34").is_dir()  # kept: its compile is running


def _rk4_gain(z: complex) -> float:
    """|R(z)| of classical RK4 on y' = lambda y with z = lambda h."""
    return abs(1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24)


@pytest.mark.parametrize("vessel, n_sub", [("gretha", 4), ("dune-otter", 4), ("otter", 24)])
def test_the_plan_takes_enough_rk4_sub_steps_for_the_vessels_fastest_pole(vessel, n_sub):
    """The plan's RK4 sub-step is stable on every decaying rigid-body pole of the run's vessel
    over its manoeuvring envelope: straight-line trims from rest to top speed and full-steering
    turns (mpcasv.models.envelope). Fossen's Otter is stiff in a turn (16.5 1/s here): with the
    presets' 4 sub-steps, or the 6 its straight-line poles need (session 5's rule), decaying
    perturbations grow (the gain below exceeds 1) and a turning stage went NaN; the plan takes
    24 there, and the presets' 4 everywhere else (Gretha: the default problems are unchanged).
    (The Otter's hull is also straight-line unstable, +2.6 1/s at top speed: a growing mode RK4
    must follow, not damp, so it is left out of the check. By default its plan closes the yaw
    loop instead, with sub-steps from that loop's poles: tests/test_mpc_heading.py.)"""
    from mpcasv.controllers import Boat
    from mpcasv.models.envelope import trim_states, turn_states

    P = load_preset("mpc-single", "mpc-single", {"horizon.steering": "rudder"})
    ocp = OCP(P, 1, outer=True, boat=Boat.load(vessel))
    assert ocp.n_sub == n_sub
    h = ocp.dt / ocp.n_sub
    gains, gains_6 = [], []
    for x in np.vstack([trim_states(ocp.model), turn_states(ocp.model)])[::4]:
        lam = np.linalg.eigvals(ocp.model.linearize(x, x[6:8])[0][:6, :6])
        lam = lam[lam.real < -1e-9]  # decaying modes: RK4 must not make them grow
        gains += [_rk4_gain(complex(v) * h) for v in lam]
        gains_6 += [_rk4_gain(complex(v) * ocp.dt / 6) for v in lam]
    assert max(gains) < 1.0
    assert (max(gains_6) > 1.0) == (vessel == "otter")
