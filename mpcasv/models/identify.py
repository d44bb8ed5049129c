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

Extra columns are ignored. Files, DUNE logs (``.lsf``, ``.lsf.gz``) included, are read by
:func:`mpcasv.io.identlog.load_log` (the I/O layer; models never import it), which also
identifies a DUNE-simulated boat through its simulator's thruster map
(:mod:`mpcasv.models.ident_thrust`).

Method
------
Actuator states are reconstructed from the set-points through the model's known lags. Then

1. equation error: ``f_param(x_k, u_k, c, p)[u, v, r]`` against Savitzky-Golay derivatives of
   the measured velocities, nonlinear least squares from the prior;
2. simulation error: the logged inputs are replayed through the shared model (RK4 of
   ``VesselModel.f_param`` with a symbolic parameter vector, built once as one CasADi function
   of the parameters, mapped over windows re-initialised from the smoothed measurement every
   ``window`` seconds; a part's samples after its last whole window form a shorter last
   window), ``scipy.optimize.least_squares`` with the exact Jacobian (forward sensitivities
   along each window, :mod:`mpcasv.models.ident_windows`); a coefficient that ends at its
   bound is analysed (:mod:`mpcasv.models.ident_bounds`);
3. validation: the last ``validation`` fraction of every log is held out and replayed the same
   way; fit = ``100 (1 - |y - y_sim| / |y - mean(y)|)`` per channel, and the held-out weighted
   error against the prior's (:func:`mpcasv.models.ident_checks.worse_than_prior`).

Each log must hold one whole window in each part
(:func:`mpcasv.models.ident_table.check_length`: 1,203 samples at 0.1 s and the defaults).

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

import casadi as ca
import numpy as np
import pandas as pd
from scipy.optimize import least_squares

from mpcasv.errors import LogError
from mpcasv.models.ident_bounds import active, at_bounds
from mpcasv.models.ident_cov import METHOD, window_covariance
from mpcasv.models.ident_table import Prepared, check_length, prepare, split, window_steps
from mpcasv.models.ident_windows import Windows, window_lengths
from mpcasv.models.params import MODEL_COEFFS, VesselParams
from mpcasv.models.vessel import IX, NX, VesselModel, rk4_expr

IDENTIFIED = ("X_udot", "Y_vdot", "N_rdot", "X_u", "X_uu", "Y_uv", "N_ur", "Y_uudelta")
DAMPING = ("X_u", "X_uu", "Y_uv", "N_ur")
OUTPUTS = ("psi", "u", "v", "r")


def mass_terms(p: VesselParams) -> dict[str, float]:
    """Total (rigid-body + added) mass terms ``m11, m22, m33`` (kg, kg, kg m^2)."""
    return {"m11": p.m - p.X_udot, "m22": p.m - p.Y_vdot, "m33": p.I_z - p.N_rdot}


# --- fitting ---------------------------------------------------------------------------------


def _windows(parts: list[Prepared], W: int, what: str = "logs"):
    """Replay windows of ``W`` steps: initial states, inputs, measured outputs and each
    window's steps (``what``: the parts' name in the error when one holds no whole window).
    A part's samples after its last whole window form one shorter window (they were left out,
    unsaid, until session 26: up to ``W - 1`` samples a part, 225 of the default zig-zag's
    1,126 training samples)."""
    x0, U, Y, lengths = [], [], [], []
    out = [IX[c] for c in OUTPUTS]
    for pr in parts:
        if len(pr.U) < W + 1:
            n, dt = len(pr.U), pr.dt
            raise LogError(f"{what}: one is too short for one {W}-sample ({W * dt:g} s) replay "
                           f"window: it has {n} samples ({n * dt:g} s)")  # fmt: skip
        for j, L in enumerate(window_lengths(len(pr.U) - 1, W)):
            k = j * W  # the outputs after each step: samples k+1 .. k+L
            x0.append(pr.Xs[k])
            U.append(pr.U[k : k + L])
            Y.append(pr.X[k + 1 : k + L + 1, out])
            lengths.append(L)
    return np.array(x0).T, np.vstack(U).T, np.vstack(Y).T, lengths


