"""Yaw autopilot tuning on the shared vessel model (``mpcasv tune yaw``).

Workflow, per surge speed ``u0``:

1. Linearise the shared model (:meth:`VesselModel.linearize`, exact CasADi Jacobians) about
   the straight-line trim at ``u0`` and hand the sway-yaw block, *including the steering lag*
   ``T_delta`` (a state of the model), to python-control as ``ss``.
2. Nomoto models of the hull (steering angle ``delta`` -> yaw rate ``r``): the second-order
   model ``K (1 + T3 s) / ((1 + T1 s)(1 + T2 s))`` is the exact transfer function of the
   linearised sway-yaw block; the first-order model ``K / (1 + T s)`` takes Nomoto's
   ``T = T1 + T2 - T3`` (Fossen 2021, eq. 7.19-7.20).
3. PID by pole placement on the first-order Nomoto model (derivative on the yaw rate): with
   ``psi/delta = K / (s (1 + T s))`` the closed loop's characteristic polynomial is
   ``T s^3 + (1 + K Kd) s^2 + K Kp s + K Ki``; it is matched to
   ``(s^2 + 2 zeta wn s + wn^2)(s + a)`` with the integral pole ``a = integral_ratio * wn``.
   ``integral_ratio`` defaults to 0.5, five times Fossen's textbook ``wn/10``: the thesis
   (§3.4.1) needed "a sufficiently large integral component" on the real boat, and a
   constant yaw moment is then trimmed out in a few closed-loop time constants.
4. Check on the loop as the execution level implements it (mpcasv/control/execution.py):
   ``delta_cmd = Kp e + Ki int(e) - Kd r_f``, ``r_f = r / (1 + T_f s)``, plant with the
   steering lag. Margins of the loop broken at the plant input (``stability_margins``,
   ``disk_margins``), step information of ``psi/psi_d``, rejection of a constant yaw
   moment, both for the continuous loop and for the sampled loop (plant with zero-order hold
   at the simulator's step, controller difference equations exactly as in
   :func:`mpcasv.control.execution.execution_law`).
5. Nonlinear check: a 45 deg heading step through :func:`mpcasv.control.execution.closed_loop`
   (the same compiled control law the simulator runs) with a far waypoint.
"""

from __future__ import annotations

import dataclasses
import math

import control as ct
import numpy as np

from mpcasv.config import replace
from mpcasv.control.params import ExecutionParams, YawSchedule
from mpcasv.models.vessel import IX, VesselModel

#: states of the yaw block handed to python-control (order kept in the ``ss`` models)
YAW_STATES = ("psi", "v", "r", "delta")
#: settling band of the nonlinear and linear heading steps (rad)
SETTLE_BAND = math.radians(2.0)


@dataclasses.dataclass(frozen=True)
class Nomoto:
    """First- and second-order Nomoto models of ``delta -> r`` at one speed (SI units)."""

    u0: float  # surge speed (m/s)
    K: float  # (rad/s)/rad
    T: float  # s, first-order time constant T1 + T2 - T3
    T1: float
    T2: float
    T3: float

    def first_order(self) -> ct.TransferFunction:
        """``r/delta = K / (1 + T s)``."""
        return ct.tf([self.K], [self.T, 1.0])

    def second_order(self) -> ct.TransferFunction:
        """``r/delta = K (1 + T3 s) / ((1 + T1 s)(1 + T2 s))``."""
        return ct.tf([self.K * self.T3, self.K], np.polymul([self.T1, 1.0], [self.T2, 1.0]))


@dataclasses.dataclass(frozen=True)
class PIDGains:
    """Yaw PID gains at one speed, as in ``[yaw]`` of the execution TOML."""

    Kp: float  # rad/rad
    Ki: float  # rad/(rad s)
    Kd: float  # rad/(rad/s)


