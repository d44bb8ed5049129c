"""Coefficients that end at a bound of the fit, and what the fit can tell about them (both
identifications: :func:`mpcasv.models.identify.identify` bounds each coefficient to 0.2-5
times its prior, :func:`mpcasv.models.ident_thrust.identify_through_map` to its sign).

A coefficient at its bound has no 1-sigma in the usual sense (the fit did not stop where the
data's cost is flat in it), and its relative 1-sigma divides by a value the bound set (at a
sign bound 0 it is infinite). Until session 26 the reports took a 1-sigma above 1000 % as "at
bound" and any 1-sigma above 25 % as "poorly determined: hold it at the prior": on DUNE's Otter
log ``N_rr`` ends at its sign bound 0 and the advice was to hold it at the prior, -464, the
value the data reject most.

What the fit tells, from the Jacobian and residuals at the solution: release the bound and take
one Gauss-Newton step (all parameters, the initial-state corrections too): where the
coefficient would go (``free``), with its HAC 1-sigma there (:mod:`mpcasv.models.ident_cov`,
on the residuals after the step: those at the bound hold the misfit it forces) and its
strongest correlation with another coefficient (the plain ``(J^T J)^-1``'s). ``z`` is how far
past the bound ``free`` lies, in that 1-sigma:

- ``z >= Z_PAST``: the data push it past the bound. A sign bound is physics (Fossen's
  convention), so the model's structure is wrong for this boat: the term is not in its
  dynamics, or another term it stands in for is missing (VSIM's yaw damping is linear: no
  ``N_rr``). A factor bound (0.2-5 x prior) means the prior is off by more than that, or the
  structure is wrong. The value at the bound is the closest the model gets; the prior is not.
- otherwise: the fit cannot tell where it is (its 1-sigma spans the bound): not identifiable
  from these data, typically because it trades off against the coefficient it is most
  correlated with; hold it at the prior or log a manoeuvre that excites it.
"""

from __future__ import annotations

import numpy as np

from mpcasv.models.ident_cov import window_covariance

#: past the bound by this many (HAC) sigma: the data push it there (about 2.3 % one-sided)
Z_PAST = 2.0
#: a correlation above this (absolute) is named as a trade-off
CORR_NAMED = 0.9


def active(x, lo, hi, mask=None, tol: float = 1e-6) -> np.ndarray:
    """Which of ``x`` sit at a (finite) bound: ``least_squares``' ``active_mask`` (``mask``)
    or within ``tol`` (scaled to the bound) of it; -1 lower, +1 upper, 0 free."""
    x, lo, hi = (np.asarray(a, float) for a in (x, lo, hi))
    at_lo = np.isfinite(lo) & (x - lo <= tol * np.maximum(1.0, np.abs(lo)))
    at_hi = np.isfinite(hi) & (hi - x <= tol * np.maximum(1.0, np.abs(hi)))
    side = np.where(at_hi, 1, np.where(at_lo, -1, 0))
    if mask is not None:
        side = np.where(side == 0, np.asarray(mask, int)[: len(side)], side)
    return side


