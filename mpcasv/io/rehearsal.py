"""Metrics of a rehearsal (``mpcasv deploy`` against ``mpcasv sitl``), comparable with the
in-process simulation of the same scenario and seed.

The SITL writes the truth (``<sitl out>/run/``) but cannot know why the ASV was commanded
what it was; the deploy log has the reasons. :func:`rehearsal_metrics` joins each SITL period
with the decision that acted during it (deploy time = world time + ``ts_offset``) and
computes every metric with :func:`mpcasv.experiments.metrics.compute_metrics`, the one
definition. Periods with no decision (before the first one, during an ASV outage) keep the
SITL's mode and get the reason ``"none"``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pandas as pd

from mpcasv.experiments.metrics import compute_metrics
from mpcasv.io.logs import read_jsonl
from mpcasv.sim.scenario import Scenario, scenario_with
from mpcasv.sim.simulator import RunResult

__all__ = ["COMPARABLE", "compare_metrics", "rehearsal_metrics", "rehearsal_scenario"]

#: Metrics a rehearsal and the in-process simulation of the same scenario, seed and duration
#: should agree on: where the ASV went, how long it stood by / tracked / avoided, how close it
#: came, what it spent, how long an AUV waited for a visit. Left out: wall-clock figures
#: (``controller_step_ms_*``), the belief metrics (the SITL world's estimator is not the
#: deploy loop's), and counts of discrete events that one period's shift can change by one.
COMPARABLE = (
    "min_range_m", "asv_distance_m", "standby_s", "label_tracking_s", "label_avoidance_s",
    "propeller_on_s", "energy_J", "reliable_fix_age_max_s", "collision_domain_s",
    "beyond_outer_s",
)  # fmt: skip
#: Sums of whole control periods: they cannot agree better than one period.
PERIOD_QUANTISED = frozenset(
    {"standby_s", "label_tracking_s", "label_avoidance_s", "propeller_on_s",
     "reliable_fix_age_max_s", "collision_domain_s", "beyond_outer_s"}
)  # fmt: skip


def _fix_times(ts: pd.DataFrame, col: str) -> list[list[float]]:
    out, k = [], 0
    while f"{col}{k}" in ts:
        n = ts[f"{col}{k}"].to_numpy(int)
        out.append([float(t) for t, c in zip(ts["t"], n, strict=True) for _ in range(c)])
        k += 1
    return out


def rehearsal_metrics(scenario: Scenario, sitl_out: str | Path, deploy_log: str | Path
                      ) -> tuple[dict, pd.DataFrame]:  # fmt: skip
    """(metrics, joined time series) of a rehearsal.

    Parameters
    ----------
    scenario : Scenario
        The scenario the SITL ran, as it realised it: ``run_scenario(load_scenario(path),
        seed, nominal)[0]`` (:mod:`mpcasv.sim.uncertainty`) for the SITL's ``--seed``
        (``--nominal``).
    sitl_out : path
        The SITL's ``--out`` folder.
    deploy_log : path
        The deploy's ``deploy.jsonl`` (or its folder).
    """
    run = Path(sitl_out) / "run"
    ts = pd.read_parquet(run / "timeseries.parquet")
    info = json.loads((run / "run.json").read_text())["sitl"]
    exact = json.loads((run / "metrics.json").read_text())
    log = Path(deploy_log)
    steps = read_jsonl(log / "deploy.jsonl" if log.is_dir() else log, "step")
    Tc = scenario.sim.control_period
    dec = pd.DataFrame({
        "t0": [s["t"] - info["ts_offset"] for s in steps],
        "d_mode": [s["cmd"]["mode"] for s in steps],
        "d_reason": [s["cmd"]["reason"] for s in steps],
        "d_auv": [-1 if s["cmd"]["auv"] is None else s["cmd"]["auv"] for s in steps],
    }).sort_values("t0")  # fmt: skip
    ts = ts.sort_values("t").reset_index(drop=True)
    ts["t0"] = ts["t"] - Tc
    j = pd.merge_asof(ts, dec, on="t0", direction="nearest", tolerance=0.25 * Tc)
    has = j["d_reason"].notna()
    j["reason"] = np.where(has, j["d_reason"], "none")
    j["auv_served"] = np.where(has, j["d_auv"], -1).astype(int)
    j["mode_agrees"] = ~has | (j["d_mode"] == j["mode"])
    sc = scenario_with(scenario, duration=len(ts) * Tc)
    res = RunResult(sc, "rehearsal", 0, j, np.zeros(len(j)), _fix_times(j, "fixes"),
                    _fix_times(j, "reliable"), 0, None, [], exact["energy_J"],
                    exact["min_range_m"], exact["min_slant_range_m"])  # fmt: skip
    metrics = compute_metrics(res)
    metrics["decisions_joined"] = int(has.sum())
    metrics["mode_disagreements"] = int((~j["mode_agrees"]).sum())
    return metrics, j


def rehearsal_scenario(world: Scenario, deploy_log: str | Path, duration: float) -> Scenario:
    """The scenario ``mpcasv simulate`` runs for a comparison with a rehearsal: ``world``
    (the scenario as the SITL realised it, :func:`mpcasv.sim.uncertainty.run_scenario`) for
    ``duration`` s, its execution level steering at a transit waypoint pushed as far on as
    the deploy pushed DUNE's References (``[sim] reference_lead_m`` = the logged
    ``link.reference_lead_m``; :func:`mpcasv.interface.pushed_waypoint`), as the SITL's boat
    steered. Without it an MPC's rehearsal parted from its simulation within a minute
    (docs/deploy.md, "The ASV's actuators"). Its observations carry the actuators at the
    periods' ends only (``[sim] actuator_samples = false``), as a deploy's do: an MPC's
    current observer then reads the same kind of measurement on both sides.

    Raises
    ------
    ValueError
        The log has no ``started`` event (not a deploy log, or cut before it); or its lead
        is one ``simulate`` cannot follow: shorter than DUNE's arrival tolerance,
        ``HORIZONTAL_TOLERANCE + |link.reference_radius_m|`` (DUNE, and the SITL, then stop
        a boat whose waypoint is near, which ``simulate`` does not model), or longer than
        ``[sim] reference_lead_m`` allows.
    """
    from mpcasv.io.dune import HORIZONTAL_TOLERANCE
    from mpcasv.sim.scenario import REFERENCE_LEAD_MAX

    log = Path(deploy_log)
    started = [e for e in read_jsonl(log / "deploy.jsonl" if log.is_dir() else log, "event")
               if e.get("event") == "started"]  # fmt: skip
    if not started:
        raise ValueError(f"{log}: no 'started' event: not a deploy log")
    link = started[0]["config"]["link"]
    lead, radius = float(link["reference_lead_m"]), abs(float(link["reference_radius_m"]))
    if not HORIZONTAL_TOLERANCE + radius <= lead <= REFERENCE_LEAD_MAX:
        raise ValueError(f"{log}: link.reference_lead_m {lead:g} m: simulate follows a lead of "
                         f"{HORIZONTAL_TOLERANCE + radius:g} m (DUNE's arrival tolerance, "
                         f"{HORIZONTAL_TOLERANCE:g} m + |reference_radius_m|: a nearer "
                         f"Reference stops the boat) to {REFERENCE_LEAD_MAX:g} m")
    return scenario_with(world, duration=duration,
                         sim=dataclasses.replace(world.sim, reference_lead_m=lead,
                                                 actuator_samples=False))


def compare_metrics(a: dict, b: dict, rel: float = 0.10, period: float = 1.0,
                    names=COMPARABLE) -> dict[str, dict]:  # fmt: skip
    """Per metric of ``names``: ``{"a": a's value, "b": b's, "rel_diff": the relative
    difference, "ok": within rel of the larger (or, for PERIOD_QUANTISED metrics, within one
    period)}``; ``a`` and ``b`` are metric dicts (:func:`compute_metrics`,
    :func:`rehearsal_metrics`)."""
    out = {}
    for name in names:
        x, y = float(a[name]), float(b[name])
        diff, scale = abs(x - y), max(abs(x), abs(y))
        floor = period if name in PERIOD_QUANTISED else 0.0
        out[name] = {
            "a": x, "b": y, "rel_diff": diff / scale if scale > 0 else 0.0,
            "ok": diff <= rel * scale or diff <= floor + 1e-9,
        }  # fmt: skip
    return out


# --- running a rehearsal as two processes (tests, scripts) ---------------------------------


def free_udp_port(host: str = "127.0.0.1") -> int:
    """A UDP port the OS says is free now (bind to port 0, read it, close)."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def start_sitl(scenario: str | Path, out: str | Path, *args: str, discovery_port: int = 0,
               wait: bool = True, timeout: float = 60.0):  # fmt: skip
    """Start ``mpcasv sitl`` on loopback (vehicles on free ports); return (Popen, ready dict
    or None if not ``wait``).

    ``args`` are further ``mpcasv sitl`` options (``--speedup``, ``--duration``, ...).
    Raises RuntimeError if the SITL does not report its ports within ``timeout`` s.
    """
    import subprocess
    import sys

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ready_file = out / "ready.json"
    ready_file.unlink(missing_ok=True)
    cmd = [sys.executable, "-m", "mpcasv", "sitl", str(scenario), "--discovery-port",
           str(discovery_port), "--base-port", "0", "--out", str(out), "--ready-file",
           str(ready_file), *args]  # fmt: skip
    with (out / "sitl.stderr").open("w") as err:  # the child has its own copy
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err)
    return proc, (wait_ready(proc, out, timeout) if wait else None)


