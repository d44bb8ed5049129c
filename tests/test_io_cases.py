"""The failing inputs of /work/shared/cases/ for the IMC link and replay, as tests (each test
names its case folder)."""

from __future__ import annotations

import shutil
from pathlib import Path

import imcpy
import pytest
from shared_data import CASES

from mpcasv.cli import main
from mpcasv.io.config import deploy_config_from_dict
from mpcasv.io.geo import Origin, to_wgs84
from mpcasv.io.imc import NavState, estimated_state, stamp
from mpcasv.io.link import ImcLink
from mpcasv.io.logs import read_jsonl

CASE_DIR = Path(__file__).parent / "data" / "cases"  # copies of the case inputs (CI)


class FakeClock:  # the deploy clock, advanced by hand
    def __init__(self, t: float = 1_700_000_000.0) -> None:
        self.t = t

    def now(self) -> float:
        return self.t

    def wall_seconds(self, s: float) -> float:
        return s


def dry_deploy(tmp_path, **extra):
    """A dry-run deploy loop (one ASV 0x2801 at 10.0.10.50, one AUV 0x2811 at 10.0.10.60,
    hybrid-single) on a :class:`FakeClock`, logging into ``tmp_path``; ``extra``: more
    configuration tables (e.g. ``watchdog``). Returns ``(deploy, clock)``; the deploy never
    runs: close it (its logs)."""
    from mpcasv.io.deploy import Deploy

    cfg = deploy_config_from_dict({
        "identity": {"id": 0x4001},
        "origin": {"lat_deg": 41.18, "lon_deg": -8.70},
        "link": {"bind": "127.0.0.1", "port": 0, "announce_to": []},
        "vehicle": [{"role": "asv", "id": 0x2801, "address": "10.0.10.50:6002"},
                    {"role": "auv", "id": 0x2811, "address": "10.0.10.60:6002"}],
        "controller": {"name": "hybrid-single", "preset": "paper1-field"},
        "log": {"dir": str(tmp_path)},
    } | extra)  # fmt: skip
    dep = Deploy(cfg, dry_run=True)
    clock = FakeClock()
    dep.clock = dep.link.clock = clock
    return dep, clock


def _link(vehicles, port=0):
    cfg = deploy_config_from_dict({
        "identity": {"id": 0x4001},
        "origin": {"lat_deg": 41.18, "lon_deg": -8.70},
        "link": {"bind": "127.0.0.1", "port": port, "announce_to": []},
        "vehicle": vehicles,
        "controller": {"name": "hybrid-single", "preset": "paper1-field"},
    })  # fmt: skip
    events: list[dict] = []
    clock = FakeClock()
    return ImcLink(cfg, clock, on_event=events.append), clock, events


# --- dune-announce-from-ephemeral-port -------------------------------------------------------
DUNE_SERVICES = ("dune://0.0.0.0/uid/1234567890;dune://0.0.0.0/version/2024.01.0;"
                 "imc+info://0.0.0.0/version/5.4.30;imc+tcp://10.0.10.50:6001/;"
                 "imc+udp://10.0.10.50:6002/")  # fmt: skip


def _dune_announce(clock, name="usv-a", src=0x2801, services=DUNE_SERVICES):
    a = imcpy.Announce()
    a.sys_name, a.sys_type, a.owner = name, imcpy.SystemType.USV, 0xFFFF
    a.lat = a.lon = a.height = 0.0
    a.services = services
    stamp(a, src, 0, clock.now(), src_ent=96)
    return a.serialize()


def feed_states(dep, clock, t: float, n: int, asv_ahead: float = 0.0,
                asv=("10.0.10.50", 6002), auv=("10.0.10.60", 6002)) -> float:  # fmt: skip
    """``n`` periods of 0.5 s of the AUV's (0x2811, 100 m north) and the ASV's (0x2801, at the
    origin; its clock ``asv_ahead`` s ahead) states into a :func:`dry_deploy`, deploy clock
    and vehicle clocks advancing together from ``t``; returns the last state's time."""
    for _ in range(n):
        clock.t += 0.5
        t += 0.5
        dep.link.handle_datagram(_es(clock, 0x2811, t, 100.0), auv)
        dep.link.handle_datagram(_es(clock, 0x2801, t + asv_ahead, 0.0), asv)
    return t


def _es(clock, src, t, N=0.0):
    o = Origin.from_degrees(41.18, -8.70)
    anchor = Origin(*to_wgs84(0.0, 0.0, o), 0.0)
    es = estimated_state(NavState(t, N, 0.0, 0.0, 0.0, 1.0, 0, 0, 1.0, 0, 0, 0), anchor, o)
    stamp(es, src, 0xFFFF, t)
    return es.serialize()


