"""``mpcasv tune yaw`` and ``mpcasv tune speed`` behind the command line (parsed in
:mod:`mpcasv.control.commands`): the checks before any work, the designs, their acceptance, the
provenance written with them and the execution TOML (written only when the acceptance passes).
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import sys
from pathlib import Path

from mpcasv.config import ConfigError

DEFAULT_SPEEDS = "0.5,1,1.5,2,2.5"  # Gretha's: 0.2 ... 1.0 u_max (the default for any vessel)
SPEED_FRACTIONS = (0.2, 0.4, 0.6, 0.8, 1.0)
DESIGN_FRACTION = 0.4  # default --design-speed / top speed: Gretha's 1 m/s
WN_PER_SPEED = 0.3  # default --wn-per-speed, rad/m (a steered propeller: rudder-like)
#: default yaw wn of a differential-thrust vessel, as a fraction of its steering lag's corner
#: 1/T_delta (rad/s), the same at every speed: its turning moment is the thrusters' difference
#: times their spacing, which does not grow with speed as a rudder's or a steered drive's does,
#: so its Nomoto K and T are the same at every speed (dune-otter: K 2.25 1/s, T 1.19 s from
#: 0.7 to 3.5 m/s) and a wn proportional to speed left it sluggish when slow (0.21 rad/s at
#: 0.7 m/s: a 5 deg disturbance moment turned it 78 deg) and short of phase margin when fast
#: (21 deg at 3.5 m/s): the default design failed. 0.3/T_delta = 0.6 rad/s passes (docs/tuning.md)
WN_LAG_FRACTION = 0.3
BASE_DEFAULT = "gretha"  # default --base (and --vessel): the execution level tuned for Gretha


def _command_line(args: argparse.Namespace, name: str) -> str:
    """The command as it could be typed again (from the parsed options, not sys.argv)."""
    parts = ["mpcasv", name]
    for key, v in vars(args).items():
        if key in ("func", "command", "tune_what", "quiet") or v is None or v is False:
            continue
        opt = "--" + key.replace("_", "-") if key != "T_f" else "--T-f"
        if v is True:
            parts.append(opt)
        else:
            text = ",".join(f"{x:g}" for x in v) if isinstance(v, list) else str(v)
            parts += [opt, shlex.quote(text)]
    return " ".join(parts)


def _provenance(old: str, key: str, text: str) -> str:
    """Replace the ``key: ...`` part of a ``"; "``-separated provenance string."""
    parts = [p for p in old.split(" | ") if p and not p.startswith(f"{key}: ")]
    parts = [p for p in parts if p.split(":")[0] in ("yaw", "speed", "reference")]
    return " | ".join(sorted([*parts, f"{key}: {text}"]))


_KEPT = "reference: kept from --base "
_KEPT_END = ", origin not recorded ("


def _kept_origin(prov: str) -> str | None:
    """The file a ``reference: kept from --base FILE, origin not recorded (...)`` part of
    the provenance names (None without one): a chain of runs keeps the first base."""
    for part in prov.split(" | "):
        if part.startswith(_KEPT) and _KEPT_END in part:
            return part[len(_KEPT):].split(_KEPT_END)[0]
    return None


def _setup(args, what: str):
    """Load and check everything before any work (one line, exit 2, for bad input)."""
    from mpcasv.control import tuning_checks as tc
    from mpcasv.control.params import load_execution
    from mpcasv.control.tuning_yaw import check_speeds
    from mpcasv.models.params import load_vessel
    from mpcasv.models.vessel import VesselModel
    from mpcasv.outputs import check_output_file, check_output_folder

    tc.check_positive(args)
    tc.check_lists(args, increasing=("speeds",) if what == "yaw" else ())
    model = VesselModel(load_vessel(args.vessel))
    try:
        ep = load_execution(args.base)
    except ConfigError as exc:
        raise ConfigError(f"--base {args.base}: {exc}") from None
    top = min(model.top_speed, model.params.u_max)
    if args.speeds is None:
        args.speeds = [round(f * top, 4) for f in SPEED_FRACTIONS]
    check_speeds(model, args.speeds, "--speeds")
    if what == "speed":
        if args.design_speed is None:
            args.design_speed = round(DESIGN_FRACTION * top, 4)
        tc.check_speed_limits(model, args)
        tc.check_distances(args, model)
        # the turns and steps run the base file's yaw loop: its T_f as if given (--T-f)
        tc.check_yaw_sampling(model, ep.yaw.T_f, f"--base {args.base}")
    check_output_folder(args.out)
    toml = check_output_file(args.toml or args.out / "execution.toml", "--toml", (".toml",),
                             parents=True)  # fmt: skip
    return model, ep, toml


def _warn_base(args, model, what: str, toml: Path) -> None:
    """Say (stderr, after the design, not before a refusal) when ``--base`` defaulted to
    Gretha's execution level for another vessel: the loop not tuned here is hers (a new
    user's dune-otter, session 43: written as "Execution level of Gretha", no word)."""
    name = model.params.name
    if args.base != BASE_DEFAULT or name == BASE_DEFAULT:
        return
    other, nxt = ("speed loop", "speed") if what == "yaw" else ("yaw gain schedule", "yaw")
    print(f"mpcasv tune: warning: --base {BASE_DEFAULT} (the default): the {other} used in "
          f"the checks and written beside the {what} design is Gretha's, not tuned for {name}; "
          f"tune it next (once this design passes and is written): mpcasv tune {nxt} --vessel "
          f"{shlex.quote(str(args.vessel))} --base {shlex.quote(str(toml))} --out "
          f"runs/tune-{nxt} --toml {shlex.quote(str(toml))}",
          file=sys.stderr)  # fmt: skip


