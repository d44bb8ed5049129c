"""The plan's thrust sigmoids fit the boat (docs/mpc.md, M3; ``fix.w_thrust``).

The plan tells "propeller off" (quiet fixes, M3; no deadband cost, M4b) from "running" by
sigmoids of the thrust around the execution level's propeller-on threshold ``T_on``. The
presets' width is 4 N: 29 % of Gretha's 14-N threshold, but until session 11 also 3.4 times
dune-otter's 1.2 N, whose plan then counted only 57 % of the fixes with the propeller off,
28 % while running at a fifth of full thrust, and charged the deadband cost while stopped; on
Case 3 it hovered at r_outer and had no reliable fix in 1500 s. The width is now at most
``T_on / 3`` (Gretha's 4 N unchanged; the shipped Otter's 3.99 N).
"""

from __future__ import annotations

import pytest

from mpcasv.controllers import Boat, load_preset
from mpcasv.mpc.problem import OCP
from mpcasv.mpc.smooth import sigmoid


def _ocp(vessel: str, overrides: dict | None = None) -> OCP:
    P = load_preset("mpc-single", "mpc-single", overrides or {})
    return OCP(P, 1, outer=True, boat=Boat.load(vessel))


@pytest.mark.parametrize("vessel", ["gretha", "dune-otter"])
def test_a_stopped_propeller_is_quiet_and_a_running_one_loud_on_any_boat(vessel):
    ocp = _ocp(vessel)
    assert ocp._quiet(0.0) >= 0.95  # stopped: (nearly) every fix counts (M3)
    assert ocp._quiet(ocp.T_floor) <= 0.2  # at the least transit thrust: few count
    running = float(sigmoid((0.0 - ocp.T_on) / ocp.w_T))  # M4b's and M4c's factor
    assert running <= 0.05  # no deadband cost while stopped


def test_the_presets_width_is_kept_where_it_fits():
    """Gretha's plan keeps the presets' 4 N; a width set below the cap is used as it is."""
    assert _ocp("gretha").w_T == 4.0
    assert _ocp("dune-otter", {"fix.w_thrust": 0.2}).w_T == 0.2
    dune = _ocp("dune-otter")
    assert dune.w_T == pytest.approx(dune.T_on / 3)
