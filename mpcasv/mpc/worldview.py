"""What the MPC knows of the world each step (docs/mpc.md, "Controller step" 1-2): the
expected fix ages, the AUVs' depths and their forecast, the anti-collision radii, the current
the plan assumes, the initial state and the OCP's parameter vector. A mixin of
:class:`~mpcasv.mpc.controller.MPCController` (its state lives there)."""

from __future__ import annotations

import math
import sys

import numpy as np

from mpcasv.estimation.current import measurement
from mpcasv.hybrid.avoidance import estimate_shape
from mpcasv.interface import Observation
from mpcasv.models.frames import ned_to_body
from mpcasv.mpc.layout import WEIGHT_NAMES
from mpcasv.mpc.order import meet_time
from mpcasv.mpc.rescue import threats
from mpcasv.mpc.variance import N_TAIL, fix_gain

_STAND = WEIGHT_NAMES.index("stand")
_ACCRUE = WEIGHT_NAMES.index("accrue")

R_HI_NONE = 1.0e5  # "no outer bound" (m)
TAU_UNKNOWN = 600.0  # fix age used for an AUV never fixed (s)
W_MAX_DEPTH = 2.0  # bound on the estimated vertical speed of an AUV (m/s)
#: the strongest current (m/s) the MPC has been run in without being carried off (session 26,
#: with the ground-speed bounds widened by the current). Session 29 (the waypoint aimed where
#: the plan points the bow; suite strong-currents, one AUV, 300 s): mpc-single stayed within
#: r_outer at 1-2 m/s in 11 of 12 conditions (2 seeds each), but with the current towards
#: the West (across its approach or its AUV's track) it got no reliable fix at 1-2 m/s,
#: 82-165 m off, already at 1.0 m/s (docs/mpc.md, "Known problems", strong currents): so
#: "tested" means "not carried beyond r_outer", not "fixes as in still water"; above it the
#: controller says so once per run
CURRENT_TESTED = 1.0


def untested_current(current) -> bool:
    """Whether the MPC has not been tested in ``current`` (N, E components, m/s): its speed,
    rounded to 0.01 m/s, is above :data:`CURRENT_TESTED` (1.004 m/s is not, 1.006 m/s is; a
    NaN component is not). The one definition of the rule: the stderr warning of a run
    (:meth:`WorldView._note_strong`), the per-step diagnostic ``mpc_cur_untested``, the metric
    ``current_untested_s`` and the deploy's event ``current_untested`` all come from it.

    Raises
    ------
    TypeError
        ``current`` does not have two components.
    """
    return round(float(np.hypot(*current)), 2) > CURRENT_TESTED


def ranges(asv_NE: np.ndarray, pa: np.ndarray) -> np.ndarray:
    """Horizontal ranges (m) from ASV positions ``(..., 2)`` to AUV positions ``(..., K, 2)``
    (shape ``(..., K)``)."""
    return np.linalg.norm(np.asarray(asv_NE, float)[..., None, :] - pa, axis=-1)