class Problem:
    """The identification problem on the shared model: its residual functions (equation
    error, replay windows) are built for given log parts by :meth:`equation_error` and
    :meth:`replay`.

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

    def _p_c(self, th: ca.SX) -> tuple[ca.SX, ca.SX]:
        """The model's parameter vector and the current, expressions of ``theta``."""
        p0 = self.prior.vector()
        entries = [ca.SX(float(v)) for v in p0]
        for j, name in enumerate(self.coeffs):
            i = MODEL_COEFFS.index(name)
            entries[i] = float(p0[i]) * th[j]
        return ca.vertcat(*entries), (th[self.n :] if self.current else ca.SX.zeros(2))

    def theta0(self) -> np.ndarray:
        return np.concatenate([np.ones(self.n), np.zeros(2)])

    def bounds(self):
        lo = np.concatenate([np.full(self.n, 0.2), [-2.0, -2.0] if self.current else [-1e-9] * 2])
        hi = np.concatenate([np.full(self.n, 5.0), [2.0, 2.0] if self.current else [1e-9] * 2])
        return lo, hi

    def params(self, theta) -> VesselParams:
        vals = {c: float(getattr(self.prior, c) * theta[j]) for j, c in enumerate(self.coeffs)}
        return self.prior.with_coeffs(**vals)

    def equation_error(self, parts: list[Prepared]):
        """The weighted equation error as a function ``theta -> (res, jac)``: ``res`` of shape
        ``(3 N,)`` (the u, v, r accelerations of each of the ``N`` samples together), ``jac``
        ``(3 N, n + 2)``; the model and its derivative in ``theta`` per sample (CasADi SX),
        mapped over the samples."""
        Xs = np.vstack([pr.Xs for pr in parts]).T
        U = np.vstack([pr.U for pr in parts]).T
        nd = np.vstack([pr.nudot for pr in parts]).T
        w = 1.0 / np.maximum(nd.std(axis=1), 1e-6)
        xs, us, th = ca.SX.sym("x", NX), ca.SX.sym("u", 2), ca.SX.sym("theta", self.n + 2)
        p, c = self._p_c(th)
        acc = self.model.f_param(xs, us, c, p)[IX["u"] : IX["r"] + 1]
        N, m = Xs.shape[1], self.n + 2
        fmap = ca.Function("ee", [xs, us, th], [acc, ca.jacobian(acc, th)]).map(N)

        def fun(theta):
            F, J = fmap(Xs, U, np.tile(np.asarray(theta, float)[:, None], (1, N)))
            res = (w[:, None] * (np.array(F) - nd)).ravel(order="F")
            J = np.array(J).reshape(3, N, m) * w[:, None, None]  # sample k: columns k m ..
            return res, J.transpose(1, 0, 2).reshape(3 * N, m)

        return fun

    def replay(self, parts: list[Prepared], window_s: float,
               what: str = "logs") -> tuple[Windows, dict]:  # fmt: skip
        """Simulation error over replay windows: a :class:`~mpcasv.models.ident_windows.Windows`
        whose ``residuals(z)`` gives ``(res, jac, Ysim)``.

        ``z = [theta, dpsi0, du0, dv0, dr0 per window]``: each window starts from the smoothed
        measurement plus a small estimated correction of its initial state (multiple
        shooting with initial-state estimation: without it the smoothing and noise of the
        initial states bias the inertia estimates). The RK4 step of the shared model is
        symbolic in ``theta``; it and its forward sensitivities are accumulated over a window
        and mapped over all windows, built once (:mod:`mpcasv.models.ident_windows`).
        """
        dt = parts[0].dt
        W = window_steps(window_s, dt)
        x0, U, Y, lengths = _windows(parts, W, what)
        xs, us, th = ca.SX.sym("x", NX), ca.SX.sym("u", 2), ca.SX.sym("theta", self.n + 2)
        p, c = self._p_c(th)
        f = lambda x, u, c_: self.model.f_param(x, u, c_, p)  # noqa: E731
        step = ca.Function("step", [xs, us, th], [rk4_expr(f, xs, us, c, dt)])
        out = [IX[c] for c in OUTPUTS]
        meas_noise = np.concatenate([pr.X[:, out] - pr.Xs[:, out] for pr in parts]).std(axis=0)
        floor = np.array([math.radians(0.2), 0.01, 0.01, math.radians(0.1)])
        w = 1.0 / np.maximum(meas_noise, floor)
        win = Windows(step, x0, U, Y, out, w, wrap=[0],  # 0: the heading
                      x0_rows=[IX["psi"], IX["u"], IX["v"], IX["r"]],
                      lengths=lengths)  # fmt: skip
        return win, {
            "Y": Y,
            "W": W,
            "windows": win.nwin,
            "lengths": win.lengths,
            "weights": w,
            "n_x0": win.nd * win.nwin,
            "replay": win.simulate,
        }


