"""The deploy configuration (TOML), validated up front into frozen dataclasses.

One file says who we are on the IMC network, which vehicles to talk to (by IMC id and/or
system name, with their roles), the local frame's origin, the link (UDP or DUNE's TCP
backseat port), the controller and its preset, the watchdog limits, the clock and the log
folder. Unknown keys, missing fields, wrong types and impossible numbers are refused with
the file and field named (:class:`mpcasv.config.ConfigError`). The sections about the run
itself (controller, clock, log) are in :mod:`mpcasv.io.config_run`, the limits (watchdog,
speed) in :mod:`mpcasv.io.config_limits`. Example files:
``experiments/deploy/sitl-case3.toml`` and ``sitl-case6.toml``; field by field in
``docs/deploy.md``.
"""

from __future__ import annotations

import ipaddress
from pathlib import Path
from typing import Annotated, Literal

from pydantic import AfterValidator, Field, Strict, field_validator, model_validator

from mpcasv.config import (
    AUV_COUNT_MAX,
    REFERENCE_LEAD_MAX,
    ConfigError,
    FieldError,
    Float,
    NonNeg,
    between,
    frozen,
    load_toml,
    parse,
)
from mpcasv.io.config_limits import SpeedSpec, WatchdogSpec
from mpcasv.io.config_run import ClockSpec, ControllerSpec, LogSpec
from mpcasv.io.deploycontroller import (
    MIN_SOLVE_MS,
    build_controller,
    check_controller,
    check_field_budget,
    controller_overrides,
    deploy_boat,
)
from mpcasv.io.netcheck import is_wildcard
from mpcasv.models.acoustics import AcousticParams

__all__ = [  # the controller's part is mpcasv.io.deploycontroller's, re-exported
    "MIN_SOLVE_MS", "DeployConfig", "build_controller", "check_controller",
    "check_field_budget", "controller_overrides", "deploy_boat", "deploy_config_from_dict",
    "DISCOVERY", "UDP_ONLY", "check_link", "load_deploy_config", "parse_address",
    "SpeedSpec", "WatchdogSpec",  # (mpcasv.io.config_limits)
]  # fmt: skip

#: An IMC system id (0xFFFF is broadcast, never a vehicle).
ImcId = Annotated[int, Strict(), Field(ge=0, le=0xFFFE)]
#: IMC's special system ids (LSTS/imc IMC_Addresses.xml) below 0xFFFF: never ours
IMC_SPECIAL_IDS = {0x0000: "'announce' (DUNE addresses its Announces to it)",
                   0xFFF0: "'broadcast'"}  # fmt: skip
Port = Annotated[int, Strict(), Field(ge=0, le=65535)]
#: ``link.plan_id``: DUNE's plan engine names the vehicle's log folder after it (changeLog)
#: and the operator's console shows it; "" was accepted
PLAN_ID_MAX = 64
#: ``[link]`` fields read only with ``transport = "udp"``: the TCP backseat link binds no
#: data port, sends no Announce and opens no discovery socket (:meth:`ImcLink.start`)
UDP_ONLY = ("port", "announce_to", "announce_period", "discovery_ports", "discovery_group",
            "discovery_bind")  # fmt: skip
#: ``[link]`` fields read only with ``transport = "udp"`` and a vehicle without ``address``
#: (learnt from its Announce, heard on the discovery ports)
DISCOVERY = ("discovery_ports", "discovery_group", "discovery_bind")


def parse_address(text: str) -> tuple[str, int]:
    """``"host:port"`` (IPv4 literal, port 1-65535) -> ``(host, port)``; ValueError if not."""
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit():
        raise ValueError(f"{text!r} is not 'IPv4:port'")
    try:
        ipaddress.IPv4Address(host)
    except ValueError:
        raise ValueError(f"{text!r}: {host!r} is not an IPv4 address") from None
    if not 0 < int(port) < 65536:
        raise ValueError(f"{text!r}: port must be 1-65535")
    return host, int(port)


