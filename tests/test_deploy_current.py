"""A field engineer watching a deploy does not see the MPC's stderr: the first decision whose
MPC planned with a current above ``CURRENT_TESTED`` (its diagnostic ``mpc_cur_untested``) is
the event ``current_untested`` in deploy.jsonl (and a warning on the console), once per run,
with the current's speed; the deploy reads the diagnostics once per decision."""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np
import pytest
from test_io_asv import _cfg as asv_cfg

from mpcasv.controllers import make_controller
from mpcasv.interface import ASVState, AUVEstimate, Observation
from mpcasv.io.deploy import Deploy
from mpcasv.io.logs import read_jsonl


def test_a_current_above_the_tested_one_is_one_deploy_event(tmp_path, caplog):
    """An MPC stepped inline by the deploy loop (no worker process: the controller is put in
    after the loop is built) on observations carrying the true current (``current =
    "oracle"``, so the current planned with is known exactly): 0.5 m/s, then 1.5 m/s for three
    decisions, then 0.5 m/s and 1.5 m/s again: one event, at the first decision at 1.5 m/s,
    a warning on the console (seen with ``--quiet`` too)."""
    caplog.set_level(logging.INFO, logger="mpcasv.deploy")
    dep = Deploy(asv_cfg(tmp_path), dry_run=True)
    mpc = make_controller("mpc-single", 1, "mpc-single", overrides={"current": "oracle"})
    mpc.reset(1)
    calls = []  # what the deploy asked of the controller, in order
    diagnostics, run_between = mpc.diagnostics, dep.run_between
    mpc.diagnostics = lambda: calls.append("diag") or diagnostics()
    dep.run_between = lambda: calls.append("between") or run_between()
    dep.controller = mpc
    auv = AUVEstimate(120.0, 0.0, 0.0, 0.0, 0.0, (1.0, 0.0, 0.0, 1.0), 0.0)

    def observe(east):
        obs = Observation(0.0, ASVState(0.0, 0.0, 0.0, 0.0), False, (auv,),
                          current_oracle=(0.0, east))  # fmt: skip
        dep.observation = lambda ts, now: (dataclasses.replace(obs, t=ts), ["ok"], [0.0])

    for t, east in enumerate((-0.5, -1.5, -1.5, -1.5, -0.5, -1.5)):
        observe(east)
        calls.clear()
        assert dep.step(float(t), float(t)) is not None
        # once for the step's record and the event, once for the work after the command
        assert calls == ["diag", "between", "diag"]
    dep.jsonl.flush()
    events = [e for e in read_jsonl(tmp_path / "deploy.jsonl", "event")
              if e["event"] == "current_untested"]  # fmt: skip
    assert len(events) == 1, events
    assert events[0]["t"] == 1.0 and events[0]["speed"] == pytest.approx(1.5)
    assert events[0]["tested"] == 1.0
    said = [r for r in caplog.records if r.getMessage().startswith("current_untested")]
    assert [r.levelno for r in said] == [logging.WARNING], said
    steps = read_jsonl(tmp_path / "deploy.jsonl", "step")
    flags = [s["diag"]["mpc_cur_untested"] for s in steps]
    assert flags == [0.0, 1.0, 1.0, 1.0, 0.0, 1.0]
    assert all(math.isclose(np.hypot(s["diag"]["mpc_cur_N"], s["diag"]["mpc_cur_E"]),
                            1.5 if f else 0.5) for s, f in zip(steps, flags, strict=True))
    dep.close()


def test_a_controller_without_the_diagnostic_raises_no_event(tmp_path):
    """The hybrid controller (no ``mpc_cur_untested``) in any current: no event."""
    dep = Deploy(asv_cfg(tmp_path), dry_run=True)
    auv = AUVEstimate(300.0, 0.0, 0.0, 0.0, 0.0, (1.0, 0.0, 0.0, 1.0), 0.0)
    obs = Observation(0.0, ASVState(0.0, 0.0, 0.0, 0.0), False, (auv,),
                      current_oracle=(0.0, -2.0))  # fmt: skip
    dep.observation = lambda ts, now: (obs, ["ok"], [0.0])
    for t in range(3):
        dep.step(float(t), float(t))
    dep.jsonl.flush()
    assert not [e for e in read_jsonl(tmp_path / "deploy.jsonl", "event")
                if e["event"] == "current_untested"]  # fmt: skip
    assert dep.current_untested_t is None
    dep.close()
