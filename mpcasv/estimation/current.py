"""The horizontal water current as estimated on board, from the ASV's own motion (issue 16
item 1).

The boat measures its velocity over ground (GNSS, or the navigation filter's EstimatedState),
its heading and yaw rate, and knows the thrust and steering its execution level applies. The
one vessel model (:func:`mpcasv.models.vessel.xdot_expr`) predicts its velocity **through the
water** from those; what the ground velocity has beyond it is the current. An extended Kalman
filter separates the two.

State (5): ``s = [u_r, v_r, r, V_N, V_E]``: surge and sway speed through the water (m/s, body
axes), yaw rate (rad/s), current (m/s, NED; constant in space over the boat's length).

Motion model over ``dt`` (the time between two observations, RK4 in sub-steps of at most
``h_max`` s, shorter for a stiff hull):

    nu_r(t + dt) = Phi(nu_r(t); T, delta, dt)                                         (C1)

the vessel model in still water (``c = 0``) started at ``[u_r, v_r, r]`` with the actuators
held, between each two samples of them through the interval, at the two samples' mean when
the observation carries them (the simulator: every plant step), else over the whole interval
at the mean of their values at its two ends (``T`` in N, ``delta`` in rad). The ends alone
misled it where the steering changes within the interval: Fossen's Otter flips its steering
between about +0.44 and -0.44 rad from one 1-s period to the next in a transit, the ends'
mean was near 0, and the prediction error read as a current of up to 0.49 m/s in still
water; from the plant steps' samples, 0.003 m/s (session 46, ``tests/test_current_observer.
py``). For a current
constant in NED the relative velocities obey exactly the still-water equations (Fossen 2021,
Property 10.1: ``M_RB nu_dot + C_RB(nu) nu = M_RB nu_r_dot + C_RB(nu_r) nu_r``, which holds
for the model's 3-DOF ``C_RB``), so (C1) needs no current. The current is a random walk:

    V(t + dt) = V(t) + w,   w ~ N(0, q_c dt I)                                           (C2)

and the model's error a white velocity noise ``N(0, q_nu dt I)`` on ``nu_r``. Linearised by
CasADi (the Jacobian of (C1), chained over the sub-steps).

Prior at the first measurement (C0; :meth:`CurrentObserver._prior`): the current
``0 +- sigma_c0`` per axis, the speed through the water ``+- sigma_nu0`` per body axis,
centred on the ground velocity while the propeller runs and on zero while it is off (how the
first ground velocity splits between the boat's motion and the current is not known; the
motion that follows tells), the yaw rate as measured.

Measurement (3): the ground velocity in body axes and the yaw rate, with the heading ``psi``
measured:

    [u, v] = nu_r[0:2] + R(psi)^T [V_N, V_E],   r = r                                    (C3)

``R(psi)`` the rotation NED <- body; noise ``N(0, diag(sigma_v^2, sigma_v^2, sigma_r^2))``.
Linear in the state given ``psi``; Joseph-form update.

Where the information comes from: with the propeller off, the model says ``nu_r -> 0`` (the
hull's drag stops it), so the ground velocity becomes the current (the drift); with the
propeller running, the model's prediction of ``u_r`` from the thrust (trim) is what the
ground speed along the heading is compared with. Without the actuators' values
(``actuators = None``, e.g. a deploy without thruster feedback) the model cannot predict
``nu_r`` while the propeller runs: ``nu_r`` is then held, with the noise ``q_blind``, and the
current is learnt only while drifting.

The filter is deterministic: no random draws; the same measurements give the same estimate.
A model that differs from the boat (hull, loads, wind) shows up as a current: what is
estimated is the "effective" current that makes the model fit the motion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from mpcasv.config import Pos, frozen
from mpcasv.interface import Observation
from mpcasv.models.envelope import rk4_sub_steps
from mpcasv.models.frames import ned_to_body
from mpcasv.models.vessel import NX, VesselModel

__all__ = [
    "CurrentObserver", "CurrentObserverParams", "MotionMeasurement", "measurement",
    "measurement_from_estimated_state",
]  # fmt: skip

NS = 5  # state size: u_r, v_r, r, V_N, V_E


@frozen
class CurrentObserverParams:
    """Tuning of :class:`CurrentObserver` (SI units; equations C1-C3 of the module).

    Attributes
    ----------
    q_nu : float
        Model-error noise of the water-relative velocities (m^2/s^3 per component): how far
        the vessel model's prediction may be off per second (1e-4: 0.01 m/s in 1 s). With
        4e-4 the estimate took longer to follow a step in the current through a standby
        (error 0.034 against 0.012 m/s 120 s after the step, ``tests/test_current_observer.py``).
    q_c : float
        Random-walk intensity of the current (m^2/s^3): the current's standard deviation grows
        by ``sqrt(q_c t)`` over ``t`` s (1e-5: 0.03 m/s in 100 s). 4e-5 follows a step
        faster but with GNSS-like noise (0.05 m/s) the error RMS rose from 0.012 to 0.017 m/s.
    q_blind : float
        Noise of the relative velocities while the propeller runs and the actuators are not
        known (m^2/s^3): large, so that the motion then says nothing about the current.
    sigma_v : float
        Measurement noise of the ground velocity, per body axis (m/s).
    sigma_r : float
        Measurement noise of the yaw rate (rad/s).
    sigma_c0 : float
        Initial standard deviation of the current per axis (m/s); the initial estimate is 0.
        1 m/s: the boat does not know the current when it starts, and tidal streams reach
        2 m/s. With 0.3 a 2 m/s current took 30 s to be found within 10 % from a start at
        rest over ground (``tests/test_current_observer.py``, the start's tests).
    sigma_nu0 : float
        Initial standard deviation of the speed through the water per body axis (m/s): how
        the first ground velocity splits into the boat's own motion and the current is not
        known (C0). Before, the split was taken as known (the ground velocity all through the
        water, to within ``sigma_v``), and only the slow random walk (C2) could move it: a
        boat drifting in 0.15-2 m/s took 120-200 s to find the current, one started at rest
        over ground in 1 m/s more than 200 s. 0.3 (session 31): with 1 m/s the first
        estimates overshot (an error of 2.8 m/s 2 s into a transit in 2 m/s; up to 1.8
        m/s above the current's speed over 24 starts), and the MPC met them with hung
        solves; 0.3 keeps the overshoot to 0.7 m/s on the first sample (0.24 after it) and
        settles within 10 % in 0-21 s (docs/mpc.md, "Known problems", the observer's start).
    h_max : float
        Longest RK4 sub-step of (C1) (s): RK4 is stable on Gretha's fast sway-yaw pole (about
        -2.4 1/s at 2.5 m/s) for sub-steps up to about 1.1 s; a stiffer hull takes shorter
        ones (:func:`~mpcasv.models.envelope.rk4_sub_steps`).
    """

    q_nu: Pos = 1e-4
    q_c: Pos = 1e-5
    q_blind: Pos = 1.0
    sigma_v: Pos = 0.05
    sigma_r: Pos = 0.01
    sigma_c0: Pos = 1.0
    sigma_nu0: Pos = 0.3
    h_max: Pos = 0.5


@dataclass(frozen=True, slots=True)
class MotionMeasurement:
    """What the observer takes at time ``t`` (s): heading ``psi`` (rad), ground velocity in
    body axes ``u``, ``v`` (m/s), yaw rate ``r`` (rad/s), and the actuators' thrust ``T`` (N)
    and steering ``delta`` (rad), or None when not known; ``propeller_on``;
    ``actuator_samples``: ``((t, T, delta), ...)`` through the interval since the previous
    measurement, in time order within it (linear between them, and from and to the two
    measurements' ``actuators`` at the interval's ends: :func:`_segments`), or None when not
    known (then the two ends' ``actuators``)."""

    t: float
    psi: float
    u: float
    v: float
    r: float
    propeller_on: bool
    actuators: tuple[float, float] | None = None
    actuator_samples: tuple[tuple[float, float, float], ...] | None = None


def measurement(obs: Observation) -> MotionMeasurement:
    """The observer's measurement in an :class:`~mpcasv.interface.Observation` (the ASV's
    navigation state, its actuators now and through the period, the propeller state)."""
    a = obs.asv
    return MotionMeasurement(obs.t, a.psi, a.u, a.v, a.r, obs.propeller_on, obs.actuators,
                             obs.actuator_samples)


def measurement_from_estimated_state(t: float, psi: float, vx: float, vy: float, r: float,
                                     propeller_on: bool, thrust: float | None = None,
                                     delta: float | None = None) -> MotionMeasurement:  # fmt: skip
    """The measurement from an IMC EstimatedState (deploy): its NED ground velocity ``vx``,
    ``vy`` (m/s) rotated into body axes by ``psi`` (rad), yaw rate ``r`` (rad/s); ``thrust``
    (N, e.g. a SetThrusterActuation value x T_max) and ``delta`` (rad) when the boat reports
    them (both, else the actuators count as unknown: the current is learnt while drifting).
    """
    act = None if thrust is None or delta is None else (float(thrust), float(delta))
    return MotionMeasurement(t, psi, *ned_to_body(psi, vx, vy), r, propeller_on, act)


def _segments(a: MotionMeasurement, b: MotionMeasurement) -> list[tuple[float, np.ndarray]] | None:
    """``[(length (s), (T, delta) held), ...]`` from ``a.t`` to ``b.t`` through
    ``b.actuator_samples``, read as a piecewise-linear signal (the plant's actuator states,
    which lag their set-points continuously): each piece between two samples is held at their
    mean. The interval's ends are the measurements' own ``actuators`` (``a``'s at ``a.t``,
    ``b``'s at ``b.t``) where the samples do not reach them; where those are unknown, the
    nearest sample is held. A held source (set-points at their arrival times) gives each
    change as two samples at the same time, the old value then the new. None without samples.

    Raises
    ------
    ValueError
        Samples out of time order, before ``a.t`` or after ``b.t``, or not finite. (Samples
        cannot show that an observation was skipped: the caller gives every one.)
    """
    if not b.actuator_samples:
        return None
    S = np.asarray(b.actuator_samples, float).reshape(-1, 3)
    if not np.all(np.isfinite(S)):
        raise ValueError(f"current observer: non-finite actuator samples at t = {b.t}")
    tol = 1e-6 + 8 * float(np.spacing(abs(b.t)))  # a microsecond, or a few ulps of a UNIX time
    if S[0, 0] < a.t - tol or S[-1, 0] > b.t + tol or np.any(np.diff(S[:, 0]) < 0):
        raise ValueError(f"current observer: actuator samples at t = {b.t} do not lie in time "
                         f"order between the previous measurement ({a.t}) and this one")
    if S[0, 0] > a.t + tol:  # from the previous measurement's actuators at its time
        first = S[0, 1:] if a.actuators is None else np.asarray(a.actuators, float)
        S = np.vstack([[a.t, *first], S])
    if S[-1, 0] < b.t - tol:  # to this measurement's at its time
        last = S[-1, 1:] if b.actuators is None else np.asarray(b.actuators, float)
        S = np.vstack([S, [b.t, *last]])
    return [(t1 - ta, 0.5 * (S[i, 1:] + S[i + 1, 1:]))
            for i, (ta, t1) in enumerate(zip(S[:-1, 0], S[1:, 0], strict=True)) if t1 > ta]


def _relative_step(model: VesselModel) -> ca.Function:
    """``(nu_r, J, a, h) -> (nu_r_next, d nu_r_next / d nu_r @ J)``: one RK4 step of (C1),
    chaining the Jacobian ``J`` of ``nu_r`` with respect to the interval's start."""
    nu, a, h = ca.SX.sym("nu", 3), ca.SX.sym("a", 2), ca.SX.sym("h")
    zero = ca.SX.zeros(2)

    def f(x):
        return model.f(x, a, zero)

    x = ca.vertcat(0, 0, 0, nu, a)  # actuators held at their set-points (no lag)
    k1 = f(x)
    k2 = f(x + h / 2 * k1)
    k3 = f(x + h / 2 * k2)
    k4 = f(x + h * k3)
    x1 = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    assert x1.shape[0] == NX
    nu1 = x1[3:6]
    J = ca.SX.sym("J", 3, 3)  # d nu / d nu at the chain's start, carried along
    return ca.Function("current_obs_step", [nu, J, a, h], [nu1, ca.jacobian(nu1, nu) @ J])


class CurrentObserver:
    """Extended Kalman filter of the current from the ASV's motion (module docstring).

    Parameters
    ----------
    model : VesselModel
        The run's vessel model (the one the simulator integrates and the MPC plans with).
    params : CurrentObserverParams, optional

    Attributes
    ----------
    s : ndarray (5,)
        ``[u_r, v_r, r, V_N, V_E]`` (m/s, m/s, rad/s, m/s, m/s); None before the first update.
    P : ndarray (5, 5)
        Its covariance.
    """

    def __init__(self, model: VesselModel, params: CurrentObserverParams | None = None):
        self.model = model
        self.params = params or CurrentObserverParams()
        self._step = _relative_step(model)
        self._n_sub: dict[float, int] = {}
        self._chains: dict[int, ca.Function] = {}  # number of RK4 steps -> their chain
        self.reset()

    def reset(self) -> None:
        self.s: np.ndarray | None = None
        self.P: np.ndarray | None = None
        self._last: MotionMeasurement | None = None

    @property
    def current(self) -> np.ndarray:
        """The estimated current ``[V_N, V_E]`` (m/s); zero before the first update."""
        return np.zeros(2) if self.s is None else self.s[3:5].copy()

    @property
    def sigma(self) -> np.ndarray:
        """1-sigma of the current's two components (m/s)."""
        if self.P is None:
            return np.full(2, self.params.sigma_c0)
        return np.sqrt(np.diag(self.P)[3:5])

    def update(self, m: MotionMeasurement) -> np.ndarray:
        """Predict from the previous measurement to ``m.t`` (C1-C2), then update with ``m``
        (C3); returns the current estimate (m/s, shape (2,)).

        Raises
        ------
        ValueError
            ``m.t`` before the previous measurement's time, a non-finite measurement, or
            actuator samples out of time order, outside the interval or not finite.
        """
        z = np.array([m.u, m.v, m.r], float)
        if not (np.all(np.isfinite(z)) and math.isfinite(m.psi)):
            raise ValueError(f"current observer: non-finite measurement at t = {m.t}")
        if self.s is None:  # the prior (C0), conditioned on this first measurement below
            self.s, self.P = self._prior(m)
        else:
            dt = m.t - self._last.t
            if dt < 0:
                raise ValueError(f"current observer: time went back ({self._last.t} -> {m.t})")
            if dt > 0:
                self._predict(dt, self._last, m)
        self._correct(z, m.psi)
        self._last = m
        return self.current

    def _prior(self, m: MotionMeasurement) -> tuple[np.ndarray, np.ndarray]:
        """The state's prior at the first measurement (C0): the current 0 +- ``sigma_c0``;
        the speed through the water +- ``sigma_nu0``, centred on the ground velocity while
        the propeller runs (a boat under way moves through the water) and on zero while it
        is off (a boat drifting moves with the water); the yaw rate as measured. Both means
        are guesses: how the ground velocity splits is learnt from the motion that follows
        (the hull's drag stops it in the water; the thrust holds a known speed), within
        0-21 s (``tests/test_current_observer.py``)."""
        P = self.params
        nu0 = (m.u, m.v) if m.propeller_on else (0.0, 0.0)
        s = np.array([*nu0, m.r, 0.0, 0.0])
        cov = np.diag([P.sigma_nu0**2, P.sigma_nu0**2, P.sigma_r**2,
                       P.sigma_c0**2, P.sigma_c0**2])  # fmt: skip
        return s, cov

    def _predict(self, dt: float, a: MotionMeasurement, b: MotionMeasurement) -> None:
        P = self.params
        known = a.actuators is not None and b.actuators is not None
        segments = _segments(a, b)
        if segments is not None:  # (C1) through the interval's samples
            q_nu = P.q_nu
        elif known:  # (C1) with the mean of the interval's two ends
            act = 0.5 * (np.asarray(a.actuators, float) + np.asarray(b.actuators, float))
            segments, q_nu = [(dt, act)], P.q_nu
        elif not (a.propeller_on or b.propeller_on):  # drifting: thrust 0, drive amidships
            segments, q_nu = [(dt, np.zeros(2))], P.q_nu
        else:  # propeller running, thrust unknown: the model cannot predict nu_r, which is
            # held (a random walk of q_blind): predicting it with the thrust at zero, as
            # before session 30, slowed it every step and the filter put the difference into
            # the current (0.58 m/s in still water after 2 minutes with sigma_c0 = 1)
            segments, q_nu = [], P.q_blind
        nu, J = self.s[0:3], np.eye(3)
        if segments:  # every RK4 sub-step's actuators and length, then one call of the chain
            n = [self._sub_steps(length) for length, _ in segments]
            A = np.repeat(np.array([act for _, act in segments]).T, n, axis=1)
            H = np.repeat([length / k for (length, _), k in zip(segments, n, strict=True)], n)
            m = len(H)
            if m not in self._chains:
                if len(self._chains) > 64:  # irregular samples: keep it bounded
                    self._chains.clear()
                self._chains[m] = self._step.mapaccum("current_obs_chain", m, 2)
            nus, Js = self._chains[m](nu, J, A, H[None, :])
            nu = np.asarray(nus[:, -1], float).ravel()
            J = np.asarray(Js[:, -3:], float)
        F = np.eye(NS)
        F[0:3, 0:3] = J
        self.s = np.concatenate([nu, self.s[3:5]])
        Q = np.diag([q_nu, q_nu, q_nu, P.q_c, P.q_c]) * dt
        self.P = F @ self.P @ F.T + Q

    def _sub_steps(self, length: float) -> int:
        """RK4 sub-steps over ``length`` s: each at most ``h_max``, more where the hull is
        stiff (a turn of Fossen's Otter)."""
        key = round(length, 9)
        if key not in self._n_sub:
            if len(self._n_sub) > 256:  # irregular intervals (a deploy): keep it bounded
                self._n_sub.clear()
            self._n_sub[key] = max(math.ceil(length / self.params.h_max - 1e-9),
                                   rk4_sub_steps(self.model, length, lags=False))  # fmt: skip
        return self._n_sub[key]

    def _correct(self, z: np.ndarray, psi: float) -> None:
        P = self.params
        c, s = math.cos(psi), math.sin(psi)
        H = np.array([[1.0, 0, 0, c, s], [0, 1.0, 0, -s, c], [0, 0, 1.0, 0, 0]])  # (C3)
        R = np.diag([P.sigma_v**2, P.sigma_v**2, P.sigma_r**2])
        S = H @ self.P @ H.T + R
        K = np.linalg.solve(S, H @ self.P).T
        self.s = self.s + K @ (z - H @ self.s)
        IKH = np.eye(NS) - K @ H
        self.P = IKH @ self.P @ IKH.T + K @ R @ K.T  # Joseph form
