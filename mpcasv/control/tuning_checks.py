"""Bad input of ``mpcasv tune yaw|speed``, refused before any work in one line (exit 2).

Besides numbers that must be finite and > 0 and lists that must not repeat a value, the
designs have physical limits that the pole placement itself cannot see, because it is done on
models that neglect them (docs/tuning.md, "Usable ranges"):

* **actuator lag**: the yaw PID is placed on the first-order Nomoto model, without the
  steering lag ``T_delta`` and the yaw-rate filter ``T_f``; the speed PI on the first-order
  surge model, without the thrust lag ``T_thrust``. A closed loop asked to be faster than the
  lag it neglects (``wn >= 1/T_delta`` or ``1/T_f``, ``w >= 1/T_thrust``) cannot be obtained:
  the loop is then unstable (Gretha loses her yaw margins already from about half of that).
* **sampling**: the execution level runs at the simulator step ``dt``; a step longer than the
  loop's fastest time constant (``T_f``, ``T_delta`` for yaw; ``T_thrust`` for speed) cannot
  represent it. The yaw-rate filter is forward Euler (``r_f += dt/T_f (r - r_f)``,
  :func:`mpcasv.control.execution.execution_law`): it rings for ``dt > T_f`` and diverges for
  ``dt > 2 T_f``. With ``dt`` within these limits the Nyquist frequency ``pi/dt`` is above
  every admitted design frequency. The nonlinear checks run the yaw loop at the simulator's
  step (:data:`mpcasv.control.tuning.DT`) whatever ``--dt``, with ``--T-f`` in ``tune yaw``
  and the ``--base`` file's ``T_f`` in ``tune speed``: both are checked against it too
  (:func:`check_yaw_sampling`).
* **speeds**: every speed option (``--speeds``, ``--design-speed``, ``--u-ff``) must be one the
  vessel can hold, in ``(0, top speed]`` (:func:`mpcasv.control.tuning_yaw.check_speeds`).
"""

from __future__ import annotations

import argparse
import math

from mpcasv.config import ConfigError

#: options of `tune yaw` / `tune speed` that are numbers > 0 (finite); lists: every value
POSITIVE = ("wn", "wn_per_speed", "zeta", "integral_ratio", "T_f", "dt", "w", "design_speed",
            "u_ff", "k_u", "distance", "u_cmd_max")  # fmt: skip


def option(key: str) -> str:
    """The command-line spelling of an ``argparse`` destination."""
    return "--T-f" if key == "T_f" else "--" + key.replace("_", "-")


def _text(values) -> str:
    return ",".join(f"{x:g}" for x in values)


def check_positive(args: argparse.Namespace) -> None:
    """Refuse a number option that is not finite and > 0 in one line (before any work: nan,
    a negative step or time constant were tracebacks, a negative zeta a wrong cause)."""
    for key in POSITIVE:
        v = getattr(args, key, None)
        for x in v if isinstance(v, list) else ([] if v is None else [v]):
            if not (math.isfinite(x) and x > 0):
                raise ConfigError(f"{option(key)} {x:g}: must be a finite number > 0")


def check_lists(args: argparse.Namespace, increasing: tuple[str, ...] = ()) -> None:
    """Refuse a list option that repeats a value (a repeated ``--u-ff`` was a traceback in the
    turn grid) and, for the options in ``increasing``, one that is not strictly increasing
    (the yaw schedule's ``--speeds``: a pydantic traceback)."""
    for key in ("speeds", "wn", "u_ff", "k_u", "distance"):
        v = getattr(args, key, None)
        if not isinstance(v, list) or (key == "wn" and len(v) <= 1):
            continue
        twice = sorted({x for x in v if v.count(x) > 1})
        if twice and key != "wn":
            raise ConfigError(f"{option(key)} {_text(v)}: {_text(twice)} given more than once")
        if key in increasing and any(b <= a for a, b in zip(v, v[1:], strict=False)):
            raise ConfigError(f"{option(key)} {_text(v)}: must be strictly increasing (the "
                              "speeds of a gain schedule)")  # fmt: skip


