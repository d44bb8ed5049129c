"""DUNE's effective configuration (``Config.ini`` of a log folder): the simulator's thrusters.

DUNE writes the configuration it ran with, every included file merged, as ``Config.ini``
beside ``Data.lsf.gz`` in each log folder. :func:`read_thruster_map` takes from it the
vehicle simulator's engine model (``[VSIM/Model/<General.Vehicle Type>]``), the map from
SetThrusterActuation to force that :mod:`mpcasv.models.ident_thrust` identifies through.
"""

from __future__ import annotations

import configparser
from pathlib import Path

from mpcasv.errors import LogError
from mpcasv.models.ident_thrust import ThrusterMap

__all__ = ["VSIM_MAX_PROP_TORQUE", "read_thruster_map"]

#: yaw moment limit of one VSIM engine (N m): ``c_max_prop_torque`` in DUNE's
#: src/Simulators/VSIM/VSIM/Engine.hpp (a source constant, not in the configuration)
VSIM_MAX_PROP_TORQUE = 6.0


def _numbers(section, key: str, n: int, path) -> list[float]:
    try:
        vals = [float(x) for x in section[key].split(",")]
    except KeyError:
        raise LogError(f"{path}: [{section.name}] has no '{key}'") from None
    except ValueError:
        raise LogError(f"{path}: [{section.name}] {key} is not {n} numbers") from None
    if len(vals) != n:
        raise LogError(f"{path}: [{section.name}] {key} has {len(vals)} numbers, not {n}")
    return vals


def read_thruster_map(path: str | Path) -> ThrusterMap:
    """The VSIM engine model of the vehicle a DUNE ``Config.ini`` configures.

    Raises
    ------
    LogError
        Unreadable file, no ``[General] Vehicle Type``, no VSIM model section for it, or
        engines that are not straight-aft thrusters on one line abreast (the only layout
        :class:`~mpcasv.models.ident_thrust.ThrusterMap` represents).
    """
    path = Path(path)
    cp = configparser.ConfigParser(strict=False, interpolation=None)
    try:
        cp.read_string(path.read_text(errors="replace"), str(path))
    except (OSError, configparser.Error) as exc:
        raise LogError(f"{path}: not a readable DUNE configuration ({exc})") from None
    try:
        kind = cp["General"]["Vehicle Type"].strip()
    except KeyError:
        raise LogError(f"{path}: no [General] Vehicle Type") from None
    name = f"VSIM/Model/{kind}"
    if name not in cp:
        raise LogError(f"{path}: no [{name}] (the simulator's model of vehicle type {kind!r})")
    sec = cp[name]
    count = int(_numbers(sec, "Engine Count", 1, path)[0])
    (f_max,) = _numbers(sec, "Engine Max Force", 1, path)
    params = [_numbers(sec, f"Engine Parameters {i}", 3, path) for i in range(count)]
    pos = [_numbers(sec, f"Engine Position {i}", 3, path) for i in range(count)]
    ori = [_numbers(sec, f"Engine Orientation {i}", 2, path) for i in range(count)]
    if any(p != params[0] for p in params) or any(o != [0.0, 0.0] for o in ori) or any(
            p[0] != pos[0][0] for p in pos):  # fmt: skip
        raise LogError(f"{path}: [{name}] engines differ or are not all pointing aft on one "
                       "line abreast: not a layout the thruster map represents")  # fmt: skip
    K_n, K_nu, rpm = params[0]
    return ThrusterMap(
        K_n=K_n, K_nu=K_nu, n_max=rpm / 60.0, F_max=f_max, Q_max=VSIM_MAX_PROP_TORQUE,
        y=tuple(p[1] for p in pos), x=pos[0][0],
        source=f"DUNE {path.name} [{name}]: Engine Parameters {K_n:g}, {K_nu:g}, {rpm:g} RPM; "
        f"Engine Max Force {f_max:g} N; Engine Position y {', '.join(f'{p[1]:g}' for p in pos)} "
        f"m; Engine.hpp c_max_prop_torque {VSIM_MAX_PROP_TORQUE:g} N m",
    )  # fmt: skip
