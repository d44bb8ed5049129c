"""``mpcasv deploy``: the chosen controller on live IMC data.

Per supervisory period (``controller.control_period``, stepped on the ASV's EstimatedState
whose timestamp reaches the next tick, so a rehearsal follows the SITL's clock exactly):
the AUVs' accepted EstimatedStates have fed their estimators (each state is a status
report, and the truth for ``perfect``), the watchdogs classify every AUV (ok / uncertain /
lost, :mod:`mpcasv.io.watchdog`), the controller steps on the Observation, the guard may
override its command, and the command goes to the ASV as a Reference (``--dry-run``: logged
only). Everything is logged (``imc.lsf``: every packet in and out; ``deploy.jsonl``: every
decision with the Observation it was made on, and every event).

Phases: ``waiting`` (for the ASV's and every AUV's first state) -> ``starting``
(PlanControl START FollowReference sent; waits for the answer with the same request id;
retried after ``plan_start_timeout``) -> ``running``. The ASV's state older than
``asv_stale_s`` -> ``asv_stale``: no more References (DUNE then ends the maneuver on its
timeout and stops), reported; when a state stamped after that verdict comes (not a late one
from before it: :meth:`~mpcasv.io.deployphases.Phases.asv_back`) -> ``waiting`` and
FollowReference is started again. A FollowRefState TIMEOUT for our maneuver restarts it;
DUNE saying our plan ended (a PlanControl to us, or its PlanControlState no longer showing our
plan EXECUTING: :mod:`~mpcasv.io.planstate`), or no FollowRefState for
``link.followref_lost_s``, stops the run (deployphases).

Shutdown (Ctrl-C / SIGTERM, or ``duration``): stop deciding (states are no longer used),
stop announcing, heart-beating and listening for discovery; a standby Reference (speed 0)
then MANDONE; wait (at most ``link.plan_done_timeout``) for DUNE's answer to MANDONE
(PlanControl SUCCESS "plan completed" with our request id); close the socket; ``summary``
(counters, CPU use, the vehicles ``heard``) is the last record written; a run that never made
a decision says why in its ``no_decision`` (``mpcasv deploy`` then exits 1).

The controller is built (an MPC's library compiled if it is not cached) before any socket is
opened: ``mpcasv deploy CONFIG --prepare`` does only that, at the quay.

A controller that solves an optimisation (one with ``use_deadline``: the MPCs) runs in field
mode (:mod:`mpcasv.mpc.deadline`): its solves run in a worker process, started here before
any socket is opened, and a solve that overruns the step's budget (``solver.budget_ms``) is
abandoned (that step takes the hybrid fallback's command). Its ``step`` runs in a thread of
its own, so the event loop (link, watchdogs, logs) keeps running during a solve; a tick that
comes while the previous step is still running is skipped (event ``step_skipped``). Other
controllers step inline (well under a millisecond). The workers are stopped at shutdown.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import math
import signal
import time
from pathlib import Path

import imcpy

from mpcasv.config import ConfigError
from mpcasv.estimation import InOrder, make_estimator
from mpcasv.interface import Command
from mpcasv.io.asvwatch import ClockRate, SpeedWatch, Thrusters, UsblFixes
from mpcasv.io.config import DeployConfig, build_controller, load_deploy_config
from mpcasv.io.deploycontroller import deploy_boat, known_plans
from mpcasv.io.deploydecide import Deciding
from mpcasv.io.deployend import Ending
from mpcasv.io.deployfeedback import BoatFeedback
from mpcasv.io.deployphases import ASV_STALE, PLAN_ENDED, RUNNING, STARTING, WAITING, Phases
from mpcasv.io.deploystep import (
    FieldMode,
    check_local,
    guard_params,
    prepare_controller,
)
from mpcasv.io.link import ImcLink, Peer
from mpcasv.io.logs import FolderLock, JsonlWriter, LsfWriter, keep_earlier
from mpcasv.io.planstate import PlanStateWatch
from mpcasv.io.transport import Clock
from mpcasv.io.watchdog import OK
from mpcasv.models.acoustics import Report

__all__ = ["ASV_STALE", "PLAN_ENDED", "RUNNING", "STARTING", "WAITING", "Deploy",
           "guard_params", "run_deploy"]  # from deploystep and deployphases

log = logging.getLogger("mpcasv.deploy")


def clock_rate_note(rate: float, speedup: float) -> str:
    """What a ``clock_rate`` event says: the ASV's clock ran ``rate`` times as fast as the
    deploy's, whose ``[clock] speedup`` is ``speedup``."""
    if rate > 1.0:
        return ("the ASV's clock runs this many times as fast as the deploy's: is [clock] "
                "speedup the SITL's --speedup?")
    return (f"the ASV's clock runs this many times as fast as the deploy's, whose [clock] "
            f"speedup is {speedup:g}: against a real vehicle it must be 1 (a rehearsal's "
            f"factor left in the file?), against a SITL its --speedup (a SITL under "
            f"--lockstep this far behind waits for a deploy too slow for the factor); its "
            f"staleness limits and --duration run {1 / max(rate, 1e-9):.3g} times too fast")


