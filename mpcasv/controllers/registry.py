"""Registry of supervisory controllers, built by name from TOML presets for one boat.

Every controller the simulator, the experiment runner and the deploy loop can use is listed
in :data:`CONTROLLERS` as ``name -> "module:attribute"``; the attribute is a
:class:`ControllerKind`. Presets are TOML files in ``mpcasv/data/presets/`` (or any path)
validated into the kind's parameter dataclass; suites may override single fields.

This module sits below the simulator, the experiments and the I/O layer: it imports none of
them (``tests/test_dependencies.py`` checks it), so controllers can import it.

One vessel per run (issue 13): a controller is built for the run's :class:`Boat` (the vessel
model's and the execution level's parameters that the simulator integrates or the boat at sea
has). A preset may not name another vessel or execution level; it is refused with one line.

A preset names the controller(s) it is for (``controller = "hybrid-single"``, or a list when
one preset serves several): every shipped preset does, and loading it for another controller
is refused in one line, even when its fields happen to validate for that one (the hybrid's
``paper1-field`` is also a valid MPC preset: a domain and a speed). A user preset without the
key is accepted as before, checked by validation only (presets written before the key existed,
e.g. the trial presets of tuned fronts, keep loading); adding the key is recommended.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import json
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mpcasv.config import ConfigError, load_toml, parse, resolve
from mpcasv.control.params import ExecutionParams, load_execution
from mpcasv.interface import Controller
from mpcasv.models.acoustics import AcousticParams
from mpcasv.models.params import VesselParams, load_vessel

CONTROLLERS: dict[str, str] = {
    "goto": "mpcasv.controllers.goto:KIND",
    "hybrid-single": "mpcasv.hybrid.single:KIND",
    "hybrid-multi": "mpcasv.hybrid.multi:KIND",
    "mpc-single": "mpcasv.mpc.controller:KIND_SINGLE",
    "mpc-multi": "mpcasv.mpc.controller:KIND_MULTI",
}

#: preset fields that name a file: resolved relative to the preset file that names them
PATH_FIELDS = ("vessel", "execution")

#: the preset key naming the controller(s) the preset is for (not a parameter: removed before
#: validation)
CONTROLLER_KEY = "controller"


def parameter_hash(params: Any) -> str:
    """SHA-256 (hex, 16 characters) of a parameter dataclass's values, without its ``name``
    and ``provenance`` (renaming a file or rewording a source does not change the boat)."""
    data = {k: v for k, v in dataclasses.asdict(params).items() if k not in ("name", "provenance")}
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class Boat:
    """The boat of one run: what the simulator integrates and every controller plans with.

    Attributes
    ----------
    vessel : VesselParams
        The Fossen 3-DOF model's parameters (:mod:`mpcasv.models.params`).
    execution : ExecutionParams
        The execution level's parameters (:mod:`mpcasv.control.params`).
    acoustics : AcousticParams
        The acoustic channel (USBL and modem) the run's fixes go through: the scenario's
        ``[acoustics]`` (the MPC's fix-rate model uses it; issue 16 item 1).
    """

    vessel: VesselParams
    execution: ExecutionParams
    acoustics: AcousticParams = AcousticParams()

    @classmethod
    def load(cls, vessel: str | Path = "gretha", execution: str | Path = "gretha") -> Boat:
        """Load from shipped names or TOML paths (:func:`mpcasv.config.resolve`).

        Raises
        ------
        ConfigError
            Unknown name, missing or invalid file.
        """
        return cls(load_vessel(vessel), load_execution(execution))

    @classmethod
    def of_scenario(cls, scenario) -> Boat:
        """The boat a scenario names (``scenario.asv.vessel`` / ``scenario.asv.execution``),
        loaded as the simulator loads it (:func:`mpcasv.sim.world.build_plant`), with the
        scenario's acoustic channel."""
        return dataclasses.replace(cls.load(scenario.asv.vessel, scenario.asv.execution),
                                   acoustics=scenario.acoustics)

    def describe(self) -> dict[str, str]:
        """What ``run.json`` records: the vessel's name and the parameter hashes."""
        return {"vessel": self.vessel.name, "vessel_sha256": parameter_hash(self.vessel),
                "execution_sha256": parameter_hash(self.execution)}  # fmt: skip


@dataclass(frozen=True)
class ControllerKind:
    """How to build one kind of controller: its parameter class, factory and default preset.

    ``build(params, n_auv, boat)`` returns the controller; ``boat`` is the run's
    :class:`Boat` (None: the controller's own default, for use outside a run).
    ``libraries(params, n_auv, boat)``, when given, lists the compiled libraries the
    controller loads (cached on disk), so that they can be compiled before a sweep starts
    (:mod:`mpcasv.controllers.prepare`). ``auv_limit(params)``, when given, is the most AUVs
    those parameters serve and why (``(limit, reason)``), or None (no limit but ``multi``):
    read by :func:`check_auv_count` before anything is compiled or run.
    """

    name: str
    params_cls: type
    build: Callable[[Any, int, Boat | None], Controller]
    default_preset: str
    multi: bool = False  # handles several AUVs
    libraries: Callable[[Any, int, Boat | None], list] | None = None
    auv_limit: Callable[[Any], tuple[int, str] | None] | None = None


def unknown_controller(name: str) -> str | None:
    """Why ``name`` is not a controller ("unknown controller 'x'; known: [...]"), or None."""
    return None if name in CONTROLLERS else (
        f"unknown controller {name!r}; known: {sorted(CONTROLLERS)}")


def controller_kind(name: str) -> ControllerKind:
    """Look up a controller kind by name, with a clear error for unknown names."""
    if (why := unknown_controller(name)) is not None:
        raise ConfigError(why)
    module, attr = CONTROLLERS[name].split(":")
    try:
        return getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"controller {name!r} is not available: {exc}") from None


