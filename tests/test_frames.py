"""The numeric NED <-> body rotation (mpcasv.models.frames) is the one the shared CasADi model
integrates (eq. 2.5), and the current's body components are what the model subtracts
(eq. 2.6): a boat whose velocity over the ground is the current has no speed through water."""

import math

import numpy as np
import pytest

from mpcasv.models.frames import body_to_ned, ned_to_body
from mpcasv.models.vessel import NU, NX

RNG = np.random.default_rng(3)
STATES = [(float(RNG.uniform(-7, 7)), *RNG.uniform(-2, 2, 4)) for _ in range(6)]


@pytest.mark.parametrize("psi,u,v,cN,cE", STATES)
def test_body_to_ned_is_the_models_position_kinematics(model, psi, u, v, cN, cE):
    x = np.zeros(NX)
    x[2:5] = psi, u, v
    eta_dot = np.asarray(model.f(x, np.zeros(NU), [cN, cE])).ravel()
    assert body_to_ned(psi, u, v) == pytest.approx(tuple(eta_dot[:2]), abs=1e-12)


@pytest.mark.parametrize("psi,u,v,cN,cE", STATES)
def test_a_boat_carried_by_the_current_has_no_speed_through_the_water(model, psi, u, v, cN, cE):
    x = np.zeros(NX)
    x[2] = psi
    x[3:5] = ned_to_body(psi, cN, cE)
    # with no speed through the water and no thrust the hull feels no force: nu_dot = 0
    nu_dot = np.asarray(model.f(x, np.zeros(NU), [cN, cE])).ravel()[3:6]
    assert nu_dot == pytest.approx(np.zeros(3), abs=1e-9)
    assert body_to_ned(psi, *x[3:5]) == pytest.approx((cN, cE), abs=1e-12)


def test_arrays_and_scalars_agree_and_the_rotations_invert():
    psi, a, b = RNG.uniform(-7, 7, 50), RNG.uniform(-3, 3, 50), RNG.uniform(-3, 3, 50)
    u, v = ned_to_body(psi, a, b)
    assert np.allclose(body_to_ned(psi, u, v), (a, b), atol=1e-12)
    assert np.array_equal(u, np.cos(psi) * a + np.sin(psi) * b)  # the arrays' old inline form


def test_a_scalar_gives_the_bits_of_the_old_inline_math_expressions():
    for p, x, y in zip(*RNG.uniform(-7, 7, (3, 200)), strict=True):
        for psi in (float(p), np.float64(p), np.array(p)):  # every scalar through math
            c, s = math.cos(float(p)), math.sin(float(p))
            assert ned_to_body(psi, x, y) == (c * x + s * y, -s * x + c * y)
            assert body_to_ned(psi, x, y) == (x * c - y * s, x * s + y * c)
    # a north current is to port (negative sway) of an east-going boat
    assert ned_to_body(0.5 * np.pi, 1.0, 0.0) == pytest.approx((0.0, -1.0))
