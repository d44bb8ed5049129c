"""The (C, F, D, G) hybrid automaton on toy systems: a thermostat and a standby timer."""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np
import pytest

from mpcasv.hybrid.system import (
    HybridAutomaton,
    HybridError,
    Jump,
    Mode,
    Transition,
    ZenoError,
)

# --- thermostat: x' = -x + 30 (heater on), x' = -x (off); hysteresis band [18, 22] ------------

LOW, HIGH, X_ON = 18.0, 22.0, 30.0


@dataclasses.dataclass(frozen=True)
class Th:
    q: str
    x: float
    n_switch: int = 0


def _exact(x_inf):  # exact flow of x' = -(x - x_inf) over dt
    return lambda s, dt: dataclasses.replace(s, x=x_inf + (s.x - x_inf) * math.exp(-dt))


def _count(s):
    return dataclasses.replace(s, n_switch=s.n_switch + 1)


def thermostat(**kw):
    return HybridAutomaton(
        [Mode("on", _exact(X_ON)), Mode("off", _exact(0.0))],
        [
            Transition("on", "off", lambda s: s.x >= HIGH, _count, "hot"),
            Transition("off", "on", lambda s: s.x <= LOW, _count, "cold"),
        ],
        **kw,
    )


def test_flow_without_jump():
    h = thermostat()
    s = h.step(0.0, Th("off", 20.0), 0.5)
    assert s.q == "off"
    assert s.x == pytest.approx(20.0 * math.exp(-0.5))
    assert h.jumps == ()
    assert h.jump_log().empty


def test_jump_then_flow_in_new_mode():
    h = thermostat()
    s = h.step(3.0, Th("off", 17.0), 0.1)
    assert s.q == "on"
    assert s.n_switch == 1  # the reset G was applied
    assert s.x == pytest.approx(X_ON + (17.0 - X_ON) * math.exp(-0.1))  # then on-flow
    assert h.jumps == (Jump(3.0, 1, "off", "on", "cold"),)


def test_closed_loop_stays_in_band_and_log_matches_trajectory():
    h, dt = thermostat(), 0.05
    s, t = Th("on", 10.0), 0.0
    modes, xs = [], []
    for _ in range(2000):
        s = h.step(t, s, dt)
        t += dt
        modes.append(s.q)
        xs.append(s.x)
    xs = np.array(xs)
    settled = xs[200:]  # after the first warm-up
    # one step of flow can overshoot the band by at most |x'| dt
    assert settled.min() > LOW - X_ON * dt and settled.max() < HIGH + X_ON * dt
    changes = sum(a != b for a, b in zip(["on", *modes[:-1]], modes, strict=True))
    log = h.jump_log()
    assert list(log.columns) == ["t", "j", "from_mode", "to_mode", "cause"]
    assert len(log) == changes == s.n_switch > 4
    assert list(log["j"]) == list(range(1, len(log) + 1))
    assert log["t"].is_monotonic_increasing
    assert (log["from_mode"] != log["to_mode"]).all()
    assert set(log.loc[log.to_mode == "off", "cause"]) == {"hot"}
    assert set(log.loc[log.to_mode == "on", "cause"]) == {"cold"}
    h.clear_log()
    assert h.jumps == ()


# --- priority, chains, Zeno guard --------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class S:
    q: str
    k: int = 0


def _still(s, dt):
    return s


def _always(s):
    return True


ABC = [Mode("A", _still), Mode("B", _still), Mode("C", _still)]


@pytest.mark.parametrize("first", ["B", "C"])
def test_priority_is_transition_order(first):
    other = "C" if first == "B" else "B"
    h = HybridAutomaton(
        ABC,
        [
            Transition("A", first, _always, cause=f"to {first}"),
            Transition("A", other, _always, cause=f"to {other}"),
        ],
    )
    assert h.step(0.0, S("A"), 1.0).q == first
    assert [j.cause for j in h.jumps] == [f"to {first}"]


