"""Tests of the speed loop, its nonlinear steps and the surge-speed reference model (eq. 3.1:
turns, pirouettes and their plots) of `mpcasv tune speed` (mpcasv.control.tuning_speed,
tuning_report); the yaw tuning is in test_tuning.py."""

from __future__ import annotations

import dataclasses
import math
import re
import warnings

import numpy as np
import pytest
from shared_data import CASES
from shared_data import needs_shared as needs_cases

from mpcasv.cli import main
from mpcasv.control.tuning import run_closed_loop
from mpcasv.control.tuning_speed import place_speed_pi, speed_figures, surge_plant, turn

warnings.filterwarnings("ignore", category=UserWarning, module="control")


def test_speed_loop_design(model, shipped):
    g = place_speed_pi(model, 1.0, 0.3, 1.0)
    assert (shipped.speed.Kp, shipped.speed.Ki) == pytest.approx((g.Kp, g.Ki), rel=1e-4)
    for u0 in (0.5, 2.5):
        f = speed_figures(surge_plant(model, u0), g, dt=0.1)
        assert f["phase_margin_deg"] >= 45 and f["gain_margin_db"] >= 6
        assert f["settling_s"] < 30


def test_turn_detects_pirouettes(model, shipped):
    """A waypoint inside the full-power turning circle is circled (pirouette) without eq. 3.1;
    with eq. 3.1 (slowing towards u_ff in the turn) the boat reaches it; one far enough is
    reached either way. (Before issue 13 the 'power turn' thrust floor made the shipped
    execution level circle the 10 m waypoint too.)"""
    from mpcasv.control.tuning_speed import PIROUETTE_TURN, without_reference

    shipped = dataclasses.replace(shipped, turn_thrust=0.0)  # eq. 3.1 without the power turn
    _, near_none = turn(model, without_reference(shipped, model), math.radians(90.0), 10.0)
    _, near = turn(model, shipped, math.radians(90.0), 10.0)
    _, far = turn(model, shipped, math.radians(90.0), 50.0)
    assert near_none["pirouette"] and near_none["circling_deg"] > 2 * math.degrees(PIROUETTE_TURN)
    # with eq. 3.1 the boat slows from full speed (2.5 m/s) in the turn; the steering floor
    # gets it on course before it is down to u_ff (measured min 0.70 m/s)
    assert not near["pirouette"] and near["min_u"] < 0.4 * model.params.u_max
    assert not far["pirouette"] and 0 < far["turn_s"] < 60 and far["total_turn_deg"] < 180


def test_a_turn_that_reaches_the_waypoint_is_not_a_pirouette(model, shipped):
    """A new user: u_ff = 0.8, k_u = 1.59 in a 90 deg turn to a waypoint 10 m away reaches
    5 m of it at 35.3 s over 48.6 m (0.4 m closest approach, 12 deg heading error on arrival,
    still closing) and was flagged a pirouette ("not within 10 deg by 5 m"), as was a 30 deg
    turn from 0.6 m/s with 37 deg of turning; that label alone excluded u_ff = 0.8 from the
    grid. A pirouette is circling the waypoint instead of reaching it (PIROUETTE_TURN); the
    turn is done on arrival."""
    from mpcasv.config import replace
    from mpcasv.control.params import SpeedReference
    from mpcasv.control.tuning_speed import PIROUETTE_CASE, turn_grid, without_reference

    ep = dataclasses.replace(shipped, turn_thrust=0.0)
    e08 = replace(ep, reference=SpeedReference(u_ff=0.8, k_u=1.59))
    _, f = turn(model, e08, math.radians(90.0), 10.0)
    assert f["reached"] and not f["pirouette"]
    assert f["turn_s"] == pytest.approx(35.3, abs=0.15) and f["reach_s"] == f["turn_s"]
    assert f["turn_m"] == pytest.approx(48.6, abs=0.2)
    _, f30 = turn(model, ep, math.radians(30.0), 10.0, u0=0.6)
    assert not f30["pirouette"] and f30["total_turn_deg"] < 45
    rows, _ = turn_grid(model, ep, [(0.6, 1.59), (0.8, 1.59)], angles_deg=(90.0,), distance=10.0)
    assert [r.ok for r in rows] == [True, True]
    # the boat without eq. 3.1 passes the waypoint and circles it: still a pirouette
    a, d, u0 = PIROUETTE_CASE
    _, none = turn(model, without_reference(ep, model), math.radians(a), d, 120.0, u0=u0)
    assert none["reached"] and none["pirouette"]


