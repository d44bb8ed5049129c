"""The SITL's vehicles send DUNE's PlanControlState (IMC 560), so that a rehearsal exercises
the deploy's plan-state watch (:mod:`mpcasv.io.planstate`).

Before, ``mpcasv sitl`` sent none: an operator's STOP in a rehearsal ended the deploy only by
the FollowRefState silence (``followref_lost``, after ``link.followref_lost_s``), where real
DUNE's PlanControlState ends it within one report. The rate and the order around START and
MANDONE are taken from the recorded Otter (``tests/data/dune-traffic-excerpt.jsonl.gz`` holds
all its PlanControlStates, PlanControls and FollowRefStates); the STOP and TIMEOUT ones from
DUNE's ``Plan/Engine/Task.cpp`` (:mod:`mpcasv.io.sitlplan`).
"""

from __future__ import annotations

import asyncio
import statistics
from pathlib import Path

import imcpy
from test_io_dune_recording import EXCERPT, HDR, OTTER, US, capture
from test_io_sitl import ME, Node, _heard, _run, _until

from mpcasv.config import load_toml
from mpcasv.io.config import deploy_config_from_dict
from mpcasv.io.deploy import Deploy
from mpcasv.io.imc import announce
from mpcasv.io.logs import read_jsonl
from mpcasv.io.rehearsal import deploy_config_for
from mpcasv.io.sitl import Sitl, SitlOptions
from mpcasv.sim.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
CASE3 = ROOT / "experiments" / "scenarios" / "case3.toml"
PC, PCS, FRS = imcpy.PlanControl, imcpy.PlanControlState, imcpy.FollowRefState
WATCHED = (PC, PCS, FRS)
OPERATOR = 0x4002  # another system than the deploy's (ME)


def _shape(msgs, plan: str) -> list[tuple]:
    """The plan-related messages as comparable tuples, ``plan`` named ``"ours"``."""
    name = lambda p: "ours" if p == plan else p  # noqa: E731
    out = []
    for m in msgs:
        if isinstance(m, PC):
            out.append(("PlanControl", m.type.name, m.info))
        elif isinstance(m, PCS):
            out.append(("PlanControlState", m.state.name, name(m.plan_id), m.man_id,
                        m.last_outcome.name))  # fmt: skip
        else:
            out.append(("FollowRefState", m.state.name))
    return out


def _changes(shape: list[tuple]) -> list[tuple]:
    """``shape`` without the periodic PlanControlStates that repeat the one before."""
    out, last = [], None
    for s in shape:
        if s[0] == "PlanControlState":
            if s == last:
                continue
            last = s
        out.append(s)
    return out


def _recorded_otter():
    """(t, message) of the recorded Otter's PlanControl to us, PlanControlState and
    FollowRefState, in capture order."""
    ids = {imcpy.Factory.id_from_abbrev(c.__name__) for c in WATCHED}
    out = []
    for t, sent, _, raw in capture(EXCERPT):
        _, mgid, _, _, src, _, dst, _ = HDR.unpack_from(raw)
        if not sent and src == OTTER and mgid in ids and dst in (US, 0xFFFF):
            out.append((t, imcpy.Packet.deserialize(raw)))
    return out


def _from(msgs, first) -> list:
    """``msgs`` from the first matching ``first`` (periodic reports sent before a request
    was handled may come first)."""
    return msgs[next(k for k, m in enumerate(msgs) if first(m)):]


def _window(msgs, first, last) -> list:
    """``msgs`` from the first matching ``first`` to the first after it matching ``last``."""
    i = next(k for k, m in enumerate(msgs) if first(m))
    j = next(k for k in range(i, len(msgs)) if last(msgs[k]))
    return msgs[i:j + 1]