def check_controller_flag(name: str, flag: str = "--controller") -> None:
    """Refuse an unknown controller given on the command line, naming the flag (it read
    "unknown controller" alone, as if from a file)."""
    if (why := unknown_controller(name)) is not None:
        raise ConfigError(f"{flag} {name}: {why}")


#: a scenario's or a suite's ``preset`` left out: the controller's default preset
DEFAULT_PRESET = "default"


def preset_used(name: str, preset: str | Path | None) -> str:
    """The preset controller ``name`` is built with when given ``preset``: ``preset`` itself
    (a shipped preset's name or a TOML path, as given), else (None or :data:`DEFAULT_PRESET`,
    a scenario file without a preset) its kind's default preset
    (:attr:`ControllerKind.default_preset`), by name: what a run or a replay records. (Before
    session 32 "default" was looked up as a preset of that name and refused in paper-table,
    sitl and the estimator evaluation; simulate alone had its own exception.)

    Raises
    ------
    ConfigError
        Unknown controller (:func:`controller_kind`).
    """
    if preset and str(preset) != DEFAULT_PRESET:
        return str(preset)
    return controller_kind(name).default_preset


def _preset_data(name: str, preset: str | Path | None) -> tuple[Path, dict]:
    path = resolve("presets", preset_used(name, preset))
    data = load_toml(path, "preset")
    for key in PATH_FIELDS:  # a path inside the preset is relative to the preset's folder
        value = data.get(key)
        if isinstance(value, str) and (value.endswith(".toml") or "/" in value):
            p = Path(value).expanduser()
            data[key] = str(p if p.is_absolute() else (path.parent / p))
    return path, data


def preset_controllers(data: Mapping[str, Any], path: str | Path) -> tuple[str, ...] | None:
    """The controllers a preset's ``controller`` key names (None: the key is absent).

    Raises
    ------
    ConfigError
        One line naming ``path``: the key is not a name or a non-empty list of names, or names
        an unknown controller.
    """
    value = data.get(CONTROLLER_KEY)
    if value is None:
        return None
    names = [value] if isinstance(value, str) else value
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise ConfigError(f"{path}: {CONTROLLER_KEY} = {value!r}: give a controller name or a "
                          "non-empty list of names")  # fmt: skip
    unknown = [n for n in names if n not in CONTROLLERS]
    if unknown:
        raise ConfigError(f"{path}: {CONTROLLER_KEY} = {value!r}: unknown controller(s) "
                          f"{unknown}; known: {sorted(CONTROLLERS)}")  # fmt: skip
    return tuple(names)