def yaw_plant(model: VesselModel, u0: float) -> ct.StateSpace:
    """Linearised yaw dynamics at straight-line speed ``u0``, steering lag included.

    Returns
    -------
    control.StateSpace
        States ``psi, v, r, delta``; input ``delta_cmd`` (rad); outputs ``psi`` (rad) and
        ``r`` (rad/s).

    Raises
    ------
    ValueError
        If the yaw block is coupled to the other states at this trim (it is not, in still
        water, to first order): the block would then not be the whole story.
    """
    A, B = model.linearize(*model.trim(u0))
    idx = [IX[k] for k in YAW_STATES]
    rest = [i for i in range(A.shape[0]) if i not in idx]
    coupling = np.abs(A[np.ix_(idx, rest)]).max()
    if coupling > 1e-9:
        raise ValueError(f"yaw block coupled to surge/position at u0={u0} ({coupling:.2e})")
    C = np.zeros((2, 4))
    C[0, 0] = C[1, 2] = 1.0
    return ct.ss(
        A[np.ix_(idx, idx)], B[np.ix_(idx, [1])], C, np.zeros((2, 1)),
        states=list(YAW_STATES), inputs=["delta_cmd"], outputs=["psi", "r"],
        name=f"yaw_u{u0 * 100:.0f}cm_s",
    )  # fmt: skip


class CourseUnstable(ValueError):
    """The hull's sway-yaw block has no real Nomoto form at this speed (message: one line)."""


def nomoto(model: VesselModel, u0: float) -> Nomoto:
    """Nomoto models of the hull at ``u0`` from the linearised sway-yaw block.

    The transfer function from the steering angle (the lag state ``delta``) to ``r`` of the
    2x2 sway-yaw block is exactly second-order Nomoto; its poles ``p_i`` give ``T_i = -1/p_i``
    (``T1 >= T2``) and its zero ``T3``. A course-unstable hull (a pole > 0) has a
    negative time constant, ``T < 0``, and a negative ``K`` (``K/T`` > 0: the
    steering still turns the bow the right way); the pole placement of :func:`place_pid`
    works for it unchanged.

    Raises
    ------
    CourseUnstable
        Complex or zero sway-yaw poles, or a zero steady turn gain ``K`` (``r/delta`` with a
        zero at ``s = 0``: Fossen's Otter) or ``T = 0``: no first-order Nomoto model (the
        message names the speed, the poles and the cause,
        :mod:`mpcasv.control.tuning_refusals`).
    """
    from mpcasv.control.tuning_refusals import no_first_order, sway_yaw_why

    A, _ = model.linearize(*model.trim(u0))
    i2 = [IX["v"], IX["r"]]
    sys2 = ct.ss(A[np.ix_(i2, i2)], A[np.ix_(i2, [IX["delta"]])], [[0.0, 1.0]], [[0.0]])
    poles, zeros = ct.poles(sys2), ct.zeros(sys2)
    pol = ", ".join(f"{complex(p).real:+.3g}{complex(p).imag:+.3g}j" for p in poles)
    if np.any(np.abs(poles.imag) > 1e-9) or np.any(np.abs(poles.real) < 1e-9):
        raise CourseUnstable(f"sway-yaw poles {pol} 1/s at u0={u0:g} m/s: no real first-order "
                             "Nomoto model (complex or zero poles); "
                             + sway_yaw_why(A[np.ix_(i2, i2)], model.params))  # fmt: skip
    T1, T2 = sorted((-1.0 / poles.real).tolist(), reverse=True)
    T3 = float(-1.0 / zeros.real[0]) if len(zeros) else 0.0
    K = float(np.real(ct.dcgain(sys2)))
    T = T1 + T2 - T3
    if abs(K) < 1e-12 or abs(T) < 1e-9:
        raise CourseUnstable(no_first_order(A, u0, K, T, pol, poles, model.params))
    return Nomoto(u0=u0, K=K, T=T, T1=T1, T2=T2, T3=T3)


def target_polynomial(wn: float, zeta: float, integral_ratio: float) -> np.ndarray:
    """The requested closed-loop polynomial ``(s^2 + 2 zeta wn s + wn^2)(s + a)``,
    ``a = integral_ratio wn`` (1/s), coefficients from ``s^3`` down (module docstring)."""
    return np.polymul([1.0, 2 * zeta * wn, wn * wn], [1.0, integral_ratio * wn])


def closed_loop_polynomial(nm: Nomoto, g: PIDGains) -> np.ndarray:
    """The PID on the first-order Nomoto model: ``T s^3 + (1 + K Kd) s^2 + K Kp s + K Ki``."""
    return np.array([nm.T, 1.0 + nm.K * g.Kd, nm.K * g.Kp, nm.K * g.Ki])


