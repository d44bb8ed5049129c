"""Tests of the yaw tuning (mpcasv.control.tuning_yaw, tuning_schedule), the shared margin and
step tools (mpcasv.control.tuning) and the shipped schedule; the speed loop, its steps and the
reference model are in test_tuning_speed.py."""

from __future__ import annotations

import dataclasses
import json
import math
import re
import warnings

import control as ct
import numpy as np
import pytest

from mpcasv.cli import main
from mpcasv.control.params import load_execution
from mpcasv.control.tuning import FAR, run_closed_loop
from mpcasv.control.tuning_speed import speed_figures
from mpcasv.control.tuning_yaw import (
    PIDGains,
    heading_step,
    loop_figures,
    nomoto,
    place_pid,
    schedule_params,
    yaw_loop,
    yaw_plant,
)  # fmt: skip
from mpcasv.models.params import load_vessel
from mpcasv.models.vessel import IX, VesselModel

warnings.filterwarnings("ignore", category=UserWarning, module="control")


@pytest.mark.parametrize("u0", [0.5, 1.5, 2.5])
def test_nomoto_matches_linearised_model(model, u0):
    """Second-order Nomoto x steering lag == delta_cmd -> r of the full 8-state Jacobians."""
    nm = nomoto(model, u0)
    assert nm.K > 0 and nm.T1 > nm.T2 > 0 and nm.T == pytest.approx(nm.T1 + nm.T2 - nm.T3)
    A, B = model.linearize(*model.trim(u0))
    lag = ct.tf([1.0], [model.params.T_delta, 1.0])
    for w in (0.01, 0.3, 1.0, 5.0):
        full = np.linalg.solve(1j * w * np.eye(8) - A, B[:, 1])[IX["r"]]
        assert complex((nm.second_order() * lag)(1j * w)) == pytest.approx(full, rel=1e-6)
    # the first-order model has the same DC gain and is close at low frequency
    assert complex(nm.first_order()(0.01j)) == pytest.approx(complex(nm.second_order()(0.01j)),
                                                             rel=0.01)  # fmt: skip


def test_pole_placement_on_nomoto(model):
    nm = nomoto(model, 1.5)
    wn, zeta, ratio = 0.45, 0.9, 0.5
    g = place_pid(nm, wn, zeta, ratio)
    s = ct.tf("s")
    psi_delta = nm.first_order() / s
    cl = ct.feedback(psi_delta, g.Kp + g.Ki / s + g.Kd * s)  # ideal PID, no lag
    want = np.sort_complex(np.roots(np.polymul([1, 2 * zeta * wn, wn**2], [1, ratio * wn])))
    assert np.allclose(np.sort_complex(ct.poles(cl)), want, atol=1e-6)


@pytest.mark.parametrize("u0", [1.0, 2.0])
def test_sampled_linear_loop_matches_nonlinear_execution_level(model, shipped, u0):
    """A 1 deg step: the linear sampled loop (built by hand from ss/tf) and the compiled
    nonlinear execution level + model agree (the loop structure and signs are right)."""
    ep = shipped
    speeds = np.array(ep.yaw.speeds)
    g = PIDGains(*(float(np.interp(u0, speeds, k)) for k in (ep.yaw.Kp, ep.yaw.Ki, ep.yaw.Kd)))
    step = math.radians(1.0)
    x0, _ = model.trim(u0)
    run = run_closed_loop(model, ep, x0, (FAR * math.cos(step), FAR * math.sin(step)), u0, 40.0)
    loop = yaw_loop(yaw_plant(model, u0), g, ep.yaw.T_f, dt=0.1)
    lin = ct.step_response(loop.T_ref, run.t).outputs * step
    assert np.abs(run.X[:, 2] - lin).max() < 0.03 * step
    assert abs(run.X[-1, 2] - step) < 0.02 * step  # integral action: no steady error


