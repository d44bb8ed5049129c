"""Replay windows for simulation-error identification, with forward sensitivities.

Both identifications (:mod:`mpcasv.models.identify`, :mod:`mpcasv.models.ident_thrust`)
replay the logged inputs through one discrete step ``x_{k+1} = F(x_k, a_k, theta)`` of the
shared model (RK4 of :meth:`mpcasv.models.vessel.VesselModel.f_param`), window by window,
each window re-initialised from the measurement (plus, optionally, a small estimated
correction ``d_j`` of some of its initial states), and fit ``theta`` by least squares on the
weighted output errors. ``scipy.optimize.least_squares`` needs the residuals' Jacobian.

The Jacobian is propagated forward along each window with the states (forward sensitivity,
e.g. Ljung, *System Identification*, 1999, sec. 10.3)::

    S_0 = [0, E],   S_{k+1} = A_k S_k + [B_k, 0],   A_k = dF/dx,  B_k = dF/dtheta

``S_k = dx_k / d[theta, d_j]`` (``E`` selects the corrected initial states), in one CasADi
SX function per step (the step, its two Jacobians and the product), accumulated over a
window (``mapaccum``) and mapped over the windows (``map``). It is the same derivative as
CasADi's automatic differentiation of the whole replay (which the identifications used
before, ``ca.jacobian`` of an MX graph): ``tests/test_ident_windows.py`` compares the two
to round-off. Measured (session 25, CPU time, two runs each, one script, the machine shared):
one evaluation with its Jacobian on ``tests/test_identify.py``'s problem (18 windows of 300
steps, 10 parameters, 72 initial-state corrections) 0.41 s against 1.08 s; the whole
``identify`` there 11-17 s against 25-28 s (the equation error's Jacobian per sample too,
:meth:`mpcasv.models.identify.Problem.equation_error`); the DUNE Otter's thruster-map fit
4.5-5.1 s against 13.5-13.9 s. The results agree to the last digits (coefficients within
1e-14 relative, the 1-sigma alike).

The Jacobian is returned dense, as before: with initial-state corrections its size grows
with the square of the log's length (a 30-min log at 10 Hz in 30-s windows: 50 400 x 178,
72 MB; 2 h: about 1.1 GB). Its correction columns are block-diagonal, so a sparse Jacobian
and ``least_squares(tr_solver="lsmr")`` would make it linear (not done).
"""

from __future__ import annotations

from collections.abc import Sequence

import casadi as ca
import numpy as np

__all__ = ["Windows", "padded_index", "window_lengths"]


def window_lengths(n_steps: int, W: int) -> list[int]:
    """The replay windows over a part of ``n_steps`` steps (``n_steps + 1`` samples): whole
    windows of ``W`` steps, then the steps after the last one as one shorter window (they were
    left out, unsaid, until session 26). Both identifications split their parts here."""
    return [min(W, n_steps - k) for k in range(0, n_steps, W)]


def padded_index(lengths: Sequence[int], W: int) -> np.ndarray:
    """Where the samples of windows of ``lengths`` (each at most ``W``), one after the
    other, sit when every window is padded to ``W``: window ``j``'s sample ``i`` at
    ``j W + i``."""
    lengths = np.asarray(lengths, int)
    if not len(lengths):
        return np.zeros(0, int)
    return np.concatenate([j * W + np.arange(L) for j, L in enumerate(lengths)])


