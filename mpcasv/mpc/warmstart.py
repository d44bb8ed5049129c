"""Starting points of the MPC's solves (docs/mpc.md, "Controller step" 3): rollouts of the
plan model (plain, or steering for an AUV's target circle), slacks filled for a guess, and the
previous plan and multipliers moved on by the elapsed period. A mixin of
:class:`~mpcasv.mpc.problem.OCP` (its dimensions and functions live there)."""

from __future__ import annotations

import math

import numpy as np

from mpcasv.control.execution import wrap
from mpcasv.models.vessel import NX as NXV  # the plan's vessel state is the model's
from mpcasv.mpc.variance import N_NAV

#: clearance (m) of the exploration's guess beyond the plan's inner range bound ``r_lo`` (which
#: already holds the plan's 5 m margin): 15 m beyond the anti-collision radius in all
CLEAR = 10.0
#: a turn by more than this (rad, 135 deg) keeps its side until it is done: with the goal
#: near astern the shorter side flips with each small change of heading, and the guess's
#: steering used to chatter lock to lock instead of turning
TURN_COMMIT = 0.75 * math.pi


def around(here: np.ndarray, goal: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> float:
    """Heading (rad, from North) from ``here`` towards ``goal`` (m, (2,)), around discs
    (``centres`` (n, 2), ``radii`` (n,), m). Straight on if the way to the goal meets no
    disc. Else along the tangent to the disc it enters first, on the side nearer the
    straight heading; if that ray meets another disc before the goal, along that disc's
    tangent on the same side (the turn only widens; at most one pass per disc). From inside
    a disc whose centre lies ahead: along its circle, on the side nearer the straight
    heading (inside one whose centre lies behind: as if it were not there)."""
    d = goal - here
    dist = float(np.hypot(*d))
    psi = math.atan2(d[1], d[0])
    if dist < 1e-6:
        return psi
    discs = [(np.asarray(c, float) - here, float(R))
             for c, R in zip(np.asarray(centres, float).reshape(-1, 2),
                             np.asarray(radii, float), strict=True)]  # fmt: skip
    outside = []
    for w, R in discs:
        if float(np.hypot(*w)) > R:
            outside.append((w, R))
        elif math.cos(math.atan2(w[1], w[0]) - psi) > 0.0:  # inside, its centre ahead
            psi_c = math.atan2(w[1], w[0])
            return min((psi_c + math.pi / 2, psi_c - math.pi / 2), key=lambda a: abs(wrap(a - psi)))
    side = 0.0
    for _ in range(len(outside)):
        hit = _first_entry(psi, dist, outside)
        if hit is None:
            break
        w, R = hit
        psi_c, alpha = math.atan2(w[1], w[0]), math.asin(min(R / float(np.hypot(*w)), 1.0))
        if not side:  # the side nearer the straight heading, kept for the later discs
            side = 1.0 if abs(wrap(psi_c + alpha - psi)) <= abs(wrap(psi_c - alpha - psi)) else -1.0
        psi = psi_c + side * alpha
    return psi


def _first_entry(psi: float, dist: float, discs: list) -> tuple | None:
    """The disc (offset from here, radius) that the ray along ``psi`` enters first within
    ``dist`` m, or None."""
    u = np.array([math.cos(psi), math.sin(psi)])
    best, entry_best = None, dist
    for w, R in discs:
        t = float(w @ u)
        m = float(np.hypot(*(w - t * u)))  # miss distance of the line
        if t <= 0.0 or m >= R - 1e-9:
            continue
        entry = t - math.sqrt(R * R - m * m)
        if entry < entry_best:
            best, entry_best = (w, R), entry
    return best


class WarmStart:
    """Rollouts, slack filling and shifts of the OCP (mixin; state in the OCP)."""

    def rollout(self, p: np.ndarray, rates: np.ndarray | None = None) -> np.ndarray:
        """A dynamically consistent primal guess: the plan under ``rates`` (N, 2; default 0)
        from the initial state, slacks and ``m`` at their smallest feasible values."""
        d = self.dims
        par = self.unpack_par(p)
        rates = np.zeros((d.N, 2)) if rates is None else np.asarray(rates, float)
        Z = np.zeros((d.N + 1, d.nx))
        Z[0] = par["z0"]
        for k in range(d.N):
            Z[k + 1] = self._advance(Z[k], rates[k], par, k)
        V = np.zeros((d.N, d.nu))
        V[:, 0:2] = rates
        return self.fill_slacks(Z, V, p)

    def _advance(self, z: np.ndarray, rate: np.ndarray, par: dict, k: int) -> np.ndarray:
        """The plan model's state after stage ``k`` from ``z`` under the rates ``rate`` (2,): a
        coarse stage (M1t) is ``tail_m`` fine steps, the rates held, on interpolated
        parameters (as :meth:`OCP._build`'s ``stage_tail``)."""
        if k < self.dims.N - self.dims.n_tail:
            return np.array(self.F(z, rate, self._q(par, k))).ravel()
        m = self.tail_m
        for j in range(m):
            z = np.array(self.F(z, rate, self._q(par, k, (j / m, (j + 1) / m)))).ravel()
        return z

    def guided_rollout(self, p: np.ndarray, auv: int, speed: float) -> np.ndarray:
        """A primal guess that heads for AUV ``auv``'s target circle at ``speed`` and stops
        there (from outside inwards, from inside outwards): :meth:`steered_rollout` towards
        the closest point of the circle, around the other AUVs' anti-collision radii
        (:func:`around`; before session 13 straight through them, and the solve from such a
        guess kept its way through: Case 6, seed 14 stood by for the last 262 s beside a
        stopped AUV that lay across the way to its target, every exploration costing 18
        times the standing plan).

        Used to escape the local minimum of standing still (at rest the steering has no
        authority, so first-order information cannot tell the solver to turn and go).
        """
        par = self.unpack_par(p)
        T_go = self.model.thrust_for_speed(speed)

        def arrived(k, z) -> bool:  # on the circle (inside: head out)
            return abs(float(np.hypot(*(z[0:2] - par["pa"][k, auv]))) - par["r_t"][auv]) <= 5.0

        others = [i for i in range(self.dims.n_auv) if i != auv]  # the discs to go round
        pa_o, r_o = par["pa"][:, others], par["r_lo"][:, others] + CLEAR

        def heading(k, z):
            if arrived(k, z):
                return None
            c = par["pa"][k, auv]
            rel = z[0:2] - c
            goal = c + rel / max(float(np.hypot(*rel)), 1e-6) * par["r_t"][auv]  # closest point
            return around(z[0:2], goal, pa_o[k], r_o[k])

        return self.steered_rollout(p, heading, lambda k, z: 0.0 if arrived(k, z) else T_go)

    def steered_rollout(self, p: np.ndarray, goal_heading, thrust) -> np.ndarray:
        """Rollout whose stage-``k`` rates drive the steering towards ``goal_heading(k, z)``
        (rad; None: straight on; with ``steering = "heading"`` the heading reference to it,
        None: to the present heading) and the thrust towards ``thrust(k, z)`` (N, clipped to the
        vessel's range), within the rate limits (the plan model, as :meth:`rollout`)."""
        d, vp = self.dims, self.vessel
        par = self.unpack_par(p)
        Z = np.zeros((d.N + 1, d.nx))
        Z[0] = par["z0"]
        rates = np.zeros((d.N, 2))
        side = 0.0  # the side (+1, -1) of a turn beyond TURN_COMMIT under way, else 0
        for k in range(d.N):
            z = Z[k]
            psi_des = goal_heading(k, z)
            if self.heading:  # the heading reference (M1h) towards the goal, else the heading
                if psi_des is None:  # no goal: no committed turn (the reference meets psi)
                    side = 0.0
                e, side = _committed(z[2] if psi_des is None else psi_des, z[7], side)
                steer_des = z[7] + e
            elif psi_des is None:
                steer_des, side = 0.0, 0.0
            else:
                e, side = _committed(psi_des, z[2], side)
                steer_des = float(np.clip(e, -vp.delta_max, vp.delta_max))
            T_des = float(np.clip(thrust(k, z), vp.T_min, vp.T_max))
            dt = self.dts[k]
            rates[k, 0] = np.clip((T_des - z[6]) / dt, -self.dT_max, self.dT_max)
            rates[k, 1] = np.clip((steer_des - z[7]) / dt, -self.dd_max, self.dd_max)
            Z[k + 1] = self._advance(z, rates[k], par, k)
        V = np.zeros((d.N, d.nu))
        V[:, 0:2] = rates
        return self.fill_slacks(Z, V, p)

    def fill_slacks(self, Z: np.ndarray, V: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Primal vector with slacks and epigraph variables set to their smallest feasible
        values (plus a small margin) for the states ``Z`` and rates ``V[:, :2]``."""
        d, par = self.dims, self.unpack_par(p)
        K = d.n_auv
        dist = np.hypot(Z[:-1, None, 0] - par["pa"][:-1, :, 0],
                        Z[:-1, None, 1] - par["pa"][:-1, :, 1])  # fmt: skip
        s = np.maximum(par["r_lo"][:-1] - dist, 0.0)
        if d.outer:
            s = np.maximum(s, dist - par["r_hi"][:-1])
        V = V.copy()
        V[:, 2 : 2 + K] = s + 1e-3
        if d.epi:
            V[:, 2 + K] = Z[:-1, NXV : NXV + K].max(axis=1) + 1e-3
        return self.join(Z, V)

    def _q(self, par: dict, k: int, part: tuple[float, float] | None = None) -> np.ndarray:
        """The plan model's parameters over stage ``k``; ``part = (a, b)``: over the part of a
        coarse stage from ``a`` to ``b`` of it (its parameters interpolated; one fine step)."""
        pa, pa1 = par["pa"][k].ravel(), par["pa"][k + 1].ravel()
        dep, dep1 = par["depth"][k], par["depth"][k + 1]
        if part is not None:
            (a, b), dpa, ddep = part, pa1 - pa, dep1 - dep
            pa, pa1, dep, dep1 = pa + a * dpa, pa + b * dpa, dep + a * ddep, dep + b * ddep
        # ext: the variance objective's nav constants (M2'); empty for the default objective
        return np.concatenate([par["current"], pa, (pa1 - pa) / self.dt, dep,
                               (dep1 - dep) / self.dt, par["d_fix"], par["channel"],
                               par["ext"][:N_NAV]])  # fmt: skip

    def _positions(self, n: int, frac: float) -> np.ndarray:
        """Where the first ``n`` stage times lie ``frac`` fine stages (``frac dt`` s) later,
        in stage indices (fractional; on the coarse tail (M1t) by its times)."""
        if not self.dims.n_tail:
            return np.arange(n) + frac
        t = self.t_stage
        return np.interp(t[:n] + frac * self.dt, t, np.arange(len(t)))

    def shift(self, w: np.ndarray, frac: float) -> np.ndarray:
        """Primal warm start moved ``frac`` fine stages (``frac dt`` s) ahead (linear
        interpolation in time, end held)."""
        Z, V = self.split(w)
        return self.join(interp_rows(Z, self._positions(len(Z), frac)),
                         interp_rows(V, self._positions(len(V), frac)))  # fmt: skip

    def shift_lam_g(self, lam: np.ndarray, frac: float) -> np.ndarray:
        """Constraint multipliers moved ``frac`` fine stages ahead (same rule as
        :meth:`shift`)."""
        d = self.dims
        return interp_rows(np.asarray(lam).reshape(d.N, d.nx + d.nh),
                           self._positions(d.N, frac)).ravel()  # fmt: skip

    def shift_lam_x(self, lam: np.ndarray, frac: float) -> np.ndarray:
        """Bound multipliers moved ``frac`` fine stages ahead."""
        return self.shift(lam, frac)


def _committed(psi_des: float, psi: float, side: float) -> tuple[float, float]:
    """The turn (rad) from ``psi`` to ``psi_des``: the shorter way, except that a turn beyond
    ``TURN_COMMIT`` already under way on ``side`` (+1, -1; 0: none) keeps it. Returns the
    turn and the side to keep at the next stage."""
    e = math.atan2(math.sin(psi_des - psi), math.cos(psi_des - psi))
    if abs(e) <= TURN_COMMIT:
        return e, 0.0
    if side and math.copysign(1.0, e) != side:
        e += side * 2.0 * math.pi  # the other way round, as committed
    return e, math.copysign(1.0, e)


def interp_rows(A: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Rows of ``A`` (n, m) evaluated at the fractional row indices ``s`` (n,) by linear
    interpolation, the last row held."""
    n = A.shape[0]
    s = np.minimum(s, n - 1)
    i0 = np.floor(s).astype(int)
    i1 = np.minimum(i0 + 1, n - 1)
    a = (s - i0)[:, None]
    return (1 - a) * A[i0] + a * A[i1]
