"""A vessel's manoeuvring envelope and its fastest poles: what bounds an explicit integrator's
step (the MPC plan's RK4 sub-steps, the simulator's plant step).

Classic RK4 is stable on a real pole ``lambda`` while ``|lambda h| < 2.785``
(:data:`RK4_STABLE`, where ``|R(z)| = 1`` on the negative real axis). The poles of a hull with
quadratic damping grow with its speeds: the yaw pole of ``N_rr |r| r`` is ``2 N_rr |r|`` over
the yaw inertia, so a hull that is slow on a straight line can be stiff in a turn. Fossen's
Otter: 3.6 1/s at its top speed straight ahead, 16.5 1/s in a full-steering turn (18.0 with
the steerable-drive mapping of ../shared/cases/vessels/otter.toml) (docs/mpc.md, "Known
problems"). The envelope is therefore sampled along manoeuvres, not only at
straight-line trims.

Not sampled (a session-9 review): speeds through the water above top speed (a boat running
with a current it does not know of), astern thrust (no shipped vessel has ``T_min < 0``) and
complex poles' smaller RK4 bound (2.62 at 122 degrees). Gretha's 4 plan sub-steps of 1 s
leave no margin there: from a top-speed trim in an unmodelled 0.6 m/s current a plan stage was
off by 100, as it was before this module. Since session 32 the plan's dynamics see the state
through :func:`mpcasv.mpc.dynamics.water_guard`, which keeps the speeds through the water
within the envelope's reach (widened by the planned current): such a stage stays finite and
bounded, though not accurate.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

#: |lambda h| on the negative real axis where classic RK4's gain reaches 1 (2.7853)
RK4_STABLE = 2.785
#: largest |lambda h| of an RK4 step with a margin (the plan's sub-steps on straight-line
#: trims, the plant's steps)
RK4_LAMBDA_H = 2.5
#: manoeuvres of the envelope: seconds simulated, the sampling interval and the RK4 step (s)
T_MANOEUVRE, T_SAMPLE, H_FINE = 60.0, 0.25, 0.01
N_TRIMS = 13  # straight-line trims from rest to u_max


def trim_states(model) -> np.ndarray:
    """Straight-line trims heading north at ``N_TRIMS`` speeds from rest to ``u_max``
    (``N_TRIMS x 8``)."""
    return np.array([model.trim(u)[0] for u in np.linspace(0.0, model.params.u_max, N_TRIMS)])


def turn_states(model) -> np.ndarray:
    """States (``n x 8``) of full-steering turns in still water, sampled every ``T_SAMPLE`` s
    over ``T_MANOEUVRE`` s: steering ``+-delta_max`` at full and half thrust, from rest and from
    the trim at top speed, the actuators following their set-points through their lags as in
    the plant. Integrated by RK4 in steps of ``H_FINE`` (stable up to 278 1/s, 15 times the
    Otter's fastest pole), in one CasADi call per manoeuvre.

    Raises ValueError if a manoeuvre leaves the finite numbers (the message names the vessel).
    """
    P = model.params
    n = round(T_MANOEUVRE / T_SAMPLE)
    step = model.rk4(T_SAMPLE, round(T_SAMPLE / H_FINE))  # an explicit count: no recursion
    run = step.mapaccum("turn", n, [0], [0])  # the state accumulated, u and c repeated
    starts = [np.zeros(8), model.trim(min(P.u_max, model.top_speed))[0]]
    out = []
    for T in (P.T_max, 0.5 * P.T_max):
        for delta in (P.delta_max, -P.delta_max):
            U = np.tile([[T], [delta]], (1, n))
            for x0 in starts:
                X = np.asarray(run(x0, U, np.zeros((2, n)))).T
                if not np.all(np.isfinite(X)):
                    raise ValueError(f"vessel {P.name}: a full-steering turn (T = {T:g} N, "
                                     f"delta = {delta:g} rad) cannot be integrated in RK4 "
                                     f"steps of {H_FINE} s")  # fmt: skip
                out.append(np.vstack([x0, X]))
    return np.vstack(out)


def fastest_pole(model, states: np.ndarray, n: int = 6) -> float:
    """Largest |eigenvalue| (1/s) of the model's Jacobian's first ``n`` states (6: the rigid
    body N..r with the actuators held; 8: with the actuators' lags) over ``states``
    (``m x 8``), the actuator set-points at the actuators' states (one mapped CasADi call)."""
    m = len(states)
    A = np.asarray(model.jacobians.map(m)(states.T, states[:, 6:8].T, np.zeros((2, m)))[0])
    A = A.reshape(8, m, 8).transpose(1, 0, 2)  # (m, 8, 8): the blocks side by side
    return float(np.abs(np.linalg.eigvals(A[:, :n, :n])).max())


class Poles(NamedTuple):
    """Fastest poles (1/s) of a vessel: ``trim`` at straight-line trims, ``envelope`` over
    trims and turns (rigid body), ``plant`` over both with the actuators' lags."""

    trim: float
    envelope: float
    plant: float


_POLES: dict[bytes, Poles] = {}


def poles(model) -> Poles:
    """The vessel's :class:`Poles`, computed once per process and parameter vector (about
    0.1 s).

    Raises
    ------
    ValueError
        A full-steering turn cannot be integrated (:func:`turn_states`).
    """
    key = model.p.tobytes()
    if key not in _POLES:
        states = envelope_states(model)
        trims = states[:N_TRIMS]
        _POLES[key] = Poles(fastest_pole(model, trims), fastest_pole(model, states),
                            fastest_pole(model, states, n=8))  # fmt: skip
    return _POLES[key]


_STATES: dict[bytes, np.ndarray] = {}


def envelope_states(model) -> np.ndarray:
    """The manoeuvring envelope's states (``m x 8``): :func:`trim_states` and
    :func:`turn_states`, computed once per process and parameter vector. Raises ValueError as
    :func:`turn_states`."""
    key = model.p.tobytes()
    if key not in _STATES:
        _STATES[key] = np.vstack([trim_states(model), turn_states(model)])
    return _STATES[key]


def sub_steps(dt: float, pole: float, bound: float) -> int:
    """Fewest RK4 sub-steps of a step of ``dt`` s with ``pole h <= bound`` (``pole`` in 1/s,
    ``bound`` :data:`RK4_STABLE` or :data:`RK4_LAMBDA_H`); at least 1."""
    return max(1, math.ceil(dt * pole / bound - 1e-9))


def rk4_sub_steps(model, dt: float, lags: bool = True) -> int:
    """RK4 sub-steps for a step of ``dt`` s on ``model``: ``|lambda|max h <= RK4_LAMBDA_H``
    (2.5, inside RK4's stability bound 2.785) on the vessel's fastest pole over its
    manoeuvring envelope, with the actuators' lags (``lags``: the plant, :meth:`VesselModel.
    rk4`) or without (the actuators at their set-points: the current observer). A stiff hull
    or a long step is integrated more finely instead of diverging in a full-steering turn
    (Fossen's Otter, 16.5 1/s: 1 sub-step of 0.1 s, 2 of 0.2 s; Gretha 1 up to 0.75 s).
    Raises ValueError as :func:`poles`."""
    p = poles(model)
    return sub_steps(dt, p.plant if lags else p.envelope, RK4_LAMBDA_H)


def course_instability(model) -> tuple[float, float] | None:
    """``(u, lambda)``: the lowest straight-line speed (m/s) at which the sway-yaw subsystem has
    an eigenvalue with positive real part, and the largest such real part (1/s) up to
    ``u_max`` (the trims of :func:`trim_states`); None for a course-stable hull. Fossen's
    Otter: from 0.26 m/s (the first trim), +2.6 1/s (cross-flow drag only, no linear
    sway damping); Gretha and dune-otter: None."""
    out = []
    for x in trim_states(model)[1:]:
        lam = float(np.max(model.sway_yaw_eigenvalues(x[3]).real))
        if lam > 1e-9:
            out.append((float(x[3]), lam))
    return (out[0][0], max(lam for _, lam in out)) if out else None
