"""The deploy loop's phases and watchdogs (a mixin of :class:`mpcasv.io.deploy.Deploy`).

Phases: ``waiting`` (for the ASV's and every AUV's first state) -> ``starting`` (PlanControl
START FollowReference sent; waits for the answer with the same request id; retried after
``plan_start_timeout``) -> ``running``; the ASV's state older than ``asv_stale_s`` ->
``asv_stale`` (no more References), and back to ``waiting`` when states come back. The
watchdogs (every 0.25 s of the deploy clock) classify the ASV and every AUV
(:func:`mpcasv.io.watchdog.auv_status`) and move the phases. A run that ends without a
single decision says why in one line (:meth:`Phases.no_decision`: no vehicle heard, or which
one never sent a state): ``mpcasv deploy`` then exits 1.

Our maneuver, once running: DUNE answers every Reference with a FollowRefState while it runs.
Its TIMEOUT (event ``followref_timeout``: we were late) -> ``waiting``: FollowReference is
started again. A Reference left unanswered for ``link.followref_lost_s`` while the ASV's
states keep coming (event ``followref_lost``: the maneuver ended without a word to us, e.g.
an operator's stop, whose answer goes to the operator, from a DUNE whose PlanControlState does
not reach us: :mod:`mpcasv.io.planstate` reads it and ends the run at once) -> ``plan_ended``,
as below. A
PlanControl that says the running plan ended or failed (FAILURE, or SUCCESS
of a STOP or "... completed", with our request id, or our plan id and a request id we never
sent; not our own MANDONE's answer at shutdown) -> ``plan_ended`` (:meth:`Phases.
_plan_ended`): no more decisions or References, nothing restarted, the run stops
(``summary`` field ``plan_ended``: ``mpcasv deploy`` then exits 1).
"""

from __future__ import annotations

import math
import time

import imcpy

from mpcasv.io.watchdog import OK, auv_status

WAITING, STARTING, RUNNING, ASV_STALE = "waiting", "starting", "running", "asv_stale"
PLAN_ENDED = "plan_ended"  # DUNE ended our plan: nothing more is decided, sent or restarted
_PC = imcpy.PlanControl


