"""DUNE and CSV logs into identification tables, and ``mpcasv identify`` itself.

The identification (:mod:`mpcasv.models.identify`, :mod:`mpcasv.models.ident_thrust`) works
on tables; reading files, DUNE's LSF logs and their ``Config.ini`` is done here, in the I/O
layer (models never import it).

DUNE logs (``.lsf``, ``.lsf.gz``) are read by :func:`mpcasv.io.lsf.read_lsf` and mapped:
navigation from EstimatedState, ``T_cmd`` = SetThrusterActuation id 0 (fraction) x ``T_max`` of
the prior, ``delta_cmd`` = SetServoPosition id 0; for a prior with ``actuation =
"differential"`` ids 0 (port) and 1 (starboard) give the total and the differential thrust.
DUNE logs the messages it receives, so a boat's log holds other vehicles' states too:
``vehicle`` (``--vehicle NAME|ID``: Announce name, or IMC id as ``0x2801`` or decimal) picks
one; by default the one vehicle that carries the actuator set-points (SetThrusterActuation)
is taken and named on stdout. A log with several steering servos on the chosen vehicle (an
AUV's fins), of a submerged vehicle, or with no or several vehicles carrying set-points and
no ``--vehicle`` is refused with a :class:`LogError`.

**Through DUNE's thruster map.** A DUNE log folder holds the configuration DUNE ran with,
``Config.ini``, beside ``Data.lsf.gz``. When the log comes from DUNE's simulator (it holds
SimulatedState), the prior has differential actuation and the configuration's VSIM model has
two fixed thrusters, ``mpcasv identify`` says so and identifies the hull through that
simulator's thruster map
(:mod:`mpcasv.models.ident_thrust`): the actuation-to-force map is DUNE's own, not a
proportional one. Its table (:func:`map_table`) holds the actuations as DUNE applied them:
over ``[t_k, t_k+1)`` the latest SetThrusterActuation of each thruster at ``t_k + dt / 2``
(DUNE's controller answers each EstimatedState within a millisecond; the timing and its
evidence: :data:`mpcasv.models.ident_thrust.ACTUATION_ADVANCE`).
"""

from __future__ import annotations

import json
import shlex
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from mpcasv.errors import LogError
from mpcasv.io.lsf import read_lsf, read_messages
from mpcasv.models.ident_table import identification_table
from mpcasv.models.identify import IDENTIFIED, identify
from mpcasv.models.params import MODEL_COEFFS, VesselParams
from mpcasv.models.vessel import dune_actuators

__all__ = ["load_log", "map_table", "pick_vehicle", "run_cli"]


def load_log(path: Path, prior: VesselParams, vehicle: str | None = None) -> pd.DataFrame:
    """Read one log (CSV, parquet or DUNE LSF) into the identification table
    (:func:`mpcasv.models.ident_table.identification_table`).

    ``vehicle`` selects one vehicle of a DUNE log (name or IMC id); see the module docstring.

    Raises
    ------
    LogError
        Unreadable file, missing columns, bad time axis, non-finite values, too short, or a
        DUNE log this model does not apply to; the message names the file.
    """
    path = Path(path)
    if not path.is_file():
        raise LogError(f"{path}: no such log file")
    name = path.name.lower()
    if name.endswith((".lsf", ".lsf.gz")):
        df = _from_lsf(path, prior, vehicle)
    elif name.endswith(".csv"):
        try:
            df = pd.read_csv(path)
        except (pd.errors.ParserError, UnicodeDecodeError, pd.errors.EmptyDataError) as exc:
            raise LogError(f"{path}: not a readable CSV ({exc})") from None
    elif name.endswith(".parquet"):
        try:
            df = pd.read_parquet(path)
        except Exception as exc:  # pyarrow raises several types for corrupt files
            raise LogError(f"{path}: not a readable parquet file ({exc})") from None
    else:
        raise LogError(f"{path}: unknown log format (expected .csv, .parquet, .lsf, .lsf.gz)")
    return identification_table(df, path)


def _vehicle_id(text: str) -> int | None:
    try:
        return int(text, 0)
    except ValueError:
        return None


