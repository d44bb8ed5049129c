"""The ASV's USBL fixes as positions in the field (session 42): ``mpcasv deploy`` hands each
UsblFixExtended's position to the AUV's estimator, as the simulator hands its fixes, in the
order of the measurements' own times (:class:`mpcasv.estimation.InOrder`: DUNE stamps a fix
when it processed it, and it often arrives after an AUV state stamped later), and a fix keeps
an AUV seen for the watchdogs: an AUV under water, out of radio contact, is not "lost" while
the ASV's USBL fixes it. Before, the fixes gave their times only (M2o) and such an AUV was
lost 30 s after its last state.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math

import numpy as np
import pytest
from test_estimation import _fix as _kf_fix
from test_estimation import _report
from test_io_cases import _es, dry_deploy, feed_states

from mpcasv.estimation import InOrder, KalmanParams, make_estimator
from mpcasv.estimation.survey_plan import KnownPlan
from mpcasv.interface import AUVEstimate
from mpcasv.io.geo import Origin
from mpcasv.io.imc import nav_state, stamp, usbl_fix_extended
from mpcasv.io.logs import read_jsonl

ASV, AUV = ("10.0.10.50", 6002), ("10.0.10.60", 6002)
VEHICLES = [{"role": "asv", "id": 0x2801, "name": "otter", "address": "10.0.10.50:6002"},
            {"role": "auv", "id": 0x2811, "name": "lauv-xplore-1",
             "address": "10.0.10.60:6002"}]  # fmt: skip
ORIGIN = Origin.from_degrees(41.18, -8.70)


def _stream(seed: int, delay: float, T: float = 120.0):
    """A straight-running AUV's measurements as (arrival time, kind, measurement): reports
    every 1 s, USBL fixes every 5 s arriving ``delay`` s after their own time."""
    rng = np.random.default_rng(seed)
    p, out = KalmanParams(), []
    for i in range(1, int(T) + 1):
        t = float(i)
        pos = np.array([1.2 * t, 0.3 * t])
        out.append((t, "report", _report(t, pos, math.atan2(0.3, 1.2), 1.24, rng, p)))
        if i % 5 == 0:
            out.append((t + delay, "fix", _kf_fix(t, pos, rng.uniform(50, 400), rng)))
    return out


def _feed(est, items) -> None:
    for _, kind, m in items:
        (est.on_fix if kind == "fix" else est.on_report)(m)


@pytest.mark.parametrize("name", ["kalman", "plan", "acoustic"])
@pytest.mark.parametrize("delay", [0.0, 1.5, 4.5])
def test_in_order_is_the_estimator_fed_in_time_order(name, delay):
    """Fed in arrival order (late fixes among newer reports), :class:`InOrder` gives at
    every arrival exactly the estimate of the same estimator fed the measurements that had
    arrived, sorted by their times; the plain estimator fed in arrival order does not."""
    plan = KnownPlan(np.array([[60.0, 15.0], [150.0, 40.0]]), 1.2)

    def make():
        return make_estimator(name, initial=AUVEstimate(0, 0, 20, t_last_fix=0.0), plan=plan)

    items = sorted(_stream(3, delay), key=lambda x: x[0])  # arrival order (stable)
    wrapped, plain, differs = InOrder(make()), make(), 0
    for i, item in enumerate(items):
        _feed(wrapped, [item])
        _feed(plain, [item])
        ref = make()
        _feed(ref, sorted(items[: i + 1], key=lambda x: x[2].t))  # stable: equal times kept
        t = item[0] + 0.5
        assert wrapped.estimate(t) == ref.estimate(t)
        differs += plain.estimate(t) != ref.estimate(t)
    # every fix but the last (no report after it) came after a newer report
    assert wrapped.reordered == (0 if delay == 0 else 23) and wrapped.dropped == 0
    assert (differs > 0) == (delay > 0)
    assert wrapped.name == name


def test_in_order_drops_what_is_older_than_its_window():
    """A measurement older than ``window_s`` before the newest is not taken, and counted; one
    just inside the window before every remembered one is placed exactly."""
    est = InOrder(make_estimator("kalman"), window_s=10.0)
    rng = np.random.default_rng(0)
    ref = make_estimator("kalman")
    taken = []
    for t in (1.0, 20.0, 25.0):
        m = _report(t, np.array([t, 0.0]), 0.0, 1.0, rng, KalmanParams())
        est.on_report(m)
        taken.append(m)
    before = est.estimate(30.0)
    est.on_fix(_kf_fix(14.0, np.array([14.0, 0.0]), 100.0, rng))  # 11 s before 25 s
    assert est.dropped == 1 and est.estimate(30.0) == before
    late = _kf_fix(16.0, np.array([16.0, 0.0]), 100.0, rng)  # inside: before 20 s, after 1 s
    est.on_fix(late)
    for m in sorted([*taken, late], key=lambda m: m.t):
        (ref.on_fix if m is late else ref.on_report)(m)
    assert est.estimate(30.0) == ref.estimate(30.0) and est.reordered == 1


def test_in_order_forgets_what_is_older_than_its_window():
    """A long run keeps only the window's measurements (and their copies), not all of them."""
    est, rng = InOrder(make_estimator("kalman"), window_s=10.0), np.random.default_rng(1)
    for i in range(500):
        est.on_report(_report(float(i), np.array([float(i), 0.0]), 0.0, 1.0, rng,
                              KalmanParams()))  # fmt: skip
    assert len(est._taken) == 11 and est._taken[0].t == 489.0


