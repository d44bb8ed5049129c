"""Issue 15 / issue 16 item 5 in the deploy: an MPC deploys in field mode. Its solves run in
a worker process with a hard deadline (started before any vehicle is contacted, also by
``--prepare``), its step runs off the event loop, so the link and the watchdogs keep running
while a solve hangs, and the workers are stopped at shutdown."""

from __future__ import annotations

import asyncio
import functools
import json
import time
from types import SimpleNamespace

import imcpy
import pytest
import tomli_w
from test_io_link import ASV_ID, AUV_ID, Fake, _cfg
from test_io_link import run as run_closing_fakes

from mpcasv.cli import main
from mpcasv.io.deploy import Deploy
from mpcasv.io.deploystep import FieldMode, check_budget
from mpcasv.io.logs import read_jsonl

BUDGET_MS = 1500.0  # the step's deadline in these tests (s of wall time, well above a tick)


class _Hang:
    """A solver whose every solve hangs (a native solver looping for ever, docs/mpc.md)."""

    def solve(self, *args):
        time.sleep(3600.0)


def hanging_solver():
    return _Hang()


def _mpc_cfg(tmp_path):
    cfg = _cfg(tmp_path)
    data = {
        "identity": {"id": cfg.identity.id},
        "origin": {"lat_deg": cfg.origin.lat_deg, "lon_deg": cfg.origin.lon_deg},
        "link": {"bind": "127.0.0.1", "port": 0, "announce_to": [], "discovery_ports": []},
        "vehicle": [{"role": "asv", "name": "fake-asv", "id": ASV_ID},
                    {"role": "auv", "name": "fake-auv"}],
        "controller": {"name": "mpc-single", "preset": "mpc-single",
                       "overrides": {"solver.budget_ms": BUDGET_MS}},
        "acoustics": {"T0": 4.0},
        "log": {"dir": str(tmp_path / "log"), "flush_s": 0.2},
    }  # fmt: skip
    return data


def test_link_and_watchdogs_run_while_a_solve_hangs(tmp_path):
    from mpcasv.io.config import deploy_config_from_dict

    cfg = deploy_config_from_dict(_mpc_cfg(tmp_path))
    dep = Deploy(cfg, dry_run=True, solver_factory=functools.partial(hanging_solver))
    assert dep.field_mode and dep.controller.deadline is not None  # before any socket
    assert dep.controller.acoustics.T0 == 4.0  # the configuration's channel, in the Boat
    seen = []  # (monotonic time, a step in flight, last ASV state's arrival)
    watch = dep.watch

    def watched():
        busy = dep._step_task is not None and not dep._step_task.done()
        seen.append((time.monotonic(), busy, dep.link.asv.nav_recv))
        watch()

    dep.watch = watched

    async def run():
        stop = asyncio.Event()
        task = asyncio.create_task(dep.run(stop))
        await asyncio.sleep(0.2)
        to = dep.link.endpoint.address
        asv = await Fake("fake-asv", ASV_ID, imcpy.SystemType.USV).open()
        auv = await Fake("fake-auv", AUV_ID).open()
        for v in (asv, auv):
            v.announce(to, dep.clock.now())
        t_end = time.monotonic() + 4.5
        i = 0
        while time.monotonic() < t_end:
            t = dep.clock.now()
            auv.send(auv.es(t, 120.0, 0.0), to, t)  # in the donut: the MPC solves
            asv.send(asv.es(t, 0.1 * i, 0.0), to, t)
            i += 1
            await asyncio.sleep(0.1)
        stop.set()
        return await task

    summary = run_closing_fakes(run)
    steps = read_jsonl(tmp_path / "log" / "deploy.jsonl", "step")
    assert steps, "no decision"
    first = steps[0]
    # the hung solve was cut at the deadline: the fallback's command, in about the budget
    assert first["diag"]["mpc_ok"] == 0 and first["controller_cmd"]["reason"] == "fallback"
    assert BUDGET_MS * 0.9 <= first["step_ms"] <= BUDGET_MS + 1000
    assert dep.controller.deadline is None  # workers stopped at shutdown
    # while it hung, the watchdogs ran every 0.25 s and the link took in the ASV's states
    busy = [s for s in seen if s[1]]
    assert len(busy) >= 4, seen
    assert busy[-1][2] > busy[0][2]  # newer ASV states accepted during the solve
    assert summary["skipped_steps"] >= 1  # the ticks during the hung solve were skipped
    recs = read_jsonl(tmp_path / "log" / "deploy.jsonl")
    assert recs[-1]["kind"] == "summary"


