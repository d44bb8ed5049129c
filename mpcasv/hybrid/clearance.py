"""Which AUV to avoid and where to go, with several anti-collision domains (issue 14).

Paper 2 eq. 8 as printed selects ``i = argmin_k r_k`` as soon as any ``r_k < r_avoid,k``, and
eq. 12 sends the ASV to the point of AUV i's target circle on the bearing from i to the ASV.
With AUVs at different depths (``r_avoid,k = sqrt(r_avoid^2 - d_k^2)``) the nearest AUV is not
always the one whose domain was entered, and the eq. 12 point of one AUV may lie inside the
domain of another. The thesis's intent (the AUV whose domain is entered has priority, and
collision avoidance comes first) is kept here by two rules, documented in docs/safety.md:

- (S1) selection: among the AUVs whose domain contains the ASV, the deepest breach
  ``i = argmin_k (r_k - r_avoid,k)`` over ``{k : r_k < r_avoid,k}``. ``r_avoid,k`` is the
  domain's radius on the bearing from AUV k to the ASV (the papers' radius for the ``fixed``
  kind).
- (S2) waypoint: the eq. 12 point ``xi_i + r_t,i [cos beta_i, sin beta_i]`` if it lies at least
  ``delta_r`` outside every other AUV's domain (the clearance the target circle keeps from
  AUV i's own domain); otherwise the candidate nearest in bearing on the target circle, then on
  circles ``delta_r`` further out, with that clearance. The outermost circle searched is far
  enough out that every one of its points has the clearance, so a point always exists.

All functions are pure; positions are NED ``[N, E]`` (m), bearings rad from North.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mpcasv.hybrid.avoidance import AvoidanceShape

__all__ = ["clear_waypoint", "deepest_breach", "shape_extent"]

BEARING_STEP_DEG = 5.0  # resolution of the bearing search of (S2)


def deepest_breach(r: ArrayLike, r_avoid: ArrayLike) -> int | None:
    """(S1): index of the AUV whose domain the ASV is deepest inside, or None.

    Parameters
    ----------
    r, r_avoid : array_like, shape (K,)
        Horizontal range to each AUV and its anti-collision radius on that bearing (m).

    Returns
    -------
    int or None
        ``argmin_k (r_k - r_avoid,k)`` over the AUVs with ``r_k < r_avoid,k``; None if the
        ASV is inside no domain.
    """
    margin = np.asarray(r, float) - np.asarray(r_avoid, float)
    if not np.any(margin < 0):
        return None
    return int(np.argmin(margin))


def shape_extent(shape: AvoidanceShape) -> NDArray:
    """Largest distance from each domain's centre to its boundary (m, shape (K,))."""
    rho = np.asarray(shape.rho, float)
    if shape.normals is None:
        return rho
    return rho + np.max(np.asarray(shape.h, float), axis=-1)


def clear_waypoint(shape: AvoidanceShape, i: int, beta: float, delta_r: float) -> NDArray:
    """(S2): the avoidance/transit waypoint for AUV ``i`` that keeps clear of every domain.

    Parameters
    ----------
    shape : AvoidanceShape
        The K AUVs' anti-collision domains (centres (K, 2), m).
    i : int
        The selected AUV.
    beta : float
        Bearing from AUV i to the ASV (rad): eq. 12's ``beta_wp``.
    delta_r : float
        Target-circle margin (m, Paper 2 eq. 6); also the clearance kept from the other
        domains and the step between the circles searched.

    Returns
    -------
    ndarray, shape (2,)
        ``[N, E]`` (m): outside AUV i's domain by ``delta_r`` along its bearing and at least
        ``delta_r`` (signed distance) outside every other AUV's domain.
    """
    center = np.asarray(shape.center, float)
    K = center.shape[0]
    others = np.arange(K) != i
    step = max(float(delta_r), 1.0)
    offsets = np.radians(np.arange(0.0, 180.0 + 1e-9, BEARING_STEP_DEG))
    offsets = np.concatenate([[0.0], np.ravel(np.column_stack([offsets[1:], -offsets[1:]]))])
    bearings = beta + offsets  # nearest to beta first
    if shape.normals is None:  # AUV i's own radius on each bearing
        own = np.full(bearings.shape, float(np.asarray(shape.rho, float)[i]))
    else:
        own = np.asarray(_one(shape, i).radius(bearings), float)
    gap = np.linalg.norm(center - center[i], axis=-1)
    # at R_far from centre i every point is >= delta_r outside every domain (a polygon's
    # signed distance is >= |q - c| cos(pi / M) - its extent)
    slack = 1.0 if shape.normals is None else math.cos(math.pi / shape.normals.shape[-2])
    R_far = float(np.max(gap + (shape_extent(shape) + step) / slack))
    n_rings = max(int(math.ceil((R_far - float(np.min(own)) - step) / step)), 0) + 1
    for j in range(n_rings + 1):
        radius = own + step * (j + 1)  # j = 0: the target circle r_t,i = r_avoid,i + delta_r
        q = center[i] + radius[:, None] * np.stack([np.cos(bearings), np.sin(bearings)], -1)
        if not np.any(others):
            return q[0]
        sd = shape.signed_distance(q[:, None, :])[:, others]  # (B, K-1)
        ok = np.all(sd >= delta_r, axis=1)
        if np.any(ok):
            return q[int(np.argmax(ok))]
    raise AssertionError("unreachable: the outermost circle is clear")  # pragma: no cover


def _one(shape: AvoidanceShape, i: int) -> AvoidanceShape:
    """The domain of AUV ``i`` alone (for its along-bearing radius)."""
    return AvoidanceShape(shape.center[i], np.asarray(shape.rho)[i], shape.normals[i], shape.h[i])