@pytest.mark.parametrize("window", [0.0, -1.0, math.inf, math.nan])
def test_in_order_refuses_a_bad_window(window):
    with pytest.raises(ValueError, match="window_s"):
        InOrder(make_estimator("kalman"), window_s=window)


def _usbl(t: float, N: float, E: float, depth: float = 20.0, accuracy: float = 1.5,
          target: str = "lauv-xplore-1") -> bytes:  # fmt: skip
    msg = usbl_fix_extended(target, N, E, depth, accuracy, ORIGIN)
    return stamp(msg, 0x2801, 0xFFFF, t).serialize()


def _submerged(tmp_path, estimator: str, fixes: bool):
    """A deploy whose AUV (states until t = 2 s, then silent: under water) is fixed by the
    ASV every 5 s (``fixes``) at (100 + 0.5 (t - t0), 10) m for 40 s; watchdog ``auv_stale_s`` 7 s
    (longer than the USBL period), ``auv_lost_s`` 30 s. Returns (deploy, events, summary)."""
    dep, clock = dry_deploy(
        tmp_path, vehicle=VEHICLES, watchdog={"auv_stale_s": 7.0, "auv_lost_s": 30.0},
        controller={"name": "hybrid-single", "preset": "paper1-field", "estimator": estimator})
    t0 = t = feed_states(dep, clock, clock.t, 4)
    for i in range(80):
        clock.t += 0.5
        t += 0.5
        dep.link.handle_datagram(_es(clock, 0x2801, t, 0.0), ASV)
        if fixes and i % 10 == 9:
            dep.link.handle_datagram(_usbl(t - 0.3, 100.0 + 0.5 * (t - t0), 10.0), ASV)
        dep.watch()
    est = dep.estimators[0].estimate(t)
    asyncio.run(dep.finish())
    path = tmp_path / "deploy.jsonl"
    return est, [e["event"] for e in read_jsonl(path, "event")], read_jsonl(path, "summary")[-1]


def test_fixes_keep_a_submerged_auv_seen_and_estimated(tmp_path):
    """With the Kalman filter the ASV's fixes keep the silent AUV ``ok`` (no ``auv_uncertain``
    or ``auv_lost``) and its estimate follows them (the last fix at N = 119.85, E = 10, 0.3 s
    before the estimate's time); without the fixes, or with the ``perfect`` estimator (the
    AUVs' own states only, which takes no fix), the same AUV is lost."""
    est, events, summary = _submerged(tmp_path / "kalman", "kalman", fixes=True)
    assert "auv_uncertain" not in events and "auv_lost" not in events
    assert "usbl_fix_positions_unused" not in events  # they are used
    assert summary["usbl_fix_positions"] == [8] and summary["usbl_fixes"] == [8]
    assert summary["estimator_reordered"] == [0] and summary["estimator_dropped"] == [0]
    assert abs(est.N - 120.0) < 2.0 and abs(est.E - 10.0) < 1.0
    _, events, summary = _submerged(tmp_path / "none", "kalman", fixes=False)
    assert "auv_lost" in events and summary["usbl_fix_positions"] == [0]
    est, events, summary = _submerged(tmp_path / "perfect", "perfect", fixes=True)
    assert "auv_lost" in events and summary["usbl_fix_positions"] == [0]
    # said once: the fixes come and 'perfect' takes none (a new user's finding, session 42)
    assert events.count("usbl_fix_positions_unused") == 1
    assert summary["usbl_fixes"] == [8]  # the times still count (M2o reads them)
    assert est.N == pytest.approx(100.0, abs=1e-3)  # its own last state


