"""How the deploy loop builds and steps its controller: the guard's parameters, the AUVs'
known plans, ``--prepare``, and the field mode (a mixin of :class:`mpcasv.io.deploy.Deploy`).

Field mode: a controller
that solves an optimisation (one with ``use_deadline``: the MPCs) solves in a worker process
with a hard deadline per step (:mod:`mpcasv.mpc.deadline`), started before any socket is
opened, and its ``step`` runs in a thread of its own so that the event loop (link,
watchdogs, logs) keeps running during a solve. Other controllers step inline.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import functools
import logging
import math
import time

from mpcasv.interface import Command
from mpcasv.io.config import DeployConfig, WatchdogSpec, build_controller, parse_address
from mpcasv.io.watchdog import GuardParams, guard_sources

log = logging.getLogger("mpcasv.deploy")


def start_field_mode(controller, factory=None, log=log.info) -> None:
    """Start the controller's solver worker (:meth:`use_deadline`), with a line before and
    after: it loads the compiled library in a new process (seconds)."""
    t0 = time.perf_counter()
    log("starting the solver worker (field mode: hard deadline per step)")
    controller.use_deadline(factory)
    log(f"solver worker ready in {time.perf_counter() - t0:.1f} s")


def check_budget(cfg: DeployConfig, controller, log=log.warning) -> bool:
    """Field mode: a step's solves and, after its command, the exploration solve each have the
    preset's ``solver.budget_ms``, and with ``solver.step_iter`` a carried step's work too;
    all should fit in 90 % of ``controller.control_period`` (a tick may come that soon after
    the last, and one that finds the step thread busy is skipped, event ``step_skipped``).
    Says so (``log``) and returns False if they may not."""
    sp = getattr(getattr(controller, "params", None), "solver", None)
    budget = getattr(sp, "budget_ms", None)
    Tc = cfg.controller.control_period
    n = 3 if getattr(sp, "step_iter", None) else 2
    if budget is not None and n * budget / 1e3 > 0.9 * Tc:
        what = ("a step, a carried step's work and the exploration solve" if n == 3 else
                "a step and its exploration solve")  # fmt: skip
        log(f"solver.budget_ms = {budget:g} ms: {what} may take {n * budget:g} ms, more "
            f"than 90 % of controller.control_period = {Tc:g} s: the ticks that come "
            "meanwhile will be skipped")  # fmt: skip
        return False
    return True


def guard_params(wd: WatchdogSpec, controller) -> GuardParams:
    """Guard parameters: the watchdog limits of ``wd`` (a deploy configuration's
    ``[watchdog]``), and the keep-out sphere of the controller's ``avoid`` option
    (:class:`mpcasv.hybrid.avoidance.AvoidanceParams`), else its domain's ``r_in``, else
    ``watchdog.keep_out_m``; the controller's ``speed``, else ``watchdog.guard_speed``
    (:func:`~mpcasv.io.watchdog.guard_sources`). One definition for the deploy and its
    replay with another controller or preset (:func:`mpcasv.io.replay.replay`)."""
    params = getattr(controller, "params", None)
    domain = getattr(controller, "domain", None)
    keep, speed_from = guard_sources(params, domain)
    if keep == "avoid":
        r_keep = params.avoid.sphere(domain)
    else:
        r_keep = domain.r_in if keep == "domain" else wd.keep_out_m
    speed = float(params.speed if speed_from == "speed" else wd.guard_speed)
    return GuardParams(wd.auv_stale_s, wd.auv_lost_s, wd.auv_speed_max, wd.auv_rise_rate,
                       float(r_keep), wd.guard_margin_m, speed)  # fmt: skip


def check_local(cfg: DeployConfig, config, log_dir=None, port: bool = False) -> None:
    """What the run needs of this host, tried before the controller is built or anything is
    written or bound for good: the log folder (``--log-dir`` or ``log.dir``) can be made and
    written (``--prepare`` and the run; an earlier run's log there is kept by the run:
    :func:`~mpcasv.io.logs.keep_earlier`); with ``port`` (the run, not
    ``--prepare``, which runs at the quay with the boat's network still down, so that the
    address of ``bind`` may not exist yet: docs/deploy.md) ``link.bind`` (and
    ``link.discovery_bind``) is an address of this host (a UDP socket bound to it and closed
    at once) and ``link.port`` on it is free; bound to 0.0.0.0 (UDP), this host has a route
    to every vehicle's address (the source address our Announce then names:
    :func:`~mpcasv.io.netcheck.announced_hosts`).

    Raises
    ------
    ConfigError
        One line naming ``config``'s field (or ``--log-dir``), the value and the cause.
    """
    from mpcasv.io.netcheck import announced_hosts, check_bindable
    from mpcasv.outputs import check_output_folder

    check_output_folder(log_dir or cfg.log.dir, "--log-dir" if log_dir else f"{config}: log.dir")
    if not port:
        return
    lk = cfg.link
    if lk.transport == "udp" and lk.port:
        check_bindable(lk.bind, lk.port, f"{config}: link.bind, link.port")
    else:
        check_bindable(lk.bind, 0, f"{config}: link.bind")
    if lk.discovery_bind is not None:
        check_bindable(lk.discovery_bind, 0, f"{config}: link.discovery_bind")
    if lk.transport == "udp":  # bound to 0.0.0.0: the addresses our Announce names
        announced_hosts(lk.bind, [parse_address(v.address) for v in cfg.vehicle if v.address],
                        f"{config}: link.bind")  # fmt: skip


def prepare_controller(cfg: DeployConfig) -> dict:
    """``mpcasv deploy CONFIG --prepare``: build the controller (an MPC's library compiled if
    it is not cached) and, for an MPC, start its solver worker once (it loads the library in a
    fresh process) and stop it; nothing is bound, nobody contacted (:func:`check_local` has
    tried the log folder and the address first). Returns what the run will use, to be read
    at the quay: controller, preset, vessel, estimator, whether it takes the ASV's
    actuators (``actuator_feedback``) and where the propeller state comes from, and the
    seconds the build took."""
    t0 = time.perf_counter()
    # progress lines at info (shown unless --quiet; they read "warning:" before session 43)
    ctl = build_controller(cfg, log=log.info)
    field = hasattr(ctl, "use_deadline")
    if field:
        check_budget(cfg, ctl)  # a real warning
        start_field_mode(ctl, log=log.info)
        ctl.close()
    c = cfg.controller
    return {"controller": c.name, "preset": c.preset, "vessel": c.vessel or "gretha",
            "estimator": c.estimator, "actuator_feedback": c.actuator_feedback,
            "propeller": cfg.watchdog.propeller, "field_mode": field,
            "seconds": time.perf_counter() - t0}


class FieldMode:
    """Mixin of :class:`~mpcasv.io.deploy.Deploy` (uses its ``cfg``, ``controller``,
    ``closing``, ``event``, ``jsonl``, ``observation`` and ``_act``)."""

    def init_field_mode(self, solver_factory=None) -> None:
        """Field mode if the controller has ``use_deadline``: start its solver worker
        (``solver_factory``: tests' hook, see ``use_deadline``) and the step thread."""
        #: field mode: solves in a worker process with a hard deadline, steps in a thread
        self.field_mode = hasattr(self.controller, "use_deadline")
        self._step_task: asyncio.Task | None = None
        self._step_pool: concurrent.futures.ThreadPoolExecutor | None = None
        self.skipped_steps = 0
        self.step_errors = 0  # steps that raised (both modes: see step_failed)
        self.between_solves = 0  # steps with solves after their command (log_between)
        self.between_ms_max = 0.0  # the longest of them, wall ms
        #: when the controller first planned with a current above the tested one (event
        #: ``current_untested``, once per run; None: not yet)
        self.current_untested_t: float | None = None
        self.cap_pending: float | None = None  # a speed cap waiting for the step in flight
        if self.field_mode:
            check_budget(self.cfg, self.controller)
            start_field_mode(self.controller, solver_factory)
            self._step_pool = concurrent.futures.ThreadPoolExecutor(
                1, thread_name_prefix="mpcasv-step")

    def schedule_step(self, ts: float, now: float) -> None:
        """Start the decision at ``ts`` in the step thread; a tick that comes while the
        previous one is still solving is skipped (event ``step_skipped``)."""
        if self.step_in_flight():
            self.skipped_steps += 1
            self.event("step_skipped", t=ts, reason="the previous step is still solving")
            return
        if self.cap_pending is not None:  # a cap that came during the last step: now
            self.set_controller_speed(self.cap_pending)
        self._step_task = asyncio.get_running_loop().create_task(self.step_async(ts, now))
        self._step_task.add_done_callback(functools.partial(self._step_ended, ts))

    def step_in_flight(self) -> bool:
        """Field mode: a step (or its work after the command) is running in the step
        thread; the controller is not to be changed from the event loop meanwhile."""
        return self._step_task is not None and not self._step_task.done()

    def _step_ended(self, ts: float, task: asyncio.Task) -> None:
        """Field mode: the step task's exception, if any, goes to :meth:`step_failed`."""
        if task.cancelled() or task.exception() is None:
            return
        self.step_failed(ts, task.exception())

    def step_failed(self, ts: float, exc: BaseException) -> None:
        """A step that raised is never silent, in field mode or inline: event ``step_error``
        with the exception's first line (logged as an error when it happens), counted in
        ``step_errors`` (and the summary). The deploy goes on: no command this tick, the next
        tick steps again, the guard's watchdogs keep running, and DUNE holds the last
        Reference until ``link.followref_timeout``, then ends the maneuver and stops."""
        self.step_errors += 1
        log.debug("step at t = %s raised", ts, exc_info=exc)
        self.event("step_error", t=ts, error=f"{type(exc).__name__}: {exc}".splitlines()[0])

    def note_untested_current(self, ts: float, diag: dict) -> None:
        """Event ``current_untested`` (once per run, at the first decision whose controller
        diagnostics ``diag`` carry ``mpc_cur_untested`` = 1: an MPC that plans with a current
        above :data:`~mpcasv.mpc.worldview.CURRENT_TESTED`), with the decision's time ``t``
        (s), the current's ``speed`` (m/s, from ``mpc_cur_N`` / ``mpc_cur_E``) and the
        ``tested`` limit (m/s). Controllers without the diagnostic: nothing.

        Raises
        ------
        KeyError
            ``diag`` flags the current but does not carry it (``mpc_cur_N`` / ``mpc_cur_E``).
        """
        if self.current_untested_t is not None or not diag.get("mpc_cur_untested"):
            return
        from mpcasv.mpc.worldview import CURRENT_TESTED  # an MPC: its modules are loaded

        self.current_untested_t = ts
        speed = math.hypot(diag["mpc_cur_N"], diag["mpc_cur_E"])
        self.event("current_untested", t=ts, speed=round(speed, 2), tested=CURRENT_TESTED)

    async def step_async(self, ts: float, now: float) -> Command | None:
        """One decision, the controller stepped in the step thread (field mode): the event
        loop runs on meanwhile. None if the shutdown began during the solve."""
        obs, status, ages = self.observation(ts, now)
        c0 = time.perf_counter()
        loop = asyncio.get_running_loop()
        raw = await loop.run_in_executor(self._step_pool, self.controller.step, obs)
        if self.closing:
            return None
        cmd = self._act(ts, now, obs, status, ages, raw, (time.perf_counter() - c0) * 1e3)
        if hasattr(self.controller, "between_steps") and not self.closing:
            # after the command is sent: an MPC's exploration solve (with its own budget)
            self.log_between(ts, await loop.run_in_executor(self._step_pool, self.run_between))
        return cmd

    def run_between(self) -> dict:
        """The controller's ``between_steps`` (an MPC's exploration solve, or a carried
        step's work, after the step's command was sent: docs/mpc.md, "Controller step" 3 and
        3b), never raising: what it did, for :meth:`log_between` (wall ``ms``; the
        diagnostics ``mpc_explore_*`` and ``mpc_deferred_*``; or ``error``)."""
        c0 = time.perf_counter()
        try:
            self.controller.between_steps()
        except Exception as exc:  # the command is sent already: logged, the next step goes on
            log.debug("between_steps raised", exc_info=exc)
            return {"error": f"{type(exc).__name__}: {exc}".splitlines()[0]}
        diag = getattr(self.controller, "diagnostics", None)
        out = {k: v for k, v in (diag() if diag else {}).items()
               if k.startswith(("mpc_explore", "mpc_deferred"))}  # fmt: skip
        return out | {"ms": (time.perf_counter() - c0) * 1e3}

    def log_between(self, ts: float, rec: dict) -> None:
        """A ``between`` record in deploy.jsonl when a solve ran (counted in the
        summary's ``between_solves``, its wall time in ``between_ms_max``); event
        ``between_error`` (an error on the console, counted in ``step_errors``) if it
        raised: the step's command was sent already, the next step starts as usual."""
        if "error" in rec:
            self.step_errors += 1
            self.event("between_error", t=ts, error=rec["error"])
        elif rec.get("mpc_explore_iter", 0) > 0 or rec.get("mpc_deferred_source"):
            self.between_solves += 1
            self.between_ms_max = max(self.between_ms_max, float(rec["ms"]))
            self.jsonl.write({"kind": "between", "t": ts} | rec)

    async def stop_stepping(self) -> None:
        """Field mode: let a step in flight end (its solve is cut at the deadline), stop the
        solver workers and the step thread."""
        if self._step_task is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(asyncio.shield(self._step_task), 5.0)
        self.close_field_mode()

    def close_field_mode(self) -> None:
        """Field mode: stop the solver workers and the step thread now (a solve in flight
        is abandoned). Safe to call repeatedly, and on a field mode that failed to start."""
        task = getattr(self, "_step_task", None)  # (none: init_field_mode never ran)
        if task is not None and not task.done():
            task.cancel()  # (its thread's solve ends at the deadline, unheard)
        if self.field_mode:
            self.field_mode = False
            try:
                self.controller.close()
            finally:
                if self._step_pool is not None:
                    self._step_pool.shutdown(wait=False, cancel_futures=True)

