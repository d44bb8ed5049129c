"""DUNE's FollowReference maneuver, as the SITL ASV runs it (pure logic, no sockets).

Behaviour kept from DUNE's ``Maneuver.FollowReference.AUV`` task (IMC-FACTS.md):

- References are taken only from ``control_src``/``control_ent`` (0xFFFF/0xFF: anyone).
- A field whose flag is unset keeps the previous Reference's value (location, speed, z,
  radius); before any location the vehicle holds where it is.
- State after each Reference: GOTO while the horizontal distance to the location is at least
  ``|radius| + horizontal_tolerance`` (15 m), HOVER inside it (surface target), WAIT before
  the first Reference. HOVER switches the control loops off; so does ``speed == 0``
  (standby, propeller off). A FollowRefState answers every Reference.
- MANDONE ends the maneuver (loops off); no Reference for ``timeout`` s ends it with
  FollowRefState TIMEOUT (loops off).
- Speeds in m/s are used as they are; percent is a fraction of the vessel's top speed; RPM
  is not simulated (such a Reference is refused: the loops stay as they were).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import imcpy
import numpy as np

from mpcasv.io.geo import Origin, to_local

__all__ = ["FollowRefManeuver"]

RF = imcpy.Reference.FlagsBits
FRS = imcpy.FollowRefState
HORIZONTAL_TOLERANCE = 15.0  # m, DUNE's "Horizontal Tolerance"


@dataclass
class _Ref:
    N: float | None = None
    E: float | None = None
    speed: float | None = None  # m/s
    radius: float = 0.0


class FollowRefManeuver:
    """One FollowReference maneuver started by PlanControl at time ``now``.

    Parameters
    ----------
    spec : imcpy.FollowReference
    now : float
        Vehicle clock (s).
    origin : Origin
        The SITL's local frame.
    top_speed : float
        For speeds given in percent (m/s).
    """

    def __init__(self, spec: imcpy.FollowReference, now: float, origin: Origin,
                 top_speed: float) -> None:  # fmt: skip
        self.control_src, self.control_ent = spec.control_src, spec.control_ent
        self.timeout = float(spec.timeout)
        self.origin, self.top_speed = origin, top_speed
        self.last_ref_time = now
        self.ref = _Ref()
        self.got_reference = False
        self.state = FRS.StateEnum.WAIT
        self.proximity = FRS.ProximityBits.FAR
        self.moving = False
        self.done = False  # MANDONE or TIMEOUT: the maneuver is over
        self.ignored = 0

    def allowed(self, msg: imcpy.Reference) -> bool:
        return (self.control_src in (0xFFFF, msg.src)) and (self.control_ent in (0xFF, msg.src_ent))

    def on_reference(self, msg: imcpy.Reference, now: float, asv_NE) -> bool:
        """Take a Reference; False if it was ignored (wrong source, or unsupported units)."""
        if self.done or not self.allowed(msg):
            self.ignored += 1
            return False
        flags = int(msg.flags)
        self.last_ref_time = now
        if flags & RF.MANDONE:
            self.state, self.proximity = FRS.StateEnum.WAIT, FRS.ProximityBits.FAR
            self.moving, self.done = False, True
            return True
        ref = self.ref
        if flags & RF.SPEED and msg.speed is not None:
            units = int(msg.speed.speed_units)
            if units == int(imcpy.SpeedUnits.METERS_PS):
                ref.speed = float(msg.speed.value)
            elif units == int(imcpy.SpeedUnits.PERCENTAGE):
                ref.speed = float(msg.speed.value) / 100.0 * self.top_speed
            else:
                self.ignored += 1
                return False
        if flags & RF.LOCATION:
            ref.N, ref.E, _ = to_local(msg.lat, msg.lon, self.origin.height, self.origin)
        if flags & RF.RADIUS:
            ref.radius = float(msg.radius)
        self.got_reference = True
        N, E = (ref.N, ref.E) if ref.N is not None else (float(asv_NE[0]), float(asv_NE[1]))
        xy = math.hypot(N - asv_NE[0], E - asv_NE[1])
        near = xy < abs(ref.radius) + HORIZONTAL_TOLERANCE
        self.state = FRS.StateEnum.HOVER if near else FRS.StateEnum.GOTO
        self.proximity = (FRS.ProximityBits.XY_NEAR | FRS.ProximityBits.Z_NEAR if near
                          else FRS.ProximityBits.Z_NEAR)  # fmt: skip
        speed = ref.speed if ref.speed is not None else 0.5 * self.top_speed  # DUNE: 50 %
        self.moving = (not near) and speed > 0
        return True

    def check_timeout(self, now: float) -> bool:
        """True (once) when no Reference came for ``timeout`` s: the maneuver fails."""
        if self.done or self.timeout == 0 or now - self.last_ref_time <= self.timeout:
            return False
        self.state, self.moving, self.done = FRS.StateEnum.TIMEOUT, False, True
        return True

    def command_vector(self) -> np.ndarray:
        """``[transit, N_wp, E_wp, U]`` for the execution level (zeros: loops off)."""
        r = self.ref
        if not self.moving or r.N is None:
            return np.zeros(4)
        speed = r.speed if r.speed is not None else 0.5 * self.top_speed
        return np.array([1.0, r.N, r.E, speed])

    def state_message(self, echo: imcpy.Reference | None = None) -> imcpy.FollowRefState:
        m = imcpy.FollowRefState()
        m.control_src, m.control_ent = self.control_src, self.control_ent
        m.state, m.proximity = self.state, self.proximity
        if echo is not None:
            m.reference = echo
        return m
