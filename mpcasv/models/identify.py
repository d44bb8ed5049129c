"""Identification of the 3-DOF vessel parameters from logged manoeuvres (``mpcasv identify``).

Log formats
-----------
CSV or parquet (``mpcasv simulate --manoeuvre`` writes them), one row per sample, columns:

======== ====== ===============================================================
``t``    s      time, strictly increasing (resampled to its median step)
``N, E`` m      position in a local NED frame (used for plots only)
``psi``  rad    heading from north
``u, v`` m/s    body-axis velocity over ground (surge, sway)
``r``    rad/s  yaw rate
``T_cmd`` N     propeller thrust set-point
``delta_cmd`` rad  steering set-point (+ turns the bow to starboard)
======== ====== ===============================================================

Extra columns are ignored. DUNE logs (``.lsf``, ``.lsf.gz``) are read by
:func:`mpcasv.io.lsf.read_lsf` and mapped: navigation from EstimatedState, ``T_cmd`` =
SetThrusterActuation id 0 (fraction) x ``T_max`` of the prior, ``delta_cmd`` = SetServoPosition
id 0. DUNE logs the messages it receives, so a boat's log holds other vehicles' states too:
``vehicle`` (``--vehicle NAME|ID``: Announce name, or IMC id as ``0x2801`` or decimal) picks
one; by default the one vehicle that carries the actuator set-points (SetThrusterActuation) is
taken and named on stdout. A log with several steering servos on the chosen vehicle (an AUV's
fins, such as the shared DUNE LAUV log), of a submerged vehicle, or with no or several
vehicles carrying set-points and no ``--vehicle`` is refused with a :class:`LogError`: the 3-DOF
model is that of a surface vessel with one steerable drive.

Method
------
Actuator states are reconstructed from the set-points through the model's known lags. Then

1. equation error: ``f_param(x_k, u_k, c, p)[u, v, r]`` against Savitzky-Golay derivatives of
   the measured velocities, nonlinear least squares from the prior;
2. simulation error: the logged inputs are replayed through the shared model (RK4 of
   ``VesselModel.f_param`` with a symbolic parameter vector, built once as one CasADi function
   of the parameters, mapped over windows re-initialised from the smoothed measurement every
   ``window`` seconds), ``scipy.optimize.least_squares`` with CasADi's exact Jacobian;
3. validation: the last ``validation`` fraction of every log is held out and replayed the same
   way; fit = ``100 (1 - |y - y_sim| / |y - mean(y)|)`` per channel.

The unknown constant current ``[V_N, V_E]`` is estimated with the parameters.

Identified subset (:data:`IDENTIFIED`) and why: the added masses ``X_udot, Y_vdot, N_rdot``
(``m`` and ``I_z`` are weighed/computed, so the total mass terms ``m11 = m - X_udot``, ``m22 = m
- Y_vdot``, ``m33 = I_z - N_rdot`` are what is identified), the surge resistance ``X_u, X_uu``,
the speed-proportional (Clarke) sway and yaw damping ``Y_uv, N_ur``, which dominate the damping
at the operating speeds, and the steering lift ``Y_uudelta``. Held at the prior: the cross terms
``Y_ur`` and ``N_uv`` (in zig-zags and turns v and r move nearly in proportion, so ``Y_ur``
trades off against ``Y_uv``: identified together on noisy simulator data they were off by up to
33 %, and ``N_uv`` by up to 75 %; that was measured before the window initial states were
estimated, and has not been re-tested since), the low-speed damping ``Y_v, Y_r, N_v, N_r`` and
cross-flow drag ``Y_vv, N_rr`` (nearly collinear with the speed-proportional terms in zig-zags
and turns at one speed), the off-diagonal added masses and ``x_g`` (weakly excited), geometry
``x_p`` and the actuator lags (from the actuators' data, not the hull).
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import casadi as ca
import numpy as np
import pandas as pd
from scipy.optimize import least_squares
from scipy.signal import savgol_filter

from mpcasv.errors import LogError
from mpcasv.models.params import MODEL_COEFFS, VesselParams
from mpcasv.models.vessel import IX, NX, VesselModel, rk4_expr

IDENTIFIED = ("X_udot", "Y_vdot", "N_rdot", "X_u", "X_uu", "Y_uv", "N_ur", "Y_uudelta")
DAMPING = ("X_u", "X_uu", "Y_uv", "N_ur")
REQUIRED = ("t", "N", "E", "psi", "u", "v", "r", "T_cmd", "delta_cmd")
OUTPUTS = ("psi", "u", "v", "r")


def mass_terms(p: VesselParams) -> dict[str, float]:
    """Total (rigid-body + added) mass terms ``m11, m22, m33`` (kg, kg, kg m^2)."""
    return {"m11": p.m - p.X_udot, "m22": p.m - p.Y_vdot, "m33": p.I_z - p.N_rdot}


# --- loading -----------------------------------------------------------------------------


def load_log(path: Path, prior: VesselParams, vehicle: str | None = None) -> pd.DataFrame:
    """Read one log into the identification table (uniform time step).

    ``vehicle`` selects one vehicle of a DUNE log (name or IMC id); see the module docstring.

    Raises
    ------
    LogError
        Unreadable file, missing columns, bad time axis, non-finite values, too short, or a
        DUNE log this model does not apply to; the message names the file.
    """
    path = Path(path)
    if not path.is_file():
        raise LogError(f"{path}: no such log file")
    name = path.name.lower()
    if name.endswith((".lsf", ".lsf.gz")):
        df = _from_lsf(path, prior, vehicle)
    elif name.endswith(".csv"):
        try:
            df = pd.read_csv(path)
        except (pd.errors.ParserError, UnicodeDecodeError, pd.errors.EmptyDataError) as exc:
            raise LogError(f"{path}: not a readable CSV ({exc})") from None
    elif name.endswith(".parquet"):
        try:
            df = pd.read_parquet(path)
        except Exception as exc:  # pyarrow raises several types for corrupt files
            raise LogError(f"{path}: not a readable parquet file ({exc})") from None
    else:
        raise LogError(f"{path}: unknown log format (expected .csv, .parquet, .lsf, .lsf.gz)")
    missing = [c for c in REQUIRED if c not in df.columns]
    if missing:
        raise LogError(f"{path}: missing columns {missing} (identification format: "
                       f"{', '.join(REQUIRED)})")  # fmt: skip
    df = df[list(REQUIRED)].apply(pd.to_numeric, errors="coerce")
    bad = [c for c in REQUIRED if not np.isfinite(df[c].to_numpy(float)).all()]
    if bad:
        raise LogError(f"{path}: non-numeric or missing values in {bad}")
    t = df["t"].to_numpy(float)
    if len(t) < 100:
        raise LogError(f"{path}: too short ({len(t)} samples; at least 100 needed)")
    if np.any(np.diff(t) <= 0):
        raise LogError(f"{path}: time column t is not strictly increasing")
    dt = float(np.median(np.diff(t)))
    grid = np.arange(t[0], t[-1] + 1e-9, dt)
    out = pd.DataFrame({"t": grid - grid[0]})
    psi = np.unwrap(df["psi"].to_numpy(float))
    for c in REQUIRED[1:]:
        src = psi if c == "psi" else df[c].to_numpy(float)
        kind = "previous" if c in ("T_cmd", "delta_cmd") else "linear"
        out[c] = _resample(t, src, grid, kind)
    return out


def _resample(t, y, grid, kind):
    if kind == "linear":
        return np.interp(grid, t, y)
    idx = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, len(t) - 1)
    return y[idx]  # zero-order hold of set-points


def _vehicle_id(text: str) -> int | None:
    try:
        return int(text, 0)
    except ValueError:
        return None


def pick_vehicle(df: pd.DataFrame, path, vehicle: str | None = None) -> str:
    """The vehicle of a multi-vehicle DUNE log to identify (its ``vehicle`` name).

    With ``vehicle`` (a name, or an IMC id such as ``0x2801`` or ``10241``) that one; without,
    the single vehicle whose rows carry thrust set-points (``thrust_0``), printed.

    Raises
    ------
    LogError
        Unknown vehicle; none or several vehicles carry set-points and none was named.
    """
    names = sorted(set(df["vehicle"]))
    if vehicle is not None:
        if vehicle in names:
            return vehicle
        vid = _vehicle_id(vehicle)
        hit = sorted(set(df.loc[df["src"] == vid, "vehicle"])) if vid is not None else []
        if len(hit) == 1:
            return hit[0]
        raise LogError(f"{path}: no vehicle {vehicle!r} in the log (vehicles: "
                       f"{', '.join(names)})")  # fmt: skip
    if "thrust_0" in df.columns:
        actuated = sorted(set(df.loc[df["thrust_0"].notna(), "vehicle"]))
    else:
        actuated = []
    if len(names) == 1 and len(actuated) <= 1:
        return names[0]
    if len(actuated) != 1:
        raise LogError(f"{path}: {len(names)} vehicles ({', '.join(names)}), {len(actuated)} "
                       "with thrust set-points: name one with --vehicle")  # fmt: skip
    print(f"{path}: {len(names)} vehicles ({', '.join(names)}); identifying '{actuated[0]}', "
          "the one with actuator set-points (--vehicle to choose)")  # fmt: skip
    return actuated[0]


def _from_lsf(path: Path, prior: VesselParams, vehicle: str | None = None) -> pd.DataFrame:
    from mpcasv.io.lsf import read_lsf

    df = read_lsf(path)
    chosen = pick_vehicle(df, path, vehicle)
    df = df[df["vehicle"] == chosen]
    vehicles = [chosen]
    if (df["depth"] > 0.5).mean() <= 0.05 and prior.actuation == "differential":
        return _differential_inputs(df, path, prior)
    fins = sorted(c for c in df.columns if c.startswith("fin_cmd_") and df[c].notna().any())
    if len(fins) > 1:
        raise LogError(
            f"{path}: {len(fins)} steering servos ({', '.join(fins)}) on '{vehicles[0]}': a "
            "finned vehicle such as an AUV, not a surface vessel with one steerable drive; the "
            "3-DOF surface model does not apply (expected SetServoPosition id 0 only)"
        )
    if (df["depth"] > 0.5).mean() > 0.05:
        raise LogError(
            f"{path}: '{vehicles[0]}' is submerged (depth up to "
            f"{df['depth'].max():.1f} m): the 3-DOF surface model does not apply"
        )
    for col, msg in (("thrust_0", "SetThrusterActuation id 0"), ("fin_cmd_0", "SetServoPosition "
                     "id 0")):  # fmt: skip
        if col not in df.columns or df[col].isna().all():
            raise LogError(f"{path}: missing messages: no {msg} (thrust/steering set-points)")
    df = df.dropna(subset=["thrust_0", "fin_cmd_0"])
    return pd.DataFrame({
        "t": df["t"], "N": df["N"], "E": df["E"], "psi": df["psi"], "u": df["u"], "v": df["v"],
        "r": df["r"], "T_cmd": df["thrust_0"].astype(float) * prior.T_max,
        "delta_cmd": df["fin_cmd_0"].astype(float),
    })  # fmt: skip


def _differential_inputs(df: pd.DataFrame, path, prior: VesselParams) -> pd.DataFrame:
    """Two fixed thrusters (prior ``actuation = "differential"``): SetThrusterActuation id 0
    (port) and id 1 (starboard), fractions ``a_0, a_1`` of each thruster's ``T_max / 2``:
    ``T_cmd = (a_0 + a_1) T_max / 2`` and ``delta_cmd = delta_max (a_0 - a_1) / 2`` (so that
    ``T_port - T_stbd = T_max delta / delta_max``, :func:`mpcasv.models.vessel.actuator_forces`).
    The thrust is taken as proportional to the set-point (no thrust-speed map)."""
    for col, i in (("thrust_0", 0), ("thrust_1", 1)):
        if col not in df.columns or df[col].isna().all():
            raise LogError(f"{path}: missing messages: no SetThrusterActuation id {i} (a vessel "
                           "with two thrusters needs both)")  # fmt: skip
    df = df.dropna(subset=["thrust_0", "thrust_1"])
    a0, a1 = df["thrust_0"].astype(float), df["thrust_1"].astype(float)
    return pd.DataFrame({
        "t": df["t"], "N": df["N"], "E": df["E"], "psi": df["psi"], "u": df["u"], "v": df["v"],
        "r": df["r"], "T_cmd": (a0 + a1) * prior.T_max / 2,
        "delta_cmd": (a0 - a1) * prior.delta_max / 2,
    })  # fmt: skip


# --- data preparation ----------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Prepared:
    """A log prepared for fitting: states with reconstructed actuators, inputs, derivatives."""

    dt: float
    X: np.ndarray  # (n, NX) measured states (N, E, psi, u, v, r) + reconstructed T, delta
    Xs: np.ndarray  # same with smoothed psi, u, v, r (initial conditions, equation error)
    U: np.ndarray  # (n, 2) set-points
    nudot: np.ndarray  # (n, 3) Savitzky-Golay derivatives of u, v, r


def prepare(df: pd.DataFrame, prior: VesselParams, smooth_s: float = 1.5) -> Prepared:
    """Reconstruct actuator states through the known lags (exact ZOH) and smooth."""
    dt = float(df["t"].iloc[1] - df["t"].iloc[0])
    U = df[["T_cmd", "delta_cmd"]].to_numpy(float)
    n = len(df)
    X = np.zeros((n, NX))
    for c in ("N", "E", "psi", "u", "v", "r"):
        X[:, IX[c]] = df[c].to_numpy(float)
    X[:, IX["psi"]] = np.unwrap(X[:, IX["psi"]])  # logs wrap heading; smoothing must not
    for j, (name, tau) in enumerate((("T", prior.T_thrust), ("delta", prior.T_delta))):
        a = 1.0 - math.exp(-dt / tau)
        y = np.empty(n)
        y[0] = U[0, j]
        for k in range(n - 1):
            y[k + 1] = y[k] + a * (U[k, j] - y[k])
        X[:, IX[name]] = y
    win = max(5, int(round(smooth_s / dt)) | 1)
    Xs = X.copy()
    nudot = np.zeros((n, 3))
    for i, c in enumerate(("u", "v", "r")):
        Xs[:, IX[c]] = savgol_filter(X[:, IX[c]], win, 2)
        nudot[:, i] = savgol_filter(X[:, IX[c]], win, 2, deriv=1, delta=dt)
    Xs[:, IX["psi"]] = savgol_filter(X[:, IX["psi"]], win, 2)
    return Prepared(dt=dt, X=X, Xs=Xs, U=U, nudot=nudot)


def split(pr: Prepared, validation: float) -> tuple[Prepared, Prepared]:
    """(training, validation): the validation part is the last ``validation`` fraction."""
    k = int(round(len(pr.U) * (1.0 - validation)))
    cut = lambda a, s: a[s]  # noqa: E731
    head = Prepared(pr.dt, *(cut(a, slice(0, k)) for a in (pr.X, pr.Xs, pr.U, pr.nudot)))
    tail = Prepared(pr.dt, *(cut(a, slice(k, None)) for a in (pr.X, pr.Xs, pr.U, pr.nudot)))
    return head, tail


# --- fitting ---------------------------------------------------------------------------------


def _windows(parts: list[Prepared], W: int):
    """Replay windows of ``W`` steps: initial states, inputs, measured outputs."""
    x0, U, Y = [], [], []
    out = [IX[c] for c in OUTPUTS]
    for pr in parts:
        for k in range(0, len(pr.U) - W, W):
            x0.append(pr.Xs[k])
            U.append(pr.U[k : k + W])
            Y.append(pr.X[k + 1 : k + W + 1, out])
    if not x0:
        raise LogError(f"logs too short for one {W}-sample replay window")
    return np.array(x0).T, np.vstack(U).T, np.vstack(Y).T


class Problem:
    """The identification problem on the shared model, its CasADi functions built once.

    ``theta = [s_1 .. s_n, V_N, V_E]``: scale factors of the identified coefficients relative
    to the prior (1 = prior) and the current (m/s).
    """

    def __init__(self, prior: VesselParams, coeffs=IDENTIFIED, current: bool = True):
        self.prior, self.coeffs, self.current = prior, tuple(coeffs), current
        unknown = [c for c in self.coeffs if c not in MODEL_COEFFS]
        if unknown:
            raise ValueError(f"not model coefficients: {unknown}; known: {MODEL_COEFFS}")
        self.model = VesselModel(prior)
        self.n = len(self.coeffs)
        th = ca.MX.sym("theta", self.n + 2)
        p0 = prior.vector()
        entries = [ca.MX(float(v)) for v in p0]
        for j, name in enumerate(self.coeffs):
            i = MODEL_COEFFS.index(name)
            entries[i] = float(p0[i]) * th[j]
        self.theta, self.p = th, ca.vertcat(*entries)
        self.c = th[self.n :] if current else ca.MX.zeros(2)

    def theta0(self) -> np.ndarray:
        return np.concatenate([np.ones(self.n), np.zeros(2)])

    def bounds(self):
        lo = np.concatenate([np.full(self.n, 0.2), [-2.0, -2.0] if self.current else [-1e-9] * 2])
        hi = np.concatenate([np.full(self.n, 5.0), [2.0, 2.0] if self.current else [1e-9] * 2])
        return lo, hi

    def params(self, theta) -> VesselParams:
        vals = {c: float(getattr(self.prior, c) * theta[j]) for j, c in enumerate(self.coeffs)}
        return self.prior.with_coeffs(**vals)

    def equation_error(self, parts: list[Prepared]) -> ca.Function:
        """Residual function ``theta -> (res, jac)`` of the equation error (weighted)."""
        Xs = np.vstack([pr.Xs for pr in parts]).T
        U = np.vstack([pr.U for pr in parts]).T
        nd = np.vstack([pr.nudot for pr in parts]).T
        w = 1.0 / np.maximum(nd.std(axis=1), 1e-6)
        fmap = self.model.f_param.map(Xs.shape[1])
        pred = fmap(Xs, U, ca.repmat(self.c, 1, Xs.shape[1]), ca.repmat(self.p, 1, Xs.shape[1]))
        res = ca.vec(ca.diag(w) @ (pred[IX["u"] : IX["r"] + 1, :] - nd))
        return ca.Function("ee", [self.theta], [res, ca.jacobian(res, self.theta)])

    def replay(self, parts: list[Prepared], window_s: float) -> tuple[ca.Function, dict]:
        """Simulation-error function ``z -> (res, jac, Ysim)`` over replay windows.

        ``z = [theta, dpsi0, du0, dv0, dr0 per window]``: each window starts from the smoothed
        measurement plus a small estimated correction of its initial state (multiple
        shooting with initial-state estimation: without it the smoothing and noise of the
        initial states bias the inertia estimates). The RK4 step of the shared model is
        symbolic in the parameters; it is accumulated over one window (``mapaccum``) and
        mapped over all windows (``map``), once.
        """
        dt = parts[0].dt
        W = max(10, int(round(window_s / dt)))
        x0, U, Y = _windows(parts, W)
        xs, us = ca.SX.sym("x", NX), ca.SX.sym("u", 2)
        cs, ps = ca.SX.sym("c", 2), ca.SX.sym("p", len(MODEL_COEFFS))
        f = lambda x, u, c: self.model.f_param(x, u, c, ps)  # noqa: E731
        step = ca.Function("step", [xs, us, cs, ps], [rk4_expr(f, xs, us, cs, dt)])
        nwin = x0.shape[1]
        dx = ca.MX.sym("dx0", 4, nwin)  # psi, u, v, r
        X0 = ca.DM(x0) + ca.vertcat(ca.MX.zeros(2, nwin), dx, ca.MX.zeros(NX - 6, nwin))
        sim = step.mapaccum("window", W).map(nwin)
        Xsim = sim(X0, U, ca.repmat(self.c, 1, W * nwin), ca.repmat(self.p, 1, W * nwin))
        out = [IX[c] for c in OUTPUTS]
        Ysim = ca.vertcat(*[Xsim[i, :] for i in out])
        meas_noise = np.concatenate([pr.X[:, out] - pr.Xs[:, out] for pr in parts]).std(axis=0)
        floor = np.array([math.radians(0.2), 0.01, 0.01, math.radians(0.1)])
        w = 1.0 / np.maximum(meas_noise, floor)
        err = Ysim - Y
        err[0, :] = ca.atan2(ca.sin(err[0, :]), ca.cos(err[0, :]))  # heading difference
        res = ca.vec(ca.diag(w) @ err)
        z = ca.vertcat(self.theta, ca.vec(dx))
        fun = ca.Function("sim", [z], [res, ca.jacobian(res, z), Ysim])
        replay = ca.Function("replay", [z], [Ysim])
        return fun, {
            "Y": Y,
            "W": W,
            "windows": nwin,
            "weights": w,
            "n_x0": 4 * nwin,
            "replay": replay,
        }


def _solve(fun: ca.Function, theta0, bounds, max_nfev: int = 100):
    """``least_squares`` on a CasADi ``z -> (res, jac, ...)``, one evaluation per point."""
    cache: dict = {}

    def both(th):
        key = th.tobytes()
        if key not in cache:
            cache.clear()
            out = fun(th)
            cache[key] = (np.array(out[0]).ravel(), np.array(out[1]))
        return cache[key]

    return least_squares(lambda th: both(th)[0], theta0, jac=lambda th: both(th)[1],
                         bounds=bounds, x_scale="jac", max_nfev=max_nfev, xtol=1e-8,
                         ftol=1e-10)  # fmt: skip


def fit_metrics(Ysim: np.ndarray, Y: np.ndarray) -> dict[str, dict[str, float]]:
    """Per output channel: RMSE (SI units) and fit % = 100 (1 - |e| / |y - mean y|)."""
    out = {}
    for i, c in enumerate(OUTPUTS):
        e = Ysim[i] - Y[i]
        if c == "psi":
            e = np.angle(np.exp(1j * e))
        spread = np.linalg.norm(Y[i] - Y[i].mean())
        out[c] = {"rmse": float(np.sqrt(np.mean(e**2))),
                  "fit_pct": float(100.0 * (1.0 - np.linalg.norm(e) / spread)) if spread > 0
                  else math.nan}  # fmt: skip
    return out


@dataclasses.dataclass(frozen=True)
class Identification:
    """Result of :func:`identify`."""

    params: VesselParams  # the prior with the identified coefficients
    coeffs: tuple[str, ...]
    theta: np.ndarray  # scale factors + current
    rel_std: dict  # coefficient -> 1-sigma relative standard deviation (from the Jacobian)
    current: tuple[float, float]  # (V_N, V_E) m/s
    metrics: dict  # stage ("prior", "equation_error", "simulation_error") -> split -> channel
    replay: dict  # split -> (measured Y, simulated Y) of the final model


def identify(logs: list[pd.DataFrame], prior: VesselParams, coeffs=IDENTIFIED,
             current: bool = True, validation: float = 0.25, window_s: float = 30.0,
             progress: bool = False) -> Identification:  # fmt: skip
    """Identify ``coeffs`` (and the current) from identification tables (see module docstring)."""
    if not 0.0 < validation < 0.9:
        raise ValueError(f"validation fraction {validation} not in (0, 0.9)")
    t_start = time.perf_counter()
    say = (
        (lambda m: print(f"[{time.perf_counter() - t_start:6.1f} s] {m}"))
        if progress
        else (lambda m: None)
    )
    prepared = [prepare(df, prior) for df in logs]
    dts = {round(pr.dt, 6) for pr in prepared}
    if len(dts) != 1:
        raise LogError(f"logs have different time steps {sorted(dts)}; resample them alike")
    train, val = zip(*(split(pr, validation) for pr in prepared), strict=True)
    prob = Problem(prior, coeffs, current)
    bounds = prob.bounds()
    th0 = prob.theta0()
    sim_tr, info_tr = prob.replay(list(train), window_s)
    sim_va, info_va = prob.replay(list(val), window_s)
    metrics = {}

    def ext(th, info):  # theta with zero initial-state corrections
        return np.concatenate([th, np.zeros(info["n_x0"])])

    def evaluate(stage, th):
        metrics[stage] = {
            "train": fit_metrics(np.array(info_tr["replay"](ext(th, info_tr))), info_tr["Y"]),
            "validation": fit_metrics(np.array(info_va["replay"](ext(th, info_va))), info_va["Y"]),
        }

    def bounds_ext(info):
        return (np.concatenate([bounds[0], np.full(info["n_x0"], -0.5)]),
                np.concatenate([bounds[1], np.full(info["n_x0"], 0.5)]))  # fmt: skip

    evaluate("prior", th0)
    say(f"equation error on {sum(len(p.U) for p in train)} samples ...")
    ee = _solve(prob.equation_error(list(train)), th0, bounds)
    say(f"  {ee.nfev} evaluations, status {ee.status}: {ee.message}")
    evaluate("equation_error", ee.x)
    say(f"simulation error on {info_tr['windows']} windows of {info_tr['W']} steps ...")
    se = _solve(sim_tr, ext(ee.x, info_tr), bounds_ext(info_tr))
    say(f"  {se.nfev} evaluations, status {se.status}: {se.message}")
    theta = se.x[: len(th0)]
    evaluate("simulation_error", theta)
    dof = max(1, len(se.fun) - len(se.x))
    try:
        cov = np.linalg.pinv(se.jac.T @ se.jac) * (2 * se.cost / dof)
        std = np.sqrt(np.clip(np.diag(cov)[: prob.n], 0, None)) / np.abs(theta[: prob.n])
    except np.linalg.LinAlgError:
        std = np.full(prob.n, math.inf)
    final = {"train": ext(theta, info_tr), "validation": ext(theta, info_va)}
    return Identification(
        params=prob.params(theta), coeffs=prob.coeffs, theta=theta,
        rel_std={c: float(s) for c, s in zip(prob.coeffs, std, strict=True)},
        current=(float(theta[prob.n]), float(theta[prob.n + 1])) if current else (0.0, 0.0),
        metrics=metrics,
        replay={"train": (info_tr["Y"], np.array(info_tr["replay"](final["train"]))),
                "validation": (info_va["Y"], np.array(info_va["replay"](final["validation"])))},
    )  # fmt: skip


# --- output --------------------------------------------------------------------------------


def write_params(path: Path, res: Identification, prior: VesselParams, sources: list[str]) -> None:
    """Write the identified parameters as a vessel TOML (loads with ``load_vessel``).

    Every number keeps a provenance entry: identified ones name the logs, the method, the
    1-sigma uncertainty and the validation fit; the others are the prior's, marked as held.
    """
    import tomli_w

    val = res.metrics["simulation_error"]["validation"]
    fit = ", ".join(f"{c} {v['fit_pct']:.1f} %" for c, v in val.items())
    from mpcasv.models.vessel import top_speed

    data = {f.name: getattr(res.params, f.name) for f in dataclasses.fields(res.params)}
    data.pop("provenance")
    data = {k: v for k, v in data.items() if v is not None}  # absent optional (T_idle)
    data["name"] = f"{prior.name}-identified"
    # the declared top speed is checked against the model at load: the identified resistance
    # moves it (set-points are fractions of the prior's T_max, so it is the full-throttle speed
    # the identified model predicts)
    data["u_max"] = round(top_speed(res.params), 4)
    prov = {}
    for key in data:
        if key == "name":
            continue
        if key == "u_max":
            prov[key] = (f"top speed of the identified model at T_max = {prior.T_max:g} N "
                         f"(prior declared {prior.u_max:g} m/s: {prior.provenance.get(key, '')})")
        elif key in res.coeffs:
            prov[key] = (f"identified by mpcasv identify from {', '.join(sources)}: simulation-"
                         f"error least squares, 1-sigma {100 * res.rel_std[key]:.1f} %; "
                         f"validation fit {fit}; prior {getattr(prior, key):.6g}")  # fmt: skip
        else:
            prov[key] = "held at the prior: " + prior.provenance.get(key, "(no provenance)")
    header = (f"# Identified by `mpcasv identify` from {', '.join(sources)}.\n"
              f"# Estimated constant current V_N = {res.current[0]:.3f} m/s, "
              f"V_E = {res.current[1]:.3f} m/s (not a vessel parameter).\n")  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(header + tomli_w.dumps({**data, "provenance": prov}))


def plot_replay(res: Identification, out: Path) -> Path:
    """Measured vs simulated outputs over the training and validation windows."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(4, 2, figsize=(13, 9), sharex="col")
    scale = {"psi": (math.degrees(1), "deg"), "u": (1, "m/s"), "v": (1, "m/s"),
             "r": (math.degrees(1), "deg/s")}  # fmt: skip
    for j, part in enumerate(("train", "validation")):
        Y, Ys = res.replay[part]
        k = np.arange(Y.shape[1]) * 0.1
        for i, c in enumerate(OUTPUTS):
            f, unit = scale[c]
            ax = axes[i, j]
            ax.plot(k, Y[i] * f, ".", ms=1, color="0.6", label="measured")
            ax.plot(k, Ys[i] * f, lw=0.8, color="tab:blue", label="simulated (identified)")
            ax.set_ylabel(f"{c} ({unit})")
            fit = res.metrics["simulation_error"][part][c]["fit_pct"]
            ax.set_title(f"{part}: {c}, fit {fit:.1f} %", fontsize=9)
        axes[3, j].set_xlabel("time over the replay windows, concatenated (s)")
    axes[0, 0].legend(fontsize=8)
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    p = out / "identify_replay.png"
    fig.savefig(p, dpi=100)
    plt.close(fig)
    return p