def test_loop_figures_detect_a_bad_design(model):
    P = yaw_plant(model, 2.5)
    good = loop_figures(yaw_loop(P, PIDGains(2.4, 0.45, 2.5), 0.2, dt=0.1))
    bad = loop_figures(yaw_loop(P, PIDGains(60.0, 0.45, 0.0), 0.2, dt=0.1))
    assert good["phase_margin_deg"] >= 45 and good["stable"]
    assert bad["phase_margin_deg"] < 45  # high gain, no derivative: the lag eats the phase


def test_shipped_schedule_meets_acceptance(model, shipped):
    """The simulator's default gains: PM >= 45 deg, GM >= 6 dB with the steering lag
    (continuous and sampled), and the nonlinear 45 deg step settles within the stated time."""
    stated = float(re.search(r"within ([0-9.]+) s", shipped.provenance).group(1))
    for i, u0 in enumerate(shipped.yaw.speeds):
        g = PIDGains(shipped.yaw.Kp[i], shipped.yaw.Ki[i], shipped.yaw.Kd[i])
        for dt in (None, 0.1):
            f = loop_figures(yaw_loop(yaw_plant(model, u0), g, shipped.yaw.T_f, dt))
            assert f["phase_margin_deg"] >= 45 and f["gain_margin_db"] >= 6, (u0, dt, f)
            assert f["dist_recover_s"] < 60  # a constant yaw moment is trimmed out
        _, nl = heading_step(model, shipped, u0)
        assert nl["settling_s"] <= stated + 1e-9, (u0, nl)


def test_shipped_schedule_is_the_tune_yaw_design(model, shipped):
    """The shipped [yaw] table is what `mpcasv tune yaw` with its defaults designs."""
    wn = [float(v) for v in re.search(r"wn \[([^\]]+)\]", shipped.provenance).group(1).split(",")]
    for i, (u0, w) in enumerate(zip(shipped.yaw.speeds, wn, strict=True)):
        g = place_pid(nomoto(model, u0), w, 1.0, 0.5)
        got = (shipped.yaw.Kp[i], shipped.yaw.Ki[i], shipped.yaw.Kd[i])
        assert got == pytest.approx((g.Kp, g.Ki, g.Kd), rel=1e-4, abs=1e-5)


def test_cli_tune_yaw_writes_loadable_schedule(tmp_path, shipped):
    toml = tmp_path / "exec.toml"
    rc = main(["tune", "yaw", "--speeds", "1,2", "--wn", "0.3,0.6", "--out", str(tmp_path),
               "--toml", str(toml), "--quiet"])  # fmt: skip
    assert rc == 0
    ep = load_execution(toml)
    assert ep.yaw.speeds == (1.0, 2.0) and ep.speed == shipped.speed
    assert (tmp_path / "step_yaw.png").stat().st_size > 10_000
    assert (tmp_path / "bode_yaw_u2.png").exists() and "| 2 |" in (tmp_path / "yaw.md").read_text()
    assert "tune yaw" in ep.provenance
    # the schedule interpolates: what the schedule helper builds is what was written
    again = schedule_params(
        shipped,
        [1.0, 2.0],
        [PIDGains(ep.yaw.Kp[i], ep.yaw.Ki[i], ep.yaw.Kd[i]) for i in range(2)],
        0.2,
    )
    assert again.yaw == ep.yaw


def test_default_yaw_design_of_a_differential_thrust_boat_passes_at_every_speed(tmp_path):
    """A differential-thrust boat's yaw dynamics do not change with speed (dune-otter's Nomoto
    K and T are the same from 0.7 to 3.5 m/s), so its default wn is one value,
    WN_LAG_FRACTION / T_delta, not proportional to speed: with 0.3 u0 the default design
    failed (phase margin 21 deg at 3.5 m/s; 0.21 rad/s at 0.7 m/s, sluggish)."""
    from mpcasv.control.tune_cli import WN_LAG_FRACTION

    otter = load_vessel("dune-otter")
    toml = tmp_path / "exec.toml"
    rc = main(["tune", "yaw", "--vessel", "dune-otter", "--speeds", "0.7,3.4", "--out",
               str(tmp_path), "--toml", str(toml), "--quiet"])  # fmt: skip
    assert rc == 0, "the default design failed its acceptance"
    wn = [d["wn"] for d in json.loads((tmp_path / "yaw.json").read_text())]
    assert wn == [pytest.approx(WN_LAG_FRACTION / otter.T_delta)] * 2
    ep = load_execution(toml)
    assert ep.yaw.Kp[0] == pytest.approx(ep.yaw.Kp[1])  # the same loop at both speeds
    assert "--wn 0.6" in ep.provenance


