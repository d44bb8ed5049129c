"""Session 17's bad-input walk of ``mpcasv sitl``, ``deploy`` and ``replay``: every impossible
value is refused in one line naming the option (or the configuration's field) and the value,
exit 2, before anything is written or bound for good (no partial ``sitl.jsonl``/``sitl.lsf``
or log folder left); a deploy that never makes a decision (no vehicle heard) exits 1 with one
line saying why.
"""

from __future__ import annotations

import json
import re
import socket
from pathlib import Path
from types import SimpleNamespace

import pytest

from mpcasv.cli import main
from mpcasv.io.deployphases import Phases

ROOT = Path(__file__).resolve().parents[1]
CASE3 = ROOT / "experiments" / "scenarios" / "case3.toml"
DEPLOY = ROOT / "experiments" / "deploy" / "sitl-case3.toml"
NOT_LOCAL = "192.0.2.1"  # TEST-NET-1 (RFC 5737): never an address of this host


def _exit_code(argv: list[str]) -> int:
    """``main(argv)``'s exit code, whether returned or raised by argparse."""
    try:
        return main([str(a) for a in argv])
    except SystemExit as exc:
        return exc.code


def _refused(argv: list[str], capsys, *words: str) -> str:
    """``argv`` exits 2 with one stderr line, no traceback, holding every one of ``words``."""
    code = _exit_code(argv)
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1 and "Traceback" not in err, err
    for word in words:
        assert word in lines[0], (word, lines[0])
    return lines[0]


@pytest.fixture
def busy_port():
    """A UDP port on 127.0.0.1 held open for the test."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    yield sock.getsockname()[1]
    sock.close()


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


# --- mpcasv sitl ------------------------------------------------------------------------------

# (extra arguments, words the one line must hold: the option and the value as given)
SITL_BAD = [
    (["--discovery-port", "70000"], ["--discovery-port", "70000"]),
    (["--discovery-port", "-1"], ["--discovery-port", "-1"]),
    (["--base-port", "65535"], ["--base-port", "65535"]),  # the AUV would take 65536
    (["--base-port", "-5"], ["--base-port", "-5"]),
    (["--speedup", "inf"], ["--speedup", "inf"]),
    (["--speedup", "1e-300"], ["--speedup", "1e-300"]),  # slept for ever, deaf to SIGTERM
    (["--origin", "100,10"], ["--origin", "100", "degrees"]),
    (["--origin", "63,200"], ["--origin", "200", "degrees"]),
    (["--origin", "nan,nan"], ["--origin", "nan"]),
    (["--seed", "-1"], ["--seed", "-1"]),
    (["--seed", str(2**32)], ["--seed", str(2**32)]),
    (["--asv-id", "10257"], ["--asv-id", "0x2811"]),  # AUV 0's id (--auv-id-base 0x2811)
    (["--asv-id", "0x2900", "--auv-id-base", "0x2900"], ["--asv-id", "0x2900"]),
    (["--asv-outage", "5,2"], ["--asv-outage", "5,2"]),
    (["--asv-outage=-1,2"], ["--asv-outage", "-1,2"]),
    (["--asv-outage", "1,inf"], ["--asv-outage", "inf"]),
    (["--asv-name="], ["--asv-name", "''"]),
    (["--asv-name", " "], ["--asv-name", "' '"]),
    (["--asv-name", "sitl-auv"], ["--asv-name", "sitl-auv"]),  # the AUV's system name
    (["--bind", "999.0.0.1"], ["--bind", "999.0.0.1"]),
    (["--bind", "nohost"], ["--bind", "nohost"]),
    (["--bind", NOT_LOCAL], ["--bind", NOT_LOCAL, "not an address of this host"]),
    (["--duration", "inf"], ["--duration", "inf"]),
]  # fmt: skip


@pytest.mark.parametrize("extra,words", SITL_BAD, ids=[" ".join(a) for a, _ in SITL_BAD])
def test_sitl_refuses_an_impossible_option_before_writing(extra, words, tmp_path, capsys):
    out = tmp_path / "sitl"
    ready = tmp_path / "ready.json"
    _refused(["sitl", CASE3, "--discovery-port", "0", "--base-port", "0", "--duration", "1",
              "--speedup", "50", "--quiet", "--out", out, "--ready-file", ready, *extra],
             capsys, *words)  # fmt: skip
    assert not out.exists() and not ready.exists()  # no partial sitl.jsonl / sitl.lsf


def test_sitl_refuses_auv_ids_past_0xfffe(tmp_path, capsys):
    """Case 6's three AUVs from 0xFFFD would take 0xFFFF, the broadcast id."""
    out = tmp_path / "sitl"
    _refused(["sitl", ROOT / "experiments" / "scenarios" / "case6.toml", "--discovery-port",
              "0", "--base-port", "0", "--auv-id-base", "0xFFFD", "--duration", "1",
              "--speedup", "50", "--quiet", "--out", out], capsys,
             "--auv-id-base", "0xFFFD", "0xFFFF")  # fmt: skip
    assert not out.exists()


