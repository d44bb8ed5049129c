"""Pieces of the I/O layer on their own: configuration errors, IMC conversions, DUNE's
FollowReference semantics as the SITL runs them, the watchdogs and guard, log records."""

from __future__ import annotations

import gzip
import json
import math
from pathlib import Path

import imcpy
import numpy as np
import pytest

from mpcasv.config import ConfigError
from mpcasv.interface import ASVState, AUVEstimate, Command, Mode, Observation, Reason
from mpcasv.io.config import deploy_config_from_dict
from mpcasv.io.deploy import ASV_STALE, RUNNING, WAITING, Deploy
from mpcasv.io.dune import FollowRefManeuver
from mpcasv.io.geo import Origin, absolute_latlon, to_local, to_wgs84
from mpcasv.io.imc import NavState, estimated_state, nav_state, reference, stamp, udp_services
from mpcasv.io.logs import JsonlWriter, read_jsonl
from mpcasv.io.records import obs_from_dict, obs_to_dict
from mpcasv.io.watchdog import (
    LOST,
    OK,
    UNCERTAIN,
    GuardParams,
    auv_status,
    grown_radius,
    guard,
    inflate,
)

ORIGIN = Origin.from_degrees(63.4406, 10.3530)
BASE = {
    "origin": {"lat_deg": 63.4406, "lon_deg": 10.3530},
    "controller": {"name": "hybrid-single", "preset": "paper1-field"},
    "vehicle": [{"role": "asv", "id": 0x2801}, {"role": "auv", "name": "a"}],
}


# --- configuration -----------------------------------------------------------------------------
@pytest.mark.parametrize(
    "change, field",
    [
        ({"link": {"bind": "localhost"}}, "link.bind"),
        ({"link": {"port": 70000}}, "link.port"),
        ({"link": {"announce_to": ["1.2.3.4"]}}, "link.announce_to"),
        ({"link": {"transport": "serial"}}, "link.transport"),
        ({"origin": {"lat_deg": 100.0, "lon_deg": 0.0}}, "origin.lat_deg"),
        ({"watchdog": {"auv_stale_s": 10.0, "auv_lost_s": 5.0}}, "watchdog"),
        ({"watchdog": {"asv_stale_s": "3"}}, "watchdog.asv_stale_s"),
        ({"watchdog": {"propeller": "rpm"}}, "watchdog.propeller"),
        ({"clock": {"speedup": 0.0}}, "clock.speedup"),
        ({"typo": 1}, "typo"),
        ({"vehicle": [{"role": "auv", "id": 1}]}, "exactly one vehicle with role 'asv'"),
        ({"vehicle": [{"role": "asv", "id": 1}, {"role": "auv", "id": 1}]}, "unique"),
        ({"vehicle": [{"role": "asv", "id": 1}, {"role": "auv"}]}, "vehicle[1]"),
        ({"vehicle": [{"role": "asv", "id": 1}, {"role": "rov", "id": 2}]}, "vehicle[1].role"),
        ({"controller": {"name": "nope"}}, "unknown controller 'nope'"),
        ({"controller": {"name": "hybrid-single", "preset": "nope"}}, "unknown preset"),
        ({"controller": {"name": "hybrid-single", "estimator": "x"}}, "controller.estimator"),
        ({"link": {"transport": "tcp"}}, "'tcp' and 'id'"),
    ],
)
def test_config_errors_name_the_field(change, field):
    data = json.loads(json.dumps(BASE)) | change
    with pytest.raises(ConfigError) as err:
        deploy_config_from_dict(data, "deploy.toml")
    assert "deploy.toml" in str(err.value) and field in str(err.value)


def test_config_two_auvs_need_a_multi_controller():
    data = BASE | {"vehicle": [*BASE["vehicle"], {"role": "auv", "id": 9}]}
    with pytest.raises(ConfigError, match="handles one AUV"):
        deploy_config_from_dict(data)
    ok = deploy_config_from_dict(data | {"controller": {"name": "hybrid-multi"}})
    assert [v.label for v in ok.auvs] == ["a", "0x0009"]