def pid_formula(nm: Nomoto, wn: float, zeta: float, integral_ratio: float) -> PIDGains:
    """The gains that make :func:`closed_loop_polynomial` ``T`` times
    :func:`target_polynomial`, coefficient by coefficient, before any clipping."""
    K, T = nm.K, nm.T
    _, c2, c1, c0 = target_polynomial(wn, zeta, integral_ratio)
    return PIDGains(Kp=T * c1 / K, Ki=T * c0 / K, Kd=(T * c2 - 1.0) / K)


def place_pid(nm: Nomoto, wn: float, zeta: float, integral_ratio: float) -> PIDGains:
    """Pole placement of the PID on the first-order Nomoto model (:func:`pid_formula`).

    ``Kd`` is clipped at 0 (a negative derivative gain would mean the hull alone is faster
    than the requested poles; the execution level takes ``Kd >= 0``): the poles are then not
    the requested ones; :func:`mpcasv.control.tuning_schedule.kd_clip` says which they are.
    """
    K, T = nm.K, nm.T
    g = pid_formula(nm, wn, zeta, integral_ratio)
    if min(g.Kp, g.Ki) <= 0 or K / T <= 0:
        raise CourseUnstable(f"at u0={nm.u0:g} m/s the Nomoto model (K = {K:.3g} 1/s, T = "
                             f"{T:.3g} s) turns the bow against the steering (K/T <= 0): no PID "
                             "by pole placement")  # fmt: skip
    return dataclasses.replace(g, Kd=max(g.Kd, 0.0))


@dataclasses.dataclass(frozen=True)
class YawLoop:
    """The yaw loop at one speed as python-control systems (continuous or sampled).

    ``P`` maps ``delta_cmd`` to ``[psi, r]``; the controller is
    ``delta_cmd = C_pi (psi_d - psi) - C_d r``.
    """

    P: ct.StateSpace
    C_pi: ct.TransferFunction  # e -> delta (Kp + Ki/s)
    C_d: ct.TransferFunction  # r -> -delta (Kd / (1 + T_f s))

    @property
    def K_fb(self) -> ct.StateSpace:
        """Feedback part ``[psi, r] -> -delta_cmd`` = ``[C_pi, C_d]``."""
        both = ct.append(ct.ss(self.C_pi), ct.ss(self.C_d))
        return ct.ss([], [], [], [[1.0, 1.0]], dt=self.P.dt) * both

    @property
    def L(self) -> ct.StateSpace:
        """Loop transfer function broken at the plant input (delta_cmd)."""
        return self.K_fb * self.P

    @property
    def T_dist(self) -> ct.StateSpace:
        """Closed loop ``psi / d`` for a disturbance ``d`` added to the steering command."""
        return ct.feedback(self.P, self.K_fb)[0, 0]

    @property
    def T_ref(self) -> ct.StateSpace:
        """Closed loop ``psi / psi_d``."""
        return self.T_dist * ct.ss(self.C_pi)


def yaw_loop(P: ct.StateSpace, g: PIDGains, T_f: float, dt: float | None = None) -> YawLoop:
    """Build the loop from ``tf``/``ss`` (no ``rootlocus_pid_designer``: see issue 6).

    With ``dt`` the plant is sampled with a zero-order hold and the controller is the exact
    difference equations of :func:`mpcasv.control.execution.execution_law` (forward-Euler
    integrator and yaw-rate filter, ``r_f`` lagging one sample).
    """
    if dt is None:
        C_pi = ct.tf([g.Kp, g.Ki], [1.0, 0.0])
        C_d = ct.tf([g.Kd], [T_f, 1.0])
    else:
        a = dt / T_f
        C_pi = ct.tf([g.Kp, g.Ki * dt - g.Kp], [1.0, -1.0], dt)
        C_d = ct.tf([g.Kd * a], [1.0, a - 1.0], dt)
        P = ct.c2d(P, dt, "zoh")
    return YawLoop(P=P, C_pi=C_pi, C_d=C_d)


