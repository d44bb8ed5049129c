"""The ``[identification]`` table of a vessel file written by ``mpcasv identify``: its
validation verdict and held-out accuracy, machine-readable, and the load-time refusal of a
file that failed its validation (:func:`check_identification`, run by
:func:`mpcasv.models.params.load_vessel`, so by ``tune``, ``simulate``, ``compare``,
``deploy`` and ``identify``'s prior alike).

Until session 48 the verdict was only a comment at the top (``# VALIDATION FAILED ... do not
use it as is``), which TOML loaders drop: ``mpcasv tune yaw --vessel`` tuned on such a file,
exit 0, without a word. Fields (all optional but ``validation``):

=========================== ======= ============================================================
``validation``              str     ``"passed"``; ``"failed"`` (``identify`` exited 1: a held-out
                                    fit below 0 % or a held-out error above the prior's,
                                    :mod:`mpcasv.models.ident_checks`); ``"not checked"``
                                    (identified through a thruster map: no acceptance bar)
``why``                     str     what failed, in ``identify``'s words
``use_anyway``              bool    ``true``: the user accepts a failed file (default false)
``held_out_from_s``         s       log time where the held-out part begins
``held_out_rms_through_map`` rad, m/s, rad/s  held-out RMS error (``psi``, ``u``, ``r``) of
                                    the hull driven through the log's actuator map (the fit's)
``held_out_rms_as_written`` as above, driven through this file's own actuator model (what
                                    the simulator, the MPC and the tuning use)
``held_out_std``            as above, the held-out signals' own standard deviation (scale)
=========================== ======= ============================================================
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from mpcasv.config import ConfigError, frozen, parse

#: the table's name in a vessel file
TABLE = "identification"
#: the header line ``identify`` wrote before the table existed (files of sessions <= 48)
LEGACY_FAILED = "# VALIDATION FAILED"


@frozen
class IdentRecord:
    """An ``[identification]`` table (module docstring; units rad, m/s, rad/s, s)."""

    validation: Literal["passed", "failed", "not checked"]
    why: str = ""
    use_anyway: bool = False
    held_out_from_s: float | None = None
    held_out_rms_through_map: dict[str, float] | None = None
    held_out_rms_as_written: dict[str, float] | None = None
    held_out_std: dict[str, float] | None = None


def check_identification(table: dict | None, text: str, path: str | Path) -> None:
    """Refuse, in one line, a vessel file that ``mpcasv identify`` marked as failed, unless
    its ``[identification]`` table says ``use_anyway = true``. ``text`` is the file's text: a
    file written before the table existed is recognised by its header's ``# VALIDATION
    FAILED`` line (it cannot carry the override: add the table).

    Raises
    ------
    ConfigError
        A malformed table (unknown key, wrong type), or a failed validation not accepted.
    """
    if table is None:
        first = next((ln for ln in text.splitlines() if ln.startswith(LEGACY_FAILED)), None)
        if first is not None:
            said = first.lstrip("# ").rstrip().rstrip(".")
            raise ConfigError(f"{path}: mpcasv identify marked this vessel file VALIDATION "
                              f"FAILED (its header: {said}); to use it "
                              f"anyway (you accept the model) add an [{TABLE}] table with "
                              'validation = "failed" and use_anyway = true')  # fmt: skip
        return
    if not isinstance(table, dict):
        raise ConfigError(f"{path}: {TABLE} must be a table ([{TABLE}]), not {table!r}")
    rec = parse(IdentRecord, table, f"{path} [{TABLE}]")
    if rec.validation == "failed" and not rec.use_anyway:
        why = f" ({rec.why})" if rec.why else ""
        raise ConfigError(f"{path}: mpcasv identify marked this vessel file VALIDATION FAILED"
                          f"{why}: do not use it as is; to use it anyway (you accept the model) "
                          f"set use_anyway = true in its [{TABLE}] table")  # fmt: skip
