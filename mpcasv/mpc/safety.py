"""The MPC's safety check and what it does when a plan may not be used (docs/mpc.md,
"Fallbacks"): exploration from a guess that heads for the target, the check of the plan's
first stages against the anti-collision radii, and the rescue solves before the hybrid
controller takes the step (:mod:`mpcasv.mpc.rescue` builds the guesses). A mixin of
:class:`~mpcasv.mpc.controller.MPCController`."""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from mpcasv.interface import Command, Mode, Observation, Reason
from mpcasv.mpc.plan_check import commands_standby
from mpcasv.mpc.rescue import command_guess, escape_guess
from mpcasv.mpc.solvers import SolveResult
from mpcasv.mpc.worldview import ranges

#: a plan's range-bound slack (m) above which a plan standing by now counts as stuck
STUCK_SLACK = 1.0


class Safety:
    """Check, exploration and rescue of the MPC (mixin; state in the controller)."""

    def _explore(self, obs: Observation, p: np.ndarray, res) -> SolveResult | None:
        """Right after a target change, and while the plan stands still every ``explore_every``
        s, also solve from a guess that heads for the target AUV's circle (standing still is a
        local minimum: at rest the rudder has no authority). Returns that solve's result (None:
        no exploration due); the caller keeps the cheaper plan (:meth:`between_steps`, which
        keeps a late standby's converged one within the bounds even if dearer, or
        :meth:`_cheaper` when the warm-started plan may not be used)."""
        P, ocp = self.params, self.ocp
        if P.explore_every <= 0:
            return None
        if self.t_explore is not None and obs.t - self.t_explore < P.explore_every - 1e-9:
            return None
        if self.deadline is not None and not self._hang_guard and res.status == "deadline":
            return None  # the field budget is spent: nothing explored, no promise used up
        Z, V = ocp.split(res.w)
        late = self._late(obs.t)
        if self.t_explore is not None and res.ok and np.max(Z[1:, 6]) >= ocp.T_on:
            if not (self._stuck(Z, V) or late):
                return None  # the plan moves already
        if late:  # explored now (or already in the target domain): the next standby plan
            self.t_depart = None  # makes a new promise
        self.t_explore = obs.t
        par = ocp.unpack_par(p)
        j = self.target
        still = ranges(obs.asv.position, par["pa"])[:, j]  # the ASV held where it is
        # already there; but inside the anti-collision radius (plus margin) at some stage, as
        # when an AUV rises under the ASV, the guess heading out to the target circle is
        # needed; and a plan stuck at rest outside the bounds is explored wherever it is (the
        # target's radius held still says nothing of a current carrying a standby into
        # another AUV's domain: session 17, 104 s inside, the plan's cost growing)
        stuck = res.ok and self._stuck(Z, V)
        if not stuck and np.all(still >= par["r_lo"][:, j]) and self.domain.in_reliable_range(
                still[0], par["r_t"][j]):
            return None
        self.explored += 1
        limit = P.solver.explore_iter  # None: the warm solve's max_iter
        guided = self._solve(p, ocp.guided_rollout(p, j, self._capped(P.speed)), max_iter=limit)
        if not stuck or (guided.ok and self._slack(ocp.split(guided.w)[1]) <= STUCK_SLACK):
            return guided
        # stuck, and heading for the target found no plan within the bounds: also from the
        # escape guess (full thrust away from the AUVs that threaten it). Session 17: at its
        # target's circle, a current carrying it into another AUV's domain, the warm start
        # stayed at rest (a local minimum: the rudder has no authority there)
        esc = escape_guess(ocp, p, P.margin, self.T_cap)
        if esc is None:
            return guided
        alt = self._solve(p, esc, max_iter=limit)
        best = alt if alt.ok and (not guided.ok or alt.f < guided.f) else guided
        return dataclasses.replace(best, ms=guided.ms + alt.ms, iters=guided.iters + alt.iters)

    def _stuck(self, Z: np.ndarray, V: np.ndarray) -> bool:
        """Whether the plan (``Z``, ``V``: :meth:`OCP.split`) stands by now (the STANDBY rule)
        and is outside the range bounds now or later (a slack above ``STUCK_SLACK``, stage 0
        included: standing by outside the bounds is stuck too): a solve stuck at rest that
        puts its start off, step after step, while the AUV leaves (dune-otter on Case 3: it
        stood by from 190 m to 260 m with r_outer at 200 m, its plan's cost growing to
        2.5e5). Such a plan is explored like one that stands still; a plan that stands by and
        moves later inside the bounds (the usual standby) is not: exploring those too was
        measured on the paper suite (more propeller time, no better fix age; docs/mpc.md,
        "Controller step")."""
        ocp, P = self.ocp, self.params
        return (commands_standby(Z[:, 6], ocp.dt, P.standby_time, ocp.T_on)
                and self._slack(V) > STUCK_SLACK)

    def _slack(self, V: np.ndarray) -> float:
        """A plan's largest range-bound slack (m; ``V`` from :meth:`OCP.split`): how far it
        goes outside a bound (inside an anti-collision radius, beyond r_outer) at any stage."""
        return float(np.max(V[:, 2 : 2 + self.ocp.dims.n_auv]))

    def _late(self, t: float) -> bool:
        """Whether the ASV still stands by one stage after the first plan of this standby
        streak meant to move off (``t_depart``: the time, set by the command): each plan
        stood by now and moved later, putting its start off step after step. With several
        AUVs no range bound holds the ASV (no slack: :meth:`_stuck` cannot see it): Case 7,
        seed 1 stood by for the last 795 s of its run, drifting in a 0.29 m/s current, its
        plans moving 8-60 s later, the target AUV 400-700 m off (docs/mpc.md, "Controller
        step"). A streak spans target changes (it is the boat's standby, whatever AUV it
        serves). The exploration inside the step reads the promise before the step's command
        (the previous plan's), the one after the command (``between_steps``) after it; both
        are the same whoever calls ``between_steps``. Several AUVs only: with one the
        outer bound's slack shows a plan stuck at rest (:meth:`_stuck`), and a standby
        stretched as the AUV comes on is the usual one; explored, on Cases 1-5 (10 seeds
        each) it let a pursuer in (Case 4, seed 0: 114 s inside the collision domain against
        5 s). A late standby's exploration after the command is kept if it converged within
        the range bounds, cheaper or not (:meth:`between_steps`; session 15: cheaper alone
        left Case 6, seed 0 standing by 166 s beside an AUV that had finished, its target
        250 m off); one inside the step (a threat) only if cheaper."""
        return (self.multi and self.t_depart is not None
                and t > self.t_depart + self.ocp.dt + 1e-9)

    @staticmethod
    def _cheaper(res: SolveResult, alt: SolveResult | None) -> SolveResult:
        """The exploration's plan ``alt`` if it converged and costs less (or ``res`` did not
        converge), else ``res``; the two solves' time and iterations summed."""
        if alt is None:
            return res
        best = alt if alt.ok and (not res.ok or alt.f < res.f) else res
        return dataclasses.replace(best, ms=res.ms + alt.ms, iters=res.iters + alt.iters)

    def between_steps(self) -> None:
        """The periodic exploration solve (while the plan stands still) of the step just
        taken, run after its command was handed over, in the idle part of the control period
        (simulator and deploy loop call this after each ``step``; a ``step`` called first
        runs it itself, so the decisions never depend on whether, or when, it was called).
        If its plan is cheaper than the one the step used (or converged and within the range
        bounds, for a standby past its promise: :meth:`_late`), the next step is warm-started
        from it instead: taken one control period later than if it were solved within the
        step, and the step's latency is the warm-started solve alone. (After a target
        change, with a threat, or when the step's plan may not be used, the exploration
        runs inside the step: deferring those cost Case 8 39 s of reliable-fix age p95.) In
        the field it has the step's budget (``solver.budget_ms``) of its own. docs/mpc.md,
        "Controller step". Before it, a carried step's work (``solver.step_iter``,
        :mod:`mpcasv.mpc.carry`), with a field budget of its own."""
        if self.deferred is not None:  # a carried step's work first (mpc/carry.py)
            self._t_step = time.perf_counter()  # the field deadline of its solves
            self._finish_deferred()
            self._note_over_budget()
        pending, self._pending = self._pending, None
        if pending is None:
            return
        obs, p_s, res = pending
        self._t_step = time.perf_counter()  # the field deadline of this solve
        late = self._late(obs.t)  # read first: an exploration makes the next promise anew
        alt = self._explore(obs, p_s, res)
        if alt is None:
            return
        # the next step starts from the exploration's plan if it is cheaper; an unconverged
        # one too (at its iteration limit, finite): only a start, as any unconverged iterate
        # (``warm_from_failures``), and the way out of a plan stuck at rest that costs more
        # every step while each exploration stops at its limit far cheaper (docs/mpc.md).
        # A standby past its promise (several AUVs, :meth:`_late`) keeps the promise: the
        # exploration's converged plan, heading for the target, is taken even if dearer
        # (each plan put its start off, priced only over the horizon; docs/mpc.md), unless
        # it leaves the range bounds (a way through an AUV's domain is never kept dearer)
        kept = late and alt.ok and self._slack(self.ocp.split(alt.w)[1]) <= STUCK_SLACK
        adopt = kept or (alt.f < res.f and (alt.ok or bool(np.all(np.isfinite(alt.w)))))
        if adopt:
            self.w_prev, self.w_ok = alt.w, alt.ok
            self.lam_prev = (alt.lam_x, alt.lam_g) if alt.ok else None
        self.explore_adopted += int(adopt)
        self._note_over_budget()
        self._diag |= {"mpc_explore_ms": alt.ms, "mpc_explore_iter": alt.iters,
                       "mpc_explore_cost": alt.f, "mpc_explore_adopted": int(adopt),
                       "mpc_hung": self._hung}  # fmt: skip

    def _note_over_budget(self) -> None:
        """Work after the command that took longer than a step's budget (since ``_t_step``):
        its step counts as over budget, once (a diagnostic, never a decision)."""
        step_over = int(self._diag.get("mpc_over_budget", 0))
        over = self._over_budget()
        self.over_budget += int(over and not step_over)
        self._diag["mpc_over_budget"] = max(step_over, over)

    def _work(self, obs: Observation, p_s: np.ndarray, p: np.ndarray, res: SolveResult,
              hybrid_cmd: Command) -> tuple[SolveResult, str | None, str]:  # fmt: skip
        """The step's work after its warm-started solve ``res`` (``p_s``: the parameters
        solved, ``p``: checked): the safety check, the exploration when it belongs in the
        step, the rescue. Returns ``(result, reason the plan may not be used or None,
        source)``."""
        reason = self._check(res, p)
        # the exploration now when the plan may not be used (before any rescue, as part of
        # it), right after a target change, or when an AUV threatens the ASV held where it is;
        # else (the periodic one while the plan stands still) after the command
        here = obs.asv.position
        if (reason is not None or self.t_explore is None
                or self._transit_reason(here, self.ocp.unpack_par(p)) is Reason.AVOIDANCE):
            alt = self._explore(obs, p_s, res)
            if (alt is not None and not alt.ok and res.ok and alt.f < res.f
                    and np.all(np.isfinite(alt.w)) and self._stuck(*self.ocp.split(res.w))):
                # a plan stuck at rest, and an exploration cheaper but at its iteration limit:
                # not this step's plan, but the next step's start, as after the command
                # (between_steps). Without it an ASV at rest inside an AUV's domain stayed
                # there: each exploration stopped at its limit far cheaper, each warm solve
                # converged back to rest (session 17)
                self._alt_start = alt.w
            res = self._cheaper(res, alt)
            reason = self._check(res, p)
        else:
            self._pending = (obs, p_s, res)
        source = "plan" if reason is None else "fallback"
        # rescue, except after a missed field deadline (no time left); after a hang in
        # simulation too (the Case 4 problem that hangs fatrop converges from the escape guess)
        if reason is not None and (res.status != "deadline" or self._hang_guard):
            res, reason, source = self._rescue(obs, p_s, p, res, reason, hybrid_cmd)
        return res, reason, source

    def _violation_now(self, p: np.ndarray) -> float:
        """How far (m) the ASV is outside the plan's range bounds now (0 inside)."""
        par = self.ocp.unpack_par(p)
        z0 = par["z0"]
        d = ranges(z0[0:2], par["pa"][0])
        gap = np.maximum(par["r_lo"][0] - d, 0.0)
        if not self.multi:
            gap = np.maximum(gap, d - par["r_hi"][0])
        return float(np.max(gap))

    def _check(self, res, p) -> str | None:
        """Why this step's plan may not be used (None: it may)."""
        sp = self.params.solver
        if not res.ok and res.status == "deadline" and self._hang_guard:
            return f"solver hung: no answer within {sp.hang_s:g} s of CPU time (hang guard)"
        if not res.ok and res.status == "deadline":
            return f"deadline: no plan within the step's {sp.budget_ms:g} ms (field mode)"
        if not res.ok:
            return f"solver: {res.status}"
        # already inside (a pursuer caught up): a plan that gets out of the way is the best
        # there is; one that goes deeper is not
        if self._depth(res.w, p) > sp.check_margin:
            return "plan enters the anti-collision radius"
        return None

    def _depth(self, w: np.ndarray, p: np.ndarray) -> float:
        """How far (m) the plan ``w`` goes both inside an anti-collision radius (r_lo without
        the margin) and deeper than the ASV is now, within its first ``check_stages`` stages
        (0: nowhere). The safety check refuses a plan when this exceeds ``check_margin``."""
        Z, _ = self.ocp.split(w)
        par = self.ocp.unpack_par(p)
        n = min(self.params.solver.check_stages, self.ocp.dims.N) + 1
        dist = ranges(Z[:n, 0:2], par["pa"][:n])
        inside = par["r_lo"][1:n] - self.params.margin - dist[1:]
        deeper = dist[0] - dist[1:]
        return float(max(np.max(np.minimum(inside, deeper)), 0.0))

    def _rescue(self, obs: Observation, p_s: np.ndarray, p: np.ndarray, res: SolveResult,
                reason: str, hybrid_cmd: Command):  # fmt: skip
        """The warm-started plan cannot be used (``reason``): solve again, within
        ``solver.rescue_iter`` iterations each, from the unconverged iterate (solver failure),
        from the escape guess (full thrust away from the AUVs near the ASV, when there are
        any) and from the hybrid controller's command, in this order; the first plan that
        passes the check is used. None passes: a converged plan that goes no deeper than the
        escape manoeuvre's rollout (within ``check_margin``) is used (the hybrid controller
        could not do better: source ``as-escape``); else the escape manoeuvre itself (source
        ``escape``); with no AUV near, the hybrid controller's command (``fallback``).

        Returns ``(result, reason or None, source)``; ``p_s`` the solved parameters (funnel),
        ``p`` those the check uses. docs/mpc.md, "Fallbacks"."""
        P, ocp = self.params, self.ocp
        esc = escape_guess(ocp, p_s, P.margin, self.T_cap)
        starts = []
        if not res.ok and res.status != "deadline" and np.all(np.isfinite(res.w)):
            starts.append(res.w)  # (a hung solve's "iterate" is its start: not again)
        if esc is not None:
            starts.append(esc)
        wp = None if hybrid_cmd.mode is Mode.STANDBY else hybrid_cmd.waypoint
        starts.append(command_guess(ocp, p_s, wp, self._capped(hybrid_cmd.speed or P.speed)))
        tried, ms, iters = [], res.ms, res.iters
        for w0 in starts:
            if self.deadline is not None and not self._hang_guard and self._left() <= 0.0:
                break  # the field budget is spent
            r = self._solve(p_s, w0, max_iter=P.solver.rescue_iter)
            ms, iters = ms + r.ms, iters + r.iters
            if r.status == "deadline" and not self._hang_guard:
                break  # field budget spent (a hang in simulation: try the next start)
            if r.ok:
                tried.append(r)
                if self._check(r, p) is None:  # the first usable plan ends the rescue
                    self.rescues += 1
                    return dataclasses.replace(r, ms=ms, iters=iters), None, "rescue"
        self.rescues += 1
        if esc is not None:
            d_esc = self._depth(esc, p)
            if tried:
                best = min(tried, key=lambda r: self._depth(r.w, p))
                if self._depth(best.w, p) <= d_esc + P.solver.check_margin:
                    return dataclasses.replace(best, ms=ms, iters=iters), None, "as-escape"
            return (SolveResult(esc, None, None, math.nan, False, "escape", iters, ms), None,
                    "escape")  # fmt: skip
        if tried:  # converged, but into the radius, with no AUV near: cannot happen often
            res = min(tried, key=lambda r: self._depth(r.w, p))
            reason = self._check(res, p) or reason
        return dataclasses.replace(res, ms=ms, iters=iters), reason, "fallback"
