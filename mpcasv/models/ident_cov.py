"""Covariance of coefficients identified by replay-window least squares, shared by
:func:`mpcasv.models.identify.identify` and
:func:`mpcasv.models.ident_thrust.identify_through_map`.

The plain covariance ``(J^T J)^-1 s^2`` assumes independent residuals. Measurement noise is,
but a model that does not match the data (a wrong structure, a set-point a step late) or a
navigation filter (DUNE logs: the estimator's states are smooth) leaves serially correlated
residuals, and the plain figures are overconfident. Here the variance of each coefficient is
the heteroscedasticity-and-autocorrelation-consistent (HAC) sandwich of Newey & West (1987,
"A simple, positive semi-definite, heteroskedasticity and autocorrelation consistent
covariance matrix", Econometrica 55(3) 703-708)::

    V = (J^T J)^-1  S  (J^T J)^-1,   S = sum over windows of
        sum_t g_t g_t^T + sum_{l=1..L} (1 - l / (L + 1)) sum_t (g_t g_{t-l}^T + g_{t-l} g_t^T)

with ``g_t = J_t^T e_t`` the score of sample ``t`` (its rows of the Jacobian, all output
channels of that instant, times their residuals), Bartlett weights ``1 - l / (L + 1)``, and the
lags taken **within** each replay window only (windows restart from the measurement and are
independent by construction). A small-sample factor ``N / (N - p)`` matches the plain
estimate's degrees of freedom.

Lag ``L`` per coefficient: Andrews' (1991, "Heteroskedasticity and autocorrelation consistent
covariance matrix estimation", Econometrica 59(3) 817-858, eq. 6.2/6.4) automatic bandwidth for
the Bartlett kernel with an AR(1) plug-in, ``L = 1.1447 (alpha n)^(1/3)``,
``alpha = 4 rho^2 / ((1 - rho)^2 (1 + rho)^2)``, ``rho`` the lag-1 autocorrelation (within
windows) of that coefficient's projected score series ``a_j^T g_t`` and ``n`` the number of
samples; never below Newey & West's (1994) fixed rule ``floor(4 (W / 100)^(2/9))``, at most
``W - 1``. The correlation that matters for a coefficient is that of its score (sensitivity
times residual), not of the residuals alone: a coefficient fixed by a channel whose residual is
white keeps its plain figure even if another channel's residual is smooth.

The HAC variance is itself an estimate: with Bartlett weights ``1 - l / (L + 1)`` (bandwidth
``S_T = L + 1``) its asymptotic relative variance is ``(4 / 3) (L + 1) / n`` (Andrews 1991,
Proposition 1(b): ``(n / S_T) Var -> 2 S^2 int k^2``, ``int k^2 = 2 / 3`` for the Bartlett
kernel), so the quoted 1-sigma has a relative standard deviation of about
``sqrt((L + 1) / (3 n))`` (half that of the variance, delta method). With a lag that reaches
the window (``L = W - 1``) and three windows (the default 150-s zig-zag's training part in
30-s windows) that is 33 %: the report then says the 1-sigma is uncertain (above
:data:`SHAKY`).

The ratio ``V_hac / V_plain`` per coefficient is reported (1 for white, homoscedastic
residuals): above :data:`RATIO_WARN` the residuals are serially correlated (the model misses
the data, or the logged states are filtered) and the plain figure would be overconfident.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

#: a coefficient whose 1-sigma is above this (relative) is named as poorly determined
LOOSE = 0.25
#: variance ratio HAC / plain above which the report says the residuals are correlated
RATIO_WARN = 4.0
#: relative standard deviation of a quoted 1-sigma above which the report says it is uncertain
SHAKY = 0.2
#: what the outputs record as the 1-sigma basis
METHOD = ("Newey-West HAC sandwich (Bartlett weights, within replay windows, lag per "
          "coefficient by Andrews' AR(1) rule)")  # fmt: skip


@dataclasses.dataclass(frozen=True)
class Covariance:
    """Variances of selected parameters: ``hac`` (quoted), ``plain`` (independent residuals),
    their ``ratio``, the Bartlett ``lag`` used (samples) and ``sigma_rel_sd``, the relative
    standard deviation of the HAC 1-sigma itself (:func:`sigma_uncertainty`), per parameter."""

    hac: np.ndarray
    plain: np.ndarray
    ratio: np.ndarray
    lag: np.ndarray
    sigma_rel_sd: np.ndarray
    method: str = METHOD
    n: int = 0  # samples the scores were summed over (the n of :func:`sigma_uncertainty`)


def nw_lag(W: int) -> int:
    """Newey & West's (1994) fixed rule ``floor(4 (W / 100)^(2/9))``, at least 1."""
    return max(1, int(math.floor(4 * (W / 100.0) ** (2.0 / 9.0))))