# (arguments, words the one line must hold): an outage the world would never apply was run
# without it, exit 0 (the old code; with --hold it waited for ever for the first Reference)
SITL_OUTAGE_NEVER = [
    (["--duration", "1", "--asv-outage", "2,3"], ["--asv-outage 2,3", "--duration 1",
                                                  "never be killed", "T0 <= 0"]),
    (["--duration", "1", "--asv-outage", "1,2"], ["--asv-outage 1,2", "--duration 1"]),
    (["--duration", "10.5", "--asv-outage", "10.2,11"], ["--asv-outage 10.2,11",
                                                          "--duration 10.5", "T0 <= 10"]),
    (["--duration", "1", "--hold", "--asv-outage", "5,6"], ["--asv-outage 5,6", "--duration 1"]),
    (["--speedup", "1000", "--asv-outage", "1500,1600"],  # no --duration: case3's 1500 s
     ["--asv-outage 1500,1600", "1500 s", "the duration of scenario case3", "T0 <= 1499"]),
    (["--duration", "5", "--asv-outage", "1.2,1.8"], ["--asv-outage 1.2,1.8", "2 s",
                                                      "never be killed"]),
]  # fmt: skip


@pytest.mark.parametrize("extra,words", SITL_OUTAGE_NEVER,
                         ids=[" ".join(a) for a, _ in SITL_OUTAGE_NEVER])  # fmt: skip
def test_sitl_refuses_an_outage_that_would_never_happen(extra, words, tmp_path, capsys):
    out = tmp_path / "sitl"
    _refused(["sitl", CASE3, "--discovery-port", "0", "--base-port", "0", "--quiet", "--out",
              out, *extra], capsys, *words)  # fmt: skip
    assert not out.exists()


@pytest.mark.parametrize("duration,outage", [(1.0, (0.0, 1.0)), (2.0, (0.5, 1.5)),
                                             (1.5, (1.0, 9.0)), (None, (1499.0, 1500.0))])
def test_sitl_takes_an_outage_that_holds_a_period_start(duration, outage):
    from mpcasv.io.sitloptions import SitlOptions
    from mpcasv.sim.scenario import load_scenario

    opt = SitlOptions(duration=duration, asv_outage=outage)
    assert opt.check(load_scenario(CASE3)) is opt


@pytest.mark.parametrize("option", ["--discovery-port", "--base-port"])
def test_sitl_refuses_a_port_in_use_before_writing(option, busy_port, tmp_path, capsys):
    out = tmp_path / "sitl"
    other = "--base-port" if option == "--discovery-port" else "--discovery-port"
    _refused(["sitl", CASE3, other, "0", option, str(busy_port), "--duration", "1", "--quiet",
              "--out", out], capsys, option, str(busy_port), "in use")  # fmt: skip
    assert not out.exists()


def test_sitl_refuses_a_busy_port_of_an_auv(busy_port, tmp_path, capsys):
    """The base port is free, the port above it (the AUV's) is not."""
    out = tmp_path / "sitl"
    _refused(["sitl", CASE3, "--discovery-port", "0", "--base-port", str(busy_port - 1),
              "--duration", "1", "--quiet", "--out", out], capsys,
             "--base-port", str(busy_port), "AUV 0")  # fmt: skip
    assert not out.exists()


# --- mpcasv deploy: the configuration -------------------------------------------------------


