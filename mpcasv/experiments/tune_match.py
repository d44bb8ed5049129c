"""Matched operating points inside ``mpcasv compare`` (issue 17 item 3).

A suite's ``[[controllers]]`` entry can name a tuned front instead of a preset:

```toml
[[controllers]]
label = "mpc"
name = "mpc-single"
front = "../../results/tune-mpc-single"   # output folder of `mpcasv tune controller`
at = "energy_J"                           # the matched metric (an objective of that search)
level = 60000.0                           # its level, in the metric's unit (J here)
```

The front point whose mean of ``at`` is nearest ``level`` is chosen (ties: the lower trial
number) and its preset (``DIR/presets/trial-NNNN[-<scenarios>].toml``, written by the search)
runs on every job of the entry: so two entries naming two controllers' fronts at one level
compare the controllers at (nearly) equal energy, on the suite's seeds, with the paired
statistics of :mod:`mpcasv.experiments.stats`. The means are the **held-out** ones when the
folder has held-out runs (candidates: the points still feasible and non-dominated on the
held-out realisations, ``front.csv`` column ``heldout_front``), else the training means (every
training front point is feasible), or the training means when the entry says
``front_means = "training"``. The choice, its front level and the level the comparison
itself achieved are written in the report (:func:`matched_table`).

Refused in one line (:class:`~mpcasv.config.ConfigError`, exit status 2) before anything
runs: a missing folder or one that is not a tuning output, an unknown metric or one that is
not an objective of the search, a level outside the candidates' range, an entry whose
controller is not the search's, a scenario none of the front's presets covers.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from mpcasv.config import ConfigError
from mpcasv.wording import count


@dataclass(frozen=True)
class FrontChoice:
    """The front point an entry runs: ``trial`` of the search in ``folder``, whose mean of
    ``at`` (``source``: "held-out" or "training" realisations) is ``front_level``, nearest
    the requested ``level``; ``low``/``high``: the candidates' range of ``at``."""

    label: str
    folder: Path
    controller: str
    at: str
    level: float
    source: str
    trial: int
    front_level: float
    low: float
    high: float
    candidates: int
    presets: tuple[tuple[str, str], ...]  # (scenario name or "*", absolute preset path)

    def preset_for(self, scenario: str, where: str) -> str:
        """The chosen point's preset file for ``scenario`` (absolute path).

        Raises
        ------
        ConfigError
            No preset of the point covers the scenario (the search's presets differ per
            scenario group and this scenario was not in its training set).
        """
        table = dict(self.presets)
        if scenario in table:
            return table[scenario]
        if "*" in table:
            return table["*"]
        raise ConfigError(f"{where}: the front {self.folder} has presets of trial {self.trial} "
                          f"for scenarios {sorted(table)} only, not {scenario!r}")  # fmt: skip


def _candidates(folder: Path, at: str, means: str | None,
                where: str = "") -> tuple[pd.DataFrame, str, str]:  # fmt: skip
    """(candidate rows, column of ``at`` to match, source) of a tuning's front table;
    ``means``: "heldout" (refused without held-out runs), "training", or None (held-out
    when the folder has held-out runs, else training)."""
    front = pd.read_csv(folder / "front.csv")
    col = f"heldout.{at}"
    has_heldout = ("heldout_front" in front and col in front
                   and bool(front[col].notna().any()))  # fmt: skip
    if means == "heldout" and not has_heldout:  # asked for: it used the training means
        raise ConfigError(f"{where}: front_means = 'heldout', but {folder} has no held-out "
                          "means of its front (searched with --no-heldout, or no feasible "
                          "point): rerun it without --no-heldout, or say "
                          "front_means = 'training'")  # fmt: skip
    if means != "training" and has_heldout:
        sel = front[front["heldout_front"].astype(bool) & front[col].notna()]
        return sel, col, "held-out"
    return front[front[f"train.{at}"].notna()], f"train.{at}", "training"


def _presets(folder: Path, trial: int, where: str) -> tuple[tuple[str, str], ...]:
    """(scenario, path) of trial ``trial``'s preset files ("*": one file for all)."""
    stem = f"trial-{trial:04d}"
    out = []
    for p in sorted((folder / "presets").glob(f"{stem}*.toml")):
        rest = p.stem[len(stem):]
        if rest == "":
            out.append(("*", str(p.resolve())))
        elif rest.startswith("-"):
            out += [(s, str(p.resolve())) for s in rest[1:].split("+")]
    if not out:
        raise ConfigError(f"{where}: {folder / 'presets'} has no preset of trial {trial} "
                          "(rerun `mpcasv tune controller` to write the outputs)")  # fmt: skip
    return tuple(out)