def test_config_more_auvs_than_a_scenario_may_have_are_refused():
    """A deployment had no bound on its AUVs (12 loaded and built hybrid-multi); a scenario
    has AUV_COUNT_MAX (docs/experiments.md, "Bounds"): the same here."""
    from mpcasv.config import AUV_COUNT_MAX

    auvs = [{"role": "auv", "id": 100 + k} for k in range(AUV_COUNT_MAX)]
    data = BASE | {"controller": {"name": "hybrid-multi"}}
    ok = deploy_config_from_dict(data | {"vehicle": [BASE["vehicle"][0], *auvs]})
    assert len(ok.auvs) == AUV_COUNT_MAX
    many = [BASE["vehicle"][0], *auvs, {"role": "auv", "id": 99}]
    with pytest.raises(ConfigError) as err:
        deploy_config_from_dict(data | {"vehicle": many}, "deploy.toml")
    assert f"deploy.toml: vehicle: {AUV_COUNT_MAX + 1} vehicles with role 'auv': at most" in (
        str(err.value))


# --- IMC conversions ---------------------------------------------------------------------------
@pytest.mark.parametrize("anchor_NE", [(0.0, 0.0), (900.0, -700.0), (-5000.0, 3000.0)])
@pytest.mark.parametrize("depth", [0.0, 3.5, 50.0])
def test_estimated_state_round_trip_through_moving_reference_point(anchor_NE, depth):
    anchor = Origin(*to_wgs84(*anchor_NE, ORIGIN), 0.0)
    nav = NavState(1.7e9, 812.3, -645.9, depth, 1.1, 1.4, 0.1, 0.01, 0.6, 1.3, 0.0, 0.0)
    es = estimated_state(nav, anchor, ORIGIN)
    assert (es.lat, es.lon) == (anchor.lat, anchor.lon)
    back = nav_state(stamp(es, 1, 2, nav.t), ORIGIN)
    assert math.hypot(back.N - nav.N, back.E - nav.E) < 1e-3  # x/y are float32 on the wire
    assert back.depth == pytest.approx(depth) and back.psi == pytest.approx(1.1)


def test_reference_transit_keeps_line_of_sight_and_standby_is_speed_zero():
    cmd = Command(Mode.TRANSIT, (300.0, 400.0), 2.5, 0, Reason.TRACKING)
    ref = reference(cmd, (0.0, 0.0), ORIGIN, lead=20.0)
    N, E, _ = to_local(ref.lat, ref.lon, 0.0, ORIGIN)
    assert math.hypot(N, E) == pytest.approx(520.0, abs=1e-3)  # 500 m + the lead
    assert math.atan2(E, N) == pytest.approx(math.atan2(400, 300), abs=1e-7)
    assert ref.speed.value == 2.5 and ref.z.value == 0.0
    flags = imcpy.Reference.FlagsBits
    assert int(ref.flags) == int(flags.LOCATION | flags.SPEED | flags.Z)
    stop = reference(Command.standby(), (12.0, -7.0), ORIGIN, lead=20.0)
    assert stop.speed.value == 0.0
    assert to_local(stop.lat, stop.lon, 0.0, ORIGIN)[:2] == pytest.approx((12.0, -7.0), abs=1e-6)


def test_udp_services():
    s = "imc+info://0.0.0.0/version/5.4;imc+udp://10.0.0.5:6002/;imc+udp://127.0.0.1:6003/;x"
    assert udp_services(s) == [("10.0.0.5", 6002), ("127.0.0.1", 6003)]
    assert udp_services("imc+udp://bad/;") == []


# --- DUNE FollowReference semantics ------------------------------------------------------------
def _followref(src=0xFFFF, timeout=5.0):
    fr = imcpy.FollowReference()
    fr.control_src, fr.control_ent, fr.timeout = src, 0xFF, timeout
    return FollowRefManeuver(fr, 100.0, ORIGIN, top_speed=3.0)


