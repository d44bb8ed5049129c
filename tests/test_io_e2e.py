"""End-to-end: ``mpcasv sitl`` and ``mpcasv deploy`` as separate processes over UDP (and TCP)
on 127.0.0.1 with ports chosen by the OS, compared with the in-process simulation.

Rehearsals run at SPEEDUP x the wall clock with ``--hold`` (the world starts with the
deploy's first decision, as ``mpcasv simulate`` does); the comparison covers the metrics of
:data:`mpcasv.io.rehearsal.COMPARABLE` over the same scenario, seed and duration.
"""

from __future__ import annotations

import json
import math
import signal
import time
from pathlib import Path

import imcpy
import numpy as np
import pandas as pd
import psutil
import pytest

from mpcasv.config import load_toml
from mpcasv.controllers import make_controller
from mpcasv.experiments.metrics import compute_metrics
from mpcasv.io.logs import read_jsonl
from mpcasv.io.lsf import read_messages
from mpcasv.io.rehearsal import (
    compare_metrics,
    deploy_config_for,
    free_udp_port,
    rehearsal_metrics,
    rehearsal_scenario,
    start_deploy,
    start_sitl,
    wait_ready,
)
from mpcasv.io.replay import replay
from mpcasv.sim.scenario import load_scenario, scenario_with
from mpcasv.sim.simulator import simulate
from mpcasv.sim.uncertainty import run_scenario

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "experiments" / "scenarios"
CONFIGS = ROOT / "experiments" / "deploy"
SPEEDUP = 20.0
SEED = 3


def _wait(pred, timeout: float, what: str, procs=()):
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        value = pred()
        if value:
            return value
        for p in procs:
            assert p.poll() is None, f"process exited early while waiting for {what}"
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def _records(path: Path, kind: str | None = None) -> list[dict]:
    return read_jsonl(path, kind) if path.exists() else []


def _events(path: Path, name: str) -> list[dict]:
    return [r for r in _records(path, "event") if r.get("event") == name]


def _stop(proc, sig=signal.SIGTERM, timeout: float = 20.0) -> int:
    if proc.poll() is None:
        proc.send_signal(sig)
    try:
        return proc.wait(timeout)
    except Exception:
        proc.kill()
        raise


def _rehearse(tmp: Path, case: str, duration: float, base: dict, *sitl_args: str):
    """Run a rehearsal to its end; return (scenario, deploy dir, sitl dir, deploy pid info)."""
    port = free_udp_port()  # both processes start at once: the deploy needs the SITL's port
    sitl, _ = start_sitl(SCENARIOS / f"{case}.toml", tmp / "sitl", "--speedup", str(SPEEDUP),
                         "--duration", str(duration), "--hold", "--seed", str(SEED), "--quiet",
                         *sitl_args, discovery_port=port, wait=False)  # fmt: skip
    cfg = deploy_config_for({"discovery": f"127.0.0.1:{port}"}, base, tmp / "deploy", SPEEDUP)
    deploy = start_deploy(cfg, tmp, "--quiet")
    try:
        wait_ready(sitl, tmp / "sitl")
        log = tmp / "deploy" / "deploy.jsonl"
        _wait(lambda: _events(log, "bound"), 30, "deploy to bind", [deploy])
        sockets = [c for c in psutil.Process(deploy.pid).net_connections("inet")]
        assert sitl.wait(duration / SPEEDUP + 60) == 0
    finally:
        code = _stop(deploy)
        _stop(sitl)
    assert code == 0, (tmp / "deploy.stderr").read_text()
    return load_scenario(SCENARIOS / f"{case}.toml"), tmp / "deploy", tmp / "sitl", sockets