def at_bounds(names, x, lo, hi, J, res, W: int, nwin: int, lengths, si, x0, mask=None,
              kind: str = "factor") -> dict[str, dict]:  # fmt: skip
    """Per coefficient at a bound (``names``: the first ``len(names)`` parameters): a dict
    with ``bound``, ``free`` and ``prior`` (SI, ``si(j, value)`` converts parameter ``j``;
    ``x0`` the start, the prior), ``sigma``
    (SI), ``z`` (past the bound, in sigma), ``side``, ``partner`` and ``corr`` (its strongest
    correlation), ``kind`` ("sign" or "factor": what the bound is) and ``verdict`` ("past":
    the data push it past; "undetermined"). Empty when none is at a bound."""
    n = len(names)
    side = active(np.asarray(x)[:n], np.asarray(lo)[:n], np.asarray(hi)[:n],
                  None if mask is None else np.asarray(mask)[:n])  # fmt: skip
    if not side.any():
        return {}
    J, e = np.asarray(J, float), np.asarray(res, float).ravel()
    step = -np.linalg.lstsq(J, e, rcond=None)[0]  # Gauss-Newton, the bounds released
    # the 1-sigma of the released estimate: from its residuals (linearised), not from those
    # at the bound, which hold the misfit the bound forces (and inflate a HAC sigma with it)
    cov = window_covariance(J, e + J @ step, W, nwin, cols=np.arange(n), lengths=lengths)
    H = np.linalg.pinv(J.T @ J)[:n, :n]
    d = np.sqrt(np.clip(np.diag(H), 1e-300, None))
    corr = H / d[:, None] / d[None, :]
    out = {}
    for j in np.flatnonzero(side):
        bound = float(hi[j] if side[j] > 0 else lo[j])
        free = float(x[j] + step[j])
        sigma = float(np.sqrt(max(cov.hac[j], 0.0)))
        z = side[j] * (free - bound) / sigma if sigma > 0 else 0.0
        c = np.abs(corr[j]).copy()
        c[j] = -1.0
        k = int(np.argmax(c)) if n > 1 else j
        out[names[j]] = {
            "bound": si(j, bound), "free": si(j, free), "prior": si(j, float(x0[j])),
            "sigma": abs(si(j, sigma) - si(j, 0.0)),
            "z": float(z), "side": "upper" if side[j] > 0 else "lower",
            "partner": names[k] if k != j else None, "corr": float(corr[j, k]) if k != j else 0.0,
            "kind": kind, "verdict": "past" if z >= Z_PAST else "undetermined",
        }  # fmt: skip
    return out


def bound_notes(at_bound: dict[str, dict], source: str = "these logs") -> list[str]:
    """The report's paragraph per coefficient at its bound (module docstring), each preceded
    by a blank line; ``source`` names the data ("this log", "these logs")."""
    one = source.startswith("this")
    push, it = ("pushes", "it") if one else ("push", "them")
    lines = []
    for c, b in at_bound.items():
        what = "its sign bound" if b["kind"] == "sign" else "its bound (0.2-5 x the prior):"
        head = (f"{c} ends at {what} {b['bound']:.4g}. With the bound released the fit would "
                f"put it at {b['free']:.4g} (1-sigma {b['sigma']:.2g}, {b['z']:+.1f} sigma "
                "past the bound")
        trade = (f"; correlation {b['corr']:+.2f} with {b['partner']}"
                 if b["partner"] and abs(b["corr"]) >= CORR_NAMED else "")  # fmt: skip
        if b["verdict"] == "past" and b["kind"] == "sign":
            text = (f"{head}{trade}): {source} {push} it past the bound. A sign is physics, "
                    "so the model's structure is wrong for this boat: the term is not in its "
                    "dynamics, or another term it stands in for is missing. Written at the "
                    f"bound {b['bound']:.4g}"
                    + (", the term is dropped" if b["bound"] == 0 else "")
                    + f", the closest the model gets to {source}; holding it at the prior "
                    f"({b['prior']:.4g}) would contradict {it}.")  # fmt: skip
        elif b["verdict"] == "past":
            text = (f"{head}{trade}): {source} {push} it past the bound: the prior "
                    f"({b['prior']:.4g}) is off by more than that factor, or the model's "
                    "structure is wrong for this boat. Written at the bound, the closest the "
                    f"model gets within it; holding it at the prior would contradict {it}: "
                    "revise the prior or the structure.")  # fmt: skip
        else:
            text = (f"{head}{trade}): its 1-sigma spans the bound, so {source} cannot tell "
                    f"where it lies (not identifiable from {it}"
                    + (f": it trades off against {b['partner']}" if trade else "")
                    + "); hold it at the prior (--coeffs without it) or log a manoeuvre that "
                    "excites it.")  # fmt: skip
        lines += ["", text]
    return lines