def report_table(res: Identification, prior: VesselParams, truth: VesselParams | None = None):
    """Markdown: coefficients (prior, identified, 1-sigma, truth error if known), fits."""
    lines = ["| coefficient | prior | identified | 1-sigma % |" + (" true | error % |" if truth
             else ""), "|---|---|---|---|" + ("---|---|" if truth else "")]  # fmt: skip
    rows = [(c, getattr(prior, c), getattr(res.params, c), 100 * res.rel_std[c],
             getattr(truth, c) if truth else None) for c in res.coeffs]  # fmt: skip
    mp, mi = mass_terms(prior), mass_terms(res.params)
    mt = mass_terms(truth) if truth else {}
    rows += [(k, mp[k], mi[k], math.nan, mt.get(k)) for k in mp]
    for c, p0, pi, sd, pt in rows:
        line = f"| {c} | {p0:.4g} | {pi:.4g} | {sd:.1f} |"
        if truth:
            line += f" {pt:.4g} | {100 * (pi / pt - 1):+.1f} |"
        lines.append(line)
    lines += ["", f"Current: V_N = {res.current[0]:.3f} m/s, V_E = {res.current[1]:.3f} m/s", "",
              "| stage | split | " + " | ".join(f"{c} fit % (RMSE)" for c in OUTPUTS) + " |",
              "|---|---|" + "---|" * len(OUTPUTS)]  # fmt: skip
    for stage, d in res.metrics.items():
        for part, m in d.items():
            lines.append(
                f"| {stage} | {part} | "
                + " | ".join(f"{m[c]['fit_pct']:.1f} ({m[c]['rmse']:.3g})" for c in OUTPUTS)
                + " |"
            )
    lines.append("RMSE in rad, m/s, m/s, rad/s; fits over replay windows re-initialised every "
                 "window from the smoothed measurement.")  # fmt: skip
    return "\n".join(lines)


