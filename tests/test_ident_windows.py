"""The identification's residual Jacobians: the replay windows' forward sensitivities
(:mod:`mpcasv.models.ident_windows`) against CasADi's automatic differentiation of the whole
replay (the formulation they replaced), and the equation error's per-sample derivative
against central differences."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from mpcasv.control.manoeuvres import simulate_manoeuvre
from mpcasv.models.ident_windows import Windows
from mpcasv.models.identify import IDENTIFIED, Problem, prepare
from mpcasv.models.params import MODEL_COEFFS, load_vessel
from mpcasv.models.vessel import IX, NX, VesselModel, rk4_expr


def _step(prior, dt):
    """RK4 of the shared model, symbolic in two scale factors and the current."""
    th = ca.SX.sym("th", 4)
    p0 = prior.vector()
    entries = [ca.SX(float(v)) for v in p0]
    for j, name in enumerate(("X_u", "N_rdot")):
        entries[MODEL_COEFFS.index(name)] = float(p0[MODEL_COEFFS.index(name)]) * th[j]
    p = ca.vertcat(*entries)
    model = VesselModel(prior)
    x, u = ca.SX.sym("x", NX), ca.SX.sym("u", 2)
    xn = rk4_expr(lambda x_, u_, c_: model.f_param(x_, u_, c_, p), x, u, th[2:], dt)
    return ca.Function("step", [x, u, th], [xn])


def test_window_sensitivities_equal_casadi_ad_of_the_replay():
    prior = load_vessel("gretha")
    rng = np.random.default_rng(3)
    W, nwin, out, rows = 15, 3, [IX["psi"], IX["u"], IX["r"]], [IX["psi"], IX["u"], IX["r"]]
    step = _step(prior, 0.2)
    x0 = np.zeros((NX, nwin))
    x0[IX["psi"]], x0[IX["u"]] = rng.uniform(-3, 3, nwin), rng.uniform(0.5, 2.0, nwin)
    A = np.vstack([rng.uniform(50, 200, W * nwin), rng.uniform(-0.3, 0.3, W * nwin)])
    Y = rng.normal(size=(3, W * nwin))
    w = np.array([2.0, 5.0, 7.0])
    win = Windows(step, x0, A, Y, out, w, wrap=[0], x0_rows=rows)
    z = np.r_[1.1, 0.9, 0.1, -0.2, rng.uniform(-0.1, 0.1, 3 * nwin)]
    res, jac, Ysim = win.residuals(z)

    # the same residuals as one MX graph, differentiated by CasADi
    zs = ca.MX.sym("z", z.size)
    E = np.zeros((NX, 3))
    E[rows, range(3)] = 1.0
    X0 = ca.DM(x0) + E @ ca.reshape(zs[4:], 3, nwin)
    X = step.mapaccum("w", W).map(nwin)(X0, A, ca.repmat(zs[:4], 1, W * nwin))
    err = ca.vertcat(*[X[i, :] for i in out]) - Y
    err[0, :] = ca.atan2(ca.sin(err[0, :]), ca.cos(err[0, :]))
    r = ca.vec(ca.diag(w) @ err)
    ref = ca.Function("ref", [zs], [r, ca.jacobian(r, zs)])
    r_ref, J_ref = (np.array(v) for v in ref(z))
    assert np.allclose(res, r_ref.ravel(), rtol=0, atol=1e-12)
    assert np.abs(jac - J_ref).max() <= 1e-9 * np.abs(J_ref).max()
    assert np.abs(jac).max(axis=0).min() > 0  # every parameter moves some residual
    # a window's correction moves that window's residuals only
    assert not jac[3 * W :, 4:7].any() and jac[: 3 * W, 4:7].any()
    assert np.allclose(win.simulate(z), Ysim)


def test_shapes_that_do_not_agree_are_refused():
    step = _step(load_vessel("gretha"), 0.2)
    with pytest.raises(ValueError, match="do not agree"):
        Windows(step, np.zeros((NX, 2)), np.zeros((2, 31)), np.zeros((1, 31)), [2], [1.0])
    with pytest.raises(ValueError, match="1 weights and wrapped rows"):
        Windows(step, np.zeros((NX, 2)), np.zeros((2, 30)), np.zeros((3, 30)), [2, 3, 5], [1.0])
    with pytest.raises(ValueError, match="outside the 8 states"):
        Windows(step, np.zeros((NX, 2)), np.zeros((2, 30)), np.zeros((1, 30)), [2], [1.0],
                x0_rows=[9])  # fmt: skip
    win = Windows(step, np.zeros((NX, 2)), np.zeros((2, 30)), np.zeros((1, 30)), [2], [1.0])
    with pytest.raises(ValueError, match="5 parameters given, 4 expected"):
        win.residuals(np.zeros(5))


def test_equation_error_jacobian_equals_finite_differences():
    prior = load_vessel("gretha")
    log = simulate_manoeuvre(VesselModel(prior), "zigzag", u0=1.5, delta_deg=20, duration=30)
    prob = Problem(prior)
    fun = prob.equation_error([prepare(log, prior)])
    th = np.r_[np.linspace(0.8, 1.2, len(IDENTIFIED)), 0.1, -0.05]
    res, jac = fun(th)
    step = 1e-6
    fd = np.column_stack([(fun(th + step * e)[0] - fun(th - step * e)[0]) / (2 * step)
                          for e in np.eye(th.size)])  # fmt: skip
    assert res.shape == (jac.shape[0],) and jac.shape[1] == th.size
    assert np.abs(jac - fd).max() <= 1e-5 * np.abs(fd).max()


def test_windows_of_several_lengths_equal_casadi_ad_of_each_window():
    """A shorter window (a part's samples after its last whole window) is replayed with the
    others: residuals and Jacobian as CasADi's AD of each window replayed on its own."""
    prior = load_vessel("gretha")
    rng = np.random.default_rng(4)
    lengths, out, rows = [12, 5, 12, 1], [IX["psi"], IX["u"], IX["r"]], [IX["u"]]
    step = _step(prior, 0.2)
    n, nwin = sum(lengths), len(lengths)
    x0 = np.zeros((NX, nwin))
    x0[IX["u"]] = rng.uniform(0.5, 2.0, nwin)
    A = np.vstack([rng.uniform(50, 200, n), rng.uniform(-0.3, 0.3, n)])
    Y = rng.normal(size=(3, n))
    w = np.array([2.0, 5.0, 7.0])
    win = Windows(step, x0, A, Y, out, w, x0_rows=rows, lengths=lengths)
    z = np.r_[1.1, 0.9, 0.1, -0.2, rng.uniform(-0.1, 0.1, nwin)]
    res, jac, Ysim = win.residuals(z)
    assert res.shape == (3 * n,) and jac.shape == (3 * n, 4 + nwin) and Ysim.shape == (3, n)
    start = np.r_[0, np.cumsum(lengths)]
    for j in range(nwin):
        one = Windows(step, x0[:, j : j + 1], A[:, start[j] : start[j + 1]],
                      Y[:, start[j] : start[j + 1]], out, w, x0_rows=rows)  # fmt: skip
        r1, J1, _ = one.residuals(np.r_[z[:4], z[4 + j]])
        sl = slice(3 * start[j], 3 * start[j + 1])
        assert np.allclose(res[sl], r1, rtol=0, atol=1e-12)
        assert np.allclose(jac[sl, :4], J1[:, :4]) and np.allclose(jac[sl, 4 + j], J1[:, 4])
        assert not np.delete(jac[sl], [0, 1, 2, 3, 4 + j], axis=1).any()
    assert np.allclose(win.simulate(z), Ysim)