def test_a_fix_stamped_before_the_auvs_last_state_is_put_in_its_place(tmp_path):
    """A fix stamped 1.2 s before the AUV's last state (DUNE processed it, the datagram came
    later) is taken in its time's place: the summary counts it as reordered; the same
    datagram twice is taken once."""
    dep, clock = dry_deploy(
        tmp_path, vehicle=VEHICLES,
        controller={"name": "hybrid-single", "preset": "paper1-field", "estimator": "kalman"})
    t = feed_states(dep, clock, clock.t, 6)
    for _ in range(2):
        dep.link.handle_datagram(_usbl(t - 1.2, 101.0, 2.0), ASV)
    asyncio.run(dep.finish())
    summary = read_jsonl(tmp_path / "deploy.jsonl", "summary")[-1]
    assert summary["estimator_reordered"] == [1] and summary["usbl_fix_positions"] == [1]
    assert dep.link.rejects == {}


def test_the_fix_covariance_and_depth(tmp_path):
    """``accuracy`` (m) is the horizontal RMS error: ``accuracy^2 / 2`` on each axis. DUNE's
    drivers that leave it 0: thesis eq. 2.9 with the deploy's ``[acoustics]`` from the ASV's
    last state (eq. 2.9 on the 3-D line of sight, as the simulator's fixes: range noise and the
    elevation-angle error along the horizontal line of sight, bearing error x slant range
    across).
    A ``z`` that is no depth: the AUV's last reported depth, said once."""
    dep, clock = dry_deploy(
        tmp_path, vehicle=VEHICLES, acoustics={"sigma_range": 0.5, "sigma_bearing_deg": 2.0},
        controller={"name": "hybrid-single", "preset": "paper1-field", "estimator": "kalman"})
    t = feed_states(dep, clock, clock.t, 4)
    asv = dataclasses.replace(dep.link.asv.nav, N=30.0, E=40.0)  # the ASV off the origin
    msg = usbl_fix_extended("lauv-xplore-1", 100.0, 0.0, 20.0, 1.5, ORIGIN)
    fix = dep._fix(0, msg, t, asv)
    assert fix.N == pytest.approx(100.0, abs=1e-6) and fix.E == pytest.approx(0.0, abs=1e-6)
    assert fix.depth == pytest.approx(20.0, abs=1e-4)
    np.testing.assert_allclose(fix.cov, (1.125, 0.0, 0.0, 1.125))
    fix = dep._fix(0, usbl_fix_extended("lauv-xplore-1", 100.0, 0.0, 20.0, 0.0, ORIGIN), t, asv)
    r_h = math.hypot(70.0, 40.0)
    los = np.array([70.0, -40.0]) / r_h  # from the ASV to the AUV
    slant = math.hypot(r_h, 20.0)
    across = np.array([-los[1], los[0]])
    # the simulator's geometry (models.acoustics U2): range noise and the elevation-angle error
    # along the horizontal line of sight, the angle error x slant range across it
    along2 = (0.5 * r_h / slant) ** 2 + (math.radians(2.0) * 20.0) ** 2
    R = along2 * np.outer(los, los) + (math.radians(2.0) * slant) ** 2 * np.outer(across, across)
    assert fix.slant == pytest.approx(slant, abs=1e-4)
    np.testing.assert_allclose(fix.cov, R.ravel(), atol=1e-6)
    msg.z_units = type(msg.z_units).ALTITUDE
    for _ in range(2):
        assert dep._fix(0, msg, t, asv).depth == 0.0  # the AUV's last state: at the surface
    asyncio.run(dep.finish())
    said = [e for e in read_jsonl(tmp_path / "deploy.jsonl", "event")
            if e["event"] == "usbl_fix_depth"]  # fmt: skip
    assert len(said) == 1 and said[0]["target"] == "lauv-xplore-1"