def _rows(costs: dict):
    """TurnRows of one 90-deg turn each with the given turn times {(u_ff, k_u): s}."""
    from mpcasv.control.tuning_speed import TurnRow

    return [TurnRow(u_ff=a, k_u=b, figures={90.0: {"turn_s": t, "reached": True,
                                                   "pirouette": False}})
            for (a, b), t in costs.items()]  # fmt: skip


def test_the_recommendation_keeps_u_cmd_max_within_the_bound_and_says_when_on_the_edge():
    """The turn times only fall as k_u grows, so the grid's largest k_u always won (k_u = 10
    was written by --set-reference). The thesis held u_cmd,max = u_ff + k_u pi/2 at the rated
    maximum speed (3.1 m/s, §3.4.1): pairs above the bound are not recommended, and an
    optimum on the grid's edge is said."""
    from mpcasv.control.tuning_speed import edge_notes, recommend

    rows = _rows({(0.6, 1.2): 30.0, (0.6, 1.59): 29.0, (0.6, 10.0): 20.0, (0.8, 1.2): 25.0,
                  (0.8, 1.59): 24.0})  # fmt: skip
    assert recommend(rows).k_u == 10.0  # unbounded: the edge
    best = recommend(rows, 3.1)
    assert (best.u_ff, best.k_u) == (0.8, 1.2)  # 0.8 + 1.59 pi/2 = 3.30 > 3.1
    notes = edge_notes(best, rows, 3.1)
    assert any("u_ff = 0.8 is the grid's largest" in n for n in notes), notes
    assert any("k_u = 1.2" in n and "the bound sets it" in n for n in notes), notes
    assert recommend(rows, 3.0976).k_u == 1.2  # the field pair's own 0.6 + 1.59 pi/2 admitted
    assert (recommend(rows[:3], 0.6 + 1.59 * math.pi / 2).k_u) == 1.59
    with pytest.raises(ValueError, match="u_ff \\+ k_u pi/2 <= 2"):
        recommend(rows, 2.0)


def test_set_reference_writes_no_k_u_above_the_bound(tmp_path, capsys):
    """`tune speed --k-u 1.59,10 --set-reference` wrote k_u = 10 (u_cmd,max 16.3 m/s)."""
    from mpcasv.control.params import load_execution

    toml = tmp_path / "e.toml"
    rc = main(["tune", "speed", "--speeds", "1", "--u-ff", "0.6", "--k-u", "1.59,10",
               "--distance", "50", "--set-reference", "--out", str(tmp_path / "o"),
               "--toml", str(toml), "--quiet"])  # fmt: skip
    cap = capsys.readouterr()
    assert rc == 0 and "(0.6, 1.59)" in cap.out and "(above the bound)" in cap.out
    assert load_execution(toml).reference.k_u == 1.59
    assert "the bound sets it" in cap.out
    rc = main(["tune", "speed", "--speeds", "1", "--u-ff", "0.6", "--k-u", "1.2,1.59",
               "--u-cmd-max", "5", "--distance", "50", "--out", str(tmp_path / "p"),
               "--quiet"])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 0 and "warning: recommended k_u = 1.59 is the grid's largest" in err, err