class Phases:
    """Phase machine and watchdogs; state (``phase``, ``pending``, ``status``, ...) lives in
    the deploy loop."""

    #: events also logged as warnings on the console (the others: info, hidden by --quiet)
    WARNING_EVENTS = frozenset({"current_untested", "aborted", "clock_rate", "speed_no_way",
                                "plan_ended", "followref_lost"})

    def init_plan_watch(self) -> None:
        """The state of the plan's watch (the deploy's constructor)."""
        self.sent_requests: set[int] = set()  # request ids of our PlanControl STARTs
        self.unanswered_since: float | None = None  # first Reference no FollowRefState answered
        self.followref_lost = 0  # followref_lost events (summary)
        self.plan_ended: str | None = None  # why DUNE ended our plan, in one line (summary)
        self.ended_by_dune = False  # its PlanControl said so (else: its answers stopped)
        self.stop_event = None  # set by run(): what ends the run when DUNE ended our plan

    def _plan_control(self, msg: imcpy.PlanControl, now: float) -> None:
        info = {"type": int(msg.type), "op": int(msg.op), "request_id": msg.request_id,
                "plan_id": msg.plan_id, "info": msg.info}  # fmt: skip
        answer = msg.type in (_PC.TypeEnum.SUCCESS, _PC.TypeEnum.FAILURE)
        if (self.closing and answer and msg.request_id == self.plan_request
                and not self.ended_by_dune):  # fmt: skip
            self.event("plan_completed", **info)  # DUNE's answer to our MANDONE
            self.plan_done.set()
            return
        pending = self.pending is not None and msg.request_id == self.pending[0]
        if self.phase == RUNNING and not self.closing and self._ends_our_plan(msg):
            self._plan_ended(msg, info)
            return
        if not pending or self.phase != STARTING:
            ours = msg.request_id in self.sent_requests or msg.plan_id == self.cfg.link.plan_id
            self.event("plan_control", ours=ours, **info)
            return
        if msg.type == _PC.TypeEnum.SUCCESS:
            self.plan_request = self.pending[0]
            self.pending, self.phase, self.started = None, RUNNING, True
            self.t_next = -math.inf
            self.unanswered_since = None  # the new maneuver: no Reference sent to it yet
            self.event("plan_started", **info)
        elif msg.type == _PC.TypeEnum.FAILURE:
            self.plan_failures += 1
            self.pending, self.phase = None, WAITING
            self.retry_at = now + self.cfg.link.plan_start_timeout
            self.event("plan_start_failed", **info)

    def _ends_our_plan(self, msg: imcpy.PlanControl) -> bool:
        """Whether PlanControl ``msg`` says the running plan ended or failed: about it (our
        request id, or our plan id with a request id we never sent: an answer to one of our
        earlier STARTs, a FAILURE after a TIMEOUT, is about a plan already left), and a
        FAILURE, or a SUCCESS of a STOP (we send none) or "... completed" (DUNE's "plan
        completed"; its answers to our START, "plan loaded" and "...: executing maneuver",
        are not)."""
        ours = msg.request_id == self.plan_request or (
            msg.plan_id == self.cfg.link.plan_id and msg.request_id not in self.sent_requests)
        if not ours:
            return False
        if msg.type == _PC.TypeEnum.FAILURE:
            return True
        return msg.type == _PC.TypeEnum.SUCCESS and (
            msg.op == _PC.OperationEnum.STOP or "completed" in msg.info.lower())

    def _plan_ended(self, msg: imcpy.PlanControl, info: dict) -> None:
        """DUNE ended our plan (:meth:`_ends_our_plan`): event ``plan_ended`` (a warning),
        phase ``plan_ended`` (no more decisions, References or restarts: the plan may have
        been stopped by an operator), the run stopped; its shutdown sends no standby and
        no MANDONE (the maneuver is no longer ours), and the summary says why
        (``plan_ended``)."""
        kind = getattr(msg.type, "name", str(msg.type))
        op = getattr(msg.op, "name", str(msg.op))
        self.ended_by_dune = True
        self.event("plan_ended", **(info | {"type": kind, "op": op}),
                   note="no more decisions or References; the plan is not restarted")
        self._end_run(f"DUNE ended our FollowReference plan {msg.plan_id!r} (PlanControl "
                      f"{kind} of op {op}, request {msg.request_id}): "
                      f"{msg.info or '(no info)'}")  # fmt: skip

    def _end_run(self, why: str) -> None:
        """Phase ``plan_ended``: nothing more decided, sent or restarted; the run stopped; the
        summary's ``plan_ended`` is ``why`` (one line)."""
        self.plan_ended = f"{why}; the deploy stopped deciding and did not restart it"
        self.phase, self.unanswered_since = PLAN_ENDED, None
        if self.stop_event is not None:
            self.stop_event.set()

    def _followref_lost(self, now: float) -> None:
        """No FollowRefState for ``link.followref_lost_s`` while our maneuver runs and the ASV's
        states keep coming: the maneuver ended without a word to us. DUNE's plan engine
        answers a stop to whoever asked for it, so an operator's stop from Neptus reaches us
        only as this silence when its PlanControlState does not (:mod:`mpcasv.io.planstate`
        acts on that first): event ``followref_lost`` (a warning) and, as for
        :meth:`_plan_ended`, no more decisions or References and nothing restarted (a
        restart would undo the operator's stop); the summary's ``plan_ended`` says why. Its
        shutdown still sends the standby Reference and MANDONE (harmless if the maneuver is
        gone; if only its answers were lost, they stop the boat at once rather than at DUNE's
        ``followref_timeout``)."""
        self.followref_lost += 1
        unanswered, limit = now - self.unanswered_since, self.cfg.link.followref_lost_s
        self.event("followref_lost", vehicle=self.link.asv.label, request_id=self.plan_request,
                   unanswered_s=unanswered, limit_s=limit, count=self.followref_lost,
                   note="no FollowRefState answers our References: no more decisions or "
                   "References; the maneuver is not restarted")  # fmt: skip
        self._end_run(f"DUNE stopped answering our References (no FollowRefState for "
                      f"{unanswered:.1f} s, link.followref_lost_s {limit:g} s) while its states "
                      "kept coming: the maneuver ended without a word to us (an operator's "
                      "stop is answered to the operator)")  # fmt: skip

    def _followref_state(self, p, msg: imcpy.FollowRefState, now: float) -> None:
        """DUNE's answer to a Reference: logged with the next decisions; ours (its
        ``control_src`` our id) answers the References sent so far; its TIMEOUT restarts the
        maneuver."""
        state = getattr(msg.state, "name", str(msg.state))
        self.followref = {"state": state, "proximity": int(msg.proximity), "recv": now}
        if msg.control_src != self.link.id:
            return
        self.unanswered_since = None
        if state == "TIMEOUT" and self.phase == RUNNING:
            self.phase = WAITING
            self.event("followref_timeout", vehicle=p.label)

    def reference_sent(self) -> None:
        """A Reference went to the ASV: the watch on its answer starts if none is awaited."""
        if self.unanswered_since is None:
            self.unanswered_since = self.clock.now()

    def _followref_silent(self, now: float) -> bool:
        """Whether a Reference to our running maneuver is unanswered for longer than
        ``link.followref_lost_s`` while the ASV's states arrived for longer than that after
        it (a dropout that stops both is ``asv_stale``'s, which resumes; never in a dry run:
        nothing is sent), and no PlanControlState read since that Reference shows our plan
        still EXECUTING (:meth:`~mpcasv.io.planstate.PlanStateWatch.plan_shown_running`).

        DUNE's ``Maneuver/FollowReference`` ends the maneuver itself ``timeout`` s
        (``link.followref_timeout``, 10 s) after the last Reference it *received*
        (FollowRefState TIMEOUT, which restarts it here). With only the silence to go on,
        References lost on the way out (states still coming) ended the run at
        ``followref_lost_s`` (5 s) while DUNE still ran our maneuver and would have taken the
        next Reference that got through. DUNE's engine saying our plan executes is the
        better word: the run then waits for DUNE's own verdict (TIMEOUT: restarted; READY:
        ``plan_ended``), while that word is fresh: a PlanControlState read within
        ``followref_lost_s`` of the ASV's last state (DUNE sends one every 0.4 s; a stream
        that stops, or a DUNE clock stepped back whose reports are all "late", is no word),
        and never past ``followref_timeout + followref_lost_s`` of silence, by when DUNE's
        own timeout has stopped the maneuver whatever reached us (a review: one EXECUTING
        read after the first unanswered Reference kept a run going for ever)."""
        if self.phase != RUNNING or self.dry_run or self.unanswered_since is None:
            return False
        lost = self.cfg.link.followref_lost_s
        silence = self.link.asv.nav_recv - self.unanswered_since  # (the last state <= now)
        if silence <= lost:
            return False
        if silence > self.cfg.link.followref_timeout + lost:
            return True
        fresh = max(self.unanswered_since, self.link.asv.nav_recv - lost)
        return not self.plan_shown_running(fresh)

    # --- phases and watchdogs ------------------------------------------------------------
    def auv_ages(self, now: float) -> list[float]:
        """Each AUV's age (s, deploy clock) for the watchdogs: since its last accepted state
        or, when the estimator takes them, the last USBL fix whose position it took
        (:attr:`mpcasv.io.asvwatch.UsblFixes.recv`): an AUV out of radio contact under
        water is seen by the ASV's USBL."""
        return [now - max(p.nav_recv, self.usbl.recv[k]) for k, p in enumerate(self.link.auvs)]

    def _looks_stale(self, now: float) -> bool:
        """Whether a watchdog would fire at ``now`` on the states read so far."""
        asv = self.link.asv
        if asv.nav is not None and self.phase != ASV_STALE and not self._asv_fresh(now):
            return True
        if self._followref_silent(now):
            return True
        ages = self.auv_ages(now)
        return any(p.nav is not None and auv_status(ages[k], self.gp) != self.status[k]
                   for k, p in enumerate(self.link.auvs))  # fmt: skip

    def _asv_fresh(self, now: float) -> bool:
        return now - self.link.asv.nav_recv <= self.cfg.watchdog.asv_stale_s

    def _advance(self, now: float) -> None:
        if self.phase != WAITING or now < self.retry_at:
            return
        missing = []
        if not self._asv_fresh(now) or self.link.asv.id is None:
            missing.append(self.link.asv.label)
        missing += [p.label for p in self.link.auvs if p.nav is None]
        if missing:
            strangers = {n: f"0x{i:04X}" for n, i in self.link.strangers.items()}
            if (tuple(missing), tuple(strangers)) != self._waiting_for:
                self._waiting_for = (tuple(missing), tuple(strangers))
                # who announced but is no configured vehicle: a misspelt name, said while
                # waiting, not only in the run's last line (a new user's finding, session 41)
                self.event("waiting", missing=missing,
                           **({"announced_not_configured": strangers} if strangers else {}))
            return
        if self.dry_run:
            self.phase, self.t_next = RUNNING, -math.inf
            self.event("running", dry_run=True)
            return
        self.request_id = (self.request_id + 1) % 0x10000
        pc = imcpy.PlanControl()
        pc.type, pc.op = _PC.TypeEnum.REQUEST, _PC.OperationEnum.START
        pc.request_id, pc.plan_id, pc.flags = self.request_id, self.cfg.link.plan_id, 0
        fr = imcpy.FollowReference()
        fr.control_src, fr.control_ent = self.link.id, 0xFF
        fr.timeout, fr.loiter_radius, fr.altitude_interval = self.cfg.link.followref_timeout, 0, 0
        pc.arg = fr
        self.link.send(self.link.asv, pc)
        self.pending, self.phase = (self.request_id, now), STARTING
        self.sent_requests.add(self.request_id)
        self.plan_state_reset()  # its plan is not yet shown EXECUTING (planstate)
        self.plan_starts += 1
        self.event("plan_start_sent", request_id=self.request_id)

    def asv_back(self, p, nav, now: float) -> bool:
        """While the ASV is stale: whether its state ``nav`` (just accepted, read at ``now``)
        brings it back (phase ``waiting``, event ``asv_resumed``).

        Only a state stamped after the verdict does: after ``stale_mark``, the ASV's own clock
        at the verdict, extrapolated from its last state before it (its timestamp plus the
        deploy-clock time since it arrived). A state stamped before, read late (sent before
        the outage and queued, or sent by a vehicle process that was itself starved of CPU),
        is evidence of the past the verdict already judged silent: it is counted
        (``asv_late_states`` in the summary; event ``asv_late_state`` for the first of each
        outage) and resumes nothing. Before session 26 any state read while stale resumed
        the loop, and a killed ASV's late states were taken for it coming back.
        """
        if nav.t > self.stale_mark:
            self.phase = WAITING
            self.event("asv_resumed", vehicle=p.label, state_t=nav.t,
                       after_verdict_s=nav.t - self.stale_mark)  # fmt: skip
            return True
        self.late_states += 1
        if self._late_reported != self.stale_events:  # the first of this outage
            self._late_reported = self.stale_events
            self.event("asv_late_state", vehicle=p.label, state_t=nav.t,
                       before_verdict_s=self.stale_mark - nav.t)  # fmt: skip
        return False

    def watch(self) -> None:
        """One pass of the watchdogs (called every 0.25 s of the deploy clock).

        Before a vehicle is judged stale, the datagrams already waiting in the socket are
        read (:meth:`ImcLink.drain`): when this process had been starved of CPU, its timer
        ran before the states that had arrived meanwhile, and a fresh ASV was called stale
        (FollowReference restarted, decisions moved off the period grid).
        """
        if self.phase == PLAN_ENDED:
            return  # the run is stopping: nothing to restart
        now = self.clock.now()
        if self._looks_stale(now) and self.link.drain():
            now = self.clock.now()
        if self.phase == PLAN_ENDED:  # said in what was just read
            return
        wd = self.cfg.watchdog
        asv = self.link.asv
        if asv.nav is not None and self.phase != ASV_STALE and not self._asv_fresh(now):
            self.event("asv_stale", vehicle=asv.label, age_s=now - asv.nav_recv,
                       limit_s=wd.asv_stale_s)  # fmt: skip
            self.phase, self.pending = ASV_STALE, None
            self.stale_events += 1
            self.stale_mark = asv.nav.t + (now - asv.nav_recv)  # the ASV's clock, now
        for k, (p, age) in enumerate(zip(self.link.auvs, self.auv_ages(now), strict=True)):
            if p.nav is None:
                continue
            st = auv_status(age, self.gp)
            if st != self.status[k]:
                if st != OK:
                    self.event(f"auv_{st}", vehicle=p.label, auv=k, age_s=age)
                self.status[k] = st
        if self._followref_silent(now):  # the maneuver ended without a word to us
            self._followref_lost(now)
        if self.phase == STARTING and now - self.pending[1] > self.cfg.link.plan_start_timeout:
            self.event("plan_start_timeout", request_id=self.pending[0])
            self.phase, self.pending = WAITING, None
        self._advance(now)
        if time.monotonic() - self._load_mark[1] >= self.clock.wall_seconds(
                self.cfg.log.load_report_s):  # fmt: skip
            self.event("load", **self.load(since=self._load_mark))
            self._load_mark = (time.process_time(), time.monotonic(), self.link.datagrams)

    def heard(self) -> list[str]:
        """The vehicles heard at least once (their labels)."""
        return [p.label for p in self.link.peers if math.isfinite(p.last_heard)]

    def no_decision(self, seconds: float) -> str | None:
        """None if the run made a decision; else why not, in one line (the vehicles never
        heard, or never in state, and where we announce and listen; over TCP where we
        connect from, ``link.bind``, and the last connection error), for a run of
        ``seconds`` of the deploy clock."""
        if self.steps:
            return None
        lk, peers = self.cfg.link, self.link.peers
        speedup = self.cfg.clock.speedup
        took = f"{round(seconds, 1):g} s" + (f" of the deploy clock ([clock] speedup "
                                             f"{speedup:g})" if speedup != 1 else "")
        heard = self.heard()
        if not heard:
            of = f"no vehicle heard in {took} (of {', '.join(p.label for p in peers)})"
            if lk.transport == "tcp":  # no Announce over TCP: link.announce_to is not read
                to = ", ".join(f"{p.label} {p.spec.tcp}" for p in peers)
                err = self.link.tcp_error
                last = f" The last connection failed: {err[0]}: {err[1]}" if err else ""
                return (f"{of}: is DUNE (or mpcasv sitl --tcp) running, with its TCP backseat "
                        f"server where the 'tcp' addresses say ({to}), and reachable from "
                        f"link.bind {lk.bind} (our end of the connections)?{last}")  # fmt: skip
            ep = self.link.endpoint  # None: the link never started
            where = f"; we listen on {ep.address[0]}:{ep.address[1]}" if ep is not None else ""
            to = ", ".join(lk.announce_to) or "nowhere (link.announce_to = [])"
            return (f"{of}: is DUNE (or mpcasv sitl) running, and does it hear our Announces "
                    f"(link.announce_to: {to}{where})?")  # fmt: skip
        silent = [p.label for p in peers if p.nav is None]
        if silent:
            others = ", ".join(f"{n!r} 0x{i:04X}" for n, i in self.link.strangers.items())
            seen = f"; announced but not configured: {others}" if others else ""
            return (f"no decision in {took}: no state (EstimatedState) accepted from "
                    f"{', '.join(silent)} (heard: {', '.join(heard)}{seen}); see the 'reject' "
                    "events and counters in deploy.jsonl")  # fmt: skip
        if self.plan_starts and not self.started:  # FollowReference never ran
            asv = self.link.asv
            who = f"the configured ASV {asv.label!r}" + (f" (0x{asv.id:04X})" if asv.id is not None
                                                         else "")  # fmt: skip
            if self.plan_failures:
                return (f"no decision in {took}: {who} refused FollowReference (PlanControl "
                        f"FAILURE {self.plan_failures} of {self.plan_starts} times; its 'info' "
                        "in the 'plan_start_failed' events of deploy.jsonl)")  # fmt: skip
            return (f"no decision in {took}: {who} never answered PlanControl START "
                    f"({self.plan_starts} sent, each given link.plan_start_timeout "
                    f"{self.cfg.link.plan_start_timeout:g} s): is it the vehicle that runs "
                    "DUNE's maneuvers, the boat? (the [[vehicle]] roles swapped?)")  # fmt: skip
        return (f"no decision in {took}: every vehicle was heard, the deploy stayed in phase "
                f"{self.phase!r} (see its events in deploy.jsonl)")  # fmt: skip