def check_preset_controller(name: str, data: Mapping[str, Any], path: str | Path) -> None:
    """Refuse a preset whose ``controller`` key does not name controller ``name``.

    Raises
    ------
    ConfigError
        One line naming the preset, the controllers it is for and ``name``.
    """
    declared = preset_controllers(data, path)
    if declared is not None and name not in declared:
        raise ConfigError(f"{path}: a preset for {' / '.join(declared)} (its '{CONTROLLER_KEY}' "
                          f"key), not for {name!r}: choose a preset of {name!r} (its default: "
                          f"{controller_kind(name).default_preset!r}), or use this preset with "
                          f"its controller ({declared[0]!r})")  # fmt: skip


def load_preset(
    name: str, preset: str | Path | None = None, overrides: Mapping[str, Any] | None = None
):
    """Validate a preset (shipped name or TOML path) for controller ``name``.

    ``overrides`` replace top-level or dotted (``"domain.delta_r"``) fields before validation.
    Paths inside the preset (``vessel``, ``execution``) are relative to the preset's folder.

    Raises
    ------
    ConfigError
        Unknown controller or preset; a preset whose ``controller`` key names other
        controllers; an override naming no parameter of the controller
        (:func:`check_override_keys`); invalid fields (a preset that validates only for other
        controllers is said to be theirs).
    """
    kind = controller_kind(name)
    path, data = _preset_data(name, preset)
    check_preset_controller(name, data, path)
    data.pop(CONTROLLER_KEY, None)
    check_override_keys(name, kind.params_cls, overrides or {})
    for key, value in (overrides or {}).items():
        target, *rest = key.split(".")
        node = data
        parts = [target, *rest]
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = value
    source = f"{path}" + (f" with overrides {dict(overrides)}" if overrides else "")
    try:
        return parse(kind.params_cls, data, source)
    except ConfigError:
        fits = _kinds_that_accept(data, kind)
        if fits and not overrides:  # a preset of another kind: say so in one line
            raise ConfigError(f"{path}: a preset for {', '.join(fits)}, not for {name!r} "
                              "(choose a preset of that controller)") from None  # fmt: skip
        raise


def check_override_keys(name: str, params_cls: type, overrides: Mapping[str, Any]) -> None:
    """Refuse an override whose dotted key names no parameter of controller ``name``
    (``params_cls``), e.g. ``solver.threads`` for a hybrid controller (it has no solver): it
    came out as pydantic's "Unexpected keyword argument", or a traceback for a key below a
    single value (``speed.x``).

    Raises
    ------
    ConfigError
        One line naming the key, the controller and the parameter it does not have, with the
        parameters there are at that level.
    """
    for key in overrides:
        parts = key.split(".")
        node: Any = params_cls
        for i, part in enumerate(parts):
            fields = getattr(node, "__pydantic_fields__", None)
            if fields is None and typing.get_origin(node) in (dict, Mapping):
                break  # a table of free keys: its values are validated by pydantic
            if fields is None or part not in fields:
                where = ".".join(parts[:i])
                there = (f"'{where}' is a single value" if fields is None else
                         f"{'its' if not where else repr(where) + ' has'} parameters: "
                         f"{', '.join(sorted(fields))}")  # fmt: skip
                raise ConfigError(f"override {key!r}: controller {name!r} has no parameter "
                                  f"{'.'.join(parts[: i + 1])!r} ({there})")  # fmt: skip
            node = fields[part].annotation


def _kinds_that_accept(data: dict, kind: ControllerKind) -> list[str]:
    """The other controllers whose parameter class validates ``data`` (sorted names)."""
    fits = []
    for other in sorted(CONTROLLERS):
        try:
            k = controller_kind(other)
            if k.params_cls is not kind.params_cls:
                parse(k.params_cls, data, other)
                fits.append(other)
        except ConfigError:
            continue
    return fits