def _ref(N=None, E=None, speed=None, src=0x4001, flags=0):
    r = imcpy.Reference()
    F = imcpy.Reference.FlagsBits
    if N is not None:
        r.lat, r.lon = to_wgs84(N, E, ORIGIN)
        flags |= F.LOCATION
    if speed is not None:
        sp = imcpy.DesiredSpeed()
        sp.value, sp.speed_units = speed, imcpy.SpeedUnits.METERS_PS
        r.speed = sp
        flags |= F.SPEED
    r.flags = flags
    return stamp(r, src, 0x2801, 0.0)


def test_followref_goto_hover_speed_zero_and_held_fields():
    m = _followref()
    S = imcpy.FollowRefState.StateEnum
    assert m.state == S.WAIT and not np.any(m.command_vector())
    assert m.on_reference(_ref(100.0, 0.0, 2.0), 101.0, (0.0, 0.0))
    assert m.state == S.GOTO and list(m.command_vector()) == pytest.approx([1, 100, 0, 2], abs=1e-6)
    assert m.on_reference(_ref(speed=1.0), 102.0, (0.0, 0.0))  # location kept
    assert list(m.command_vector()) == pytest.approx([1, 100, 0, 1], abs=1e-6)
    assert m.on_reference(_ref(speed=0.0), 103.0, (0.0, 0.0))  # speed 0: loops off
    assert not np.any(m.command_vector())
    assert m.on_reference(_ref(speed=2.0), 103.5, (0.0, 0.0))
    assert m.command_vector()[0] == 1.0
    assert m.on_reference(_ref(110.0, 0.0), 104.0, (96.0, 0.0))  # 14 m < 15 m: arrived
    assert m.state == S.HOVER and not np.any(m.command_vector())
    assert m.on_reference(_ref(140.0, 0.0), 105.0, (96.0, 0.0))
    assert m.state == S.GOTO


def test_followref_source_filter_mandone_and_timeout():
    m = _followref(src=0x4001, timeout=5.0)
    assert not m.on_reference(_ref(50.0, 0.0, 1.0, src=0x9999), 101.0, (0.0, 0.0))
    assert m.ignored == 1 and m.state == imcpy.FollowRefState.StateEnum.WAIT
    assert m.on_reference(_ref(50.0, 0.0, 1.0), 101.0, (0.0, 0.0))
    assert not m.check_timeout(105.9)
    assert m.check_timeout(106.1) and m.done and not np.any(m.command_vector())
    assert not m.check_timeout(107.0)  # reported once
    m2 = _followref()
    m2.on_reference(_ref(50.0, 0.0, 1.0), 101.0, (0.0, 0.0))
    assert m2.on_reference(_ref(flags=imcpy.Reference.FlagsBits.MANDONE), 102.0, (0.0, 0.0))
    assert m2.done and not np.any(m2.command_vector())
    assert not m2.on_reference(_ref(50.0, 0.0, 1.0), 103.0, (0.0, 0.0))  # over


# --- watchdogs and guard -----------------------------------------------------------------------
GP = GuardParams(stale_s=3.0, lost_s=30.0, v_max=2.0, w_max=0.5, r_keep=50.0, margin_m=10.0,
                 speed=1.5)  # fmt: skip


def _obs(asv=(0.0, 0.0), auvs=((60.0, 0.0),)):
    ests = tuple(AUVEstimate(N, E, 0.0, t_last_fix=0.0) for N, E in auvs)
    return Observation(10.0, ASVState(*asv, 0.0), False, ests)


def test_status_and_inflation():
    assert [auv_status(a, GP) for a in (0.0, 3.0, 3.1, 30.0, 30.1)] == [
        OK,
        OK,
        UNCERTAIN,
        UNCERTAIN,
        LOST,
    ]
    e = inflate(AUVEstimate(0, 0, 0, cov=(4.0, 1.0, 1.0, 9.0)), 5.0, 2.0)
    assert e.cov == (104.0, 1.0, 1.0, 109.0) and e.sigma > 10.0