def _solve(fun, theta0, bounds, max_nfev: int = 100):
    """``least_squares`` on ``z -> (res, jac, ...)`` (a CasADi function or a Python callable
    returning arrays), one evaluation per point."""
    cache: dict = {}

    def both(th):
        key = th.tobytes()
        if key not in cache:
            cache.clear()
            out = fun(th)
            cache[key] = (np.asarray(out[0]).ravel(), np.asarray(out[1]))  # no copy
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
    #: per coefficient: variance of the quoted (HAC) 1-sigma over the plain, independent-
    #: residual one (:mod:`mpcasv.models.ident_cov`; 1 for white residuals)
    var_ratio: dict = dataclasses.field(default_factory=dict)
    rel_std_plain: dict = dataclasses.field(default_factory=dict)  # (J^T J)^-1 s^2, for reference
    #: per coefficient: relative standard deviation of the quoted 1-sigma itself
    #: (:func:`mpcasv.models.ident_cov.sigma_uncertainty`)
    sigma_rel_sd: dict = dataclasses.field(default_factory=dict)
    sigma_method: str = METHOD
    #: coefficient -> what the fit tells of one at its bound (0.2 or 5 x the prior):
    #: :func:`mpcasv.models.ident_bounds.at_bounds`; empty when none is
    at_bound: dict = dataclasses.field(default_factory=dict)
    #: per coefficient: the Bartlett lag of its 1-sigma (samples), and the samples it summed
    sigma_lag: dict = dataclasses.field(default_factory=dict)
    sigma_n: int = 0
    sources: tuple[str, ...] = ()  # the logs, as the refusals name them
    #: held-out weighted error (the fit's criterion) of "prior" and "identified", with the
    #: channel "weights": :func:`mpcasv.models.ident_checks.weighted_error`
    validation_error: dict = dataclasses.field(default_factory=dict)


