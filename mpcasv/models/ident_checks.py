"""What the logs can identify, and whether the identified model passed its validation.

:func:`check_identifiable` refuses, before the fit, coefficients the logs carry no
information about: their columns of the equation-error regression (the Jacobian at the prior)
are zero or collinear, so any value fits as well as any other, the 1-sigma is undefined and
the "identified" value is whatever the optimiser stopped at. The typical cause is an input
that never varies (a steering set-point logged as a constant 0 while the boat turns): the
message names the coefficients and the constant input. :func:`check_covariance` refuses a fit
whose 1-sigma is not finite all the same (a column that is zero at the solution only).

:func:`validation_failures` and :func:`worse_than_prior` are the acceptance of ``mpcasv
identify`` (exit 1 when either fails). A held-out fit below 0 % (``R^2 < 0``) means the
identified model predicts the validation part of the logs worse than their mean value does: a
weak bar, since any model that tracks the heading's trend passes it on psi. The second bar
compares with what the user already has: the identified model's held-out error, weighted as
the fit weighs it (each channel's RMSE over its noise level, squared, averaged over the
channels: the fit's own criterion, 1 at the noise level), must not exceed the prior's on the
same held-out windows by more than :data:`PRIOR_MARGIN` of the prior's or of the noise level,
whichever is larger. The margin is estimation noise: with the prior the truth, one noisy
150-s zig-zag (seeds 0-3) gave 1.000-1.006 times the prior's; noise-free, both were about
3.5e-7 (far below the noise level, where a ratio means nothing: 1.05). Worse than that, the
fit has learned something of the training part that does not carry over (a wrong structure,
a change between the parts, too little excitation): keep the prior.
"""

from __future__ import annotations

import math

import numpy as np

from mpcasv.errors import LogError

#: the identified model's held-out weighted error may exceed the prior's by this fraction of
#: the prior's or of the noise level (1), whichever is larger (module docstring)
PRIOR_MARGIN = 0.02

#: relative column norm (to the largest) under which a coefficient has no effect on the fit
ZERO_COLUMN = 1e-9
#: smallest / largest singular value of the column-normalised regression under which the
#: coefficients are collinear (good logs of the shipped vessels: about 4e-3)
COLLINEAR = 1e-8
#: the set-points, as the message names them, and the coefficients that act only through
#: each (mpcasv.models.vessel.actuator_forces: the steered leg's lift, the differential yaw)
INPUTS = {"T_cmd": "thrust set-point T_cmd", "delta_cmd": "steering set-point delta_cmd"}
THROUGH = {"delta_cmd": ("Y_uudelta", "N_diff", "x_p")}


def source(df, i: int) -> str:
    """The file a table was read from (``identification_table`` keeps it), else ``log i``."""
    return str(df.attrs.get("source", f"log {i + 1}"))


def zero_columns(J: np.ndarray) -> np.ndarray:
    """Which columns of ``J`` have no effect (norm at most ``ZERO_COLUMN`` of the largest; all
    of them when every column is zero or one is not finite), shape ``(J.shape[1],)``."""
    norms = np.linalg.norm(J, axis=0)
    top = norms.max() if norms.size and np.isfinite(norms).all() else 0.0
    return norms <= ZERO_COLUMN * top if top > 0 else np.ones(norms.shape, bool)


def unidentifiable(J: np.ndarray, coeffs) -> tuple[list[str], str]:
    """Coefficients whose columns of ``J`` are zero, else those spanning its (numerical) null
    space; and which of the two (``"zero"``, ``"collinear"``; ``""`` if none)."""
    zero = [c for c, z in zip(coeffs, zero_columns(J), strict=True) if z]
    if zero:
        return zero, "zero"
    norms = np.linalg.norm(J, axis=0)
    _, s, Vt = np.linalg.svd(J / norms, full_matrices=False)
    null = Vt[s <= COLLINEAR * s[0]]
    if not len(null):
        return [], ""
    weight = np.abs(null).max(axis=0)
    return [c for c, w in zip(coeffs, weight, strict=True) if w > 0.1], "collinear"


def constant_inputs(tables, coeffs=None) -> list[str]:
    """"the steering set-point delta_cmd never varies (always 0)" for each input constant over
    every log (only those ``coeffs`` act through, when given: :data:`THROUGH`)."""
    out = []
    for col, label in INPUTS.items():
        if coeffs is not None and not set(coeffs) & set(THROUGH.get(col, ())):
            continue
        values = np.concatenate([np.asarray(t[col], float) for t in tables])
        if values.size and np.ptp(values) == 0:
            out.append(f"the {label} never varies (always {values[0]:g})")
    return out


def check_identifiable(J: np.ndarray, coeffs, tables, names) -> None:
    """Refuse coefficients the regression ``J`` (columns: ``coeffs``) cannot identify.

    Raises
    ------
    LogError
        One line: the coefficients, the logs, the constant input if there is one, and what
        to do (hold them at the prior, or log a manoeuvre that excites them).
    """
    bad, kind = unidentifiable(np.asarray(J, float), coeffs)
    if not bad:
        return
    why = "; ".join(constant_inputs(tables, bad if kind == "zero" else None))
    one = len(bad) == 1
    what = (("it has" if one else "they have") + " no effect on the fit" if kind == "zero" else
            "they are collinear in the fit (one trades off against another)")  # fmt: skip
    it = "it" if one else "them"
    raise LogError(f"{', '.join(bad)} cannot be identified from {', '.join(names)}: "
                   f"{why + ', so ' if why else ''}{what} (rank-deficient regression); hold "
                   f"{it} at the prior (--coeffs without {it}) or log a manoeuvre that excites "
                   f"{it}")  # fmt: skip


def check_covariance(std: dict, names) -> None:
    """Refuse a fit whose 1-sigma of some coefficient is not finite (LogError, one line)."""
    bad = [c for c, s in std.items() if not np.isfinite(s)]
    if bad:
        raise LogError(f"{', '.join(bad)} cannot be identified from {', '.join(names)}: the "
                       "fit's covariance is singular for them (1-sigma not finite); hold them "
                       "at the prior (--coeffs without them)")  # fmt: skip


def validation_failures(metrics: dict) -> dict[str, float]:
    """Output channel -> held-out fit % of the final model, for the fits below 0 % (R^2 < 0)."""
    val = metrics.get("simulation_error", {}).get("validation", {})
    return {c: m["fit_pct"] for c, m in val.items() if m.get("fit_pct", 0.0) < 0}


def weighted_error(fits: dict, weights: dict) -> float:
    """The fit's criterion on replayed data: the mean over channels of ``(w_c RMSE_c)^2``
    (``fits``: channel -> ``{"rmse": ...}``; ``weights``: channel -> ``1 / noise level``)."""
    return float(np.mean([(weights[c] * fits[c]["rmse"]) ** 2 for c in weights]))


def worse_than_prior(validation_error: dict) -> float | None:
    """The identified model's held-out weighted error over the prior's when it exceeds it by
    more than ``PRIOR_MARGIN`` of the prior's or of the noise level (1), whichever is larger
    (``validation_error``: ``{"prior": ..., "identified": ...}``, :func:`weighted_error`),
    else ``None`` (also when not recorded, and when the prior's replay diverged: a non-finite
    error is no yardstick)."""
    e0, e1 = validation_error.get("prior"), validation_error.get("identified")
    if e0 is None or e1 is None or not np.isfinite(e0):
        return None
    if np.isfinite(e1) and e1 <= e0 + PRIOR_MARGIN * max(e0, 1.0):
        return None
    return float(e1 / e0) if e0 > 0 else math.inf