def pick_vehicle(df: pd.DataFrame, path, vehicle: str | None = None) -> str:
    """The vehicle of a multi-vehicle DUNE log to identify (its ``vehicle`` name).

    With ``vehicle`` (a name, or an IMC id such as ``0x2801`` or ``10241``) that one; without,
    the single vehicle whose rows carry thrust set-points (``thrust_0``), printed.

    Raises
    ------
    LogError
        Unknown vehicle; none or several vehicles carry set-points and none was named.
    """
    names = sorted(set(df["vehicle"]))
    if vehicle is not None:
        if vehicle in names:
            return vehicle
        vid = _vehicle_id(vehicle)
        hit = sorted(set(df.loc[df["src"] == vid, "vehicle"])) if vid is not None else []
        if len(hit) == 1:
            return hit[0]
        raise LogError(f"{path}: no vehicle {vehicle!r} in the log (vehicles: "
                       f"{', '.join(names)})")  # fmt: skip
    if "thrust_0" in df.columns:
        actuated = sorted(set(df.loc[df["thrust_0"].notna(), "vehicle"]))
    else:
        actuated = []
    if len(names) == 1 and len(actuated) <= 1:
        return names[0]
    if len(actuated) != 1:
        raise LogError(f"{path}: {len(names)} vehicles ({', '.join(names)}), {len(actuated)} "
                       "with thrust set-points: name one with --vehicle")  # fmt: skip
    print(f"{path}: {len(names)} vehicles ({', '.join(names)}); identifying '{actuated[0]}', "
          "the one with actuator set-points (--vehicle to choose)")  # fmt: skip
    return actuated[0]


def _from_lsf(path: Path, prior: VesselParams, vehicle: str | None = None) -> pd.DataFrame:
    df = read_lsf(path)
    chosen = pick_vehicle(df, path, vehicle)
    df = df[df["vehicle"] == chosen]
    vehicles = [chosen]
    if (df["depth"] > 0.5).mean() <= 0.05 and prior.actuation == "differential":
        return _differential_inputs(df, path, prior)
    fins = sorted(c for c in df.columns if c.startswith("fin_cmd_") and df[c].notna().any())
    if len(fins) > 1:
        raise LogError(
            f"{path}: {len(fins)} steering servos ({', '.join(fins)}) on '{vehicles[0]}': a "
            "finned vehicle such as an AUV, not a surface vessel with one steerable drive; the "
            "3-DOF surface model does not apply (expected SetServoPosition id 0 only)"
        )
    if (df["depth"] > 0.5).mean() > 0.05:
        raise LogError(
            f"{path}: '{vehicles[0]}' is submerged (depth up to "
            f"{df['depth'].max():.1f} m): the 3-DOF surface model does not apply"
        )
    for col, msg in (("thrust_0", "SetThrusterActuation id 0"), ("fin_cmd_0", "SetServoPosition "
                     "id 0")):  # fmt: skip
        if col not in df.columns or df[col].isna().all():
            hint = _no_servo_hint(df, prior) if col == "fin_cmd_0" else ""
            raise LogError(f"{path}: missing messages: no {msg} (thrust/steering set-points)"
                           + hint)
    df = df.dropna(subset=["thrust_0", "fin_cmd_0"])
    T, delta = dune_actuators(prior, df["thrust_0"].astype(float),
                              servo=df["fin_cmd_0"].astype(float))  # fmt: skip
    return pd.DataFrame({
        "t": df["t"], "N": df["N"], "E": df["E"], "psi": df["psi"], "u": df["u"], "v": df["v"],
        "r": df["r"], "T_cmd": T, "delta_cmd": delta,
    })  # fmt: skip