def andrews_lag(h: np.ndarray, W: int, n: int | None = None) -> int:
    """Bartlett lag for one score series ``h`` of shape ``(windows, W)`` (see module doc;
    ``n``: its samples, when shorter windows are padded with zeros, default ``h.size``)."""
    den = float(np.sum(h[:, :-1] ** 2))
    rho = float(np.sum(h[:, 1:] * h[:, :-1])) / den if den > 0 else 0.0
    rho = min(max(rho, -0.99), 0.99)
    alpha = 4 * rho**2 / ((1 - rho) ** 2 * (1 + rho) ** 2)
    L = int(math.ceil(1.1447 * (alpha * (h.size if n is None else n)) ** (1.0 / 3.0)))
    return int(min(W - 1, max(nw_lag(W), L)))


def sigma_uncertainty(lag, n: int) -> np.ndarray:
    """Relative standard deviation of a 1-sigma from a Bartlett long-run variance with lag
    ``lag`` (bandwidth ``lag + 1``) over ``n`` samples: ``sqrt((lag + 1) / (3 n))``, half the
    variance's ``sqrt(4 (lag + 1) / (3 n))`` (Andrews 1991, Proposition 1(b); module
    docstring). Asymptotic; on white noise in 3 windows of 300 samples (Monte Carlo, 2000
    draws, session 25) the spread was 0.029 / 0.048 / 0.065 / 0.28 against 0.027 / 0.047 /
    0.064 / 0.33 for lag 1 / 5 / 10 / 299 (at a lag as long as the window it overstates)."""
    return np.sqrt((np.asarray(lag, float) + 1.0) / (3.0 * n))


def samples_for(lag: int, rel_sd: float) -> int:
    """The fewest samples over which :func:`sigma_uncertainty` at ``lag`` is at most
    ``rel_sd``: ``ceil((lag + 1) / (3 rel_sd^2))``."""
    return math.ceil((lag + 1) / (3.0 * rel_sd**2))


def bartlett_lrv(h: np.ndarray, L: int) -> float:
    """Sum over windows of the Bartlett-weighted long-run variance of ``h`` (windows, W)."""
    s = float(np.sum(h * h))
    for lag in range(1, L + 1):
        s += 2 * (1 - lag / (L + 1)) * float(np.sum(h[:, lag:] * h[:, :-lag]))
    return s


def window_covariance(J: np.ndarray, res: np.ndarray, W: int, nwin: int, cols=None,
                      lengths=None) -> Covariance:  # fmt: skip
    """HAC and plain variances of the parameters ``cols`` (default all) of a least-squares fit
    with Jacobian ``J`` and residuals ``res``, laid out as the replay functions build them:
    ``nwin`` windows of ``W`` samples one after the other (or of ``lengths``, each at most
    ``W``: :class:`~mpcasv.models.ident_windows.Windows`), each sample's ``k`` output
    channels together (``ca.vec`` of a ``(k, n)`` matrix), ``len(res) = k n``."""
    from mpcasv.models.ident_windows import padded_index

    J = np.asarray(J, float)
    e = np.asarray(res, float).ravel()
    N, p = J.shape
    lengths = np.full(nwin, W) if lengths is None else np.asarray(lengths, int)
    n = int(lengths.sum())
    if N != len(e) or N % n or len(lengths) != nwin or lengths.max() > W:
        raise ValueError(f"{N} residual rows do not split into {nwin} windows of {W} samples"
                         + ("" if n == W * nwin else f" ({n} in all)"))  # fmt: skip
    k = N // n
    cols = np.arange(p) if cols is None else np.asarray(cols)
    Hinv = np.linalg.pinv(J.T @ J)
    A = Hinv[:, cols]  # (p, m)
    dof = max(1, N - p)
    plain = np.diag(Hinv)[cols] * float(e @ e) / dof
    # projected scores a_j^T g_t per sample (channels of one instant summed), per window; a
    # shorter window padded with zero scores (they add nothing to any sum)
    g = ((J @ A) * e[:, None]).reshape(n, k, len(cols)).sum(axis=1)
    H = np.zeros((nwin * W, len(cols)))
    H[padded_index(lengths, W)] = g
    H = H.reshape(nwin, W, len(cols))
    hac, lags = np.empty(len(cols)), np.empty(len(cols), int)
    for j in range(len(cols)):
        h = H[:, :, j]
        lags[j] = andrews_lag(h, W, n)
        hac[j] = bartlett_lrv(h, lags[j]) * N / dof
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(plain > 0, hac / plain, 1.0)
    return Covariance(hac=hac, plain=plain, ratio=ratio, lag=lags,
                      sigma_rel_sd=sigma_uncertainty(lags, n), n=n)


def ratio_line(var_ratio: dict) -> str:
    """One report line: the 1-sigma basis and each coefficient's HAC / plain variance."""
    ratios = ", ".join(f"{c} {r:.2g}" for c, r in var_ratio.items())
    return (f"1-sigma: {METHOD}; its variance over the independent-residual one "
            f"(J^T J)^-1 s^2: {ratios}")


def data_name(n_logs: int) -> str:
    """How the report names the data: "this log" for one, "these logs" for several."""
    return "this log" if n_logs == 1 else "these logs"