def test_the_sitl_asv_reports_its_plan_as_the_recorded_dune(tmp_path):
    """START, then MANDONE: the SITL ASV's PlanControlStates and answers, in the recorded
    Otter's order and fields, and its periodic reports at the recorded rate."""
    rec = _recorded_otter()
    ts = [t for t, m in rec if isinstance(m, PCS)]
    period = statistics.median(b - a for a, b in zip(ts, ts[1:], strict=False))
    msgs = [m for _, m in rec]
    rec_plan = next(m.plan_id for m in msgs if isinstance(m, PC))
    is_init = lambda m: isinstance(m, PCS) and m.state.name == "INITIALIZING"  # noqa: E731
    is_frs = lambda m: isinstance(m, FRS)  # noqa: E731
    is_done = lambda m: isinstance(m, PC) and m.info == "plan completed"  # noqa: E731
    is_ready = lambda m: isinstance(m, PCS) and m.state.name == "READY"  # noqa: E731
    rec_start = _changes(_shape(_window(msgs, is_init, is_frs), rec_plan))
    rec_end = _shape(_window(msgs, is_done, is_ready), rec_plan)
    got = {}

    async def body(sitl):
        asv, node = await _heard(sitl)
        # the periodic reports: PlanControlStates over a stretch of the SITL clock
        assert await _until(lambda: node.of(PCS, sitl.asv.id))
        n0, c0 = len(node.of(PCS, sitl.asv.id)), sitl.clock.now()
        await sitl.clock.sleep(20 * period)
        got["rate"] = (len(node.of(PCS, sitl.asv.id)) - n0) / (sitl.clock.now() - c0)
        got["before"] = node.of(PCS, sitl.asv.id)[-1]
        # START FollowReference, then MANDONE
        mark = len(node.got)
        pc = PC()
        pc.type, pc.op, pc.request_id, pc.plan_id = (PC.TypeEnum.REQUEST, PC.OperationEnum.START,
                                                     5, "p")  # fmt: skip
        fr = imcpy.FollowReference()
        fr.control_src, fr.control_ent, fr.timeout = ME, 0xFF, 60.0
        pc.arg = fr
        node.send(pc, asv, dst=sitl.asv.id)
        assert await _until(lambda: any(is_frs(m) for m in node.got[mark:]))
        got["start"] = _from([m for m in node.got[mark:] if isinstance(m, WATCHED)
                              and m.src != ME], is_init)  # fmt: skip
        mark = len(node.got)
        ref = imcpy.Reference()
        ref.flags = imcpy.Reference.FlagsBits.MANDONE
        node.send(ref, asv, dst=sitl.asv.id)
        assert await _until(lambda: any(is_ready(m) for m in node.got[mark:]))
        got["end"] = _from([m for m in node.got[mark:] if isinstance(m, (PC, PCS))
                            and m.src != ME], is_done)  # fmt: skip
        # each AUV's engine reports too (READY, no plan), as the recorded LAUV's
        for auv in sitl.auvs:
            node.send(imcpy.Heartbeat(), ("127.0.0.1", auv.port), dst=auv.id)
        assert await _until(lambda: all(node.of(PCS, a.id) for a in sitl.auvs))

    _run(tmp_path, body, duration=1000.0)
    assert abs(got["rate"] * period - 1.0) < 0.2, (got["rate"], period)
    assert got["before"].state.name == "READY" and got["before"].plan_id == ""
    assert _changes(_shape(got["start"], "p")) == rec_start
    assert _shape(got["end"], "p")[:len(rec_end)] == rec_end
    executing = next(m for m in got["start"] if isinstance(m, PCS) and m.state.name == "EXECUTING")
    assert executing.man_type == imcpy.Factory.id_from_abbrev("FollowReference")


def test_a_stop_and_a_timeout_end_the_plan_with_failure(tmp_path):
    """DUNE's ``stopPlan``: SUCCESS to the stopping system, READY (the plan, FAILURE); a STOP
    with no plan running is refused. A FollowReference timeout: FollowRefState TIMEOUT, then
    PlanControl FAILURE to the starter (its request id), then READY (FAILURE)."""
    got = {}

    async def body(sitl):
        asv, node = await _heard(sitl)

        def request(op, req, timeout=None):
            pc = PC()
            pc.type, pc.op, pc.request_id, pc.plan_id = PC.TypeEnum.REQUEST, op, req, "p"
            if timeout is not None:
                fr = imcpy.FollowReference()
                fr.control_src, fr.control_ent, fr.timeout = ME, 0xFF, timeout
                pc.arg = fr
            node.send(pc, asv, dst=sitl.asv.id)
            return len(node.got)

        async def collect(mark, last):
            assert await _until(lambda: any(last(m) for m in node.got[mark:]), timeout=3.0)
            return [m for m in node.got[mark:] if isinstance(m, WATCHED) and m.src != ME]

        ready = lambda m: isinstance(m, PCS) and m.state.name == "READY"  # noqa: E731
        answer = lambda m: isinstance(m, PC) and m.src == sitl.asv.id  # noqa: E731
        mark = request(PC.OperationEnum.START, 1, timeout=600.0)
        await collect(mark, lambda m: isinstance(m, FRS))
        mark = request(PC.OperationEnum.STOP, 2)
        got["stop"] = await collect(mark, ready)
        mark = request(PC.OperationEnum.STOP, 3)
        got["idle_stop"] = await collect(mark, answer)
        mark = request(PC.OperationEnum.START, 4, timeout=2.0)  # 2 s: 0.1 s of wall at 20x

        def ended_after_timeout():  # (READY reports of the idle engine come before it)
            new = node.got[mark:]
            at = [k for k, m in enumerate(new) if isinstance(m, FRS) and m.state.name == "TIMEOUT"]
            return bool(at) and any(ready(m) for m in new[at[0]:])

        assert await _until(ended_after_timeout, timeout=3.0)
        got["timeout"] = [m for m in node.got[mark:] if isinstance(m, WATCHED) and m.src != ME]

    _run(tmp_path, body, duration=1000.0)
    stop = _shape(_from(got["stop"], lambda m: isinstance(m, PC)), "p")
    assert stop[0] == ("PlanControl", "SUCCESS", "plan stopped")
    assert stop[-1] == ("PlanControlState", "READY", "ours", "", "FAILURE")
    assert [(m.type.name, m.request_id) for m in got["idle_stop"] if isinstance(m, PC)] == [
        ("FAILURE", 3)]
    timed = _changes(_shape(got["timeout"], "p"))
    after = timed[timed.index(("FollowRefState", "TIMEOUT")):]
    assert after == [("FollowRefState", "TIMEOUT"),
                     ("PlanControl", "FAILURE", "reference source timed out"),
                     ("PlanControlState", "READY", "ours", "", "FAILURE")]
    failure = next(m for m in got["timeout"] if isinstance(m, PC) and m.type.name == "FAILURE")
    assert failure.request_id == 4 and failure.dst == ME