def test_prepare_starts_the_solver_worker_before_any_vehicle(tmp_path, capsys):
    data = _mpc_cfg(tmp_path)
    path = tmp_path / "deploy.toml"
    path.write_text(tomli_w.dumps(data))
    assert main(["deploy", str(path), "--prepare"]) == 0
    out = json.loads(capsys.readouterr().out)["prepared"]
    assert out["controller"] == "mpc-single" and out["field_mode"] is True
    # what the run will use, read at the quay (a new user's finding, session 41)
    c = data["controller"]
    assert (out["preset"], out["estimator"]) == (c["preset"], c.get("estimator", "perfect"))
    assert out["actuator_feedback"] is c.get("actuator_feedback", True)
    assert not (tmp_path / "log").exists()  # nobody contacted, nothing logged


def test_achievable_speed_caps_a_planned_speed(tmp_path):
    """With ``speed_feedback`` the learned achievable speed caps every transit command sent,
    also a controller whose speed comes from its plan (an MPC) rather than ``params.speed``."""
    from test_io_asv import _cfg as asv_cfg

    from mpcasv.interface import ASVState, AUVEstimate, Command, Mode, Observation

    dep = Deploy(asv_cfg(tmp_path, controller={"speed_feedback": True}), dry_run=True)

    class Planner:  # an MPC's command: the speed of its plan
        def step(self, obs):
            return Command(Mode.TRANSIT, (500.0, 0.0), 3.4, 0)

    dep.controller = Planner()
    auv = AUVEstimate(300.0, 0.0, 0.0, 0.0, 0.0, (1.0, 0.0, 0.0, 1.0), 0.0)
    obs = Observation(0.0, ASVState(0.0, 0.0, 0.0, 0.7), True, (auv,))
    dep.observation = lambda ts, now: (obs, ["ok"], [0.0])
    assert dep.step(0.0, 0.0).speed == 3.4  # nothing learned yet
    dep.speed_cap = 0.7
    assert dep.step(1.0, 1.0).speed == 0.7
    dep.jsonl.flush()
    last = read_jsonl(tmp_path / "deploy.jsonl", "step")[-1]
    assert last["controller_cmd"]["speed"] == 3.4 and last["cmd"]["speed"] == 0.7
    assert last["speed_capped"] is True
    dep.close()
    # the autopilot's own limit (DUNE's Maximum Absolute Speed) caps it too
    lim = Deploy(asv_cfg(tmp_path / "lim", speed={"command_max": 2.5}), dry_run=True)
    lim.controller, lim.observation = Planner(), dep.observation
    assert lim.step(0.0, 0.0).speed == 2.5
    lim.close()


def test_otter_deploy_config_plans_with_the_identified_otter(monkeypatch):
    """experiments/deploy/dune-otter.toml names the vessel identified from DUNE's Otter log;
    the MPC is built for that boat (with the configuration's acoustic channel)."""
    from pathlib import Path

    import pytest

    from mpcasv.io.config import build_controller, deploy_boat, load_deploy_config
    from mpcasv.models.params import load_vessel

    cfg = load_deploy_config(Path(__file__).resolve().parents[1] / "experiments" / "deploy"
                             / "dune-otter.toml")  # fmt: skip
    assert deploy_boat(cfg).vessel == load_vessel("dune-otter")
    # no speed cap for its MPC: DUNE's loop would stay near its floor (docs/deploy.md)
    assert not cfg.controller.speed_feedback and cfg.speed.command_max == 2.5
    seen = {}

    class Built(Exception):
        pass

    def build_ocp(params, n_auv, multi, log=print, boat=None):  # stands in for the compile
        seen["boat"] = boat
        raise Built

    monkeypatch.setattr("mpcasv.mpc.controller.build_ocp", build_ocp)
    with pytest.raises(Built):
        build_controller(cfg, log=lambda *a: None)
    assert seen["boat"].vessel.name == "dune-otter"
    assert seen["boat"].acoustics == cfg.acoustics


def test_a_step_that_raises_is_logged_not_lost(tmp_path):
    """Field mode runs each step as a task nobody awaited: an exception in it ended the step
    without a word (found in review), so the MPC could stop commanding silently. It is now an
    event ``step_error`` with the exception's first line, counted in ``step_errors``."""
    import contextlib

    from mpcasv.io.config import deploy_config_from_dict

    cfg = deploy_config_from_dict(_mpc_cfg(tmp_path))
    dep = Deploy(cfg, dry_run=True, solver_factory=functools.partial(hanging_solver))

    async def boom(ts, now):
        raise ValueError("the observation carries no true current\nsecond line")

    dep.step_async = boom

    async def run():
        dep.schedule_step(3.0, 3.0)
        with contextlib.suppress(ValueError):
            await dep._step_task
        await asyncio.sleep(0)  # the done-callback runs

    try:
        asyncio.run(run())
    finally:
        dep.close()  # the solver workers and the logs (it never runs)
    dep.jsonl.flush()
    errors = [e for e in read_jsonl(tmp_path / "log" / "deploy.jsonl", "event")
              if e["event"] == "step_error"]  # fmt: skip
    assert [e["error"] for e in errors] == ["ValueError: the observation carries no true current"]
    assert dep.step_errors == 1