def _compare(scenario, deploy_dir: Path, sitl_dir: Path,
             nominal: bool = False) -> tuple[dict, dict]:  # fmt: skip
    """(simulation's metrics, rehearsal's) of the world both run: ``scenario`` realised for
    SEED, as ``mpcasv simulate --seed`` and ``mpcasv sitl --seed`` realise it (``nominal``:
    its nominal values, ``--nominal``)."""
    run = json.loads((sitl_dir / "run" / "run.json").read_text())
    world, real = run_scenario(scenario, SEED, nominal)
    assert run["realisation"]["values"] == real.as_dict()["values"]
    assert bool(real.values) != nominal
    m_dep, joined = rehearsal_metrics(world, sitl_dir, deploy_dir)
    info = run["sitl"]
    print("SITL:", {k: info[k] for k in ("counts", "overruns", "sitl_wall_s")})
    # the SITL's boat steered at the deploy's pushed References: simulate it so (session 42)
    sc = rehearsal_scenario(world, deploy_dir, m_dep["duration_s"])
    assert sc.sim.reference_lead_m == 20.0
    res = simulate(sc, make_controller(sc.controller, len(sc.auv), sc.preset), SEED)
    m_sim = compute_metrics(res)
    return m_sim, m_dep


def _check_logs(deploy_dir: Path, n_auv: int) -> list[dict]:
    steps = read_jsonl(deploy_dir / "deploy.jsonl", "step")
    refs = read_messages(deploy_dir / "imc.lsf", imcpy.Reference)
    ours = refs[refs["src"] == 0x4001]
    # one Reference per decision, then the final standby and MANDONE
    assert len(ours) == len(steps) + 2
    assert int(ours["flags"].iloc[-1]) & int(imcpy.Reference.FlagsBits.MANDONE)
    assert ours["speed.value"].iloc[-2] == 0.0
    es = read_messages(deploy_dir / "imc.lsf", imcpy.EstimatedState)
    assert es["src"].nunique() == n_auv + 1
    records = read_jsonl(deploy_dir / "deploy.jsonl")
    summary = records[-1]
    assert summary["kind"] == "summary"  # the last record
    assert summary["rejects"] == {}, summary["rejects"]
    # the SITL echoes our Heartbeats and PlanControls as DUNE does; it has ended when the
    # deploy is stopped: MANDONE gets no answer and the wait ends on its timeout
    assert summary["relayed"].get("echo", 0) > 0
    assert not summary["plan_completed"]
    names = [r.get("event") for r in records]
    assert names.index("final_standby") < names.index("plan_done_timeout")
    return steps


def _check_usbl_fixes(steps: list[dict], sitl_dir: Path) -> None:
    """Each decision's observation has the time of the last USBL fix the SITL's world made
    up to it (the ASV's UsblFixExtended, stamped at the fix's own time; session 41): before
    the first fix none (the world's known start is no fix of the ASV's USBL)."""
    run = sitl_dir / "run"
    offset = json.loads((run / "run.json").read_text())["sitl"]["ts_offset"]
    ts = pd.read_parquet(run / "timeseries.parquet")
    last_fix = {round(t, 6): t - age for t, age in zip(ts["t"], ts["fix_age0"], strict=True)}
    seen = [(round(s["t"] - offset, 6), s["obs"]["usbl_fix_times"][0]) for s in steps]
    seen = [(t, f) for t, f in seen if t in last_fix]
    assert len(seen) >= len(steps) - 1 and any(f is not None for _, f in seen)
    for t, f in seen:
        assert last_fix[t] == 0.0 if f is None else f - offset == pytest.approx(last_fix[t]), t


def _check_actuators(steps: list[dict], sitl_dir: Path, scenario) -> None:
    """While the ASV's loops run, each decision's observation has the plant's thrust and
    steering at its time, read from the SITL's SetThrusterActuation and SetServoPosition
    (float32 on the wire; session 41: before, the deploy passed none and an MPC's plan and
    current observer started from another state than in ``mpcasv simulate``)."""
    from mpcasv.models.params import load_vessel

    T_max = load_vessel(scenario.asv.vessel).T_max
    run = sitl_dir / "run"
    offset = json.loads((run / "run.json").read_text())["sitl"]["ts_offset"]
    ts = pd.read_parquet(run / "timeseries.parquet")
    plant = {round(t, 6): (T, d) for t, T, d in zip(ts["t"], ts["thrust"], ts["delta"],
                                                     strict=True)}  # fmt: skip
    running = [(plant[round(s["t"] - offset, 6)], s["obs"]["actuators"]) for s in steps
               if round(s["t"] - offset, 6) in plant and s["obs"]["actuators"] is not None
               and s["obs"]["actuators"][0] != 0.0]  # fmt: skip
    assert len(running) > 50, len(running)
    for (T, d), (T_obs, d_obs) in running:
        assert abs(T_obs - T) <= 1e-6 * T_max and abs(d_obs - d) <= 1e-6, (T, d, T_obs, d_obs)