def loop_figures(loop: YawLoop, step: float = math.radians(45.0)) -> dict[str, float]:
    """Margins and step figures of a yaw loop (angles in deg, times in s, margins in dB).

    ``disk_*`` are the balanced (skew 0) disk margins of ``control.disk_margins``.
    ``dist_*``: response to a constant yaw moment equivalent to 5 deg of steering: peak
    heading deviation (deg) and the time after which it stays below 0.5 deg.
    """
    from mpcasv.control.tuning import loop_margins, settling_time, step_figures

    L = loop.L
    dt = L.dt if L.isdtime() else None
    T_ref = loop.T_ref
    poles = ct.poles(loop.T_dist)  # all the closed loop's states
    t = np.arange(0.0, 200.0, dt or 0.05)
    with np.errstate(over="ignore", invalid="ignore"):  # an unstable loop diverges: "inf"
        resp = ct.step_response(T_ref, t)
        dist = ct.step_response(loop.T_dist, t).outputs * math.radians(5.0)
    steps = step_figures(resp.outputs * step, t, step, SettlingTimeThreshold=SETTLE_BAND / step)
    return loop_margins(L) | steps | {
        "dist_peak_deg": float(np.degrees(np.abs(dist).max())) if np.isfinite(dist).all()
        else math.inf,
        "dist_recover_s": settling_time(t, dist, math.radians(0.5)),
        "stable": bool(np.all(np.abs(poles) < 1) if dt else np.all(poles.real < 0)),
    }  # fmt: skip


def schedule_params(ep: ExecutionParams, speeds, gains, T_f: float) -> ExecutionParams:
    """``ep`` with the yaw schedule replaced by ``gains`` at ``speeds``."""
    yaw = YawSchedule(
        speeds=tuple(float(s) for s in speeds),
        Kp=tuple(g.Kp for g in gains), Ki=tuple(g.Ki for g in gains),
        Kd=tuple(g.Kd for g in gains), T_f=T_f,
    )  # fmt: skip
    return replace(ep, yaw=yaw)


def heading_step(model: VesselModel, ep: ExecutionParams, u0: float,
                 step: float = math.radians(45.0), t_end: float = 120.0):  # fmt: skip
    """Nonlinear ``step`` heading change at straight-line speed ``u0`` (speed cap ``u0``).

    The vessel starts in trim heading north (the speed integrator too:
    :func:`mpcasv.control.tuning_speed.trim_integrator`); the waypoint is :data:`FAR` away at
    bearing ``step``, so the execution level (guidance, eq. 3.1, PID, speed loop) sees a heading
    step. Returns the :class:`mpcasv.control.tuning.Run` and its figures: ``settling_s``
    (±2 deg), ``overshoot_deg``, ``rise_s`` (10-90 %), ``max_delta_deg`` (of the vessel's
    ``delta_max_deg``), and ``min_u``,
    ``min_u_ref`` (m/s): the least surge speed and speed reference during the run. The step is
    also a speed change: eq. 3.1 cuts the speed reference to ``u_ff + k_u (pi/2 - |psi_e|)``
    (1.85 m/s at 45 deg with the field tuning), below ``u0`` at the faster speeds.
    """
    from mpcasv.control.tuning import FAR, run_closed_loop, settling_time
    from mpcasv.control.tuning_speed import trim_integrator

    x0, _ = model.trim(u0)
    run = run_closed_loop(model, ep, x0, (FAR * math.cos(step), FAR * math.sin(step)), u0, t_end,
                          I_u=trim_integrator(model, u0))  # fmt: skip
    err = run.psi_error
    turned = step - err  # heading change achieved
    i10 = int(np.argmax(turned >= 0.1 * step))
    i90 = int(np.argmax(turned >= 0.9 * step))
    return run, {
        "settling_s": settling_time(run.t, err, SETTLE_BAND),
        "overshoot_deg": float(np.degrees(max(0.0, -err.min()))),
        "rise_s": float(run.t[i90] - run.t[i10]) if turned.max() >= 0.9 * step else math.inf,
        "max_delta_deg": float(np.degrees(np.abs(run.X[:, 7]).max())),
        "min_u": float(run.X[:, IX["u"]].min()),
        "min_u_ref": float(run.Y[:, 1].min()),
        "delta_max_deg": math.degrees(model.params.delta_max),
    }


