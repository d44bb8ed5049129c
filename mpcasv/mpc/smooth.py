"""Smooth stand-ins the MPC's problem uses for its kinks (CasADi and numpy), and their
smoothing lengths (docs/mpc.md, M3, M7)."""

from __future__ import annotations

import casadi as ca
import numpy as np

SOFTPLUS_M = 5.0  # smoothing length of the time-to-go softplus (m)
SOFT_T = 5.0  # smoothing of (T_tail - t_go)+ (s)
D_EPS = 0.1  # smoothing of the range sqrt (m)
#: the thrust sigmoids' width (M3, M4b, M4c) is at most the lower of the propeller-on and quiet
#: thresholds over this:
#: a stopped propeller then counts as >= 95 % quiet (sig(3)) on any boat
W_T_OF_T_ON = 3.0


def sigmoid(x):
    """Logistic function (numerically safe for CasADi and numpy)."""
    return 0.5 + 0.5 * np.tanh(0.5 * x) if not isinstance(x, (ca.SX, ca.MX)) else (
        0.5 + 0.5 * ca.tanh(0.5 * x))  # fmt: skip


def softplus(x):
    """``log(1 + exp(x))`` without overflow (CasADi expression)."""
    return ca.fmax(x, 0) + ca.log1p(ca.exp(-ca.fabs(x)))
