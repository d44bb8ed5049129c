"""The surge-speed reference model's turns (``mpcasv tune speed``): thesis eq. 3.1,
``u_cmd = u_ff + k_u (pi/2 - |psi_e|)`` (``u_ff`` if ``|psi_e| >= pi/2``), checked on the
nonlinear closed loop. Starting at full speed, turns of 90 and 180 deg towards a waypoint at a
fixed distance must reach it (within :data:`ARRIVAL_RADIUS`) without
"pirouettes" (circling the waypoint instead of reaching it: :data:`PIROUETTE_TURN`); the grid
of ``(u_ff, k_u)`` pairs, the recommendation under the ``u_cmd,max`` bound and the pirouette
check (a hard turn while accelerating). Split from :mod:`mpcasv.control.tuning_speed` (which
re-exports these names) to keep modules to one reading.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from mpcasv.config import replace
from mpcasv.control.params import ExecutionParams, SpeedReference
from mpcasv.control.tuning import run_closed_loop, settling_time
from mpcasv.models.vessel import VesselModel

#: heading band that counts as "on course" (rad)
TURN_BAND = math.radians(10.0)
#: radius of the acceptance circle (m): a turn has reached its waypoint once the boat is this
#: close to it, and the turn's figures stop there. A fixed choice for every vessel, stated in
#: speed.md beside the vessel's length: about one hull length of Gretha (5.2 m, PAPER-FACTS
#: §1), where the line-of-sight heading to a point under the bow stops meaning anything. Not
#: the vessel's own length (a review asked): the Otters' 2 m is inside their turning circle at
#: speed, and after passing the waypoint they orbit it 2-5 m away, turning for the rest of the
#: run; that holding would count as circling (:func:`circling`) and made 41 of 152 measured
#: dune-otter turns pirouettes (with Gretha's yaw gains, every pair of the default grid),
#: though each had come within 2 m of its waypoint. The circle has to hold the boat's
#: turn back, not its hull.
ARRIVAL_RADIUS = 5.0
#: heading change (rad) with the heading error outside :data:`TURN_BAND` before the boat heads
#: for the waypoint (beyond the commanded turn; :func:`circling`) that makes a pirouette: one
#: full circle. A boat whose
#: turning circle leaves the waypoint outside points its bow at it within one revolution (its
#: heading sweeps every direction while the line of sight to the waypoint moves less); one that
#: turns a full circle without doing so circles the waypoint instead of reaching it, the
#: pirouettes of thesis §3.4.1 ("pirouettes instead of following its set-point ... not able to
#: achieve its desired heading")
PIROUETTE_TURN = 2 * math.pi
#: time (s) :func:`turn` allows for the turn itself (the fixed run length until a review; the
#: default grid's slowest turn is done in 89 s); :func:`turn_time` adds the straight run
TURN_T_END = 150.0
#: longest run (s) of a turn (:func:`turn_time`): a ``--distance`` or ``--u-ff`` asking for
#: more is refused (:func:`distance_refusal`); ``--distance 1e9`` ran for ever (a review)
TURN_RUN_MAX = 1800.0


def in_circle(dist, radius: float = ARRIVAL_RADIUS):
    """Whether a distance ``dist`` (m, array or number) from the waypoint is within the
    arrival circle of ``radius`` m, its edge included: the one definition of "inside" for
    :func:`arrival`, the pirouette rule and the refusal of a ``--distance`` not beyond it."""
    return dist <= radius


def arrival(X: np.ndarray, wp, radius: float = ARRIVAL_RADIUS) -> tuple[np.ndarray, int]:
    """The distances (m, shape (n,)) of the states ``X`` (rows ``[N, E, ...]``) from the
    waypoint ``wp`` and the index of the first within ``radius`` m (``n`` if none): the one
    definition of "reached" for the turns, their rule and their plots."""
    dist = np.hypot(X[:, 0] - wp[0], X[:, 1] - wp[1])
    near = in_circle(dist, radius)
    return dist, int(np.argmax(near)) if near.any() else len(dist)


def headed_for(psi_e: np.ndarray, dist: np.ndarray, start: int, radius: float) -> int:
    """The first index from ``start`` at which the boat heads for the waypoint: its heading
    error ``psi_e`` (rad) is within :data:`TURN_BAND` and stays below pi/2 (the boat keeps
    closing on the waypoint, as seen from its bow: eq. 3.1's ``|psi_e| < pi/2``) until it is
    next within ``radius`` m of it (``dist``, m), or to the end of the run; ``len(psi_e)`` if
    never. A heading that only sweeps through the band (a boat spinning through its heading)
    is not heading for the waypoint: the rule cut its stretches there, so 1199 deg of spin
    counted as 339 deg (a review); a boat that heads for it and wobbles out of the band on the
    way (Gretha turning back after passing it: on course, then 16 deg off as she speeds up)
    still is."""
    err = np.abs(psi_e)
    on, closing = err <= TURN_BAND, err < math.pi / 2  # a non-finite error is neither
    m = len(err)
    inside = np.flatnonzero(in_circle(dist[start:], radius)) + start
    i = start
    while i < m:
        if not on[i]:
            i += 1
            continue
        nxt = inside[inside >= i]
        stop = int(nxt[0]) if len(nxt) else m  # the next arrival (or the end)
        away = np.flatnonzero(~closing[i:stop])
        if not len(away):
            return i
        i += int(away[0])
    return m


def circling(run, wp, angle: float, radius: float = ARRIVAL_RADIUS) -> float:
    """The heading change (rad) the boat of ``run`` turned without heading for the waypoint
    ``wp`` (:func:`headed_for`: on course, ``|psi_e| <= TURN_BAND``, and staying so until it
    is next within ``radius`` m of it), the larger of two parts:

    * the approach, until the first arrival within ``radius`` (the line of sight to a
      waypoint under the bow swings round as the boat passes it): every heading change made
      off course before the boat heads for it, less the commanded turn ``|angle|``;
    * after the arrival, from the first sample back outside the circle until the boat heads
      back for the waypoint: the heading change made off course outside the circle. A boat
      that has reached the waypoint and turned back towards it is not circling it, nor one
      that orbits inside the circle (a small hull that passed it: every dune-otter turn read
      as a pirouette, a review), while one that loops round it, passing near it each time
      (Gretha without eq. 3.1), is.

    More than :data:`PIROUETTE_TURN` is a pirouette. (Until a review each stretch off course
    was counted alone, cut wherever the heading error swept through the band: a boat spinning
    in place, its bow crossing the waypoint's bearing once a turn, was never flagged.)"""
    dist, n = arrival(run.X, wp, radius)
    out = ~(np.abs(run.psi_error) <= TURN_BAND)  # a non-finite error is outside
    dpsi = np.abs(np.diff(np.unwrap(run.X[:, 2])))  # dpsi[k]: from sample k to k + 1
    k = np.arange(len(dpsi))
    j = headed_for(run.psi_error[:n], dist[:n], 0, radius)
    worst = float(np.sum(dpsi[(k < j) & out[:-1]])) - abs(angle)
    # after the arrival, from the first sample back outside the circle: off course until it
    # heads back, outside the circle (from the arrival itself, the heading error of that one
    # sample decided whether any of it counted: within 10 deg, the boat was "heading back"
    # at once, a review)
    again = np.flatnonzero(~in_circle(dist[n:], radius)) + n
    if len(again):
        o = int(again[0])
        back = headed_for(run.psi_error, dist, o, radius)
        sel = (k >= o) & (k < back) & out[:-1] & ~in_circle(dist[:-1], radius)
        worst = max(worst, float(np.sum(dpsi[sel])))
    return max(worst, 0.0)


def distance_refusal(distance: float, u_slow: float | None = None,
                     radius: float = ARRIVAL_RADIUS) -> str | None:  # fmt: skip
    """Why a turn to a waypoint ``distance`` m away cannot be run (None if it can), the one
    rule and message of :func:`turn` and ``--distance``'s refusal: at or inside the arrival
    circle of ``radius`` m (:func:`in_circle`), where the boat starts, so every turn is
    reached at once (0.0 s over 0.0 m, and recommended, a review); or, with ``u_slow`` the
    run's slowest speed (m/s, ``min(u_ff, u_max)``), a run (:func:`turn_time`) longer than
    :data:`TURN_RUN_MAX`. A distance that is not a finite number (NaN, inf) is refused first:
    ``NaN <= radius`` is False, so it passed the arrival circle's rule (a review)."""
    if not math.isfinite(distance):
        return (f"{distance:g} m: not a finite number; distances must be finite and exceed "
                f"{radius:g} m")  # fmt: skip
    d = _digits(distance, lambda v: v == distance)
    if in_circle(distance, radius):
        return (f"{d} m: at or inside the {radius:g} m arrival circle, where the boat "
                "starts: every turn would be reached at once (0 s, 0 m); distances must exceed "
                f"{radius:g} m")  # fmt: skip
    if u_slow is not None and TURN_T_END + distance / u_slow > TURN_RUN_MAX:
        # the digits to show the run above the cap and the longest distance not above the
        # refused one ("= 1800 s, above the 1800 s cap; at most 660 m" for 660.0001, a review)
        t, most = TURN_T_END + distance / u_slow, (TURN_RUN_MAX - TURN_T_END) * u_slow
        u = _digits(u_slow, lambda v: v == u_slow)
        return (f"{d} m: a turn would run {TURN_T_END:g} s + {d} m / "
                f"{u} m/s (min(u_ff, u_max)) = {_digits(t, lambda v: v > TURN_RUN_MAX)} "
                f"s, above the {TURN_RUN_MAX:g} s cap; at {u} m/s distances must be at "
                f"most {_digits(most, lambda v: v <= most and v < distance)} m (or give a "
                "larger --u-ff)")  # fmt: skip
    return None


def _digits(x: float, shows) -> str:
    """``x`` with the fewest significant digits (4 at least) whose value ``shows`` holds for,
    e.g. above a cap it is compared with; Python's shortest round trip if none does."""
    for p in range(4, 18):
        text = f"{x:.{p}g}"
        if shows(float(text)):
            return text
    return repr(x)


def turn_time(model: VesselModel, ep: ExecutionParams, distance: float) -> float:
    """Length (s) of :func:`turn`'s run to a waypoint ``distance`` m away: :data:`TURN_T_END`
    for the turn, plus the straight run to the waypoint at the slowest speed eq. 3.1 asks
    for, ``min(u_ff, u_max)`` (m/s; ``u_cmd = u_ff`` from ``|psi_e| >= pi/2``). With a fixed
    150 s a waypoint 400 m away was "not reached" (NR) by every pair: a property of the run,
    not of the tuning (a review). At most :data:`TURN_RUN_MAX` (:func:`distance_refusal`)."""
    return TURN_T_END + distance / min(ep.reference.u_ff, model.params.u_max)


def turn(model: VesselModel, ep: ExecutionParams, angle: float, distance: float,
         t_end: float | None = None, u0: float | None = None,
         radius: float | None = None):  # fmt: skip
    """Turn by ``angle`` (rad) from full speed (or trim at ``u0``; the speed integrator at its
    trim value, :func:`trim_integrator`) towards a waypoint ``distance`` m away, for ``t_end``
    s (default :func:`turn_time`); reached within ``radius`` m (default
    :data:`ARRIVAL_RADIUS`). Eq. 3.1 (``ep.reference``) sets the speed
    reference ``u_ff + k_u (pi/2 - |psi_e|)``, the command is ``u_max``.

    Returns the run and ``{"turn_s", "turn_m", "reached", "reach_s", "pirouette",
    "circling_deg", "total_turn_deg", "min_u", "radius", "t_end"}``: time (s) and path length
    (m) until the turn is done, i.e. the heading error stays within :data:`TURN_BAND` until
    the arrival, or the boat is within ``radius`` of the waypoint, whichever comes first
    (``inf`` if neither within ``t_end``); whether and when (s) it reached that circle; the
    heading change (deg) until the turn was done; :func:`circling` (deg) and whether it
    pirouetted (more than :data:`PIROUETTE_TURN`); the least surge speed (m/s) until the turn
    was done; the radius (m) and run length (s) used. ValueError for a waypoint
    :func:`distance_refusal` refuses (the run length only when ``t_end`` is not given).
    """
    radius = ARRIVAL_RADIUS if radius is None else radius
    u_slow = min(ep.reference.u_ff, model.params.u_max) if t_end is None else None
    why = distance_refusal(distance, u_slow, radius)
    if why:
        raise ValueError(f"waypoint {why}")
    from mpcasv.control.tuning_speed import trim_integrator

    t_end = turn_time(model, ep, distance) if t_end is None else t_end
    if u0 is None:
        u0 = min(model.top_speed, model.params.u_max)
    x0, _ = model.trim(u0)
    wp = (distance * math.cos(angle), distance * math.sin(angle))
    run = run_closed_loop(model, ep, x0, wp, model.params.u_max, t_end,
                          I_u=trim_integrator(model, u0))  # fmt: skip
    _, n = arrival(run.X, wp, radius)
    reached = n < len(run.t)
    ts = settling_time(run.t[:n], run.psi_error[:n], TURN_BAND)  # on course until the arrival
    if reached and not ts < run.t[n]:
        ts = float(run.t[n])
    i = int(round(ts / (run.t[1] - run.t[0]))) if math.isfinite(ts) else len(run.t) - 1
    total = float(np.sum(np.abs(np.diff(np.unwrap(run.X[: i + 1, 2])))))
    circ = circling(run, wp, angle, radius)
    return run, {
        "turn_s": ts,
        "turn_m": float(run.distance[i]) if math.isfinite(ts) else math.inf,
        "reached": reached,
        "reach_s": float(run.t[n]) if reached else math.inf,
        "pirouette": bool(circ > PIROUETTE_TURN),
        "circling_deg": float(np.degrees(circ)),
        "total_turn_deg": float(np.degrees(total)),
        "min_u": float(run.X[: i + 1, 3].min()),
        "radius": radius,
        "t_end": float(t_end),
    }


@dataclasses.dataclass(frozen=True)
class TurnRow:
    """One (u_ff, k_u) pair of the reference-model grid."""

    u_ff: float
    k_u: float
    figures: dict  # angle_deg -> turn() figures

    @property
    def ok(self) -> bool:
        """Every turn reached its waypoint (within :data:`ARRIVAL_RADIUS`) without a
        pirouette (:data:`PIROUETTE_TURN`)."""
        return all(f["reached"] and not f["pirouette"] for f in self.figures.values())

    @property
    def cost(self) -> float:
        """Sum of the turn times (s): :func:`recommend` minimises it among the rows that are
        :attr:`ok` and within the ``u_cmd,max`` bound."""
        return float(sum(f["turn_s"] for f in self.figures.values()))


def turn_grid(model: VesselModel, ep: ExecutionParams, pairs, angles_deg=(90.0, 180.0),
              distance: float = 50.0, progress: bool = False):  # fmt: skip
    """Run :func:`turn` for each (u_ff, k_u) pair and angle; returns rows and runs."""
    from tqdm import tqdm

    rows, runs = [], {}
    for u_ff, k_u in tqdm(list(pairs), desc="turn grid", disable=not progress):
        epi = replace(ep, reference=SpeedReference(u_ff=u_ff, k_u=k_u))
        figs = {}
        for a in angles_deg:
            runs[(u_ff, k_u, a)], figs[a] = turn(model, epi, math.radians(a), distance)
        rows.append(TurnRow(u_ff=u_ff, k_u=k_u, figures=figs))
    return rows, runs


def merge_grids(grids: dict) -> list[TurnRow]:
    """One row per (u_ff, k_u) with the turns of every distance of ``grids`` (``{distance:
    (rows, runs)}`` of :func:`turn_grid`; the last row of each, the baseline without the
    reference model, left out), figures keyed ``"<distance>m/<angle>"``."""
    by_pair: dict = {}
    for d, (rows, _) in grids.items():
        for r in rows[:-1]:
            figs = by_pair.setdefault((r.u_ff, r.k_u), {})
            figs.update({f"{d}m/{a}": f for a, f in r.figures.items()})
    return [TurnRow(u_ff=a, k_u=b, figures=f) for (a, b), f in by_pair.items()]


def u_cmd_max(u_ff: float, k_u: float) -> float:
    """Eq. 3.1's largest speed command, at zero heading error: ``u_ff + k_u pi/2`` (m/s)."""
    return u_ff + k_u * math.pi / 2


#: relative slack of the ``u_cmd,max`` bound, so that the bound a pair itself sets admits it
U_CMD_MAX_RTOL = 1e-6


def within(u_ff: float, k_u: float, bound: float) -> bool:
    """Whether eq. 3.1's largest command :func:`u_cmd_max` is at most ``bound`` (m/s), with
    :data:`U_CMD_MAX_RTOL` of slack (the bound a pair itself sets admits it)."""
    return u_cmd_max(u_ff, k_u) <= bound * (1 + U_CMD_MAX_RTOL)


def admitted(rows: list[TurnRow], bound: float) -> list[TurnRow]:
    """The rows whose :func:`u_cmd_max` is at most ``bound`` (m/s). The thesis chose ``k_u``
    for a given ``u_ff`` to hold ``u_cmd,max`` at the boat's rated maximum speed (§3.4.1:
    ``u_ff`` 0.4 -> 0.6 m/s with ``k_u`` 1.72 -> 1.59 m/s "to maintain the maximum commanded
    speed", 3.1 m/s), and found lower ``k_u`` more stable: the turn times alone only fall as
    ``k_u`` grows, so without the bound the grid's largest ``k_u`` always won."""
    return [r for r in rows if within(r.u_ff, r.k_u, bound)]


def recommend(rows: list[TurnRow], bound: float = math.inf) -> TurnRow:
    """Among the rows :func:`admitted` under ``bound`` (m/s) whose turns all reached the
    waypoint without a pirouette (:attr:`TurnRow.ok`), the one with the least total turn
    time; ValueError if none."""
    good = [r for r in admitted(rows, bound) if r.ok]
    if not good:
        raise ValueError(why_none(rows, bound))
    return min(good, key=lambda r: r.cost)


def why_none(rows: list[TurnRow], bound: float) -> str:
    """Why :func:`recommend` found no pair: of the rows :func:`admitted` under ``bound``
    (m/s), each counted once, how many pirouetted in some turn (P), how many missed a waypoint
    in the run (NR), and how many did both. The summary said "no pair of the grid reached
    every waypoint" when every pair had reached every waypoint and pirouetted, and then "of
    the 1 (u_ff, k_u) pairs ... 1 pirouetted (P) and 1 did not reach (NR)", one pair read as
    two (reviews)."""
    ok = admitted(rows, bound)
    both = pir = nr = 0
    for r in ok:
        p = any(f["pirouette"] for f in r.figures.values())
        n = any(not f["reached"] for f in r.figures.values())
        both, pir, nr = both + (p and n), pir + (p and not n), nr + (n and not p)
    parts = [f"{pir} pirouetted in a turn (P)"] if pir else []
    parts += [f"{nr} did not reach a waypoint within the run (NR)"] if nr else []
    parts += [f"{both} did both (P and NR)"] if both else []
    text = ", ".join(parts[:-1]) + (" and " if len(parts) > 1 else "") + (parts[-1] if parts
                                                                         else "none passed")
    pairs = "pair" if len(ok) == 1 else "pairs"
    return (f"of the {len(ok)} (u_ff, k_u) {pairs} of the grid with u_ff + k_u pi/2 <= "
            f"{bound:.4g} m/s, {text}: no recommendation")


def edge_notes(best: TurnRow, rows: list[TurnRow], bound: float) -> list[str]:
    """Where the recommendation ``best`` sits on the grid ``rows``: on its edge (the largest
    or smallest ``u_ff`` or ``k_u`` given: the optimum may lie beyond, a warning), or with
    ``k_u`` set by the ``u_cmd,max`` ``bound`` (a larger ``k_u`` of the grid at that ``u_ff``
    was excluded by it: the rule at work)."""
    out = []
    for name, values, v in (("u_ff", {r.u_ff for r in rows}, best.u_ff),
                            ("k_u", {r.k_u for r in rows}, best.k_u)):  # fmt: skip
        if len(values) < 2:
            continue
        ok = admitted(rows, bound)
        larger = [r for r in rows if r.u_ff == best.u_ff and r.k_u > best.k_u]
        # the bound sets k_u only when every larger k_u at this u_ff is above it (one within
        # it lost on time or on a pirouette: then the note was false, a review)
        larger_cut = name == "k_u" and bool(larger) and not any(r in ok for r in larger)
        if larger_cut:
            out.append(f"k_u = {v:g} is the largest of the grid at u_ff = {best.u_ff:g} with "
                       f"u_ff + k_u pi/2 <= {bound:.4g} m/s (--u-cmd-max): the bound sets it")
        elif v in (max(values), min(values)):
            end = "largest" if v == max(values) else "smallest"
            out.append(f"{name} = {v:g} is the grid's {end}: the least turn time may lie "
                       f"beyond it (extend --{name.replace('_', '-')})")
    return out


def without_reference(ep: ExecutionParams, model: VesselModel) -> ExecutionParams:
    """``ep`` with eq. 3.1 switched off: the speed reference is the command at every heading
    error (``u_ff = u_max``, ``k_u = 0``)."""
    return replace(ep, reference=SpeedReference(u_ff=model.params.u_max, k_u=0.0))


#: the pirouette check of docs/tuning.md: (angle deg, distance m, start speed m/s)
PIROUETTE_CASE = (90.0, 10.0, 0.6)


def pirouette_check(model: VesselModel, ep: ExecutionParams, angle_deg: float = 150.0,
                    distance: float = 25.0, u0: float = 0.6, t_end: float = 120.0):  # fmt: skip
    """Hard turn while accelerating (thesis §3.4.1), with and without eq. 3.1.

    From trim at ``u0`` (slow, e.g. leaving standby) the waypoint is ``distance`` m away at
    ``angle_deg`` off the bow and the command asks for ``u_max``. Returns
    ``{"with": (run, figures), "without": (run, figures)}`` with :func:`turn`'s figures.
    """
    a = math.radians(angle_deg)
    return {
        "with": turn(model, ep, a, distance, t_end, u0=u0),
        "without": turn(model, without_reference(ep, model), a, distance, t_end, u0=u0),
    }