def _check_bind(sockets) -> None:
    assert sockets, "deploy has no socket"
    for c in sockets:
        assert c.laddr.ip == "127.0.0.1", c


def test_case3_rehearsal_matches_simulation(tmp_path):
    base = load_toml(CONFIGS / "sitl-case3.toml")
    base["watchdog"] |= {"asv_stale_s": 5.0, "auv_stale_s": 5.0}  # tolerate a loaded CI host
    sc, deploy_dir, sitl_dir, sockets = _rehearse(tmp_path, "case3", 300.0, base)
    _check_bind(sockets)
    steps = _check_logs(deploy_dir, 1)
    _check_usbl_fixes(steps, sitl_dir)
    _check_actuators(steps, sitl_dir, sc)
    m_sim, m_dep = _compare(sc, deploy_dir, sitl_dir)
    table = compare_metrics(m_sim, m_dep)
    print(json.dumps(table, indent=1))
    assert m_dep["duration_s"] == 300.0
    assert m_dep["decisions_joined"] == 300 and m_dep["mode_disagreements"] == 0
    assert m_dep["min_range_m"] >= 10.0
    assert all(v["ok"] for v in table.values()), table
    assert len(steps) == 300
    # replaying the log with the logged controller reproduces every decision
    rep = replay(deploy_dir)
    assert rep.n_steps == len(steps) and rep.n_differ == 0
    # and a different tuning would have decided differently somewhere
    other = replay(deploy_dir, preset="paper1-sim")
    assert other.n_differ > 0


def test_case3_rehearsal_under_water(tmp_path):
    """The AUV under water (``mpcasv sitl --auv-states acoustic``: after the start only its
    status reports that got through, every 30 s at best): the deploy's Kalman filter takes the
    ASV's USBL fixes' positions (session 42), keeps the AUV seen and believes it where
    ``mpcasv simulate``'s Kalman filter believes it (measured: 0.9 m RMS apart, seed 1 at 5x,
    scratch /work/s42/reh3.py), about as far from the truth. Before, only the fix times were
    read: the beliefs were 20 m RMS off and 9 of the 10 comparable metrics out of tolerance
    (reh3.py with the positions switched off). Not a metric-by-metric check: the deploy's
    filter starts from the AUV's first radio state, velocity included, where the simulator's
    knows the start position only (seed 3: ``beyond_outer_s`` 6.2 s against 8.5 s, the other
    9 within tolerance). ``auv_stale_s`` is long because ``simulate`` has no watchdog (this
    seed's world goes 25 s without a fix at t = 145 s: the guard's overrides at 20 s part
    the runs); the watchdogs' use of the fixes: tests/test_deploy_usbl_positions.py."""
    base = load_toml(CONFIGS / "sitl-case3.toml")
    base["watchdog"] |= {"asv_stale_s": 20.0, "auv_stale_s": 100.0, "auv_lost_s": 200.0}
    base["controller"] |= {"estimator": "kalman"}
    sc, deploy_dir, sitl_dir, _ = _rehearse(tmp_path, "case3", 300.0, base, "--lockstep",
                                            "--auv-states", "acoustic")  # fmt: skip
    sc = scenario_with(sc, estimator="kalman")
    steps = _check_logs(deploy_dir, 1)
    records = read_jsonl(deploy_dir / "deploy.jsonl")
    summary = records[-1]
    assert summary["usbl_fix_positions"][0] >= 30 and summary["estimator_dropped"] == [0]
    assert summary["usbl_fix_outliers"] == [0]  # the simulated USBL has none: none refused
    assert not [r for r in records if r.get("event") in ("auv_uncertain", "auv_lost")]
    es = read_messages(deploy_dir / "imc.lsf", imcpy.EstimatedState)
    assert (es["src"] == 0x2811).sum() <= 300 / 30 + 3  # no 2-Hz radio states: the reports
    run = json.loads((sitl_dir / "run" / "run.json").read_text())
    assert run["sitl"]["auv_states"] == "acoustic"  # the run folder says how it ran
    world, _ = run_scenario(sc, SEED, False)
    res = simulate(rehearsal_scenario(world, deploy_dir, 300.0),
                   make_controller(sc.controller, 1, sc.preset), SEED)  # fmt: skip
    offset = json.loads((sitl_dir / "run" / "run.json").read_text())["sitl"]["ts_offset"]
    sim = res.timeseries.set_index(res.timeseries["t"].round(6))
    truth = pd.read_parquet(sitl_dir / "run" / "timeseries.parquet")
    truth = truth.set_index(truth["t"].round(6))
    to_sim, err, err_sim = [], [], []
    for s in steps:
        t, e = round(s["obs"]["t"] - offset, 6), s["obs"]["auvs"][0]
        if t in sim.index and t in truth.index:
            to_sim.append(math.hypot(e["N"] - sim.at[t, "est0_N"], e["E"] - sim.at[t, "est0_E"]))
            err.append(math.hypot(e["N"] - truth.at[t, "auv0_N"], e["E"] - truth.at[t, "auv0_E"]))
            err_sim.append(math.hypot(sim.at[t, "est0_N"] - sim.at[t, "auv0_N"],
                                      sim.at[t, "est0_E"] - sim.at[t, "auv0_E"]))  # fmt: skip
    rms = [math.sqrt(np.mean(np.square(x))) for x in (to_sim, err, err_sim)]
    print(f"belief RMS (m): to simulate's {rms[0]:.2f}, deploy's error {rms[1]:.2f}, "
          f"simulate's {rms[2]:.2f}")
    assert len(to_sim) >= 290 and rms[0] < 3.0 and rms[1] < rms[2] + 1.0, rms
    m_sim, m_dep = _compare(sc, deploy_dir, sitl_dir)
    print(json.dumps(compare_metrics(m_sim, m_dep), indent=1))
    assert m_dep["decisions_joined"] == 300
    assert replay(deploy_dir).n_differ == 0