def _no_servo_hint(df: pd.DataFrame, prior: VesselParams) -> str:
    """What to say when a log has thrust but no steering servo: a boat steered by differential
    thrust (DUNE's Otter: SetThrusterActuation ids 0 and 1) needs a differential prior."""
    from mpcasv.config import DATA_DIR
    from mpcasv.models.params import load_vessel

    shipped = sorted(p.stem for p in (DATA_DIR / "vessels").glob("*.toml"))
    differential = [n for n in shipped if load_vessel(n).actuation == "differential"]
    two = "thrust_1" in df.columns and df["thrust_1"].notna().any()
    seen = ("; the log has no steering servo but thrusters 0 and 1 (differential thrust, as "
            "DUNE's Otter)" if two else "; the log has no steering servo")  # fmt: skip
    options = " or ".join(f"--vessel {n}" for n in differential)
    return (f"{seen}: the prior {prior.name!r} steers a drive (actuation {prior.actuation!r}); "
            f"try a differential-thrust prior: {options}")


def _differential_inputs(df: pd.DataFrame, path, prior: VesselParams) -> pd.DataFrame:
    """Two fixed thrusters (prior ``actuation = "differential"``): SetThrusterActuation id 0
    (port) and id 1 (starboard), fractions ``a_0, a_1`` of each thruster's ``T_max / 2``:
    ``T_cmd = (a_0 + a_1) T_max / 2`` and ``delta_cmd = delta_max (a_0 - a_1) / 2``
    (:func:`mpcasv.models.vessel.dune_actuators`, which the deploy reads its actuators with)."""
    for col, i in (("thrust_0", 0), ("thrust_1", 1)):
        if col not in df.columns or df[col].isna().all():
            raise LogError(f"{path}: missing messages: no SetThrusterActuation id {i} (a vessel "
                           "with two thrusters needs both)")  # fmt: skip
    df = df.dropna(subset=["thrust_0", "thrust_1"])
    T, delta = dune_actuators(prior, df["thrust_0"].astype(float), df["thrust_1"].astype(float))
    return pd.DataFrame({
        "t": df["t"], "N": df["N"], "E": df["E"], "psi": df["psi"], "u": df["u"], "v": df["v"],
        "r": df["r"], "T_cmd": T, "delta_cmd": delta,
    })  # fmt: skip