@needs_cases
@pytest.mark.parametrize("vessel", ["otter.toml", "cybership2.toml"])
def test_tune_speed_runs_on_third_party_hulls(tmp_path, capsys, vessel):
    """Acceptance of issue 13: `mpcasv tune speed` on the Otter and CyberShip II files, no
    traceback, honest margins (exit 0 = pass, 1 = acceptance FAIL; never an exception)."""
    rc = main(["tune", "speed", "--vessel", str(CASES / "vessels" / vessel), "--out",
               str(tmp_path), "--u-ff", "0.6", "--k-u", "1.59", "--distance", "50",
               "--quiet"])  # fmt: skip
    out = capsys.readouterr().out
    assert rc in (0, 1) and "loop margins" in out
    assert not re.search(r"\| -?\d+ / inf \|", out)  # no 'inf' sampled phase margin


def test_speed_steps_flag_thrust_saturation_and_speeds_beyond_the_boat(model, shipped):
    """`tune speed`'s steps on the nonlinear loop: a step to beyond the straight-course top
    speed is flagged unreachable (not run); a step whose first command, feed-forward plus
    Kp times the step, is beyond T_max (or below T_min) starts saturated, and is slower than
    the linear loop that has no limit; a step whose first command is within the limits never
    reaches one and matches the linear loop (with the feed-forward) it was designed on."""
    from mpcasv.control.tuning_report import speed_tables
    from mpcasv.control.tuning_speed import feed_forward_gain, speed_step

    P, g = model.params, shipped.speed
    top = min(model.top_speed, P.u_max)
    beyond = speed_step(model, shipped, top, top + 0.5)
    assert not beyond["reachable"] and beyond["why"].startswith("UNREACHABLE")

    def first(u0, u1):  # the first thrust command (N); integrator's trim ~0 from 1 m/s
        return model.thrust_for_speed(u1) + g.Kp * (u1 - u0)

    def linear(u0, u1):
        return speed_figures(surge_plant(model, u0), g, 0.1, step=u1 - u0,
                             ff=feed_forward_gain(model, u0))  # fmt: skip

    up, down, small = (2.0, 2.5), (1.0, 0.5), (1.5, 1.6)
    assert first(*up) > P.T_max and first(*down) < P.T_min
    assert P.T_min < first(*small) < P.T_max and P.T_min < first(1.5, 1.4) < P.T_max
    s_up, s_down, s_small = (speed_step(model, shipped, *s) for s in (up, down, small))
    assert s_up["at_T_max"] > 0 and s_up["rise_s"] > linear(*up)["rise_s"]
    assert s_down["at_T_min"] > 0 and s_down["rise_s"] > linear(*down)["rise_s"]
    assert s_small["at_T_max"] == 0 and s_small["at_T_min"] == 0
    lin = linear(*small)
    assert s_small["rise_s"] == pytest.approx(lin["rise_s"], abs=0.2)
    assert s_small["overshoot_pct"] == pytest.approx(lin["overshoot_pct"], abs=2.0)
    # the report says the direction, the flag and the unreachable step
    f = speed_figures(surge_plant(model, top), g, 0.1)
    text = speed_tables(g, {top: (f, f), 1.5: (f, f)}, {}, None,
                        {top: [beyond], 1.5: [s_small]}, "limits")  # fmt: skip
    row_top = next(r for r in text.splitlines() if r.startswith(f"| {top:g} | up to"))
    row_small = next(r for r in text.splitlines() if r.startswith("| 1.5 | up to 1.6"))
    assert "UNREACHABLE" in row_top and row_small.endswith("| none |")
    text = speed_tables(g, {2.0: (f, f)}, {}, None, {2.0: [s_up]}, "limits")
    assert "SATURATED: T_max" in next(r for r in text.splitlines() if "| 2 | up to 2.5" in r)


