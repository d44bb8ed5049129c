"""Identification of a hull driven through a known thruster map (DUNE's simulated Otter).

DUNE's vehicle simulator (VSIM) does not turn a thruster's actuation ``a`` (``-1..1``,
SetThrusterActuation) into a force proportionally: per thruster ``i`` (``Engine.cpp``,
``Object.cpp``, ``ASV.cpp`` of ``src/Simulators/VSIM/VSIM``; values from the log folder's
``Config.ini``, section ``[VSIM/Model/<vehicle type>]``)::

    n_i = a_i n_max                               (rev/s; n_max = Engine Parameters[2] / 60)
    T_i = (K_n n_i - K_nu V) |n_i|                (N; V = |(u, v)|, the vehicle's speed)
    X_i = clip(T_i, +-F_max)                      (Engine Max Force)
    N_i = clip(-y_i T_i, +-Q_max)                 (y_i: Engine Position, + starboard;
                                                   Q_max: c_max_prop_torque of Engine.hpp)

The force is steep in speed (the ``K_nu V`` term): the boat settles where ``T_i`` falls to
the hull's resistance, near ``V = K_n n_i / K_nu``. The shared model's thrust state ``T`` is
a force with a first-order lag (:mod:`mpcasv.models.vessel`), so the map is kept *outside*
the model, as the actuator it is: during identification it is evaluated on the
*simulated* speed at every RK4 sub-step and its total force and moment are set as the
model's thrust ``T`` and differential input ``delta = N / N_diff`` (the lags then hold them:
``T_cmd = T``). The hull is the one symbolic model (``VesselModel.f_param``); nothing of its
equations is repeated here.

Identified: the surge and yaw inertia and damping, ``m`` (= ``m - X_udot`` with ``X_udot =
0``), ``X_u``, ``X_uu``, ``I_z`` (= ``I_z - N_rdot``), ``N_r``, ``N_rr``
(:data:`HULL_COEFFS`), by simulation-error least squares (``scipy.optimize.least_squares``
with the exact Jacobian, :mod:`mpcasv.models.ident_windows`) over replay windows
re-initialised from the measurement, on the first ``1 - validation`` of the log; the rest
is held out and replayed the same way (speed, heading and yaw-rate RMS:
:func:`replay_metrics`).

Timing: table row ``k`` is the state at ``t_k`` and the actuations over ``[t_k, t_k+1)``
(:data:`MAP_COLUMNS`, :data:`ACTUATION_ADVANCE`); a replay step from row ``k`` is compared
with the measurement at row ``k + 1`` (:class:`~mpcasv.models.ident_windows.Windows`: the
outputs *after* each step).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import casadi as ca
import numpy as np
import pandas as pd
from scipy.optimize import least_squares

from mpcasv.errors import LogError
from mpcasv.models.ident_bounds import active, at_bounds
from mpcasv.models.ident_cov import METHOD, window_covariance
from mpcasv.models.ident_table import (
    check_length,
    hold_rows,
    regular_grid,
    split_index,
    window_steps,
)  # fmt: skip
from mpcasv.models.ident_vsim import LAG_S, Y_V, vsim_structure  # noqa: F401 (re-exported)
from mpcasv.models.ident_windows import Windows, window_lengths
from mpcasv.models.params import MODEL_COEFFS, VesselParams
from mpcasv.models.vessel import IX, NX, VesselModel, rk4_expr

#: hull coefficients identified through a thruster map (module docstring)
HULL_COEFFS = ("m", "I_z", "X_u", "X_uu", "N_r", "N_rr")
#: sign of each (bounds of the fit): +1 positive, -1 negative (Fossen's convention)
_SIGN = {"m": 1, "I_z": 1, "X_u": -1, "X_uu": -1, "N_r": -1, "N_rr": -1}
#: columns of a thruster-map identification table: row ``k`` holds the state measured at
#: ``t_k`` and the actuations ``a_0``, ``a_1`` that act over the step ``[t_k, t_k+1)``
MAP_COLUMNS = ("t", "N", "E", "psi", "u", "v", "r", "a_0", "a_1")
#: Timing (samples): the step from EstimatedState ``k`` carries the actuation DUNE sent in
#: answer to EstimatedState ``k + ACTUATION_ADVANCE`` (:func:`mpcasv.io.identlog.map_table`).
#: Evidence, DUNE's Otter log (dune-otter-ident, session 25): SetThrusterActuation (10 Hz per
#: thruster) is logged 0.12 ms (median; 0.03-0.6 ms, 0-99th percentile) after the
#: EstimatedState it answers; EstimatedState (10 Hz) is the latest SimulatedState (25 Hz,
#: VSIM's step) 10.6 ms later (median) and matches it best shifted by 0.02 s (u RMS 0.0018
#: m/s, r 0.008 rad/s; at 0.1 s: 0.015, 0.066); VSIM applies an actuation from its next step
#: (the README's free-run check), about 30 ms after it is sent. So the actuation acts over
#: ``[t_k, t_k+1)`` but for its first 0.3 step: 0 samples to the nearest step. The fit says
#: the same (``mpcasv identify``, validation 0.3, Y after each step): held-out r RMS 0.082,
#: 0.018, 0.077, 0.164 rad/s and I_z 20.4, 12.16, 21.4, 1001 kg m^2 (Config.ini: 12) for
#: advances -1, 0, +1, +2; VSIM's own hull replays best at 0 too (held-out u 0.021, 0.0084,
#: 0.021, 0.025 m/s). Before session 25 the table's actuations were a step late (a
#: zero-order hold without tolerance; now :func:`mpcasv.models.ident_table.hold_rows`) and the
#: replay compared each step with the measurement one step earlier: the two cancelled.
ACTUATION_ADVANCE = 0
OUTPUTS = ("psi", "u", "r")
#: weights of the residuals (1 / typical error): psi (rad), u (m/s), r (rad/s). The heading
#: is reported, not fitted: DUNE's yaw loop chatters (true r std about 4 deg/s on straight
#: legs) with each thruster's moment at its clip, so a replay's heading drifts by timing
#: alone; even VSIM's own parameters give 0.044 rad RMS over 10-s windows (docs/deploy.md;
#: 0.10 rad with the replay a step misaligned, before session 25)
_WEIGHT = (0.0, 1 / 0.01, 1 / 0.02)


@dataclasses.dataclass(frozen=True)
class ThrusterMap:
    """DUNE VSIM's thruster model (module docstring), one entry per thruster in ``y``.

    Attributes
    ----------
    K_n : float
        Thrust per ``n|n|`` (N s^2), ``Engine Parameters[0]``.
    K_nu : float
        Thrust loss per ``|n| V`` (N s/m), ``Engine Parameters[1]``.
    n_max : float
        Propeller speed at actuation 1 (rev/s), ``Engine Parameters[2] / 60``.
    F_max : float
        Force limit per thruster (N), ``Engine Max Force``.
    Q_max : float
        Yaw moment limit per thruster (N m), ``c_max_prop_torque`` (Engine.hpp).
    y : tuple of float
        Lateral position of thruster ``i`` (m, + starboard), ``Engine Position i``[1].
    x : float
        Longitudinal position of the thrusters (m, + forward), ``Engine Position``[0].
    source : str
        Where the numbers come from (provenance).
    """

    K_n: float
    K_nu: float
    n_max: float
    F_max: float
    Q_max: float
    y: tuple[float, ...]
    x: float = 0.0
    source: str = ""

    def forces(self, a: Sequence, U):
        """Surge force and yaw moment ``(X, N)`` (N, N m) of actuations ``a`` (one per
        thruster, ``-1..1``) at speed ``U`` (m/s). CasADi or float arguments."""
        X, N = 0, 0
        for a_i, y_i in zip(a, self.y, strict=True):
            n = a_i * self.n_max
            T = (self.K_n * n - self.K_nu * U) * ca.fabs(n)
            X = X + ca.fmin(ca.fmax(T, -self.F_max), self.F_max)
            N = N + ca.fmin(ca.fmax(-y_i * T, -self.Q_max), self.Q_max)
        return X, N

    def max_moment(self) -> float:
        """Largest yaw moment of full differential actuation (N m)."""
        return sum(min(self.Q_max, abs(y) * self.F_max) for y in self.y)

    def steady_speed(self, params: VesselParams, a: float) -> float:
        """Straight-line speed (m/s) with every thruster at actuation ``a`` (> 0): where the
        map's total force equals the hull's resistance ``-(X_u u + X_uu |u| u)``."""
        lo, hi = 0.0, 20.0
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            X, _ = self.forces([a] * len(self.y), mid)
            if float(X) + params.X_u * mid + params.X_uu * mid * mid > 0:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)


@dataclasses.dataclass(frozen=True)
class MapFit:
    """Result of :func:`identify_through_map`."""

    params: VesselParams  # the prior with the identified hull coefficients
    coeffs: tuple[str, ...]
    rel_std: dict  # coefficient -> 1-sigma relative (HAC, :mod:`mpcasv.models.ident_cov`)
    rel_std_plain: dict  # the same from (J^T J)^-1 s^2 (independent residuals), for reference
    var_ratio: dict  # coefficient -> HAC variance / plain variance (1 for white residuals)
    metrics: dict  # "prior" / "identified" -> "train" / "validation" -> channel -> RMS
    split_s: float  # log time (s from its start) where the held-out part begins
    replay: dict  # "train" / "validation" -> (measured, simulated) arrays (3, n)
    nfev: int
    #: per coefficient: relative standard deviation of the quoted 1-sigma itself
    #: (:func:`mpcasv.models.ident_cov.sigma_uncertainty`)
    sigma_rel_sd: dict = dataclasses.field(default_factory=dict)
    sigma_method: str = METHOD
    #: coefficient -> what the fit tells of one at its sign bound
    #: (:func:`mpcasv.models.ident_bounds.at_bounds`); empty when none is
    at_bound: dict = dataclasses.field(default_factory=dict)
    #: per coefficient: the Bartlett lag of its 1-sigma (samples), and the samples it summed
    sigma_lag: dict = dataclasses.field(default_factory=dict)
    sigma_n: int = 0


def check_table(df: pd.DataFrame, source) -> pd.DataFrame:
    """A thruster-map identification table (:data:`MAP_COLUMNS`) on a uniform time grid
    (:func:`mpcasv.models.ident_table.regular_grid`).

    Raises
    ------
    LogError
        Missing columns, non-finite values, time not increasing, too short, a gap.
    """
    missing = [c for c in MAP_COLUMNS if c not in df.columns]
    if missing:
        raise LogError(f"{source}: missing columns {missing}")
    df = df[list(MAP_COLUMNS)].astype(float)
    if not np.isfinite(df.to_numpy()).all():
        raise LogError(f"{source}: non-finite values in {list(MAP_COLUMNS)}")
    t = df["t"].to_numpy()
    if len(t) < 2 or np.any(np.diff(t) <= 0):  # the length a fit needs: check_length
        raise LogError(f"{source}: need at least 2 samples with t strictly increasing")
    grid, dt = regular_grid(t, source)
    out = {"t": grid - grid[0]}
    psi = np.unwrap(df["psi"].to_numpy())
    hold = hold_rows(t, grid, dt)
    for c in MAP_COLUMNS[1:]:
        y = psi if c == "psi" else df[c].to_numpy()
        out[c] = y[hold] if c.startswith("a_") else np.interp(grid, t, y)
    table = pd.DataFrame(out)
    table.attrs["source"] = str(source)  # named in identify_through_map()'s refusals
    return table


class _Replay:
    """Windows of the log replayed through the map and the model, symbolic in the hull."""

    def __init__(self, prior: VesselParams, tmap: ThrusterMap, coeffs, scale, df, window_s,
                 n_sub: int):  # fmt: skip
        dt = float(df["t"].iloc[1] - df["t"].iloc[0])
        model = VesselModel(prior)
        th = ca.SX.sym("theta", len(coeffs))
        p0 = prior.vector()
        entries = [ca.SX(float(v)) for v in p0]
        for j, name in enumerate(coeffs):
            entries[MODEL_COEFFS.index(name)] = scale[j] * th[j]
        # Y_ur = m - X_udot: cancels the centripetal sway force (:func:`vsim_structure`)
        im, iu = MODEL_COEFFS.index("m"), MODEL_COEFFS.index("Y_ur")
        entries[iu] = entries[im] - prior.X_udot
        p = ca.vertcat(*entries)
        xs, a_s = ca.SX.sym("x", NX), ca.SX.sym("a", 2)
        c0 = ca.DM.zeros(2)
        N_diff = float(p0[MODEL_COEFFS.index("N_diff")])
        x, h = xs, dt / n_sub
        for _ in range(n_sub):  # the map on the simulated speed at every sub-step
            # |(u, v)|, smooth at rest (the Jacobian of a plain norm is NaN there)
            U = ca.sqrt(x[IX["u"]] ** 2 + x[IX["v"]] ** 2 + prior.eps_abs**2) - prior.eps_abs
            Xf, Nm = tmap.forces([a_s[0], a_s[1]], U)
            act = ca.vertcat(Xf, Nm / N_diff)
            x = ca.vertcat(x[: IX["T"]], act)
            x = rk4_expr(lambda x_, u_, c_: model.f_param(x_, u_, c_, p), x, act, c0, h)
        step = ca.Function("map_step", [xs, a_s, th], [x])
        W = window_steps(window_s, dt)
        n = len(df) - 1  # steps: a window of W steps needs W + 1 samples
        if n < W:
            raise LogError(f"log part of {len(df)} samples is shorter than one window ({W} "
                           "steps)")  # fmt: skip
        lengths = window_lengths(n, W)  # whole windows, then a shorter one (session 26)
        nwin = len(lengths)
        # step k goes from sample k to sample k + 1 under row k's actuations (map_table: the
        # actuation that acts over [t_k, t_k+1)); Y is the measurement *after* each step
        # (the Windows contract), samples 1 .. n
        A = df[["a_0", "a_1"]].to_numpy()[:n].T
        x0 = np.zeros((NX, nwin))
        for c in ("N", "E", "psi", "u", "v", "r"):
            x0[IX[c]] = df[c].to_numpy()[:n:W]
        self.Y = np.vstack([df[c].to_numpy()[1 : n + 1] for c in OUTPUTS])
        win = Windows(step, x0, A, self.Y, [IX[c] for c in OUTPUTS], _WEIGHT, wrap=[0],
                      lengths=lengths)  # fmt: skip
        self.fun, self.sim = win.residuals, win.simulate  # theta -> (res, jac, Ysim); Ysim
        self.lengths = lengths
        self.windows, self.W = nwin, W


def rms(Ysim: np.ndarray, Y: np.ndarray) -> dict[str, float]:
    """RMS error per output (``psi`` wrapped): rad, m/s, rad/s."""
    out = {}
    for i, c in enumerate(OUTPUTS):
        e = Ysim[i] - Y[i]
        if c == "psi":
            e = np.angle(np.exp(1j * e))
        out[c] = float(np.sqrt(np.mean(e**2)))
    return out


def identify_through_map(df: pd.DataFrame, prior: VesselParams, tmap: ThrusterMap,
                         coeffs: Sequence[str] = HULL_COEFFS, validation: float = 0.3,
                         window_s: float = 30.0, n_sub: int = 2,
                         say=lambda m: None) -> MapFit:  # fmt: skip
    """Identify ``coeffs`` of ``prior`` from a table of :data:`MAP_COLUMNS` (actuations
    ``a_0``, ``a_1`` of the thrusters at ``tmap.y``), holding out the last ``validation``
    fraction (module docstring). The prior's values of ``coeffs`` are the starting point.

    Raises
    ------
    ValueError
        ``validation`` not in (0, 0.9), a coefficient not in :data:`HULL_COEFFS`, or a
        prior without differential actuation.
    LogError
        A log too short for one whole replay window in each of its training and validation
        parts (:func:`mpcasv.models.ident_table.check_length`).
    """
    if not 0.0 < validation < 0.9:
        raise ValueError(f"validation fraction {validation} not in (0, 0.9)")
    bad = [c for c in coeffs if c not in HULL_COEFFS]
    if bad:
        raise ValueError(f"through a thruster map only {HULL_COEFFS} are identified, not {bad}")
    if prior.actuation != "differential" or len(tmap.y) != 2:
        raise ValueError("a thruster map needs a differential-thrust prior and two thrusters")
    dt = float(df["t"].iloc[1] - df["t"].iloc[0])
    check_length(len(df), dt, window_steps(window_s, dt), validation,
                 df.attrs.get("source", "the log"), n_shared=len(coeffs),
                 n_out=sum(w > 0 for w in _WEIGHT))  # fmt: skip
    k = split_index(len(df), validation)
    train, val = df.iloc[:k].reset_index(drop=True), df.iloc[k:].reset_index(drop=True)
    v0 = np.array([getattr(prior, c) for c in coeffs], float)
    scale = np.array([abs(v) if v != 0 else 1.0 for v in v0])
    th0 = v0 / scale
    sign = np.array([_SIGN[c] for c in coeffs])
    lo = np.where(sign > 0, 1e-3 * th0, -np.inf)
    hi = np.where(sign > 0, np.inf, 0.0)
    th0 = np.clip(th0, lo + 1e-12, hi)
    rp_tr = _Replay(prior, tmap, coeffs, scale, train, window_s, n_sub)
    rp_va = _Replay(prior, tmap, coeffs, scale, val, window_s, n_sub)
    say(f"simulation error on {rp_tr.windows} windows of {rp_tr.W} steps "
        f"({len(val)} samples held out) ...")  # fmt: skip
    cache: dict = {}

    def both(th):
        key = th.tobytes()
        if key not in cache:
            cache.clear()
            r, J, _ = rp_tr.fun(th)
            cache[key] = (r, J)
        return cache[key]

    sol = least_squares(lambda th: both(th)[0], th0, jac=lambda th: both(th)[1],
                        bounds=(lo, hi), x_scale="jac", max_nfev=200, xtol=1e-10,
                        ftol=1e-12)  # fmt: skip
    say(f"  {sol.nfev} evaluations, status {sol.status}: {sol.message}")
    at_bound = at_bounds(coeffs, sol.x, lo, hi, sol.jac, sol.fun, rp_tr.W, rp_tr.windows,
                         rp_tr.lengths, lambda j, v: float(scale[j] * v), th0,
                         sol.active_mask, kind="sign")  # fmt: skip
    side = active(sol.x, lo, hi, sol.active_mask)  # at a bound: on it (not 1e-17 inside)
    sol.x = np.where(side > 0, hi, np.where(side < 0, lo, sol.x))
    cov = window_covariance(sol.jac, sol.fun, rp_tr.W, rp_tr.windows,
                            lengths=rp_tr.lengths)  # as identify()'s
    std = np.sqrt(np.clip(cov.hac, 0, None)) / np.maximum(np.abs(sol.x), 1e-12)
    std_plain = np.sqrt(np.clip(cov.plain, 0, None)) / np.maximum(np.abs(sol.x), 1e-12)
    values = {c: float(scale[j] * sol.x[j]) for j, c in enumerate(coeffs)}

    def metrics(th):
        return {"train": rms(np.array(rp_tr.sim(th)), rp_tr.Y),
                "validation": rms(np.array(rp_va.sim(th)), rp_va.Y)}  # fmt: skip

    values["Y_ur"] = values.get("m", prior.m) - prior.X_udot
    return MapFit(
        params=prior.with_coeffs(**values), coeffs=tuple(coeffs),
        rel_std={c: float(s) for c, s in zip(coeffs, std, strict=True)},
        rel_std_plain={c: float(s) for c, s in zip(coeffs, std_plain, strict=True)},
        var_ratio={c: float(r) for c, r in zip(coeffs, cov.ratio, strict=True)},
        sigma_rel_sd={c: float(r) for c, r in zip(coeffs, cov.sigma_rel_sd, strict=True)},
        metrics={"prior": metrics(th0), "identified": metrics(sol.x)},
        split_s=float(val["t"].iloc[0]),
        replay={"train": (rp_tr.Y, np.array(rp_tr.sim(sol.x))),
                "validation": (rp_va.Y, np.array(rp_va.sim(sol.x)))},
        nfev=int(sol.nfev), at_bound=at_bound,
        sigma_lag={c: int(L) for c, L in zip(coeffs, cov.lag, strict=True)}, sigma_n=cov.n,
    )  # fmt: skip


def replay_metrics(df: pd.DataFrame, params: VesselParams, tmap: ThrusterMap,
                   window_s: float = 30.0, n_sub: int = 2) -> dict[str, float]:
    """RMS errors (:func:`rms`) of ``params`` replaying a table of :data:`MAP_COLUMNS`
    through ``tmap`` in windows re-initialised from the measurement every ``window_s``."""
    if params.Y_ur != params.m - params.X_udot:
        raise ValueError(f"{params.name}: Y_ur != m - X_udot (not a thruster-map structure)")
    rp = _Replay(params, tmap, (), np.zeros(0), df, window_s, n_sub)
    return rms(np.array(rp.sim(ca.DM.zeros(0))), rp.Y)