def test_case6_rehearsal_matches_simulation(tmp_path):
    base = load_toml(CONFIGS / "sitl-case6.toml")
    # 20 s of the deploy clock = 1 s of wall time at SPEEDUP 20: with --lockstep (below) the
    # SITL stops publishing while it waits for the deploy's Reference, so a deploy starved of
    # CPU for longer than asv_stale_s (5 s = 0.25 s of wall time was the limit) called the
    # ASV stale, restarted FollowReference and never stepped again (deadlock on a host with
    # load 7 on 2 cores; newuser6)
    base["watchdog"] |= {"asv_stale_s": 20.0, "auv_stale_s": 20.0}
    # the deploy's frame 400 m north-east of the SITL's and DUNE-like reference points moved
    # every 100 m: positions must go through absolute lat/lon to agree
    base["origin"] = {"lat_deg": 63.4406 + 400 / 111_000, "lon_deg": 10.3530 + 400 / 49_800}
    # --lockstep: the world waits for each answering Reference; on a loaded host the default
    # window (0.9 period = 45 ms of wall time at SPEEDUP 20) let about a third of them act a
    # period late and the world drift from `mpcasv simulate`'s (newuser6)
    # the seed's realisation (a current of up to 0.3 m/s): at t = 250 s the ASV, inside
    # auv1's collision domain, escapes with Gretha's power turn; until session 25 only
    # `simulate` marked the escape (the SITL's maneuver did not) and the runs parted there
    sc, deploy_dir, sitl_dir, sockets = _rehearse(tmp_path, "case6", 300.0, base,
                                                  "--reanchor", "100", "--lockstep")  # fmt: skip
    _check_bind(sockets)
    _check_logs(deploy_dir, 3)
    m_sim, m_dep = _compare(sc, deploy_dir, sitl_dir)
    table = compare_metrics(m_sim, m_dep)
    print(json.dumps(table, indent=1))
    info = json.loads((sitl_dir / "run" / "run.json").read_text())["sitl"]
    assert info["lockstep"] and "late_references" not in info["counts"], info
    assert m_dep["decisions_joined"] == 300 and m_dep["mode_disagreements"] == 0
    assert m_dep["min_range_m"] >= 10.0
    assert all(v["ok"] for v in table.values()), table
    assert m_dep["mode_switches"] > 4  # the ASV did visit the AUVs in turn
    assert replay(deploy_dir).n_differ == 0