@pytest.mark.parametrize("u1", [0.505, 0.495])
def test_a_speed_step_starts_the_speed_integrator_in_trim(model, shipped, monkeypatch, u1):
    """`speed_step` starts the boat in trim at u0, and the speed loop too: the integrator holds
    what the feed-forward T_ff leaves out of the trim thrust (the idle-drive drag, +1.24 N at
    0.5 m/s on Gretha). Its first thrust command is then trim + T_ff(u1) - T_ff(u0) + Kp
    (u1 - u0), and a step small enough for the model to stay linear (5 mm/s, no thrust limit)
    matches the linear loop's: rise within 0.2 s, overshoot within 2 % of the step, settling
    within 1 s. With the integrator started at 0 it did not (0.5 -> 0.505 m/s: rise 4.5 s, no
    overshoot; 0.5 -> 0.495 m/s: rise 1.2 s, overshoot 56 %; linear 1.7 s and 21 %)."""
    from mpcasv.control import tuning_speed as ts
    from mpcasv.control.execution import feed_forward_thrust

    runs = []

    def capture(*args, **kw):
        runs.append(run_closed_loop(*args, **kw))
        return runs[-1]

    monkeypatch.setattr(ts, "run_closed_loop", capture)
    u0, g, P = 0.5, shipped.speed, model.params
    T0, ff = model.thrust_for_speed(u0), lambda u: float(feed_forward_thrust(u, P))
    assert T0 - ff(u0) > 1.0  # the trim of the integrator is not 0 at this speed
    s = ts.speed_step(model, shipped, u0, u1)
    assert runs[0].U[1, 0] == pytest.approx(T0 + ff(u1) - ff(u0) + g.Kp * (u1 - u0), abs=1e-6)
    lin = speed_figures(surge_plant(model, u0), g, 0.1, step=u1 - u0,
                        ff=ts.feed_forward_gain(model, u0))  # fmt: skip
    assert s["at_T_max"] == 0 and s["at_T_min"] == 0
    assert s["rise_s"] == pytest.approx(lin["rise_s"], abs=0.2)
    assert s["overshoot_pct"] == pytest.approx(lin["overshoot_pct"], abs=2.0)
    assert s["settling_s"] == pytest.approx(lin["settling_s"], abs=1.0)


def test_the_pirouette_and_turn_plots_show_what_the_runs_do(model, shipped, tmp_path,
                                                            monkeypatch):  # fmt: skip
    """pirouette.png: the pirouette's label says what its whole run does (it passes within
    5 m of the waypoint, then circles it to the end; the rest is drawn), the legend is
    outside the paths' axes. turns_10m.png: one panel per angle, so the "no ref. model" 90
    deg run is not under the 180 deg one."""
    from mpcasv.control import tuning_report as tr
    from mpcasv.control.tuning_speed import PIROUETTE_CASE, pirouette_check, turn_grid

    figs = []
    monkeypatch.setattr(tr.plt, "close", figs.append)
    ep = dataclasses.replace(shipped, turn_thrust=0.0)
    a, d, u0 = PIROUETTE_CASE
    checks = pirouette_check(model, ep, a, d, u0)
    wp = (d * math.cos(math.radians(a)), d * math.sin(math.radians(a)))
    tr.plot_pirouette(checks, wp, tmp_path, "t")
    run, f = checks["without"]
    total = np.degrees(np.sum(np.abs(np.diff(np.unwrap(run.X[:, 2])))))
    assert f["pirouette"] and total > 720  # it circles the waypoint: more than two turns
    fig = figs[-1]
    labels = [t.get_text() for lg in fig.legends for t in lg.get_texts()]
    assert not fig.axes[0].get_legend()  # not over the start and the waypoint
    label = next(t for t in labels if t.startswith("without"))
    assert "then (dashed)" in label and f"turned {total:.0f} deg" in label
    dist = np.hypot(run.X[:, 0] - wp[0], run.X[:, 1] - wp[1])
    out = int(np.argmax((dist >= 5.0) & (np.cumsum(dist < 5.0) > 0)))  # leaves 5 m again
    assert f"circles it {dist[out:].min():.1f}-{dist[out:].max():.1f} m away" in label
    assert any(len(ln.get_xdata()) == len(run.t) - int(np.argmax(np.hypot(
        run.X[:, 0] - wp[0], run.X[:, 1] - wp[1]) < 5.0)) for ln in fig.axes[0].lines)
    rows, runs = turn_grid(model, ep, [(0.6, 1.59), (model.params.u_max, 0.0)], distance=10.0)
    tr.plot_speed(model, ep.speed, {10.0: (rows, runs)}, (0.6, 1.59), None, tmp_path)
    fig = figs[-1]
    for ax, angle in zip(fig.axes, (90, 180), strict=True):
        assert ax.get_title() == f"{angle} deg turn"
        assert sum(ln.get_label().startswith("no ref. model") for ln in ax.lines) == 1
    no_ref_90 = next(ln for ln in fig.axes[0].lines if ln.get_label().startswith("no ref"))
    assert "PIROUETTE" in no_ref_90.get_label()  # as the grid's table says (P)