def test_grown_radius_uses_the_shared_uncertain_radius():
    deep = AUVEstimate(0.0, 0.0, 45.0)
    assert grown_radius(deep, 0.0, GP) == pytest.approx(math.sqrt(50**2 - 45**2))
    # after 10 s it may have risen 5 m and moved 20 m
    assert grown_radius(deep, 10.0, GP) == pytest.approx(math.sqrt(50**2 - 40**2) + 20.0)
    assert grown_radius(AUVEstimate(0, 0, 80.0), 5.0, GP) == 0.0  # cannot reach the surface
    assert grown_radius(AUVEstimate(0, 0, 0.0), 1e4, GP) == pytest.approx(50.0 + 2.0 * 30.0)


def test_guard_policy():
    obs = _obs()  # ASV 60 m from the AUV
    stand = Command.standby(auv=0)
    assert guard(stand, obs, [OK], [1.0], GP) == (stand, None)
    # uncertain for 4 s: grown radius 58 m < 60 m: nothing to do
    assert guard(stand, obs, [UNCERTAIN], [4.0], GP) == (stand, None)
    # for 10 s: 70 m > 60 m: move straight away to 70 + 10 m
    cmd, why = guard(stand, obs, [UNCERTAIN], [10.0], GP)
    assert why == "guard_avoid" and cmd.mode is Mode.TRANSIT and cmd.reason is Reason.AVOIDANCE
    assert cmd.waypoint == pytest.approx((60.0 - 80.0, 0.0)) and cmd.speed == 1.5
    # lost, outside its (capped) grown disc: stand by
    far = _obs(asv=(0.0, 500.0))
    cmd, why = guard(Command(Mode.TRANSIT, (0, 0), 2.0), far, [LOST], [100.0], GP)
    assert why == "auv_lost_standby" and cmd.mode is Mode.STANDBY
    assert cmd.reason is Reason.FALLBACK
    # uncertain: a transit waypoint inside the grown disc is moved out of it
    go = Command(Mode.TRANSIT, (60.0, 65.0), 2.0, 0, Reason.TRACKING)
    cmd, why = guard(go, far, [UNCERTAIN], [10.0], GP)
    assert why == "guard_waypoint"
    assert math.hypot(cmd.waypoint[0] - 60.0, cmd.waypoint[1]) == pytest.approx(80.0)


def test_deploy_watchdogs_in_the_decisions(tmp_path, request):
    """Stale AUV -> inflated covariance and the guard in the logged decision; lost ->
    standby; stale ASV -> phase asv_stale (no decisions) until its state returns."""
    cfg = deploy_config_from_dict(BASE | {"log": {"dir": str(tmp_path)}})
    dep = Deploy(cfg, dry_run=True)
    request.addfinalizer(dep.close)  # its logs (it never runs)
    asv, auv = dep.link.asv, dep.link.auvs[0]
    now = 1000.0
    dep.clock.now = lambda: now
    asv.id, auv.id = 0x2801, 0x2811
    nav = NavState(now, 0.0, 0.0, 0.0, 0.0, 0.0, 0, 0, 0, 0, 0, 0)
    auv_nav = NavState(now, 60.0, 0.0, 0.0, 0.0, 0.0, 0, 0, 0, 0, 0, 0)
    auv.nav, auv.nav_recv = auv_nav, now
    dep._on_state(auv, auv_nav, now)
    asv.nav, asv.nav_recv = nav, now
    dep._on_state(asv, nav, now)
    assert dep.phase == RUNNING and dep.steps == 1
    for age in (2.0, 10.0, 40.0):
        now = 1000.0 + age
        asv.nav_recv = now
        dep.watch()
        dep.step(now, now)
    dep.jsonl.flush()
    steps = read_jsonl(tmp_path / "deploy.jsonl", "step")
    assert [s["status"] for s in steps] == [["ok"], ["ok"], ["uncertain"], ["lost"]]
    assert steps[2]["obs"]["auvs"][0]["cov"][0] == pytest.approx((2.0 * 10.0) ** 2)
    assert steps[2]["override"] == "guard_avoid"  # 60 m < 50 + 2 x 10 m
    assert steps[3]["override"] == "guard_avoid"  # still inside the capped disc
    events = [r["event"] for r in read_jsonl(tmp_path / "deploy.jsonl", "event")]
    assert "auv_uncertain" in events and "auv_lost" in events
    now = 1000.0 + 40.0 + 3.5  # no ASV state for 3.5 s > asv_stale_s = 3
    dep.watch()
    assert dep.phase == ASV_STALE
    nav = NavState(now, 0.0, 0.0, 0.0, 0.0, 0.0, 0, 0, 0, 0, 0, 0)  # stamped after the verdict
    asv.nav, asv.nav_recv = nav, now
    dep._on_state(asv, nav, now)
    assert dep.phase in (WAITING, RUNNING)