def _write_if_pass(ok: bool, toml: Path, ep, what: str, args) -> str:
    """Write the execution TOML only when the acceptance passed; the words for the summary.

    A design that fails its acceptance (exit 1) leaves ``--toml`` as it was: the file is what
    the simulator and ``--base`` load, and a failing design written there would be used as if
    good (it was, until session 17). Its gains are in the report (yaw.json, speed.md)."""
    from mpcasv.control.tuning import write_execution_toml

    if not ok:
        return f"{toml} NOT written (acceptance FAIL; the {what} design is in the report)"
    command = _command_line(args, f"tune {what}")
    write_execution_toml(toml, ep, _header(ep, args.vessel, toml, command, what, args.out))
    return f"wrote {toml}"


def run_tune_yaw(args: argparse.Namespace) -> int:
    from mpcasv.config import replace
    from mpcasv.control.tuning_checks import check_yaw_limits
    from mpcasv.control.tuning_report import plot_yaw, yaw_table
    from mpcasv.control.tuning_schedule import (
        above_ok,
        off_schedule,
        off_schedule_summary,
        poles_text,
        schedule_notes,
    )  # fmt: skip
    from mpcasv.control.tuning_yaw import CourseUnstable, tune_yaw

    if args.wn is not None and args.wn_per_speed is not None:  # was silently ignored
        raise ConfigError(f"--wn-per-speed {args.wn_per_speed:g} with --wn "
                          f"{','.join(f'{w:g}' for w in args.wn)}"
                          ": --wn sets the natural frequencies itself, so --wn-per-speed would "
                          "be unused: give one of them")  # fmt: skip
    model, ep, toml = _setup(args, "yaw")
    if args.wn is None and args.wn_per_speed is None:
        # (the default in the provenance's command line, as if given)
        if model.params.actuation == "differential":
            args.wn = [WN_LAG_FRACTION / model.params.T_delta]
        else:
            args.wn_per_speed = WN_PER_SPEED
    speeds = args.speeds
    if args.wn is None:
        wn = [args.wn_per_speed * u for u in speeds]
    elif len(args.wn) in (1, len(speeds)):
        wn = args.wn * len(speeds) if len(args.wn) == 1 else args.wn
    else:
        raise ConfigError(f"--wn: {len(args.wn)} values for {len(speeds)} speeds")
    check_yaw_limits(model, args, wn)
    args.out.mkdir(parents=True, exist_ok=True)
    try:
        ep_new, designs, runs = tune_yaw(model, ep, speeds, wn, args.zeta, args.integral_ratio,
                                         args.T_f, args.dt, progress=not args.quiet)  # fmt: skip
    except CourseUnstable as exc:
        raise ConfigError(f"{args.vessel}: {exc}") from None
    plot_yaw(model, designs, runs, args.T_f, args.out)
    off = off_schedule(model, ep_new, args.dt)  # held below/above, interpolated between
    table = "\n".join([yaw_table(designs), *schedule_notes(designs, off)])
    # nan (a margin neither python-control nor the sweep could compute) fails every >= test
    ok = all(d.sampled["phase_margin_deg"] >= 45 and d.sampled["gain_margin_db"] >= 6
             and d.linear["phase_margin_deg"] >= 45 and d.linear["gain_margin_db"] >= 6
             and d.linear["stable"] and d.sampled["stable"]
             and math.isfinite(d.nonlinear["settling_s"]) for d in designs)  # fmt: skip
    ok_above = above_ok(off)  # gains held above the schedule: every faster transit runs them
    ok = ok and ok_above
    ts_max = max(d.nonlinear["settling_s"] for d in designs)
    cmd = _command_line(args, "tune yaw")
    text = (f"{cmd}: pole placement on first-order Nomoto models of vessel "
            f"{model.params.name}, wn {[round(w, 3) for w in wn]} rad/s, zeta {args.zeta}, "
            f"integral pole {args.integral_ratio} wn, T_f {args.T_f} s; min PM "
            f"{min(d.sampled['phase_margin_deg'] for d in designs):.0f} deg, min GM "
            f"{min(d.sampled['gain_margin_db'] for d in designs):.1f} dB (sampled, steering lag "
            f"incl.); nonlinear 45 deg step settles to 2 deg within {ts_max:.1f} s")  # fmt: skip
    ep_new = replace(ep_new, provenance=_provenance(ep.provenance, "yaw", text))
    wrote = _write_if_pass(ok, toml, ep_new, "yaw", args)
    _warn_base(args, model, "yaw", toml)
    (args.out / "yaw.md").write_text(table + "\n")
    (args.out / "yaw.json").write_text(json.dumps([_design_dict(d) for d in designs], indent=1))
    print(table)
    print(
        f"{wrote}; wrote {args.out}/yaw.md, yaw.json and plots; acceptance "
        f"(PM >= 45 deg, GM >= 6 dB, nonlinear step settles) at the schedule speeds and "
        f"above them to the top speed: {'PASS' if ok else 'FAIL'}; "
        f"{off_schedule_summary(off)} (yaw.md)"
    )
    for d in designs:
        if d.kd_clip:
            print(f"pole placement not achieved at {d.u0:g} m/s: Kd = "
                  f"{d.kd_clip['Kd_formula']:.2f} s clipped to 0; poles "
                  f"{poles_text(d.kd_clip['poles_achieved'])} 1/s instead of "
                  f"{poles_text(d.kd_clip['poles_requested'])} 1/s (yaw.md)")  # fmt: skip
    return 0 if ok else 1