def test_case_dune_announce_from_ephemeral_port():
    """Case dune-announce-from-ephemeral-port: DUNE's Announce comes from its Announce task's
    own socket (10.0.10.50:47123) and names imc+udp://10.0.10.50:6002/: accepted, the data
    address and the id learnt; data then passes from 6002 only; an Announce from another host
    naming that address is refused."""
    link, clock, events = _link([{"role": "asv", "name": "usv-a"},
                                 {"role": "auv", "name": "auv-b"}])  # fmt: skip
    link.handle_datagram(_dune_announce(clock), ("10.0.10.50", 47123))
    assert dict(link.rejects) == {} and link.accepted["Announce"] == 1
    assert link.asv.addresses == {("10.0.10.50", 6002)} and link.asv.id == 0x2801
    assert [e["event"] for e in events] == ["discovered"]
    clock.t += 0.5
    link.handle_datagram(_es(clock, 0x2801, clock.t), ("10.0.10.50", 6002))
    assert link.accepted["EstimatedState"] == 1
    link.handle_datagram(_es(clock, 0x2801, clock.t + 0.1), ("10.0.10.50", 47123))
    assert link.rejects["address_mismatch"] == 1  # data only from the service address
    link.handle_datagram(_dune_announce(clock), ("10.0.10.99", 47123))
    assert link.rejects["address_mismatch"] == 2  # a host its services do not name


def test_case_dune_announce_static_address_any_port():
    """Case dune-announce-from-ephemeral-port with id and address configured: the Announce
    from the configured host's ephemeral port is accepted too (not address_mismatch)."""
    link, clock, _ = _link([{"role": "asv", "name": "usv-a", "id": 0x2801,
                             "address": "10.0.10.50:6002"},
                            {"role": "auv", "name": "auv-b"}])  # fmt: skip
    link.handle_datagram(_dune_announce(clock), ("10.0.10.50", 47123))
    assert dict(link.rejects) == {} and link.accepted["Announce"] == 1
    link.handle_datagram(_dune_announce(clock), ("10.0.10.51", 47123))
    assert link.rejects["address_mismatch"] == 1


def test_case_dune_announce_without_service_teaches_identity_only():
    """DUNE's first Announce at start-up has no imc+udp service: the id is learnt, no
    address; what the vehicle streams from that host before its next Announce is counted
    apart (pre_discovery), not rejected; from another host it is a reject."""
    link, clock, _ = _link([{"role": "asv", "name": "usv-a"}, {"role": "auv", "name": "auv-b"}])
    bare = "dune://0.0.0.0/uid/1;imc+info://0.0.0.0/version/5.4.30"
    link.handle_datagram(_dune_announce(clock, services=bare), ("10.0.10.50", 47123))
    assert link.asv.id == 0x2801 and not link.asv.addresses
    link.handle_datagram(_es(clock, 0x2801, clock.t), ("10.0.10.50", 6002))
    assert link.relayed["pre_discovery"] == 1 and not link.rejects
    link.handle_datagram(_es(clock, 0x2801, clock.t), ("10.0.10.77", 6002))
    assert link.rejects["not_announced"] == 1


# --- vehicle-clock-step ------------------------------------------------------------------------
def _clock_step_run(step: float, n: int = 40, at: int = 10, N_of=lambda k: 0.5 * k):
    """The case's repro: 2 Hz states of a configured AUV moving north at 1 m/s, the vehicle
    clock stepping by ``step`` after state ``at``."""
    link, clock, events = _link([{"role": "asv", "id": 0x2801, "address": "10.0.10.50:6002"},
                                 {"role": "auv", "id": 0x2811,
                                  "address": "10.0.10.60:6002"}])  # fmt: skip
    accepted = []
    link.on_state = lambda p, nav, now: accepted.append(nav.t)
    vclock = clock.t - 7200.0
    for k in range(n):
        clock.t += 0.5
        vclock += 0.5
        if k == at:
            vclock += step
        link.handle_datagram(_es(clock, 0x2811, vclock, N_of(k)), ("10.0.10.60", 6002))
    return link, accepted, [e for e in events if e["event"] == "clock_step"]


@pytest.mark.parametrize("step,reason", [(7200.0, "time_jump"), (-7200.0, "out_of_order"),
                                         (30.0, "time_jump"), (-3.0, "out_of_order")])
