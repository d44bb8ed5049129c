"""The opt-in soft floor on the planned ground surge while the propeller runs (weights.floor,
eq. M4f, docs/mpc.md "Known problems", strong currents): its stage cost is
``floor * sig((T - T_on) / w_T) * (speed_min - u)_+^2``, and with the default 0 the term is
not in the problem at all (the same compiled library as before it existed)."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from mpcasv.controllers import load_preset
from mpcasv.mpc import codegen
from mpcasv.mpc.derivatives import nlp_functions
from mpcasv.mpc.layout import WEIGHT_NAMES
from mpcasv.mpc.problem import OCP


def _floor_cost(floor: float, T: float, u: float) -> float:
    """The stage cost rate with every other weight 0."""
    ocp = OCP(load_preset("mpc-single", "mpc-single", {"weights.floor": floor}), 1, True)
    z, v = ca.SX.sym("z", ocp.dims.nx), ca.SX.sym("v", ocp.dims.nu)
    L = ca.Function("L", [z, v], [ocp._stage_cost(z, v, None, dict.fromkeys(WEIGHT_NAMES, 0.0),
                                                   None)])  # fmt: skip
    z0 = np.zeros(ocp.dims.nx)
    z0[3], z0[6] = u, T
    return float(L(z0, np.zeros(ocp.dims.nu)))


def test_the_floor_costs_a_slow_planned_surge_only_while_the_propeller_runs():
    T_run = 200.0  # N, far above any propeller-on threshold
    assert _floor_cost(10.0, T_run, -0.3) == pytest.approx(10.0 * 0.8**2, rel=1e-6)
    assert _floor_cost(10.0, T_run, 0.0) == pytest.approx(10.0 * 0.5**2, rel=1e-6)
    assert _floor_cost(10.0, T_run, 0.7) == 0.0  # above speed_min: free
    # propeller off: the smooth propeller-on indicator's tail (its width w_T) only
    assert _floor_cost(10.0, 0.0, -0.3) < 0.05 * _floor_cost(10.0, T_run, -0.3)
    assert _floor_cost(0.0, T_run, -0.3) == 0.0


def test_floor_0_is_the_problem_without_the_term():
    base = load_preset("mpc-single", "mpc-single")
    assert base.weights.floor == 0.0
    key = codegen.library_key(nlp_functions(OCP(base, 1, True), "fatrop"), "fatrop", "-O1")
    on = load_preset("mpc-single", "mpc-single", {"weights.floor": 10.0})
    assert codegen.library_key(nlp_functions(OCP(on, 1, True), "fatrop"), "fatrop",
                               "-O1") != key  # fmt: skip