def _deploy_config(tmp_path: Path, **lines: str) -> Path:
    """The shipped rehearsal configuration with its log folder in ``tmp_path``, any free data
    port, and each ``key = value`` line whose key is given replaced (key ``section__key`` for
    a key that is in several tables: the first one after ``[section]``)."""
    text = DEPLOY.read_text()
    text = re.sub(r"(?m)^dir = .*$", f'dir = "{tmp_path / "log"}"', text)
    text = re.sub(r"(?m)^port = .*$", "port = 0", text)
    for key, value in lines.items():
        section, _, key = key.rpartition("__")
        start = text.index(f"[{section}]") if section else 0
        pattern = re.compile(rf"(?m)^{key} = .*$")
        m = pattern.search(text, start)
        assert m is not None, key
        text = text[:m.start()] + f"{key} = {value}" + text[m.end():]
    path = tmp_path / "deploy.toml"
    path.write_text(text)
    return path


# (lines replaced, words the one line must hold: the field and the value)
DEPLOY_BAD_FIELDS = {
    "empty identity name": ({"identity__name": '""'}, ["identity.name", "''"]),
    "blank identity name": ({"identity__name": '"  "'}, ["identity.name", "'  '"]),
    "empty vehicle name": ({"vehicle__name": '""'}, ["vehicle[0].name", "''"]),
    "huge control period": ({"control_period": "1e9"}, ["controller.control_period", "1e+09",
                                                        "60 s"]),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(DEPLOY_BAD_FIELDS))
@pytest.mark.parametrize("mode", [["--prepare"], ["--dry-run", "--duration", "1"]])
def test_deploy_refuses_an_impossible_field(case, mode, tmp_path, capsys):
    lines, words = DEPLOY_BAD_FIELDS[case]
    path = _deploy_config(tmp_path, **lines)
    _refused(["deploy", path, "--quiet", *mode], capsys, str(path), *words)
    assert not (tmp_path / "log").exists()


# --prepare only: the old code ran a dry run of 1 s of a 1e-6 clock for 11 days
@pytest.mark.parametrize("speedup", ["1e-06", "1e+06"])
def test_deploy_refuses_an_impossible_clock_factor(speedup, tmp_path, capsys):
    path = _deploy_config(tmp_path, speedup=speedup)
    _refused(["deploy", path, "--quiet", "--prepare"], capsys, str(path), "clock.speedup",
             speedup, "[0.01, 1000]")  # fmt: skip


# a field engineer's trial (session 45): both accepted; with a 60-s heartbeat DUNE stops
# streaming 30 s after each Heartbeat (its UDP transport's Contact Timeout), and the deploy
# said only asv_stale
LINK_PERIODS = {
    "heartbeat_period = 3600.0": ["link.heartbeat_period", "3600 s", "[0.1, 10] s", "30 s"],
    "heartbeat_period = 60": ["link.heartbeat_period", "60 s", "Contact Timeout"],
    "heartbeat_period = 0.0001": ["link.heartbeat_period", "0.0001 s", "[0.1, 10] s"],
    "announce_period = 0.0001": ["link.announce_period", "0.0001 s", "[1, 60] s"],
    "announce_period = 3600.0": ["link.announce_period", "3600 s", "restarted DUNE"],
}


@pytest.mark.parametrize("line", sorted(LINK_PERIODS))
@pytest.mark.parametrize("mode", [["--prepare"], ["--dry-run", "--duration", "1"]])
def test_deploy_refuses_a_link_period_dune_cannot_work_with(line, mode, tmp_path, capsys):
    path = _deploy_config(tmp_path)
    path.write_text(path.read_text().replace("[link]\n", f"[link]\n{line}\n", 1))
    _refused(["deploy", path, "--quiet", *mode], capsys, str(path), *LINK_PERIODS[line])
    assert not (tmp_path / "log").exists()


def test_deploy_takes_the_link_periods_at_their_bounds(tmp_path, capsys):
    path = _deploy_config(tmp_path)
    text = path.read_text().replace("[link]\n", "[link]\nheartbeat_period = 10.0\n"
                                    "announce_period = 1.0\n", 1)  # fmt: skip
    path.write_text(text)
    assert _exit_code(["deploy", path, "--quiet", "--prepare"]) == 0, capsys.readouterr().err


