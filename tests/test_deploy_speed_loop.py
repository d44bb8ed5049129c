"""``controller.speed_feedback`` in closed loop with DUNE's Otter speed loop: the cap must not
lock the boat at the speed it first made.

DUNE's stock Otter (``otter.ini``, ``[Control.ASV.Differential.HeadingAndSpeed]``) reaches a
speed only while it is behind its set-point: a 250-RPM floor (about 0.7 m/s), a proportional
gain of 1.25 RPM per m/s and an integrator of 1 RPM/s per m/s of error. The deploy used to
cap its commands at the achievable speed it learned, so DUNE's error went to zero and the
boat stayed at its floor for a whole mission (a field engineer's finding against the recorded
traffic, session 47: 0.71 m/s for 10 min; without the cap 0.89 -> 1.35 -> 1.77 m/s at 1, 4
and 10 min). Now a hybrid's command at the cap asks DUNE for its own speed, and the cap
follows the achievable speed up (an MPC's command is sent capped: docs/deploy.md).
"""

from __future__ import annotations

import dataclasses

from test_io_link_replay_options import _cap_config

from mpcasv.interface import ASVState, AUVEstimate, Observation
from mpcasv.io.config import deploy_config_from_dict
from mpcasv.io.deploy import Deploy
from mpcasv.io.imc import NavState
from mpcasv.io.logs import read_jsonl
from mpcasv.io.replay import replay


class DuneOtterSurge:
    """DUNE's Otter speed loop and VSIM's surge, straight ahead, from
    ``../shared/data/dune-otter-ident/README.md`` ("Speed and heading controller": MPS PID
    1.25, 1.0, 0.5, integral limit 400, feed-forward 120 RPM per m/s, +-300 RPM/s, RPM in
    [250, 1200], 0 below 0.1 m/s; "The model as implemented": thrust per thruster
    ``(0.9 n - 10.7 |u|) |n|`` clipped at 12 N, ``n = a 2500 / 60``, ``30 du/dt = X - 6 u -
    0.0165 u |u|``), stepped at DUNE's 10 Hz."""

    def __init__(self) -> None:
        self.u = self.I = self.rpm = 0.0
        self.e_prev: float | None = None

    def step(self, v_d: float, dt: float = 0.1) -> float:
        e = v_d - self.u
        self.I = max(-400.0, min(400.0, self.I + 1.0 * e * dt))
        d = 0.0 if self.e_prev is None else (e - self.e_prev) / dt
        self.e_prev = e
        rpm = 1.25 * e + 0.5 * d + self.I + 120.0 * v_d
        rpm = max(self.rpm - 300.0 * dt, min(self.rpm + 300.0 * dt, rpm))
        self.rpm = 0.0 if v_d < 0.1 else max(250.0, min(1200.0, rpm))
        n = self.rpm / 1200.0 * 2500.0 / 60.0
        X = 2.0 * max(-12.0, min(12.0, (0.9 * n - 10.7 * abs(self.u)) * abs(n)))
        for _ in range(int(round(dt / 0.04))):
            self.u += 0.04 * (X - 6.0 * self.u - 0.0165 * self.u * abs(self.u)) / 30.0
        return self.u


def _mission(tmp_path, feedback: bool, seconds: int = 600):
    """A hybrid-single deploy (command_max 2 m/s) transiting towards an AUV far ahead while
    its References drive :class:`DuneOtterSurge`: one decision a second, states at 10 Hz.
    Returns the deploy (closed) and the boat's speed each second."""
    cfg = _cap_config(tmp_path)
    cfg["controller"] = cfg["controller"] | {"speed_feedback": feedback}
    dep = Deploy(deploy_config_from_dict(cfg))
    dep.event("started", config=dataclasses.asdict(dep.cfg), guard=dataclasses.asdict(dep.gp))
    dep.link.asv.id = 0x2801
    boat, N, speeds = DuneOtterSurge(), 0.0, []
    for s in range(seconds):
        t = float(s)
        auv = AUVEstimate(N + 5000.0, 0.0, 0.0, 0.0, 0.0, (1.0, 0.0, 0.0, 1.0), t)
        obs = Observation(t, ASVState(N, 0.0, 0.0, boat.u), True, (auv,))
        cmd = dep._act(t, t, obs, ["ok"], [0.0], dep.controller.step(obs), 0.0)
        for k in range(1, 11):
            u = boat.step(cmd.speed)
            N += 0.1 * u
            tk = t + 0.1 * k
            dep._on_state(dep.link.asv, NavState(tk, N, 0, 0, 0, u, 0, 0, u, 0, 0, 0), tk)
        speeds.append(boat.u)
    dep.close()
    return dep, speeds


def test_the_speed_cap_does_not_lock_duneS_otter_at_its_floor(tmp_path):
    """With speed_feedback the boat speeds up as without it (it stayed at 0.7 m/s), the
    controller's cap follows it up, every command at the cap asked DUNE for the controller's
    own top speed (at most command_max), and replay reproduces every decision."""
    _, free = _mission(tmp_path / "free", feedback=False)
    dep, fed = _mission(tmp_path / "fed", feedback=True)
    assert free[60] < 1.0 and free[-1] > 1.6  # DUNE's loop climbs over minutes
    assert fed[-1] > 1.6 and abs(fed[-1] - free[-1]) < 0.05
    caps = [e["new"] for e in read_jsonl(dep.jsonl.path, "event")
            if e["event"] == "controller_speed_cap"]  # fmt: skip
    assert caps[0] < 0.8 and caps[-1] > 1.5 and caps == sorted(caps)  # followed it up
    steps = read_jsonl(dep.jsonl.path, "step")
    capped = [s for s in steps if s["speed_cap"] is not None]
    assert capped and all(s["speed_ask"] == 2.5 and s["cmd"]["speed"] == 2.0 for s in capped)
    assert all(s["controller_cmd"]["speed"] <= s["speed_cap"] + 1e-9 for s in capped)
    rep = replay(dep.jsonl.path)
    assert rep.n_differ == 0 and rep.n_steps == len(steps)
