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