def test_the_pirouette_label_gives_the_circling_after_the_pass(tmp_path, monkeypatch):
    """The label's distance range is the circling's after the pass: it read "5-11 m" with the
    minimum taken over the samples from the first one already inside 5 m. A made-up run that
    passes 1 m from the waypoint and then circles it 6-11 m away says 6.0-11.0 m."""
    from mpcasv.control import tuning_report as tr
    from mpcasv.control.tuning import Run

    figs = []
    monkeypatch.setattr(tr.plt, "close", figs.append)
    t = np.arange(0.0, 60.05, 0.1)
    X = np.zeros((len(t), 8))
    k = t < 14.85  # the pass: east along N = 1 m, closest at E = 0, ends inside 5 m
    X[k, 0], X[k, 1] = 1.0, t[k] - 10.0
    a = 2 * math.pi * (t[~k] - 15.0) / 20.0  # then a circle of 8.5 m radius around (2.5, 0)
    X[~k, 0], X[~k, 1] = 2.5 + 8.5 * np.cos(a), 8.5 * np.sin(a)
    X[:, 2] = np.linspace(0.0, 10.0, len(t))
    run = Run(t=t, X=X, U=np.zeros((len(t), 2)), Y=np.zeros((len(t), 2)))
    f = {"pirouette": True, "turn_s": math.inf, "total_turn_deg": 573.0}
    tr.plot_pirouette({"with": (run, f), "without": (run, f)}, (0.0, 0.0), tmp_path, "t")
    label = next(t.get_text() for lg in figs[-1].legends for t in lg.get_texts()
                 if t.get_text().startswith("without"))  # fmt: skip
    assert "within 5 m of the waypoint at 5 s" in label, label
    assert "circles it 6.0-11.0 m away to 60 s" in label, label


def test_a_speed_loop_crossing_over_below_the_sweep_is_measured_and_its_steps_must_settle(
        model, tmp_path, capsys):  # fmt: skip
    """`tune speed --w 0.0001`: Kp 0, Ki ~1e-5, crossover ~1e-7 rad/s. The margin sweep
    started at 1e-4 rad/s, found no crossover and overrode python-control's 90 deg with "inf";
    "loop margins PASS" although a step from 0.5 to 1 m/s never settled in 120 s. The sweep
    now starts below the loop's crossover, and the steps must settle (exit 1, TOML kept)."""
    import control as ct

    from mpcasv.control.tuning import loop_margins
    from mpcasv.control.tuning_speed import pi_tf

    g = place_speed_pi(model, 1.0, 1e-4, 1.0)
    assert g.Kp == 0 and g.Ki < 2e-5
    for dt in (None, 0.1):
        P = surge_plant(model, 1.0)
        L = ct.ss(pi_tf(g, dt)) * (ct.c2d(P, dt, "zoh") if dt else P)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m = loop_margins(L)
        assert m["phase_margin_deg"] == pytest.approx(90.0, abs=0.5), m
        assert m["w_gain_crossover"] == pytest.approx(1.1e-7, rel=0.05)
    toml = tmp_path / "e.toml"
    rc = main(["tune", "speed", "--w", "0.0001", "--speeds", "1", "--u-ff", "0.6", "--k-u",
               "1.59", "--distance", "50", "--out", str(tmp_path / "o"), "--toml", str(toml),
               "--quiet"])  # fmt: skip
    out = capsys.readouterr().out
    assert rc == 1 and not toml.exists()
    assert "loop margins PASS; speed steps settle (2 %, within 120 s): FAIL: " in out
    assert "1->0.5 m/s" in out