def choose_front(label: str, front: str, at: str, level: float, base: Path, where: str,
                 means: str | None = None) -> FrontChoice:  # fmt: skip
    """The point of the tuning in ``front`` (relative to ``base``, the suite's folder) nearest
    ``level`` of metric ``at`` (see the module docstring); ``means = "training"``: among
    the training front by training means even when the folder has held-out runs.

    Raises
    ------
    ConfigError
        Missing folder, not a tuning output, unknown metric or not an objective, no candidate,
        ``level`` outside the candidates' range, no preset file of the chosen point.
    """
    from mpcasv.experiments.metrics import METRIC_INFO

    folder = Path(front).expanduser()
    folder = (folder if folder.is_absolute() else base / folder).resolve()
    if not folder.is_dir():
        raise ConfigError(f"{where}: front folder {front!r} not found (looked at {folder})")
    for name in ("tune.json", "front.csv"):
        if not (folder / name).exists():
            raise ConfigError(f"{where}: {folder} has no {name}: not an output folder of "
                              "'mpcasv tune controller'")  # fmt: skip
    if at not in METRIC_INFO:
        raise ConfigError(f"{where}: at = {at!r}: unknown metric (metrics.json keys: see "
                          "docs/metrics.md)")  # fmt: skip
    summary = json.loads((folder / "tune.json").read_text())
    if at not in summary["objectives"]:
        raise ConfigError(f"{where}: at = {at!r} is not an objective of the search in {folder} "
                          f"(its objectives: {summary['objectives']})")  # fmt: skip
    rows, col, source = _candidates(folder, at, means, where)
    if not len(rows):
        raise ConfigError(f"{where}: the front in {folder} has no {source} point to choose from")
    low, high = float(rows[col].min()), float(rows[col].max())
    if not (math.isfinite(level) and low <= level <= high):
        unit = METRIC_INFO[at].unit
        # full precision: a bound shown rounded (20689.6) could not be typed back as a level
        raise ConfigError(f"{where}: level = {level!r} {unit} is outside the front's {at} "
                          f"range [{low!r}, {high!r}] ({source} means of "
                          f"{count(len(rows), 'point')} in {folder})")  # fmt: skip
    dist = (rows[col] - level).abs()
    best = rows.assign(_d=dist).sort_values(["_d", "trial"]).iloc[0]
    trial = int(best["trial"])
    return FrontChoice(label=label, folder=folder, controller=summary["controller"], at=at,
                       level=float(level), source=source, trial=trial,
                       front_level=float(best[col]), low=low, high=high, candidates=len(rows),
                       presets=_presets(folder, trial, where))  # fmt: skip


#: what the report's "Matched operating points" table says (mpcasv.experiments.report)
MATCHED_NOTE = (
    "Entries naming a tuned front (`front`, `at`, `level`): the front point nearest the level "
    "(`trial`, its `front level` over the tuning's realisations) runs with its preset; "
    "`achieved` is the mean of the metric over this comparison's runs of the entry "
    "(other scenarios, durations or seeds than the tuning's move it)."
)


def _g(v: float) -> float:
    return float(f"{v:.5g}") if math.isfinite(v) else v


def matched_table(fronts: list[FrontChoice], results: pd.DataFrame) -> pd.DataFrame:
    """One row per front entry: the choice and the level achieved in this comparison (mean of
    ``at`` over the entry's ``ok`` runs of ``results``; NaN without any)."""
    rows = []
    for c in fronts:
        ok = results[(results["label"] == c.label) & (results["status"] == "ok")] \
            if len(results) else results  # fmt: skip
        achieved = float(ok[c.at].mean()) if len(ok) and c.at in ok else math.nan
        rel = achieved / c.level - 1 if c.level else math.nan
        rows.append({"label": c.label, "controller": c.controller, "front": str(c.folder),
                     "at": c.at, "level": c.level, "trial": c.trial,
                     "front level": _g(c.front_level), "from": f"{c.source} means",
                     "front range": f"[{c.low:.5g}, {c.high:.5g}] ({count(c.candidates, 'point')})",
                     "achieved": _g(achieved), "runs": len(ok),
                     "achieved / level - 1": _g(rel)})  # fmt: skip
    return pd.DataFrame(rows).set_index("label")
