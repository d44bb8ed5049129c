"""The MPC problem's parameter vector (docs/mpc.md, "Variables and dynamics"): its layout,
how it is packed from the per-step data and unpacked again. A mixin of
:class:`~mpcasv.mpc.problem.OCP` (its dimensions live there), with the channel and weight
vectors it holds.

    p = [z_0 (nx), current (2), stage parameters (N+1 x 5K), d_fix (K), r_t (K),
         target one-hot (K), channel (NCH), weights (NW), variance block (n_ext; 0 by default)]
"""

from __future__ import annotations

import numpy as np

from mpcasv.models.acoustics import AcousticParams
from mpcasv.mpc.variance import N_TAIL

#: the cost weights are parameters (retuning needs no recompilation), in this order
WEIGHT_NAMES = (
    "age",
    "worst",
    "thrust",
    "power",
    "dT",
    "ddelta",
    "slack",
    "tail",
    "inv_U_go",
    "deadband",
    "running",
    "stand",
    "accrue",
)
NW = len(WEIGHT_NAMES)
#: the acoustic channel as it enters the parameters (channel_vector), in this order
CHANNEL_NAMES = ("rate", "p_good", "p_sporadic", "d1", "d2", "propeller_factor")
NCH = len(CHANNEL_NAMES)


def channel_vector(ac: AcousticParams, noisy: bool = False) -> np.ndarray:
    """The fix-rate model's channel parameters (eq. M3) from the scenario's (or deploy
    configuration's) acoustic channel: transmissions per second per AUV (``1 / T0`` with USBL,
    else the status reports' ``1 / T_report``), success probabilities within ``d1`` and in
    ``(d1, d2]``, and the factor while the propeller runs when such fixes count (``noisy``,
    :attr:`~mpcasv.mpc.params.FixRateParams.noisy_fixes`; else 0)."""
    rate = 1.0 / ac.T0 if ac.usbl else 1.0 / ac.T_report
    f_prop = ac.propeller_factor if noisy else 0.0
    return np.array([rate, ac.p_good, ac.p_sporadic, ac.d1, ac.d2, f_prop])


class ParamLayout:
    """Packing and unpacking of the OCP's parameter vector (mixin; state in the OCP)."""

    def pack(self, x0, tau0, current, pa, r_lo, r_hi, depth, d_fix, r_t,
             target: int = 0, channel=None, ext=None) -> np.ndarray:  # fmt: skip
        """Parameter vector from the per-step data.

        Parameters
        ----------
        x0 : array (8,)
            Vessel state ``[N, E, psi, u, v, r, T, delta]`` (with ``steering = "heading"``
            the last is the heading reference ``psi_ref``, rad: M1h).
        tau0 : array (K,)
            Expected fix ages now (s).
        current : array (2,)
            ``[V_N, V_E]`` (m/s).
        pa : array (N+1, K, 2)
            Predicted AUV positions at the stage times.
        r_lo, r_hi : array (N+1, K)
            Lower (r_inner / r_avoid) and upper (r_outer) range bounds per stage (m).
        depth : array (N+1, K) or (K,)
            Forecast AUV depth per stage (m; a (K,) array: constant over the horizon).
        d_fix, r_t : array (K,)
            Range of the reliable-fix sigmoid (``target`` fix model), target radius (m).
        target : int
            The AUV the terminal cost has the ASV visit next.
        channel : array (NCH,), optional
            :func:`channel_vector` of the run's acoustic channel (default: the default
            :class:`~mpcasv.models.acoustics.AcousticParams`).
        ext : array (n_ext,), optional
            ``objective = "variance"`` only: :meth:`ext_vector` (default: the default
            channel, the AUVs held where the horizon ends).
        """
        d = self.dims
        K, N = d.n_auv, d.N
        dep = np.broadcast_to(np.asarray(depth, float), (N + 1, K))
        ch = (channel_vector(AcousticParams(), self.params.fix.noisy_fixes) if channel is None
              else np.asarray(channel, float))  # fmt: skip
        stage = np.concatenate(
            [np.asarray(pa, float).reshape(N + 1, 2 * K), np.asarray(r_lo, float),
             np.asarray(r_hi, float), dep], axis=1,
        )  # fmt: skip
        return np.concatenate([np.asarray(x0, float), np.asarray(tau0, float),
                               np.asarray(current, float), stage.ravel(),
                               np.asarray(d_fix, float), np.asarray(r_t, float),
                               np.eye(K)[target], ch, self.weight_vector(),
                               self._ext_or_default(ext, pa, dep)])  # fmt: skip

    def _ext_or_default(self, ext, pa, dep) -> np.ndarray:
        """The variance block for :meth:`pack` (empty for the default objective)."""
        if not self.variance:
            return np.zeros(0)
        if ext is not None:
            return np.asarray(ext, float)
        K = self.dims.n_auv
        last = np.asarray(pa, float).reshape(-1, K, 2)[-1]  # (K, 2)
        return self.ext_vector(AcousticParams(), np.repeat(last[:, None], N_TAIL, axis=1),
                               np.repeat(dep[-1][:, None], N_TAIL, axis=1), last)  # fmt: skip

    def weight_vector(self) -> np.ndarray:
        """The cost weights as they enter the parameter vector (normalised, M4)."""
        wt, vp = self.params.weights, self.vessel
        return np.array([wt.age / wt.tau_ref, wt.worst / wt.tau_ref, wt.thrust / vp.T_max,
                         wt.power / (vp.T_max * vp.u_max), wt.dT / self.dT_max**2,
                         wt.ddelta / self.dd_max**2, wt.slack, wt.tail, 1 / wt.U_go,
                         wt.deadband, wt.running, wt.stand, 1.0])  # fmt: skip

    def unpack_par(self, p: np.ndarray) -> dict:
        """Inverse of :meth:`pack` (arrays)."""
        d = self.dims
        K, N, nx = d.n_auv, d.N, d.nx
        o = nx + 2
        S = p[o : o + (N + 1) * d.n_stage_par].reshape(N + 1, d.n_stage_par)
        o += (N + 1) * d.n_stage_par
        return {
            "z0": p[:nx], "current": p[nx:nx + 2], "pa": S[:, :2 * K].reshape(N + 1, K, 2),
            "r_lo": S[:, 2 * K:3 * K], "r_hi": S[:, 3 * K:4 * K], "depth": S[:, 4 * K:5 * K],
            "d_fix": p[o:o + K], "r_t": p[o + K:o + 2 * K],
            "target": int(np.argmax(p[o + 2 * K:o + 3 * K])),
            "channel": p[o + 3 * K:o + 3 * K + NCH],
            "weights": p[o + 3 * K + NCH:o + 3 * K + NCH + NW],
            "ext": p[o + 3 * K + NCH + NW:o + 3 * K + NCH + NW + d.n_ext],
        }  # fmt: skip
