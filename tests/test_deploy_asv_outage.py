"""The deploy loop around an ASV outage: what brings the ASV back after ``asv_stale``.

In CI beside a sweep (session 20) ``tests/test_io_e2e.py::test_asv_killed_and_restarted``
logged ``asv_stale``, then ``asv_resumed`` 0.55 s (deploy clock) later with decisions after
it, then ``asv_stale`` again: states the killed ASV had sent before its outage, read late,
were taken for the ASV back. Only a state stamped after the verdict (by the ASV's own
clock) may resume the loop (:meth:`mpcasv.io.deployphases.Phases.asv_back`).
"""

from __future__ import annotations

import asyncio

from test_io_cases import _es, dry_deploy, feed_states

from mpcasv.io.deploy import ASV_STALE, RUNNING
from mpcasv.io.logs import read_jsonl

ASV, AUV = ("10.0.10.50", 6002), ("10.0.10.60", 6002)


def _running(tmp_path):
    """A dry-run deploy fed 10 s of both vehicles' states at 2 Hz (deploy clock = the
    vehicles' clock); returns (deploy, clock, timestamp of the last ASV state)."""
    dep, clock = dry_deploy(tmp_path, watchdog={"asv_stale_s": 3.0, "auv_stale_s": 3.0})
    t = clock.t
    for _ in range(20):
        t = feed_states(dep, clock, t, 1)
        dep.watch()
    assert dep.phase == RUNNING
    return dep, clock, t


def _events(tmp_path, dep, name):
    dep.jsonl.flush()
    return [r for r in read_jsonl(tmp_path / "deploy.jsonl", "event") if r["event"] == name]


def test_late_states_from_before_the_outage_do_not_bring_the_asv_back(tmp_path):
    dep, clock, t_last = _running(tmp_path)
    steps = dep.steps
    clock.t += 3.5  # the ASV went silent (killed): 3.5 s > asv_stale_s
    dep.watch()
    assert dep.phase == ASV_STALE and len(_events(tmp_path, dep, "asv_stale")) == 1
    # what it had sent before it went silent, read only now (its two next states)
    for k in (1, 2):
        clock.t += 0.05
        dep.link.handle_datagram(_es(clock, 0x2801, t_last + 0.5 * k, 0.5 * k), ASV)
        assert dep.link.accepted["EstimatedState"] == 40 + k  # the link takes them (in order)
        dep.watch()
        assert dep.phase == ASV_STALE, "a state from before the verdict resumed the loop"
    assert dep.steps == steps and not _events(tmp_path, dep, "asv_resumed")
    late = _events(tmp_path, dep, "asv_late_state")
    assert len(late) == 1 and late[0]["state_t"] == t_last + 0.5
    assert late[0]["before_verdict_s"] == 3.0  # the verdict came 3.5 s after t_last
    clock.t += 5.0  # still silent: no second stale verdict for the same outage
    dep.watch()
    assert len(_events(tmp_path, dep, "asv_stale")) == 1 and dep.phase == ASV_STALE
    # back (a restarted DUNE): a state stamped after the verdict, by its own clock
    t_back = t_last + 8.6  # 8.6 s of deploy clock after the last state on time
    dep.link.handle_datagram(_es(clock, 0x2811, t_back, 100.0), AUV)
    dep.link.handle_datagram(_es(clock, 0x2801, t_back, 1.0), ASV)
    assert dep.link.rejects == {}
    resumed = _events(tmp_path, dep, "asv_resumed")
    assert len(resumed) == 1 and resumed[0]["state_t"] == t_back
    assert dep.phase == RUNNING and dep.steps == steps + 1  # dry run: running at once
    asyncio.run(dep.finish())
    summary = read_jsonl(tmp_path / "deploy.jsonl")[-1]
    assert summary["kind"] == "summary" and summary["asv_late_states"] == 2
    assert summary["asv_stale_events"] == 1


def test_a_fresh_state_after_the_verdict_brings_the_asv_back_at_once(tmp_path, request):
    """The same outage without late states: the first state after it resumes the loop
    (a restarted DUNE's first state, stamped 4 s after the last one, 4 s of deploy clock
    later)."""
    dep, clock, t_last = _running(tmp_path)
    request.addfinalizer(dep.close)  # its logs (it never runs)
    clock.t += 3.5
    dep.watch()
    assert dep.phase == ASV_STALE
    clock.t += 0.5
    dep.link.handle_datagram(_es(clock, 0x2811, t_last + 4.0, 100.0), AUV)
    dep.link.handle_datagram(_es(clock, 0x2801, t_last + 4.0, 1.0), ASV)
    assert dep.phase == RUNNING and len(_events(tmp_path, dep, "asv_resumed")) == 1
    assert not _events(tmp_path, dep, "asv_late_state") and dep.late_states == 0