def test_sources_any_and_several():
    h = HybridAutomaton(
        ABC,
        [
            Transition(("A", "B"), "C", lambda s: s.k == 1, cause="k1"),
            Transition(None, "A", lambda s: s.k == 2 and s.q != "A", cause="k2"),
        ],
    )
    assert h.step(0.0, S("B", 1), 1.0).q == "C"
    assert h.step(0.0, S("C", 1), 1.0).q == "C"  # C is not a source of "k1"
    assert h.step(0.0, S("C", 2), 1.0).q == "A"


def test_chain_resolved_within_one_step_up_to_max_jumps():
    inc = lambda s: dataclasses.replace(s, k=s.k + 1)  # noqa: E731
    trs = [
        Transition("A", "B", _always, inc, "ab"),
        Transition("B", "C", _always, inc, "bc"),
    ]
    h = HybridAutomaton(ABC, trs, max_jumps=2)
    s = h.step(7.0, S("A"), 1.0)
    assert (s.q, s.k) == ("C", 2)
    assert [(j.t, j.j, j.from_mode, j.to_mode) for j in h.jumps] == [
        (7.0, 1, "A", "B"),
        (7.0, 2, "B", "C"),
    ]
    with pytest.raises(ZenoError):
        HybridAutomaton(ABC, trs, max_jumps=1).step(0.0, S("A"), 1.0)


@pytest.mark.parametrize("max_jumps", [1, 5])
def test_zeno_guard_raises(max_jumps):
    h = HybridAutomaton(
        ABC,
        [Transition("A", "B", _always, cause="ab"), Transition("B", "A", _always, cause="ba")],
        max_jumps=max_jumps,
    )
    with pytest.raises(ZenoError, match="consecutive jumps"):
        h.step(0.0, S("A"), 1.0)
    assert len(h.jumps) == max_jumps


def test_ill_posed_states_and_definitions_raise():
    h = HybridAutomaton([Mode("A", _still, flow_set=lambda s: s.k >= 0)], [])
    with pytest.raises(HybridError, match="neither C nor D"):
        h.step(0.0, S("A", -1), 1.0)
    with pytest.raises(HybridError, match="unknown mode"):
        h.step(0.0, S("Z"), 1.0)
    with pytest.raises(ValueError, match="unique"):
        HybridAutomaton([Mode("A", _still), Mode("A", _still)], [])
    with pytest.raises(ValueError, match="unknown mode"):
        HybridAutomaton(ABC, [Transition("A", "Z", _always)])
    with pytest.raises(ValueError, match="unknown mode"):
        HybridAutomaton(ABC, [Transition(("A", "Z"), "B", _always)])


# --- a Paper-2-like standby timer in a NamedTuple state ----------------------------------------


class Boat(NamedTuple):
    q: int  # 1 standby, 2 transit
    x: float  # distance to the target (m)
    tau: float  # standby countdown (s)


T_STANDBY, EPS, SPEED = 10.0, 1.0, 2.0


def _standby(s, dt):
    return s._replace(tau=s.tau - dt, x=s.x + 0.5 * dt)  # drift away, timer counts down


def _transit(s, dt):
    return s._replace(x=max(s.x - SPEED * dt, 0.0))


def test_countdown_timer_standby_lasts_T():
    h = HybridAutomaton(
        [Mode(1, _standby, flow_set=lambda s: s.tau >= 0.0), Mode(2, _transit)],
        [
            Transition(2, 1, lambda s: s.x < EPS, lambda s: s._replace(tau=T_STANDBY), "arrived"),
            Transition(1, 2, lambda s: s.tau <= 0.0, cause="timer"),
        ],
    )
    dt, s, t = 0.5, Boat(2, 30.0, 0.0), 0.0
    for _ in range(200):
        s = h.step(t, s, dt)
        t += dt
    log = h.jump_log()
    assert len(log) >= 4
    arrive = log[log.cause == "arrived"].t.to_numpy()
    leave = log[log.cause == "timer"].t.to_numpy()
    n = min(len(arrive), len(leave))
    np.testing.assert_allclose(leave[:n] - arrive[:n], T_STANDBY)
    assert list(log.from_mode[:2]) == [2, 1]
