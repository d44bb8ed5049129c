"""The horizontal rotation between the NED frame and the body frame (Fossen 2011, eq. 2.6).

``R(psi) = [[cos psi, -sin psi], [sin psi, cos psi]]`` takes a body-frame horizontal vector
(surge, sway) to NED (north, east); its transpose the other way. These are its numeric
form, for the simulator, the estimators, the MPC's world view and the IMC edge.

Scalars (as a Python ``float``) go through :mod:`math` and arrays through NumPy, so a caller
gets the same bits it got with its own ``math.cos`` / ``np.cos`` before. The symbolic form is
written in :func:`mpcasv.models.vessel.xdot_expr` and in the MPC's guard
(:func:`mpcasv.mpc.dynamics.water_guard`).
"""

from __future__ import annotations

import math

import numpy as np


def _cos_sin(psi):
    if np.ndim(psi) == 0:  # any scalar (float, int, NumPy scalar, 0-d array): as a float
        psi = float(psi)
        return math.cos(psi), math.sin(psi)
    return np.cos(psi), np.sin(psi)


def ned_to_body(psi, a_N, a_E):
    """``R(psi)^T [a_N, a_E]``: a horizontal NED vector (e.g. the current ``[V_N, V_E]`` or a
    ground velocity, m/s) in body axes, ``(a_u, a_v)`` (surge, sway). ``psi`` (rad) and the
    components are scalars or arrays of one shape (eq. 2.6: ``nu_c = R^T(psi) v_c``)."""
    c, s = _cos_sin(psi)
    return c * a_N + s * a_E, -s * a_N + c * a_E


def body_to_ned(psi, a_u, a_v):
    """``R(psi) [a_u, a_v]``: a body-frame horizontal vector (surge, sway; e.g. ``u, v`` in
    m/s) in NED axes, ``(a_N, a_E)``. Scalars or arrays of one shape (eq. 2.6)."""
    c, s = _cos_sin(psi)
    return c * a_u - s * a_v, s * a_u + c * a_v