def test_case_vehicle_clock_step_recovered(step, reason):
    """Case vehicle-clock-step, forward and backward: after 3 self-consistent states on the
    new time base the link re-anchors (event clock_step with the offset) and accepts the
    states again; only the 2 states before the proof are rejected; a second step later is
    recovered the same way."""
    link, accepted, steps = _clock_step_run(step)
    assert len(accepted) == 38
    assert dict(link.rejects) == {reason: 2}
    assert len(steps) == 1
    assert steps[0]["offset_s"] == pytest.approx(step, abs=1e-6)
    assert steps[0]["states"] == 3
    # re-anchored onto the old time base: the timestamps handed on never step (the deploy's
    # decision grid and the estimators see one continuous clock)
    gaps = [b - a for a, b in zip(accepted[:-1], accepted[1:], strict=True)]
    assert gaps[9] == pytest.approx(1.5, abs=1e-6)  # the two rejected states' place
    assert all(g == pytest.approx(0.5, abs=1e-6) for g in gaps[:9] + gaps[10:])
    assert link.auvs[0].track.offset == pytest.approx(step, abs=1e-6)


def test_case_vehicle_clock_step_single_outlier_is_not_a_step():
    """One wrong timestamp, then the old time base again: no re-anchoring, one reject."""
    link, clock, events = _link([{"role": "asv", "id": 0x2801, "address": "10.0.10.50:6002"},
                                 {"role": "auv", "id": 0x2811,
                                  "address": "10.0.10.60:6002"}])  # fmt: skip
    t = clock.t
    for k in range(20):
        clock.t += 0.5
        ts = t + 0.5 * (k + 1) + (500.0 if k == 8 else 0.0)
        link.handle_datagram(_es(clock, 0x2811, ts, 0.5 * k), ("10.0.10.60", 6002))
    assert dict(link.rejects) == {"time_jump": 1}
    assert not [e for e in events if e["event"] == "clock_step"]


def test_case_vehicle_clock_step_needs_plausible_positions():
    """A 'new time base' whose positions jump away is no clock step: never re-anchored."""
    link, accepted, steps = _clock_step_run(7200.0, N_of=lambda k: 0.5 * k if k < 10
                                            else 5000.0 + 0.5 * k)  # fmt: skip
    assert len(accepted) == 10 and not steps
    assert sum(link.rejects.values()) == 30


# --- replay-given-binary-log -----------------------------------------------------------------
@pytest.mark.parametrize("name", ["imc.lsf", "Data.lsf.gz"])
def test_case_replay_given_binary_log(name, tmp_path, capsys):
    """Case replay-given-binary-log: one line naming the file and why, exit 2."""
    src = CASES / "replay-given-binary-log" / name
    if not src.is_file():
        src = CASE_DIR / "replay-given-binary-log" / name
    shutil.copy(src, tmp_path / name)
    assert main(["replay", str(tmp_path / name)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "not a deploy log" in err[0] and name in err[0] and "LSF" in err[0]


def test_case_vehicle_clock_step_twice_and_asv_grid(tmp_path, request):
    """Case vehicle-clock-step on the ASV, backward then forward: the deploy keeps deciding
    once per control period on the re-anchored timestamps (a backward step would otherwise
    stop its decision grid until the vehicle clock caught up)."""
    from mpcasv.io.deploy import RUNNING

    dep, clock = dry_deploy(tmp_path)
    request.addfinalizer(dep.close)  # its logs (it never runs)
    vclock = clock.t
    for k in range(120):  # 60 s at 2 Hz
        clock.t += 0.5
        vclock += 0.5
        if k == 30:
            vclock -= 600.0
        if k == 80:
            vclock += 3600.0
        link = dep.link
        link.handle_datagram(_es(clock, 0x2811, vclock - 5.0, 100.0), ("10.0.10.60", 6002))
        link.handle_datagram(_es(clock, 0x2801, vclock, 0.5 * k), ("10.0.10.50", 6002))
        if k % 2:
            dep.watch()
    assert dep.phase == RUNNING
    dep.jsonl.flush()  # the log is still open: read every record, not the buffer's cut
    offsets = [round(r["offset_s"]) for r in read_jsonl(tmp_path / "deploy.jsonl", "event")
               if r["event"] == "clock_step"]  # fmt: skip
    assert sorted(offsets) == [-600, -600, 3600, 3600]  # both vehicles, both steps
    ts = [r["t"] for r in read_jsonl(tmp_path / "deploy.jsonl", "step")]
    assert len(ts) >= 55 and all(0.5 <= b - a <= 2.0 for a, b in zip(ts[:-1], ts[1:],
                                                                      strict=True))
