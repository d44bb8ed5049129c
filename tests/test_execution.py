"""The execution level against thesis eq. 3.1 (issue 13 item 2) and its limits (item 4)."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from mpcasv.cli import main
from mpcasv.control.execution import steering_floor
from mpcasv.control.params import load_execution
from mpcasv.control.tuning_speed import PIROUETTE_CASE, pirouette_check, turn
from mpcasv.models.params import load_vessel
from mpcasv.models.vessel import IX, VesselModel


@pytest.fixture(scope="module")
def model() -> VesselModel:
    return VesselModel(load_vessel("gretha"))


@pytest.fixture(scope="module")
def ep():
    return load_execution("gretha")


def test_thrust_floor_never_holds_the_boat_above_eq_3_1(model, ep):
    """The floor is at most the trim thrust at u_ff (so the speed it can hold is <= u_ff <=
    u_ref) and vanishes once the leg's lift gives the boat its steering authority."""
    P = model.params
    us = np.linspace(0.0, 2.5, 251)
    floor = np.array([float(ca.DM(steering_floor(u, P, ep))) for u in us])
    T_trim_ff = model.thrust_for_speed(ep.reference.u_ff)
    assert floor.max() <= T_trim_ff + 1e-9
    assert floor[us <= ep.reference.u_ff] == pytest.approx(ep.thrust_floor * P.T_max)
    assert np.all(floor[us >= 0.8] == 0.0)
    assert np.all(np.diff(floor) <= 1e-12)  # fades out monotonically with speed
    # side force at full steering never below that of steady cruising at u_ff
    d = P.delta_max
    side = floor * math.sin(d) + abs(P.Y_uudelta) * us**2 * d
    side_ff = ep.thrust_floor * P.T_max * math.sin(d) + abs(P.Y_uudelta) * ep.reference.u_ff**2 * d
    assert np.all(side[us >= ep.reference.u_ff] >= side_ff - 1e-9)


def test_hard_turn_speed_is_eq_3_1s(model, ep):
    """A 180 deg turn from full speed: while |psi_e| >= pi/2 eq. 3.1 asks for u_ff, and the boat
    slows to it; no 'power turn' thrust holds it faster (the old floor went up to 0.8 T_max)."""
    run, f = turn(model, ep, math.radians(180.0), 50.0)
    hard = np.abs(run.psi_error) >= math.pi / 2
    assert hard[:50].all()
    assert np.allclose(run.Y[hard, 1], ep.reference.u_ff)
    i = int(np.argmax(~hard[1:])) + 1  # end of the hard part
    assert run.X[i, IX["u"]] < ep.reference.u_ff + 0.05
    assert run.U[hard, 0].max() <= model.params.T_max + 1e-9


def test_pirouette_check_with_and_without_eq_3_1(model, ep):
    """docs/figures/pirouette.png: hard turn while accelerating, waypoint inside the turning
    circle at full power; without eq. 3.1 the boat circles it, with it the boat gets there."""
    a, d, u0 = PIROUETTE_CASE
    res = pirouette_check(model, ep, a, d, u0)
    assert res["without"][1]["pirouette"] and not math.isfinite(res["without"][1]["turn_s"])
    assert not res["with"][1]["pirouette"] and res["with"][1]["turn_s"] < 100


@pytest.mark.parametrize(
    ("args", "match"),
    [(["--delta", "40"], "--delta 40 deg beyond gretha's steering limit delta_max = 30.0 deg"),
     (["--speed", "3.0"], "--speed 3 m/s outside \\(0, 2.5\\] m/s: gretha cannot hold it")],
)  # fmt: skip
def test_manoeuvre_set_points_beyond_the_limits_are_refused(tmp_path, capsys, args, match):
    import re

    rc = main(["simulate", "--manoeuvre", "zigzag", *args, "--out", str(tmp_path / "z.csv")])
    err = capsys.readouterr().err
    assert rc == 2 and re.search(match, err) and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "z.csv").exists()
