"""Shared pieces of the tuning tools: nonlinear closed-loop runs and the execution TOML.

The nonlinear checks run the execution level exactly as the simulator does, through
:func:`mpcasv.control.execution.closed_loop` (the compiled CasADi unrolling of guidance, speed
reference model, yaw PID, speed loop and the shared vessel model); nothing here re-implements
the control law. The yaw tuning is in :mod:`mpcasv.control.tuning_yaw`, the speed loop and the
surge-speed reference model in :mod:`mpcasv.control.tuning_speed`.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from mpcasv.control.execution import NZ, closed_loop, wrap
from mpcasv.control.params import ExecutionParams
from mpcasv.models.vessel import VesselModel

#: plant step of the nonlinear checks (s): the simulator's default ``sim.dt``
DT = 0.1
#: distance of the "far" waypoint of heading steps (m): line-of-sight heading then moves by
#: less than 0.05 deg over the whole run
FAR = 1.0e5


@dataclasses.dataclass(frozen=True)
class Run:
    """A nonlinear closed-loop run sampled at the plant step."""

    t: np.ndarray  # s, after each plant step (first sample: the initial state at t = 0)
    X: np.ndarray  # (n, NX) states
    U: np.ndarray  # (n, 2) actuator set-points applied up to that sample
    Y: np.ndarray  # (n, 2) [psi_d, u_ref]

    @property
    def psi_error(self) -> np.ndarray:
        """``psi_d - psi`` wrapped to (-pi, pi] (rad)."""
        return np.asarray(wrap(self.Y[:, 0] - self.X[:, 2]), float).ravel()

    @property
    def distance(self) -> np.ndarray:
        """Path length travelled since t = 0 (m)."""
        steps = np.hypot(np.diff(self.X[:, 0]), np.diff(self.X[:, 1]))
        return np.concatenate([[0.0], np.cumsum(steps)])


_CL_CACHE: dict = {}


def run_closed_loop(model: VesselModel, ep: ExecutionParams, x0, wp, u_cap: float,
                    t_end: float, current=(0.0, 0.0), dt: float = DT) -> Run:  # fmt: skip
    """Run the execution level + vessel model from ``x0`` towards waypoint ``wp``.

    The compiled closed loop is cached per (model, params, dt). Integrators start at zero
    (the speed loop has the trim thrust as feed-forward) and ``r_f`` at the initial yaw rate.
    """
    key = (model.p.tobytes(), ep, dt)  # by value: an id() can be reused after GC
    if key not in _CL_CACHE:
        _CL_CACHE[key] = closed_loop(model, ep, dt, int(round(1.0 / dt)))
    CL = _CL_CACHE[key]
    x = np.asarray(x0, float)
    z = np.zeros(NZ)
    z[2] = x[5]
    cmd = np.array([1.0, wp[0], wp[1], u_cap])
    c = np.asarray(current, float)
    Xs, Us, Ys = [x[None, :]], [np.zeros((1, 2))], [np.full((1, 2), np.nan)]
    for _ in range(int(math.ceil(t_end))):
        x, z, X, U, Y = CL(x, z, cmd, c)
        x, z = np.array(x).ravel(), np.array(z).ravel()
        Xs.append(np.array(X).T)
        Us.append(np.array(U).T)
        Ys.append(np.array(Y).T)
    X, U, Y = np.vstack(Xs), np.vstack(Us), np.vstack(Ys)
    Y[0] = Y[1]
    U[0] = U[1]
    return Run(t=np.arange(len(X)) * dt, X=X, U=U, Y=Y)


def loop_margins(L) -> dict:
    """Classical and balanced disk margins of an open loop ``L`` (continuous or sampled).

    ``disk_*`` are the skew-0 disk margins of ``control.disk_margins`` (gain margin in dB, as
    python-control returns it); frequencies in rad/s.
    """
    import warnings

    import control as ct

    with warnings.catch_warnings():  # 'frd' fallback notes
        warnings.simplefilter("ignore", UserWarning)
        gm, pm, _, wg, wp, _ = ct.stability_margins(L)
    dt = L.dt if L.isdtime() else None
    omega = np.logspace(-3, math.log10(math.pi / dt if dt else 100.0) - 1e-6, 2000)
    dm, dgm, dpm = ct.disk_margins(L, omega, skew=0.0)
    return {
        "gain_margin_db": 20 * math.log10(gm) if np.isfinite(gm) else math.inf,
        "phase_margin_deg": float(pm),
        "w_gain_crossover": float(wp),  # |L| = 1 (phase margin frequency)
        "w_phase_crossover": float(wg),
        "disk_margin": float(dm),
        "disk_gain_margin_db": float(dgm),
        "disk_phase_margin_deg": float(dpm),
    }


def step_figures(info: dict) -> dict:
    """Rise, settling time (s) and overshoot (%) from ``control.step_info``."""
    return {
        "rise_s": float(info["RiseTime"]),
        "settling_s": float(info["SettlingTime"]),
        "overshoot_pct": float(info["Overshoot"]),
    }


def settling_time(t: np.ndarray, err: np.ndarray, band: float) -> float:
    """First time after which ``|err| <= band`` until the end (``inf`` if never)."""
    outside = np.nonzero(np.abs(err) > band)[0]
    if len(outside) == 0:
        return 0.0
    if outside[-1] == len(err) - 1:
        return math.inf
    return float(t[outside[-1] + 1])


def write_execution_toml(path: Path, ep: ExecutionParams, header: list[str]) -> None:
    """Write execution parameters as TOML with a comment header (provenance in the file).

    The file round-trips through :func:`mpcasv.control.params.load_execution`.
    """

    def value(v) -> str:
        if isinstance(v, str):
            return json.dumps(v, ensure_ascii=False)
        if isinstance(v, tuple | list):
            return "[" + ", ".join(f"{float(x):.6g}" for x in v) + "]"
        return f"{float(v):.6g}"

    top, tables = [], []
    for f in dataclasses.fields(ep):  # generic: follows ExecutionParams as it evolves
        v = getattr(ep, f.name)
        if dataclasses.is_dataclass(v):
            tables += ["", f"[{f.name}]"]
            tables += [f"{g.name} = {value(getattr(v, g.name))}" for g in dataclasses.fields(v)]
        else:
            top.append(f"{f.name} = {value(v)}")
    body = "\n".join([*top, *tables, ""])
    text = "".join(f"# {line}\n" if line else "#\n" for line in header)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text + body)
