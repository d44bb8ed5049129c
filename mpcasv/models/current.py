"""A water current that varies in time and space (a scenario's optional ``[current_field]``).

The current at time ``t`` and horizontal position ``p = (N, E)`` is

    V(t, p) = V_0 + k(t) + G (clip(p - p_0))

with ``V_0`` the scenario's constant ``current = [V_N, V_E]``, ``k(t)`` the knots
``(t, dV_N, dV_E)`` interpolated linearly in time (held at the first / last knot outside
them; zero without knots), ``G`` the 2 x 2 gradient ``[[dV_N/dN, dV_N/dE], [dV_E/dN, dV_E/dE]]``
(1/s) about ``origin = p_0``, and ``clip`` holding the displacement at ``radius`` m from the
origin (the field is constant along each ray beyond it, so it stays bounded). All m/s.

Carrying the AUVs: with a ``[current_field]`` table the same current (times ``auv_factor``,
default 1) also carries every AUV, evaluated at the AUV's horizontal position: one current for
the whole water column (simple; at depth it would really differ, set ``auv_factor`` < 1 for
a weaker one). Without the table the AUVs are not carried (the model of the existing
scenarios and results). The simulator evaluates the field once per supervisory period, at the
period's middle time and at each vehicle's position at the period's start (the compiled
closed loop takes one constant current per period).
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import model_validator

from mpcasv.config import Coord, Float, Length, Prob, Time, frozen

#: current speeds above this are refused: the ASV (Gretha, ~2 m/s) could not hold station
V_MAX = 2.0


@frozen
class CurrentField:
    """The ``[current_field]`` table: a time profile and a spatial gradient added to the
    scenario's constant current, and how much of it carries the AUVs (see module docstring)."""

    # (t s, dV_N m/s, dV_E m/s): t within the longest run; the speeds bounded with the
    # gradient by Scenario's check (the whole field within 2 m/s)
    knots: tuple[tuple[Time, Float, Float], ...] = ()
    gradient: tuple[tuple[Float, Float], tuple[Float, Float]] | None = None  # G, 1/s
    origin: tuple[Coord, Coord] = (0.0, 0.0)  # p_0 (N, E), m
    radius: Length = 1000.0  # m: the gradient's displacement is held beyond this
    auv_factor: Prob = 1.0  # fraction of the current carrying the AUVs

    @model_validator(mode="after")
    def _check(self) -> CurrentField:
        ts = [k[0] for k in self.knots]
        if any(b <= a for a, b in zip(ts, ts[1:], strict=False)):
            raise ValueError(f"knots: times must increase strictly, got {ts}")
        return self

    def extra_max(self) -> float:
        """An upper bound (m/s) of ``|k(t) + G clip(p - p_0)|`` over all t and p."""
        k = max((math.hypot(dn, de) for _, dn, de in self.knots), default=0.0)
        g = 0.0 if self.gradient is None else float(np.linalg.norm(self.gradient, 2))
        return k + g * self.radius

    def evaluator(self, base) -> CurrentEvaluator:
        """A fast evaluator of the field around the constant current ``base`` (V_N, V_E)."""
        return CurrentEvaluator(self, base)


class CurrentEvaluator:
    """``V(t, P)`` of a :class:`CurrentField` for positions ``P`` of shape (2,) or (2, m)."""

    def __init__(self, spec: CurrentField, base):
        self.base = np.asarray(base, float)
        k = np.array(spec.knots, float).reshape(-1, 3)
        self._t, self._k = k[:, 0], k[:, 1:]
        self._G = None if spec.gradient is None else np.array(spec.gradient, float)
        self._p0 = np.array(spec.origin, float)
        self._R = spec.radius
        self.auv_factor = spec.auv_factor

    def __call__(self, t: float, P: np.ndarray) -> np.ndarray:
        """Current (m/s) at time ``t`` (s) and positions ``P`` (rows N, E; m)."""
        P = np.asarray(P, float)
        V = self.base.copy()
        if len(self._t):
            V = V + np.array([np.interp(t, self._t, self._k[:, 0]),
                              np.interp(t, self._t, self._k[:, 1])])  # fmt: skip
        if P.ndim == 2:
            V = np.repeat(V[:, None], P.shape[1], axis=1)
        if self._G is not None:
            d = P - (self._p0 if P.ndim == 1 else self._p0[:, None])
            r = np.hypot(d[0], d[1])
            d = d * np.minimum(1.0, self._R / np.maximum(r, 1e-12))
            V = V + self._G @ d
        return V


__all__ = ["CurrentField", "CurrentEvaluator", "V_MAX"]