def test_the_sitl_auvs_send_their_reports_under_water():
    """``mpcasv sitl --auv-states acoustic``: after the start, each AUV sends an
    EstimatedState per status report of its world that got through (its navigation position,
    heading and speed), once, stamped at the report's time; with ``radio`` none of them (the
    true state at 2 Hz instead). A bad value is refused in one line."""
    from types import SimpleNamespace

    from mpcasv.config import ConfigError
    from mpcasv.io.sitloptions import SitlOptions
    from mpcasv.io.sitlpublish import Publishing
    from mpcasv.models.acoustics import Report
    from mpcasv.sim.scenario import load_scenario

    sent = []

    class Vehicle(SimpleNamespace):
        def publish(self, msg, t=None):
            sent.append((self.index, t, msg))

    reports = [Report(30.0, 0, 120.0, 5.0, 18.0, 0.5, 1.4, 3.0),
               Report(60.0, 0, 150.0, 20.0, 18.5, 0.6, 1.5, 4.0)]  # fmt: skip
    sitl = SimpleNamespace(ts_offset=1000.0, tick=1045.0, reports_sent=[0], origin=ORIGIN,
                           world=SimpleNamespace(reports=[reports]),
                           auvs=[Vehicle(index=0, anchor=None)], asv=SimpleNamespace(alive=True),
                           opt=SimpleNamespace(reanchor_m=1000.0))  # fmt: skip
    sitl.now = lambda: sitl.tick
    sitl._es = lambda v, nav: Publishing._es(sitl, v, nav)
    sitl._offset = lambda v, nav: Publishing._offset(sitl, v, nav)
    Publishing.publish_reports(sitl)
    Publishing.publish_reports(sitl)  # the same tick again: nothing new
    assert [(k, t) for k, t, _ in sent] == [(0, 1030.0)] and sitl.reports_sent == [1]
    nav = nav_state(sent[0][2], ORIGIN)
    assert (nav.N, nav.E, nav.depth) == pytest.approx((120.0, 5.0, 18.0), abs=1e-3)
    assert nav.psi == pytest.approx(0.5) and nav.u == pytest.approx(1.4)
    sitl.asv.alive, sitl.tick = False, 1075.0  # the ASV's DUNE down: its modem hears nothing
    Publishing.publish_reports(sitl)
    assert len(sent) == 1 and sitl.reports_sent == [2]  # the 60-s report is lost
    sc = load_scenario("experiments/scenarios/case3.toml")
    with pytest.raises(ConfigError, match="--auv-states 'sonar': one of radio, acoustic"):
        SitlOptions(auv_states="sonar").check(sc)


def test_the_sitl_auvs_dive_at_the_first_reference():
    """``acoustic``: the AUVs' true states at 2 Hz until the ASV has taken a Reference (with or
    without ``--hold``: the deploy must start), then only the reports made after that; the
    dive stays when the ASV's DUNE restarts without a maneuver. ``radio``: never."""
    from types import SimpleNamespace

    from mpcasv.io.sitlpublish import Publishing
    from mpcasv.models.acoustics import Report

    def sitl(mode):
        s = SimpleNamespace(opt=SimpleNamespace(auv_states=mode), dived=False, maneuver=None,
                            period=None, reports_sent=[0], asv=SimpleNamespace(alive=False),
                            auvs=[SimpleNamespace(index=0, publish=lambda m, t=None: out.append(
                                ("radio", m)))],
                            world=SimpleNamespace(x=np.zeros(8), S=np.zeros((5, 1)), reports=[[
                                Report(30.0, 0, 1.0, 2.0, 3.0, 0.0, 1.0, 1.0)]]))  # fmt: skip
        s._es = lambda v, nav: nav
        s._nav_auv = lambda S, k: "state"
        s.publish_fixes = lambda: None
        s.publish_reports = lambda: out.append(("reports", tuple(s.reports_sent)))
        return s

    for mode in ("acoustic", "radio"):
        out = []
        s = sitl(mode)
        Publishing.publish_states(s, mid=False)
        s.maneuver = SimpleNamespace(got_reference=False)
        Publishing.publish_states(s, mid=False)
        s.maneuver.got_reference = True
        Publishing.publish_states(s, mid=False)
        s.maneuver = None  # the ASV's DUNE restarted: no maneuver
        Publishing.publish_states(s, mid=False)
        kinds = [k for k, _ in out]
        if mode == "radio":
            assert kinds == ["radio"] * 4 and not s.dived
        else:  # the report made before the dive went by radio: skipped
            assert kinds == ["radio", "radio", "reports", "reports"] and s.dived
            assert out[2] == ("reports", (1,))


