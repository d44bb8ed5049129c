"""Draw ``docs/figures/case4-escape.png``: Case 4's head-on encounter with three execution files.

Case 4 nominal (hybrid-single, paper1-field), seed 0, run with ``mpcasv simulate
CASE --nominal --no-plots`` on a scenario copy whose ``[asv] execution`` names a variant of
``mpcasv/data/execution/gretha.toml`` (docs/tuning.md, "Why Case 4 and Case 8 still collide"):

* ``eq31``: ``turn_thrust = 0`` (eq. 3.1 true in every turn);
* ``all``: the power turn in every transit (``turn_scope = "all"``, shipped before session 4);
* ``shipped``: the file as shipped (``turn_scope = "avoidance"``: the power turn only while
  the ASV is inside a collision domain, decided by the world from the true ranges,
  ``World.advance`` in ``mpcasv/sim/world.py``).

Each run's window is aligned on its closest approach. Run from the repository's root::

    PYTHONPATH=. MPLBACKEND=Agg python docs/figures/case4_escape.py --runs runs/case4-escape

(three runs of 1242 s, a few seconds each; the runs are kept in ``--runs``).
"""

from __future__ import annotations

import argparse
import tomllib
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import tomli_w

from mpcasv.cli import main as mpcasv

ROOT = Path(__file__).resolve().parents[2]
CASE = ROOT / "experiments" / "scenarios" / "case4.toml"
EXECUTION = ROOT / "mpcasv" / "data" / "execution" / "gretha.toml"
#: name -> (changes to the execution file, legend, colour)
VARIANTS = {
    "eq31": ({"turn_thrust": 0.0}, "eq. 3.1 true (turn_thrust = 0)", "tab:red"),
    "all": ({"turn_scope": "all"}, 'power turn in every transit (turn_scope = "all")',
            "tab:blue"),
    "shipped": ({}, 'shipped: power turn inside the collision domain (turn_scope = "avoidance")',
                "tab:green"),
}  # fmt: skip
WINDOW = (-35.0, 20.0)  # s around the closest approach
STRIP = {"eq31": -4.0, "all": -7.0, "shipped": -10.0}  # m: where each run's strip is drawn


def run_variant(name: str, changes: dict, runs: Path) -> pd.DataFrame:
    """The variant's time series (run once; reused if its folder exists)."""
    out = runs / name
    if not (out / "timeseries.parquet").exists():
        runs.mkdir(parents=True, exist_ok=True)
        execution = tomllib.loads(EXECUTION.read_text()) | changes
        exe_path = runs / f"execution-{name}.toml"
        exe_path.write_text(tomli_w.dumps(execution))
        scenario = tomllib.loads(CASE.read_text())
        scenario.setdefault("asv", {})["execution"] = str(exe_path.resolve())
        sc_path = runs / f"case4-{name}.toml"
        sc_path.write_text(tomli_w.dumps(scenario))
        code = mpcasv(["simulate", str(sc_path), "--nominal", "--out", str(out), "--no-plots",
                       "--quiet"])  # fmt: skip
        if code != 0:
            raise SystemExit(f"mpcasv simulate {sc_path} failed (exit {code})")
    return pd.read_parquet(out / "timeseries.parquet")


def window(ts: pd.DataFrame) -> pd.DataFrame:
    """Rows within :data:`WINDOW` of the closest approach, with ``tau`` = t - t(min range)."""
    i = int(ts["range_min0"].to_numpy().argmin())
    tau = ts["t"] - ts["t"].iloc[i]
    w = ts.assign(tau=tau)
    return w[(w["tau"] >= WINDOW[0]) & (w["tau"] <= WINDOW[1])]


def draw(series: dict[str, pd.DataFrame], path: Path) -> None:
    fig, (ax_p, ax_r, ax_u) = plt.subplots(1, 3, figsize=(15, 4.6))
    for name, ts in series.items():
        _, label, c = VARIANTS[name]
        w = window(ts)
        ax_p.plot(w["E"], w["N"], color=c, label=label)
        ax_p.plot(w["auv0_E"], w["auv0_N"], ":", color=c)
        ax_r.plot(w["tau"], w["range_min0"], color=c)
        k = int(w["range_min0"].to_numpy().argmin())
        rmin = float(w["range_min0"].iloc[k])
        ax_r.plot([w["tau"].iloc[k]], [rmin], "o", color=c)
        dx, dy = {"eq31": (8, -2), "all": (0, 14), "shipped": (0, 26)}[name]
        ax_r.annotate(f"{rmin:.1f} m", (w["tau"].iloc[k], rmin), color=c,
                      ha="left" if dx else "center", textcoords="offset points",
                      xytext=(dx, dy))  # fmt: skip
        inside = w["coll_s"].to_numpy() > 0  # steps with time inside the collision domain
        y0 = STRIP[name]
        ax_r.fill_between(w["tau"], y0, y0 + 2.0, where=inside, step="mid", color=c,
                          alpha=0.6, lw=0)  # fmt: skip
        ax_u.plot(w["tau"], w["u"], color=c)
        transit = w["mode"] == "transit"
        ax_u.plot(w["tau"], np.where(transit, w["u_ref"], np.nan), "--", color=c, lw=1)
    r_in = float(series["shipped"]["r_inner0"].iloc[0])
    ax_r.axhline(r_in, color="grey", lw=0.8, ls=":")
    ax_r.text(WINDOW[0], r_in + 1.5, f"r_inner = {r_in:.0f} m", fontsize=8)
    ax_r.axhline(10.0, color="k", lw=0.8, ls="--")
    ax_r.text(WINDOW[0], 11.5, "10 m (test)", fontsize=8)
    ax_p.set(xlabel="E (m)", ylabel="N (m)", title="paths (ASV solid, pursuer dotted)")
    ax_p.set_aspect("equal", adjustable="datalim")
    ax_p.legend(fontsize=7, loc="upper left")
    ax_r.set(xlabel="t - t(min range) (s)", ylabel="range to pursuer (m)",
             title="Case 4 (nominal): head-on encounter\n(strips below 0: steps inside the "
                   "collision domain)", ylim=(-11.0, None))  # fmt: skip
    ax_u.set(xlabel="t - t(min range) (s)", ylabel="surge u (m/s)",
             title="speed (solid), eq. 3.1 u_ref in transit (dashed)")  # fmt: skip
    for ax in (ax_p, ax_r, ax_u):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def cli() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=Path, default=Path("runs/case4-escape"))
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "figures" / "case4-escape.png")
    args = ap.parse_args()
    series = {name: run_variant(name, ch, args.runs) for name, (ch, _, _) in VARIANTS.items()}
    draw(series, args.out)
    for name, ts in series.items():
        w = window(ts)
        inside = w["coll_s"] > 0
        print(f"{name}: min range {ts['range_min0'].min():.2f} m; in the window u "
              f"{w['u'].min():.2f}-{w['u'].max():.2f} m/s; inside the collision domain "
              f"{w['coll_s'].sum():.1f} s (steps {w.loc[inside, 'tau'].min():.0f} to "
              f"{w.loc[inside, 'tau'].max():.0f} s)")  # fmt: skip
    print(f"wrote {args.out}")


if __name__ == "__main__":
    cli()