def wait_ready(proc, out: str | Path, timeout: float = 60.0) -> dict:
    """The ready dict a SITL started by :func:`start_sitl` writes once its ports are bound."""
    import time

    out = Path(out)
    ready_file = out / "ready.json"
    t_end = time.monotonic() + timeout
    while not ready_file.exists():
        if proc.poll() is not None or time.monotonic() > t_end:
            proc.kill()
            proc.wait()  # reaped: no zombie, no "still running" ResourceWarning
            raise RuntimeError(f"mpcasv sitl did not start: {(out / 'sitl.stderr').read_text()}")
        time.sleep(0.05)
    return json.loads(ready_file.read_text())


def deploy_config_for(ready: dict, base: dict, log_dir: str | Path, speedup: float) -> dict:
    """A deploy configuration (as a dict) for the SITL described by ``ready``: ``base`` with
    the clock (``speedup``) and the log folder (``log_dir``) set, and its link set for the
    SITL on 127.0.0.1. UDP: the SITL's discovery address as ``announce_to``, a free data
    port, and no discovery ports of our own when a vehicle has no ``address`` (the SITL
    answers our Announce at our data port; parallel tests cannot share DUNE's). TCP
    (``link.transport = "tcp"`` in ``base``): ``bind`` set, and ``base``'s fields the TCP
    link never reads removed (refused at load, :func:`mpcasv.io.config.check_link`): the
    UDP-only ``[link]`` fields (:data:`mpcasv.io.config.UDP_ONLY`) and every vehicle's
    ``address``. Without an ``[acoustics]`` in ``base``, the SITL's world's channel (its
    ready info's ``acoustics``): an MPC then plans its fixes as ``mpcasv simulate`` of the
    same scenario and seed does."""
    from mpcasv.io.config import UDP_ONLY

    cfg = json.loads(json.dumps(base))
    link = cfg.setdefault("link", {})
    if link.get("transport") == "tcp":
        cfg["link"] = {k: v for k, v in link.items() if k not in UDP_ONLY} | {"bind": "127.0.0.1"}
        cfg["vehicle"] = [{k: v for k, v in veh.items() if k != "address"}
                          for veh in cfg.get("vehicle", [])]  # fmt: skip
    else:
        link |= {"bind": "127.0.0.1", "port": 0, "announce_to": [ready["discovery"]]}
        if any("address" not in veh for veh in cfg.get("vehicle", [])):
            link["discovery_ports"] = []  # (unread, and refused, when all have one)
    cfg.setdefault("clock", {})["speedup"] = float(speedup)
    cfg.setdefault("log", {})["dir"] = str(log_dir)
    if "acoustics" in ready and "acoustics" not in cfg:  # the channel the SITL's world drew
        cfg["acoustics"] = dict(ready["acoustics"])
    return cfg


def start_deploy(config: dict, workdir: str | Path, *args: str):
    """Write ``config`` as TOML into ``workdir`` and start ``mpcasv deploy`` on it."""
    import subprocess
    import sys

    import tomli_w

    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    path = workdir / "deploy.toml"
    path.write_text(tomli_w.dumps(config))
    with (workdir / "deploy.stderr").open("w") as err:  # the child has its own copy
        return subprocess.Popen([sys.executable, "-m", "mpcasv", "deploy", str(path), *args],
                                stdout=subprocess.DEVNULL, stderr=err)  # fmt: skip
