"""The shared vessel model: rest, top speed, dissipation, turning, linearisation, stability."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mpcasv.config import ConfigError, load_toml, parse
from mpcasv.models.params import MODEL_COEFFS, VesselParams, load_vessel
from mpcasv.models.vessel import IX, NX, VesselModel


@pytest.fixture(scope="module")
def model() -> VesselModel:
    return VesselModel(load_vessel("gretha"))


def run(model, x0, u, seconds, dt=0.1, c=(0.0, 0.0)):
    F = model.rk4(dt)
    xs = [np.asarray(x0, float)]
    for _ in range(int(round(seconds / dt))):
        xs.append(np.array(F(xs[-1], u, c)).ravel())
    return np.array(xs)


def test_at_rest_without_current_stays_at_rest(model):
    xs = run(model, np.zeros(NX), [0.0, 0.0], 60.0)
    assert np.abs(xs).max() < 1e-12


def test_full_thrust_settles_at_top_speed(model):
    P = model.params
    xs = run(model, np.zeros(NX), [P.T_max, 0.0], 300.0)
    u_end = xs[-1, IX["u"]]
    assert abs(u_end - 2.5) <= 0.1
    assert abs(xs[-1, IX["u"]] - xs[-100, IX["u"]]) < 1e-3  # settled
    assert abs(model.top_speed - 2.5) <= 0.1


def test_thrust_off_speed_decays_monotonically_and_energy_dissipates(model):
    x0 = model.trim(2.5)[0]
    x0[IX["r"]], x0[IX["v"]] = 0.2, 0.3  # some sway and yaw too
    x0[IX["T"]] = 0.0  # propeller off: no energy in
    xs = run(model, x0, [0.0, 0.0], 120.0)
    P = model.params
    speed = np.hypot(xs[:, IX["u"]], xs[:, IX["v"]])
    # kinetic energy with the (symmetric) mass matrix M = M_RB + M_A
    M = np.array([[P.m - P.X_udot, 0, 0],
                  [0, P.m - P.Y_vdot, P.m * P.x_g - P.Y_rdot],
                  [0, P.m * P.x_g - P.N_vdot, P.I_z - P.N_rdot]])  # fmt: skip
    nu = xs[:, [IX["u"], IX["v"], IX["r"]]]
    E = 0.5 * np.einsum("ti,ij,tj->t", nu, M, nu)
    assert np.all(np.diff(E) <= 1e-9)  # Coriolis forces do no work; damping dissipates
    assert speed[-1] < 0.35 * speed[0]
    # straight ahead, the surge speed itself decays monotonically
    straight = run(model, model.trim(2.5)[0], [0.0, 0.0], 120.0)
    assert np.all(np.diff(straight[:, IX["u"]]) <= 1e-12)


def test_constant_steering_gives_a_steady_turning_circle(model):
    P = model.params
    xs = run(model, model.trim(1.5)[0], [P.T_max * 0.5, np.radians(20)], 400.0)
    r = xs[-300:, IX["r"]]
    assert r.min() > 0 and (r.max() - r.min()) < 1e-3 * r.mean()  # steady, to starboard
    # the last full circle: positions lie on a circle of radius U/r
    U = np.hypot(xs[-1, IX["u"]], xs[-1, IX["v"]])
    R = U / xs[-1, IX["r"]]
    pts = xs[-int(2 * np.pi / xs[-1, IX["r"]] / 0.1) :, :2]
    centre = pts.mean(axis=0)
    radii = np.hypot(*(pts - centre).T)
    assert np.allclose(radii, R, rtol=0.02)


def test_linearisation_agrees_with_finite_differences(model):
    rng = np.random.default_rng(3)
    x0 = np.array([10.0, -5.0, 0.7, 1.8, 0.2, 0.05, 150.0, 0.1])
    u0 = np.array([120.0, -0.2])
    c0 = np.array([0.2, -0.1])
    A, B = model.linearize(x0, u0, c0)
    f = lambda x, u: np.array(model.f(x, u, c0)).ravel()  # noqa: E731
    for _ in range(3):
        dx = rng.normal(size=NX) * 1e-6 * (1 + np.abs(x0))
        du = rng.normal(size=2) * 1e-6 * (1 + np.abs(u0))
        fd = f(x0 + dx, u0 + du) - f(x0 - dx, u0 - du)
        lin = 2 * (A @ dx + B @ du)
        assert np.allclose(fd, lin, rtol=1e-5, atol=1e-9)


@pytest.mark.parametrize("u", [0.05, 0.3, 0.6, 1.0, 1.5, 2.0, 2.5, 2.6])
def test_straight_line_stable_at_every_speed(model, u):
    A = model.linearize(*model.trim(u))[0]
    dyn = [IX[k] for k in ("u", "v", "r", "T", "delta")]  # N, E, psi are pure integrators
    assert np.max(np.linalg.eigvals(A[np.ix_(dyn, dyn)]).real) < 0
    assert np.max(model.sway_yaw_eigenvalues(u).real) < -0.05


def test_current_is_felt_through_the_relative_velocity(model):
    # with the propeller off, a boat at rest ends up drifting with the current
    xs = run(model, np.zeros(NX), [0.0, 0.0], 400.0, c=(0.3, -0.2))
    vel_ned = np.diff(xs[-20:, :2], axis=0).mean(axis=0) / 0.1
    assert np.allclose(vel_ned, [0.3, -0.2], atol=0.01)


def test_every_shipped_number_has_provenance():
    p = load_vessel("gretha")
    numeric = {f.name for f in dataclasses.fields(p)} - {"name", "provenance"}
    assert numeric <= set(p.provenance)
    assert all(len(p.provenance[k]) > 5 for k in numeric)
    assert set(MODEL_COEFFS) <= numeric


def _gretha_data():
    from mpcasv.config import resolve

    return load_toml(resolve("vessels", "gretha"))


def test_missing_parameter_is_refused_naming_the_field():
    data = _gretha_data()
    del data["N_rr"]
    with pytest.raises(ConfigError, match="N_rr"):
        parse(VesselParams, data, "gretha.toml")


def test_non_numeric_parameter_is_refused_naming_the_field():
    data = _gretha_data()
    data["X_u"] = "-11.2"
    with pytest.raises(ConfigError, match=r"gretha.toml: X_u: .*number"):
        parse(VesselParams, data, "gretha.toml")


def test_missing_provenance_entry_is_refused():
    data = _gretha_data()
    del data["provenance"]["I_z"]
    with pytest.raises(ConfigError, match="provenance missing"):
        parse(VesselParams, data, "gretha.toml")
