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
                    t_end: float, current=(0.0, 0.0), dt: float = DT,
                    transit: float = 1.0, I_u: float = 0.0) -> Run:  # fmt: skip
    """Run the execution level + vessel model from ``x0`` towards waypoint ``wp``
    (``transit``: the command's first entry, 2 for a collision-avoidance transit).

    The compiled closed loop is cached per (model, params, dt). The yaw integrator starts at
    zero, the speed integrator at ``I_u`` (N; :func:`mpcasv.control.tuning_speed.trim_integrator`
    is its trim value, which the feed-forward leaves to it) and ``r_f`` at the initial yaw rate.
    """
    key = (model.p.tobytes(), ep, dt)  # by value: an id() can be reused after GC
    if key not in _CL_CACHE:
        _CL_CACHE[key] = closed_loop(model, ep, dt, int(round(1.0 / dt)))
    CL = _CL_CACHE[key]
    x = np.asarray(x0, float)
    z = np.zeros(NZ)
    z[1], z[2] = I_u, x[5]
    cmd = np.array([transit, wp[0], wp[1], u_cap])
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


#: agreement demanded between python-control's margins and the frequency sweep
PM_TOL_DEG, GM_TOL_DB = 2.0, 1.0


def sweep_margins(L, omega) -> dict:
    """Classical margins of a SISO loop from its frequency response on the grid ``omega``.

    Gain crossovers (``|L| = 1``) and phase crossovers (phase = -180 deg mod 360) are located
    by sign changes on the grid and refined linearly. Returns ``phase_margin_deg`` (smallest
    over the gain crossovers; ``inf`` if ``|L|`` never crosses 1 on the grid) with its
    frequency, and ``gain_margin_db`` (smallest ``-20 log|L|`` over the phase crossovers;
    ``inf`` if none). Frequencies in rad/s; a sampled loop is evaluated at ``exp(j w dt)``.
    """
    H = np.asarray(L.frequency_response(omega).complex, complex).ravel()
    mag, ph = np.abs(H), np.unwrap(np.angle(H))
    out = {"phase_margin_deg": math.inf, "w_gain_crossover": math.nan,
           "gain_margin_db": math.inf, "w_phase_crossover": math.nan}  # fmt: skip
    lm = np.log(mag)
    for i in np.nonzero(np.sign(lm[:-1]) != np.sign(lm[1:]))[0]:
        f = lm[i] / (lm[i] - lm[i + 1])
        w = omega[i] + f * (omega[i + 1] - omega[i])
        phase = ph[i] + f * (ph[i + 1] - ph[i])
        pm = (math.degrees(phase) + 180.0 + 180.0) % 360.0 - 180.0
        if abs(pm) < abs(out["phase_margin_deg"]):
            out["phase_margin_deg"], out["w_gain_crossover"] = pm, float(w)
    s180 = (ph + math.pi) / (2 * math.pi)  # integer where the phase is -180 deg (mod 360)
    for i in np.nonzero(np.floor(s180[:-1]) != np.floor(s180[1:]))[0]:
        k = max(np.floor(s180[i]), np.floor(s180[i + 1]))
        f = (k - s180[i]) / (s180[i + 1] - s180[i])
        w = omega[i] + f * (omega[i + 1] - omega[i])
        gm = -20 * math.log10(mag[i] + f * (mag[i + 1] - mag[i]))
        if gm < out["gain_margin_db"]:
            out["gain_margin_db"], out["w_phase_crossover"] = gm, float(w)
    return out


#: the start of python-control's warning when it computes a sampled loop's margins from its
#: frequency response instead of polynomial roots (control.margins, 0.10)
FRD_FALLBACK = "stability_margins: Falling back to 'frd' method"


#: what ``margin_method`` says after scipy's BadCoefficients warning inside python-control
ILL = " (badly conditioned coefficients)"


def _stability_margins(L) -> tuple[float, float, float, float, str]:
    """``control.stability_margins(L)`` as (gm, pm, w_phase_crossover, w_gain_crossover,
    method): its fallback warning (:data:`FRD_FALLBACK`) becomes ``method = "frd"``, scipy's
    ``BadCoefficients`` (near-zero leading coefficients of the loop's transfer function: a
    speed PI with ``Kp = 0``, four lines of stderr per loop) appends :data:`ILL` to it (the
    frequency sweep of :func:`loop_margins` checks those margins); any other warning is
    passed on unchanged."""
    import warnings

    import control as ct
    from scipy.signal import BadCoefficients

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gm, pm, _, wg, wp, _ = ct.stability_margins(L)
    method, ill = "poly", ""
    for w in caught:
        if issubclass(w.category, UserWarning) and str(w.message).startswith(FRD_FALLBACK):
            method = "frd"
        elif issubclass(w.category, BadCoefficients):
            ill = ILL
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno, source=w.source)
    return gm, pm, wg, wp, method + ill


#: the frequency sweep's grid density (points per decade) and its lowest possible start (rad/s)
SWEEP_PER_DECADE, SWEEP_LOWEST = 3000, 1e-12


