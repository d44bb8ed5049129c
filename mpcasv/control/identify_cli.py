"""``mpcasv identify`` on top of :func:`mpcasv.io.identlog.run_cli`: the refusals it lacked
and the validation acceptance (exit codes: :func:`run_identify`)."""

from __future__ import annotations

import argparse
import json

from mpcasv.config import ConfigError
from mpcasv.errors import LogError

DUNE_LOGS = (".lsf", ".lsf.gz")


def check_identify(args: argparse.Namespace) -> None:
    """Refuse, in one line, what the identification would misread: a folder given as a log,
    ``--vehicle`` without a DUNE log (CSV and parquet logs hold one vehicle: it was ignored),
    a coefficient named twice in ``--coeffs``."""
    for p in args.logs:
        if p.is_dir():
            raise LogError(f"{p}: a folder, not a log file (give the logs in it, e.g. "
                           f"{p / '*.csv'})")  # fmt: skip
    pick = getattr(args, "vehicle_pick", None)
    if pick is not None and not any(str(p).lower().endswith(DUNE_LOGS) for p in args.logs):
        logs = ", ".join(map(str, args.logs))
        raise ConfigError(f"--vehicle {pick}: picks a vehicle of a DUNE log (.lsf, .lsf.gz); "
                          f"{logs}: a CSV or parquet log holds one vehicle; leave --vehicle out")
    names = [c.strip() for c in (args.coeffs or "").split(",") if c.strip()]
    twice = sorted({c for c in names if names.count(c) > 1})
    if twice:
        raise ConfigError(f"--coeffs {args.coeffs}: {', '.join(twice)} given more than once")


def run_identify(args: argparse.Namespace) -> int:
    """``mpcasv identify``: 0 identified and validated; 1 identified, but a held-out fit is
    below 0 % (the model predicts the validation data worse than their mean) or its held-out
    weighted error is above the prior's (:func:`~mpcasv.models.ident_checks.worse_than_prior`:
    it predicts them worse than the prior): reported, and the TOML says VALIDATION FAILED (in
    its header and, machine-readable, ``[identification] validation = "failed"``, which every
    loader refuses: :mod:`mpcasv.models.ident_record`); 2
    bad input (incl. coefficients the logs cannot identify, nothing written)."""
    from mpcasv.io.identlog import run_cli
    from mpcasv.models.ident_checks import validation_failures, worse_than_prior

    check_identify(args)
    rc = run_cli(args)
    report = args.out.with_name(args.out.stem + "-report") / "identify.json"
    if rc or not report.is_file():
        return rc
    rec = json.loads(report.read_text())
    failed = validation_failures(rec.get("metrics", {}))
    if failed:
        fits = ", ".join(f"{c} {v:.1f} %" for c, v in failed.items())
        print(f"validation FAIL: held-out fit below 0 % for {fits}: the identified model "
              f"predicts the held-out data worse than their mean; {args.out} is marked "
              "VALIDATION FAILED, do not use it as is (its [identification] validation = "
              "\"failed\": mpcasv refuses to load it unless use_anyway = true there)")  # fmt: skip
    worse = worse_than_prior(rec.get("validation_error", {}))
    if worse:
        print(f"validation FAIL: held-out weighted error {worse:.3g} x the prior's: the "
              f"identified model predicts the held-out data worse than the prior; {args.out} "
              "is marked VALIDATION FAILED, keep the prior (its [identification] validation = "
              "\"failed\": mpcasv refuses to load it unless use_anyway = true there)")  # fmt: skip
    return 1 if failed or worse else rc
