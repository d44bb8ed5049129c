"""EstimatedState checks against late and reordered states: a burst of late states is not a
vehicle clock step (``mpcasv.io.statecheck``), a real step arriving at the vehicle's rate is."""

from __future__ import annotations

import pytest
from test_io_cases import _es, _link

AUV = ("10.0.10.60", 6002)


def _run(schedule):
    """Feed the AUV's states ``(arrival offset s, vehicle timestamp offset s, N m)`` in list
    order through a link on a FakeClock. Returns ``(link, accepted timestamps (offsets),
    clock_step events)``."""
    link, clock, events = _link([{"role": "asv", "id": 0x2801, "address": "10.0.10.50:6002"},
                                 {"role": "auv", "id": 0x2811,
                                  "address": "10.0.10.60:6002"}])  # fmt: skip
    t0 = clock.t
    v0 = t0 - 7200.0  # the vehicle's clock is its own
    accepted = []
    link.on_state = lambda p, nav, now: accepted.append(round(nav.t - v0, 6))
    for arrival, stamp, N in schedule:
        clock.t = t0 + arrival
        link.handle_datagram(_es(clock, 0x2811, v0 + stamp, N), AUV)
    return link, accepted, [e for e in events if e["event"] == "clock_step"]


@pytest.mark.parametrize("rate,late", [(2.0, 3), (2.0, 5), (10.0, 3), (10.0, 5),
                                       (10.0, 12)])  # fmt: skip
def test_a_burst_of_late_states_is_not_a_clock_step(rate, late):
    """A stall holds ``late`` states; a newer one is accepted, then the held ones arrive
    together (1 ms apart), then the stream resumes: the late ones are rejected as
    out_of_order, no clock_step, no offset, every fresh state accepted on its own time."""
    p = 1.0 / rate
    n0 = 20  # steady states before the stall
    sched = [(p * k, p * k, 0.5 * p * k) for k in range(n0)]  # 0.5 m/s north
    fresh = n0 + late  # the newer state delivered before the held ones
    sched.append((p * fresh, p * fresh, 0.5 * p * fresh))
    sched += [(p * fresh + 0.001 * (i + 1), p * k, 0.5 * p * k)
              for i, k in enumerate(range(n0, fresh))]  # fmt: skip
    sched += [(p * k, p * k, 0.5 * p * k) for k in range(fresh + 1, fresh + 20)]
    link, accepted, steps = _run(sched)
    assert not steps
    assert dict(link.rejects) == {"out_of_order": late}
    assert link.auvs[0].track.offset == 0.0
    kept = [*range(n0), *range(fresh, fresh + 20)]  # all but the late ones
    assert accepted == [round(p * k, 6) for k in kept]


@pytest.mark.parametrize("step", [-5.0, -12.0])
def test_a_real_backward_step_at_the_vehicle_rate_still_re_anchors(step):
    """DUNE's Monitors.Clock steps the clock back by more than 4 s: the states after it come
    at the vehicle's rate (10 Hz here, with arrival jitter of up to 30 ms), 3 of them
    re-anchor (clock_step with the offset), the 2 before are rejected."""
    p = 0.1
    jitter = [0.0, 0.03, 0.01, 0.025, 0.0, 0.02]
    sched = []
    for k in range(60):
        stamp = p * k + (step if k >= 30 else 0.0)
        sched.append((p * k + jitter[k % len(jitter)], stamp, 0.05 * k))
    link, accepted, steps = _run(sched)
    assert len(steps) == 1
    assert steps[0]["offset_s"] == pytest.approx(step, abs=0.1)
    assert steps[0]["states"] == 3
    assert dict(link.rejects) == {"out_of_order": 2}
    assert len(accepted) == 58


def test_a_real_step_whose_first_states_came_in_a_burst_re_anchors_once_spread():
    """A backward step of 8 s during a stall: the first 3 states on the new base arrive
    together (a burst: no proof yet), the next ones at the vehicle's 2 Hz; the chain proves
    the step once it spans at least half its timestamps' span in arrival time (5 states)."""
    sched = [(0.5 * k, 0.5 * k, 0.25 * k) for k in range(20)]
    sched += [(11.0 + 0.001 * i, 0.5 * k - 8.0, 0.25 * k) for i, k in enumerate(range(20, 23))]
    sched += [(0.5 * k, 0.5 * k - 8.0, 0.25 * k) for k in range(23, 40)]
    link, accepted, steps = _run(sched)
    assert len(steps) == 1 and steps[0]["states"] == 5
    assert steps[0]["offset_s"] == pytest.approx(-8.0, abs=1e-3)
    assert dict(link.rejects) == {"out_of_order": 4}
    assert accepted == [0.5 * k for k in range(20)] + [0.5 * k for k in range(24, 40)]


def test_a_duplicated_state_is_dropped_silently_and_counted_apart():
    """UDP delivers a datagram twice at times: an exact copy of the last accepted state is
    no reject (no counter, no event), counted in ``duplicates`` by vehicle, not handed on
    again; every state of a stream sent twice is taken once, with no reject."""
    link, clock, events = _link([{"role": "asv", "id": 0x2801, "address": "10.0.10.50:6002"},
                                 {"role": "auv", "id": 0x2811, "name": "lauv-x",
                                  "address": "10.0.10.60:6002"}])  # fmt: skip
    accepted = []
    link.on_state = lambda p, nav, now: accepted.append(nav.t)
    t0 = clock.t
    for k in range(10):
        clock.t = t0 + 0.5 * k
        packet = _es(clock, 0x2811, t0 + 0.5 * k, 0.25 * k)
        link.handle_datagram(packet, AUV)
        clock.t += 0.001
        link.handle_datagram(packet, AUV)  # the copy, a millisecond later
    assert accepted == [t0 + 0.5 * k for k in range(10)]
    assert dict(link.rejects) == {}
    assert not [e for e in events if e["event"] == "reject"]
    assert dict(link.duplicates) == {"lauv-x": 10}
    assert link.counters()["duplicates"] == {"lauv-x": 10}
    assert link.auvs[0].last_heard == t0 + 0.5 * 9  # the copy is no sign of life either


def test_an_older_state_or_another_at_the_same_time_is_still_out_of_order():
    """Not a copy of the last accepted state: an older one (even one accepted before), or
    another state with the last one's timestamp, is out_of_order, as before."""
    link, clock, events = _link([{"role": "asv", "id": 0x2801, "address": "10.0.10.50:6002"},
                                 {"role": "auv", "id": 0x2811,
                                  "address": "10.0.10.60:6002"}])  # fmt: skip
    t0 = clock.t
    first = _es(clock, 0x2811, t0, 0.0)
    link.handle_datagram(first, AUV)
    clock.t = t0 + 0.5
    link.handle_datagram(_es(clock, 0x2811, t0 + 0.5, 0.25), AUV)
    link.handle_datagram(_es(clock, 0x2811, t0 + 0.5, 0.30), AUV)  # same time, other place
    link.handle_datagram(first, AUV)  # a copy of an older one: late
    assert dict(link.rejects) == {"out_of_order": 2}
    assert len([e for e in events if e["event"] == "reject"]) == 2
    assert dict(link.duplicates) == {}
    assert link.auvs[0].nav.N == pytest.approx(0.25, abs=1e-6)