class WorldView:
    """The per-step world model of the MPC (mixin; state in the controller)."""

    def _fix_ages(self, obs: Observation, elapsed: float) -> np.ndarray:
        """Propagate (or read) the expected fix ages over ``elapsed`` s (eq. M2, exact for a
        constant rate)."""
        if self.params.fix_age_source == "estimate":
            ages = np.array([obs.t - a.t_last_fix for a in obs.auvs])
            return np.where(np.isfinite(ages), np.maximum(ages, 0.0), TAU_UNKNOWN)
        ages = self.tau if elapsed <= 0 else self._expected_ages(obs, elapsed)
        if self.params.fix_age_source == "observed":
            ages = self._observed_fixes(obs, ages)
        return ages

    def _expected_ages(self, obs: Observation, elapsed: float) -> np.ndarray:
        """The expected fix ages (s, shape (K,)) ``elapsed`` s (> 0) after ``self.tau``
        (eq. M2 at the observed state's rates, exact for a constant rate), and the expected
        fixes counted since the target's choice and the run's start (M9, M9t)."""
        rho = self._rates(obs)
        self.fixes_since += rho * elapsed  # expected fixes since the target's choice (M9)
        self.fixes_run += rho * elapsed  # ... since the run began (the first tour, M9t)
        if self.ocp.variance:  # (M2') what a fix at this range removes
            slant = np.array([math.hypot(*(a.position - obs.asv.position), a.depth)
                              for a in obs.auvs])  # fmt: skip
            ac = self.acoustics
            rho = rho * fix_gain(self.tau, slant, ac.sigma_range,
                                 math.radians(ac.sigma_bearing_deg),
                                 self.params.navigation.eps_a)  # fmt: skip
        decay = np.exp(-rho * elapsed)
        with np.errstate(divide="ignore", invalid="ignore"):
            relaxed = 1 / rho + (self.tau - 1 / rho) * decay
        return np.where(rho > 1e-9, relaxed, self.tau + elapsed)

    def _observed_fixes(self, obs: Observation, ages: np.ndarray) -> np.ndarray:
        """(M2o, ``fix_age_source = "observed"``) ``ages`` (s, shape (K,)) with the age of
        each AUV whose fix the ASV's own USBL reported since the previous step while the
        ASV was quiet within its reliable-fix range (Paper 2 eq. 9, at the believed range)
        set to that fix's age, and that AUV counted as served (``fixes_since``,
        ``fixes_run`` at least 1: mpc/target.py). Fix times already there at the run's
        first step are not news.

        Raises
        ------
        ValueError
            The observation carries no USBL fix times (an observation built by hand, or
            read from a deploy log written before the deploy read DUNE's).
        """
        if obs.usbl_fix_times is None:
            raise ValueError("fix_age_source = 'observed' needs the ASV's own USBL fix times "
                             "(Observation.usbl_fix_times), which this observation does not "
                             "carry (a deploy log written before the deploy read DUNE's "
                             "UsblFixExtended?): use 'model'")  # fmt: skip
        t_fix = np.asarray(obs.usbl_fix_times, float)
        seen, self._seen_fix = self._seen_fix, t_fix
        if seen is None:
            return ages
        dist, r_t = self._reach_now(obs)
        reliable = (t_fix > seen) & self.domain.reliable_fix_possible(dist, r_t,
                                                                      obs.propeller_on)  # eq. 9
        self.fixes_since[reliable] = np.maximum(self.fixes_since[reliable], 1.0)
        self.fixes_run[reliable] = np.maximum(self.fixes_run[reliable], 1.0)
        return np.where(reliable, np.maximum(obs.t - t_fix, 0.0), ages)

    def _reach_now(self, obs: Observation) -> tuple[np.ndarray, np.ndarray]:
        """(horizontal range, target-circle radius ``r_t``) of each AUV now (m, shapes (K,)),
        at the believed positions and depths: the geometry of Paper 2's reliable-fix rule
        (eq. 9), for the target's dwell (M9) and the observed fixes (M2o)."""
        pos = np.array([a.position for a in obs.auvs])
        dist = np.hypot(*(pos - obs.asv.position).T)
        return dist, self._radii(obs, 0.0, obs.asv.position) + self.domain.delta_r

    def _fix_geometry(self, obs: Observation, r_lo0: np.ndarray):
        """(depth now, d_fix) per AUV: ``d_fix`` is the reliable-fix range of the ``target``
        fix model (M3; unused by the ``acoustic`` one, whose range is the channel's)."""
        K = len(obs.auvs)
        if self.params.fix.range_kind == "acoustic":
            depth = np.array([a.depth for a in obs.auvs])
            return depth, np.full(K, self.acoustics.d1)
        d_fix = self.domain.reliable_limit(r_lo0 + self.domain.delta_r)
        if self.params.fix.inset > 0:  # the sigmoid centred inside the reliable-fix circle
            d_fix = d_fix - self.params.fix.inset
        return np.zeros(K), d_fix

    def _rates(self, obs: Observation) -> np.ndarray:
        """Fix rates now (1/s): propeller state as observed, geometry and channel as in the
        plan (eq. M3)."""
        r_lo = self._radii(obs, 0.0, obs.asv.position)
        _, d_fix = self._fix_geometry(obs, r_lo)
        T = self.ocp.vessel.T_max if obs.propeller_on else 0.0
        x = np.array([obs.asv.N, obs.asv.E, 0, 0, 0, 0, T, 0])
        return np.array([float(self.ocp.rho_fun(x, a.position, a.depth, d_fix[i], self.channel))
                         for i, a in enumerate(obs.auvs)])  # fmt: skip

    def _track_depth(self, obs: Observation) -> None:
        """Vertical speed of each AUV from its last two distinct depth estimates (exact for a
        steady climb under the perfect estimator; the mean rate between reports under the
        acoustic one); back to 0 once the estimate has held longer than twice that interval
        (the AUV levelled off); bounded by ``W_MAX_DEPTH``."""
        for i, a in enumerate(obs.auvs):
            h = self._depth_hist[i]
            if not math.isfinite(a.depth):
                continue
            if not h or abs(a.depth - h[-1][1]) > 1e-6:
                h.append((obs.t, a.depth))
                del h[:-2]
            if len(h) == 2 and h[1][0] > h[0][0]:
                gap = h[1][0] - h[0][0]
                w = (h[1][1] - h[0][1]) / gap
                held = obs.t - h[1][0]
                self.w_depth[i] = 0.0 if held > 2 * gap + 1e-9 else np.clip(w, -W_MAX_DEPTH,
                                                                              W_MAX_DEPTH)
            else:
                self.w_depth[i] = 0.0

    def depth_forecast(self, obs: Observation, ts: np.ndarray) -> np.ndarray:
        """Each AUV's depth at offsets ``ts`` (s) from now: the estimate moved at the tracked
        vertical speed, not above the surface (m, shape ``(len(ts), K)``)."""
        d0 = np.array([a.depth for a in obs.auvs], float)
        return np.maximum(d0[None, :] + np.asarray(ts, float)[:, None] * self.w_depth[None, :],
                          0.0)  # fmt: skip

    def _radii(self, obs: Observation, lookahead, asv_NE, depth=None) -> np.ndarray:
        """Anti-collision radius (r_inner / r_avoid) of each AUV ``lookahead`` s ahead, along
        the bearing from the AUV to ``asv_NE``, at the AUVs' ``depth`` (forecast; None: the
        estimates'): shape (K,), or (S, K) for S stages at once (``lookahead`` shape (S,),
        ``asv_NE`` (S, 1, 2) or (2,), ``depth`` (S, K))."""
        shape = estimate_shape(self.params.avoidance, self.domain, obs.auvs, obs.t, lookahead,
                               depth)  # fmt: skip
        rel = np.asarray(asv_NE, float) - shape.center
        return np.asarray(shape.radius(np.arctan2(rel[..., 1], rel[..., 0])), float)

    def _plan_current(self, obs: Observation) -> np.ndarray:
        """The current the plan assumes (``params.current``), after the observer has taken
        this observation: its estimate, the true current the simulator put in the
        observation (oracle), or zero (m/s, shape (2,)).

        Raises
        ------
        ValueError
            ``current = "oracle"`` and the observation carries no true current (only the
            simulator provides it, and only to a controller that asks).
        """
        est = self.observer.update(measurement(obs))
        mode = self.params.current
        if mode == "estimated":
            return self._note_strong(obs, est, "estimated on board")
        if mode == "zero":
            return np.zeros(2)
        if obs.current_oracle is None:
            raise ValueError("MPC current = 'oracle': the observation carries no true current "
                             "(only the simulator provides it, for ablations); use "
                             "current = 'estimated'")  # fmt: skip
        return self._note_strong(obs, np.asarray(obs.current_oracle, float), "the true one")

    #: print :meth:`_note_strong`'s line; False where the caller says it in its own terms: a
    #: sweep (metric ``current_untested_s`` and one line at its end; each job's line would
    #: name no job and break the progress bar) and a deploy (event ``current_untested``)
    say_current = True

    def _note_strong(self, obs: Observation, current: np.ndarray, what: str) -> np.ndarray:
        """``current`` (m/s, shape (2,)); the first time in a run that it is stronger than
        :data:`CURRENT_TESTED`, one line on stderr saying that the MPC is untested there
        (unless :attr:`say_current` is False)."""
        if untested_current(current) and not self.current_noted:
            self.current_noted = True
            if not self.say_current:
                return current
            speed = float(np.hypot(*current))
            print(f"mpcasv: warning: {self.name} at t = {obs.t:.0f} s: the current ({what}) is "
                  f"{speed:.2f} m/s, above the {CURRENT_TESTED:g} m/s the MPC has been run in "
                  "without being carried off; in a current across its approach or its AUV's "
                  "track mpc-single was measured 82-165 m off without a reliable fix at 1-2 m/s "
                  "(docs/mpc.md, \"Known problems\": strong currents)",
                  file=sys.stderr)  # fmt: skip
        return current

    def _x0(self, obs: Observation) -> np.ndarray:
        """Plan initial state: the observed thrust and steering (``obs.actuators``) when the
        observation carries them; else trim thrust for the current speed through the water
        (ground surge speed less the planned current along the heading) while the propeller
        runs (at least the on-threshold), else 0, and steering from the previous plan. With
        ``steering = "heading"`` the eighth state is the heading reference whose yaw PD gives
        that steering angle (M1h). The heading is taken on the previous step's branch (within
        pi of the heading this method returned last, whether that step's plan was used or
        not): the warm start continues from it, and an observed heading wrapped to (-pi, pi]
        (deploy: IMC's ``psi``) would put 2 pi between them. The simulator's heading is
        continuous, so there nothing changes."""
        a, ocp = obs.asv, self.ocp
        vp = ocp.vessel
        T0, d0 = 0.0, 0.0
        if obs.actuators is not None and self.params.initial_actuators == "observed":
            # the boat knows its actuators (simulation; deploy with feedback): plan from them
            T0, d0 = obs.actuators
            T0, d0 = (float(np.clip(T0, vp.T_min, vp.T_max)),
                      float(np.clip(d0, -vp.delta_max, vp.delta_max)))  # fmt: skip
        elif obs.propeller_on:
            u_c = ned_to_body(a.psi, self.current[0], self.current[1])[0]
            T0 = min(max(ocp.model.thrust_for_speed(max(a.u - u_c, 0.0)), 1.2 * ocp.T_on),
                     vp.T_max)  # fmt: skip
            if self.plan is not None:
                d0 = float(np.interp(obs.t, self.plan.t, self.plan.extra["delta"]))
        psi = a.psi  # on the branch of the previous step's (a deploy's heading is wrapped)
        if self.psi_prev is not None:
            psi += 2 * math.pi * round((self.psi_prev - psi) / (2 * math.pi))
        self.psi_prev = psi
        x = np.array([a.N, a.E, psi, a.u, a.v, a.r, T0, d0])
        if ocp.heading:  # the heading reference whose yaw PD gives that steering (M1h)
            x[7] = ocp.heading_reference(x, x[7])
        return x

    def parameters(self, obs: Observation) -> np.ndarray:
        """The parameter vector of the OCP for this observation (after fix-age bookkeeping)."""
        d = self.ocp.dims
        K, N = d.n_auv, d.N
        ts = self.ocp.t_stage  # the stages' times from now (s)
        # the estimator's forecast (along the known plan) or constant velocity
        pa = np.stack([a.predict(ts) for a in obs.auvs], axis=1)  # (N+1, K, 2)
        # bearing of each stage from the previous plan (or the current position)
        if self.w_prev is not None:
            Z, _ = self.ocp.split(self.w_prev)
            asv = Z[:, None, 0:2]
        else:
            asv = np.broadcast_to(obs.asv.position, (N + 1, 1, 2))
        # each AUV's depth over the horizon, and with it the radii: the collision domain of an
        # AUV rising towards the surface grows (r_inner / r_avoid from 0 below r_in)
        depth = self.depth_forecast(obs, ts)
        if self.params.avoidance.kind == "fixed":
            r_lo = self._radii(obs, np.zeros(N + 1), obs.asv.position, depth)
        else:
            r_lo = self._radii(obs, np.asarray(ts, float), asv, depth)
        if self.multi:
            r_hi = np.full((N + 1, K), R_HI_NONE)
        else:
            r_hi = np.asarray(self.domain.outer(depth), float)
        _, d_fix = self._fix_geometry(obs, r_lo[0])
        r_t = r_lo[-1] + self.domain.delta_r
        m = self.params.margin  # the plan keeps this far off the anti-collision radius
        ext = None
        if self.ocp.variance:
            ext = self.ocp.ext_vector(self.acoustics, *self._tail(obs, ts[-1], asv[-1, 0], r_t),
                                      U_go=self.U_go)  # fmt: skip
        p = self.ocp.pack(self._x0(obs), self.tau, self.current, pa, r_lo + m, r_hi - m,
                          depth, d_fix, r_t, self.target, self.channel, ext)  # fmt: skip
        self._stand_off_under_threat(p)
        return self._cap_parameters(p)  # a speed cap's transit speed (mpc/speedcap.py)

    def _stand_off_under_threat(self, p: np.ndarray) -> None:
        """``p`` without the standing-time term (M7s, ``weights.stand`` set to 0, in place)
        and without the integral terminal's age accrued on the way (M7i, the weight
        ``accrue`` set to 0: M7a's pull is left) while an AUV threatens the ASV adrift
        (:func:`~mpcasv.mpc.rescue.threats`: within its anti-collision radius plus 20 m at
        some stage). Both extrapolate the AUV in a straight line past the horizon; an AUV that
        closes in on the ASV may be turning towards it (a pursuer re-aims), and no place is
        then one to stand at or to head for (docs/mpc.md, M7s and M7i)."""
        W = self.ocp.unpack_par(p)["weights"]
        gated = W[_STAND] > 0 or (self.params.weights.terminal == "integral"
                                  and not self.ocp.variance)  # M7c replaces M7i  # fmt: skip
        self.stand_off = bool(gated and threats(self.ocp, p, self.params.margin).any())
        if self.stand_off:
            W[_STAND] = W[_ACCRUE] = 0.0

    def _tail(self, obs: Observation, t_N: float, asv_N: np.ndarray, r_t: np.ndarray):
        """The variance objective's view past the horizon (M7c; :mod:`mpcasv.mpc.variance`):
        each AUV's forecast position (K, N_TAIL, 2; m) and depth (K, N_TAIL; m) at the
        midpoints of the tail's ``N_TAIL`` segments, and where the ASV, leaving the previous
        plan's end ``asv_N`` (m) at ``t_N`` (s from now), would meet it at ``U_go`` (K, 2;
        :func:`~mpcasv.mpc.order.meet_time`): an AUV coming towards the ASV is met sooner
        than its distance says."""
        wt, K = self.params.weights, len(obs.auvs)
        mids = t_N + wt.tail * (np.arange(N_TAIL) + 0.5) / N_TAIL
        fc = [self.forecast(a) for a in obs.auvs]
        tail_pa = np.stack([f(mids) for f in fc])  # (K, N_TAIL, 2)
        tail_depth = self.depth_forecast(obs, mids).T  # (K, N_TAIL)
        meet = np.empty((K, 2))
        for i, f in enumerate(fc):
            s = meet_time(asv_N, f, float(r_t[i]), self.U_go, t_N)
            meet[i] = f(np.array([t_N + s]))[0]
        return tail_pa, tail_depth, meet