def _deploy_with_silent_auv(tmp_path, **watchdog):
    dep, clock = dry_deploy(
        tmp_path, vehicle=VEHICLES, watchdog=watchdog,
        controller={"name": "hybrid-single", "preset": "paper1-field", "estimator": "kalman"})
    t = feed_states(dep, clock, clock.t, 4)
    return dep, clock, t


def test_implausible_fixes_are_not_taken(tmp_path):
    """A fix 5 km from where the AUV was 0.3 s ago, or at lat/lon (0, 0) (540 km away, past
    ``max_distance_m``), is refused: counted, one event, the estimate unchanged; its time still
    counts (M2o). A plausible one 3 m off is taken."""
    dep, clock, t = _deploy_with_silent_auv(tmp_path)
    before = dep.estimators[0].estimate(t)
    dep.link.handle_datagram(_usbl(t - 0.3, 100.0 + 5000.0, 0.0), ASV)
    msg = usbl_fix_extended("lauv-xplore-1", 0.0, 0.0, 20.0, 1.5, ORIGIN)
    msg.lat = msg.lon = 0.0
    dep.link.handle_datagram(stamp(msg, 0x2801, 0xFFFF, t - 0.2).serialize(), ASV)
    assert dep.estimators[0].estimate(t) == before
    assert dep.usbl.outliers == [2] and dep.usbl.positions == [0] and dep.usbl.counts == [2]
    dep.link.handle_datagram(_usbl(t - 0.1, 103.0, 0.0), ASV)
    assert dep.usbl.outliers == [2] and dep.usbl.positions == [1]
    asyncio.run(dep.finish())
    events = [e for e in read_jsonl(tmp_path / "deploy.jsonl", "event")
              if e["event"] == "usbl_fix_outlier"]  # fmt: skip
    assert len(events) == 1 and "from the estimate" in events[0]["why"]
    assert read_jsonl(tmp_path / "deploy.jsonl", "summary")[-1]["usbl_fix_outliers"] == [2]


def test_a_fix_the_estimator_drops_does_not_keep_the_auv_seen(tmp_path):
    """A fix stamped 70 s before the AUV's last state (its clock off the ASV's: older than the
    60-s window) is dropped by the estimator: not counted as taken, the AUV's age not reset
    (a review's finding: it had been), one event."""
    dep, clock, t = _deploy_with_silent_auv(tmp_path)
    dep.link.handle_datagram(_usbl(t - 70.0, 100.0, 0.0), ASV)
    assert dep.estimators[0].dropped == 1 and dep.usbl.positions == [0]
    assert dep.usbl.recv == [-math.inf]
    asyncio.run(dep.finish())
    names = [e["event"] for e in read_jsonl(tmp_path / "deploy.jsonl", "event")]
    assert names.count("usbl_fix_dropped") == 1


def test_a_fix_brings_an_uncertain_auv_back(tmp_path):
    """The AUV silent past ``auv_stale_s`` is uncertain; the ASV's next fix of it makes it ok
    again (``auv_fresh`` by ``usbl_fix``), and its age restarts from that fix's arrival."""
    dep, clock, t = _deploy_with_silent_auv(tmp_path, auv_stale_s=3.0, auv_lost_s=30.0)
    for _ in range(10):  # 5 s of ASV states only
        clock.t += 0.5
        t += 0.5
        dep.link.handle_datagram(_es(clock, 0x2801, t, 0.0), ASV)
        dep.watch()
    assert dep.status == ["uncertain"]
    dep.link.handle_datagram(_usbl(t - 0.2, 104.0, 1.0), ASV)
    assert dep.status == ["ok"] and dep.auv_ages(clock.t) == [0.0]
    for _ in range(10):  # uncertain again, and again brought back
        clock.t += 0.5
        t += 0.5
        dep.link.handle_datagram(_es(clock, 0x2801, t, 0.0), ASV)
        dep.watch()
    dep.link.handle_datagram(_usbl(t - 0.2, 106.0, 1.0), ASV)
    asyncio.run(dep.finish())
    fresh = [e for e in read_jsonl(tmp_path / "deploy.jsonl", "event") if e["event"] == "auv_fresh"]
    assert len(fresh) == 2 and all(e["by"] == "usbl_fix" and e["was"] == "uncertain"
                                   for e in fresh)  # fmt: skip
    # the first says what to do about it (a new user's finding, session 42), once
    assert "auv_stale_s" in fresh[0]["note"] and "note" not in fresh[1]


