"""Held-out accuracy of a vessel identified through a thruster map, *as written*.

The identification through DUNE's thruster map (:mod:`mpcasv.models.ident_thrust`) fits the
hull with the log's actuations driven through VSIM's nonlinear map (speed-dependent force,
clipped at ``F_max`` and ``Q_max`` per thruster). The vessel file cannot hold that map: its
own actuator model is linear (:func:`mpcasv.models.vessel.dune_actuators`: ``T = (a_0 + a_1)
T_max / 2``, ``delta = delta_max (a_0 - a_1) / 2``, so a yaw moment ``y_thr T_max (a_0 -
a_1) / 2``; for ``dune-otter`` 0.12 N m at 1 % differential where VSIM's map gives 6.5 N m
at 0.21 actuation and 0.7 m/s), with first-order lags ``T_thrust``, ``T_delta``. That is
what the simulator, the MPC and the tuning use. The held-out RMS through the map is
therefore not the accuracy of the file: :func:`written_accuracy` replays the same held-out
windows through the file's own actuator model, and ``mpcasv identify`` writes both, and
warns when they differ by more than :data:`GAP_FACTOR`.

Replay (the same windows as the map fit's held-out replay, :func:`replay_windows`): windows
of ``window_s`` re-initialised from the logged state (``psi``, ``u``, ``v``, ``r``; no
smoothing, as the map's), the lag states ``T``, ``delta`` reconstructed from the set-points
through the written lags from the start of the log (exact zero-order hold,
:func:`mpcasv.models.ident_table.prepare`), RK4 of the shared model in ``n_sub`` sub-steps,
no current (DUNE's run had none), outputs after each step compared with the log.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pandas as pd

from mpcasv.models.ident_table import prepare, split_index, window_steps
from mpcasv.models.ident_thrust import OUTPUTS, rms
from mpcasv.models.ident_windows import Windows, window_lengths
from mpcasv.models.params import VesselParams
from mpcasv.models.vessel import IX, NX, VesselModel, dune_actuators, rk4_expr

#: an as-written held-out RMS (u or r, the fitted channels) above this many times the one
#: through the map is a gap ``mpcasv identify`` warns about (stderr and the file's header):
#: the map's own RMS is at the log's noise floor (r: EstimatedState's 0.017 rad/s), so twice
#: it is already a model error of the size of the noise
GAP_FACTOR = 2.0
#: the channels compared for the gap (psi is reported, not fitted: ident_thrust._WEIGHT)
GAP_CHANNELS = ("u", "r")


def replay_windows(X: np.ndarray, U: np.ndarray, P: VesselParams, dt: float,
                   window_s: float = 30.0, n_sub: int = 2) -> np.ndarray:  # fmt: skip
    """Simulated outputs :data:`~mpcasv.models.ident_thrust.OUTPUTS` (shape ``(3, n - 1)``)
    of ``P`` replaying inputs ``U`` (``(n, 2)``: ``T_cmd`` N, ``delta_cmd`` rad; row ``k``
    acts over ``[t_k, t_k+1)``) from the states ``X`` (``(n, NX)``, model order) in windows
    of ``window_s`` re-initialised from ``X``; the outputs are those after each step (compare
    with ``X[1:]``)."""
    n = len(X) - 1
    W = window_steps(window_s, dt)
    lengths = window_lengths(n, W)
    model = VesselModel(P)
    xs, us, th = ca.SX.sym("x", NX), ca.SX.sym("u", 2), ca.SX.sym("th", 0)
    step = ca.Function("written_step", [xs, us, th],
                       [rk4_expr(model.f, xs, us, ca.DM.zeros(2), dt, n_sub)])  # fmt: skip
    out = [IX[c] for c in OUTPUTS]
    x0 = X[:n:W].T
    win = Windows(step, x0, U[:n].T, X[1 : n + 1, out].T, out, np.ones(len(out)), wrap=[0],
                  lengths=lengths)  # fmt: skip
    return np.asarray(win.simulate(np.zeros(0)))


def written_accuracy(table: pd.DataFrame, P: VesselParams, validation: float,
                     window_s: float = 30.0, n_sub: int = 2) -> dict:  # fmt: skip
    """Held-out accuracy of ``P`` as written, on a thruster-map table (columns
    :data:`~mpcasv.models.ident_thrust.MAP_COLUMNS`): the actuations ``a_0``, ``a_1`` through
    ``P``'s own actuator model (:func:`~mpcasv.models.vessel.dune_actuators`), the held-out
    part the last ``validation`` of the log (:func:`~mpcasv.models.ident_table.split_index`,
    as the map fit's).

    Returns
    -------
    dict
        ``"validation"``: RMS error per output (psi rad, u m/s, r rad/s, :func:`rms`);
        ``"std"``: the held-out logged u and r standard deviations (m/s, rad/s: the scale the
        errors compare with); ``"replay"``: (measured, simulated) arrays ``(3, n)``.
    """
    T_cmd, delta_cmd = dune_actuators(P, table["a_0"].to_numpy(float),
                                      table["a_1"].to_numpy(float))  # fmt: skip
    inputs = pd.DataFrame({c: table[c] for c in ("t", "N", "E", "psi", "u", "v", "r")})
    inputs["T_cmd"], inputs["delta_cmd"] = T_cmd, delta_cmd
    pr = prepare(inputs, P)  # the lag states through the written lags, from the log's start
    k = split_index(len(table), validation)
    X, U = pr.X[k:], pr.U[k:]
    Ysim = replay_windows(X, U, P, pr.dt, window_s, n_sub)
    Y = X[1:, [IX[c] for c in OUTPUTS]].T
    std = {c: float(np.std(X[:, IX[c]])) for c in GAP_CHANNELS}
    return {"validation": rms(Ysim, Y), "std": std, "replay": (Y, Ysim)}


def gap(through_map: dict[str, float], as_written: dict[str, float]) -> dict[str, float]:
    """The fitted channels (:data:`GAP_CHANNELS`) whose as-written held-out RMS is above
    :data:`GAP_FACTOR` times the one through the map: channel -> ratio (empty: no gap)."""
    out = {}
    for c in GAP_CHANNELS:
        ratio = as_written[c] / through_map[c] if through_map[c] > 0 else np.inf
        if ratio > GAP_FACTOR:
            out[c] = float(ratio)
    return out