# --- records and logs --------------------------------------------------------------------------
def test_observation_round_trip_is_exact(tmp_path):
    obs = Observation(1.7e9 + 0.1, ASVState(1 / 3, -2 / 7, 0.1, 1.2, 0.0, -0.01), True, (
        AUVEstimate(10.0 / 3, 5.5, 2.0, 0.1, 0.2, (1.0, 0.1, 0.1, 2.0), 1.7e9),
        AUVEstimate(math.nan, 0.0, 0.0, t_last_fix=-math.inf)))  # fmt: skip
    w = JsonlWriter(tmp_path / "x.jsonl")
    w.write({"kind": "step", "obs": obs_to_dict(obs)})
    w.close()
    back = obs_from_dict(read_jsonl(tmp_path / "x.jsonl", "step")[0]["obs"])
    assert back.t == obs.t and back.propeller_on is True
    assert back.asv == obs.asv and back.auvs[0] == obs.auvs[0]  # bit for bit
    assert math.isnan(back.auvs[1].N) and back.auvs[1].t_last_fix == -math.inf


def test_read_jsonl_skips_a_torn_last_line(tmp_path):
    p = tmp_path / "x.jsonl"
    p.write_text('{"kind": "a"}\n{"kind": "b"}\n{"kind": "c", "x": 1')
    assert [r["kind"] for r in read_jsonl(p)] == ["a", "b"]
    p.write_text('{"kind": "a"}\nnot json\n{"kind": "c"}\n')
    with pytest.raises(ValueError, match="x.jsonl:2"):
        read_jsonl(p)


# --- a real DUNE log through the link ----------------------------------------------------------
SHARED_LOG = next((d / "dune-lauv-followref.lsf.gz" for d in (
    Path(__file__).resolve().parents[2] / "shared" / "data", Path("/work/shared/data"))
    if (d / "dune-lauv-followref.lsf.gz").is_file()),
    Path(__file__).resolve().parents[2] / "shared" / "data" / "dune-lauv-followref.lsf.gz")


@pytest.mark.skipif(not SHARED_LOG.exists(), reason="shared DUNE log not available")
def test_real_dune_messages_through_the_deploy_link(tmp_path):
    """DUNE's own EstimatedState, PlanControl answer, FollowRefState and thruster messages
    (stock LAUV simulator driven by FollowReference) pass every check, give the positions
    mpcasv.io.lsf.read_lsf gives, and move the deploy loop from 'starting' to 'running'."""
    from imcpy.lsf import LSFReader

    from mpcasv.io.deploy import STARTING
    from mpcasv.io.lsf import read_lsf

    data = gzip.decompress(SHARED_LOG.read_bytes())
    types = [imcpy.EstimatedState, imcpy.PlanControl, imcpy.FollowRefState,
             imcpy.SetThrusterActuation, imcpy.Announce]  # fmt: skip
    with LSFReader(data, use_index=False, save_index=False) as reader:
        msgs = [m for m in reader.read_message(types=types) if m.src == 0x00D1]
    es0 = next(m for m in msgs if isinstance(m, imcpy.EstimatedState))
    lat0, lon0 = (math.degrees(v) for v in absolute_latlon(es0)[:2])
    cfg = deploy_config_from_dict({
        "identity": {"id": 0x4001}, "origin": {"lat_deg": lat0, "lon_deg": lon0},
        "vehicle": [{"role": "asv", "id": 0x00D1, "name": "lauv-simulator-1",
                     "address": "127.0.0.1:6002"}, {"role": "auv", "id": 0x0AAA}],
        "controller": {"name": "hybrid-single"}, "log": {"dir": str(tmp_path)},
    })  # fmt: skip
    dep = Deploy(cfg)
    clock = {"t": msgs[0].timestamp}
    dep.clock.now = lambda: clock["t"]
    dep.phase, dep.pending = STARTING, (1, clock["t"])  # as if we had sent request 1
    for m in msgs:
        clock["t"] = m.timestamp
        dep.link.handle_message(m, m.serialize(), ("127.0.0.1", 6002), None)
    link = dep.link
    n_es = sum(isinstance(m, imcpy.EstimatedState) for m in msgs)
    assert dict(link.rejects) == {}
    assert link.accepted["EstimatedState"] == n_es and link.accepted["PlanControl"] == 1
    assert dep.phase == RUNNING and dep.started
    assert dep.followref["state"] == "GOTO"
    on, source, stale = dep.thrusters.propeller(clock["t"], True)
    assert dep.thrusters.last and on and source == "thruster" and not stale
    table = read_lsf(SHARED_LOG, Origin.from_degrees(lat0, lon0))
    last = table.iloc[-1]
    assert link.asv.nav.t == last["t"]
    assert math.hypot(link.asv.nav.N - last["N"], link.asv.nav.E - last["E"]) < 0.01
    dep.close()