# --- mpcasv deploy: what the run needs of this host --------------------------------------


def _host_cases(tmp_path: Path) -> dict[str, tuple[dict, list[str]]]:
    afile = tmp_path / "afile"
    afile.write_text("keep me\n")
    return {
        "log dir in /proc": ({"dir": '"/proc/mpcasv-bad/log"'}, ["log.dir", "/proc/mpcasv-bad"]),
        "log dir is a file": ({"dir": f'"{afile}"'}, ["log.dir", str(afile), "a file"]),
        "foreign bind": ({"bind": f'"{NOT_LOCAL}"'}, ["link.bind", NOT_LOCAL,
                                                      "not an address of this host"]),
        "foreign discovery bind": ({"discovery_ports": f'[]\ndiscovery_bind = "{NOT_LOCAL}"'},
                                   ["link.discovery_bind", NOT_LOCAL]),
    }  # fmt: skip


# (the run checked the log folder already; --prepare did not. The addresses only in the run:
# --prepare runs at the quay with the boat's network down, docs/deploy.md)
HOST_CASES = [("log dir in /proc", "--prepare"), ("log dir is a file", "--prepare"),
              ("foreign bind", "--dry-run"), ("foreign discovery bind", "--dry-run")]


@pytest.mark.parametrize("case,mode", HOST_CASES)
def test_deploy_tries_the_log_folder_and_the_bind_address_first(case, mode, tmp_path, capsys):
    mode = [mode] if mode == "--prepare" else [mode, "--duration", "1"]
    lines, words = _host_cases(tmp_path)[case]
    path = _deploy_config(tmp_path, **lines)
    _refused(["deploy", path, "--quiet", *mode], capsys, str(path), *words)
    assert not (tmp_path / "log").exists()
    assert case != "log dir is a file" or (tmp_path / "afile").read_text() == "keep me\n"


def test_prepare_takes_an_address_of_the_boats_network_while_it_is_down(tmp_path, capsys):
    """A review found ``--prepare`` refusing ``link.bind`` set to the boat network's address
    with that network down, where docs/deploy.md says to run it."""
    lines, _ = _host_cases(tmp_path)["foreign bind"]
    path = _deploy_config(tmp_path, **lines)
    assert _exit_code(["deploy", path, "--quiet", "--prepare"]) == 0, capsys.readouterr().err


def test_deploy_refuses_a_data_port_in_use_before_starting(busy_port, tmp_path, capsys):
    path = _deploy_config(tmp_path)
    path.write_text(path.read_text().replace("port = 0", f"port = {busy_port}", 1))
    _refused(["deploy", path, "--dry-run", "--duration", "1", "--quiet"], capsys,
             "link.port", str(busy_port), "in use")  # fmt: skip
    assert not (tmp_path / "log").exists()


# --- mpcasv deploy: a run that never decides ------------------------------------------------


def test_a_deploy_that_hears_no_vehicle_exits_1_saying_so(tmp_path, capsys):
    nobody = f"127.0.0.1:{_free_port()}"
    path = _deploy_config(tmp_path, announce_to=f'["{nobody}"]', speedup="20.0")
    code = _exit_code(["deploy", path, "--dry-run", "--duration", "20", "--quiet"])
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert code == 1, err
    assert len(lines) == 1 and "Traceback" not in err, err
    assert "no vehicle heard" in lines[0] and nobody in lines[0], lines[0]
    summary = json.loads(out.strip().splitlines()[-1])["summary"]
    assert summary["steps"] == 0 and summary["heard"] == []
    assert summary["no_decision"] in lines[0]
    last = (tmp_path / "log" / "deploy.jsonl").read_text().strip().splitlines()[-1]
    assert json.loads(last)["no_decision"] == summary["no_decision"]  # the log says why too


