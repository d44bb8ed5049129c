"""The identification table: a log's rows on a uniform time grid, set-points held, states
interpolated (:func:`identification_table`), with the grid and the hold as one definition
for every identification (:func:`regular_grid`, :func:`hold_rows`; the thruster-map table of
:mod:`mpcasv.models.ident_thrust` uses them too); the length a fit needs
(:func:`min_samples`, :func:`check_length`); a table prepared for fitting and its split
(:func:`prepare`, :func:`split`). Fitting is :mod:`mpcasv.models.identify`.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd
from scipy.signal import savgol_filter

from mpcasv.errors import LogError
from mpcasv.models.params import VesselParams
from mpcasv.models.vessel import IX, NX

#: columns of an identification table (:mod:`mpcasv.models.identify`, "Log formats")
REQUIRED = ("t", "N", "E", "psi", "u", "v", "r", "T_cmd", "delta_cmd")


def identification_table(df: pd.DataFrame, path) -> pd.DataFrame:
    """The identification table of a log already read (:data:`REQUIRED` columns), on a
    uniform time grid (:func:`regular_grid`; set-points held, :func:`hold_rows`, the rest
    interpolated). Reading files, DUNE logs included, is :func:`mpcasv.io.identlog.load_log`.

    Raises
    ------
    LogError
        Missing columns, bad time axis, non-finite values, too short; naming ``path``.
    """
    missing = [c for c in REQUIRED if c not in df.columns]
    if missing:
        raise LogError(f"{path}: missing columns {missing} (identification format: "
                       f"{', '.join(REQUIRED)})")  # fmt: skip
    df = df[list(REQUIRED)].apply(pd.to_numeric, errors="coerce")
    bad = [c for c in REQUIRED if not np.isfinite(df[c].to_numpy(float)).all()]
    if bad:
        raise LogError(f"{path}: non-numeric or missing values in {bad}")
    t = df["t"].to_numpy(float)
    if len(t) < 2:  # the length a fit needs is checked where it is known: check_length
        raise LogError(f"{path}: too short ({len(t)} sample; a time step needs 2)")
    if np.any(np.diff(t) <= 0):
        raise LogError(f"{path}: time column t is not strictly increasing")
    grid, dt = regular_grid(t, path)
    out = pd.DataFrame({"t": grid - grid[0]})
    psi = np.unwrap(df["psi"].to_numpy(float))
    hold = hold_rows(t, grid, dt)
    for c in REQUIRED[1:]:
        src = psi if c == "psi" else df[c].to_numpy(float)
        out[c] = src[hold] if c in ("T_cmd", "delta_cmd") else np.interp(grid, t, src)
    out.attrs["source"] = str(path)  # named in identify()'s refusals
    return out


def window_steps(window_s: float, dt: float) -> int:
    """Steps of a replay window of ``window_s`` seconds at step ``dt`` (at least 10): one
    rule for both identifications (:mod:`mpcasv.models.identify`,
    :mod:`mpcasv.models.ident_thrust`)."""
    return max(10, int(round(window_s / dt)))


def split_index(n: int, validation: float) -> int:
    """Samples of a log of ``n`` in its training part: the first ``round(n (1 -
    validation))``; the rest is held out (one rule for both identifications)."""
    return int(round(n * (1.0 - validation)))


def min_samples(W: int, validation: float, n_shared: int = 0, n_out: int = 1,
                n_corr: int = 0) -> int:  # fmt: skip
    """The fewest samples a log needs for a replay-window fit: its training part
    (:func:`split_index`) and its held-out part each hold one whole replay window of ``W``
    steps (``W + 1`` samples: a window's outputs are the samples after each step), and the
    training part's residuals (``n_out`` per step) are at least the parameters fitted
    (``n_shared`` for the whole fit plus ``n_corr`` initial-state corrections per window).

    With the default 30-s windows at 0.1 s (``W = 300``) and ``validation = 0.25`` that is
    1,203 samples (the held-out quarter must hold 301; "at least 100" was the rule until
    session 26). The parameter count does not bind for ``identify()`` (four outputs, four
    corrections a window: ``4 W >= p + 4`` for every ``W >= 10`` and all 31 model
    coefficients with the current; one window of 300 steps: 1,200 residuals, 14 parameters by
    default).

    Raises
    ------
    ValueError
        ``validation`` outside (0, 1): a part would never hold a window."""
    if not 0.0 < validation < 1.0:
        raise ValueError(f"validation must be in (0, 1), got {validation}")
    n = 2 * (W + 1)
    while True:  # the parts grow with n (k by 0 or 1 a sample), so the first n that fits
        k = split_index(n, validation)
        if k >= W + 1 and n - k >= W + 1:
            steps = k - 1
            if n_out * steps >= n_shared + n_corr * math.ceil(steps / W):
                return n
        n += 1


def check_length(n: int, dt: float, W: int, validation: float, source, n_shared: int = 0,
                 n_out: int = 1, n_corr: int = 0) -> None:  # fmt: skip
    """Refuse a log of ``n`` samples shorter than :func:`min_samples` in one line: the
    samples needed and given (and seconds), why, and a ``--validation`` that would do when
    one would.

    Raises
    ------
    LogError
        Too short, naming ``source``.
    """
    need = min_samples(W, validation, n_shared, n_out, n_corr)
    if n >= need:
        return
    fits = [v / 100 for v in range(1, 90)
            if min_samples(W, v / 100, n_shared, n_out, n_corr) <= n]  # fmt: skip
    hint = (f"; --validation {min(fits, key=lambda v: abs(v - validation)):g} would fit it"
            if fits else "; no --validation fits it (the fewest samples, at 0.5: "
            f"{min_samples(W, 0.5, n_shared, n_out, n_corr)})")  # fmt: skip
    k = split_index(n, validation)
    raise LogError(f"{source}: too short to identify from: {need} samples ({need * dt:g} s) "
                   f"needed, {n} given ({n * dt:g} s): one whole {W}-step ({W * dt:g} s) "
                   "replay window must fit in each of the training and validation parts (the "
                   f"last {validation:g} held out, --validation), which have {k} and {n - k} "
                   f"samples{hint}")  # fmt: skip


#: the longest gap a log may have, in its steps: a shorter one is bridged (states
#: interpolated, set-points held), a longer one refused (a 3-s hole bridged by straight
#: lines moved N_rdot 22 % and X_udot 118 %, silently, session 25)
MAX_GAP_STEPS = 3.0


def regular_grid(t: np.ndarray, source) -> tuple[np.ndarray, float]:
    """``(grid, dt)``: the uniform time grid (s) a log with strictly increasing times ``t``
    is resampled onto, and its step. ``dt`` is the span over the number of steps it holds
    (each interval counted in median steps, rounded: a missing sample counts as the step it
    misses), not the median step itself: on jittered times the median is a little off and a
    grid built from it drifts against the logged times (uniform +-4 ms jitter on a 150-s
    0.1-s zig-zag: 1 to 148 ms over 8 seeds, so steering switches fell a step off and N_rdot
    came out 23 % off with a 4.5 % 1-sigma; DUNE's Otter log: 7.3 ms at most, now 3.9 ms).
    One definition for every identification table (this module's and
    :func:`mpcasv.models.ident_thrust.check_table`).

    Raises
    ------
    LogError
        A gap longer than :data:`MAX_GAP_STEPS` steps, naming ``source``, where and how long.
    """
    d = np.diff(t)
    med = float(np.median(d))
    i = int(np.argmax(d))
    if d[i] > MAX_GAP_STEPS * med:
        raise LogError(f"{source}: a gap of {d[i]:.3g} s after t = {t[i] - t[0]:.1f} s (the "
                       f"log's step is {med:.3g} s; at most {MAX_GAP_STEPS:g} steps are "
                       "bridged): identification replays a regular log; split it at the gap "
                       "and give the parts as separate logs")  # fmt: skip
    steps = max(1, int(np.sum(np.maximum(1, np.round(d / med)))))  # a dropped sample: 2
    dt = float((t[-1] - t[0]) / steps)
    return t[0] + dt * np.arange(steps + 1), dt


def hold_rows(t: np.ndarray, grid: np.ndarray, dt: float) -> np.ndarray:
    """Index of the logged row whose set-point holds at each ``grid`` time (zero-order hold):
    the row whose ``[t_k - dt/2, t_k + dt/2)`` contains it, a row's set-point acting over its
    own step. One rule for every identification table (this module's, and the thruster map's
    actuations, :func:`mpcasv.models.ident_thrust.check_table`).

    The half-step tolerance matters: ``grid`` is ``t_0 + k dt`` (:func:`regular_grid`), and
    logged times are rounded, jitter and drift around it. A plain ``searchsorted(t, grid,
    side="right") - 1`` took the previous row, one step late, wherever the grid fell just
    before the logged time: a CSV that rounds ``t`` to 6 digits made the median step 3.6e-16 s
    short for logs of 137 s or more at 0.1 s (every steering switch a step late until session
    24, then a tolerance of 1e-3 step); in DUNE's Otter log (dune-otter-ident) ``t_k - grid_k``
    is 0.18 to 3.6 ms (5th-95th percentile, up to 7.3 ms) and 6,633 of the 6,651 actuations
    were a step late (session 25).
    """
    return np.clip(np.searchsorted(t, grid + dt / 2, side="right") - 1, 0, len(t) - 1)


# --- a table prepared for fitting (mpcasv.models.identify; here since session 26: size) -----


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
    k = split_index(len(pr.U), validation)
    arrays = (pr.X, pr.Xs, pr.U, pr.nudot)
    return (Prepared(pr.dt, *(a[:k] for a in arrays)),
            Prepared(pr.dt, *(a[k:] for a in arrays)))  # fmt: skip