def test_the_regenerate_recipe_in_the_toml_uses_the_real_out(tmp_path, capsys):
    """The TOML's "Regenerate" recipe said `--out runs/tune-yaw` / `runs/tune-speed` whatever
    `--out` was given; it now holds the command that wrote the file, this run's --out, and
    the other tool's --out from its provenance (Gretha's shipped yaw: runs/tune-yaw)."""
    import shlex

    out, toml = tmp_path / "my speed", tmp_path / "e.toml"
    rc = main(["tune", "speed", "--speeds", "1", "--u-ff", "0.6", "--k-u", "1.59", "--distance",
               "50", "--out", str(out), "--toml", str(toml), "--quiet"])  # fmt: skip
    capsys.readouterr()
    head = [ln for ln in toml.read_text().splitlines() if ln.startswith("#")]
    q = shlex.quote(str(out))
    assert rc == 0
    assert any(ln.startswith("# Written by: mpcasv tune speed ") and f"--out {q}" in ln
               for ln in head), head  # fmt: skip
    speed = next(ln for ln in head if ln.startswith("#   mpcasv tune speed"))
    assert f"--out {q} " in speed and "runs/tune-speed" not in speed
    assert any(ln.startswith("#   mpcasv tune yaw --out runs/tune-yaw ") for ln in head)


def _orbit(rho: float, loops: float = 3.0):
    """A synthetic turn to the waypoint (0, 10) m: straight at it from the origin, on course
    until 5 m from it (off course from there: it arrives turning), to 1 m from it, then
    orbiting it at radius ``rho`` m, 90 deg off the line of sight, for ``loops`` turns."""
    from types import SimpleNamespace

    approach = np.linspace(0.0, 9.0, 90)
    ang = np.linspace(0.0, 2 * np.pi * loops, int(200 * loops))
    N = np.concatenate([np.zeros_like(approach), rho * np.sin(ang)])
    E = np.concatenate([approach, 10.0 - rho * np.cos(ang)])
    psi = np.concatenate([np.full_like(approach, np.pi / 2), np.pi / 2 + ang])
    err = np.concatenate([np.where(approach > 5.0, np.pi / 2, 0.0), np.full_like(ang, np.pi / 2)])
    X = np.zeros((len(N), 6))
    X[:, 0], X[:, 1], X[:, 2] = N, E, psi
    return SimpleNamespace(X=X, psi_error=err)


def test_an_orbit_inside_the_arrival_circle_is_not_a_pirouette_one_round_it_is():
    """After the arrival only the turning outside the circle counts: a small hull that passed
    the waypoint and orbits within 2 m of it reached it (every dune-otter turn read as a
    pirouette, 496 deg, a review); one that passed it and loops round it at 8 m circles it
    (3 loops)."""
    from mpcasv.control.tuning_speed import ARRIVAL_RADIUS, PIROUETTE_TURN, circling

    assert ARRIVAL_RADIUS > 2.0
    assert circling(_orbit(2.0), (0.0, 10.0), math.radians(90.0)) == 0.0
    round_it = circling(_orbit(8.0), (0.0, 10.0), math.radians(90.0))
    assert round_it > 2 * PIROUETTE_TURN and round_it == pytest.approx(3 * 2 * np.pi, rel=0.02)