class Windows:
    """Replay windows of a step ``F(x, a, theta) -> x_next`` and their weighted residuals.

    Parameters
    ----------
    step:
        CasADi function ``(x (nx), a (na), theta (n_th)) -> x_next (nx)``; differentiable
        (SX or MX of SX functions).
    x0:
        Initial states, shape ``(nx, nwin)``.
    A:
        Inputs, shape ``(na, nwin * W)``: window ``j``'s inputs are columns
        ``j W .. (j + 1) W - 1``.
    Y:
        Measured outputs after each step, shape ``(len(out), nwin * W)``.
    out:
        State indices of the outputs (rows of ``Y``).
    weights:
        Weight of each output's error (``1 / typical error``), length ``len(out)``.
    wrap:
        Output rows whose errors are angles, wrapped to ``(-pi, pi]``.
    x0_rows:
        State indices with an estimated initial correction per window (the parameter vector
        of :meth:`residuals` is then ``[theta, d_0, d_1, ...]``, ``d_j`` of length
        ``len(x0_rows)``); empty for none.
    lengths:
        Steps of each window (``A`` and ``Y`` then hold ``sum(lengths)`` columns, window after
        window); default: ``nwin`` windows of one length. A log's samples after its last
        whole window form a shorter window (session 26: they were left out silently).

    Raises
    ------
    ValueError
        Shapes that do not agree; weights not one per output; wrapped rows, outputs or
        corrected states out of range.
    """

    def __init__(self, step: ca.Function, x0: np.ndarray, A: np.ndarray, Y: np.ndarray,
                 out: Sequence[int], weights: Sequence[float], wrap: Sequence[int] = (),
                 x0_rows: Sequence[int] = (), lengths: Sequence[int] | None = None):  # fmt: skip
        nx, self.nwin = x0.shape
        if lengths is None:  # windows of one length
            W = A.shape[1] // max(self.nwin, 1)
            lengths = [W] * self.nwin
        self.lengths = np.asarray(lengths, int)
        self.W = int(self.lengths.max()) if self.nwin else 0
        self.n = int(self.lengths.sum())  # samples replayed (outputs compared)
        if (len(self.lengths) != self.nwin or (self.nwin and self.lengths.min() < 1)
                or A.shape[1] != self.n or Y.shape != (len(out), self.n)):  # fmt: skip
            raise ValueError(f"windows: x0 {x0.shape}, A {A.shape}, Y {Y.shape} and "
                             f"{len(self.lengths)} window lengths do not agree")  # fmt: skip
        if len(weights) != len(out) or not set(wrap) <= set(range(len(out))):
            raise ValueError(f"windows: {len(weights)} weights and wrapped rows {list(wrap)} "
                             f"for {len(out)} outputs")  # fmt: skip
        if not set(out) | set(x0_rows) <= set(range(nx)):
            raise ValueError(f"windows: outputs {list(out)} or corrected states "
                             f"{list(x0_rows)} outside the {nx} states")  # fmt: skip
        self.n_th = step.size1_in(2)
        # windows shorter than the longest are padded to it (the window's last input held,
        # after its last compared sample, so nothing compared depends on the padding) and the
        # padded samples dropped from every result: CasADi maps one window length
        self.keep = padded_index(self.lengths, self.W)
        src = np.repeat(np.cumsum(self.lengths) - 1, self.W)  # each window's last sample
        src[self.keep] = np.arange(self.n)
        self.x0, self.A = np.asarray(x0, float), np.asarray(A, float)[:, src]
        self.Y, self._Ypad = Y, np.asarray(Y, float)[:, src]
        self.out, self.wrap = list(out), list(wrap)
        self.w = np.asarray(weights, float)
        self.x0_rows, self.nd = list(x0_rows), len(x0_rows)
        self.n_z = self.n_th + self.nd * self.nwin
        self._step, self._nx, self._m = step, nx, self.n_th + self.nd
        self._sens = None  # built at the first residuals(): a held-out part only simulates
        self._plain = step.mapaccum("window", self.W).map(self.nwin)
        self.E = np.zeros((nx, self.nd))
        self.E[self.x0_rows, np.arange(self.nd)] = 1.0
        no = len(self.out)
        self._rows = (self.keep[:, None] * no + np.arange(no)).ravel()  # residual rows kept

    def _sensitivity_map(self) -> ca.Function:
        """The step with its forward sensitivities, accumulated over a window, mapped."""
        if self._sens is None:
            nx, m, step = self._nx, self._m, self._step
            x, a = ca.SX.sym("x", nx), ca.SX.sym("a", step.size1_in(1))
            th, S = ca.SX.sym("th", self.n_th), ca.SX.sym("S", nx, m)
            xn = step(x, a, th)
            Sn = ca.jacobian(xn, x) @ S + ca.horzcat(ca.jacobian(xn, th),
                                                     ca.SX.zeros(nx, self.nd))  # fmt: skip
            sens = ca.Function("sens_step", [ca.vertcat(x, ca.vec(S)), a, th],
                               [ca.vertcat(xn, ca.vec(Sn))])  # fmt: skip
            self._sens = sens.mapaccum("window", self.W).map(self.nwin)
        return self._sens

    def _start(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        z = np.asarray(z, float).ravel()
        if z.size != self.n_z:
            raise ValueError(f"{z.size} parameters given, {self.n_z} expected")
        d = z[self.n_th :].reshape(self.nwin, self.nd).T  # column j: window j's correction
        return z[: self.n_th], self.x0 + self.E @ d

    def simulate(self, z: np.ndarray) -> np.ndarray:
        """The simulated outputs, shape ``(len(out), n)`` (``n`` the samples of all windows),
        at parameters ``z``."""
        th, X0 = self._start(z)
        X = np.array(self._plain(X0, self.A, np.tile(th[:, None], (1, self.A.shape[1]))))
        return X[self.out][:, self.keep]

    def residuals(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(res, jac, Ysim)``: the weighted errors ``w_i (y_sim - y)`` in column-major order
        (sample by sample, the outputs of a sample together, window after window), shape
        ``(len(out) n,)``; their Jacobian with respect to ``z``, dense ``(len(res), n_z)``;
        the simulated outputs ``(len(out), n)``."""
        th, X0 = self._start(z)
        nx, m, n_th, nd = self._nx, self._m, self.n_th, self.nd
        S0 = np.zeros((nx, m))
        S0[:, n_th:] = self.E
        Z0 = np.vstack([X0, np.tile(S0.reshape(-1, 1, order="F"), (1, self.nwin))])
        TH = np.tile(th[:, None], (1, self.A.shape[1]))
        out = np.array(self._sensitivity_map()(Z0, self.A, TH))
        Ysim = out[self.out]
        err = Ysim - self._Ypad
        for i in self.wrap:  # d wrap(e) / de = 1 (the same as CasADi's atan2(sin, cos))
            err[i] = np.arctan2(np.sin(err[i]), np.cos(err[i]))
        res = (self.w[:, None] * err).ravel(order="F")
        n, no = out.shape[1], len(self.out)
        S = out[nx:].reshape(nx, m, n, order="F")[self.out]  # (no, m, n)
        S = S * self.w[:, None, None]
        jac = np.zeros((no * n, self.n_z))
        rows = S.transpose(2, 0, 1).reshape(no * n, m)  # row (sample, output)
        jac[:, :n_th] = rows[:, :n_th]
        if nd:
            win = np.repeat(np.arange(n) // self.W, no)  # each row's window
            cols = n_th + nd * win[:, None] + np.arange(nd)
            jac[np.arange(no * n)[:, None], cols] = rows[:, n_th:]
        if len(self._rows) == len(res):  # no padding
            return res, jac, Ysim
        return res[self._rows], jac[self._rows], Ysim[:, self.keep]
