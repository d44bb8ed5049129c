"""The report's forest plot and floating-point noise: a case whose min range differed by
-3.23e-11 m (of ~140 m) got an x axis in units of 1e-11 m, which looked like a real
difference. Such a difference is drawn at 0; a real small one keeps its place and scale."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from mpcasv.experiments import report_figures as rf
from mpcasv.experiments import stats


def _row(case, ref_median, med, lo, hi, verdict="negligible difference", p=0.002):
    return {"reference": "hybrid", "other": "mpc", "metric": "min_range_m", "better": "higher",
            "case": case, "n": 10, "runs": 10, "n_unpaired": 0, "ref_median": ref_median,
            "median": med, "ci_low": lo, "ci_high": hi, "p": p, "note": "",
            "verdict": verdict}  # fmt: skip


@pytest.fixture
def drawn(monkeypatch):
    """The figures forest_figure draws (kept open instead of saved)."""
    figs = []
    monkeypatch.setattr(rf, "_save", lambda fig, path: figs.append(fig) or path)
    yield figs
    for fig in figs:
        rf.plt.close(fig)


def _panel(table, figs, tmp_path):
    (h,) = [h for h in stats.HEADLINE if h.name == "min_range_m"]
    rf.forest_figure(pd.DataFrame(table), [h], tmp_path / "forest.png")
    fig = figs[-1]
    fig.canvas.draw()
    ax = fig.axes[0]
    xs = [float(x) for line in ax.get_lines() for x in np.atleast_1d(line.get_xdata())]
    return ax, xs


def test_a_difference_zero_to_float_precision_is_drawn_at_zero(drawn, tmp_path):
    ax, xs = _panel([_row("case1", 140.2, -3.23e-11, -3.5e-11, -3.0e-11),
                     _row("case3", 61.5, 0.0, 0.0, 0.0, "no difference", math.nan)],
                    drawn, tmp_path)  # fmt: skip
    lo, hi = ax.get_xlim()
    assert hi - lo > 1e-3, (lo, hi)  # not an axis of 1e-11 m
    assert ax.xaxis.get_offset_text().get_text() == ""  # no "1e-11" multiplier
    dots = [x for x in xs if np.isfinite(x)]
    assert dots and all(x == 0.0 for x in dots), dots  # both cases at 0 (the zero line too)
    labels = [t.get_text() for a in drawn[-1].axes for t in a.get_yticklabels()]
    assert "0 to float precision (-3.23e-11) n=10" in labels, labels


def test_a_real_small_difference_keeps_its_place(drawn, tmp_path):
    """1e-6 m of 140 m (7e-9 relative) is above the noise: drawn where it is, on its scale."""
    ax, xs = _panel([_row("case1", 140.2, 1e-6, 5e-7, 2e-6),
                     _row("case3", 61.5, 0.0, 0.0, 0.0, "no difference", math.nan)],
                    drawn, tmp_path)  # fmt: skip
    assert 1e-6 in xs, xs
    lo, hi = ax.get_xlim()
    assert hi < 1e-5 and lo > -1e-5, (lo, hi)


def test_float_noise_is_relative_to_the_metric_size():
    g = pd.DataFrame([_row("a", 140.2, -3.23e-11, -3.5e-11, -3e-11),   # noise
                      _row("b", 140.2, 1e-6, 5e-7, 2e-6),              # real, small
                      _row("c", 1e-3, -3.23e-11, -3.5e-11, -3e-11),    # 3e-8 of 1 mm: real
                      _row("d", 0.0, 0.0, 0.0, 0.0),                   # exactly zero
                      _row("e", 140.2, -1e-11, math.nan, math.nan)])   # n/a CI, noise median
    assert rf.float_noise(g).tolist() == [True, False, False, False, True]
