"""Open-loop identification manoeuvres on the shared model (``mpcasv simulate --manoeuvre``).

The plant is driven with actuator set-points only (no autopilot), integrated by
:meth:`VesselModel.rk4`, and logged in the identification format of
:mod:`mpcasv.models.identify` (``t, N, E, psi, u, v, r, T_cmd, delta_cmd``), with optional
Gaussian measurement noise (seeded) on the measured columns and a constant current.

- ``zigzag``: Kempf zig-zag (IMO MSC/Circ.1053): steady approach at ``u0``, then the steering
  set-point switches between +-``delta_deg`` each time the heading passes +-``delta_deg`` from
  the initial heading; thrust held at the trim value. Excites sway-yaw and the steering force.
- ``turning-circle``: steady approach, then ``delta_deg`` to starboard, then to port; thrust at
  trim. Excites the steady-turn balance (Coriolis, speed loss, drift angle).
- ``speed-steps``: steps of thrust through fractions of ``T_max`` with small steering
  doublets (``0.3 delta_deg``; ``delta_deg`` 0 runs it straight); excites surge mass and the
  resistance curve.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pandas as pd

from mpcasv.models.current import V_MAX
from mpcasv.models.vessel import IX, VesselModel

MANOEUVRES = ("zigzag", "turning-circle", "speed-steps")
#: the manoeuvres that identify the steering: they need ``delta_deg`` != 0 (speed-steps, which
#: identifies the surge, may run straight)
STEERING = ("zigzag", "turning-circle")
#: columns of an identification log (see mpcasv.models.identify)
COLUMNS = ("t", "N", "E", "psi", "u", "v", "r", "T_cmd", "delta_cmd")


@dataclasses.dataclass(frozen=True)
class Noise:
    """Standard deviations of the measurement noise (SI units)."""

    pos: float = 0.3  # N, E (m)
    psi: float = math.radians(0.5)  # rad
    vel: float = 0.03  # u, v (m/s)
    r: float = math.radians(0.3)  # rad/s

    @classmethod
    def none(cls) -> Noise:
        return cls(0.0, 0.0, 0.0, 0.0)


def simulate_manoeuvre(model: VesselModel, name: str, u0: float = 1.5, delta_deg: float = 20.0,
                       duration: float = 150.0, dt: float = 0.1, current=(0.0, 0.0),
                       noise: Noise | None = None, seed: int = 0) -> pd.DataFrame:  # fmt: skip
    """Simulate one manoeuvre; return the identification table (noise added if given).

    Set-points beyond the vessel's limits are refused, not clipped: an identification log must
    hold the inputs the boat really received.

    Raises
    ------
    mpcasv.config.ConfigError (a ValueError)
        Unknown manoeuvre name; ``delta_deg`` 0 for a :data:`STEERING` manoeuvre (no
        steering to identify) or ``|delta_deg|`` beyond ``delta_max``; ``u0`` beyond the speed
        the vessel holds at ``T_max`` (its trim thrust would exceed ``T_max``); ``u0 <= 0``.
    """
    from mpcasv.config import ConfigError

    if name not in MANOEUVRES:
        raise ConfigError(f"unknown manoeuvre {name!r}; known: {', '.join(MANOEUVRES)}")
    P = model.params
    if delta_deg == 0 and name in STEERING:  # 0 wrote a straight line with exit 0
        raise ConfigError(f"--delta 0: the {name} steers by +-delta, so 0 deg never steers "
                          "(a straight line: nothing to identify the steering from); give an "
                          "angle, e.g. --delta 20")  # fmt: skip
    if abs(math.radians(delta_deg)) > P.delta_max * (1 + 1e-9):
        raise ConfigError(f"--delta {delta_deg:g} deg beyond {P.name}'s steering limit delta_max "
                          f"= {math.degrees(P.delta_max):.1f} deg")  # fmt: skip
    top = min(model.top_speed, P.u_max)
    if not 0 < u0 <= top * (1 + 1e-9):
        raise ConfigError(f"--speed {u0:g} m/s outside (0, {top:.3g}] m/s: {P.name} cannot hold "
                          f"it at T_max = {P.T_max:g} N")  # fmt: skip
    F = model.rk4(dt)
    c = np.asarray(current, float)
    x, _ = model.trim(u0)
    T_trim = model.thrust_for_speed(u0)
    d = math.radians(delta_deg)
    n = int(round(duration / dt))
    X, U = np.zeros((n + 1, len(x))), np.zeros((n + 1, 2))
    X[0] = x
    side, t_approach = 1.0, T_APPROACH
    for k in range(n):
        t = k * dt
        if name == "zigzag":
            if t >= t_approach and side * (x[IX["psi"]]) >= d:
                side = -side
            u_cmd = (T_trim, 0.0 if t < t_approach else side * d)
        elif name == "turning-circle":
            steer = 0.0 if t < t_approach else (d if t < t_approach + (duration - t_approach) / 2
                                                else -d)  # fmt: skip
            u_cmd = (T_trim, steer)
        else:  # speed-steps
            levels = (0.3, 0.9, 0.05, 1.0, 0.15, 0.6)  # of T_max: ~0.4 to 2.5 m/s
            i = min(int(t // (duration / len(levels))), len(levels) - 1)
            doublet = 0.3 * d * math.copysign(1.0, math.sin(2 * math.pi * t / 20.0))
            T_step = T_trim if t < t_approach else levels[i] * P.T_max
            u_cmd = (T_step, doublet if (t % 20.0) < 8.0 and t >= t_approach else 0.0)
        U[k] = u_cmd
        x = np.array(F(x, np.array(u_cmd), c)).ravel()
        X[k + 1] = x
    U[n] = U[n - 1]
    df = pd.DataFrame({"t": np.arange(n + 1) * dt})
    for col in ("N", "E", "psi", "u", "v", "r"):
        df[col] = X[:, IX[col]]
    df["T_cmd"], df["delta_cmd"] = U[:, 0], U[:, 1]
    if noise is not None:
        rng = np.random.default_rng(seed)
        sig = {"N": noise.pos, "E": noise.pos, "psi": noise.psi, "u": noise.vel, "v": noise.vel,
               "r": noise.r}  # fmt: skip
        for col, s in sig.items():
            df[col] = df[col] + rng.normal(0.0, s, len(df)) if s > 0 else df[col]
        df["psi"] = np.angle(np.exp(1j * df["psi"]))
    return df


def write_log(df: pd.DataFrame, path: Path) -> Path:
    """Write an identification table as CSV or parquet (by the file suffix)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".parquet":
        df.to_parquet(path, index=False)
    else:
        df.to_csv(path, index=False, float_format="%.6g")
    return path