def fixed(x: float, digits: int = 3, zero: float = 1e-6) -> str:
    """``x`` with ``digits`` decimals, read as written: a figure that rounds to zero has no
    minus ("-0.000" was printed for a current of -2e-9 m/s), and a value that rounds to zero
    but is at least ``zero`` in size keeps two significant digits (0.00042) instead."""
    if not math.isfinite(x):
        return str(x)
    text = f"{x:.{digits}f}"
    if float(text) != 0.0:
        return text
    return f"{x:.2g}" if abs(x) >= zero else f"{0.0:.{digits}f}"


def correlated_warning(var_ratio: dict, source: str = "these logs") -> str | None:
    """The report's warning when a coefficient's HAC variance is above :data:`RATIO_WARN`
    times the plain one (``None`` otherwise); ``source`` names the data (:func:`data_name`)."""
    high = {c: r for c, r in var_ratio.items() if r > RATIO_WARN}
    if not high:
        return None
    worst = max(high, key=high.get)
    return (f"The replay residuals are serially correlated: the HAC variance is up to "
            f"{high[worst]:.0f} times the independent-residual one ({worst}; above "
            f"{RATIO_WARN:g} for {', '.join(high)}; the 1-sigma includes it). Either the model "
            f"does not explain {source} to {'its' if source.startswith('this') else 'their'} "
            "noise level (a wrong structure, a set-point "
            "logged a step late), or the logged states are filtered (DUNE logs: the "
            "navigation estimator's states are smooth, not white measurements).")  # fmt: skip


def report_notes(coeffs, rel_std: dict, var_ratio: dict, source: str = "these logs",
                 sigma_rel_sd: dict | None = None, at_bound: dict | None = None,
                 lag: dict | None = None, n: int = 0) -> list[str]:  # fmt: skip
    """The report's lines after the coefficient table, for both identification methods: the
    1-sigma basis with each coefficient's HAC / plain ratio (:func:`ratio_line`), the
    coefficients whose 1-sigma is above :data:`LOOSE` (not those at a bound: ``at_bound``,
    :func:`mpcasv.models.ident_bounds.bound_notes` says what the fit tells of them),
    :func:`correlated_warning` and :func:`uncertain_sigma_note` (``lag``, ``n``); each
    preceded by a blank line. ``source`` names the data (:func:`data_name`)."""
    from mpcasv.models.ident_bounds import bound_notes

    at_bound = at_bound or {}
    lines = ["", ratio_line(var_ratio)] if var_ratio else []
    loose = [c for c in coeffs if rel_std[c] > LOOSE and c not in at_bound]
    if loose:
        it = "it" if len(loose) == 1 else "them"
        lines += ["", f"Poorly determined by {source} (1-sigma above {100 * LOOSE:.0f} %): "
                  f"{', '.join(loose)}; hold {it} at the prior (--coeffs without {it}) or log "
                  f"a manoeuvre that excites {it} (speed steps for the surge terms)."]  # fmt: skip
    lines += bound_notes(at_bound, source)
    notes = [correlated_warning(var_ratio, source),
             uncertain_sigma_note(sigma_rel_sd or {}, source, lag, n)]  # fmt: skip
    return lines + [x for note in notes if note for x in ("", note)]


def uncertain_sigma_note(sigma_rel_sd: dict, source: str = "these logs",
                         lag: dict | None = None, n: int = 0) -> str | None:  # fmt: skip
    """The report's line when a quoted 1-sigma is itself uncertain by more than
    :data:`SHAKY` (:func:`sigma_uncertainty`; ``None`` when none is). With the Bartlett
    ``lag`` per coefficient and the ``n`` samples the scores were summed over it gives the
    formula's figures and the samples that would bring it to :data:`SHAKY` at that lag."""
    shaky = {c: r for c, r in sigma_rel_sd.items() if r > SHAKY}
    if not shaky:
        return None
    which = "every coefficient" if len(shaky) == len(sigma_rel_sd) else ", ".join(shaky)
    worst = max(shaky, key=shaky.get)
    figures = ""
    if lag and n and worst in lag:
        L = int(lag[worst])
        need = samples_for(L, SHAKY)
        figures = (f"; {worst}: lag L = {L} samples over n = {n:,} samples in replay windows, "
                   f"sqrt((L + 1) / (3 n)); at that lag it falls to {100 * SHAKY:.0f} % from "
                   f"n = {need:,}, {need / n:.1f} times the samples")  # fmt: skip
    return (f"The quoted 1-sigma is itself uncertain ({which}): its HAC variance sums the "
            f"scores over a lag that is long against the samples of {source} in replay "
            "windows, so it rests on few independent pieces; the 1-sigma's own relative "
            f"standard deviation is about {100 * shaky[worst]:.0f} % (asymptotic{figures}). "
            "Read it as an order of magnitude; a longer log, or more logs, give more "
            "samples.")  # fmt: skip
