"""Supervisory controllers by name: the registry (:mod:`mpcasv.controllers.registry`) and the
trivial ``goto`` controller. Imports nothing of the simulator, the experiments or the I/O
layer, so every controller (hybrid, MPC) can register itself here."""

from mpcasv.controllers.registry import (
    CONTROLLERS,
    Boat,
    ControllerKind,
    check_boat,
    controller_kind,
    load_preset,
    make_controller,
    parameter_hash,
    preset_used,
)

__all__ = [
    "CONTROLLERS", "Boat", "ControllerKind", "check_boat", "controller_kind", "load_preset",
    "make_controller", "parameter_hash", "preset_used",
]  # fmt: skip