def check_boat(params: Any, boat: Boat, source: str) -> None:
    """Refuse parameters that name another vessel or execution level than the run's.

    Raises
    ------
    ConfigError
        One line naming ``source`` (the preset), the field and both boats.
    """
    for field, loader, mine in (("vessel", load_vessel, boat.vessel),
                                ("execution", load_execution, boat.execution)):  # fmt: skip
        named = getattr(params, field, None)
        if named is None:
            continue
        other = loader(named)
        if parameter_hash(other) != parameter_hash(mine):
            raise ConfigError(
                f"{source}: {field} = {named!r} is not the run's {field} ({mine.name!r}, "
                f"parameters {parameter_hash(mine)} vs {parameter_hash(other)}): one vessel per "
                f"run; remove '{field}' from the preset or name the run's file"
            )


def auv_limit(name: str, params: Any) -> tuple[int, str] | None:
    """The most AUVs controller ``name`` with parameters ``params`` serves and why (its
    kind's ``auv_limit``), or None: no limit beyond the kind's ``multi``."""
    limit = controller_kind(name).auv_limit
    return None if limit is None else limit(params)


def checked_preset(name: str, n_auv: int, preset: str | Path | None = None,
                   overrides: dict | None = None,
                   holder: str = "the scenario") -> tuple[ControllerKind, Any]:  # fmt: skip
    """``(kind, params)`` of controller ``name`` with ``preset`` and ``overrides``, checked
    for ``n_auv`` AUVs: the kind's "handles one AUV" first (before the preset is read), then
    the parameters' own limit (:func:`check_auv_count`). The one sequence for
    :func:`make_controller`, the library preparation, sitl and deploy (before anything is
    compiled or run).

    Raises
    ------
    ConfigError
        As :func:`check_auv_count` and :func:`load_preset`.
    """
    check_auv_count(name, n_auv, holder=holder)
    params = load_preset(name, preset, overrides)
    return check_auv_count(name, n_auv, params, preset, holder), params


def check_auv_count(name: str, n_auv: int, params: Any = None, preset: str | Path | None = None,
                    holder: str = "the scenario") -> ControllerKind:  # fmt: skip
    """The kind of controller ``name`` if it handles ``n_auv`` AUVs.

    With ``params`` (loaded from ``preset``, named in the message), also their own limit
    (:func:`auv_limit`: e.g. the visiting order of ``mpc-multi-order``). ``holder`` is what
    has the AUVs, for the message (``"the config"`` in a deployment).

    Raises
    ------
    ConfigError
        Unknown controller, several AUVs for a one-AUV controller, or more AUVs than the
        parameters serve.
    """
    kind = controller_kind(name)
    if n_auv > 1 and not kind.multi:
        raise ConfigError(f"controller {name!r} handles one AUV, {holder} has {n_auv}")
    limit = None if params is None else auv_limit(name, params)
    if limit is not None and n_auv > limit[0]:
        raise ConfigError(f"controller {name!r} with preset {preset_used(name, preset)!r} "
                          f"handles at most {limit[0]} AUVs, {holder} has {n_auv} "
                          f"({limit[1]})")  # fmt: skip
    return kind


def make_controller(
    name: str, n_auv: int, preset: str | Path | None = None,
    overrides: Mapping[str, Any] | None = None, *, boat: Boat | None = None,
) -> Controller:  # fmt: skip
    """Build controller ``name`` for ``n_auv`` AUVs from a preset, for the run's ``boat``.

    ``boat`` is the scenario's (or the deploy configuration's) vessel and execution level;
    None only outside a run (unit tests): the controller's own default.

    Raises
    ------
    ConfigError
        Unknown controller or preset, invalid preset, too many AUVs for the kind, or a preset
        that names another vessel than ``boat``'s.
    """
    kind, params = checked_preset(name, n_auv, preset, overrides)  # before building
    if boat is not None:
        check_boat(params, boat, str(resolve("presets", preset_used(name, preset))))
    return kind.build(params, n_auv, boat)