@dataclasses.dataclass(frozen=True)
class YawDesign:
    """Everything ``mpcasv tune yaw`` found at one speed."""

    u0: float
    wn: float
    zeta: float
    nomoto: Nomoto
    gains: PIDGains
    linear: dict  # continuous loop figures (loop_figures)
    sampled: dict  # sampled loop figures at the simulator's step
    nonlinear: dict  # 45 deg heading step with the whole schedule (heading_step)
    kd_clip: dict | None = None  # Kd clipped to 0: the poles achieved (tuning_schedule.kd_clip)


def tune_yaw(model: VesselModel, ep: ExecutionParams, speeds, wn, zeta: float = 1.0,
             integral_ratio: float = 0.5, T_f: float = 0.2, dt: float = 0.1,
             progress: bool = False):  # fmt: skip
    """Design the gain schedule and check it (linear and nonlinear) at every speed.

    Parameters
    ----------
    model : VesselModel
    ep : ExecutionParams
        Base parameters; the returned ones have the new ``[yaw]`` schedule.
    speeds : sequence of float
        Surge speeds (m/s), strictly increasing.
    wn : sequence of float
        Closed-loop natural frequency per speed (rad/s).
    zeta, integral_ratio, T_f : float
        Damping ratio, integral pole / ``wn``, yaw-rate filter time constant (s).
    dt : float
        Step (s) of the sampled-loop check (the nonlinear runs use the simulator's default
        step :data:`mpcasv.control.tuning.DT`).

    Returns
    -------
    (ExecutionParams, list[YawDesign], dict[float, Run])
    """
    from tqdm import tqdm

    from mpcasv.control.tuning_schedule import kd_clip

    speeds = [float(s) for s in speeds]
    check_speeds(model, speeds)
    noms = [nomoto(model, u) for u in speeds]
    gains = [place_pid(nm, w, zeta, integral_ratio) for nm, w in zip(noms, wn, strict=True)]
    ep_new = schedule_params(ep, speeds, gains, T_f)
    designs, runs = [], {}
    for u, w, nm, g in tqdm(list(zip(speeds, wn, noms, gains, strict=True)), desc="tune yaw",
                            disable=not progress):  # fmt: skip
        P = yaw_plant(model, u)
        linear, sampled = loop_figures(yaw_loop(P, g, T_f)), loop_figures(yaw_loop(P, g, T_f, dt))
        if nm.T < 0 and not (linear["stable"] and sampled["stable"]):
            p_max = max(-1.0 / nm.T1, -1.0 / nm.T2)
            raise CourseUnstable(
                f"hull course-unstable at u0={u:g} m/s (sway-yaw pole {p_max:+.2f} 1/s, Nomoto "
                f"T = {nm.T:.2f} s): the PID placed on the first-order Nomoto model (wn "
                f"{w:.2f} rad/s) does not stabilise the {'sampled ' if linear['stable'] else ''}"
                "loop with the steering lag; no schedule written"
            )
        run, nl = heading_step(model, ep_new, u)
        runs[u] = run
        designs.append(YawDesign(u0=u, wn=float(w), zeta=zeta, nomoto=nm, gains=g,
                                 linear=linear, sampled=sampled, nonlinear=nl,
                                 kd_clip=kd_clip(nm, g, w, zeta, integral_ratio)))  # fmt: skip
    return ep_new, designs, runs


def check_speeds(model: VesselModel, speeds, what: str = "speeds") -> None:
    """Refuse design speeds the vessel cannot hold (above its top speed at ``T_max``, or <= 0).

    Raises
    ------
    mpcasv.config.ConfigError
        One line naming ``what`` (the option), the speeds, the top speed and the vessel.
    """
    from mpcasv.config import ConfigError

    top = min(model.top_speed, model.params.u_max)
    bad = [u for u in speeds if not 0 < u <= top * (1 + 1e-6)]
    if bad:
        raise ConfigError(f"{what} {bad} m/s outside (0, {top:.3g}] m/s: {model.params.name} "
                          f"cannot hold them at T_max = {model.params.T_max:g} N")  # fmt: skip