def check_speed(model, opt: str, value: float) -> None:
    """Refuse a speed option the vessel cannot hold: outside ``(0, top speed]``."""
    top = min(model.top_speed, model.params.u_max)
    if not 0 < value <= top * (1 + 1e-6):
        raise ConfigError(f"{opt} {value:g} m/s: outside (0, {top:.3g}] m/s: "
                          f"{model.params.name} cannot hold it at T_max = "
                          f"{model.params.T_max:g} N")  # fmt: skip


def _sampling(dt: float, limits: dict[str, float], loop: str, why: str, opt: str = "--dt",
              fix: str | None = None) -> None:  # fmt: skip
    tau = min(limits.values())
    if dt > tau * (1 + 1e-9):
        what = ", ".join(f"{k} = {v:g} s" for k, v in limits.items())
        raise ConfigError(f"{opt} {dt:g} s: longer than the {loop} loop's fastest time constant "
                          f"({what}): {fix or f'use {opt} <= {tau:g} s'} ({why})")


#: why a yaw loop cannot run at a step longer than its fastest time constant
YAW_SAMPLING = ("a sampled loop cannot follow a faster lag; the forward-Euler yaw-rate filter "
                "rings for dt > T_f and diverges for dt > 2 T_f")


def check_yaw_sampling(model, T_f: float, T_f_from: str, dt: float | None = None) -> None:
    """Refuse a yaw loop run at a step longer than its fastest time constant: the sampled
    analysis's ``dt`` (``--dt``, if given) longer than ``T_f`` (s, from ``T_f_from``:
    ``--T-f`` or ``--base FILE``) or the vessel's ``T_delta``; the nonlinear checks' step
    :data:`mpcasv.control.tuning.DT` (the simulator's default) longer than ``T_f``, where a
    base file's ``T_f`` is run by ``tune speed`` too (``T_f = 0.02`` at 0.1 s: the filter
    diverged unrefused). The plant's ``T_delta`` is integrated in the simulator's sub-steps:
    not checked against ``DT``."""
    from mpcasv.control.tuning import DT

    P = model.params
    filt = {f"T_f ({T_f_from})": T_f}
    if dt is not None:  # the sampled design: the filter and the steering lag
        _sampling(dt, filt | {f"T_delta ({P.name})": P.T_delta}, "yaw", YAW_SAMPLING)
    # the nonlinear checks: the forward-Euler filter alone (the plant's steering lag is
    # integrated by the simulator in its sub-steps: a vessel with T_delta = 0.05 s was refused
    # here although it runs, a review)
    _sampling(DT, filt, "yaw", YAW_SAMPLING, "the nonlinear checks' step (the simulator's)",
              f"the yaw loop must have T_f >= {DT:g} s")


def check_yaw_limits(model, args: argparse.Namespace, wn: list[float]) -> None:
    """Refuse a yaw design outside the usable range (module docstring): ``--dt`` above ``T_f``
    or ``T_delta``, the nonlinear checks' step above ``T_f`` (:func:`check_yaw_sampling`);
    ``wn`` at or above ``1/T_delta`` or ``1/T_f``."""
    P = model.params
    check_yaw_sampling(model, args.T_f, "--T-f", args.dt)
    corners = {"1/T_delta": 1.0 / P.T_delta, "1/T_f": 1.0 / args.T_f}
    w_max = min(corners.values())
    for u, w in zip(args.speeds, wn, strict=True):
        if w >= w_max:
            given = (f"--wn {w:g}" if args.wn is not None else
                     f"--wn-per-speed {args.wn_per_speed:g} (wn = {w:g} rad/s at {u:g} m/s)")
            what = ", ".join(f"{k} = {v:.3g} rad/s" for k, v in corners.items())
            raise ConfigError(f"{given}: the yaw loop's natural frequency must be below the "
                              f"steering lag's and the yaw-rate filter's corners ({what}): the "
                              "PID is placed on a Nomoto model without them, a faster loop is "
                              "unstable")  # fmt: skip