def test_the_sitl_sends_its_fixes_late_with_usbl_delay(tmp_path):
    """``--usbl-delay 1.5``: each fix goes out 1.5 s of world time after it, stamped at its own
    time; a deploy fed the AUV's 2-Hz states meanwhile takes it in its place (reordered).
    A delay outside [0, 60] s is refused in one line."""
    from types import SimpleNamespace

    from mpcasv.config import ConfigError
    from mpcasv.io.sitloptions import SitlOptions
    from mpcasv.io.sitlpublish import Publishing
    from mpcasv.models.acoustics import Fix
    from mpcasv.sim.scenario import load_scenario

    sent = []
    fixes = [Fix(5.0, 0, 100.0, 0.0, 20.0, (1.0, 0.0, 0.0, 1.0), 102.0)]
    sitl = SimpleNamespace(ts_offset=1000.0, tick=1006.0, fixes_sent=[0], origin=ORIGIN,
                           opt=SimpleNamespace(usbl_delay=1.5), world=SimpleNamespace(
                               fixes=[fixes]), auvs=[SimpleNamespace(index=0, name="a")],
                           asv=SimpleNamespace(publish=lambda m, t=None: sent.append(t)))
    sitl.now = lambda: sitl.tick
    Publishing.publish_fixes(sitl)  # 1 s after the fix: not yet
    sitl.tick = 1006.5
    Publishing.publish_fixes(sitl)
    assert sent == [1005.0]  # sent 1.5 s late, stamped at the fix's time
    sc = load_scenario("experiments/scenarios/case3.toml")
    for bad in (-1.0, 61.0, math.nan):
        with pytest.raises(ConfigError, match="--usbl-delay"):
            SitlOptions(usbl_delay=bad).check(sc)


def _fixes(dep, times_N, E=0.0):
    for t, N in times_N:
        dep.link.handle_datagram(_usbl(t, N, E), ASV)


def test_fixes_that_agree_with_each_other_overrule_a_wrong_estimate(tmp_path):
    """The AUV's own states put it at N = 100 m and then stop (under water); the ASV's USBL
    finds it 200 m further on, fix after fix. The first two are refused (outliers against the
    estimate); the third agrees with them, so the AUV's estimator restarts from all three,
    in time order (event ``usbl_fixes_agree``): the estimate was wrong, and would otherwise
    refuse every fix for good."""
    from mpcasv.io.deployfeedback import USBL_AGREE

    dep, clock, t = _deploy_with_silent_auv(tmp_path)
    _fixes(dep, [(t - 0.6, 100.2)])  # a good fix, older than the AUV's last state: reordered
    assert dep.estimators[0].reordered == 1 and dep.usbl.positions == [1]
    _fixes(dep, [(t - 0.2, 300.1), (t - 0.3, 300.0)])  # the second one out of order
    assert dep.usbl.outliers == [USBL_AGREE - 1] and dep.usbl.positions == [1]
    assert abs(dep.estimators[0].estimate(t).N - 100.0) < 1.0
    _fixes(dep, [(t, 300.3)])
    assert dep.usbl.outliers == [USBL_AGREE] and dep.usbl.positions == [1 + USBL_AGREE]
    assert abs(dep.estimators[0].estimate(t).N - 300.3) < 1.0  # restarted from the fixes
    assert dep.estimators[0].reordered == 1  # carried on; the three taken in time order
    asyncio.run(dep.finish())
    events = read_jsonl(tmp_path / "deploy.jsonl", "event")
    agree = [e for e in events if e["event"] == "usbl_fixes_agree"]
    assert len(agree) == 1 and agree[0]["fix_t"] == [t - 0.3, t - 0.2, t]
    assert [e["event"] for e in events].count("usbl_fix_outlier") == 1