def add_arguments(p) -> None:
    """Options of ``mpcasv simulate --manoeuvre`` (``--seed`` and ``--out`` are shared)."""
    g = p.add_argument_group("identification manoeuvre (open-loop, writes a CSV/parquet log)")
    g.add_argument(
        "--manoeuvre",
        choices=MANOEUVRES,
        help="simulate this manoeuvre instead of a scenario; --out FILE.csv|.parquet",
    )
    g.add_argument("--vessel", help="vessel parameters: name or TOML (default gretha)")
    g.add_argument("--speed", type=float, help="approach speed, m/s (default 1.5)")
    g.add_argument("--delta", type=float, help="steering angle, deg (default 20)")
    g.add_argument("--duration", type=float,
                   help="duration, s (default 150; with a SCENARIO: simulate only its first "
                   "DURATION seconds)")  # fmt: skip
    g.add_argument(
        "--current",
        type=float,
        nargs=2,
        metavar=("V_N", "V_E"),
        help="constant current, m/s (default 0 0)",
    )
    g.add_argument(
        "--noise",
        action="store_true",
        help="add measurement noise (0.3 m, 0.5 deg, 0.03 m/s, 0.3 deg/s; --seed)",
    )


#: straight approach at the trim before each manoeuvre's inputs start (s)
T_APPROACH = 10.0
#: the longest manoeuvre log (s): an hour at dt = 0.1 s is 36 000 rows
DURATION_MAX = 3600.0

