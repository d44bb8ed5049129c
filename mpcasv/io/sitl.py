"""``mpcasv sitl``: the simulator's ASV and AUVs as separate IMC systems on one host,
behaving towards the network as DUNE does.

Each vehicle has its own UDP socket (its ``imc+udp`` service) and IMC id. Like DUNE they

- announce themselves (every 10 s of the SITL clock, and at once to a system they learn);
  a shared discovery socket stands in for DUNE's multicast discovery group (parallel
  tests cannot share 224.0.75.69:30100-30104, so discovery is unicast to ``--discovery``);
- accept datagrams only from systems whose Announce they have heard, from the address it
  names, and stream only to systems that sent a Heartbeat in the last 30 s;
- send EstimatedState at 2 Hz (reference point re-anchored every ``--reanchor`` metres, as
  DUNE moves it), the ASV also its actuators' set-points while its control loops run (a
  transit Reference), one 0.0 each when they stop, and none while they are off (as DUNE's
  Otter in HOVER or standby): SetThrusterActuation (thrust / T_max) id 0 and SetServoPosition
  id 0 (the steering angle, rad) for a steerable drive, SetThrusterActuation ids 0 (port) and
  1 (starboard) for two fixed thrusters (:func:`mpcasv.io.asvwatch.dune_set_points`), and a
  UsblFixExtended per USBL fix of the world (:mod:`mpcasv.io.sitlpublish`);
- announce from a socket of their own (not the ``imc+udp`` port) and relay Heartbeats and
  PlanControls back to the systems they stream to, our own included (as DUNE);
- the ASV answers PlanControl START with a FollowReference argument (SUCCESS "plan loaded"
  and "FollowReference: executing maneuver" to the sender, and "plan completed" after
  MANDONE, as recorded DUNE;
  FAILURE for anything else; ignored unless addressed to it or broadcast) and then runs
  :class:`mpcasv.io.dune.FollowRefManeuver` (References, FollowRefState, MANDONE, timeout,
  speed 0 = loops off);
- every vehicle reports its plan engine's PlanControlState every 0.4 s and at every change,
  the ASV's around START, STOP, MANDONE and a timeout as DUNE's (:mod:`mpcasv.io.sitlplan`,
  :mod:`mpcasv.io.sitlasv`).

The physics is :class:`mpcasv.sim.world.World`, advanced one supervisory period at a time
with the command vector of the ASV's maneuver (zeros when there is none). After publishing
the states of a period boundary the SITL waits until the Reference answering them arrives
(at most ``--reaction`` of a period; the mid-period state goes out late if the wait runs past
it) and then advances with the latest Reference: the same zero-order hold as the in-process
simulator, so that a rehearsal can be compared with it (a Reference that misses its window
acts one period late and is counted in ``late_references``). A real DUNE does not wait: with
``--reaction`` small the SITL shows what the deploy loop's latency does. ``--hold`` keeps the
world at t = 0 until the first Reference (the deploy loop's first decision then sees the scenario's
initial state, as in ``mpcasv simulate``). ``--lockstep`` waits for the Reference answering
each period's state however long the deploy loop takes (and the clock of the world waits
with it): no Reference is late and no wall-clock timing changes the world, so a rehearsal on a
loaded host still decides as ``mpcasv simulate`` does (tests/test_io_e2e.py).

Timestamps are ``epoch + n h`` (integer epoch, h = half a period), so differences of
timestamps are exact. ``--speedup`` runs the clock faster than the wall clock (the deploy
side must use the same factor). SIGUSR1 kills the ASV's IMC system (its DUNE is gone: socket
closed, loops off, the boat drifts) and SIGUSR2 restarts it (a fresh DUNE: no maneuver, no
known systems); ``--asv-outage T0,T1`` does the same at the first period starts at or after
world times T0 and T1 (one that would never kill the ASV is refused:
:mod:`mpcasv.io.sitloptions`).

The options are checked before anything is written or bound for good
(:mod:`mpcasv.io.sitloptions`: ranges, distinct ids and names, the address and ports tried).
Output folder ``--out``: ``sitl.lsf`` (every packet in and out), ``sitl.jsonl`` (events)
and, on exit (duration reached, SIGINT or SIGTERM), ``run/`` written as ``mpcasv simulate``
writes a run (``timeseries.parquet``, ``metrics.json``, ``run.json``...:
:mod:`mpcasv.io.sitlout`; the mode comes from the References, the reasons are unknown to a
vehicle: :mod:`mpcasv.io.rehearsal` joins them from the deploy log).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import os
import signal
import time
from pathlib import Path

import imcpy

from mpcasv.interface import Command, Mode, Reason
from mpcasv.io.dune import FollowRefManeuver
from mpcasv.io.geo import Origin
from mpcasv.io.imc import BadInput, decode, udp_services
from mpcasv.io.logs import JsonlWriter, LsfWriter
from mpcasv.io.netcheck import local_hosts
from mpcasv.io.simvehicle import SimVehicle
from mpcasv.io.sitlasv import AsvDune
from mpcasv.io.sitloptions import SitlOptions
from mpcasv.io.sitlout import RunOutput
from mpcasv.io.sitlpublish import Publishing
from mpcasv.io.transport import Clock, UdpEndpoint
from mpcasv.sim.scenario import Scenario

__all__ = ["Sitl", "SitlOptions"]

log = logging.getLogger("mpcasv.sitl")
Addr = tuple[str, int]
ANNOUNCE_S = 10.0


class Sitl(AsvDune, Publishing, RunOutput):
    """The SITL runner (see the module docstring)."""

    def __init__(self, scenario: Scenario, opt: SitlOptions) -> None:
        from mpcasv.controllers.registry import checked_preset
        from mpcasv.sim.uncertainty import run_scenario
        from mpcasv.sim.world import World

        opt.check(scenario)  # commands.py checked it already
        # the world mpcasv simulate runs for the same seed and duration (realised)
        scenario, self.realisation = run_scenario(scenario, opt.seed, opt.nominal, opt.duration)
        self.sc, self.opt = scenario, opt
        self.clock = Clock(opt.speedup)
        self.origin = Origin.from_degrees(*opt.origin)
        # the scenario's controller and preset are the deploy's, but a scenario naming ones
        # that cannot run is refused here as simulate refuses it; validated, not built (an
        # MPC would load its solver library for nothing)
        checked_preset(scenario.controller, len(scenario.auv), scenario.preset)
        self.world = World(scenario, opt.seed)  # judged by the scenario's domain (issue 12)
        self.domain = self.world.domain
        self.Tc = scenario.sim.control_period
        self.h = self.Tc / 2 if scenario.sim.n_sub % 2 == 0 else self.Tc
        opt.out.mkdir(parents=True, exist_ok=True)
        self.lsf = LsfWriter(opt.out / "sitl.lsf")
        self.jsonl = JsonlWriter(opt.out / "sitl.jsonl")
        self.asv = SimVehicle(self, opt.asv_name, opt.asv_id, "asv", -1)
        self.auvs = [SimVehicle(self, opt.auv_name(a.name), opt.auv_id_base + k, "auv", k)
                     for k, a in enumerate(scenario.auv)]  # fmt: skip
        self.vehicles = [self.asv, *self.auvs]
        self.discovery: UdpEndpoint | None = None  # bound by start()
        self.directory: dict[int, list[Addr]] = {}  # who announced to the discovery socket
        self.maneuver: FollowRefManeuver | None = None
        self.plan_owner: tuple | None = None  # (request id, plan id, node, stream) of START
        self.ref_event = asyncio.Event()
        self.in_window = False
        self.counts: dict[str, int] = {}
        self.rows: list[dict] = []
        self.period = None
        self.prev_S = self.world.S.copy()
        self.ts_offset: float | None = None  # timestamp of world t = 0
        self.held = opt.hold
        self.loops_on = False  # the ASV's control loops ran at the last published state
        self.fixes_sent = [0] * len(self.auvs)  # the world's USBL fixes sent, per AUV
        self.reports_sent = [0] * len(self.auvs)  # its status reports (--auv-states acoustic)
        self.dived = False  # --auv-states acoustic: the AUVs' states now come as reports
        self.epoch = 0.0
        self.n = 0

    # --- clock and bookkeeping -----------------------------------------------------------
    def now(self) -> float:
        """Timestamp of the current tick (exact multiples of h after an integer epoch)."""
        return self.epoch + self.n * self.h

    def count(self, what: str) -> None:
        self.counts[what] = self.counts.get(what, 0) + 1

    def event(self, name: str, **info) -> None:
        self.jsonl.write({"kind": "event", "event": name, "t": self.now(),
                          "t_world": self.world.t} | info)  # fmt: skip
        log.info("%s %s", name, info)

    # --- main loop ---------------------------------------------------------------------------
    def on_discovery(self, data: bytes, addr: Addr) -> None:
        try:
            msg, raw = decode(data)
        except BadInput:
            self.count("discovery_bad")
            return
        self.lsf.write(raw)
        if not isinstance(msg, imcpy.Announce):
            return
        self.directory[msg.src] = udp_services(msg.services)
        for v in self.vehicles:
            if v.alive:
                v.learn(msg)

    async def start(self) -> None:
        o = self.opt
        self.discovery = await UdpEndpoint.open(o.bind, o.discovery_port, self.on_discovery)
        for k, v in enumerate(self.vehicles):
            v.port = o.base_port + k if o.base_port else 0
            await v.open(o.bind)
            if o.tcp:
                await v.serve_tcp(o.bind)
        self.epoch = float(math.ceil(self.clock.now()) + 1)
        # the addresses a peer can send to (bound to 0.0.0.0: this host's, loopback last);
        # the addresses below at the first
        hosts = local_hosts(o.bind)
        ready = {
            "pid": os.getpid(), "hosts": hosts,
            "discovery": f"{hosts[0]}:{self.discovery.address[1]}",
            "vehicles": [{"name": v.name, "id": v.id, "role": v.role,
                          "address": f"{hosts[0]}:{v.port}",
                          "tcp": f"{hosts[0]}:{v.tcp_port}" if o.tcp else None}
                         for v in self.vehicles],
            "acoustics": self.write_acoustics(),
        }  # fmt: skip
        self.event("ready", **ready)
        if o.ready_file is not None:
            tmp = Path(f"{o.ready_file}.tmp")
            tmp.write_text(json.dumps(ready))
            tmp.replace(o.ready_file)
        print(json.dumps({"ready": ready}), flush=True)

    async def run(self, stop: asyncio.Event) -> dict:
        """Run until ``stop`` is set or the duration is reached; then :meth:`finish`. A run
        that fails (a port taken after the options were checked, say) or is cancelled
        writes event ``aborted`` (``reason``) and closes its sockets and logs
        (:meth:`close`, no ``run/`` folder) before the exception goes on."""
        try:
            return await self._run(stop)
        except BaseException as exc:
            if not self.jsonl.closed:
                reason = ("cancelled" if isinstance(exc, asyncio.CancelledError)
                          else f"{type(exc).__name__}: {exc}".splitlines()[0])  # fmt: skip
                self.event("aborted", reason=reason)
            self.close()
            raise

    async def _run(self, stop: asyncio.Event) -> dict:
        self._stop = stop
        await self.start()
        n_steps = self.opt.periods(self.sc)
        per = round(self.Tc / self.h)
        helpers = [asyncio.create_task(self._flush_loop()),
                   asyncio.create_task(self.publish_plan_states())]  # fmt: skip
        try:
            wall_s, overruns = await self._loop(stop, n_steps, per)
        finally:
            for task in helpers:
                task.cancel()
        for task in helpers:
            with contextlib.suppress(asyncio.CancelledError):
                await task
        return self.finish(wall_s, overruns)

    async def _loop(self, stop: asyncio.Event, n_steps: int, per: int) -> tuple[float, int]:
        """The ticks until ``stop`` or ``n_steps`` periods; (wall seconds, overruns)."""
        boundary = 0  # tick index of the next period boundary
        next_announce = 0.0
        outage = self.opt.asv_outage
        wall0 = time.perf_counter()
        overruns = 0
        while not stop.is_set() and len(self.rows) < n_steps:
            await self.clock.sleep_until(self.now())
            if self.clock.now() > self.now() + self.h:
                overruns += 1
            if self.now() >= next_announce:
                next_announce = self.now() + ANNOUNCE_S
                for v in self.vehicles:
                    v.announce_to([n.services[0] for n in v.nodes.values() if n.services])
            if outage is not None and not self.held:
                if self.asv.alive and outage[0] <= self.world.t < outage[1]:
                    self.kill_asv()
                elif not self.asv.alive and self.world.t >= outage[1]:
                    await self.restart_asv()
            self.maneuver_timeout()
            at_boundary = self.n == boundary or self.held
            if at_boundary:
                self.ref_event.clear()  # only a Reference answering this state counts
            self.publish_states(mid=not at_boundary)
            if at_boundary:
                await self._react()
                if self.held and self.maneuver is not None and self.maneuver.got_reference:
                    self.held = False
                if not self.held:
                    if self.ts_offset is None:
                        self.ts_offset = self.now() - self.world.t
                        self.event("world_started", ts_offset=self.ts_offset)
                    self._advance()
                    boundary = self.n + per
            self.n += 1
        return time.perf_counter() - wall0, overruns

    async def _flush_loop(self) -> None:
        while True:
            await asyncio.sleep(0.5)
            self.jsonl.flush()
            self.lsf.flush()

    async def _react(self) -> None:
        """Wait (up to ``reaction`` of a period) for the Reference answering this state."""
        m = self.maneuver
        if m is None or m.done or not self.asv.alive:
            return
        self.in_window = True
        try:
            if self.opt.lockstep:  # until the Reference comes (or the SITL is stopped)
                waits = [asyncio.ensure_future(e.wait()) for e in (self.ref_event, self._stop)]
                _, pending = await asyncio.wait(waits, return_when=asyncio.FIRST_COMPLETED)
                for w in pending:
                    w.cancel()
                return
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(
                    self.ref_event.wait(), self.clock.wall_seconds(self.opt.wait_periods * self.Tc)
                )
        finally:
            self.in_window = False

    def _advance(self) -> None:
        from mpcasv.sim.simulator import timeseries_row

        w = self.world
        cmd_vec = self.command_vector()
        self.prev_S = w.S.copy()
        self.period = w.advance(cmd_vec)
        if cmd_vec[0] > 0.5:
            cmd = Command(Mode.TRANSIT, (float(cmd_vec[1]), float(cmd_vec[2])),
                          float(cmd_vec[3]), None, Reason.NOMINAL)  # fmt: skip
        else:
            cmd = Command.standby()
        row = timeseries_row(w, w.observation(), cmd, self.period, 0.0)
        row["asv_alive"] = self.asv.alive
        self.rows.append(row)

    def close_sockets(self) -> None:
        """Close every vehicle's sockets (and TCP server and its clients) and the discovery
        socket. Safe to call repeatedly, and before :meth:`start` or after it failed."""
        for v in self.vehicles:
            v.close()
            if v.tcp_server is not None:
                v.tcp_server.close()
            for stream in list(v.tcp_clients):
                stream.close()
        if self.discovery is not None:
            self.discovery.close()

    def close(self) -> None:
        """Close the sockets and the logs, writing no run folder (:meth:`finish` does that
        at the end of a run). Safe to call repeatedly."""
        try:
            self.close_sockets()
        finally:
            self.jsonl.close()
            self.lsf.close()


def run_sitl(scenario: Scenario, opt: SitlOptions) -> dict:
    """Run the SITL until its duration, SIGINT or SIGTERM (signals as in the module doc).

    The world is built (seconds: the scenario's realisation, the vessel model) before the event
    loop starts, as the deploy builds its controller: a Ctrl-C meanwhile raises
    KeyboardInterrupt at once (``mpcasv sitl`` exits 130, nothing bound or written). Built
    inside the loop, before its handlers, it met asyncio's own SIGINT handler, which only
    cancels the main task: the build ran on to its end (5.8 s after the Ctrl-C on a loaded
    host), then the SITL stopped at its first await without its shutdown (session 26).
    """
    sitl = Sitl(scenario, opt)

    async def main() -> dict:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        loop.add_signal_handler(signal.SIGUSR1, sitl.kill_asv)
        loop.add_signal_handler(signal.SIGUSR2,
                                lambda: asyncio.ensure_future(sitl.restart_asv()))  # fmt: skip
        return await sitl.run(stop)

    try:
        return asyncio.run(main())
    finally:
        sitl.close()  # (closed already unless the event loop failed before the run)