def run_tune_speed(args: argparse.Namespace) -> int:
    from mpcasv.config import replace
    from mpcasv.control.params import SpeedReference
    from mpcasv.control.tuning_checks import check_u_cmd_max
    from mpcasv.control.tuning_report import plot_speed, speed_tables
    from mpcasv.control.tuning_speed import (
        SPEED_STEP,
        STEP_T_END,
        edge_notes,
        feed_forward_gain,
        merge_grids,
        place_speed_pi,
        recommend,
        speed_figures,
        speed_step,
        straight_speed_limit,
        surge_plant,
        turn_grid,
        unsettled_steps,
    )  # fmt: skip

    model, ep, toml = _setup(args, "speed")
    bound_notes = check_u_cmd_max(args, ep, model)  # where the bound came from
    args.out.mkdir(parents=True, exist_ok=True)
    g = place_speed_pi(model, args.design_speed, args.w, args.zeta)
    ep_new = replace(ep, speed=g)
    # the steps with the execution level's feed-forward of u_ref (it sets the step, not the
    # margins: without it the linear step was the feedback loop's alone, 4.5 % overshoot at
    # 1.5 m/s where the boat's small step overshoots 18 %)
    loop = {
        u: (
            speed_figures(surge_plant(model, u), g, ff=feed_forward_gain(model, u)),
            speed_figures(surge_plant(model, u), g, args.dt, ff=feed_forward_gain(model, u)),
        )
        for u in args.speeds
    }
    # the same steps on the nonlinear loop, thrust limits included, up and down (a linear
    # step is the same either way; the boat's is not: it can only coast down at T_min and
    # cannot go beyond its top speed)
    steps = {u: [speed_step(model, ep_new, u, u + du) for du in (SPEED_STEP, -SPEED_STEP)]
             for u in args.speeds}  # fmt: skip
    top, top_why = straight_speed_limit(model, ep_new)
    limits = (f"thrust {model.params.T_min:g} ... {model.params.T_max:g} N; straight-course "
              f"top speed {top:.3g} m/s: the {top_why}")  # fmt: skip
    pairs = [(a, b) for a in args.u_ff for b in args.k_u]
    field = (ep.reference.u_ff, ep.reference.k_u)
    grids = {}
    # the grid and the pirouette check tune eq. 3.1 itself: the optional power turn is off
    ep_31 = replace(ep_new, turn_thrust=0.0)
    for d in args.distance:
        rows, runs = turn_grid(model, ep_31, [*pairs, (model.params.u_max, 0.0)], distance=d,
                               progress=not args.quiet)  # fmt: skip
        grids[d] = (rows, runs)
    # recommend on the grid (the last row, "no reference model", is a baseline only)
    merged = merge_grids(grids)
    try:
        best = recommend(merged, args.u_cmd_max)
        notes = edge_notes(best, merged, args.u_cmd_max)
    except ValueError as exc:  # no pair passed (P or NR, why_none): reported, the base's kept
        best, notes = None, []
        none_reason = str(exc)
    ok_margins = all(c["phase_margin_deg"] >= 45 and c["gain_margin_db"] >= 6 and c["stable"]
                     for f in loop.values() for c in f)  # fmt: skip
    unsettled = unsettled_steps(loop, steps)  # a stable loop may still never get there
    ok_loop = ok_margins and not unsettled
    cmd = _command_line(args, "tune speed")
    text = (f"{cmd}: PI by pole placement on the linearised surge model at "
            f"{args.design_speed} m/s, w {args.w} rad/s, zeta {args.zeta}; min PM "
            f"{min(f[1]['phase_margin_deg'] for f in loop.values()):.0f} deg (sampled, thrust "
            f"lag incl.)")  # fmt: skip
    prov = _provenance(ep.provenance, "speed", text)
    if args.set_reference and best is None:
        raise ConfigError(f"--set-reference: {none_reason}")
    if args.set_reference:
        ep_new = replace(ep_new, reference=SpeedReference(u_ff=best.u_ff, k_u=best.k_u))
        prov = _provenance(
            prov, "reference", f"{_command_line(args, 'tune speed')}: recommended by the turn grid"
        )
    elif ("reference: " not in prov or "reference: field tuning" in prov
          or _KEPT in prov):  # fmt: skip
        # "field tuning" only for the shipped values: a [reference] of unknown origin was
        # labelled so, and read as Gretha's next time (a review). A [reference] kept from an
        # earlier --base keeps that file as its origin, with this run's recommendation (the
        # last run's was copied on unchanged, a review)
        field = ep.reference == SpeedReference()
        origin = _kept_origin(prov) or str(args.base)
        prov = _provenance(
            prov,
            "reference",
            ("field tuning, thesis §3.4.1 (kept; the turn grid " if field else
             f"kept from --base {origin}, origin not recorded (u_ff = {ep.reference.u_ff:g}, "
             f"k_u = {ep.reference.k_u:g} m/s; the turn grid ")
            + (f"of mpcasv tune speed recommends u_ff={best.u_ff}, k_u={best.k_u} within "
               f"u_cmd,max <= {args.u_cmd_max:.4g} m/s)" if best
               else f"of mpcasv tune speed recommends none: {none_reason})"),
        )
    ep_new = replace(ep_new, provenance=prov)
    wrote = _write_if_pass(ok_loop, toml, ep_new, "speed", args)
    _warn_base(args, model, "speed", toml)
    plot_speed(model, g, grids, field, best, args.out)
    from mpcasv.control.tuning_report import plot_pirouette
    from mpcasv.control.tuning_speed import PIROUETTE_CASE, pirouette_check

    a, d, u0 = PIROUETTE_CASE
    plot_pirouette(pirouette_check(model, ep_31, a, d, u0), (d * math.cos(math.radians(a)),
                   d * math.sin(math.radians(a))), args.out,
                   f"{model.params.name}: waypoint {d:g} m at {a:g} deg, from {u0:g} m/s, "
                   f"command u_max = {model.params.u_max:g} m/s")  # fmt: skip
    text_tables = speed_tables(g, loop, grids, best, steps, limits, args.u_cmd_max,
                               [*notes, *bound_notes],
                               (model.params.name, model.params.L))  # fmt: skip
    (args.out / "speed.md").write_text(text_tables + "\n")
    print(text_tables)
    print(
        (f"recommended (u_ff, k_u) = ({best.u_ff}, {best.k_u}) (u_ff + k_u pi/2 <= "
         f"{args.u_cmd_max:.4g} m/s)" if best else
         f"no recommended (u_ff, k_u): {none_reason}")
        + f"; {wrote}; wrote "
        f"{args.out}/speed.md and plots; loop margins {'PASS' if ok_margins else 'FAIL'}; "
        f"speed steps settle (2 %, within {STEP_T_END:g} s): "
        + ("PASS" if not unsettled else f"FAIL: {', '.join(unsettled)}")
    )
    print(_steps_summary(steps))
    for note in bound_notes:  # where the bound came from, every run (speed.md too)
        print(f"mpcasv tune: note: {note}", file=sys.stderr)
    for note in notes:  # the optimum on the grid's edge: say so where it is seen
        if "beyond it" in note:
            print(f"mpcasv tune: warning: recommended {note}", file=sys.stderr)
    return 0 if ok_loop else 1