def test_an_operators_stop_in_the_sitl_ends_a_rehearsal_deploy_as_plan_ended(tmp_path):
    """A rehearsal (the SITL and the deploy of ``sitl-case3.toml``, in one event loop) whose
    plan an operator (another IMC system) stops at the SITL: the deploy reads its
    PlanControlState EXECUTING, then READY / FAILURE, and ends with ``plan_ended`` from the
    PlanControlState, well before ``followref_lost_s``. Before, the SITL sent no
    PlanControlState: the deploy ended on ``followref_lost``."""
    speedup = 5.0
    sc = load_scenario(CASE3)
    base = load_toml(ROOT / "experiments" / "deploy" / "sitl-case3.toml")

    async def main():
        sitl = Sitl(sc, SitlOptions(speedup=speedup, discovery_port=0, out=tmp_path / "sitl",
                                    duration=1000.0))  # fmt: skip
        sitl_stop, dep_stop = asyncio.Event(), asyncio.Event()
        sitl_task = asyncio.create_task(sitl.run(sitl_stop))
        operator = None
        try:
            assert await _until(lambda: sitl.epoch > 0)
            ready = {"discovery": f"127.0.0.1:{sitl.discovery.address[1]}"}
            cfg = deploy_config_from_dict(deploy_config_for(ready, base, tmp_path / "deploy",
                                                            speedup))  # fmt: skip
            with Deploy(cfg) as dep:
                dep_task = asyncio.create_task(dep.run(dep_stop))
                assert await _until(lambda: dep.plan_executing and dep.steps >= 3, timeout=30)
                operator = await Node().open()  # Neptus, say: a system of its own
                h, port = operator.ep.address
                operator.send(announce("neptus", imcpy.SystemType.CCU, [f"imc+udp://{h}:{port}/"]),
                              sitl.discovery.address, src=OPERATOR)  # fmt: skip
                assert await _until(lambda: operator.of(imcpy.Announce, sitl.asv.id))
                pc = PC()
                pc.type, pc.op, pc.request_id = PC.TypeEnum.REQUEST, PC.OperationEnum.STOP, 77
                pc.plan_id = cfg.link.plan_id
                operator.send(pc, ("127.0.0.1", sitl.asv.port), dst=sitl.asv.id, src=OPERATOR)
                t_stop = sitl.clock.now()
                assert await _until(dep_stop.is_set, timeout=30)
                ended_after = sitl.clock.now() - t_stop
                summary = await dep_task
            return sitl, dep, summary, ended_after
        finally:
            sitl_stop.set()
            if operator is not None:
                operator.ep.close()
                Node.opened.remove(operator)
            await sitl_task

    sitl, dep, summary, ended_after = asyncio.run(main())
    events = [e for e in read_jsonl(tmp_path / "deploy" / "deploy.jsonl", "event")]
    names = [e["event"] for e in events]
    assert "plan_executing" in names
    ended = [e for e in events if e["event"] == "plan_ended"]
    assert len(ended) == 1 and ended[0]["source"] == "PlanControlState", ended
    assert (ended[0]["state"], ended[0]["last_outcome"]) == ("READY", "FAILURE")
    assert "followref_lost" not in names
    assert ended_after < dep.cfg.link.followref_lost_s, ended_after
    assert "PlanControlState READY" in summary["plan_ended"]
