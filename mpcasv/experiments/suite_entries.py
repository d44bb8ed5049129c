"""How a suite's ``[[controllers]]`` entries become (controller, preset, overrides) per
scenario (:func:`mpcasv.experiments.suite.expand`): which entries are usable, the controller
and preset an entry runs on a scenario (its own, the scenario's, or a tuned front's point:
:mod:`mpcasv.experiments.tune_match`) and the scenario's domain overrides."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from mpcasv.config import ConfigError, anchor
from mpcasv.experiments.suite_file import ControllerEntry, Suite, _flatten


def _preset_ref(preset: str, base: Path) -> str:
    """Suite-relative preset paths made absolute (see :func:`mpcasv.config.anchor`); names kept."""
    return anchor(preset, base)


def _usable_controllers(suite: Suite, path: Path, names: list[str]):
    """[(i, entry)] whose controllers exist, and the optional entries skipped (with why)."""
    from mpcasv.controllers import controller_kind

    usable, skipped = [], []
    for i, entry in enumerate(suite.controllers):
        where = f"{path}: controllers[{i}] ({entry.label})"
        for key in ("name", "single", "multi"):
            cname = getattr(entry, key)
            if cname is None:
                continue
            try:
                controller_kind(cname)
            except ConfigError as exc:
                if entry.optional and "not available" in str(exc):
                    skipped.append(f"optional controller {entry.label} ({cname}): {exc}")
                    break
                raise ConfigError(f"{where}: {key}: {exc}") from None
        else:
            for field, values in (("scenarios", entry.scenarios or ()), ("presets", entry.presets)):
                for s in values:
                    if s not in names:
                        raise ConfigError(f"{where}: {field}: {s!r} is not among the suite's "
                                          f"scenarios {names}")  # fmt: skip
            if entry.scenarios is not None:  # a preset for a scenario it does not run: unused
                unused = [s for s in entry.presets if s not in entry.scenarios]
                if unused:
                    raise ConfigError(f"{where}: presets: {unused[0]!r} is not among this "
                                      f"entry's scenarios {list(entry.scenarios)}, so its "
                                      "preset would be unused: add it to 'scenarios' or "
                                      "drop it from 'presets'")  # fmt: skip
            usable.append((i, entry))
    return usable, skipped


def _controller_and_preset(entry: ControllerEntry, sc, where: str, base: Path, choice=None):
    """The registered controller name and preset reference of ``entry`` on scenario ``sc``
    (``choice``: the entry's :class:`~mpcasv.experiments.tune_match.FrontChoice`)."""
    from mpcasv.controllers.registry import check_auv_count

    n_auv = len(sc.auv)
    cname = entry.controller_for(n_auv)
    if cname is None:
        key = "multi" if n_auv > 1 else "single"
        raise ConfigError(f"{where}: no controller for {n_auv} AUV(s): give '{key}' or "
                          "restrict 'scenarios'")  # fmt: skip
    try:
        check_auv_count(cname, n_auv)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    if choice is not None:
        if cname != choice.controller:
            raise ConfigError(f"{where}: the front {choice.folder} tuned {choice.controller!r}, "
                              f"not {cname!r}")  # fmt: skip
        return cname, choice.preset_for(sc.name, where)
    preset = entry.presets.get(sc.name, entry.preset)
    if preset == "scenario":
        if sc.controller != cname:
            raise ConfigError(f"{where}: preset = 'scenario', but the scenario's preset "
                              f"{sc.preset!r} is for {sc.controller!r}, not {cname!r}")  # fmt: skip
        preset = sc.preset
    return cname, (None if preset == "default" else _preset_ref(preset, base))


def _scenario_domain(entry: ControllerEntry, sc, where: str) -> dict[str, Any]:
    """``domain.*`` overrides from the scenario's own preset (``domain_from = "scenario"``):
    the preset its controller runs with (:func:`~mpcasv.controllers.registry.preset_used`: a
    scenario without a preset means its controller's default preset; it was looked up as a
    preset named 'default' and refused without the suite, scenario or entry)."""
    from mpcasv.config import load_toml, resolve
    from mpcasv.controllers.registry import DEFAULT_PRESET, preset_used

    if entry.domain_from != "scenario":
        return {}
    preset = preset_used(sc.controller, sc.preset)
    domain = load_toml(resolve("presets", preset)).get("domain")
    if not isinstance(domain, Mapping):
        whose = (f" (the default of its controller {sc.controller!r}: it names none)"
                 if sc.preset == DEFAULT_PRESET else "")  # fmt: skip
        raise ConfigError(f"{where}: domain_from = 'scenario', but the scenario's preset "
                          f"{preset!r}{whose} has no [domain] table")  # fmt: skip
    return _flatten(domain, "domain.")


def _front_choices(usable, path: Path) -> dict:
    """{entry index: FrontChoice} of the entries that name a tuned front."""
    from mpcasv.experiments.tune_match import choose_front

    return {i: choose_front(e.label, e.front, e.at or "energy_J", e.level, path.parent,
                            f"{path}: controllers[{i}] ({e.label})",
                            e.front_means)  # None: held-out means when there are some
            for i, e in usable if e.front is not None}  # fmt: skip