def test_cli_refuses_mismatched_wn(tmp_path, capsys):
    rc = main(["tune", "yaw", "--speeds", "1,1.5,2", "--wn", "0.3,0.6", "--out", str(tmp_path)])
    assert rc == 2 and "--wn: 2 values for 3 speeds" in capsys.readouterr().err


@pytest.mark.parametrize("what", ["yaw", "speed"])
def test_cli_refuses_speeds_beyond_the_vessels_top_speed(tmp_path, capsys, what):
    """Issue 13 item 4: tuning steps at speeds the vessel cannot hold at T_max are refused."""
    rc = main(["tune", what, "--speeds", "1,3", "--out", str(tmp_path), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "speeds [3.0] m/s outside (0, 2.5] m/s: gretha cannot hold them" in err


from shared_data import CASES  # noqa: E402  (../shared beside the checkout)
from shared_data import needs_shared as needs_cases  # noqa: E402


@needs_cases
@pytest.mark.parametrize("vessel", ["otter.toml", "cybership2.toml"])
def test_unstable_hull_tune_yaw_refuses_in_one_line(tmp_path, capsys, vessel):
    """../shared/cases/unstable-hull-tune-yaw: a course-unstable hull (Otter, CyberShip II in
    the 3-DOF form) gives one line naming the speed and the unstable pole, exit 2, no
    traceback, no schedule written."""
    path = CASES / "vessels" / vessel
    rc = main(["tune", "yaw", "--vessel", str(path), "--out", str(tmp_path), "--quiet"])
    err = [line for line in capsys.readouterr().err.splitlines() if "error:" in line]
    assert rc == 2 and len(err) == 1
    assert re.search(r"course-unstable at u0=[0-9.]+ m/s \(sway-yaw pole \+[0-9.]+ 1/s", err[0])
    assert not (tmp_path / "execution.toml").exists()


@needs_cases
def test_unstable_nomoto_model_has_negative_T_and_pole_placement_stabilises_it():
    """../shared/cases/unstable-hull-tune-yaw: the first-order Nomoto model of the Otter at
    0.5 m/s has T < 0 (and K < 0, K/T > 0); the PID placed on it puts the poles of the
    first-order loop where asked (Fossen's pole placement covers T < 0)."""
    m = VesselModel(load_vessel(CASES / "vessels" / "otter.toml"))
    assert np.max(m.sway_yaw_eigenvalues(0.5).real) > 0.1  # course-unstable (+0.20 1/s)
    nm = nomoto(m, 0.5)
    assert nm.T < 0 and nm.K < 0
    wn, zeta, ratio = 0.6, 1.0, 0.5
    g = place_pid(nm, wn, zeta, ratio)
    assert g.Kp > 0 and g.Ki > 0 and g.Kd > 0
    s = ct.tf("s")
    cl = ct.feedback(nm.first_order() / s, g.Kp + g.Ki / s + g.Kd * s)
    want = np.sort_complex(np.roots(np.polymul([1, 2 * zeta * wn, wn**2], [1, ratio * wn])))
    assert np.allclose(np.sort_complex(ct.poles(cl)), want, atol=1e-6)


@needs_cases
def test_sampled_phase_margin_is_cross_checked_by_a_sweep():
    """../shared/cases/sampled-phase-margin: python-control gives PM = inf for this sampled
    loop; the reported margin is the sweep's, ~77.7 deg at ~0.098 rad/s, and says so."""
    from mpcasv.control.params import SpeedLoop

    P = ct.ss([[-0.90706433, 0.01169591], [0.0, -1.0]], [[0.0], [1.0]], [[1.0, 0.0]], [[0.0]])
    g = SpeedLoop(Kp=0.0, Ki=7.695)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        samp, cont = speed_figures(P, g, 0.1), speed_figures(P, g)
    assert samp["phase_margin_deg"] == pytest.approx(77.7, abs=0.3)
    assert samp["w_gain_crossover"] == pytest.approx(0.098, abs=0.001)
    assert "python-control inf" in samp["margin_check"]
    assert cont["phase_margin_deg"] == pytest.approx(78.2, abs=0.3)  # continuous: agree
    assert cont["margin_check"] == "python-control = sweep"


def test_margins_without_crossover_are_infinite_only_if_the_sweep_agrees():
    from mpcasv.control.tuning import loop_margins, sweep_margins

    L = ct.tf([0.5], [1.0, 1.0])  # |L| < 1 everywhere: no gain crossover, no phase crossover
    m = loop_margins(L)
    assert m["phase_margin_deg"] == math.inf and m["margin_check"] == "python-control = sweep"
    L2 = ct.tf([4.0], [1.0, 2.0, 1.0, 0.0])  # crossover near 1.3 rad/s, closed loop unstable
    sw = sweep_margins(L2, np.logspace(-3, 2, 20000))
    assert sw["phase_margin_deg"] < 0 and sw["gain_margin_db"] < 0


def test_a_response_that_does_not_settle_reads_not_reached():
    from mpcasv.control.tuning import step_figures
    from mpcasv.control.tuning_report import _t

    t = np.arange(0.0, 50.0, 0.1)
    f = step_figures(np.exp(0.1 * t) - 1.0, t, 1.0)  # diverges
    assert f["settling_s"] == math.inf and _t(f["settling_s"]) == "not reached"
    f = step_figures(1.0 - np.cos(t), t, 1.0)  # oscillates for ever
    assert f["settling_s"] == math.inf


def test_the_yaw_bode_plot_names_its_loop_and_gives_the_gain_margin_in_db(model):
    """`tune yaw`'s Bode plot read "sys[372]: Gm = 25.76 (at ...)": python-control's name of
    an unnamed system and the gain margin as a ratio. It names the loop (a speed with a
    ".", which a python-control system's name may not hold) and gives GM in dB, PM in deg."""
    import matplotlib.pyplot as plt

    from mpcasv.control.tuning import loop_margins
    from mpcasv.control.tuning_report import bode_yaw_figure

    d = dataclasses.make_dataclass("Design", ["u0", "gains"])(2.5, PIDGains(2.4, 0.45, 2.5))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fig = bode_yaw_figure(model, d, 0.2)
        want = loop_margins(yaw_loop(yaw_plant(model, 2.5), d.gains, 0.2).L)
    try:
        assert fig._suptitle.get_text() == "yaw loop at u0 = 2.5 m/s (broken at steering command)"
        line = fig.axes[0].get_title()
        assert "sys[" not in line, line
        m = re.fullmatch(r"L \(u0 = 2\.5 m/s\): Gm = (\S+) dB \(at \S+ rad/s\), "
                         r"Pm = (\S+) deg \(at \S+ rad/s\)", line)  # fmt: skip
        assert m, line
        assert float(m[1]) == pytest.approx(want["gain_margin_db"], abs=0.1), line
        assert float(m[2]) == pytest.approx(want["phase_margin_deg"], abs=0.5), line
        assert fig.axes[0].get_ylabel() == "Magnitude [dB]"
    finally:
        plt.close(fig)


def test_the_nonlinear_heading_step_says_it_is_also_a_speed_change(model, shipped):
    """Eq. 3.1 cuts the speed reference of the 45 deg step to u_ff + k_u (pi/2 - pi/4) where
    that is below u0 (and the boat slows); below it the command's cap u0 holds. yaw.md says
    both causes of the slower rise, and the overshoot columns carry their units."""
    from mpcasv.control.tuning_report import yaw_table
    from mpcasv.control.tuning_yaw import tune_yaw

    ref = shipped.reference
    cut = ref.u_ff + ref.k_u * math.pi / 4
    _, fast = heading_step(model, shipped, 2.5)
    _, slow = heading_step(model, shipped, 0.5)
    assert fast["min_u_ref"] == pytest.approx(cut, abs=1e-3) and cut < 2.5
    assert fast["min_u"] < 2.5 - 0.25  # the boat follows it down (measured 2.00 m/s)
    assert slow["min_u_ref"] == pytest.approx(0.5, abs=1e-9)
    _, designs, _ = tune_yaw(model, shipped, [0.5, 2.5], [0.15, 0.75])
    text = yaw_table(designs)
    row = [r for r in text.splitlines() if r.startswith("| 2.5 |")][-1]  # the steps' table
    assert re.search(r"\d %", row) and re.search(r"\d deg, \d+ deg, \d\.\d\d \|$", row), row
    assert "overshoot (% of step)" in text and "overshoot (deg)" in text
    note = next(r for r in text.splitlines() if r.startswith("Nonlinear step"))
    assert "speed change" in note and f"to {cut:.2f} (boat down to" in note
    assert "at u0 = 2.5 m/s" in note and "0.5" not in note.split("speed change")[1]


@pytest.mark.parametrize("u0", [0.5, 1.5])
def test_the_heading_step_starts_in_trim_with_the_speed_integrator(model, shipped, u0):
    """A heading step of 0 from trim at ``u0`` holds ``u0``: the speed integrator starts at its
    trim value, as in the speed steps (it started at 0: 1.9 mm/s of sag at 0.5 m/s, where the
    feed-forward leaves the idle drive's drag to the integrator; ``turn`` starts it there too)."""
    run, _ = heading_step(model, shipped, u0, step=0.0, t_end=60.0)
    assert np.abs(run.X[:, IX["u"]] - u0).max() < 1e-6


def test_a_clipped_kd_and_the_margins_off_the_schedule_are_reported(model, shipped, tmp_path,
                                                                    capsys):  # fmt: skip
    """Gretha at 0.5 m/s: the pole placement's Kd is negative, clipped to 0, and the poles
    achieved are those of the loop with Kd = 0 (not the requested ones); at 1.5 m/s nothing
    is clipped. Below the lowest schedule speed the gains are held and the hull's steering
    authority falls (K ~ u^2): the phase margin falls with the speed and fails the bar at
    0.2 m/s; every row's verdict is its margins' against the bar. stdout says both."""
    from mpcasv.control.tuning_schedule import GM_MIN, PM_MIN, kd_clip, off_schedule

    nm = nomoto(model, 0.5)
    g = place_pid(nm, 0.15, 1.0, 0.5)
    clip = kd_clip(nm, g, 0.15, 1.0, 0.5)
    assert g.Kd == 0 and clip["Kd_formula"] == pytest.approx(
        (nm.T * (2 * 0.15 + 0.075) - 1) / nm.K) and clip["Kd_formula"] < 0
    s = ct.tf("s")
    cl = ct.feedback(nm.first_order() / s, g.Kp + g.Ki / s)  # the PI that is left
    got = np.sort_complex([complex(*p) for p in clip["poles_achieved"]])
    assert np.allclose(got, np.sort_complex(ct.poles(cl)), atol=1e-9)
    want = np.sort_complex([complex(*p) for p in clip["poles_requested"]])
    assert not np.allclose(got, want, atol=1e-3)
    assert kd_clip(nomoto(model, 1.5), place_pid(nomoto(model, 1.5), 0.45, 1.0, 0.5), 0.45,
                   1.0, 0.5) is None  # fmt: skip
    rows = off_schedule(model, shipped, 0.1)
    below = [r for r in rows if r["where"].startswith("below")]
    assert [r["u0"] for r in below] == [0.2, 0.3, 0.4]
    first = (shipped.yaw.Kp[0], shipped.yaw.Ki[0], shipped.yaw.Kd[0])
    assert all(r["gains"] == pytest.approx(first) for r in below)
    pms = [min(r["pm"]) for r in below]
    assert pms == sorted(pms) and not below[0]["ok"] and pms[0] < PM_MIN
    for r in rows:
        assert r["ok"] == (r["stable"] and min(r["pm"]) >= PM_MIN and min(r["gm"]) >= GM_MIN)
    between = [r["u0"] for r in rows if r["where"].startswith("between")]
    assert between == [0.75, 1.25, 1.75, 2.25]
    rc = main(["tune", "yaw", "--speeds", "0.5,1", "--out", str(tmp_path), "--quiet"])
    out = capsys.readouterr().out
    assert rc == 0 and "pole placement not achieved at 0.5 m/s: Kd = -2.05 s clipped to 0" in out
    assert "off the schedule: FAIL at 0.2 m/s (PM 38." in out
    assert "| 0.2 | below (gains held) |" in (tmp_path / "yaw.md").read_text()


def test_fossens_otter_refusal_names_the_zero_turn_gain_not_a_missing_steering_effect(
        tmp_path, capsys):  # fmt: skip
    """Fossen's Otter (shipped `otter`): the steering does act on the yaw acceleration (the
    Jacobian's dr_dot/d delta, 4.44 rad/s^2 per rad), but r/delta has a zero at s = 0 (its
    steady turn gain is zero) and a sway-yaw pole in the right half-plane. The refusal says
    that, in one line, exit 2 (it said "no first-order effect on the yaw rate")."""
    m = VesselModel(load_vessel("otter"))
    rc = main(["tune", "yaw", "--vessel", "otter", "--out", str(tmp_path), "--quiet"])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert rc == 2 and len(err) == 1 and "no first-order effect" not in err[0]
    u0 = float(re.search(r"at u0=([0-9.]+) m/s", err[0]).group(1))
    A, _ = m.linearize(*m.trim(u0))
    b_r = A[IX["r"], IX["delta"]]
    assert abs(b_r) > 1.0 and f"yaw acceleration ({b_r:.3g} rad/s^2 per rad)" in err[0]
    assert "steady turn gain r/delta(s=0) is zero" in err[0]
    p_max = np.linalg.eigvals(A[np.ix_([IX["v"], IX["r"]], [IX["v"], IX["r"]])]).real.max()
    assert p_max > 0 and f"{p_max:+.3g}" in err[0] and "right half-plane" in err[0]
    assert "Y_v = 0 in the vessel file" in err[0] and not (tmp_path / "execution.toml").exists()




def test_gains_held_above_the_schedule_are_checked_up_to_the_top_speed(tmp_path, capsys):
    """`tune yaw --speeds 0.5` PASSed: the 0.5 m/s gains held above it, up to Gretha's top
    speed 2.5 m/s, were never checked (sampled PM 30.1 deg there against the 45 deg bar). They
    run in every faster transit, so they count in the acceptance: exit 1, TOML not written."""
    from mpcasv.control.tuning_schedule import off_speeds

    assert [u for u, w in off_speeds([0.5], 2.5) if w.startswith("above")] == pytest.approx(
        [0.5 + 2 / 3, 0.5 + 4 / 3, 2.5], abs=1e-3)
    assert not [u for u, w in off_speeds([0.5, 2.5], 2.5) if w.startswith("above")]
    # a top speed a hair above the last schedule speed: one row at it, not three equal ones
    # (dune-otter: 3.4783 -> 3.47844 m/s gave three "3.4784", a review)
    assert [u for u, w in off_speeds([1.0, 3.4783], 3.47844) if w.startswith("above")] == [
        3.4784]
    toml = tmp_path / "e.toml"
    rc = main(["tune", "yaw", "--speeds", "0.5", "--out", str(tmp_path / "o"), "--toml",
               str(toml), "--quiet"])  # fmt: skip
    out = capsys.readouterr().out
    assert rc == 1 and not toml.exists()
    assert "| 2.5 | above (gains held) |" in out and "30.1 |" in out.split("| 2.5 | above")[1]
    assert "2.5 m/s (PM 30.1 deg" in out and "above them to the top speed: FAIL" in out