class Deploy(Deciding, Phases, PlanStateWatch, BoatFeedback, FieldMode, Ending):
    """The deploy loop (see the module docstring).

    Parameters
    ----------
    cfg : DeployConfig
    dry_run : bool
        Compute and log the commands, send no PlanControl/Reference.
    log_dir : Path, optional
        Overrides ``cfg.log.dir``.
    solver_factory : callable, optional
        Field mode (controllers with ``use_deadline``): builds the worker's solver (tests:
        :meth:`mpcasv.mpc.solving.Solving.use_deadline`); None: the controller's own.
    """

    def __init__(self, cfg: DeployConfig, dry_run: bool = False, log_dir: Path | None = None,
                 solver_factory=None):  # fmt: skip
        self.cfg, self.dry_run = cfg, dry_run
        # what close() releases; None until opened (a constructor that fails closes them)
        self.lsf: LsfWriter | None = None
        self.jsonl: JsonlWriter | None = None
        self.lock: FolderLock | None = None
        self.link: ImcLink | None = None
        self.field_mode = False
        self._summary_written = False
        try:
            self.clock = Clock(cfg.clock.speedup)
            self.t_started = self.clock.now()  # the deploy clock when the link started (run())
            c = cfg.controller
            self.n_auv = len(cfg.auvs)
            self.controller = build_controller(cfg, log=log.info)
            self.controller.reset(self.n_auv)
            if getattr(self.controller, "needs_usbl_fixes", False) and \
                    cfg.watchdog.propeller == "command":
                log.warning("fix_age_source = 'observed' judges each USBL fix by the propeller "
                            "state, here our own command (watchdog.propeller = 'command'), "
                            "not the thrusters DUNE reports")  # fmt: skip
            self.init_field_mode(solver_factory)  # before any socket is opened
            self.domain = getattr(self.controller, "domain", None)
            plans = known_plans(cfg)
            # in time order: the ASV's USBL fixes arrive after AUV states stamped later
            self.new_estimator = lambda k: InOrder(make_estimator(c.estimator, initial=None,
                                                                  plan=plans[k]))  # fmt: skip
            self.estimators = [self.new_estimator(k) for k in range(self.n_auv)]
            self.log_dir = Path(log_dir or cfg.log.dir)
            # one deploy per folder (a second one renamed and interleaved the first's logs),
            # and an earlier run's log renamed, not written over (its names in 'started')
            self.lock = FolderLock(self.log_dir, "--log-dir" if log_dir else "log.dir")
            self.kept = keep_earlier(self.log_dir)
            if self.kept:
                log.info("kept the earlier run's log in %s: %s", self.log_dir,
                         ", ".join(f"{a} -> {b}" for a, b in self.kept.items()))  # fmt: skip
            self.lsf = LsfWriter(self.log_dir / "imc.lsf")
            self.jsonl = JsonlWriter(self.log_dir / "deploy.jsonl")
            self.link = ImcLink(cfg, self.clock, self.lsf, self._on_state, self._on_message,
                                self._on_event)  # fmt: skip
            self.gp = guard_params(cfg.watchdog, self.controller)
            self.phase = WAITING
            self.t_next = -math.inf  # next supervisory tick (ASV state time)
            self.request_id = 0
            self.pending: tuple[int, float] | None = None  # (request id, sent at)
            self.retry_at = -math.inf
            self.started = False  # FollowReference has been started at least once
            self.plan_starts = 0  # PlanControl START requests sent (no_decision)
            self.plan_failures = 0  # ... answered FAILURE
            self.status = ["missing"] * self.n_auv
            wd = cfg.watchdog
            self.thrusters = Thrusters(wd.asv_stale_s, wd.propeller_on_threshold)
            self.usbl = UsblFixes(self.n_auv)  # the ASV's own USBL fixes (M2o reads them)
            self.clock_rate = ClockRate()  # the ASV's clock against ours (clock.speedup)
            self.vessel = deploy_boat(cfg).vessel  # its actuation maps DUNE's set-points
            self.speed = SpeedWatch(cfg.speed)
            self.speed_cap: float | None = None  # applied to the controller (speed_feedback)
            self.speed_base: float | None = None  # its params.speed before the 1st cap
            self.speed_top: float | None = None  # its top speed then (params or plan)
            self.closing = False  # shutdown begun: no more decisions
            self.plan_request: int | None = None  # request id of the running FollowReference
            self.plan_done = asyncio.Event()
            self._propeller_note: str | None = None
            self._said: set[str] = set()  # what is said once per run (BoatFeedback.first)
            self._cpu0, self._wall0 = time.process_time(), time.monotonic()
            self._load_mark = (self._cpu0, self._wall0, 0)
            self.followref: dict | None = None
            self.init_plan_watch()
            self.init_plan_state()
            self.steps = 0
            self.overrides = 0
            self.stale_events = 0
            self.stale_mark = math.inf  # the ASV's own clock when it was called stale (asv_back)
            self.late_states = 0  # ASV states read while stale but stamped before the verdict
            self._late_reported = 0  # the outage (stale_events) whose first late state was logged
            self._waiting_for: tuple = ()
            self._propeller_source = "command"
            self.last_cmd: Command | None = None
        except BaseException:
            self.close()
            raise

    # --- reports -------------------------------------------------------------------------
    def _on_event(self, rec: dict) -> None:
        self.jsonl.write(rec)
        if rec.get("event") == "step_error":
            log.error("controller step at t = %.3f failed: %s (no command this tick; the next "
                      "tick steps again)", rec.get("t"), rec.get("error"))  # fmt: skip
        elif rec.get("event") == "between_error":
            log.error("controller's work after the step at t = %.3f failed: %s (the command "
                      "was sent; the next tick steps again)", rec.get("t"), rec.get("error"))
        elif rec.get("event") == "reject" and rec.get("reason") == "internal_error":
            # a bug in our own handling, not the input's fault: the message was dropped
            log.error("internal error while handling %s from %s: %s (the message was dropped; "
                      "counted in rejects 'internal_error'; a bug: please report it with "
                      "deploy.jsonl)", rec.get("msg"), rec.get("addr"), rec.get("detail"))
        elif rec.get("event") != "reject":  # a current above the tested one: also --quiet
            detail = {k: v for k, v in rec.items() if k not in ("kind", "event", "t")}
            level = logging.WARNING if rec["event"] in self.WARNING_EVENTS else logging.INFO
            log.log(level, "%s %s", rec["event"], detail)

    def event(self, name: str, **info) -> None:
        self.link.event(name, phase=self.phase, **info)

    # --- input ---------------------------------------------------------------------------
    def _on_state(self, p: Peer, nav, now: float) -> None:
        if self.closing:
            return
        if p.role == "asv":
            rate = self.clock_rate.state(nav.t, now)
            if rate is not None:
                self.event("clock_rate", rate=round(rate, 2), speedup=self.cfg.clock.speedup,
                           note=clock_rate_note(rate, self.cfg.clock.speedup))
            ev = self.speed.state(nav.t, math.hypot(nav.v_N, nav.v_E), nav.u)
            if ev is not None:
                self.event(ev.pop("event"), **ev)
            self._speed_feedback()  # the cap follows the achievable speed
            if self.phase == ASV_STALE and not self.asv_back(p, nav, now):
                return  # a late state, from before the verdict: the ASV is not back
            self._advance(now)
            if self.phase == RUNNING:
                self._maybe_step(nav.t, now)
            return
        k = p.index
        self.usbl.refused[k].clear()  # the AUV's own word: refused fixes no longer in a row
        est = self.estimators[k]
        est.on_truth(nav.t, nav.N, nav.E, nav.depth, nav.v_N, nav.v_E)
        sog = math.hypot(nav.v_N, nav.v_E)  # the report's velocity is over ground: its
        course = math.atan2(nav.v_E, nav.v_N) if sog > 0.0 else nav.psi  # course, not heading
        est.on_report(
            Report(
                nav.t,
                k,
                nav.N,
                nav.E,
                nav.depth,
                course,
                sog,
                self.cfg.watchdog.report_sigma_m,
            )
        )
        if self.status[k] not in (OK, "missing"):
            self.event("auv_fresh", vehicle=p.label, auv=k, was=self.status[k])
        self.status[k] = OK

    def _on_message(self, p: Peer, msg, now: float) -> None:
        if isinstance(msg, imcpy.PlanControl):
            self._plan_control(msg, now)
        elif self.closing:
            return
        elif isinstance(msg, imcpy.FollowRefState):
            self._followref_state(p, msg, now)
        elif isinstance(msg, imcpy.PlanControlState):
            self._plan_control_state(p, msg, now)
        elif isinstance(msg, imcpy.SetThrusterActuation):
            self.thrusters.update(msg.id, msg.value, now)
        elif isinstance(msg, imcpy.SetServoPosition):
            self.thrusters.update_servo(msg.id, msg.value, now)
        elif isinstance(msg, imcpy.UsblFixExtended):
            self._usbl_fix(p, msg)

    # --- run and stop --------------------------------------------------------------------
    async def run(self, stop: asyncio.Event, duration: float | None = None) -> dict:
        """Run until ``stop`` is set (or ``duration`` s of the deploy clock); return the
        final counters.

        A run that fails (the link cannot bind, say) or is cancelled is aborted
        (:meth:`abort`) and the exception goes on."""
        try:
            return await self._run(stop, duration)
        except BaseException as exc:
            self.abort(exc)
            raise

    async def _run(self, stop: asyncio.Event, duration: float | None) -> dict:
        self.stop_event = stop  # DUNE ending our plan stops the run (Phases._plan_ended)
        await self.link.start()
        self.t_started = self.clock.now()
        self.event(
            "started",
            controller=self.cfg.controller.name,
            dry_run=self.dry_run,
            speedup=self.cfg.clock.speedup,
            log_dir=str(self.log_dir),
            earlier_log_kept=self.kept,
            # the configuration as run: log.dir the folder used (--log-dir overrides it)
            config=dataclasses.asdict(dataclasses.replace(
                self.cfg, log=dataclasses.replace(self.cfg.log, dir=str(self.log_dir)))),
            guard=dataclasses.asdict(self.gp),
        )
        tasks = [asyncio.create_task(self._every_clock(0.25, self.watch)),
                 asyncio.create_task(self._flush_loop())]  # fmt: skip
        if duration is not None:
            tasks.append(asyncio.create_task(self._stop_after(duration, stop)))
        try:
            await stop.wait()
        finally:  # (cancelled: run() aborts)
            for t in tasks:
                t.cancel()
        for t in tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await t
        return await self.shutdown()

    async def _every_clock(self, period: float, fn) -> None:
        while True:
            await self.clock.sleep(period)
            fn()

    async def _flush_loop(self) -> None:
        while True:
            await asyncio.sleep(self.cfg.log.flush_s)
            self.jsonl.flush()
            self.lsf.flush()

    async def _stop_after(self, duration: float, stop: asyncio.Event) -> None:
        await self.clock.sleep(duration)
        stop.set()