#: options that only a manoeuvre reads (a SCENARIO run refuses them rather than ignore them)
MANOEUVRE_ONLY = ("vessel", "speed", "delta", "current", "noise")


def _log_path(out: Path | None, name: str) -> Path:
    """Where ``--out`` puts the log: ``FILE.csv`` / ``FILE.parquet`` as given, else a folder
    that gets ``name`` (default ``runs/NAME``); refused (ConfigError) if it cannot be written,
    or if it names another kind of file (``--out m.txt`` wrote a folder called m.txt)."""
    from mpcasv.config import ConfigError
    from mpcasv.outputs import FILE_SUFFIXES, check_output_file, check_output_folder

    if out is None:
        return check_output_file(Path("runs") / name, parents=True)
    if out.suffix in (".csv", ".parquet"):  # as write_log reads it
        return check_output_file(out, parents=True)
    if not out.is_dir() and out.suffix.lower() in FILE_SUFFIXES:
        raise ConfigError(f"--out {out}: a manoeuvre log is written as FILE.csv or "
                          f"FILE.parquet (or into a folder), not as {out.suffix}")  # fmt: skip
    return check_output_folder(out) / name


def run_cli(args) -> int:
    """``mpcasv simulate --manoeuvre NAME``: write one identification log."""
    from mpcasv.config import ConfigError, check_seed
    from mpcasv.models.params import load_vessel

    if args.duration is not None and not (
            math.isfinite(args.duration) and T_APPROACH < args.duration <= DURATION_MAX):
        # 0.1 s wrote a "2 samples, 0 s" log; 1e12 s tried to allocate 582 TiB
        raise ConfigError(f"--duration {args.duration:g}: a manoeuvre lasts more than its "
                          f"{T_APPROACH:g}-s approach and at most {DURATION_MAX:g} s")
    if args.current is not None and math.hypot(*args.current) > V_MAX:  # as scenarios refuse
        raise ConfigError(f"--current {args.current[0]:g} {args.current[1]:g}: speed "
                          f"{math.hypot(*args.current):.3g} m/s above {V_MAX:g} m/s")
    # nan in --delta or --current wrote a log of nan states with exit 0; --seed -1 with
    # --noise was a numpy traceback
    for opt, values in (("--delta", [args.delta]), ("--current", list(args.current or []))):
        bad = [v for v in values if v is not None and not math.isfinite(v)]
        if bad:
            raise ConfigError(f"{opt} {bad[0]:g}: must be a finite number")
    if args.seed is not None and not args.noise:  # the seed draws the noise alone
        raise ConfigError(f"--seed {args.seed}: a manoeuvre without --noise has nothing "
                          "random (the seed would change nothing): add --noise, or leave "
                          "--seed out")  # fmt: skip
    if args.seed is None:
        args.seed = 0
    check_seed(args.seed)
    out = _log_path(args.out, f"{args.manoeuvre}-{args.seed}.csv")  # before the work
    model = VesselModel(load_vessel(args.vessel or "gretha"))
    noise = Noise() if args.noise else None
    df = simulate_manoeuvre(model, args.manoeuvre,
                            u0=1.5 if args.speed is None else args.speed,
                            delta_deg=20.0 if args.delta is None else args.delta,
                            duration=150.0 if args.duration is None else args.duration,
                            current=args.current or (0.0, 0.0), noise=noise,
                            seed=args.seed)  # fmt: skip
    write_log(df, out)
    print(f"wrote {out} ({len(df)} samples, {df['t'].iloc[-1]:.0f} s, noise "
          f"{f'on, seed {args.seed}' if noise else 'off'})")  # fmt: skip
    return 0