def test_the_bound_is_said_to_set_k_u_only_when_it_does():
    """(0.4, 1.2) recommended while (0.4, 1.59) was within u_cmd,max = 3.1 m/s and lost on
    time: the note said "the bound sets it" (a review); it is the grid's smallest k_u. With
    every larger k_u at that u_ff above the bound, the bound does set it."""
    from mpcasv.control.tuning_speed import TurnRow, edge_notes, recommend

    def rows(costs):
        return [TurnRow(u_ff=a, k_u=b, figures={90.0: {"turn_s": t, "reached": True,
                                                       "pirouette": False}})
                for (a, b), t in costs.items()]  # fmt: skip

    r = rows({(0.4, 1.2): 10.0, (0.4, 1.59): 12.0, (0.4, 2.0): 5.0, (0.6, 1.2): 11.0})
    best = recommend(r, 3.1)
    assert (best.u_ff, best.k_u) == (0.4, 1.2)
    notes = edge_notes(best, r, 3.1)
    assert not any("the bound sets it" in n for n in notes)
    assert any(n.startswith("k_u = 1.2 is the grid's smallest") for n in notes)
    r = rows({(0.4, 1.2): 10.0, (0.4, 2.0): 5.0, (0.6, 1.2): 11.0})
    assert any("the bound sets it" in n for n in edge_notes(recommend(r, 3.1), r, 3.1))


def test_a_vessel_with_fast_steering_is_tuned_at_the_simulators_step(tmp_path):
    """The nonlinear checks' 0.1 s step was checked against the vessel's T_delta too, so Gretha
    with T_delta = 0.05 s could not be tuned at all (the simulator integrates the steering
    lag in its sub-steps; only the forward-Euler yaw-rate filter needs T_f >= 0.1 s)."""
    from mpcasv.config import ConfigError, resolve
    from mpcasv.control.tuning_checks import check_yaw_sampling
    from mpcasv.models.params import load_vessel
    from mpcasv.models.vessel import VesselModel

    text = resolve("vessels", "gretha").read_text()
    assert "T_delta = 0.3\n" in text
    path = tmp_path / "fast.toml"
    path.write_text(text.replace("T_delta = 0.3\n", "T_delta = 0.05\n", 1))
    model = VesselModel(load_vessel(path))
    check_yaw_sampling(model, 0.2, "--T-f")  # no refusal
    with pytest.raises(ConfigError, match="T_delta"):
        check_yaw_sampling(model, 0.2, "--T-f", dt=0.1)  # the sampled design at 0.1 s: refused


def test_no_recommendation_says_the_pairs_pirouetted_not_that_they_missed(tmp_path, capsys,
                                                                          monkeypatch):
    """Every pair reached every waypoint and pirouetted: the summary line said "no pair of the
    grid reached every waypoint" (speed.md said the right thing; a review). It says why."""
    from mpcasv.control import tuning_turns as ts

    real = ts.turn

    def pirouetting(*a, **k):
        run, f = real(*a, **k)
        return run, f | {"pirouette": True}

    monkeypatch.setattr(ts, "turn", pirouetting)
    rc = main(["tune", "speed", "--speeds", "1", "--u-ff", "0.6", "--k-u", "1.59",
               "--distance", "50", "--out", str(tmp_path / "o"), "--quiet"])  # fmt: skip
    line = next(s for s in capsys.readouterr().out.splitlines()
                if s.startswith("no recommended"))  # fmt: skip
    assert rc == 0 and "reached every waypoint" not in line, line
    assert "1 pirouetted in a turn (P)" in line and "(NR)" not in line, line


def _spin(turns: float, wp=(0.0, 30.0)):
    """A synthetic boat spinning at 10 deg/s on a 1 m circle at the origin, never nearer the
    waypoint ``wp`` (m) than 29 m: its bow sweeps through the waypoint's bearing once a turn."""
    from types import SimpleNamespace

    psi = np.radians(10.0) * np.arange(0.0, 36.0 * turns, 0.1)
    N, E = np.sin(psi), 1.0 - np.cos(psi)
    X = np.zeros((len(psi), 6))
    X[:, 0], X[:, 1], X[:, 2] = N, E, psi
    los = np.arctan2(wp[1] - E, wp[0] - N)
    return SimpleNamespace(X=X, psi_error=(psi - los + np.pi) % (2 * np.pi) - np.pi)