def _steps_summary(steps: dict) -> str:
    """One line on the nonlinear speed steps: how many touch a thrust limit, the longest at
    one, which are beyond the boat (every figure, linear beside nonlinear, in speed.md)."""
    all_ = [st for v in steps.values() for st in v]
    run = [st for st in all_ if st["reachable"]]
    sat = [st for st in run if st["at_T_max"] > 0 or st["at_T_min"] > 0]
    no = [f"{st['u0']:g}->{st['u1']:g}" for st in all_ if st.get("why", "").startswith("UNREACH")]
    text = f"nonlinear speed steps (thrust limits incl.): {len(sat)} of {len(run)} reach a limit"
    if sat:
        w = max(sat, key=lambda st: max(st["at_T_max"], st["at_T_min"]))
        k = "T_max" if w["at_T_max"] >= w["at_T_min"] else "T_min"
        text += (f"; longest {w['u0']:g}->{w['u1']:g} m/s, at {k} {100 * w[f'at_{k}']:.0f} % "
                 f"of the run, rise {w['rise_s']:.1f} s")  # fmt: skip
    return text + (f"; UNREACHABLE: {', '.join(no)} m/s" if no else "") + " (speed.md)"


def _recorded_out(provenance: str, what: str) -> str | None:
    """The ``--out`` of the ``mpcasv tune <what>`` command recorded in ``provenance`` (its
    ``"<what>: mpcasv tune <what> ...: ..."`` entry), or None."""
    for part in provenance.split(" | "):
        if part.startswith(f"{what}: mpcasv tune {what} "):
            try:
                words = shlex.split(part[len(what) + 2:].split(": ", 1)[0])
            except ValueError:
                return None
            if "--out" in words[:-1]:
                return words[words.index("--out") + 1]
    return None


