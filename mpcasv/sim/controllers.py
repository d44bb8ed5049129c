"""Registry of supervisory controllers, built by name from TOML presets.

Every controller the simulator, the experiment runner and the deploy loop can use is listed
in :data:`CONTROLLERS` as ``name -> "module:attribute"``; the attribute is a
:class:`ControllerKind`. Presets are TOML files in ``mpcasv/data/presets/`` (or any path)
validated into the kind's parameter dataclass; suites may override single fields.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mpcasv.config import ConfigError, load_toml, parse, resolve
from mpcasv.interface import Controller

CONTROLLERS: dict[str, str] = {
    "goto": "mpcasv.sim.goto:KIND",
    "hybrid-single": "mpcasv.hybrid.single:KIND",
    "hybrid-multi": "mpcasv.hybrid.multi:KIND",
    "mpc-single": "mpcasv.mpc.controller:KIND_SINGLE",
    "mpc-multi": "mpcasv.mpc.controller:KIND_MULTI",
}


@dataclass(frozen=True)
class ControllerKind:
    """How to build one kind of controller: its parameter class, factory and default preset."""

    name: str
    params_cls: type
    build: Callable[[Any, int], Controller]  # (params, n_auv) -> controller
    default_preset: str
    multi: bool = False  # handles several AUVs


def controller_kind(name: str) -> ControllerKind:
    """Look up a controller kind by name, with a clear error for unknown names."""
    if name not in CONTROLLERS:
        raise ConfigError(f"unknown controller {name!r}; known: {sorted(CONTROLLERS)}")
    module, attr = CONTROLLERS[name].split(":")
    try:
        return getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"controller {name!r} is not available: {exc}") from None


def load_preset(
    name: str, preset: str | Path | None = None, overrides: Mapping[str, Any] | None = None
):
    """Validate a preset (shipped name or TOML path) for controller ``name``.

    ``overrides`` replace top-level or dotted (``"domain.delta_r"``) fields before validation.
    """
    kind = controller_kind(name)
    path = resolve("presets", preset or kind.default_preset)
    data = load_toml(path)
    for key, value in (overrides or {}).items():
        target, *rest = key.split(".")
        node = data
        parts = [target, *rest]
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = value
    source = f"{path}" + (f" with overrides {dict(overrides)}" if overrides else "")
    return parse(kind.params_cls, data, source)


def make_controller(
    name: str, n_auv: int, preset: str | Path | None = None,
    overrides: Mapping[str, Any] | None = None,
) -> Controller:  # fmt: skip
    """Build controller ``name`` for ``n_auv`` AUVs from a preset."""
    kind = controller_kind(name)
    if n_auv > 1 and not kind.multi:
        raise ConfigError(f"controller {name!r} handles one AUV, the scenario has {n_auv}")
    return kind.build(load_preset(name, preset, overrides), n_auv)