def test_compare_metrics_tolerances():
    from mpcasv.io.rehearsal import COMPARABLE, compare_metrics

    base = {k: 100.0 for k in COMPARABLE}
    assert all(v["ok"] for v in compare_metrics(base, base | {"energy_J": 109.0}).values())
    assert not compare_metrics(base, base | {"energy_J": 112.0})["energy_J"]["ok"]
    zero = base | {"beyond_outer_s": 0.0}
    # sums of whole control periods may differ by one period, not more
    assert compare_metrics(zero, zero | {"beyond_outer_s": 1.0})["beyond_outer_s"]["ok"]
    assert not compare_metrics(zero, zero | {"beyond_outer_s": 2.0})[
        "beyond_outer_s"]["ok"]  # fmt: skip
    assert not compare_metrics(base | {"min_range_m": 0.0}, base | {"min_range_m": 1.0})[
        "min_range_m"]["ok"]  # fmt: skip


@pytest.mark.parametrize("estimator", ["perfect", "acoustic", "kalman", "plan"])
def test_deploy_feeds_the_simulators_estimators(tmp_path, estimator, request):
    """Each AUV EstimatedState reaches the estimator as in the simulator (a status report,
    and the truth for 'perfect'); the belief follows a straight-running AUV."""
    ctl = {"name": "hybrid-single", "preset": "paper1-field", "estimator": estimator}
    if estimator == "plan":
        ctl["scenario"] = str(Path(__file__).resolve().parents[1] / "experiments" / "scenarios"
                              / "case3.toml")  # fmt: skip
    cfg = deploy_config_from_dict(BASE | {"controller": ctl, "log": {"dir": str(tmp_path)}})
    dep = Deploy(cfg, dry_run=True)
    request.addfinalizer(dep.close)  # its logs (it never runs)
    asv, auv = dep.link.asv, dep.link.auvs[0]
    asv.id = 0x2801
    for i in range(20):
        now = 1000.0 + i
        dep.clock.now = lambda now=now: now
        a = NavState(now, -200.0 + 1.35 * i, 0.0, 0.0, 0.0, 1.35, 0, 0, 1.35, 0.0, 0, 0)
        auv.nav, auv.nav_recv = a, now
        dep._on_state(auv, a, now)
        s = NavState(now, -250.0, -150.0, 0.0, 0.5, 0, 0, 0, 0, 0, 0, 0)
        asv.nav, asv.nav_recv = s, now
        dep._on_state(asv, s, now)
    obs, status, _ = dep.observation(now, now)
    assert dep.steps == 20 and status == ["ok"]
    assert obs.auvs[0].N == pytest.approx(-200.0 + 1.35 * 19, abs=0.5)
    assert obs.auvs[0].t_last_fix == pytest.approx(now)