def _system_name(v: str | None) -> str | None:
    if v is not None and not v.strip():
        raise ValueError(f"{v!r}: an IMC system name cannot be empty (omit the field to use "
                         "the default or, for a vehicle, its id alone)")  # fmt: skip
    return v


def _plan_id(v: str) -> str:
    ok = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789-_.")
    if not 0 < len(v) <= PLAN_ID_MAX or not set(v) <= ok:
        shown = repr(v) if len(v) <= PLAN_ID_MAX else f"{v[:20]!r}... ({len(v)} characters)"
        raise ValueError(f"{shown}: a plan id is 1-{PLAN_ID_MAX} letters, digits, '-', '_' or "
                         "'.' (DUNE's plan engine names the vehicle's log folder after it)")
    return v


def _check_address(v: str | None) -> str | None:
    if v is not None:
        parse_address(v)
    return v


@frozen
class Identity:
    """Who the deploy loop is on the IMC network (announced as a CCU)."""

    name: str = "mpcasv-deploy"
    id: ImcId = 0x4001

    _name = field_validator("name")(_system_name)

    @field_validator("id")
    @classmethod
    def _id(cls, v: int) -> int:
        if v in IMC_SPECIAL_IDS:
            raise ValueError(f"0x{v:04X} is IMC's special id {IMC_SPECIAL_IDS[v]}, not a "
                             "system's: take a free one (e.g. 0x4001)")  # fmt: skip
        return v


@frozen
class OriginSpec:
    """Origin of the local NED frame the controller works in (degrees, metres)."""

    lat_deg: Annotated[float, Strict(), Field(ge=-90, le=90)]
    lon_deg: Annotated[float, Strict(), Field(ge=-180, le=180)]
    height: Float = 0.0


@frozen
class Vehicle:
    """One vehicle: its role and IMC id and/or system name (both given: both must match).

    ``address`` (``"IPv4:port"`` of its IMC UDP service) is optional: by default it is learnt
    from the vehicle's Announce. ``tcp`` is its backseat server for ``link.transport = "tcp"``
    (refused with ``"udp"``, which would not read it; ``address`` is refused with ``"tcp"``).
    """

    role: Literal["asv", "auv"]
    id: ImcId | None = None
    name: str | None = None
    address: str | None = None
    tcp: str | None = None

    _name = field_validator("name")(_system_name)

    @field_validator("address", "tcp")
    @classmethod
    def _addr(cls, v: str | None) -> str | None:
        return _check_address(v)

    @model_validator(mode="after")
    def _named(self) -> Vehicle:
        if self.id is None and not self.name:
            raise ValueError("a vehicle needs an 'id' or a 'name' (or both)")
        return self

    @property
    def label(self) -> str:
        return self.name or f"0x{self.id:04X}"