def run_deploy(config: str | Path, dry_run: bool = False, log_dir: Path | None = None,
               duration: float | None = None, prepare: bool = False) -> dict:  # fmt: skip
    """Load ``config``, build the controller (compiling what it needs), and run the deploy
    loop until Ctrl-C / SIGTERM (or ``duration``). ``prepare``: stop after building, before
    any socket is opened. Both first try what the run needs of this host
    (:func:`~mpcasv.io.deploystep.check_local`: the log folder, the bind address; the run also
    ``link.port``). ``prepare`` with ``dry_run`` or ``duration`` (run options: nothing runs)
    is refused in one line (ConfigError)."""
    if prepare and (dry_run or duration is not None):
        given = " and ".join(o for o, on in (("--dry-run", dry_run),
                                             ("--duration", duration is not None)) if on)
        raise ConfigError(f"--prepare builds the controller and exits without running, so "
                          f"{given} {'have' if ' and ' in given else 'has'} no effect: prepare "
                          f"first, then run with {given} (without --prepare)")  # fmt: skip
    cfg = load_deploy_config(config)
    check_local(cfg, config, log_dir, port=not prepare)
    if prepare:
        return prepare_controller(cfg)
    with Deploy(cfg, dry_run, log_dir) as deploy:

        async def main() -> dict:
            stop = asyncio.Event()
            loop = asyncio.get_running_loop()
            for sig in (signal.SIGINT, signal.SIGTERM):
                loop.add_signal_handler(sig, stop.set)
            return await deploy.run(stop, duration)

        return asyncio.run(main())
