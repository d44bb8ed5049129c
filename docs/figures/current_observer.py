"""Draw ``docs/figures/current_observer.png``: the on-board current observer
(``mpcasv/estimation/current.py``) driven by the simulated World, transits (propeller on) and
standby (drifting) in turn every 150 s, 0.10 m/s North throughout and a 0.15 m/s step East at
t = 400 s (a current field's knots, added to the constant current), white noise of 0.05 m/s
on the measured velocities (seed 0): the harness of ``tests/test_current_observer.py``
(``drive``). Run from the repository's root::

    MPLBACKEND=Agg python docs/figures/current_observer.py

(900 simulated seconds, a few seconds of wall time.)
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))

from test_current_observer import drive, scenario  # noqa: E402


def main() -> None:
    data = scenario(900.0, current=[0.1, 0.0], current_field={
        "knots": [[400.0, 0.0, 0.0], [401.0, 0.0, 0.15]], "auv_factor": 0.0})  # fmt: skip
    t, est, truth, prop = drive(data, noise=0.05, seed=0)
    fig, axes = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
    for i, (ax, name) in enumerate(zip(axes, ("V_N", "V_E"), strict=True)):
        on = prop.astype(bool)
        ax.fill_between(t, -0.05, 0.25, where=on, color="0.9", step="post", label="propeller on")
        ax.plot(t, truth[:, i], "k", lw=1.6, label="true current")
        ax.plot(t, est[:, i], lw=1.0, label="estimate (velocity noise 0.05 m/s)")
        ax.set_ylim(-0.05, 0.25)
        ax.set_ylabel(f"{name} (m/s)")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("t (s)")
    axes[0].set_title("On-board current observer: transits and standby in turn, "
                      "a 0.15 m/s step East at 400 s")  # fmt: skip
    fig.tight_layout()
    out = ROOT / "docs" / "figures" / "current_observer.png"
    fig.savefig(out, dpi=100)
    err = np.hypot(*(est - truth).T)
    settled = t[np.flatnonzero(err[t < 400.0] >= 0.03).max() + 1]
    print(f"wrote {out}; within 0.03 m/s of the truth from t = {settled:.0f} s until the step")


if __name__ == "__main__":
    main()