@frozen
class LinkSpec:
    """Transport, addresses and the IMC timing (seconds of the deploy clock)."""

    transport: Literal["udp", "tcp"] = "udp"
    # the one local address we bind; 0.0.0.0 (every one) needs every vehicle's 'address': our
    # Announce then names the address each vehicle sees us from (netcheck.announced_hosts)
    bind: str = "127.0.0.1"
    port: Port = 6002  # 0: any free port (tests)
    announce_to: tuple[str, ...] = (
        "224.0.75.69:30100", "224.0.75.69:30101", "224.0.75.69:30102",
        "224.0.75.69:30103", "224.0.75.69:30104",
    )  # fmt: skip
    # DUNE's UDP transport streams to a system only while it has heard from it within its
    # contact timeout (Transports.UDP "Contact Timeout", 30 s, checked every 5 s); while the
    # deploy waits or the ASV is stale, the Heartbeat is all it sends: 60 s stopped the
    # streaming 30 s after each one. At most 10 s: three per timeout, two may be lost. At
    # least 0.1 s: DUNE's own is 1 Hz; faster floods the link (0.0001 s was accepted)
    heartbeat_period: between(0.1, 10, "s", "DUNE's UDP transport stops streaming to a "
                              "system not heard from for 30 s (its Contact Timeout): keep three "
                              "Heartbeats within it; DUNE's own is 1 s") = 1.0
    # DUNE takes datagrams only from systems whose Announce it has heard; a restarted DUNE
    # knows nobody until our next one. DUNE announces every 10 s (Transports.Announce)
    announce_period: between(1, 60, "s", "a restarted DUNE takes nothing from us until our "
                             "next Announce: a minute at most; DUNE's own is 10 s") = 10.0
    # FollowReference.timeout: DUNE ends the maneuver after it without a Reference (its own
    # stop if we go silent; 1e5 s switched it off)
    followref_timeout: between(1, 300, "s", "DUNE's own stop when the deploy goes silent: "
                               "minutes switch it off") = 10.0
    # DUNE answers every Reference with a FollowRefState while FollowReference runs: one left
    # unanswered this long means the maneuver ended without a word to us (an operator's stop
    # is answered to the operator): event followref_lost, the run stops (nothing restarted)
    followref_lost_s: between(1, 300, "s", "DUNE answers each Reference within milliseconds; "
                              "minutes without an answer is no watchdog") = 5.0
    plan_id: Annotated[str, Strict(), AfterValidator(_plan_id)] = "mpcasv-followref"
    # wait this long for PlanControl SUCCESS, then retry (checked every watchdog tick: 1e-4 s
    # re-sent START at every tick, 1e9 s never retried a lost one)
    plan_start_timeout: between(1, 60, "s", "DUNE answers a START within a second or two; "
                                "shorter re-sends it before the answer can come, longer "
                                "leaves a lost one unretried for minutes") = 5.0
    # push the Reference past DUNE's arrival tolerance
    reference_lead_m: between(0, REFERENCE_LEAD_MAX, "m", "a lead beyond 1 km is no waypoint, "
                              "as a scenario's [sim] reference_lead_m") = 20.0
    reference_radius_m: NonNeg = 0.0  # Reference.radius (DUNE arrives at |radius| + 15 m)
    # DUNE announces only to its discovery ports (multicast and loopback), never to our data
    # port: a vehicle without 'address' is learnt there. Opened only if such a vehicle exists.
    # On the vehicles' own host leave DUNE its ports (it binds the first free of 30100-30104
    # without SO_REUSEADDR): e.g. [30103, 30104] with two DUNEs. () = data port only.
    discovery_ports: tuple[Port, ...] = (30100, 30101, 30102, 30103, 30104)
    discovery_group: str = "224.0.75.69"  # joined on the interface of 'bind'
    discovery_bind: str | None = None  # None: 0.0.0.0, or 'bind' if that is a loopback address
    # at shutdown, wait this long for PlanControl "plan completed" (1e9 s never ended)
    plan_done_timeout: between(0.1, 60, "s", "DUNE answers MANDONE at once; a shutdown that "
                               "waits minutes for it is no shutdown") = 3.0

    @field_validator("discovery_ports")
    @classmethod
    def _ports(cls, v: tuple[int, ...]) -> tuple[int, ...]:
        if 0 in v:
            raise ValueError("0 (a port the OS picks) is no discovery port: DUNE announces "
                             "only to 30100-30104")  # fmt: skip
        twice = sorted({p for p in v if v.count(p) > 1})
        if twice:
            raise ValueError(f"{', '.join(map(str, twice))} given twice: each port is opened "
                             "once (a second socket on it hears every Announce again)")
        return v

    @field_validator("bind", "discovery_group")
    @classmethod
    def _bind(cls, v: str) -> str:
        ipaddress.IPv4Address(v)
        return v

    @field_validator("discovery_bind")
    @classmethod
    def _dbind(cls, v: str | None) -> str | None:
        if v is not None:
            ipaddress.IPv4Address(v)
        return v

    @property
    def discovery_host(self) -> str:
        if self.discovery_bind is not None:
            return self.discovery_bind
        return self.bind if ipaddress.IPv4Address(self.bind).is_loopback else "0.0.0.0"

    @field_validator("announce_to")
    @classmethod
    def _announce(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        for a in v:
            parse_address(a)
        return v


@frozen
class DeployConfig:
    """A complete deploy configuration (see the module docstring)."""

    origin: OriginSpec
    controller: ControllerSpec
    vehicle: tuple[Vehicle, ...]
    identity: Identity = Identity()
    link: LinkSpec = LinkSpec()
    watchdog: WatchdogSpec = WatchdogSpec()
    speed: SpeedSpec = SpeedSpec()
    clock: ClockSpec = ClockSpec()
    log: LogSpec = LogSpec()
    # the acoustic channel of the operation (USBL and modem; a scenario's [acoustics] fields):
    # the MPC's fix-rate model plans with it (the run's Boat, as in simulation)
    acoustics: AcousticParams = AcousticParams()

    @model_validator(mode="after")
    def _timeout(self) -> DeployConfig:
        Tc = self.controller.control_period
        if self.link.followref_timeout < 2 * Tc:  # one late or skipped tick must not end it
            raise FieldError("link.followref_timeout", (
                f"{self.link.followref_timeout:g} s is shorter than two controller."
                f"control_period = {Tc:g} s: DUNE would end the maneuver after one late or "
                "skipped decision"))  # fmt: skip
        lost = self.link.followref_lost_s
        if lost < 2 * Tc:  # a Reference goes every period: one lost answer must not end it
            raise FieldError("link.followref_lost_s", (
                f"{lost:g} s is shorter than two controller.control_period = {Tc:g} s: one lost "
                "FollowRefState answer would end the run"))  # fmt: skip
        return self

    @model_validator(mode="after")
    def _vehicles(self) -> DeployConfig:
        roles = [v.role for v in self.vehicle]
        if roles.count("asv") != 1:
            raise ValueError(f"exactly one vehicle with role 'asv' is needed, got {roles}")
        if "auv" not in roles:
            raise ValueError("at least one vehicle with role 'auv' is needed")
        if roles.count("auv") > AUV_COUNT_MAX:
            raise FieldError("vehicle", f"{roles.count('auv')} vehicles with role 'auv': at most "
                             f"{AUV_COUNT_MAX}, as in a scenario (docs/experiments.md, "
                             "'Bounds')")  # fmt: skip
        seen: dict[str, str] = {}  # UDP: the link tells the vehicles apart by address
        for k, v in enumerate(self.vehicle):
            if v.address is not None and v.address in seen:
                raise FieldError(f"vehicle.{k}.address", (
                    f"{v.address} is also {seen[v.address]}'s: each DUNE has its own port, "
                    "and from a vehicle's address another system's id is a relay"))  # fmt: skip
            if v.address is not None:
                seen[v.address] = v.label
        ids = [v.id for v in self.vehicle if v.id is not None]
        names = [v.name for v in self.vehicle if v.name]
        if len(set(ids)) != len(ids) or len(set(names)) != len(names):
            raise ValueError("vehicle ids and names must be unique")
        if self.identity.id in ids or self.identity.name in names:
            raise ValueError("identity.id / identity.name clash with a vehicle")
        if self.link.transport == "tcp" and any(v.tcp is None or v.id is None
                                                for v in self.vehicle):  # fmt: skip
            raise ValueError("link.transport = 'tcp' needs 'tcp' and 'id' for every vehicle")
        unaddressed = [v.label for v in self.vehicle if v.address is None]
        if self.link.transport == "udp" and is_wildcard(self.link.bind) and unaddressed:
            raise FieldError("link.bind", (
                f"{self.link.bind} (every local address) needs every vehicle's 'address' (not "
                f"given for {', '.join(unaddressed)}): DUNE streams only to the imc+udp address "
                "of our Announce that our datagrams come from, which is told from a vehicle's "
                "address, and keeps the services of our first Announce; give them, or bind to "
                "this host's address on the vehicles' network"))  # fmt: skip
        return self  # the fields the transport does not read: check_link

    @property
    def asv(self) -> Vehicle:
        return next(v for v in self.vehicle if v.role == "asv")

    @property
    def auvs(self) -> tuple[Vehicle, ...]:
        """The AUVs in file order: AUV k of the controller is the k-th ``role = "auv"``."""
        return tuple(v for v in self.vehicle if v.role == "auv")


def load_deploy_config(path: str | Path) -> DeployConfig:
    """Load and validate a deploy TOML file; also checks controller, preset and estimator
    names now, so that nothing fails after the vehicles have been contacted."""
    return deploy_config_from_dict(load_toml(path, "deploy"), path)


def deploy_config_from_dict(data: dict, source: str | Path = "<deploy config>") -> DeployConfig:
    """Validate a deploy configuration given as a mapping (a TOML file's tables), with the
    checks of :func:`load_deploy_config`; ``source`` names it in the messages."""
    cfg = parse(DeployConfig, data, source)
    link = data.get("link")
    check_link(cfg, frozenset(link if isinstance(link, dict) else ()), source)
    watchdog = data.get("watchdog")
    check_controller(cfg, source, frozenset(watchdog if isinstance(watchdog, dict) else ()))
    return cfg


def check_link(cfg: DeployConfig, link_set, source: str | Path) -> None:
    """Refuse, in one line, every link field written in the file that the run would never
    read (``link_set``: the ``[link]`` keys written; a vehicle's ``address`` and ``tcp`` are
    None unless written). Defaults are never refused.

    - ``transport = "tcp"``: the :data:`UDP_ONLY` ``[link]`` fields and a vehicle's
      ``address`` (the link connects to each vehicle's ``tcp`` backseat server: it binds no
      data port, sends no Announce and opens no discovery socket);
    - ``transport = "udp"``: a vehicle's ``tcp``, and the :data:`DISCOVERY` fields when every
      vehicle has an ``address`` (nobody to discover: no discovery socket is opened,
      :meth:`mpcasv.io.link.ImcLink.start`).

    The advice works as given: removing the fields named loads the file.

    Raises
    ------
    ConfigError
        One line naming ``source``, every unread field, why, and what to do.
    """
    link = [f for f in UDP_ONLY if f in link_set]
    address = [v.label for v in cfg.vehicle if v.address is not None]
    tcp = [v.label for v in cfg.vehicle if v.tcp is not None]
    found = [f"link.{f}" for f in DISCOVERY if f in link_set]  # unread if all addressed
    all_addressed = len(address) == len(cfg.vehicle)
    groups, other = [], None  # (fields, why they are not read); the other transport's advice
    if cfg.link.transport == "tcp":
        fields = [f"link.{f}" for f in link]
        fields += [f"vehicle.address (of {', '.join(address)})"] if address else []
        n = len(link) + len(address)  # fields named, a vehicle's each
        if fields:
            groups.append((fields, "not read with link.transport = 'tcp' (the link connects "
                           "to each vehicle's 'tcp' backseat server: it binds no data port, "
                           "sends no Announce, opens no discovery port and sends nothing to a "
                           "vehicle's UDP 'address')"))  # fmt: skip
            also = (f" and {', '.join(found)} (every vehicle has an 'address')"
                    if found and all_addressed else "")  # fmt: skip
            other = f"to use UDP instead, set link.transport = 'udp' and remove every 'tcp'{also}"
    else:
        n = len(tcp)
        if tcp:
            groups.append(([f"vehicle.tcp (of {', '.join(tcp)})"], "read only with "
                           "link.transport = 'tcp' (the transport is 'udp')"))  # fmt: skip
            drop = [*(["every 'address'"] if address else []), *(f"link.{f}" for f in link)]
            other = ("to use DUNE's TCP backseat instead, set link.transport = 'tcp' and give "
                     "every vehicle a 'tcp' and an 'id'"
                     + (f", and remove {', '.join(drop)}" if drop else ""))  # fmt: skip
        if found and all_addressed:
            groups.append((found, "not read when every vehicle has an 'address' (nobody to "
                           "discover: the link opens no discovery socket)"))  # fmt: skip
            n += len(found)
    if not groups:
        return
    text = "; ".join(f"{', '.join(f)}: {why}" for f, why in groups)
    raise ConfigError(f"{source}: {text}: remove {'it' if n == 1 else 'them'}"
                      + (f" (or, {other})" if other else ""))