def _header(ep, vessel: str, toml: Path, command: str | None = None, what: str = "",
            out: Path | None = None) -> list[str]:  # fmt: skip
    """The comment heading an execution TOML of ``vessel`` (``--vessel`` as given) written to
    ``toml`` by ``command`` (``mpcasv tune <what> ... --out out``): what it holds, the command
    that wrote it and how to regenerate it (it said "of Gretha" whatever the vessel until
    session 43; its recipe said ``--out runs/tune-yaw`` whatever ``--out`` was given: the
    recipe now takes this run's ``--out`` and the other tool's from its provenance)."""
    v = "" if vessel == BASE_DEFAULT else f" --vessel {shlex.quote(str(vessel))}"
    outs = {w: shlex.quote(str(out)) if w == what and out is not None else
            shlex.quote(_recorded_out(ep.provenance, w) or f"runs/tune-{w}")
            for w in ("yaw", "speed")}  # fmt: skip
    toml = shlex.quote(str(toml))
    lines = [
        f"Execution level of {vessel}: yaw PID gain schedule, speed loop, surge-speed",
        "reference model. GENERATED by `mpcasv tune yaw` ([yaw]) and `mpcasv tune speed`",
        f"([speed]) on the shared vessel model ({vessel}); [reference] is the field tuning of",
        "thesis §3.4.1 unless the provenance says otherwise.",
        *([f"Written by: {command}"] if command else []),
        "Regenerate (yaw, speed, then yaw again so that its nonlinear check uses the new speed",
        "loop; the designs themselves do not depend on each other):",
        f"  mpcasv tune yaw{v} --out {outs['yaw']} --toml {toml}",
        f"  mpcasv tune speed{v} --base {toml} --out {outs['speed']} --toml {toml}",
        f"  mpcasv tune yaw{v} --base {toml} --out {outs['yaw']} --toml {toml}",
        "Provenance of each table:",
    ]
    return lines + [f"  {p}" for p in ep.provenance.split(" | ")]


def _design_dict(d) -> dict:
    import dataclasses

    out = dataclasses.asdict(d)
    return json.loads(json.dumps(out, default=float).replace("Infinity", "null"))
