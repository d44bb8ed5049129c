"""Common random numbers for the acoustic channel and the AUVs' navigation: synchronised
streams, so that two controllers run on the same (scenario, seed) meet the same noise.

A paired comparison (``mpcasv compare``) runs every controller in the same drawn world; its
variance falls when the noise is shared too (common random numbers: Law & Kelton,
*Simulation Modeling and Analysis*, "synchronisation"). Until session 48 one generator drew
ping success, fix errors and status reports in the order they happened: a fix's errors were
drawn only when its ping succeeded, so after the first ping whose outcome differed between two
controllers every later draw was shifted, and from there on the two runs met unrelated noise
(a statistician's review).

Now each AUV ``k`` has three streams, ``SeedSequence(seed, spawn_key=(CHANNEL_STREAM, kind,
k))``, and every event draws the same number of values whether or not they are used:

- **ping** (every USBL ping of AUV ``k``, at its fixed times ``k T0 / n + j T0``): a uniform
  for the ping's success (``< p``), three standard normals for the fix's errors (the slant
  range's, and the angle's across the line of sight and in elevation:
  :func:`mpcasv.models.acoustics.usbl_fix`; before the 3-D geometry the same three were the errors
  along the line of sight, across it and in depth), a uniform for the fix getting back to the
  AUV (``< p``) and the new dead-reckoning interval's draws (two standard normals and a
  uniform, :class:`mpcasv.models.auv_nav.AUVNavFilter`);
- **report** (every status report of AUV ``k``, at ``k T_report / n + i T_report``): a uniform
  for its success;
- **period** (every control period, for every AUV, at the surface or not): two standard
  normals for a GPS fix's error and a dead-reckoning interval's draws after it.

So ping ``j`` of AUV ``k`` succeeds in both runs when its uniform is below both runs'
success probabilities, and then with the same standard errors (scaled by each run's
geometry). The AUVs' first dead-reckoning intervals come from a fourth stream (``kind``
:data:`START`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CHANNEL_STREAM", "ChannelStreams", "PingDraws", "ins_draws"]

#: first spawn key of the channel's streams ("CRN"); the realisations' is
#: :data:`mpcasv.sim.distributions.STREAM_TAG`
CHANNEL_STREAM = 0x43524E
PING, REPORT, PERIOD, START = range(4)


def ins_draws(g: np.random.Generator) -> np.ndarray:
    """A dead-reckoning interval's draws from ``g``, shape (3,): two standard normals and a
    uniform in [0, 1) (:class:`mpcasv.models.auv_nav.AUVNavFilter`)."""
    return np.append(g.standard_normal(2), g.random())


@dataclass(frozen=True)
class PingDraws:
    """One ping's draws (see the module docstring): ``u_ok``, ``u_reach`` uniforms in
    [0, 1); ``z`` shape (3,) standard normals of the fix; ``ins`` shape (3,) the new
    dead-reckoning interval's (two standard normals, one uniform)."""

    u_ok: float
    z: np.ndarray
    u_reach: float
    ins: np.ndarray


class ChannelStreams:
    """The synchronised streams of ``n_auv`` AUVs for ``seed`` (module docstring)."""

    def __init__(self, seed: int, n_auv: int):
        def gen(kind: int, k: int) -> np.random.Generator:
            return np.random.default_rng(
                np.random.SeedSequence(seed, spawn_key=(CHANNEL_STREAM, kind, k)))

        self._ping = [gen(PING, k) for k in range(n_auv)]
        self._report = [gen(REPORT, k) for k in range(n_auv)]
        self._period = [gen(PERIOD, k) for k in range(n_auv)]
        self._start = [gen(START, k) for k in range(n_auv)]

    def start(self) -> np.ndarray:
        """The AUVs' first dead-reckoning intervals' draws, shape (n_auv, 3)."""
        return np.array([ins_draws(g) for g in self._start])

    def ping(self, k: int) -> PingDraws:
        """AUV ``k``'s next ping's draws."""
        g = self._ping[k]
        u_ok, z = g.random(), g.standard_normal(3)
        return PingDraws(u_ok, z, g.random(), ins_draws(g))

    def report(self, k: int) -> float:
        """AUV ``k``'s next status report's success uniform."""
        return float(self._report[k].random())

    def period(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """AUV ``k``'s draws for this control period: a GPS fix's two standard normals and the
        dead-reckoning interval's draws after it, shape (2,) and (3,)."""
        g = self._period[k]
        return g.standard_normal(2), ins_draws(g)