@pytest.mark.parametrize("case", ["disagree", "accepted_between", "state_between", "off_map",
                                  "span"])
def test_refused_fixes_that_do_not_make_a_case_stay_refused(tmp_path, case):
    """No restart: three refused fixes that do not agree with each other (500 m apart within
    a second); a fix taken between them; a state of the AUV's own between them (a multipath
    reflection that stays put while the AUV's states come: a review's finding, session 42,
    four restarts a minute); fixes off the map (past ``max_distance_m``: never evidence);
    three that agree but span more than ``USBL_AGREE_SPAN``."""
    from mpcasv.io.deployfeedback import USBL_AGREE_SPAN

    dep, clock, t = _deploy_with_silent_auv(tmp_path, auv_stale_s=600.0, auv_lost_s=900.0)
    if case == "disagree":
        _fixes(dep, [(t - 0.3, 300.0), (t - 0.2, 800.0), (t - 0.1, 300.0)])
    elif case == "accepted_between":
        _fixes(dep, [(t - 0.3, 300.0), (t - 0.2, 300.1), (t - 0.15, 100.5), (t - 0.1, 300.2)])
    elif case == "state_between":
        _fixes(dep, [(t - 0.3, 300.0), (t - 0.2, 300.1)])
        t = feed_states(dep, clock, t, 1)  # the AUV's own word: at N = 100
        _fixes(dep, [(t - 0.1, 300.2)])
    elif case == "off_map":
        msg = usbl_fix_extended("lauv-xplore-1", 0.0, 0.0, 20.0, 1.5, ORIGIN)
        msg.lat = msg.lon = 0.0
        for i in range(3):
            dep.link.handle_datagram(stamp(msg, 0x2801, 0xFFFF, t - 0.3 + 0.1 * i).serialize(),
                                     ASV)  # fmt: skip
    else:  # one place 900 m off, the last one 40 s later (no state between: ASV states only)
        _fixes(dep, [(t - 0.3, 1000.0), (t - 0.2, 1000.0)])
        for _ in range(int(2 * (USBL_AGREE_SPAN + 10))):
            clock.t += 0.5
            t += 0.5
            dep.link.handle_datagram(_es(clock, 0x2801, t, 0.0), ASV)
        _fixes(dep, [(t, 1000.0)])
        assert dep.usbl.outliers == [3]  # all three refused by the gate
    N = dep.estimators[0].estimate(t).N  # 40 s on in "span": the AUV's last velocity, 1 m/s
    assert abs(N - (140.0 if case == "span" else 100.0)) < 5.0, (case, N)
    asyncio.run(dep.finish())
    names = [e["event"] for e in read_jsonl(tmp_path / "deploy.jsonl", "event")]
    assert "usbl_fixes_agree" not in names, case


def test_fixes_agree_needs_each_pair_within_the_gate():
    from mpcasv.io.deployfeedback import fixes_agree
    from mpcasv.models.acoustics import Fix

    cov = (1.0, 0.0, 0.0, 1.0)

    def fixes(*tN):
        return [Fix(t, 0, N, 0.0, 20.0, cov, 300.0) for t, N in tN]

    assert fixes_agree(fixes((0.0, 300.0), (1.0, 301.0), (2.0, 302.0)), 2.0)
    assert not fixes_agree(fixes((0.0, 300.0), (1.0, 800.0), (2.0, 300.0)), 2.0)
    # 40 m in 2 s: too fast for an AUV of 2 m/s, not for one of 20 m/s
    assert not fixes_agree(fixes((0.0, 300.0), (1.0, 320.0), (2.0, 340.0)), 2.0)
    assert fixes_agree(fixes((0.0, 300.0), (1.0, 320.0), (2.0, 340.0)), 20.0)
    # in time order, whatever the order given
    assert fixes_agree(fixes((2.0, 302.0), (0.0, 300.0), (1.0, 301.0)), 2.0)
    assert not fixes_agree(fixes((0.0, 300.0), (2.0, 301.0), (1.0, 340.0)), 2.0)