def test_a_boat_spinning_through_its_heading_is_a_pirouette():
    """Three and a third turns of spin, the bow crossing the waypoint's bearing each turn
    (within 10 deg for 2 s): the rule cut the count at each crossing (339 deg of 1199, no
    pirouette; a review). Crossing the bearing is not heading for the waypoint: that needs
    the error within the band and the boat closing on it (|psi_e| < pi/2) until it arrives.
    A boat that heads for it and wobbles 15 deg out of the band on the way is not circling."""
    from types import SimpleNamespace

    from mpcasv.control.tuning_speed import PIROUETTE_TURN, circling

    spin = _spin(10 / 3)
    turned = float(np.sum(np.abs(np.diff(spin.X[:, 2]))))
    assert turned > 3 * 2 * np.pi
    assert circling(spin, (0.0, 30.0), math.radians(90.0)) > PIROUETTE_TURN
    # on course (east) from the start, weaving +-15 deg on the way to the waypoint 30 m east
    t = np.arange(0.0, 30.0, 0.1)
    err = np.radians(15.0) * np.sin(2 * np.pi * t / 5.0)
    X = np.zeros((len(t), 6))
    X[:, 1], X[:, 2] = t, np.pi / 2 + err
    weave = SimpleNamespace(X=X, psi_error=err)
    # commanded turn 0: with 90 deg (as until a review) the allowance for the commanded turn
    # absorbed the wobble, and the check passed whether or not the wobble counted
    assert circling(weave, (0.0, 30.0), 0.0) < math.radians(30.0)


def test_a_far_waypoint_is_reached_in_a_run_as_long_as_the_distance_needs(model, shipped):
    """Every turn ran 150 s: a waypoint 400 m away was "not reached" (NR) by every pair, a
    property of the run length, not of the tuning (a review). The run is 150 s for the turn
    plus the distance at the slowest speed eq. 3.1 asks for, min(u_ff, u_max)."""
    ep = dataclasses.replace(shipped, turn_thrust=0.0)
    run, f = turn(model, ep, math.radians(90.0), 400.0)
    assert f["reached"] and not f["pirouette"] and f["reach_s"] > 150.0
    from mpcasv.control.tuning_speed import ARRIVAL_RADIUS, TURN_T_END, turn_time

    u_slow = min(ep.reference.u_ff, model.params.u_max)
    assert turn_time(model, ep, 400.0) == pytest.approx(TURN_T_END + 400.0 / u_slow)
    assert run.t[-1] == pytest.approx(turn_time(model, ep, 400.0), abs=0.5)  # whole steps
    with pytest.raises(ValueError, match="inside the 5 m arrival circle"):
        turn(model, ep, math.radians(90.0), 0.6 * ARRIVAL_RADIUS)


def test_the_bound_is_the_base_files_own_and_says_so_and_the_radius_is_stated(tmp_path,
                                                                              capsys):
    """`tune speed --vessel dune-otter` bounds u_ff + k_u pi/2 by the base file's (Gretha's)
    3.0976 m/s, as before a review's default from vessel names parsed out of the provenance
    (it refused working commands): speed.md and stderr say where the bound came from; the
    5 m arrival radius is stated as fixed, beside the hull length."""
    from mpcasv.models.params import load_vessel

    P = load_vessel("dune-otter")
    rc = main(["tune", "speed", "--vessel", "dune-otter", "--speeds", "1", "--u-ff", "0.6",
               "--k-u", "1.59,2", "--distance", "50", "--out", str(tmp_path / "o"),
               "--quiet"])  # fmt: skip
    cap = capsys.readouterr()
    md = (tmp_path / "o" / "speed.md").read_text()
    origin = ("--u-cmd-max defaulted to the --base file's own u_ff + k_u pi/2 = 3.0976 m/s "
              "(--base gretha: u_ff = 0.6, k_u = 1.59 m/s); for another hull pass --u-cmd-max")
    assert rc == 0 and "u_ff + k_u pi/2 <= 3.098 m/s (--u-cmd-max)" in md, md
    assert f"- {origin}" in md and f"mpcasv tune: note: {origin}" in cap.err, cap.err
    assert "below --u-cmd-max" not in cap.err  # dune-otter's u_max 3.48 m/s is above it
    assert f"a fixed radius for every vessel; dune-otter is {P.L:g} m long" in md
