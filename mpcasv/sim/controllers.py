"""Moved: the controller registry is :mod:`mpcasv.controllers` (controllers import nothing of
the simulator). This re-export keeps modules not yet updated working (``mpcasv.io``); new code
imports ``mpcasv.controllers``. Remove once nothing imports ``mpcasv.sim.controllers``."""

from mpcasv.controllers.registry import (  # noqa: F401
    CONTROLLERS,
    Boat,
    ControllerKind,
    controller_kind,
    load_preset,
    make_controller,
)
