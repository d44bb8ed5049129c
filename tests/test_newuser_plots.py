"""Figures a new user opens (session 5, newuser5): every title is inside the figure."""

from __future__ import annotations

from types import SimpleNamespace

import matplotlib.pyplot as plt
import pandas as pd

from mpcasv.experiments.tune_outputs import front_figure


def test_tune_front_title_fits_a_one_panel_figure():
    # `mpcasv tune controller` with two objectives draws one 5.2-inch panel; its one-line
    # title "hybrid-single: 2 complete trials; training means vs held-out means of the
    # training front" was cut at both edges of front.png
    a, b = "reliable_fix_age_p95_s", "energy_J"
    spec = SimpleNamespace(controller="hybrid-single", objectives=[a, b],
                           constraint="collision_domain_s")  # fmt: skip
    trials = pd.DataFrame({"state": ["COMPLETE"] * 2, a: [57.0, 57.0], b: [0.0, 10.0],
                           "collision_domain_s": [0.0, 0.0]})  # fmt: skip
    front = pd.DataFrame({"trial": [0, 1], f"train.{a}": [57.0, 57.0], f"train.{b}": [0.0, 10.0],
                          f"heldout.{a}": [57.0, 57.0], f"heldout.{b}": [6156.0, 4131.0]})
    fig = front_figure(spec, trials, front)
    try:
        fig.canvas.draw()
        box = fig._suptitle.get_window_extent(fig.canvas.get_renderer())
        assert box.x0 >= 0 and box.x1 <= fig.bbox.width and box.y1 <= fig.bbox.height, box
    finally:
        plt.close(fig)


def _tuning_folder(d, controller: str, objectives: list[str], front: pd.DataFrame):
    """A minimal output folder of ``mpcasv tune controller``: tune.json, front.csv and one
    held-out part (what ``tune compare --plot`` reads)."""
    import json

    (d / "heldout" / "parts").mkdir(parents=True)
    (d / "tune.json").write_text(json.dumps({"controller": controller,
                                             "objectives": objectives}))  # fmt: skip
    front.to_csv(d / "front.csv", index=False)
    pd.DataFrame({"job_id": ["j0"], "status": ["ok"]}).to_parquet(
        d / "heldout" / "parts" / "j0.parquet")
    return d


def _saved_figures(monkeypatch) -> list:
    """The figures saved while the test runs (kept open: ``plt.close`` is a no-op)."""
    from matplotlib.figure import Figure

    saved = []
    real = Figure.savefig

    def keep(fig, *args, **kwargs):
        saved.append(fig)
        return real(fig, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", keep)
    monkeypatch.setattr(plt, "close", lambda *a, **k: None)
    return saved


def _legend_off_the_data(fig) -> None:
    """Every legend of ``fig`` lies outside every panel (it covered a data point)."""
    renderer = fig.canvas.get_renderer()
    legends = [*fig.legends, *(ax.get_legend() for ax in fig.axes if ax.get_legend())]
    assert legends
    for leg in legends:
        lb = leg.get_window_extent(renderer)
        for ax in fig.axes:
            if ax.get_visible():
                assert not lb.overlaps(ax.get_window_extent(renderer)), (lb, ax.get_xlabel())


def _title_inside(fig) -> None:
    box = fig._suptitle.get_window_extent(fig.canvas.get_renderer())
    assert box.x0 >= 0 and box.x1 <= fig.bbox.width and box.y1 <= fig.bbox.height, box


def test_tune_compare_fronts_png_says_per_axis_which_way_is_better(tmp_path, monkeypatch):
    """``mpcasv tune compare A B --at energy_J --plot fronts.png`` with the objectives
    energy_J and reliable_fixes (one 572 px panel): the title said "lower is better" for both
    (reliable_fixes is higher-is-better) and was cut at both ends ("d fronts re-run on the
    held-out realisations (means over the runs; lower is be"); the legend, inside the panel,
    covered a data point."""
    from mpcasv.experiments.tune_compare import plot_fronts

    a, b = "energy_J", "reliable_fixes"
    dirs = []
    for name, energy, fixes in (("A", [15838.1, 9000.0], [0.0, 4.0]),
                                ("B", [10470.0, 16000.0], [0.0, 1.0])):  # fmt: skip
        d = tmp_path / name
        d.mkdir()
        front = pd.DataFrame({"trial": [0, 1], f"heldout.{a}": energy, f"heldout.{b}": fixes,
                              "heldout_front": [True, name == "A"]})  # fmt: skip
        dirs.append(_tuning_folder(d, "hybrid-single", [a, b], front))
    saved = _saved_figures(monkeypatch)
    plot_fronts(dirs, tmp_path / "fronts.png")
    (fig,) = saved
    fig.canvas.draw()
    (ax,) = [ax for ax in fig.axes if ax.get_visible()]
    assert "lower is better" in ax.get_xlabel(), ax.get_xlabel()
    assert "higher is better" in ax.get_ylabel(), ax.get_ylabel()
    assert "lower is better" not in fig._suptitle.get_text()
    _title_inside(fig)
    _legend_off_the_data(fig)


def test_tune_controller_front_png_legend_off_the_data():
    """front.png of ``mpcasv tune controller``: the legend sat in the first panel, on the
    points ("best" place of matplotlib can still cover one)."""
    a, b = "energy_J", "reliable_fixes"
    spec = SimpleNamespace(controller="hybrid-single", objectives=[a, b],
                           constraint="collision_domain_s")  # fmt: skip
    trials = pd.DataFrame({"state": ["COMPLETE"] * 4, a: [10034.0, 13000.0, 20700.0, 19000.0],
                           b: [0.0, 0.0, 0.0, 3.0], "collision_domain_s": [0.0] * 4})
    front = pd.DataFrame({"trial": [0, 3], f"train.{a}": [10034.0, 19000.0],
                          f"train.{b}": [0.0, 3.0], f"heldout.{a}": [15838.0, 18000.0],
                          f"heldout.{b}": [0.0, 2.0]})  # fmt: skip
    fig = front_figure(spec, trials, front)
    try:
        fig.canvas.draw()
        _title_inside(fig)
        _legend_off_the_data(fig)
    finally:
        plt.close(fig)