def run_cli(args) -> int:
    """``mpcasv identify LOG... --out params.toml``."""
    import json

    from mpcasv.models.params import load_vessel

    prior = load_vessel(args.vessel)
    coeffs = tuple(c.strip() for c in args.coeffs.split(",")) if args.coeffs else IDENTIFIED
    unknown = [c for c in coeffs if c not in MODEL_COEFFS]
    if unknown:
        from mpcasv.config import ConfigError

        raise ConfigError(f"--coeffs: not model coefficients: {unknown}")
    logs = [load_log(p, prior, getattr(args, "vehicle_pick", None)) for p in args.logs]
    res = identify(logs, prior, coeffs, current=not args.no_current,
                   validation=args.validation, progress=not args.quiet)  # fmt: skip
    write_params(args.out, res, prior, [str(p) for p in args.logs])
    folder = args.out.with_name(args.out.stem + "-report")
    plot_replay(res, folder)
    table = report_table(res, prior)
    (folder / "identify.md").write_text(table + "\n")
    (folder / "identify.json").write_text(json.dumps({
        "coeffs": {c: getattr(res.params, c) for c in res.coeffs}, "rel_std": res.rel_std,
        "current": res.current, "metrics": res.metrics}, indent=1))  # fmt: skip
    print(table)
    print(f"wrote {args.out} and {folder}/ (identify.md, identify.json, identify_replay.png)")
    return 0
