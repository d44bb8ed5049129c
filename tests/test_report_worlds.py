"""The unit of the report's paired statistics is the world, not the run (a new user's
finding, session 43): six seeds of a scenario without an ``[uncertain]`` table drew one world,
and the report gave their six equal differences a zero-width interval, p = 0.03 and "mpc
better". And the smallest number of pairs with a verdict is the smallest with which the
two-sided Wilcoxon test can reach p < 0.05 (6)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from mpcasv.experiments import stats
from mpcasv.experiments.acceptance import Acceptance, acceptance_table, report_parts
from mpcasv.experiments.report import headline_table
from mpcasv.experiments.stats import paired_stat, paired_table, per_world

BETTER = {"collision_domain_s": "lower"}


def table(realisations: list[str], shift=-1.2, noise=0.0) -> pd.DataFrame:
    """Rows of hybrid and mpc per seed (seed i drew world ``realisations[i]``): the mpc's
    collision-domain time is the hybrid's plus ``shift`` (plus ``noise`` x seed)."""
    rows = []
    for seed, real in enumerate(realisations):
        level = 20.0 + 5.0 * int(real[1:]) if real else 20.0 + seed
        for v, value in (("hybrid", level), ("mpc", level + shift + noise * seed)):
            rows.append({"index": len(rows), "scenario": "loiter", "variant": v,
                         "current": "scenario", "estimator": "perfect", "seed": seed,
                         "realisation": real, "status": "ok", "collision_domain_s": value})
    return pd.DataFrame(rows)


def test_six_seeds_of_one_world_are_one_pair_with_no_verdict():
    t = paired_table(table(["w0"] * 6), ["collision_domain_s"], BETTER).iloc[0]
    assert (t["n"], t["runs"]) == (1, 6)
    assert t["median"] == pytest.approx(-1.2)
    assert np.isnan(t["p"]) and t["verdict"] == "n/a"  # before: p = 0.031, "mpc better"
    assert headline_table(paired_table(table(["w0"] * 6), ["collision_domain_s"], BETTER)
                          )["pairs"].iloc[0] == "1 world (6 runs)"  # fmt: skip


def test_seeds_of_distinct_worlds_stay_pairs_and_shared_ones_are_averaged():
    t = paired_table(table([f"w{i}" for i in range(6)]), ["collision_domain_s"], BETTER)
    assert (t["n"].iloc[0], t["runs"].iloc[0], t["verdict"].iloc[0]) == (6, 6, "mpc better")
    # 12 seeds over 6 worlds, two each: 6 pairs, each the mean of its two runs
    df = table([f"w{i // 2}" for i in range(12)], noise=0.1)
    p, _ = stats.pairs(df, "collision_domain_s", "hybrid", "mpc")
    w = per_world(p)
    assert len(w) == 6 and w["runs"].tolist() == [2] * 6
    d = (w["other"] - w["ref"]).to_numpy()
    assert d == pytest.approx([-1.2 + 0.1 * (2 * i + 0.5) for i in range(6)])
    t = paired_table(df, ["collision_domain_s"], BETTER).iloc[0]
    assert (t["n"], t["runs"]) == (6, 12) and t["median"] == pytest.approx(np.median(d))


def test_rows_without_a_realisation_are_each_their_own_world():
    p, _ = stats.pairs(table([""] * 6), "collision_domain_s", "hybrid", "mpc")
    assert len(per_world(p)) == 6
    p, _ = stats.pairs(table(["w0"] * 6).drop(columns="realisation"), "collision_domain_s",
                       "hybrid", "mpc")  # fmt: skip
    assert len(per_world(p)) == 6 and per_world(p)["runs"].tolist() == [1] * 6


def test_five_pairs_get_no_verdict_six_can():
    # the smallest two-sided exact Wilcoxon p with n non-zero differences is 2 / 2^n
    assert stats.MIN_PAIRS == 6 and 2 / 2**5 > stats.ALPHA > 2 / 2**6
    five, six = paired_stat(np.zeros(5), -np.arange(1.0, 6)), paired_stat(np.zeros(6),
                                                                           -np.arange(1.0, 7))
    assert five.note == "n/a: 5 pairs < 6" and np.isnan(five.p)
    assert six.note == "" and six.p == pytest.approx(2 / 2**6)


def test_the_acceptance_counts_worlds_and_says_when_nothing_was_judged():
    acc = Acceptance({"collision_domain_s": 0.0})
    t = acceptance_table(table(["w0"] * 6), acc, "hybrid", "mpc", [])
    assert (t["pairs"].iloc[0], t["runs"].iloc[0]) == (1, 6)
    assert t["verdict"].iloc[0].startswith("n/a")
    (_, _, [(_, d, says)]) = report_parts(table(["w0"] * 6), acc, ["hybrid", "mpc"], [])
    assert says == "**The target is not judged** (its verdict says why)."
    assert d["pairs"].tolist() == ["1 world (6 runs)"]
    (_, _, [(_, _, says)]) = report_parts(table([f"w{i}" for i in range(6)]), acc,
                                          ["hybrid", "mpc"], [])  # fmt: skip
    assert says == "**The target is met.**"


def test_conditions_on_one_world_are_one_world_and_the_order_is_kept():
    # a review (session 43): the estimators of one realisation counted as separate worlds,
    # and rows without a realisation id were put after the merged ones
    df = table(["w0", "", "w1", "w0", ""])
    df.loc[df["seed"] == 3, "estimator"] = "kalman"  # w0 again, under another estimator
    p, _ = stats.pairs(df, "collision_domain_s", "hybrid", "mpc")
    w = per_world(p)
    # each world where its first pair was in the pairs' order
    first = {}
    for i, (real, seed) in enumerate(zip(p["realisation"], p["seed"], strict=True)):
        first.setdefault(real or f"row {i}", (i, seed))
    expected = sorted(first.values())
    assert w["seed"].tolist() == [s for _, s in expected]
    assert sorted(w["runs"].tolist()) == [1, 1, 1, 2] and len(w) == 4
    assert w.loc[w["realisation"] == "w0", "runs"].tolist() == [2]