def test_the_started_event_names_the_log_folder_used(tmp_path, capsys):
    """``--log-dir`` overrides ``log.dir``: the ``started`` event's ``config.log.dir`` is the
    folder used, as its ``log_dir`` is (it showed the file's folder; a field engineer's
    trial, session 45)."""
    nobody = f"127.0.0.1:{_free_port()}"
    path = _deploy_config(tmp_path, announce_to=f'["{nobody}"]', speedup="20.0")
    used = tmp_path / "elsewhere"
    code = _exit_code(["deploy", path, "--dry-run", "--duration", "2", "--quiet",
                       "--log-dir", used])  # fmt: skip
    assert code == 1, capsys.readouterr().err
    assert not (tmp_path / "log").exists()
    started = next(json.loads(line) for line in (used / "deploy.jsonl").read_text().splitlines()
                   if json.loads(line).get("event") == "started")  # fmt: skip
    assert started["log_dir"] == str(used) == started["config"]["log"]["dir"]


def _deploy_stub(steps: int, heard: list[bool], state: list[bool],
                 transport: str = "udp", speedup: float = 1.0) -> SimpleNamespace:  # fmt: skip
    tcp = transport == "tcp"
    peers = [SimpleNamespace(label=f"v{k}", last_heard=0.0 if h else float("-inf"),
                             nav=object() if s else None,
                             spec=SimpleNamespace(tcp=f"127.0.0.1:{6001 + k}" if tcp else None))
             for k, (h, s) in enumerate(zip(heard, state, strict=True))]  # fmt: skip
    link = SimpleNamespace(announce_to=() if tcp else ("127.0.0.1:30100",), transport=transport,
                           bind="127.0.0.1")
    stub = SimpleNamespace(
        steps=steps, phase="waiting", plan_starts=0, plan_failures=0, started=False,
        cfg=SimpleNamespace(link=link, clock=SimpleNamespace(speedup=speedup)),
        link=SimpleNamespace(peers=peers, endpoint=None if tcp else SimpleNamespace(
            address=("127.0.0.1", 1)), tcp_error=None, strangers={}),  # fmt: skip
    )
    stub.heard = lambda: Phases.heard(stub)
    return stub


def test_no_decision_names_what_was_missing():
    assert Phases.no_decision(_deploy_stub(3, [True, True], [True, True]), 5.0) is None
    why = Phases.no_decision(_deploy_stub(0, [False, False], [False, False]), 5.0)
    assert why.startswith("no vehicle heard in 5 s") and "v0, v1" in why
    assert "link.announce_to: 127.0.0.1:30100" in why and "127.0.0.1:1" in why
    # over TCP no Announce is sent (link.announce_to is not read): it names the tcp servers
    why = Phases.no_decision(_deploy_stub(0, [False, False], [False, False], "tcp"), 5.0)
    assert why.startswith("no vehicle heard in 5 s") and "announce" not in why.lower()
    assert "v0 127.0.0.1:6001, v1 127.0.0.1:6002" in why and "sitl --tcp" in why
    # at a speed-up the seconds are the deploy clock's (a new user's finding, session 42:
    # "297 s" after a minute of wall time)
    why = Phases.no_decision(_deploy_stub(0, [False, False], [False, False], speedup=5.0), 297)
    assert why.startswith("no vehicle heard in 297 s of the deploy clock ([clock] speedup 5)")
    why = Phases.no_decision(_deploy_stub(0, [True, True], [True, False]), 5.0)
    assert "no state" in why and "from v1 " in why and "heard: v0, v1" in why
    assert "announced but not configured" not in why


def test_no_decision_names_the_systems_that_announced_but_are_not_configured():
    """An AUV configured as 'auv' against the SITL's 'sitl-auv' (id 0x2811, the configured
    one too): the run ended with "no state accepted from auv (heard: sitl-asv)", which says
    something is wrong but not what (a new user's finding, session 41). The reject names the
    vehicle configured with that id, and the line names who announced."""
    from test_io_cases import _dune_announce, _link

    link, clock, events = _link([{"role": "asv", "name": "usv-a"},
                            {"role": "auv", "name": "auv", "id": 0x2811}])  # fmt: skip
    services = "imc+udp://10.0.10.60:6002/"
    link.handle_datagram(_dune_announce(clock, "sitl-auv", 0x2811, services),
                         ("10.0.10.60", 47000))  # fmt: skip
    assert link.rejects["unknown_sender"] == 1
    assert "(0x2811 is configured as 'auv')" in events[-1]["detail"], events[-1]
    assert link.strangers == {"sitl-auv": 0x2811}
    stub = _deploy_stub(0, [True, False], [True, False])
    stub.link.strangers = link.strangers
    why = Phases.no_decision(stub, 60.0)
    assert "announced but not configured: 'sitl-auv' 0x2811" in why, why
    why = Phases.no_decision(_deploy_stub(0, [True, True], [True, True]), 5.0)
    assert "'waiting'" in why