@pytest.mark.parametrize("field,value,said", [
    # only a simulator knows the true current: "oracle" passed --prepare and would have
    # failed at every step in the field (found in review)
    ("current", "oracle", "current = 'oracle'"),
])  # fmt: skip
def test_a_simulator_only_setting_is_refused_before_any_vehicle(tmp_path, capsys, monkeypatch,
                                                                 field, value, said):  # fmt: skip
    """A setting only a simulation can feed is refused in one line at --prepare, not at
    every step in the field, and before the controller is built (an uncached MPC library
    would compile for a minute first: a new user's finding, session 40)."""
    import mpcasv.controllers

    def built(*a, **k):
        raise AssertionError("the controller was built before the refusal")

    monkeypatch.setattr(mpcasv.controllers, "make_controller", built)
    data = _mpc_cfg(tmp_path)
    data["controller"]["overrides"][field] = value
    path = tmp_path / "deploy.toml"
    path.write_text(tomli_w.dumps(data))
    assert main(["deploy", str(path), "--prepare"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and said in err[0], err


def test_observed_fixes_pass_the_configuration_checks(tmp_path):
    """M2o (``fix_age_source = "observed"``) was refused at --prepare while the deploy did
    not read DUNE's UsblFixExtended (session 40); it reads them now (tests/
    test_deploy_usbl.py), so the configuration loads with it."""
    from mpcasv.io.config import deploy_config_from_dict

    data = _mpc_cfg(tmp_path)
    data["controller"]["overrides"]["fix_age_source"] = "observed"
    cfg = deploy_config_from_dict(data)
    assert cfg.controller.overrides["fix_age_source"] == "observed"


def test_an_inline_step_that_raises_is_logged_when_it_happens_and_the_deploy_goes_on(
        tmp_path, caplog):  # fmt: skip
    """Review (session 5): outside field mode (the hybrid steps inline, in the link's
    datagram handler) a step that raised was caught by the link as a reject
    ``internal_error`` of the ASV's (accepted) state: not logged on the console, seen only
    in the summary at shutdown. Now as in field mode: event ``step_error`` (first line),
    logged as an error when it happens, counted in ``step_errors``; the deploy goes on and
    steps again once the controller does."""
    import logging

    from test_io_link import _start, _until

    async def run():
        dep, stop, task = await _start(_cfg(tmp_path), tmp_path, dry_run=True)
        assert not dep.field_mode
        good = dep.controller.step
        fail = {"on": True}

        def step(obs):
            if fail["on"]:
                raise ValueError("no estimate for AUV 0\nsecond line")
            return good(obs)

        dep.controller.step = step
        to = dep.link.endpoint.address
        asv = await Fake("fake-asv", ASV_ID, imcpy.SystemType.USV).open()
        auv = await Fake("fake-auv", AUV_ID).open()
        now = dep.clock.now
        auv.announce(to, now())
        asv.announce(to, now())
        assert await _until(lambda: dep.link.auvs[0].id == AUV_ID and dep.link.asv.addresses)

        async def states_until(pred):
            for _ in range(40):
                t = now()
                auv.send(auv.es(t, 100.0, 50.0), to, t)
                asv.send(asv.es(t, 0.0, 0.0), to, t)
                if await _until(pred, 0.25):
                    return True
            return False

        assert await states_until(lambda: dep.step_errors >= 2)
        assert not task.done() and dep.steps == 0
        fail["on"] = False
        assert await states_until(lambda: dep.steps >= 1)  # it goes on
        stop.set()
        return dep, await task

    with caplog.at_level(logging.ERROR, logger="mpcasv.deploy"):
        dep, summary = run_closing_fakes(run)
    errors = [e for e in read_jsonl(tmp_path / "log" / "deploy.jsonl", "event")
              if e["event"] == "step_error"]  # fmt: skip
    assert len(errors) == summary["step_errors"] == dep.step_errors >= 2
    assert {e["error"] for e in errors} == {"ValueError: no estimate for AUV 0"}
    assert "internal_error" not in summary["rejects"]  # not an input's fault
    shown = [r.getMessage() for r in caplog.records if r.levelno == logging.ERROR]
    assert len(shown) == len(errors) and all("ValueError: no estimate" in m for m in shown)
    assert summary["steps"] >= 1


class _Host(FieldMode):
    """The field mode's bookkeeping without a link: events and records kept in lists."""

    def __init__(self, controller):
        self.controller, self.events, self.records, self.step_errors = controller, [], [], 0
        self.between_solves, self.between_ms_max = 0, 0.0
        self.jsonl = SimpleNamespace(write=self.records.append)

    def event(self, name, **info):
        self.events.append((name, info))


class _Explorer:
    """``between_steps``: an exploration solve, then nothing due, then a carried step's work
    (``solver.step_iter``), then an exception."""

    def __init__(self):
        self.calls, self.diag = 0, {}

    def between_steps(self):
        self.calls += 1
        nothing = {"mpc_explore_iter": 0, "mpc_explore_ms": float("nan"),
                   "mpc_deferred_iter": 0, "mpc_deferred_ms": float("nan")}  # fmt: skip
        if self.calls == 1:
            self.diag = nothing | {"mpc_explore_iter": 12, "mpc_explore_ms": 3.0,
                                   "mpc_explore_adopted": 1}  # fmt: skip
        elif self.calls == 2:
            self.diag = nothing
        elif self.calls == 3:
            self.diag = nothing | {"mpc_deferred_iter": 40, "mpc_deferred_ms": 20.0,
                                   "mpc_deferred_source": "plan"}  # fmt: skip
        else:
            raise RuntimeError("boom\nsecond line")

    def diagnostics(self):
        return dict(self.diag) | {"mpc_ok": 1}


def test_the_work_after_a_step_is_logged_and_never_raises():
    """An exploration solve or a carried step's work after the command gives a ``between``
    record (nothing when none ran); one that raises is event ``between_error`` (counted in
    ``step_errors``), not an exception out of the step: the command was sent, the next tick
    steps as usual."""
    host = _Host(_Explorer())
    for t in (1.0, 2.0, 3.0, 4.0):
        host.log_between(t, host.run_between())
    assert len(host.records) == 2
    rec, deferred = host.records
    assert rec["kind"] == "between" and rec["t"] == 1.0 and rec["mpc_explore_iter"] == 12
    assert rec["ms"] >= 0.0 and "mpc_ok" not in rec
    assert deferred["t"] == 3.0 and deferred["mpc_deferred_iter"] == 40
    assert deferred["mpc_deferred_source"] == "plan"
    assert host.events == [("between_error", {"t": 4.0, "error": "RuntimeError: boom"})]
    assert host.step_errors == 1
    assert host.between_solves == 2  # the summary's
    assert host.between_ms_max == max(rec["ms"], deferred["ms"])


def test_a_budget_that_leaves_no_room_for_the_exploration_is_reported():
    """A step and its exploration each have ``solver.budget_ms``: with a 1-s period, 200 ms
    (the presets) fits; 500 ms may not (a tick may come 0.9 s after the last)."""
    said = []
    cfg = SimpleNamespace(controller=SimpleNamespace(control_period=1.0))

    def ctl(ms):
        return SimpleNamespace(params=SimpleNamespace(solver=SimpleNamespace(budget_ms=ms)))

    assert check_budget(cfg, ctl(200.0), log=said.append)
    assert not said
    assert not check_budget(cfg, ctl(500.0), log=said.append)
    assert len(said) == 1 and "solver.budget_ms = 500 ms" in said[0]
    assert check_budget(cfg, SimpleNamespace(), log=said.append)  # no solver: nothing to say
    # with a step budget (solver.step_iter) a carried step's work comes after the command too
    three = SimpleNamespace(params=SimpleNamespace(solver=SimpleNamespace(budget_ms=200.0,
                                                                          step_iter=15)))
    assert check_budget(cfg, three, log=said.append) and len(said) == 1
    three.params.solver.budget_ms = 400.0
    assert not check_budget(cfg, three, log=said.append)
    assert len(said) == 2 and "1200 ms" in said[1] and "carried" in said[1]


def test_a_budget_that_leaves_the_solves_no_time_is_refused(tmp_path, capsys):
    """New-user check: ``solver.budget_ms = 0.5`` was accepted silently; in the field a step
    keeps ``STEP_RESERVE_S`` (30 ms) of its budget for the fallback, so every solve would be
    abandoned at once. Refused with the configuration (also by ``--prepare``), in one line."""
    from mpcasv.config import ConfigError
    from mpcasv.io.config import deploy_config_from_dict

    data = _mpc_cfg(tmp_path)
    for ms in (0.5, 30.0, 30.5):
        data["controller"]["overrides"] = {"solver.budget_ms": ms}
        with pytest.raises(ConfigError, match=f"budget_ms = {ms:g} ms can never work in the"):
            deploy_config_from_dict(data)
    data["controller"]["overrides"] = {"solver.budget_ms": 31.0}
    deploy_config_from_dict(data)  # leaves the solves 1 ms: accepted
    data["controller"]["overrides"] = {"solver.budget_ms": 0.5}
    path = tmp_path / "deploy.toml"
    path.write_text(tomli_w.dumps(data))
    assert main(["deploy", str(path), "--prepare"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "give at least 31 ms" in err[0], err
    assert not (tmp_path / "log").exists()