# Speed-up of the outage test. Its limits are in deploy-clock seconds (the verdict within 0.5 s
# of asv_stale_s: the watchdog's 0.25-s pass and as much again), which a speed-up divides into
# wall time: at 20x they were 25 ms, and a deploy scheduled 9 ms late on a loaded host
# (two busy loops beside it on 2 cores) logged an age of 3.509 s (session 26: 2 of 8 runs
# failed, this and the kill timed from the signal below). At 5x they are 100 ms.
OUTAGE_SPEEDUP = 5.0


def _case3_rehearsal(tmp_path, base: dict, speedup: float):
    """A Case 3 SITL (2000 s at ``speedup``) and a deploy of ``base`` against it: (sitl,
    deploy, deploy log, SITL log)."""
    sitl, ready = start_sitl(SCENARIOS / "case3.toml", tmp_path / "sitl", "--speedup",
                             str(speedup), "--duration", "2000", "--quiet")  # fmt: skip
    deploy = start_deploy(deploy_config_for(ready, base, tmp_path / "deploy", speedup), tmp_path)
    return sitl, deploy, tmp_path / "deploy" / "deploy.jsonl", tmp_path / "sitl" / "sitl.jsonl"


def test_asv_killed_and_restarted(tmp_path):
    """SIGUSR1 kills the SITL ASV's IMC system: deploy reports it within its limit, stops
    commanding; SIGUSR2 brings it back: FollowReference is restarted and control resumes;
    SIGTERM: final standby + MANDONE reach the ASV."""
    base = load_toml(CONFIGS / "sitl-case3.toml")
    limit = base["watchdog"]["asv_stale_s"]
    speedup = OUTAGE_SPEEDUP
    sitl, deploy, log, sitl_log = _case3_rehearsal(tmp_path, base, speedup)
    procs = [sitl, deploy]
    try:
        _wait(lambda: len(_records(log, "step")) >= 20, 60, "20 decisions", procs)
        sitl.send_signal(signal.SIGUSR1)
        # timed from the kill itself, not from sending the signal: a SITL starved of CPU
        # handled it up to 1 s of the clock later (50 ms of wall time at 20x)
        killed = _wait(lambda: _events(sitl_log, "asv_killed"), 30, "asv_killed", procs)[0]
        stale = _wait(lambda: _events(log, "asv_stale"), 30, "asv_stale", procs)[0]
        delay = (stale["wall"] - killed["wall"]) * speedup  # deploy clock seconds
        print(f"ASV outage noticed after {delay:.2f} s (limit {limit} s), age {stale['age_s']}")
        assert limit <= stale["age_s"] <= limit + 0.5
        assert delay <= limit + 1.0
        n_at_stale = len(_records(log, "step"))
        time.sleep(10 / speedup)  # 10 s of outage: no decision is made or sent
        assert len(_records(log, "step")) <= n_at_stale + 1
        sitl.send_signal(signal.SIGUSR2)
        _wait(lambda: _events(log, "asv_resumed"), 30, "asv_resumed", procs)
        _wait(lambda: len(_events(log, "plan_started")) >= 2, 30, "FollowReference again", procs)
        _wait(lambda: len(_records(log, "step")) >= n_at_stale + 10, 30, "control again", procs)
    finally:
        code = _stop(deploy)
        time.sleep(0.5)
        _stop(sitl)
    assert code == 0
    sitl_events = [r["event"] for r in read_jsonl(sitl_log, "event")]
    assert sitl_events.count("maneuver_started") == 2
    assert "asv_killed" in sitl_events and "asv_restarted" in sitl_events
    assert "maneuver_done" in sitl_events  # the deploy's MANDONE on SIGTERM
    summary = read_jsonl(log)[-1]  # answered "plan completed", as DUNE does; summary last
    assert summary["kind"] == "summary" and summary["plan_completed"]
    assert _events(log, "plan_completed")[0]["info"] == "plan completed"
    steps = read_jsonl(log, "step")
    stale_t = _events(log, "asv_stale")[0]["t"]
    resumed = _events(log, "asv_resumed")[0]
    assert not any(stale_t < s["clock"] < resumed["t"] for s in steps)
    # back on the restarted ASV's states only, not on late ones of the killed ASV (CI,
    # session 20: asv_resumed 0.55 s after asv_stale, decisions, asv_stale again)
    restarted = _events(sitl_log, "asv_restarted")[0]
    assert resumed["wall"] > restarted["wall"] and summary["asv_stale_events"] == 1
    ts = json.loads((tmp_path / "sitl" / "run" / "metrics.json").read_text())
    assert ts["min_range_m"] >= 10.0