@pytest.mark.parametrize("scenario, says", [
    (None, "needs controller.scenario"),
    ("case4.toml", "no AUV of scenario 'case4' has a plan"),  # a transit: no waypoints
])  # fmt: skip
def test_deploy_plan_estimator_without_plans_is_refused(tmp_path, scenario, says):
    """``estimator = "plan"`` with no plan for any AUV would silently run the Kalman filter
    (a new user's walk-through, session 23): refused at load, in one line."""
    ctl = {"name": "hybrid-single", "preset": "paper1-field", "estimator": "plan"}
    if scenario is not None:
        ctl["scenario"] = str(Path(__file__).resolve().parents[1] / "experiments" / "scenarios"
                              / scenario)  # fmt: skip
    with pytest.raises(ConfigError, match=says) as info:
        deploy_config_from_dict(BASE | {"controller": ctl, "log": {"dir": str(tmp_path)}})
    assert "\n" not in str(info.value) and "'kalman'" in str(info.value)


def test_sitl_maneuver_escapes_with_the_power_turn_as_simulate_does():
    """A transit inside a collision domain is an escape (Gretha's power turn, turn_scope
    "avoidance") whoever sends it: World.advance decides it from the true ranges, for the
    simulator's Command and for the SITL's FollowReference maneuver alike (the SITL advances
    the world with the maneuver's vector, ``transit`` = 1). Before, only ``simulate`` marked the
    escape: Case 6 seed 3's rehearsal, after a standby inside auv1's domain at t = 250 s with a
    169 degree heading error, commanded the 29 N steering floor where the simulation commanded
    the 223 N power turn (until session 25 a "Known limits" entry of docs/deploy.md; now
    documented in docs/deploy.md section 1, "the one escape rule of World.advance", and the
    Case 6 rehearsal's agreement in section 5)."""
    from mpcasv.config import load_toml
    from mpcasv.control.execution import NCMD, command_vector
    from mpcasv.sim.scenario import scenario_from_dict
    from mpcasv.sim.world import World

    root = Path(__file__).resolve().parents[1]
    data = load_toml(root / "experiments" / "scenarios" / "case6.toml")
    data["preset"] = str(root / "mpcasv" / "data" / "presets" / "paper2-field.toml")
    # 4 m south of auv1 (at the surface, going north), heading north at 0.95 m/s (above eq.
    # 3.1's u_ff = 0.6 m/s of a hard turn: the speed loop asks for no thrust); the waypoint
    # 200 m south
    data["asv"]["start"] = {"N": 91.0, "E": -75.0, "psi_deg": 0.0, "speed": 0.95}
    sc = scenario_from_dict(data)
    wp = (-109.0, -74.0)
    m = _followref()
    assert m.on_reference(_ref(*wp, 2.5), 101.0, (91.0, -75.0))

    def first_transit(cmd_of, standby_periods: int) -> tuple[float, float]:
        w = World(sc, seed=0)
        for _ in range(standby_periods):
            w.advance(np.zeros(NCMD))
        stay = w.stay
        period = w.advance(cmd_of())
        return stay, float(period.U[0].max())

    sim = Command(Mode.TRANSIT, wp, 2.5, 0, Reason.AVOIDANCE)
    stay, T_sim = first_transit(lambda: command_vector(sim), 2)
    _, T_sitl = first_transit(m.command_vector, 2)
    _, T_escape = first_transit(lambda: np.array([2.0, *wp, 2.5]), 2)
    assert stay > 0  # inside the collision domain when the transit starts
    assert T_sim == pytest.approx(T_escape) and T_sitl == pytest.approx(T_escape)
    assert T_escape > 200.0  # the power turn (0.8 T_max at a heading error past 90 deg)
    # outside a collision domain (the first period: no stay yet) the same transit is a
    # tracking turn: no power turn, whoever sends it
    stay0, T0 = first_transit(m.command_vector, 0)
    assert stay0 == 0 and T0 < 60.0
