"""The geometric account of every control period, from ground truth, the same for every
controller (issue 12; definitions and sources in docs/metrics.md).

At each plant step and for each AUV ``k`` the true horizontal range ``r_k`` and the AUV's true
depth ``d_k`` give, with the SCENARIO's evaluation domain (:func:`evaluation_domain`):

- inside the collision domain: ``r_k < r_inner(d_k)`` (Paper 1 eq. 5; with several AUVs the
  same radius is Paper 2's ``r_avoid,k``, eq. 5);
- in the target domain: ``r_k in [r_t,k - eps_minus, r_t,k + eps_plus]`` (Paper 1 eq. 10,
  Paper 2 eq. 7; :func:`mpcasv.hybrid.domains.in_target_domain`);
- beyond the outer boundary: ``r_k > r_outer(d_k)`` (Paper 1 eq. 5);
- a reliable fix possible: ``r_k < r_t,k + eps_plus`` with the propeller off (Paper 2 eq. 9,
  :func:`mpcasv.hybrid.domains.reliable_fix_possible`: the rule of the reliable-fix ages);

and the propeller is on when the actual thrust exceeds the execution level's threshold
(``n_p != 0``). A controller's own domain and its reason labels play no part.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mpcasv.config import load_toml, parse, resolve
from mpcasv.hybrid.domains import (
    DomainParams,
    in_target_domain,
    r_inner,
    r_outer,
    reliable_fix_possible,
)

__all__ = ["StepAccount", "classify", "evaluation_domain", "stay_lengths", "unknown_seconds"]


def evaluation_domain(scenario) -> DomainParams | None:
    """The domain a scenario is judged by: the ``[domain]`` table of the scenario's own preset
    (the case's published domain, as ``domain_from = "scenario"`` in suites), whichever
    controller runs. ``None`` if the preset has no ``[domain]`` (e.g. the ``goto`` demo): the
    domain-based metrics are then null.

    Raises
    ------
    ConfigError
        The preset file is missing or its ``[domain]`` table is invalid.
    """
    if scenario.preset == "default":
        return None
    path = resolve("presets", scenario.preset)
    table = load_toml(path).get("domain")
    if table is None:
        return None
    return parse(DomainParams, table, f"{path} [domain]")


@dataclass(frozen=True)
class StepAccount:
    """One period's account at plant-step resolution (``n`` plant steps, ``m`` AUVs).

    ``stay`` is the length (s) of the ongoing continuous stay inside any collision domain at
    each plant step (0 outside), carried across periods.
    """

    dt: float  # plant step, s
    prop: np.ndarray  # (n,) propeller on
    coll: np.ndarray  # (m, n) inside AUV k's collision domain
    target: np.ndarray  # (m, n) in AUV k's target domain
    beyond: np.ndarray  # (m, n) beyond AUV k's r_outer
    stay: np.ndarray  # (n,) s
    possible: np.ndarray  # (m, n) a reliable fix of AUV k possible (Paper 2 eq. 9)

    @property
    def any_coll(self) -> np.ndarray:
        return self.coll.any(axis=0)

    @property
    def all_beyond(self) -> np.ndarray:
        return self.beyond.all(axis=0)

    def step_seconds(self, j: slice = slice(None)) -> dict[str, float]:
        """Seconds of each class over the plant steps ``j`` (all by default): the time-series
        columns ``prop_on_s``, ``coll_s``, ``coll_stay_s`` (longest stay reached),
        ``beyond_s``, ``escape_s`` (propeller on inside a collision domain), ``track_s``
        (propeller on beyond every r_outer), and per AUV ``coll{k}_s``, ``target{k}_s``,
        ``possible{k}_s`` (a reliable fix possible)."""
        dt, cnt = self.dt, np.count_nonzero
        prop, coll, beyond = self.prop[j], self.any_coll[j], self.all_beyond[j]
        out = {
            "prop_on_s": cnt(prop) * dt, "coll_s": cnt(coll) * dt,
            "coll_stay_s": float(self.stay[j].max()), "beyond_s": cnt(beyond) * dt,
            "escape_s": cnt(prop & coll) * dt, "track_s": cnt(prop & beyond) * dt,
        }  # fmt: skip
        per_coll, per_target = cnt(self.coll[:, j], axis=1), cnt(self.target[:, j], axis=1)
        per_possible = cnt(self.possible[:, j], axis=1)
        for k in range(self.coll.shape[0]):
            out[f"coll{k}_s"] = float(per_coll[k] * dt)
            out[f"target{k}_s"] = float(per_target[k] * dt)
            out[f"possible{k}_s"] = float(per_possible[k] * dt)
        return out


def stay_lengths(inside: np.ndarray, carry: float, dt: float) -> np.ndarray:
    """Length (s) of the ongoing continuous stay at each step of ``inside`` (bool, (n,)),
    starting from a stay of ``carry`` s before the first step; 0 where outside."""
    out = np.zeros(inside.shape[0])
    run = carry
    for j, x in enumerate(inside):
        run = run + dt if x else 0.0
        out[j] = run
    return out


def classify(domain: DomainParams, ranges: np.ndarray, depths: np.ndarray, prop: np.ndarray,
             dt: float, carry: float) -> StepAccount:  # fmt: skip
    """The account of one period.

    Parameters
    ----------
    domain : DomainParams
        The scenario's evaluation domain.
    ranges, depths : ndarray, shape (m, n)
        True horizontal ranges (m) and AUV depths (m) at each plant step.
    prop : ndarray of bool, shape (n,)
        Propeller on at each plant step.
    dt : float
        Plant step (s).
    carry : float
        Continuous stay inside a collision domain (s) at the end of the previous period.
    """
    inner = r_inner(depths, domain.r_in)  # = r_avoid,k with several AUVs (Paper 2 eq. 5)
    coll = ranges < inner
    r_t = inner + domain.delta_r  # Paper 1 eq. 8; Paper 2 eq. 6
    target = in_target_domain(ranges, r_t, domain.eps_minus, domain.eps_plus)
    beyond = ranges > r_outer(depths, domain.r_out)
    prop = np.asarray(prop, bool)
    possible = reliable_fix_possible(ranges, r_t, domain.eps_plus, prop[None, :])  # eq. 9
    inside = coll.any(axis=0)
    if inside.any() or carry > 0:
        stay = stay_lengths(inside, carry, dt)
    else:
        stay = np.zeros(inside.shape[0])
    return StepAccount(dt, prop, coll, target, beyond, stay, possible)


def unknown_seconds(n_auv: int) -> dict[str, float]:
    """The domain-based columns of :meth:`StepAccount.step_seconds` when the scenario has no
    evaluation domain: NaN (unknown). ``prop_on_s`` needs no domain (set by the caller)."""
    out = dict.fromkeys(("coll_s", "coll_stay_s", "beyond_s", "escape_s", "track_s"), np.nan)
    for k in range(n_auv):
        out[f"coll{k}_s"] = out[f"target{k}_s"] = out[f"possible{k}_s"] = np.nan
    return out
