"""Tests of the yaw / speed tuning tools (mpcasv.control.tuning*) and the shipped schedule."""

from __future__ import annotations

import math
import re
import warnings

import control as ct
import numpy as np
import pytest

from mpcasv.cli import main
from mpcasv.control.params import load_execution
from mpcasv.control.tuning import FAR, run_closed_loop
from mpcasv.control.tuning_speed import place_speed_pi, speed_figures, surge_plant, turn
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


@pytest.fixture(scope="module")
def model() -> VesselModel:
    return VesselModel(load_vessel("gretha"))


@pytest.fixture(scope="module")
def shipped():
    return load_execution("gretha")


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


def test_speed_loop_design(model, shipped):
    g = place_speed_pi(model, 1.0, 0.3, 1.0)
    assert (shipped.speed.Kp, shipped.speed.Ki) == pytest.approx((g.Kp, g.Ki), rel=1e-4)
    for u0 in (0.5, 2.5):
        f = speed_figures(surge_plant(model, u0), g, dt=0.1)
        assert f["phase_margin_deg"] >= 45 and f["gain_margin_db"] >= 6
        assert f["settling_s"] < 30


def test_turn_detects_pirouettes(model, shipped):
    """A waypoint inside the turning circle is circled (pirouette); one far enough is not."""
    _, near = turn(model, shipped, math.radians(90.0), 10.0)
    _, far = turn(model, shipped, math.radians(90.0), 50.0)
    assert near["pirouette"] and not math.isfinite(near["turn_s"])
    assert not far["pirouette"] and 0 < far["turn_s"] < 60 and far["total_turn_deg"] < 180


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


def test_cli_refuses_mismatched_wn(tmp_path, capsys):
    rc = main(["tune", "yaw", "--speeds", "1,2,3", "--wn", "0.3,0.6", "--out", str(tmp_path)])
    assert rc == 2 and "--wn: 2 values for 3 speeds" in capsys.readouterr().err