def check_speed_limits(model, args: argparse.Namespace) -> None:
    """Refuse a speed-loop design outside the usable range (module docstring): a speed the
    vessel cannot hold; ``--dt`` above ``T_thrust``; ``--w`` at or above ``1/T_thrust``."""
    P = model.params
    check_speed(model, "--design-speed", args.design_speed)
    for u in args.u_ff:
        check_speed(model, "--u-ff", u)
    _sampling(args.dt, {f"T_thrust ({P.name})": P.T_thrust}, "speed",
              "a sampled loop cannot follow a faster lag")
    if args.w >= 1.0 / P.T_thrust:
        raise ConfigError(f"--w {args.w:g} rad/s: the speed loop's natural frequency must be "
                          f"below the thrust lag's corner 1/T_thrust = {1 / P.T_thrust:.3g} "
                          f"rad/s ({P.name}): the PI is placed on a surge model without it, a "
                          "faster loop is unstable")  # fmt: skip


def check_distances(args: argparse.Namespace, model) -> None:
    """Refuse a turn-grid ``--distance`` (m) that
    :func:`mpcasv.control.tuning_turns.distance_refusal` refuses: at or inside the arrival
    circle, or a run longer than its cap at the grid's slowest speed ``min(u_ff, u_max)``
    (``--distance 1e9`` ran for ever, a review)."""
    from mpcasv.control.tuning_turns import distance_refusal

    u_slow = min(min(args.u_ff), model.params.u_max)
    for d in args.distance:
        why = distance_refusal(d, u_slow)
        if why:
            raise ConfigError(f"--distance {why}")


def check_u_cmd_max(args: argparse.Namespace, ep, model) -> list[str]:
    """Default ``--u-cmd-max`` (m/s), the bound on eq. 3.1's largest command
    ``u_ff + k_u pi/2``, to the ``--base`` file's own (the thesis kept ``u_cmd,max`` at the
    rated top speed when it changed ``u_ff``, §3.4.1: 3.0976 m/s for Gretha's field pair), and
    refuse a grid none of whose pairs is within it (one line, before any work).

    Returns the notes on the bound, for stderr and speed.md: where a default came from (the
    base file's own, which for another hull may be another vessel's: pass ``--u-cmd-max``),
    and when the vessel's top speed ``u_max`` is below it (the execution level caps the
    reference there). The base's [reference] is not attributed to a vessel: a default taken
    from names parsed out of the provenance refused working commands (a review)."""
    from mpcasv.control.tuning_turns import u_cmd_max, within

    notes, defaulted = [], args.u_cmd_max is None
    if defaulted:
        args.u_cmd_max = round(u_cmd_max(ep.reference.u_ff, ep.reference.k_u), 4)
        notes.append(f"--u-cmd-max defaulted to the --base file's own u_ff + k_u pi/2 = "
                     f"{args.u_cmd_max:g} m/s (--base {args.base}: u_ff = {ep.reference.u_ff:g}"
                     f", k_u = {ep.reference.k_u:g} m/s); for another hull pass "
                     "--u-cmd-max")  # fmt: skip
    P = model.params
    if P.u_max < args.u_cmd_max:
        notes.append(f"{P.name}'s top speed u_max = {P.u_max:g} m/s is below --u-cmd-max "
                     f"{args.u_cmd_max:g} m/s: the execution level caps the speed reference "
                     "at u_max (u_ref = min(eq. 3.1, command, u_max)), so speeds eq. 3.1 asks "
                     "above it are run at u_max")  # fmt: skip
    low = min(u_cmd_max(a, b) for a in args.u_ff for b in args.k_u)
    if not any(within(a, b, args.u_cmd_max) for a in args.u_ff for b in args.k_u):
        raise ConfigError(f"--u-ff {_text(args.u_ff)} --k-u {_text(args.k_u)}: every pair has "
                          f"u_ff + k_u pi/2 above --u-cmd-max {args.u_cmd_max:g} m/s (least "
                          f"{low:.4g} m/s): no pair of the grid may be recommended"
                          + (f" ({notes[0]})" if defaulted else ""))  # fmt: skip
    return notes