def test_asv_killed_while_the_sitl_is_starved(tmp_path):
    """The CI failure of session 20 on demand: the SITL gets no CPU (SIGSTOP) when SIGUSR1
    comes; the deploy rightly calls the ASV stale; on SIGCONT the SITL sends the states of
    the ticks it missed before it handles the kill. Those states, stamped before the verdict
    and read after it, brought the ASV "back" (asv_resumed, FollowReference START to a dead
    ASV, asv_stale again: 5 of 6 runs before session 26). Only the restart may."""
    base = load_toml(CONFIGS / "sitl-case3.toml")
    sitl, deploy, log, sitl_log = _case3_rehearsal(tmp_path, base, SPEEDUP)
    procs = [sitl, deploy]
    try:
        _wait(lambda: len(_records(log, "step")) >= 20, 60, "20 decisions", procs)
        sitl.send_signal(signal.SIGSTOP)
        try:
            sitl.send_signal(signal.SIGUSR1)  # pending until SIGCONT
            _wait(lambda: _events(log, "asv_stale"), 30, "asv_stale", [deploy])
        finally:
            sitl.send_signal(signal.SIGCONT)
        _wait(lambda: _events(sitl_log, "asv_killed"), 30, "asv_killed", procs)
        # the killed ASV's late states went into the deploy's socket before anything the
        # restarted one sends: the first asv_resumed must come after the restart
        sitl.send_signal(signal.SIGUSR2)
        _wait(lambda: _events(log, "asv_resumed"), 30, "asv_resumed", procs)
        _wait(lambda: len(_events(log, "plan_started")) >= 2, 30, "FollowReference again", procs)
    finally:
        code = _stop(deploy)
        time.sleep(0.5)
        _stop(sitl)
    assert code == 0
    late = _events(log, "asv_late_state")
    print(f"late states read after the verdict: {read_jsonl(log)[-1].get('asv_late_states')}", late)
    restarted = _events(sitl_log, "asv_restarted")[0]
    resumed = _events(log, "asv_resumed")[0]
    assert resumed["wall"] > restarted["wall"], "the killed ASV's late states brought it back"
    assert sum(e["wall"] < resumed["wall"] for e in _events(log, "asv_stale")) == 1
    assert not any(e["wall"] < restarted["wall"] for e in _events(log, "plan_start_sent")[1:])


@pytest.mark.parametrize("transport", ["tcp"])
def test_tcp_backseat(tmp_path, transport):
    """The same loop over DUNE's TCP backseat port (imcpy.Parser on the stream)."""
    args = ("--speedup", str(SPEEDUP), "--duration", "60", "--hold", "--tcp", "--quiet")
    sitl, ready = start_sitl(SCENARIOS / "case3.toml", tmp_path / "sitl", *args)
    base = load_toml(CONFIGS / "sitl-case3.toml")
    veh = {v["name"]: v for v in ready["vehicles"]}
    base["vehicle"] = [{"role": v["role"], "id": v["id"], "tcp": v["tcp"]} for v in veh.values()]
    base["link"]["transport"] = transport  # its UDP-only fields are then left out
    cfg = deploy_config_for(ready, base, tmp_path / "deploy", SPEEDUP)
    deploy = start_deploy(cfg, tmp_path, "--quiet")
    try:
        assert sitl.wait(60 / SPEEDUP + 60) == 0
    finally:
        code = _stop(deploy)
        _stop(sitl)
    assert code == 0, (tmp_path / "deploy.stderr").read_text()
    # a normal end with the deploy connected: no asyncio traceback (session 45: two)
    assert "Traceback" not in (tmp_path / "sitl" / "sitl.stderr").read_text()
    steps = read_jsonl(tmp_path / "deploy" / "deploy.jsonl", "step")
    info = json.loads((tmp_path / "sitl" / "run" / "run.json").read_text())["sitl"]
    assert info["periods"] == 60 and len(steps) == 60
    assert info["counts"].get("references", 0) == 60
    assert math.isfinite(steps[-1]["obs"]["auvs"][0]["N"])
