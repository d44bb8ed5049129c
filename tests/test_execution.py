"""The execution level against thesis eq. 3.1 (issue 13 item 2) and its limits (item 4)."""

from __future__ import annotations

import dataclasses
import math

import casadi as ca
import numpy as np
import pytest

from mpcasv.cli import main
from mpcasv.control.execution import steering_floor
from mpcasv.control.params import load_execution
from mpcasv.control.steering import full_lock_turns, lock_thrust
from mpcasv.control.tuning_speed import PIROUETTE_CASE, pirouette_check, turn
from mpcasv.models.vessel import IX


@pytest.fixture(scope="module")
def ep():
    """Gretha's execution level true to eq. 3.1: the shipped file's optional power turn off
    (it is on in the shipped file because this derived hull turns too slowly at low speed:
    :func:`test_shipped_file_keeps_eq_3_1_in_tracking_turns_and_escapes_with_power`)."""
    return dataclasses.replace(load_execution("gretha"), turn_thrust=0.0)


def test_steering_floor_is_the_least_full_lock_thrust_within_eq_3_1(model, ep):
    """T_lock = min(T_req, T_hold): the least thrust whose steady full-lock turn reaches
    r_steer, capped by the one whose steady full-lock turn runs at u_ff (Gretha: the cap binds,
    29.4 N for 2.56 deg/s against 62.0 N for 4.5 deg/s). The floor is T_lock at full lock,
    nothing on a straight course and less for slower commands."""
    P = model.params
    u_ff = ep.reference.u_ff
    lock = lock_thrust(model, ep)
    turns = full_lock_turns(model)
    assert np.all(np.diff(turns.u) > 0) and np.all(np.diff(turns.r) > 0)
    # each grid point is a steady turn of the model
    for i in (0, len(turns.T) // 2, -1):
        x = [0, 0, 0, turns.u[i], turns.v[i], turns.r[i], turns.T[i], P.delta_max]
        xdot = np.array(model.f(x, [turns.T[i], P.delta_max], [0, 0])).ravel()
        assert np.abs(xdot[3:6]).max() < 1e-4
    assert lock["T_lock"] == pytest.approx(min(lock["T_req"], lock["T_hold"]))
    assert lock["u_lock"] <= u_ff + 1e-6  # never faster than eq. 3.1's turn speed
    assert lock["r_lock"] <= ep.r_steer + 1e-9  # and no more authority than asked for
    assert lock["T_lock"] > model.thrust_for_speed(u_ff)  # a turn costs more than straight
    fl = lambda u_ref, d: float(ca.DM(steering_floor(u_ref, d, model, ep)))  # noqa: E731
    assert fl(u_ff, P.delta_max) == pytest.approx(lock["T_lock"])
    assert fl(2.5, -P.delta_max) == pytest.approx(lock["T_lock"])
    assert fl(u_ff, 0.0) == 0.0
    assert fl(u_ff / 2, P.delta_max) == pytest.approx(lock["T_lock"] / 4)


def test_speed_in_a_hard_turn_stays_at_eq_3_1s_command(model, ep):
    """A long hard turn from straight running at u_ff (waypoint 200 m astern): eq. 3.1 keeps
    commanding u_ff and the floor does not hold the boat faster: the speed stays within
    0.05 m/s of u_ff and ends within 0.02 m/s (measured: 0.607 and 0.602 m/s). With twice the
    floor the boat would run at 0.82 m/s (measured), so this can fail."""
    u_ff = ep.reference.u_ff
    run, _ = turn(model, ep, math.radians(180.0), 200.0, t_end=60.0, u0=u_ff)
    hard = np.abs(run.psi_error) >= math.pi / 2
    n = int(np.argmax(~hard))  # end of the first hard part
    assert n * (run.t[1] - run.t[0]) > 15.0
    assert np.all(run.Y[:n, 1] == pytest.approx(u_ff))  # eq. 3.1's command itself
    u = run.X[:n, IX["u"]]
    assert u.max() <= u_ff + 0.05
    assert u[-50:].max() <= u_ff + 0.02  # last 5 s of the hard part


def test_hard_turn_speed_is_eq_3_1s(model, ep):
    """A 180 deg turn from full speed: while |psi_e| >= pi/2 eq. 3.1 asks for u_ff and the boat
    slows all through it; no 'power turn' thrust holds it (the old floor went up to
    0.8 T_max = 224 N): the thrust is at most the steering floor at full lock."""
    run, f = turn(model, ep, math.radians(180.0), 50.0)
    hard = np.abs(run.psi_error) >= math.pi / 2
    assert hard[:50].all()
    assert np.allclose(run.Y[hard, 1], ep.reference.u_ff)
    i = int(np.argmax(~hard[1:])) + 1  # end of the hard part
    assert np.all(np.diff(run.X[:i, IX["u"]]) < 0)  # slowing down all through it
    assert run.U[:i, 0].max() <= lock_thrust(model, ep)["T_lock"] + 1e-6


def test_pirouette_check_with_and_without_eq_3_1(model, ep):
    """docs/figures/pirouette.png: hard turn while accelerating (from 0.6 m/s, waypoint 10 m
    at 90 deg, command u_max). Without eq. 3.1 the boat speeds up in the turn and circles the
    waypoint; with it the speed stays at u_ff while |psi_e| >= pi/2 and the thrust at most the
    steering floor, and the boat gets on course."""
    a, d, u0 = PIROUETTE_CASE
    res = pirouette_check(model, ep, a, d, u0)
    run_wo, f_wo = res["without"]
    # it passes 5 m from the waypoint (the turn is "done" there) and then circles it
    assert f_wo["pirouette"] and f_wo["circling_deg"] > 720
    assert run_wo.X[run_wo.t <= 20.0, IX["u"]].max() > 1.2  # speeding up in the turn
    run, _ = res["with"]
    n = int(np.argmax(np.abs(run.psi_error) < math.radians(80.0)))  # the turn: [0, n)
    hard = (np.abs(run.psi_error) >= math.pi / 2 - 1e-9) & (np.arange(len(run.t)) < n)
    assert hard.sum() > 50  # the check has hard-turn samples to look at
    assert run.X[hard, IX["u"]].max() <= ep.reference.u_ff + 0.05
    assert run.U[hard, 0].max() <= lock_thrust(model, ep)["T_lock"] + 1e-6
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


def test_shipped_file_keeps_eq_3_1_in_tracking_turns_and_escapes_with_power(model):
    """The shipped Gretha file (docs/tuning.md, "What ships"): eq. 3.1 governs every tracking
    turn (a long hard turn stays at u_ff), and only a collision-avoidance transit turns with
    the power turn (well above u_ff). Recorded so that the remaining override stays visible."""
    from mpcasv.control.tuning import run_closed_loop

    shipped = load_execution("gretha")
    assert shipped.turn_thrust > 0 and shipped.turn_scope == "avoidance"
    u_ff = shipped.reference.u_ff
    x0, _ = model.trim(u_ff)
    for transit, above in ((1.0, False), (2.0, True)):
        run = run_closed_loop(model, shipped, x0, (-200.0, 1e-3), model.params.u_max, 60.0,
                              transit=transit)  # fmt: skip
        n = int(np.argmax(np.abs(run.psi_error) < math.pi / 2))
        u_hard = float(run.X[:n, IX["u"]].max())
        assert (u_hard > u_ff + 0.3) if above else (u_hard <= u_ff + 0.05), (transit, u_hard)


def test_power_turn_scoped_to_avoidance_keeps_eq_3_1_in_tracking_turns(model):
    """turn_scope = "avoidance": the power turn acts only in collision-avoidance transits
    (cmd[0] = 2: the ASV inside a collision domain, from true ranges); a tracking transit's
    long hard turn stays at eq. 3.1's u_ff while an avoidance transit's runs well above it
    (docs/tuning.md)."""
    from mpcasv.control.execution import command_vector, escape_vector
    from mpcasv.control.tuning import run_closed_loop
    from mpcasv.interface import Command, Mode, Reason

    shipped = load_execution("gretha")
    ep = dataclasses.replace(shipped, turn_thrust=0.8, turn_scope="avoidance")
    u_ff = ep.reference.u_ff
    x0, _ = model.trim(u_ff)
    u_max = {}
    for transit in (1.0, 2.0):
        run = run_closed_loop(model, ep, x0, (-200.0, 1e-3), model.params.u_max, 60.0,
                              transit=transit)  # fmt: skip
        hard = np.abs(run.psi_error) >= math.pi / 2
        n = int(np.argmax(~hard))
        assert n * (run.t[1] - run.t[0]) > 10.0
        u_max[transit] = float(run.X[:n, IX["u"]].max())
    assert u_max[1.0] <= u_ff + 0.05
    assert u_max[2.0] > u_ff + 0.3
    wp = (10.0, 0.0)
    # one rule for every controller: geometry (World.advance's `escaping`), never the label
    tracking = command_vector(Command(Mode.TRANSIT, wp, 1.0, 0, Reason.TRACKING))
    assert command_vector(Command(Mode.TRANSIT, wp, 1.0, 0, Reason.AVOIDANCE))[0] == 1.0
    assert list(escape_vector(tracking, True)) == [2.0, *wp, 1.0]
    assert escape_vector(tracking, False)[0] == 1.0
    assert escape_vector(command_vector(Command.standby(0)), True)[0] == 0.0
