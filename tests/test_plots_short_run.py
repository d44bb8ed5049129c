"""The figures ``mpcasv simulate`` writes show their data however short the run (the tester's
defect: a valid one-second run wrote range.png and fix_age.png with nothing visible, one sample
drawn as a line without markers on a 0.96-1.04 s axis)."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.collections import LineCollection, PolyCollection

from mpcasv.controllers import make_controller
from mpcasv.sim import plots
from mpcasv.sim.scenario import scenario_from_dict
from mpcasv.sim.simulator import simulate


def run(duration: float):
    sc = scenario_from_dict({
        "name": "short", "duration": duration, "controller": "hybrid-single",
        "preset": "paper1-sim",
        "auv": [{"name": "a0", "start": {"N": 200.0, "E": 0.0, "depth": 10.0},
                 "behaviour": {"loiter": {}}}],
    })  # fmt: skip
    return simulate(sc, make_controller("hybrid-single", 1, "paper1-sim"), seed=0)


def figures(result, tmp_path, monkeypatch) -> dict:
    """Every figure :func:`plots.plot_run` draws, by file name, not closed."""
    drawn = {}

    def keep(fig, path, tight=True):
        drawn[path.name] = fig
        return path

    monkeypatch.setattr(plots, "_save", keep)
    plots.plot_run(result, tmp_path)
    return drawn


def has_marker(line) -> bool:
    return line.get_marker() not in (None, "", " ", "None", "none") and line.get_markersize() > 0


def visible(line) -> bool:
    """Markers, or a line through at least two distinct points."""
    x, y = np.asarray(line.get_xdata(), float), np.asarray(line.get_ydata(), float)
    segment = len(x) >= 2 and line.get_linestyle() not in ("None", "", " ") and (
        np.ptp(x) > 0 or np.ptp(y) > 0)  # fmt: skip
    return has_marker(line) or bool(segment)


@pytest.fixture(scope="module")
def one_second():
    res = run(1.0)
    assert len(res.timeseries) == 1  # one control step: one sample
    return res


def test_a_one_sample_run_draws_every_series_visibly(one_second, tmp_path, monkeypatch):
    drawn = figures(one_second, tmp_path, monkeypatch)
    assert set(drawn) == {"paths.png", "range.png", "fix_age.png"}
    try:
        for name, fig in drawn.items():
            for ax in fig.axes:
                for line in ax.lines:
                    if len(line.get_xdata()):
                        assert visible(line), (name, line.get_label())
                for coll in ax.collections:  # bands: a fill must have width, a bar length
                    if isinstance(coll, PolyCollection):
                        for p in coll.get_paths():
                            assert np.ptp(p.vertices[:, 0]) > 0, (name, coll.get_label())
                    elif isinstance(coll, LineCollection):
                        for seg in coll.get_segments():
                            assert np.ptp(seg[:, 1]) > 0, (name, coll.get_label())
            if name != "paths.png":  # time axes: from the run's start to past the sample
                for ax in fig.axes:
                    lo, hi = ax.get_xlim()
                    assert lo <= 0.0 and hi > 1.0, (name, lo, hi)
        lo, hi = drawn["fix_age.png"].axes[0].get_ylim()
        assert lo <= 0.0 < 1.0 < hi  # the age of 1 s, above an axis from 0
    finally:
        for fig in drawn.values():
            plt.close(fig)


def test_a_longer_run_keeps_plain_lines(tmp_path, monkeypatch):
    drawn = figures(run(5.0), tmp_path, monkeypatch)
    try:
        lines = [ln for ax in drawn["range.png"].axes for ln in ax.lines]
        lines += [ln for ax in drawn["fix_age.png"].axes for ln in ax.lines
                  if ln.get_linestyle() not in ("None", "", " ")]  # not the fix ticks
        assert lines and not any(has_marker(ln) for ln in lines)
        assert all(isinstance(c, PolyCollection) for ax in drawn["range.png"].axes
                   for c in ax.collections)  # fmt: skip
    finally:
        for fig in drawn.values():
            plt.close(fig)
