"""``mpcasv replay``: re-run a controller over a deploy log and show where it would differ.

The deploy log (``deploy.jsonl``) holds, for every decision, the exact Observation the
controller was given (estimates already inflated by the watchdogs), the watchdogs' verdicts
and the command sent. Replay builds the controller named in the log (or another one / another
preset) for the boat the deploy drove (the logged ``controller.vessel`` and ``[acoustics]``:
:func:`mpcasv.io.deploycontroller.field_boat`, as the deploy built it), feeds it the same
Observations in order, applies the guard with the logged verdicts (the logged guard, or the
replayed controller's built as the deploy builds it) and compares command by command
(:func:`mpcasv.io.records.same_command`; the table has both speeds). The deploy's speed caps
are replayed as logged: each decision with the ``controller.speed_feedback`` cap it saw
(:func:`replay` says how an older log's are placed), and every transit command capped as the
deploy capped it (that cap, the speed asked at it and ``speed.command_max``:
:func:`mpcasv.io.deployfeedback.cap_command`).
The logged ``controller.overrides`` were written for the logged controller and preset: they
are applied only when replaying those, and the report says so when they are left out.
Replaying with the logged controller must reproduce every decision; anything else points at
non-determinism or a changed controller.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import pandas as pd

from mpcasv.config import ConfigError, parse, resolve
from mpcasv.controllers import make_controller, preset_used
from mpcasv.interface import Mode
from mpcasv.io.config import WatchdogSpec
from mpcasv.io.deploycontroller import field_boat, refuse_simulation_only
from mpcasv.io.deployfeedback import cap_command, cap_controller_speed
from mpcasv.io.deploystep import guard_params
from mpcasv.io.logs import read_jsonl_cut
from mpcasv.io.records import cmd_from_dict, obs_from_dict, same_command
from mpcasv.io.watchdog import GuardParams, guard
from mpcasv.models.acoustics import AcousticParams

__all__ = ["ReplayReport", "logged_boat", "print_replay", "replay"]


@dataclass
class ReplayReport:
    """The comparison: one row per logged decision."""

    log: Path
    controller: str
    preset: str  # the preset replayed with (given, logged, else the controller's default)
    table: pd.DataFrame  # t, logged/replayed mode, reason, auv, waypoint distance, same
    notes: tuple[str, ...] = ()  # what the replay did differently from a plain re-run, said

    @property
    def n_steps(self) -> int:
        return len(self.table)

    @property
    def n_differ(self) -> int:
        return int((~self.table["same"]).sum()) if len(self.table) else 0


def _log_path(log: str | Path) -> Path:
    p = Path(log)
    if p.is_dir():
        p = p / "deploy.jsonl"
    if not p.is_file():
        raise ConfigError(f"{log}: no deploy log (deploy.jsonl) there")
    with p.open("rb") as fh:
        head = fh.read(4096)
    binary = head[:2] in (b"\x1f\x8b", b"\x54\xfe", b"\xfe\x54")  # gzip, IMC sync
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as exc:
        binary = binary or exc.start < len(head) - 4  # not a multi-byte char cut at 4096
    if binary:
        raise ConfigError(f"{log}: not a deploy log (deploy.jsonl, JSON lines); an IMC/LSF "
                          "log? (replay reads the deploy.jsonl beside imc.lsf)")  # fmt: skip
    return p


def logged_boat(cfg: dict, source: str | Path = "<deploy log>"):
    """The boat a deploy drove, from the configuration its log records (``controller.vessel``,
    ``acoustics``; absent: Gretha, the default channel) as the deploy built it
    (:func:`~mpcasv.io.deploycontroller.field_boat`).

    Raises
    ------
    ConfigError
        The logged vessel cannot be loaded, or the logged acoustics are invalid.
    """
    acoustics = parse(AcousticParams, cfg.get("acoustics") or {}, f"{source}: acoustics")
    vessel = cfg["controller"].get("vessel")
    try:
        return field_boat(vessel, acoustics)
    except ConfigError as exc:  # say where the name came from (a path relative to the deploy's
        raise ConfigError(f"{source}: the logged controller.vessel {vessel!r}: {exc} (a "
                          "relative path is the deploy's: replay from its folder)") from None


def _preset_named(name: str, preset: str | None) -> str:
    """The preset of controller ``name`` as a note names it: ``"preset P"`` with P the preset
    used (:func:`preset_used`); for a controller this version does not know (a log's older
    name: nothing of it is built) the logged preset, else ``"its default preset"``."""
    try:
        return f"preset {preset_used(name, preset)}"
    except ConfigError:
        return f"preset {preset}" if preset else "its default preset"


def _same_preset(name: str, a: str | None, b: str | None) -> bool:
    """Whether presets ``a`` and ``b`` of controller ``name`` are the same file: a shipped
    name and its path are (``replay --preset`` with the logged preset's path dropped the
    logged overrides as if it were another: a new user's finding, session 41)."""
    pa, pb = preset_used(name, a), preset_used(name, b)
    if pa == pb:
        return True
    try:
        return resolve("presets", pa).resolve() == resolve("presets", pb).resolve()
    except ConfigError:  # one is no file this version can find: not the same
        return False


def _cap_of(event: dict) -> float:
    """The cap a ``controller_speed_cap`` event applied: the plan's, else the new speed (a
    cap is applied only below the controller's speed, so new = the cap)."""
    return float(event["plan"] if event.get("plan") is not None else event["new"])


def _cap(ctl, cap: float, base: float | None) -> None:
    """Cap ``ctl`` at ``cap`` as the deploy did (:func:`cap_controller_speed`; ``base``: its
    speed before any cap); a controller without a ``speed`` gets the cap on its commands
    only."""
    if base is not None:
        cap_controller_speed(ctl, cap, base)


def replay(log: str | Path, controller: str | None = None, preset: str | None = None,
           tol_m: float = 0.5) -> ReplayReport:  # fmt: skip
    """Replay the decisions of a deploy log (see the module docstring).

    The guard: the logged one when replaying the logged controller and preset; else the
    replayed controller's, built as the deploy builds it (:func:`~mpcasv.io.deploystep.
    guard_params`, its keep-out sphere and speed, with the logged ``[watchdog]`` values).

    The speed caps: a step record of a deploy since the cap is applied between steps holds
    the cap its decision saw (``speed_cap``: its controller capped before the step started,
    its command capped at it), and the replay applies exactly that. An older log's step
    records do not: its caps are then taken in time order for the controller (a
    ``controller_speed_cap`` event counts for a step whose decision began, its ``clock``,
    at or after the event's ``t``: a cap that came while a field-mode step was solving is
    not seen by that step) and in log order for the commands (the older deploy capped a
    command with the cap in force when it was sent).
    """
    path = _log_path(log)
    records, cut = read_jsonl_cut(path)  # one reading: the records and a cut last line
    started = [r for r in records if r.get("kind") == "event" and r.get("event") == "started"]
    steps = [r for r in records if r.get("kind") == "step"]
    if not started or "config" not in started[0]:
        raise ConfigError(f"{path}: no 'started' record with the configuration")
    if not steps:
        raise ConfigError(f"{path}: no decisions logged")
    cfg = started[0]["config"]
    c = cfg["controller"]
    name = controller or c["name"]
    preset = preset or (c["preset"] if name == c["name"] else None)
    # the logged controller and preset: the deploy's overrides and guard are theirs (the
    # logged preset is resolved only for a controller of that name: one this version knows)
    same = name == c["name"] and _same_preset(name, preset, c["preset"])
    notes = []
    if cut:  # a cut log replayed without a word (a new user, session 43)
        notes.append("the log's last line is cut (the deploy ended mid-write: killed, or the "
                     "host lost power): replayed up to it")  # fmt: skip
    if not any(r.get("kind") == "summary" for r in records):
        notes.append("the log has no 'summary' record: the deploy did not end normally "
                     "(killed or crashed), or it is still running")  # fmt: skip
    if not same and c["overrides"]:
        notes.append(f"the logged controller.overrides {c['overrides']} are not applied: they "
                     f"were written for {c['name']} with "
                     f"{_preset_named(c['name'], c['preset'])}")  # fmt: skip
    n_auv = len(steps[0]["obs"]["auvs"])
    ctl = make_controller(name, n_auv, preset, c["overrides"] if same else None,
                          boat=logged_boat(cfg, path))  # fmt: skip
    # a deploy log has no true current; an older one no USBL fix times
    refuse_simulation_only(ctl, name, usbl_fixes="usbl_fix_times" in steps[0]["obs"])
    ctl.reset(n_auv)
    if same:
        gp = GuardParams(**started[0]["guard"])
    else:  # the replayed controller's guard, as the deploy would have built it
        if not isinstance(cfg.get("watchdog"), dict):
            raise ConfigError(f"{path}: no logged [watchdog] values (the guard of another "
                              "controller or preset is built from them)")  # fmt: skip
        gp = guard_params(_logged_watchdog(cfg["watchdog"], path, notes), ctl)
    command_max = (cfg.get("speed") or {}).get("command_max")
    speed = getattr(getattr(ctl, "params", None), "speed", None)
    base = None if speed is None else float(speed)  # before any cap
    t0 = steps[0]["clock"]
    cmd_cap = ctl_cap = None  # the cap on the commands, the cap applied to the controller
    pending, caps = [], []  # an older log's caps not yet applied to the controller; notes
    rows = []
    for s in records:  # in the order the deploy wrote them
        if s.get("kind") == "event" and s.get("event") == "controller_speed_cap":
            cap = _cap_of(s)
            pending.append((s["t"], cap))
            cmd_cap = cap
            dt = s["t"] - t0
            caps.append(f"{cap:g} m/s {abs(dt):.1f} s {'after' if dt >= 0 else 'before'} "
                        "the first decision")  # fmt: skip
            continue
        if s.get("kind") != "step":
            continue
        if "speed_cap" in s:  # the cap this decision saw, recorded by the deploy
            cmd_cap = s["speed_cap"]
            if cmd_cap is not None and cmd_cap != ctl_cap:
                _cap(ctl, cmd_cap, base)
                ctl_cap = cmd_cap
        else:  # an older log: the caps that came before the decision began
            while pending and pending[0][0] <= s["clock"]:
                _cap(ctl, pending.pop(0)[1], base)
        obs = obs_from_dict(s["obs"])
        raw = ctl.step(obs)
        cmd, override = guard(raw, obs, s["status"], s["ages"], gp)
        cmd = cap_command(cmd, cmd_cap, command_max, s.get("speed_ask"))[0]  # None: older logs
        logged = cmd_from_dict(s["cmd"])
        dist = float("nan")
        if cmd.waypoint is not None and logged.waypoint is not None:
            dist = ((cmd.waypoint[0] - logged.waypoint[0]) ** 2
                    + (cmd.waypoint[1] - logged.waypoint[1]) ** 2) ** 0.5  # fmt: skip
        rows.append({
            "t": s["t"], "logged_mode": str(logged.mode), "replay_mode": str(cmd.mode),
            "logged_reason": str(logged.reason), "replay_reason": str(cmd.reason),
            "logged_auv": logged.auv, "replay_auv": cmd.auv, "waypoint_diff_m": dist,
            "logged_speed": _speed(logged), "replay_speed": _speed(cmd),
            "logged_override": s["override"], "replay_override": override,
            "same": same_command(cmd, logged, tol_m),
        })  # fmt: skip
    if caps or command_max is not None:
        notes.append("speed caps replayed as the deploy applied them: "
                     + "; ".join([*(["controller_speed_cap (controller.speed_feedback) "
                                     + ", ".join(caps)] if caps else []),
                                  *([f"speed.command_max {command_max:g} m/s"]
                                    if command_max is not None else [])]))  # fmt: skip
    return ReplayReport(path, name, preset_used(name, preset), pd.DataFrame(rows), tuple(notes))


def _logged_watchdog(logged: dict, path: Path, notes: list[str]):
    """The logged ``[watchdog]`` values as :class:`~mpcasv.io.config_limits.WatchdogSpec` would hold
    them; values this version bounds tighter than the deploy that wrote them did (session
    43: ``asv_stale_s`` in [1, 60] s) are taken as logged, with a note, not refused: the log
    is what happened."""
    try:
        return parse(WatchdogSpec, logged, f"{path}: watchdog")
    except ConfigError as exc:
        if "outside the allowed range" not in str(exc):  # an unknown key, a wrong type: no
            raise
        defaults = {f.name: getattr(WatchdogSpec(), f.name)
                    for f in dataclasses.fields(WatchdogSpec)}  # fmt: skip
        why = " ".join(str(exc).split())  # one line
        notes.append(f"the logged [watchdog] is outside this version's bounds ({why}); "
                     "replayed with the logged values")  # fmt: skip
        return SimpleNamespace(**(defaults | logged))


def _speed(cmd) -> float:
    """A transit's speed (m/s); NaN for standby (its speed is ignored)."""
    return float(cmd.speed) if cmd.mode is Mode.TRANSIT else float("nan")


def print_replay(rep: ReplayReport, show: int = 20) -> None:
    """Summary, the stretches where decisions differ, and the first ``show`` differing steps."""
    t = rep.table
    print(f"replayed {rep.n_steps} decisions of {rep.log} with {rep.controller} "
          f"(preset {rep.preset}): {rep.n_differ} differ")  # fmt: skip
    for note in rep.notes:
        print(f"note: {note}")
    if rep.n_differ == 0:
        return
    t0 = t["t"].iloc[0]
    diff = ~t["same"].to_numpy()
    start = None
    print("differing stretches (s after the first decision):")
    for i, d in enumerate([*diff, False]):
        if d and start is None:
            start = i
        elif not d and start is not None:
            a, b = t["t"].iloc[start] - t0, t["t"].iloc[i - 1] - t0
            print(f"  {a:8.1f} .. {b:8.1f}  ({i - start} steps)")
            start = None
    cols = ["t", "logged_mode", "replay_mode", "logged_reason", "replay_reason", "logged_auv",
            "replay_auv", "waypoint_diff_m", "logged_speed", "replay_speed"]  # fmt: skip
    sub = t.loc[diff, cols].head(show).copy()
    sub["t"] = sub["t"] - t0
    print(sub.to_string(index=False, float_format=lambda v: f"{v:.1f}"))