def map_table(path: Path, vehicle: str | None = None,
              advance: int | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:  # fmt: skip
    """(table of :data:`mpcasv.models.ident_thrust.MAP_COLUMNS`, the vehicle's
    :func:`~mpcasv.io.lsf.read_lsf` rows) of a DUNE log of a boat with thrusters 0 and 1.

    Row ``k`` holds EstimatedState ``k`` (at ``t_k``) and, as ``a_0``, ``a_1``, the
    actuation that acts over the step ``[t_k, t_k+1)``: the latest SetThrusterActuation of
    each thruster before ``t_(k + advance) + dt / 2``. ``advance`` (samples; default
    :data:`mpcasv.models.ident_thrust.ACTUATION_ADVANCE` = 0, chosen by the data, evidence
    there) shifts the actuations earlier (``+1``: the one sent a step later) or later
    (``-1``: a step late). With 0 the step from ``t_k`` carries DUNE's answer to
    EstimatedState ``k`` (logged 0.12 ms after it, median).

    Raises
    ------
    LogError
        Unreadable log, unknown vehicle, or no SetThrusterActuation of thruster 0 or 1.
    """
    from mpcasv.models.ident_thrust import ACTUATION_ADVANCE, check_table

    advance = ACTUATION_ADVANCE if advance is None else int(advance)

    df = read_lsf(path)
    chosen = pick_vehicle(df, path, vehicle)
    df = df[df["vehicle"] == chosen].reset_index(drop=True)
    act = read_messages(path, "SetThrusterActuation")
    act = act[act["src"] == int(df["src"].iloc[0])]
    t = df["t"].to_numpy(float)
    dt = float(np.median(np.diff(t)))
    table = pd.DataFrame({c: df[c].to_numpy(float) for c in ("t", "N", "E", "psi", "u", "v",
                                                             "r")})  # fmt: skip
    for i in (0, 1):
        s = act[act["id"] == i]
        if s.empty:
            raise LogError(f"{path}: missing messages: no SetThrusterActuation id {i} (a vessel "
                           "with two thrusters needs both)")  # fmt: skip
        k = np.searchsorted(s["t"].to_numpy(float), t + (advance + 0.5) * dt, side="right") - 1
        table[f"a_{i}"] = np.where(k >= 0, s["value"].to_numpy(float)[np.clip(k, 0, None)], 0.0)
    return check_table(table, path), df


def _thruster_map_for(logs: list[Path], prior: VesselParams):
    """DUNE's thruster map when the one log comes from DUNE's simulator (it holds
    SimulatedState: VSIM ran) with a ``Config.ini`` beside it, and the prior has differential
    actuation; else None, said on stdout for a differential prior (the thrust is then taken
    proportional to the set-point). A real vehicle's Config.ini lists the VSIM models too
    (common/vsim-models.ini is always included), so the log decides, not the file."""
    from mpcasv.io.dune_config import read_thruster_map

    if prior.actuation != "differential":
        return None
    why = None
    if len(logs) != 1:
        why = f"{len(logs)} logs (the thruster map takes one DUNE log)"
    elif not (Path(logs[0]).parent / "Config.ini").is_file():
        why = "no Config.ini beside the log"
    elif str(logs[0]).lower().endswith((".lsf", ".lsf.gz")):
        try:
            read_messages(logs[0], "SimulatedState")
        except LogError:
            why = "no SimulatedState in the log (not DUNE's simulator)"
    else:
        why = "not a DUNE log"
    if why is not None:
        print(f"{logs[0]}: {why}: thrust taken proportional to the set-point (no thruster map)")
        return None
    tmap = read_thruster_map(Path(logs[0]).parent / "Config.ini")
    print(f"{logs[0]}: identifying through DUNE's thruster map: {tmap.source}")
    return tmap


def run_map_identification(args, prior: VesselParams, tmap) -> int:
    """``mpcasv identify`` through a thruster map: writes the vessel file and a report
    folder beside it (``identify.md``, ``identify.json``)."""
    from mpcasv.models.ident_mapout import (
        gap_warning,
        held_out_text,
        map_params,
        phase_speeds,
        plot_map_replay,
        report,
        write_vessel,
        written_vessel,
    )  # fmt: skip
    from mpcasv.models.ident_thrust import HULL_COEFFS, identify_through_map, vsim_structure
    from mpcasv.models.ident_written import written_accuracy

    coeffs = tuple(c.strip() for c in args.coeffs.split(",")) if args.coeffs else HULL_COEFFS
    bad = [c for c in coeffs if c not in HULL_COEFFS]
    if bad:
        from mpcasv.config import ConfigError

        raise ConfigError(f"--coeffs: through a thruster map only {', '.join(HULL_COEFFS)} "
                          f"are identified, not {bad}")  # fmt: skip
    log = Path(args.logs[0])
    table, nav = map_table(log, getattr(args, "vehicle_pick", None))
    shaped, held = vsim_structure(prior, tmap)
    say = (lambda m: None) if args.quiet else print
    fit = identify_through_map(table, shaped, tmap, coeffs, validation=args.validation, say=say)
    name = args.out.stem
    as_written = written_accuracy(table, map_params(fit, tmap), args.validation)
    P, data = written_vessel(fit, tmap, name, held, [str(log)], prior, as_written)
    warn = gap_warning(fit, as_written)
    pick = getattr(args, "vehicle_pick", None)
    q = shlex.quote
    command = (f"mpcasv identify {q(str(log))} --vessel {q(str(args.vessel))}"
               + (f" --vehicle {q(str(pick))}" if pick is not None else "")
               + (f" --coeffs {q(args.coeffs)}" if args.coeffs else "")
               + f" --validation {args.validation:g} --out {q(str(args.out))}")  # as typed
    header = (f"# {name}: identified by `{command}` through DUNE's thruster map "
              f"({tmap.source}).\n# Hull from the log; held values and the thrust limit: see "
              "[provenance] and docs/deploy.md.\n"
              f"# 1-sigma: {fit.sigma_method}.\n"
              f"# Accuracy: {held_out_text(fit, as_written)}; also in [identification].\n"
              + (f"# {warn}.\n" if warn else ""))  # fmt: skip
    write_vessel(args.out, data, header)
    if warn:
        print(f"{args.out}: {warn}", file=sys.stderr)
    cmd = nav["ref_speed"].to_numpy(float) if "ref_speed" in nav else None
    phases = None
    if cmd is not None:
        cmd = np.nan_to_num(cmd, nan=-1.0)
        a = table[["a_0", "a_1"]].mean(axis=1).to_numpy()
        n = min(len(cmd), len(a))
        phases = phase_speeds(table["t"].to_numpy()[:n], cmd[:n], table["u"].to_numpy()[:n],
                              a[:n])  # fmt: skip
        phases = [ph for ph in phases if ph["commanded"] >= 0]
    table_md = report(fit, P, tmap, prior, phases, as_written)
    folder = args.out.with_name(args.out.stem + "-report")
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "identify.md").write_text(table_md + "\n")
    plot_map_replay(fit, folder)
    (folder / "identify.json").write_text(json.dumps({
        "coeffs": {c: getattr(P, c) for c in fit.coeffs}, "rel_std": fit.rel_std,
        "rel_std_plain": fit.rel_std_plain, "var_ratio": fit.var_ratio,
        "sigma_rel_sd": fit.sigma_rel_sd, "sigma_lag": fit.sigma_lag, "at_bound": fit.at_bound,
        "sigma_method": fit.sigma_method, "metrics": fit.metrics, "split_s": fit.split_s,
        "as_written": {"validation": as_written["validation"], "std": as_written["std"]},
        "T_max": P.T_max, "u_max": P.u_max,
        "phases": phases}, indent=1))  # fmt: skip
    print(table_md)
    print(f"wrote {args.out} and {folder}/ (identify.md, identify.json, identify_replay.png)")
    return 0


