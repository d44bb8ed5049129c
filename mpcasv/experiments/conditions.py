"""The conditions of a suite (current x estimator) applied to a scenario, and the realisation
each seed draws under them: shared by the expansion of a suite (:func:`mpcasv.experiments.
suite.expand`) and the worker that runs a job (``Job.realised_scenario``), so both draw the
same realisation."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from mpcasv.config import ConfigError

if TYPE_CHECKING:
    from mpcasv.experiments.suite_file import Suite


def axis_label(current) -> str:
    """A suite's current value as a string: ``scenario``, ``off`` or ``V_N,V_E``."""
    if isinstance(current, str):
        return current
    return f"{current[0]:g},{current[1]:g}"


def condition_scenario(sc0, current_axis: str, current: tuple[float, float], duration: float):
    """Scenario ``sc0`` under one suite condition, before its realisation is drawn.

    ``current_axis = "scenario"`` keeps the scenario's current and its uncertainty; ``off`` or
    a value fixes the current to ``current`` (its uncertainty dropped: the suite says what the
    current is). ``duration`` replaces the scenario's.
    """
    from mpcasv.sim.scenario import scenario_with
    from mpcasv.sim.uncertainty import without_current

    sc = scenario_with(sc0, current=current, duration=duration)
    return sc if current_axis == "scenario" else without_current(sc)


def conditions(suite: Suite, sc0, path: Path, file: Path):
    """(scenario under the condition, current, current axis label, estimator) per condition."""
    for current in suite.current:
        vc = {"scenario": sc0.current, "off": (0.0, 0.0)}.get(current, current)
        vc = (float(vc[0]), float(vc[1]))
        axis = axis_label(current)
        try:
            sc = condition_scenario(sc0, axis, vc, suite.duration or sc0.duration)
        except ConfigError as exc:
            raise ConfigError(f"{path}: current {current!r} with {file}: {exc}") from None
        for est in suite.estimator:
            yield sc, vc, axis, (sc0.estimator if est == "scenario" else est)


def realisations(sc, seeds, where: str) -> dict:
    """``{seed: (Realisation, realised current (V_N, V_E) m/s)}`` of scenario ``sc`` (drawn
    here, so a bad draw stops the suite before any job starts)."""
    from mpcasv.sim.uncertainty import realise

    out = {}
    for seed in seeds:
        try:
            done, real = realise(sc, seed)
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        out[seed] = (real, (float(done.current[0]), float(done.current[1])))
    return out
