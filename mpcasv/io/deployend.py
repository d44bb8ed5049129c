"""How a deploy ends (:class:`Ending`, a mixin of :class:`mpcasv.io.deploy.Deploy`; state
there): the shutdown after Ctrl-C / SIGTERM or ``duration`` (the final standby and MANDONE,
DUNE's "plan completed" awaited), the ``summary`` record, the abort of a run that failed or
was cancelled, and :meth:`Ending.close`, which releases the sockets, the solver workers and
the logs on every way out (docs/deploy.md)."""

from __future__ import annotations

import asyncio
import logging

import imcpy

from mpcasv.interface import Command
from mpcasv.io.imc import RF, reference

__all__ = ["Ending"]

log = logging.getLogger("mpcasv.deploy")


class Ending:
    """Shutdown, summary, abort and close of the deploy loop (mixin)."""

    def begin_shutdown(self) -> bool:
        """Stop deciding and listening for vehicles, then the final standby and MANDONE (if
        we ever started FollowReference, and DUNE has not said it ended it: after its
        ``plan_ended`` the maneuver is no longer ours to command). True if MANDONE was sent."""
        self.closing = True
        self.link.stop_receiving()
        asv = self.link.asv
        if self.dry_run or not self.started or asv.id is None or self.ended_by_dune:
            return False
        here = (asv.nav.N, asv.nav.E) if asv.nav is not None else (0.0, 0.0)
        self.link.send(asv, reference(Command.standby(), here, self.link.origin))
        done = imcpy.Reference()
        done.flags = RF.MANDONE
        self.link.send(asv, done)
        self.event("final_standby", mandone=True, request_id=self.plan_request)
        return True

    async def finish(self) -> dict:
        """Close the link, stop the solver workers, then write ``summary`` (the last record)
        and close the logs."""
        await asyncio.sleep(0.05)  # let the last datagrams leave
        await self.link.stop()
        await self.stop_stepping()
        summary = self.write_summary()
        self.close()
        return summary

    def write_summary(self, **extra) -> dict:
        """Write the ``summary`` record (the last one: the link is closed and nothing is
        decided any more) with ``extra`` fields; return it."""
        summary = {"steps": self.steps, "overrides": self.overrides,
                   "skipped_steps": self.skipped_steps, "step_errors": self.step_errors,
                   "between_solves": self.between_solves,
                   "between_ms_max": round(self.between_ms_max, 3),
                   "asv_stale_events": self.stale_events, "asv_late_states": self.late_states,
                   "plan_completed": self.plan_done.is_set(), "load": self.load(),
                   "heard": self.heard(), "usbl_fixes": list(self.usbl.counts),
                   "usbl_fixes_unmatched": dict(self.usbl.unmatched),
                   "usbl_fix_positions": list(self.usbl.positions),
                   "usbl_fix_outliers": list(self.usbl.outliers),
                   "estimator_reordered": [e.reordered for e in self.estimators],
                   "estimator_dropped": [e.dropped for e in self.estimators],
                   "followref_lost": self.followref_lost,
                   "plan_state_late": self.plan_state_late, **self.link.counters()}  # fmt: skip
        why = self.no_decision(self.clock.now() - self.t_started)
        if why is not None:
            summary["no_decision"] = why
        if self.plan_ended is not None:  # DUNE ended our plan: mpcasv deploy exits 1
            summary["plan_ended"] = self.plan_ended
        summary |= extra
        self.jsonl.write({"kind": "summary", "t": self.clock.now(), **summary})
        self._summary_written = True
        return summary

    def abort(self, exc: BaseException) -> None:
        """A run that failed or was cancelled (not stopped): event ``aborted`` (``reason``:
        ``"cancelled"``, or the exception's type and first line), the ``summary`` with the
        same ``aborted`` field, then :meth:`close`. Nothing is waited for and nothing more
        is sent: no final standby, no MANDONE (a FollowReference we had started ends on
        DUNE's ``link.followref_timeout``, as after an ``asv_stale``); a solve in flight is
        abandoned. After the summary (the run had finished): only :meth:`close`."""
        if isinstance(exc, asyncio.CancelledError):
            reason = "cancelled"
        else:
            reason = f"{type(exc).__name__}: {exc}".splitlines()[0]
        try:
            if not self._summary_written:
                self.closing = True
                self.event("aborted", reason=reason)
                self.link.close()
                self.close_field_mode()
                self.write_summary(aborted=reason)
        except Exception:  # the exception that aborted the run is the one to raise
            log.warning("the aborted run's event or summary could not be written",
                        exc_info=True)  # fmt: skip
        finally:
            self.close()

    def close(self) -> None:
        """Release what the deploy holds, without its shutdown: the link's sockets, the
        solver workers and the step thread (field mode), the log files. Safe to call
        repeatedly, and on a deploy that never ran; :meth:`run` closes on every way out.
        Also ``with Deploy(...) as deploy:``."""
        try:
            if self.link is not None:
                self.link.close()
            self.close_field_mode()
        finally:
            for f in (self.jsonl, self.lsf, self.lock):
                if f is not None:
                    f.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    async def shutdown(self) -> dict:
        """:meth:`begin_shutdown`, wait for DUNE's "plan completed" (at most
        ``link.plan_done_timeout``), :meth:`finish`."""
        if self.begin_shutdown():
            wait = self.clock.wall_seconds(self.cfg.link.plan_done_timeout)
            try:
                await asyncio.wait_for(self.plan_done.wait(), wait)
            except TimeoutError:
                self.event("plan_done_timeout", timeout_s=self.cfg.link.plan_done_timeout)
        return await self.finish()
