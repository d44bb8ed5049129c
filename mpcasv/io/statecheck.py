"""Plausibility checks of a vehicle's EstimatedState, with recovery from a vehicle clock step.

An exact copy of the last accepted state (the same packet, byte for byte: UDP may deliver a
datagram twice) is no new information and no fault: :class:`Duplicate` is raised, which the
link counts apart (``duplicates``) and drops silently. Otherwise a state is checked against
the vehicle's last accepted one: lat/lon in range
[``out_of_range``], within ``max_distance_m`` of the origin [``out_of_area``], newer
[``out_of_order``], not further ahead than the arrival clock allows plus ``clock_slack_s``
[``time_jump``], and not further away than the vehicle's top speed allows plus
``jump_margin_m`` [``jump``].

A vehicle's clock may step once while it runs (DUNE's ``Monitors.Clock`` sets the system
clock to GPS time after 10 fixes when it is more than 4 s off, in either direction), after
which every state fails the time checks against the last accepted one. States that fail only
the time checks are kept as a *chain* while they agree with each other on the new time base
(timestamps increasing with the arrival clock, within ``clock_slack_s``; positions within the
speed bound) and their positions agree with the last accepted state over the *arrival* time
elapsed. When ``clock_step_states`` states form such a chain *and* it arrived over at least
half the time its timestamps span, the link re-anchors on the new time base: the last of them
is accepted and :class:`ClockStep` (with the offset, new minus old time base) is reported.
The states before it stay rejected (counted); a chain broken by an inconsistent state starts
again from that state; a chain that came too fast waits for more states (an accepted state
ends it). The spread rule tells a step from late states: after a step the vehicle keeps
sending at its own rate, so arrival gaps match timestamp gaps; states held by a network stall
(or reordered) and delivered together after a newer one agree with each other and with the
last position too, but arrive as a burst, and are only ``out_of_order`` (before session 28
three of them re-anchored the link on a spurious backward step of about their lag, which
then shifted every fresh timestamp).

Re-anchoring maps the new time base back onto the old one: from then on the vehicle's
timestamps are handed on minus the (accumulated) offset, so that the deploy's decision grid
(stepped on the ASV's timestamps) and the AUV estimators (which compare the AUVs' times with
the ASV's) never see the step; ``StateTrack.offset`` holds it.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import imcpy

from mpcasv.io.config import WatchdogSpec
from mpcasv.io.geo import Origin
from mpcasv.io.imc import BadInput, NavState, nav_state

__all__ = ["ClockStep", "Duplicate", "StateTrack", "check_state"]


@dataclass(frozen=True)
class ClockStep:
    """A re-anchoring: ``offset`` s (new time base minus old, at the re-anchoring state)."""

    offset: float
    states: int  # states in the chain that proved it
    t_old: float  # last accepted timestamp on the old base
    t_new: float  # the accepted timestamp on the new base


class Duplicate(Exception):
    """The state is an exact copy of the last accepted one (not a reject: nothing is wrong)."""


@dataclass
class StateTrack:
    """Per-vehicle memory of the checks: the last accepted state and a clock-step chain."""

    nav: NavState | None = None  # last accepted state
    recv: float = -math.inf  # deploy clock when it arrived
    chain: list[tuple[NavState, float]] = field(default_factory=list)  # (state, arrival)
    offset: float = 0.0  # s subtracted from the vehicle's timestamps (its clock steps)
    raw: bytes | None = None  # the last accepted state's packet, as received


def _consistent(a: NavState, a_recv: float, b: NavState, b_recv: float, vmax: float,
                wd: WatchdogSpec) -> str | None:  # fmt: skip
    """None if ``b`` follows ``a`` plausibly (time base and speed), else the failed check."""
    dt = b.t - a.t
    arrival = b_recv - a_recv
    if dt <= 0:
        return "out_of_order"
    if dt > arrival + wd.clock_slack_s:
        return "time_jump"
    if math.hypot(b.N - a.N, b.E - a.E) > vmax * dt + wd.jump_margin_m:
        return "jump"
    return None


def _spread(chain: list[tuple[NavState, float]]) -> bool:
    """Whether the chain arrived over at least half the time its timestamps span: a vehicle
    sending on a new time base sends at its own rate; a burst of late (held, duplicated or
    reordered) states comes faster than twice that rate, however its timestamps agree."""
    (first, first_recv), (last, last_recv) = chain[0], chain[-1]
    return last_recv - first_recv >= 0.5 * (last.t - first.t)


def check_state(es: imcpy.EstimatedState, track: StateTrack, now: float, origin: Origin,
                vmax: float, wd: WatchdogSpec,
                raw: bytes | None = None) -> tuple[NavState, ClockStep | None]:  # fmt: skip
    """Check ``es`` (arrived at deploy-clock ``now``; ``raw``: its packet as received) against
    ``track``; on acceptance update ``track`` and return the state (and the clock step it
    completed, if any).

    Raises
    ------
    Duplicate
        ``raw`` is the packet of the last accepted state (the state is dropped, ``track``
        unchanged: a clock-step chain too).
    BadInput
        With the reason of the module docstring (the state is then not accepted).
    """
    if raw is not None and track.nav is not None and raw == track.raw:
        raise Duplicate
    if abs(es.lat) > math.pi / 2 or abs(es.lon) > math.pi or es.depth > 12000:
        raise BadInput("out_of_range", f"lat {es.lat} lon {es.lon} depth {es.depth}")
    nav = nav_state(es, origin)
    if track.offset:
        nav = dataclasses.replace(nav, t=nav.t - track.offset)
    if not all(map(math.isfinite, (nav.N, nav.E))):
        raise BadInput("non_finite", "position after conversion")
    if math.hypot(nav.N, nav.E) > wd.max_distance_m:
        raise BadInput("out_of_area", f"{math.hypot(nav.N, nav.E):.0f} m from the origin")
    prev = track.nav
    step = None
    if prev is not None:
        bad = _consistent(prev, track.recv, nav, now, vmax, wd)
        if bad == "jump":
            dist = math.hypot(nav.N - prev.N, nav.E - prev.E)
            raise BadInput("jump", f"{dist:.0f} m in {nav.t - prev.t:.2f} s")
        if bad is not None:
            step = _clock_step(nav, now, track, vmax, wd)
            if step is None:
                dt = nav.t - prev.t
                detail = (f"t {nav.t:.3f} <= last {prev.t:.3f}" if bad == "out_of_order"
                          else f"+{dt:.1f} s after {now - track.recv:.1f} s")  # fmt: skip
                raise BadInput(bad, detail)
            track.offset += step.offset
            nav = dataclasses.replace(nav, t=nav.t - step.offset)
    track.nav, track.recv, track.raw = nav, now, raw
    track.chain.clear()
    return nav, step


def _clock_step(nav: NavState, now: float, track: StateTrack, vmax: float,
                wd: WatchdogSpec) -> ClockStep | None:  # fmt: skip
    """Extend (or restart) the chain with ``nav``; a ClockStep once it is long enough."""
    prev = track.nav
    elapsed = now - track.recv  # arrival time since the last accepted state
    if math.hypot(nav.N - prev.N, nav.E - prev.E) > vmax * elapsed + wd.jump_margin_m:
        track.chain.clear()  # not where the vehicle can be: no evidence of a clock step
        return None
    if track.chain:
        last, last_recv = track.chain[-1]
        if _consistent(last, last_recv, nav, now, vmax, wd) is not None:
            track.chain.clear()
        elif abs((nav.t - last.t) - (now - last_recv)) > wd.clock_slack_s:
            track.chain.clear()
    track.chain.append((nav, now))
    if len(track.chain) < wd.clock_step_states or not _spread(track.chain):
        return None
    offset = nav.t - (prev.t + elapsed)
    return ClockStep(offset, len(track.chain), prev.t, nav.t)
