"""Helpers to build observations around AUVs at given ranges, bearings and depths."""

from __future__ import annotations

import math

from mpcasv.interface import ASVState, AUVEstimate, Observation


def obs_at(t, asv_NE, auvs, propeller_on=False):
    """``auvs`` = [(N, E, depth), ...]."""
    ests = tuple(AUVEstimate(n, e, d, t_last_fix=t) for n, e, d in auvs)
    return Observation(t, ASVState(asv_NE[0], asv_NE[1], 0.0), propeller_on, ests)


def polar(auv, r, beta):
    return (auv[0] + r * math.cos(beta), auv[1] + r * math.sin(beta))