def identify(logs: list[pd.DataFrame], prior: VesselParams, coeffs=IDENTIFIED,
             current: bool = True, validation: float = 0.25, window_s: float = 30.0,
             progress: bool = False) -> Identification:  # fmt: skip
    """Identify ``coeffs`` (and the current) from identification tables (see module docstring).

    Raises
    ------
    LogError
        Coefficients the logs cannot identify (:mod:`mpcasv.models.ident_checks`: their
        regression columns are zero or collinear, e.g. a steering set-point that never varies,
        or their 1-sigma is not finite), logs with different time steps, a log too short
        for one whole replay window in each of its training and validation parts
        (:func:`mpcasv.models.ident_table.check_length`).
    """
    from mpcasv.models.ident_checks import (
        check_covariance,
        check_identifiable,
        source,
        weighted_error,
        zero_columns,
    )

    if not 0.0 < validation < 0.9:
        raise ValueError(f"validation fraction {validation} not in (0, 0.9)")
    t_start = time.perf_counter()
    say = (
        (lambda m: print(f"[{time.perf_counter() - t_start:6.1f} s] {m}"))
        if progress
        else (lambda m: None)
    )
    names = [source(df, i) for i, df in enumerate(logs)]
    for df, name in zip(logs, names, strict=True):  # before smoothing: it needs a few samples
        dt = float(df["t"].iloc[1] - df["t"].iloc[0])
        check_length(len(df), dt, window_steps(window_s, dt), validation, name,
                     n_shared=len(coeffs) + 2, n_out=len(OUTPUTS), n_corr=4)  # fmt: skip
    prepared = [prepare(df, prior) for df in logs]
    dts = {round(pr.dt, 6) for pr in prepared}
    if len(dts) != 1:
        raise LogError(f"logs have different time steps {sorted(dts)}; resample them alike")
    train, val = zip(*(split(pr, validation) for pr in prepared), strict=True)
    prob = Problem(prior, coeffs, current)
    bounds = prob.bounds()
    th0 = prob.theta0()
    ee_fun = prob.equation_error(list(train))
    J0 = ee_fun(th0)[1][:, : prob.n]
    check_identifiable(J0, prob.coeffs, logs, names)  # before minutes of fitting
    one = len(logs) == 1
    sim_tr, info_tr = prob.replay(list(train), window_s, "the log's training part" if one
                                  else "the logs' training parts")  # fmt: skip
    held = (f"the log's validation part (its last {validation:g}, --validation)" if one else
            f"the logs' validation parts (the last {validation:g} of each log, --validation)")
    sim_va, info_va = prob.replay(list(val), window_s, held)
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
    ee = _solve(ee_fun, th0, bounds)
    say(f"  {ee.nfev} evaluations, status {ee.status}: {ee.message}")
    evaluate("equation_error", ee.x)
    say(f"simulation error on {info_tr['windows']} windows of {info_tr['W']} steps ...")
    se = _solve(sim_tr.residuals, ext(ee.x, info_tr), bounds_ext(info_tr))
    say(f"  {se.nfev} evaluations, status {se.status}: {se.message}")
    lo, hi = bounds_ext(info_tr)
    at_bound = at_bounds(prob.coeffs, se.x, lo, hi, se.jac, se.fun, info_tr["W"],
                         info_tr["windows"], info_tr["lengths"],
                         lambda j, v: float(getattr(prior, prob.coeffs[j]) * v), th0,
                         se.active_mask)  # fmt: skip
    side = active(se.x[: prob.n], lo[: prob.n], hi[: prob.n], se.active_mask[: prob.n])
    theta = se.x[: len(th0)].copy()
    theta[: prob.n] = np.where(side > 0, hi[: prob.n], np.where(side < 0, lo[: prob.n],
                                                                theta[: prob.n]))  # fmt: skip
    evaluate("simulation_error", theta)
    try:
        cov = window_covariance(se.jac, se.fun, info_tr["W"], info_tr["windows"],
                                cols=np.arange(prob.n), lengths=info_tr["lengths"])  # fmt: skip
        std = np.sqrt(np.clip(cov.hac, 0, None)) / np.abs(theta[: prob.n])
        std_plain = np.sqrt(np.clip(cov.plain, 0, None)) / np.abs(theta[: prob.n])
        ratio, shaky, lags, n_sigma = cov.ratio, cov.sigma_rel_sd, cov.lag, cov.n
    except np.linalg.LinAlgError:
        std = std_plain = ratio = shaky = np.full(prob.n, math.inf)
        lags, n_sigma = np.zeros(prob.n, int), 0
    # pinv gives a coefficient without effect a 1-sigma of 0 %: it is unknown (inf)
    std = np.where(zero_columns(se.jac[:, : prob.n]), math.inf, std)
    rel_std = {c: float(s) for c, s in zip(prob.coeffs, std, strict=True)}
    rel_std_plain = {c: float(s) for c, s in zip(prob.coeffs, std_plain, strict=True)}
    var_ratio = {c: float(r) for c, r in zip(prob.coeffs, ratio, strict=True)}
    sigma_rel_sd = {c: float(r) for c, r in zip(prob.coeffs, shaky, strict=True)}
    check_covariance(rel_std, names)
    final = {"train": ext(theta, info_tr), "validation": ext(theta, info_va)}
    w = dict(zip(OUTPUTS, (float(x) for x in info_tr["weights"]), strict=True))
    verr = {"prior": weighted_error(metrics["prior"]["validation"], w),
            "identified": weighted_error(metrics["simulation_error"]["validation"], w),
            "weights": w}  # fmt: skip
    return Identification(
        params=prob.params(theta), coeffs=prob.coeffs, theta=theta,
        rel_std=rel_std,
        current=(float(theta[prob.n]), float(theta[prob.n + 1])) if current else (0.0, 0.0),
        metrics=metrics, var_ratio=var_ratio, rel_std_plain=rel_std_plain,
        sigma_rel_sd=sigma_rel_sd, at_bound=at_bound,
        sigma_lag={c: int(L) for c, L in zip(prob.coeffs, lags, strict=True)},
        sigma_n=int(n_sigma), sources=tuple(names), validation_error=verr,
        replay={"train": (info_tr["Y"], np.array(info_tr["replay"](final["train"]))),
                "validation": (info_va["Y"], np.array(info_va["replay"](final["validation"])))},
    )  # fmt: skip
