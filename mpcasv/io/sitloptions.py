"""The options of ``mpcasv sitl`` (:class:`SitlOptions`) and their checks, made before any
output is written or any socket is kept open.

:meth:`SitlOptions.check` refuses, in one line naming the option and the value
(:class:`mpcasv.config.ConfigError`, exit 2): a seed outside ``[0, 2**32 - 1]``; a clock
factor outside ``[SPEEDUP_MIN, SPEEDUP_MAX]`` (a tiny one slept for ever, deaf to SIGTERM;
inf was a traceback); an origin that is not a latitude in [-90, 90] and a longitude in
[-180, 180] degrees; a port above 65535 (the base port plus one port per vehicle above it);
an ASV IMC id equal to an AUV's, or AUV ids past 0xFFFE; an empty ASV name or one equal to
an AUV's; an ``--asv-outage`` whose restart is not after its kill, or whose kill would never
happen: the world checks the outage at the start of each supervisory period, so T0 after the
last period's start (T0 at or past the run's duration, ``--duration`` or the scenario's) or
an outage that holds no period start was silently never applied. :meth:`SitlOptions.check_binds`
then binds (and closes at once) the address and every fixed port the SITL will bind, so that a
foreign address, a host name or a port in use is refused with the option named, before
``--out`` is written.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from mpcasv.config import ConfigError, check_seed
from mpcasv.io.netcheck import PORT_MAX, check_bindable, check_ipv4, check_port

if TYPE_CHECKING:
    from mpcasv.sim.scenario import Scenario

__all__ = ["REACTION", "SPEEDUP_MAX", "SPEEDUP_MIN", "SitlOptions", "check_speedup"]

#: The clock factors accepted (``--speedup`` and the deploy's ``clock.speedup``)
SPEEDUP_MIN, SPEEDUP_MAX = 0.01, 1000.0
#: the default longest wait for the Reference answering a state (periods; ``--reaction``)
REACTION = 0.9
IMC_ID_MAX = 0xFFFE  # 0xFFFF is broadcast


#: what the SITL's AUVs send as EstimatedState (:attr:`SitlOptions.auv_states`)
AUV_STATES = ("radio", "acoustic")
#: the longest ``--usbl-delay`` (s)
USBL_DELAY_MAX = 60.0


def check_speedup(speedup: float, what: str = "--speedup") -> float:
    """``speedup`` if it is a number in ``[SPEEDUP_MIN, SPEEDUP_MAX]``; else ConfigError."""
    if not SPEEDUP_MIN <= speedup <= SPEEDUP_MAX:  # nan fails too
        raise ConfigError(f"{what} {speedup:g}: a clock factor is in [{SPEEDUP_MIN:g}, "
                          f"{SPEEDUP_MAX:g}] (1: real time)")  # fmt: skip
    return speedup


@dataclass(frozen=True)
class SitlOptions:
    """Everything ``mpcasv sitl`` takes besides the scenario (see its ``--help``)."""

    seed: int = 0  # the world's draws and the scenario's realisation, as in mpcasv simulate
    nominal: bool = False  # simulate the scenario's nominal values (no draw from [uncertain])
    speedup: float = 1.0
    bind: str = "127.0.0.1"
    discovery_port: int = 30100
    base_port: int = 0  # vehicle k binds base_port + k (0: any free port)
    origin: tuple[float, float] = (63.4406, 10.3530)  # deg
    duration: float | None = None  # world seconds (default: the scenario's)
    hold: bool = False
    reaction: float | None = None  # longest wait for a Reference, periods (None: REACTION)
    lockstep: bool = False  # wait for the answering Reference however long it takes
    reanchor_m: float = 1000.0
    asv_name: str = "sitl-asv"
    asv_id: int = 0x2801
    auv_id_base: int = 0x2811
    tcp: bool = False
    asv_outage: tuple[float, float] | None = None
    out: Path = Path("runs/sitl")
    plots: bool = False
    ready_file: Path | None = None
    #: the AUVs' EstimatedStates: ``radio`` at 2 Hz (at the surface, as DUNE over Wi-Fi), or
    #: ``acoustic``: so until the ASV's first Reference (the AUVs dive as the operation
    #: starts), then only the world's status reports that got through (under water: position
    #: with the AUV's own navigation error), stamped at theirs
    auv_states: str = "radio"
    #: world seconds between a USBL fix and the ASV's sending of it, stamped at the fix's own
    #: time (DUNE's processing and the network: AUV states stamped later may come first)
    usbl_delay: float = 0.0

    @staticmethod
    def auv_name(name: str) -> str:
        """The IMC system name of the scenario's AUV ``name``."""
        return f"sitl-{name}"

    def periods(self, scenario: Scenario) -> int:
        """The supervisory periods the world runs: ``duration`` (default the scenario's) in
        periods of ``scenario.sim.control_period``, a partial last one counted whole. With
        ``hold`` the world waits at t = 0 for the first Reference and then runs as many."""
        duration = self.duration or scenario.duration
        return int(math.ceil(duration / scenario.sim.control_period - 1e-9))

    @property
    def wait_periods(self) -> float:
        """The longest wait for the Reference answering a state (periods): ``reaction``, by
        default :data:`REACTION` (not read with ``lockstep``, which waits however long)."""
        return REACTION if self.reaction is None else self.reaction

    def check(self, scenario: Scenario) -> SitlOptions:
        """Refuse impossible values (see the module docstring) for ``scenario`` (its AUVs, its
        duration and control period); nothing is bound or written. Returns ``self``."""
        auv_names = [a.name for a in scenario.auv]
        if self.reaction is not None and self.lockstep:
            raise ConfigError(f"--reaction {self.reaction:g} has no effect with --lockstep, "
                              "which waits for every answering Reference however long it "
                              "takes: give one of them")  # fmt: skip
        if not 0 <= self.wait_periods < 1:  # nan fails too
            raise ConfigError(f"--reaction must be in [0, 1) periods, got {self.reaction}")
        check_seed(self.seed, "--seed")
        check_speedup(self.speedup)
        lat, lon = self.origin
        if not (-90 <= lat <= 90 and -180 <= lon <= 180):  # nan fails too
            raise ConfigError(f"--origin {lat:g},{lon:g}: 'lat,lon' in degrees, latitude in "
                              "[-90, 90] and longitude in [-180, 180]")  # fmt: skip
        if not 0 <= self.usbl_delay <= USBL_DELAY_MAX:  # nan fails too
            raise ConfigError(f"--usbl-delay {self.usbl_delay:g}: seconds in [0, "
                              f"{USBL_DELAY_MAX:g}] (a fix later than that is no fix to steer "
                              "by)")  # fmt: skip
        if self.auv_states not in AUV_STATES:
            raise ConfigError(f"--auv-states {self.auv_states!r}: one of {', '.join(AUV_STATES)}")
        check_ipv4(self.bind, "--bind")
        check_port(self.discovery_port, "--discovery-port")
        n = len(auv_names)
        check_port(self.base_port, "--base-port", PORT_MAX - n,
                   f"vehicle k binds base + k, and there are {1 + n} vehicles")  # fmt: skip
        if self.auv_id_base + n - 1 > IMC_ID_MAX:
            raise ConfigError(f"--auv-id-base 0x{self.auv_id_base:04X}: the {n} AUVs take ids "
                              f"up to 0x{self.auv_id_base + n - 1:04X}, past 0xFFFE")  # fmt: skip
        if self.auv_id_base <= self.asv_id < self.auv_id_base + n:
            k = self.asv_id - self.auv_id_base
            raise ConfigError(f"--asv-id 0x{self.asv_id:04X} ({self.asv_id}): the IMC id of AUV "
                              f"{k} ({self.auv_name(auv_names[k])}; --auv-id-base "
                              f"0x{self.auv_id_base:04X}); every system needs its own id")
        if not self.asv_name.strip():
            raise ConfigError(f"--asv-name {self.asv_name!r}: an IMC system name cannot be empty")
        if self.asv_name in {self.auv_name(a) for a in auv_names}:
            raise ConfigError(f"--asv-name {self.asv_name!r}: the name of an AUV; every system "
                              "needs its own name")  # fmt: skip
        if self.asv_outage is not None:
            t0, t1 = self.asv_outage
            if not (0 <= t0 < t1 < math.inf):  # nan fails too
                raise ConfigError(f"--asv-outage {t0:g},{t1:g}: 'T0,T1' kills the ASV at world "
                                  "time T0 and restarts it at T1: 0 <= T0 < T1, finite")
            self._check_outage_happens(scenario)
        return self

    def _check_outage_happens(self, scenario: Scenario) -> None:
        """ConfigError if no period start (k Tc, k < :meth:`periods`) lies in [T0, T1): the
        SITL kills the ASV at the first one at or after T0 (:meth:`Sitl.run`), so without one
        the outage was silently never applied. ``--hold`` changes nothing: the world's time
        stays at 0 while held and then runs the same periods."""
        t0, t1 = self.asv_outage
        tc = scenario.sim.control_period
        n = self.periods(scenario)
        k = math.ceil(t0 / tc - 1e-9)  # the period start at which the ASV is killed
        given = f"--asv-outage {t0:g},{t1:g}"
        if k >= n:
            dur = (f"--duration {self.duration:g}" if self.duration
                   else f"the duration of scenario {scenario.name}")  # fmt: skip
            raise ConfigError(f"{given}: the run lasts {self.duration or scenario.duration:g} s "
                              f"of world time ({dur}) and the ASV is killed at the first period "
                              f"start (every {tc:g} s) at or after T0, the last being "
                              f"{(n - 1) * tc:g} s: it would never be killed; give T0 <= "
                              f"{(n - 1) * tc:g}")  # fmt: skip
        if k * tc >= t1 - 1e-9:
            raise ConfigError(f"{given}: the ASV is killed at the first period start (every "
                              f"{tc:g} s) at or after T0, {k * tc:g} s, which is not before T1:"
                              " it would never be killed; give an outage that holds a period "
                              "start")  # fmt: skip

    def check_binds(self, n_auv: int) -> None:
        """Bind (and close) ``--bind`` with ``--discovery-port`` and each vehicle's UDP port
        (``--base-port`` + k; port 0 only tries the address); ConfigError naming the option."""
        check_bindable(self.bind, self.discovery_port, "--bind/--discovery-port")
        if not self.base_port:
            check_bindable(self.bind, 0, "--bind")
            return
        for k in range(1 + n_auv):
            check_bindable(self.bind, self.base_port + k,
                           "--bind/--base-port" + (f" (+{k}: AUV {k - 1})" if k else ""))