def test_no_decision_names_the_asv_that_never_answered_plan_control(tmp_path):
    """The roles swapped (a field engineer's trial, session 45): every vehicle heard and in
    state, PlanControl START sent to the configured 'ASV' again and again, never answered.
    The line said only "every vehicle was heard, the deploy stayed in phase 'starting'"; it
    names the configured ASV and the PlanControl it never answered. A vehicle that answers
    FAILURE is named as refusing. Lockstep on a hand-advanced clock; the watchdog pass run by
    hand."""
    import imcpy
    from test_deploy_speed_watch import _state
    from test_io_cases import dry_deploy

    from mpcasv.io.imc import stamp

    PC = imcpy.PlanControl

    for failure in (False, True):
        dep, clock = dry_deploy(tmp_path / str(failure))
        dep.dry_run = False
        dep.link._send_raw = lambda data, addr, p=None: True  # sent nowhere
        t0 = clock.t
        for k in range(1, 61):  # 30 s at 2 Hz
            clock.t = t0 + 0.5 * k
            dep.link.handle_datagram(_state(0x2811, clock.t, 1000.0, 0.0), ("10.0.10.60", 6002))
            dep.link.handle_datagram(_state(0x2801, clock.t, 0.0, 0.0), ("10.0.10.50", 6002))
            if failure and dep.pending is not None:
                pc = PC()
                pc.type, pc.op = PC.TypeEnum.FAILURE, PC.OperationEnum.START
                pc.request_id, pc.plan_id, pc.info = dep.pending[0], "mpcasv-followref", "no"
                raw = stamp(pc, 0x2801, dep.link.id, clock.t).serialize()
                dep.link.handle_datagram(raw, ("10.0.10.50", 6002))
            dep.watch()
        why = dep.no_decision(30.0)
        assert "the configured ASV" in why and "0x2801" in why, why
        assert dep.plan_starts >= 3 and not dep.started
        if failure:
            assert "refused FollowReference" in why and "plan_start_failed" in why, why
        else:
            assert "never answered PlanControl START" in why and "roles swapped" in why, why
        dep.close()


# --- mpcasv replay --------------------------------------------------------------------------


@pytest.mark.parametrize("option,value", [("--tol", "-1"), ("--tol", "nan"), ("--tol", "inf"),
                                          ("--show", "-1")])  # fmt: skip
def test_replay_refuses_an_impossible_option(option, value, tmp_path, capsys):
    out = tmp_path / "r.jsonl"
    _refused(["replay", tmp_path, option, value, "--json", out], capsys, option, value)
    assert not out.exists()


def test_waiting_names_who_announced_but_is_not_configured(tmp_path):
    """While the deploy waits for a misnamed AUV, its 'waiting' event (on the console) names
    the system that announced instead, not only the run's last line (a new user's finding,
    session 41: without --duration an operator waited blind)."""
    from test_io_cases import _dune_announce, dry_deploy

    from mpcasv.io.logs import read_jsonl

    dep, clock = dry_deploy(tmp_path, vehicle=[
        {"role": "asv", "id": 0x2801, "address": "10.0.10.50:6002"},
        {"role": "auv", "name": "auv", "id": 0x2811}])  # fmt: skip
    dep.watch()
    dep.link.handle_datagram(_dune_announce(clock, "sitl-auv", 0x2811,
                                            "imc+udp://10.0.10.60:6002/"), ("10.0.10.60", 47000))
    dep.watch()
    dep.jsonl.flush()
    waiting = [e for e in read_jsonl(tmp_path / "deploy.jsonl", "event")
               if e["event"] == "waiting"]  # fmt: skip
    assert "announced_not_configured" not in waiting[0]
    assert waiting[-1]["announced_not_configured"] == {"sitl-auv": "0x2811"}
    dep.close()
