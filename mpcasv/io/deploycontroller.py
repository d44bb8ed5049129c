"""How the deploy builds and checks its controller from a :class:`~mpcasv.io.config.DeployConfig`:
the preset overrides, the boat (vessel and acoustic channel), the build (an MPC's library
compiled now if it is not cached), and the checks made when the configuration is loaded
(controller, preset, estimator, vessel, an MPC's field budget, the AUV count).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from mpcasv.config import ConfigError

if TYPE_CHECKING:
    from mpcasv.io.config import DeployConfig

__all__ = ["MIN_SOLVE_MS", "build_controller", "check_controller", "check_field_budget",
           "check_watchdog", "controller_overrides", "deploy_boat", "field_boat",
           "known_plans"]


def controller_overrides(cfg: DeployConfig, speed: float | None = None) -> dict[str, Any]:
    """The preset overrides the deploy builds its controller with: ``controller.overrides``,
    plus ``speed`` when the learned achievable speed caps it (``controller.speed_feedback``).
    The vessel is not an override: it is the run's :class:`~mpcasv.controllers.Boat`
    (:func:`deploy_boat`)."""
    out = dict(cfg.controller.overrides)
    if speed is not None:
        out["speed"] = float(speed)
    return out


def deploy_boat(cfg: DeployConfig):
    """The boat the deploy drives (``controller.vessel``, default Gretha) with the
    configuration's acoustic channel (``[acoustics]``): the one vessel the controller plans
    with; a preset that names another vessel is refused in one line."""
    return field_boat(cfg.controller.vessel, cfg.acoustics)


def field_boat(vessel: str | None, acoustics):
    """The :class:`~mpcasv.controllers.Boat` of a deploy: ``vessel`` (shipped name or TOML
    path; None: Gretha) with the acoustic channel ``acoustics``
    (:class:`~mpcasv.models.acoustics.AcousticParams`). One definition for the deploy
    (:func:`deploy_boat`) and its replay (:func:`mpcasv.io.replay.replay`)."""
    import dataclasses

    from mpcasv.controllers import Boat

    return dataclasses.replace(Boat.load(vessel or "gretha"), acoustics=acoustics)


def build_controller(cfg: DeployConfig, speed: float | None = None, log=print):
    """The deploy's controller (compiles an MPC's library now if it is not cached: progress
    on ``log``; the other controllers have nothing to compile, and ``log`` says so)."""
    import threading
    import time

    from mpcasv.controllers import controller_kind, make_controller

    c = cfg.controller
    t0 = time.perf_counter()
    what = ("nothing to compile (only an MPC has a compiled library)"
            if controller_kind(c.name).libraries is None else
            "an MPC compiles its library now if it is not cached (about a minute the first "
            "time)")  # fmt: skip
    log(f"preparing controller {c.name} (preset {c.preset or 'default'}"
        f"{', vessel ' + c.vessel if c.vessel else ''}): {what}")  # fmt: skip
    done = threading.Event()

    def progress() -> None:  # a line every 10 s while building (compiling)
        while not done.wait(10.0):
            log(f"still preparing {c.name}: {time.perf_counter() - t0:.0f} s")

    threading.Thread(target=progress, daemon=True).start()
    try:
        ctl = make_controller(c.name, len(cfg.auvs), c.preset, controller_overrides(cfg, speed),
                              boat=deploy_boat(cfg))  # fmt: skip
    finally:
        done.set()
    if hasattr(ctl, "say_current"):  # the event current_untested says it, in the run's time
        ctl.say_current = False
    refuse_simulation_only(ctl, c.name)
    log(f"controller {c.name} ready in {time.perf_counter() - t0:.1f} s")
    return ctl


def refuse_simulation_only(ctl, name: str, usbl_fixes: bool = True) -> None:
    """Refuse a controller (or its parameters: the same ``needs_*`` attributes) that reads
    what only a simulator observes, where a deploy's observations (and so its log's, which
    ``mpcasv replay`` replays) do not carry it: the true current (``current = "oracle"``);
    and, where ``usbl_fixes`` is False (a deploy log written before the deploy read DUNE's
    ``UsblFixExtended``), the ASV's own USBL fix times (``fix_age_source = "observed"``, M2o).

    Raises
    ------
    ConfigError
        One line naming the setting and what to use instead.
    """
    if getattr(ctl, "needs_current_oracle", False):  # only a simulator knows the true current
        raise ConfigError(f"controller {name}: current = 'oracle' needs the simulator's true "
                          "current; in a deployment use 'estimated' or 'zero'")  # fmt: skip
    if getattr(ctl, "needs_usbl_fixes", False) and not usbl_fixes:
        raise ConfigError(f"controller {name}: fix_age_source = 'observed' needs the ASV's "
                          "own USBL fix times, which this log's observations do not carry "
                          "(written before mpcasv deploy read DUNE's UsblFixExtended): "
                          "replay it with a preset whose fix_age_source is 'model' "
                          "(--preset)")  # fmt: skip


#: the least time (ms) a step's solves can work with in the field: a warm-started solve's
#: median is 2-7 ms (docs/deploy.md, ``solver.threads``)
MIN_SOLVE_MS = 1.0


def check_field_budget(params) -> None:
    """Refuse a ``solver.budget_ms`` that can never work in the field: the deadline keeps
    :data:`~mpcasv.mpc.solving.STEP_RESERVE_S` of every step's budget for the fallback and
    its command, and the solves need :data:`MIN_SOLVE_MS` of the rest; with less, each solve
    would be abandoned at once (its worker killed and replaced) and every step would take the
    fallback. Parameters without ``solver`` (the hybrid controllers) pass.

    Raises
    ------
    ConfigError
        One line with the budget, the reserve and the least budget accepted.
    """
    budget = getattr(getattr(params, "solver", None), "budget_ms", None)
    if budget is None:
        return
    from mpcasv.mpc.solving import STEP_RESERVE_S

    reserve = STEP_RESERVE_S * 1e3
    if budget < reserve + MIN_SOLVE_MS:
        raise ConfigError(f"solver.budget_ms = {budget:g} ms can never work in the field: a "
                          f"step keeps {reserve:g} ms of its budget for the fallback, which "
                          f"leaves the solves {max(budget - reserve, 0.0):g} ms (every step "
                          f"would take the fallback); give at least {reserve + MIN_SOLVE_MS:g} "
                          "ms (the presets: 200)")  # fmt: skip


def check_controller(cfg: DeployConfig, source: str | Path,
                     watchdog_set: frozenset[str] = frozenset()) -> None:  # fmt: skip
    """Validate the controller's name, preset, overrides, vessel, an MPC's field budget
    (:func:`check_field_budget`), the estimator and its scenario (read only by ``plan``),
    the AUV count (the controller itself is built by :func:`build_controller`, before any
    vehicle is contacted), every AUV's system name when the controller reads the ASV's USBL
    fixes (``fix_age_source = "observed"``: DUNE names their target by it), and that no
    ``[watchdog]`` field set explicitly (the names in ``watchdog_set``) goes unread with this
    controller and mode (:func:`check_watchdog`)."""
    from mpcasv.config import ConfigError, resolve
    from mpcasv.controllers import check_boat
    from mpcasv.controllers.registry import checked_preset
    from mpcasv.estimation import ESTIMATORS

    c = cfg.controller
    if c.estimator not in ESTIMATORS:
        raise ConfigError(
            f"{source}: controller.estimator: unknown {c.estimator!r}; known {sorted(ESTIMATORS)}"
        )
    try:
        _, params = checked_preset(c.name, len(cfg.auvs), c.preset, controller_overrides(cfg),
                                   "the config")  # fmt: skip
        if c.vessel is not None:
            resolve("vessels", c.vessel)
        check_boat(params, deploy_boat(cfg), str(c.preset or c.name))
        check_field_budget(params)
        refuse_simulation_only(params, c.name)  # before anything is compiled
    except ConfigError as exc:
        raise ConfigError(f"{source}: controller: {exc}") from None
    check_watchdog(cfg, params, watchdog_set, source)
    unnamed = [k for k, v in enumerate(cfg.auvs) if not v.name]
    if getattr(params, "needs_usbl_fixes", False) and unnamed:
        raise ConfigError(f"{source}: controller: fix_age_source = 'observed' reads the ASV's "
                          "UsblFixExtended, which names each AUV by its system name: give "
                          f"AUV {unnamed[0]}'s [[vehicle]] a name")  # fmt: skip
    if c.speed_feedback and not hasattr(params, "speed"):
        raise ConfigError(f"{source}: controller.speed_feedback: {c.name!r} has no 'speed' "
                          "to cap")  # fmt: skip
    if c.scenario is not None and c.estimator != "plan":
        raise ConfigError(f"{source}: controller.scenario: read only by estimator = 'plan' "
                          f"(the AUVs' plans), the estimator is {c.estimator!r}: remove "
                          "scenario, or set estimator = 'plan'")  # fmt: skip
    if c.scenario is not None and not Path(c.scenario).is_file():
        raise ConfigError(f"{source}: controller.scenario: no such file {c.scenario!r}")
    if c.estimator == "plan" and c.scenario is None:
        raise ConfigError(f"{source}: controller.estimator = 'plan' needs controller.scenario "
                          "(the scenario holding the AUVs' plans); without it every AUV "
                          "would run the Kalman filter: give scenario, or estimator = "
                          "'kalman'")  # fmt: skip
    try:
        known_plans(cfg)  # the scenario loads and has the configuration's AUVs
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    if c.estimator == "plan" and c.scenario is not None:
        from mpcasv.estimation import check_plan_estimator
        from mpcasv.sim.scenario import load_scenario

        check_plan_estimator(load_scenario(c.scenario), "plan",
                             f"{source}: controller.estimator = 'plan' with controller."
                             f"scenario {c.scenario!r}", "the scenario of the AUVs' plans, "
                             "or estimator = 'kalman'")  # fmt: skip


def check_watchdog(cfg: DeployConfig, params, watchdog_set, source: str | Path) -> None:
    """Refuse a ``[watchdog]`` field set explicitly (named in ``watchdog_set``) that the run
    would never read: ``keep_out_m`` and ``guard_speed`` when the controller's ``avoid``
    option or domain, and its ``speed``, take their place in the guard
    (:func:`mpcasv.io.watchdog.guard_sources`); ``propeller_on_threshold`` with
    ``propeller = "command"`` (no thruster is read). Defaults are never refused.

    Raises
    ------
    ConfigError
        One line naming ``source``, the field, the controller or mode, and what to do.
    """
    from mpcasv.io.watchdog import guard_sources

    c, wd = cfg.controller, cfg.watchdog
    keep, speed_from = guard_sources(params, getattr(params, "domain", None))
    what = {"avoid": "its 'avoid' sphere", "domain": "its domain's r_in"}
    if "keep_out_m" in watchdog_set and keep != "keep_out_m":
        raise ConfigError(f"{source}: watchdog.keep_out_m: not read with controller "
                          f"{c.name!r}, whose guard keeps out {what[keep]}: remove "
                          "keep_out_m (it is for controllers without a domain)")  # fmt: skip
    if "guard_speed" in watchdog_set and speed_from != "guard_speed":
        raise ConfigError(f"{source}: watchdog.guard_speed: not read with controller "
                          f"{c.name!r}, whose guard transits at its own 'speed' "
                          f"({params.speed:g} m/s): remove guard_speed (set the speed in "
                          "controller.overrides)")  # fmt: skip
    if "propeller_on_threshold" in watchdog_set and wd.propeller != "thruster":
        raise ConfigError(f"{source}: watchdog.propeller_on_threshold: read only with "
                          f"watchdog.propeller = 'thruster' (it is {wd.propeller!r}: no "
                          "thruster is read): remove it, or set propeller = "
                          "'thruster'")  # fmt: skip


def known_plans(cfg: DeployConfig) -> list:
    """The AUVs' plans as the ASV knows them (:func:`mpcasv.estimation.scenario_plans`, one per
    AUV of the configuration, in order) from ``controller.scenario``; ``[None] * n`` without a
    scenario. An AUV without a plan (a pursuer, a transit) has None: its ``plan`` estimator is
    its Kalman filter, as in the simulator.

    Raises
    ------
    ConfigError
        The scenario cannot be loaded, or holds another number of AUVs than the configuration.
    """
    n = len(cfg.auvs)
    if cfg.controller.scenario is None:
        return [None] * n
    from mpcasv.estimation import scenario_plans
    from mpcasv.sim.scenario import load_scenario

    sc = load_scenario(cfg.controller.scenario)
    if len(sc.auv) != n:
        raise ConfigError(f"controller.scenario {cfg.controller.scenario} has {len(sc.auv)} "
                          f"AUVs, the config {n}")  # fmt: skip
    return scenario_plans(sc)