def run_cli(args) -> int:
    """``mpcasv identify LOG... --out params.toml``."""
    from mpcasv.config import ConfigError
    from mpcasv.models.ident_output import plot_replay, report_table, write_params
    from mpcasv.models.params import load_vessel

    if not 0.0 < args.validation < 0.9:  # nan too: it was a traceback from identify()
        raise ConfigError(f"--validation {args.validation:g}: the fraction of each log held out "
                          "must be in (0, 0.9)")  # fmt: skip
    if args.coeffs is not None and not args.coeffs.strip(","):
        raise ConfigError("--coeffs is empty: name coefficients, or omit it for the documented "
                          "subset")  # fmt: skip
    from mpcasv.outputs import check_output_file, check_output_folder

    check_output_file(args.out, "--out", (".toml",), parents=True)  # before the fit
    check_output_folder(args.out.with_name(args.out.stem + "-report"), "--out's report folder")
    prior = load_vessel(args.vessel)
    tmap = _thruster_map_for(args.logs, prior)
    if tmap is not None:
        return run_map_identification(args, prior, tmap)
    coeffs = tuple(c.strip() for c in args.coeffs.split(",")) if args.coeffs else IDENTIFIED
    unknown = [c for c in coeffs if c not in MODEL_COEFFS]
    if unknown:
        raise ConfigError(f"--coeffs: not model coefficients: {unknown}")
    logs = [load_log(p, prior, getattr(args, "vehicle_pick", None)) for p in args.logs]
    res = identify(logs, prior, coeffs, current=not args.no_current,
                   validation=args.validation, progress=not args.quiet)  # fmt: skip
    write_params(args.out, res, prior, [str(p) for p in args.logs])
    folder = args.out.with_name(args.out.stem + "-report")
    plot_replay(res, folder)
    table = report_table(res, prior)
    (folder / "identify.md").write_text(table + "\n")
    (folder / "identify.json").write_text(json.dumps({
        "coeffs": {c: getattr(res.params, c) for c in res.coeffs}, "rel_std": res.rel_std,
        "rel_std_plain": res.rel_std_plain, "var_ratio": res.var_ratio,
        "sigma_rel_sd": res.sigma_rel_sd, "sigma_lag": res.sigma_lag, "at_bound": res.at_bound,
        "sigma_method": res.sigma_method, "current": res.current,
        "validation_error": res.validation_error,
        "metrics": res.metrics}, indent=1))  # fmt: skip
    print(table)
    print(f"wrote {args.out} and {folder}/ (identify.md, identify.json, identify_replay.png)")
    return 0
