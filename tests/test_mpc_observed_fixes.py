"""``fix_age_source = "observed"`` (eq. M2o): the ASV's own USBL fixes reach the MPC's fix
ages. The expected ages of eq. M2 ignore the fixes that arrive: after a reliable fix an AUV's
expected age still reads 20-150 s and the ASV stays until the expectation says the AUV is
served (docs/mpc.md, "What stands in the way of the acceptance" 2). With M2o a fix the ASV's
USBL reports while the ASV is quiet within the AUV's reliable-fix range (Paper 2 eq. 9, at
the believed range) sets that AUV's age to the fix's and counts it as served."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from mpcasv.control.execution import NCMD
from mpcasv.controllers import make_controller
from mpcasv.interface import ASVState, AUVEstimate, Observation
from mpcasv.sim.scenario import load_scenario, scenario_with
from mpcasv.sim.world import World

#: AUV 0 60 m north of the ASV (reliable-fix range at the surface: r_t + eps = 80 m), AUV 1
#: 300 m south
AUVS = (AUVEstimate(60.0, 0.0, 0.0), AUVEstimate(-300.0, 0.0, 0.0))
TAU0 = np.array([150.0, 150.0])
ASV0 = ASVState(0.0, 0.0, 0.0)


@functools.cache
def _ctrl(source: str = "observed"):
    # the SX virtual machine: the fix-age bookkeeping needs no compiled library
    return make_controller("mpc-multi", 2, "mpc-multi",
                           overrides={"solver.compiled": False,
                                      "fix_age_source": source})  # fmt: skip


def _ages(fixes_then, fixes_now, propeller_on=False, asv=ASV0, source="observed"):
    """The controller's fix ages one second after a step that saw ``fixes_then``."""
    c = _ctrl(source)
    c.reset(2)
    c.tau = TAU0.copy()
    c._fix_ages(Observation(10.0, asv, propeller_on, AUVS, usbl_fix_times=fixes_then), 0.0)
    c.tau = TAU0.copy()
    ages = c._fix_ages(Observation(11.0, asv, propeller_on, AUVS, usbl_fix_times=fixes_now),
                       1.0)  # fmt: skip
    return c, ages


def test_a_quiet_fix_in_range_resets_the_age_and_serves_the_auv():
    c, ages = _ages((0.0, 0.0), (11.0, 0.0))
    assert ages[0] == 0.0 and c.fixes_since[0] >= 1.0 and c.fixes_run[0] >= 1.0
    # AUV 1 (no new fix, 300 m off): eq. M2 as before, one second older
    _, model = _ages((0.0, 0.0), (11.0, 0.0), source="model")
    assert ages[1] == model[1] == pytest.approx(151.0)
    assert model[0] > 100.0  # the expectation alone: 126 s after a second quiet in range


@pytest.mark.parametrize("case", ["propeller on", "out of range", "not news", "model"])
def test_other_fixes_leave_the_expected_age(case):
    kw = {"propeller on": {"propeller_on": True},
          "out of range": {"asv": ASVState(-30.0, 0.0, 0.0)},  # 90 m from AUV 0
          "not news": {},
          "model": {"source": "model"}}[case]  # fmt: skip
    then = (11.0, 0.0) if case == "not news" else (0.0, 0.0)
    c, ages = _ages(then, (11.0, 0.0), **kw)
    assert ages[0] > 100.0 and c.fixes_since[0] < 1.0
    if case != "model":  # the same as eq. M2 alone
        _, model = _ages(then, (11.0, 0.0), source="model",
                         **{k: v for k, v in kw.items() if k != "source"})  # fmt: skip
        assert np.array_equal(ages, model)


def test_the_observed_fix_serves_the_target_and_the_target_moves_on():
    """Through the controller's step: the run's first target, AUV 0 (60 m off, expected age
    150 s), has a reliable fix; with M2o it is served at once and the target moves to AUV 1
    (300 m off, 200 s); with the expected ages alone AUV 0's age is still 126 s, above
    ``tau_served``, and the target stays."""
    targets = {}
    for source in ("observed", "model"):
        c = _ctrl(source)
        c.reset(2)
        assert c._seen_fix is None  # a new run: no fix times seen yet
        c.tau = np.array([150.0, 200.0])
        c.step(Observation(10.0, ASV0, False, AUVS, usbl_fix_times=(0.0, 0.0)))
        c.step(Observation(11.0, ASV0, False, AUVS, usbl_fix_times=(11.0, 0.0)))
        targets[source] = (c.target, round(float(c.tau[0]), 1))
    assert targets["observed"][0] == 1 and targets["observed"][1] == 0.0
    assert targets["model"][0] == 0 and targets["model"][1] > 100.0


def test_an_observation_without_fix_times_is_refused():
    c = _ctrl()
    c.reset(2)
    with pytest.raises(ValueError, match="needs the ASV's own USBL fix times"):
        c._fix_ages(Observation(10.0, ASVState(0.0, 0.0, 0.0), False, AUVS), 1.0)


def test_the_simulator_reports_the_asvs_usbl_fix_times():
    """The observation carries the time of each AUV's last successful ping (the start's
    known position at t = 0 before the first), whatever the estimator (``perfect`` here:
    its own ``t_last_fix`` is always now)."""
    sc = load_scenario("experiments/scenarios/case6.toml")
    sc = scenario_with(sc, duration=60.0)
    w = World(sc, seed=0)
    assert w.observation().usbl_fix_times == (0.0, 0.0, 0.0)
    cmd = np.zeros(NCMD)  # standby
    seen = set()
    for _ in range(30):
        w.advance(cmd)
        obs = w.observation()
        assert obs.usbl_fix_times == tuple(w.last_fix)
        seen |= {t for t in obs.usbl_fix_times if t > 0}
    assert len(seen) >= 3  # pings every T0 = 5 s per AUV, most of them fixes


def test_the_variance_objective_refuses_observed_ages():
    """With ``objective = "variance"`` the ages stand for navigation variances (M2'): a fix
    at range leaves some, which a reset to the fix's age would drop. A new user's run of the
    combination (mpc-multi-variance, Case 6, seed 0) followed a served AUV for minutes; it is
    refused at load."""
    from mpcasv.config import ConfigError
    from mpcasv.controllers import load_preset

    with pytest.raises(ConfigError, match="fix_age_source = 'observed' needs objective = 'age'"):
        load_preset("mpc-multi", "mpc-multi-variance", {"fix_age_source": "observed"})
    assert load_preset("mpc-multi", "mpc-multi", {"fix_age_source": "observed"}).fix_age_source \
        == "observed"