def sweep_floor(L, crossovers) -> float:
    """Where the frequency sweep of :func:`loop_margins` starts (rad/s): 1e-4, or two decades
    below the lowest finite crossover python-control found (``crossovers``, rad/s), and lower
    still, a decade at a time down to :data:`SWEEP_LOWEST`, while the loop's gain is below 10
    and still rising towards low frequency (an integrator whose crossover lies below: a speed
    PI with ``Ki ~ 1e-5`` crosses over at 1e-7 rad/s, and a sweep from 1e-4 found none and
    reported PM "inf")."""
    def gain(w: float) -> float:
        return float(np.abs(np.asarray(L.frequency_response([w]).complex).ravel()[0]))

    lo = min([1e-4, *(w / 100 for w in crossovers if np.isfinite(w) and w > 0)])
    while lo > SWEEP_LOWEST * (1 + 1e-9) and gain(lo) < 10 and gain(lo / 10) > 2 * gain(lo):
        lo /= 10
    return lo


def loop_margins(L) -> dict:
    """Classical and balanced disk margins of an open loop ``L`` (continuous or sampled).

    ``control.stability_margins`` is cross-checked against :func:`sweep_margins` on a dense
    grid from :func:`sweep_floor` (below every crossover) up to 1e3 rad/s, or to Nyquist for
    a sampled loop. Where they disagree (python-control 0.10's
    discrete-time margins miss gain crossovers: ``inf`` where the loop has one, see
    ../shared/cases/sampled-phase-margin) the sweep's value is reported and
    ``margin_check`` says so; a margin neither can compute is ``nan``, which fails every
    ``>=`` acceptance test. ``margin_method`` is the method python-control used: ``"poly"``,
    or ``"frd"`` where it judged its polynomial method numerically unreliable for the sampled
    loop (its "Falling back to 'frd'" warning, caught here and said in the report), followed
    by :data:`ILL` after scipy's ``BadCoefficients`` warning (caught, said in the report);
    its other warnings are not silenced.
    ``disk_*`` are the skew-0 disk margins of ``control.disk_margins`` (gain margin in dB, as
    python-control returns it); frequencies in rad/s.
    """
    import control as ct

    gm, pm, wg, wp, method = _stability_margins(L)
    dt = L.dt if L.isdtime() else None
    lo = sweep_floor(L, (wg, wp))
    top = math.log10(math.pi / dt if dt else 1e3) - 1e-6
    omega = np.logspace(math.log10(lo) + 1, top - (0 if dt else 1), 2000)
    sweep = sweep_margins(L, np.logspace(math.log10(lo), top,
                                         int(SWEEP_PER_DECADE * (top - math.log10(lo)))))
    lib = {"gain_margin_db": 20 * math.log10(gm) if np.isfinite(gm) and gm > 0 else
           (math.inf if gm == math.inf else math.nan),
           "phase_margin_deg": float(pm)}  # fmt: skip
    notes = []
    for key, tol in (("phase_margin_deg", PM_TOL_DEG), ("gain_margin_db", GM_TOL_DB)):
        a, b = lib[key], sweep[key]
        same = (a == b) if (math.isinf(a) or math.isinf(b)) else abs(a - b) <= tol
        if not same:
            notes.append(f"{key}: python-control {a:.4g}, sweep {b:.4g} (sweep used)")
            lib[key] = b
    dm, dgm, dpm = ct.disk_margins(L, omega, skew=0.0)
    return {
        "gain_margin_db": lib["gain_margin_db"],
        "phase_margin_deg": lib["phase_margin_deg"],
        "w_gain_crossover": float(sweep["w_gain_crossover"]) if notes else float(wp),
        "w_phase_crossover": float(sweep["w_phase_crossover"]) if notes else float(wg),
        "margin_check": "; ".join(notes) if notes else "python-control = sweep",
        "margin_method": method,
        "disk_margin": float(dm),
        "disk_gain_margin_db": float(dgm),
        "disk_phase_margin_deg": float(dpm),
    }


def step_figures(y, t, yfinal: float, **kw) -> dict:
    """Rise, settling time (s) and overshoot (%) of a step response ``y(t)`` towards ``yfinal``.

    ``control.step_info`` where the response settles; a response that diverges or does not
    settle within ``t`` reports ``inf`` ("not reached") instead of failing in the library.
    """
    import control as ct

    y = np.asarray(y, float).ravel()
    band = kw.get("SettlingTimeThreshold", 0.02) * abs(yfinal)
    if not np.all(np.isfinite(y)) or abs(y[-1] - yfinal) > band:
        over = 100 * (np.nanmax(y) / yfinal - 1) if np.all(np.isfinite(y)) else math.inf
        reached = np.nonzero(y >= 0.9 * yfinal)[0]
        rise = float(t[reached[0]] - t[np.argmax(y >= 0.1 * yfinal)]) if len(reached) else math.inf
        return {"rise_s": rise, "settling_s": math.inf, "overshoot_pct": max(float(over), 0.0)}
    info = ct.step_info(y, t, yfinal=yfinal, **kw)
    return {
        "rise_s": float(info["RiseTime"]),
        "settling_s": float(info["SettlingTime"]),
        "overshoot_pct": float(info["Overshoot"]),
    }


def settling_time(t: np.ndarray, err: np.ndarray, band: float) -> float:
    """First time after which ``|err| <= band`` until the end (``inf`` if never; a non-finite
    error, a response that diverged, is outside the band)."""
    outside = np.nonzero(~(np.abs(err) <= band))[0]
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
