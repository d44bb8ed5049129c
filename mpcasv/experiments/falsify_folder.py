"""The output folder of ``mpcasv falsify``: which search it holds, checked before any run.

A search (an Optuna study in ``DIR/study.db``) is defined by its family (name and content:
the template and the ranges), controller, preset (as named and its values), seed, objective
and required separation; the budget may grow and ``--workers``/``--timeout`` change nothing
a run gives. This identity is written to ``DIR/falsify.json`` (:data:`IDENTITY_FILE`) before
the first trial. Rerunning with the same identity resumes the study; a folder holding another
search is refused in one line saying what differs (:func:`check_study_folder`). Before, the
study's name left out the seed (another ``--seed`` resumed the old study), and another family
or controller added its worst cases next to the first search's in ``DIR/worst``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

from mpcasv.config import ConfigError

#: what a search's runs are (:func:`study_identity`); 2 since session 44, 3 since session 48
#: (the world's synchronised random streams, :mod:`mpcasv.sim.streams`: a study of format 2
#: holds runs of the old draws and is refused, not extended)
SEARCH_FORMAT = 3
#: the file recording the search a folder holds
IDENTITY_FILE = "falsify.json"
#: files a search writes into its folder (a folder with any of them and no IDENTITY_FILE was
#: written before the identity was recorded: its seed is unknown)
SEARCH_FILES = ("study.db", "trials.csv", "trials.md", "summary.json", "worst")


def _sha(obj) -> str:
    text = json.dumps(obj, sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def study_identity(family, controller: str, preset: str | None, params, seed: int,
                   objective: str, separation: float | None) -> dict:  # fmt: skip
    """What defines a search (see the module docstring), as JSON-ready values.

    ``family`` is a :class:`~mpcasv.experiments.falsify_family.LoadedFamily`; ``params`` the
    controller's validated preset (its values are hashed, so an edited preset file is
    another search).
    """
    return {
        # 2 (session 44): every run carries the search's preset, whose [domain] the world
        # judges by (the power turn); a search of format 1 (none: runs without it) is another
        # search and is refused, not extended
        "format": SEARCH_FORMAT,
        "family": family.name,
        # its description and the template's name and description say nothing of the search:
        # editing them keeps the study (a review)
        "family_sha256": _sha([_without(dataclasses.asdict(family.spec)),
                               _without(family.template, "name")]),
        "controller": controller,
        "preset": preset or "default",
        "preset_sha256": _sha(dataclasses.asdict(params)),
        "seed": seed,
        "objective": objective,
        "separation_m": separation,
    }


def _without(d: dict, *keys: str) -> dict:
    """``d`` less its ``description`` (and ``keys``)."""
    return {k: v for k, v in d.items() if k not in ("description", *keys)}


def check_study_folder(out: Path, identity: dict, option: str = "--out") -> None:
    """Refuse ``out`` when it holds another search than ``identity`` (the same one resumes).

    Raises
    ------
    ConfigError
        One line naming the option, the folder and what differs (``seed 0 there, 1 now``),
        or saying that the folder holds a search of unknown identity, or that its identity
        file cannot be read; each asks for another ``--out``.
    """
    recorded = out / IDENTITY_FILE
    if not recorded.exists():
        found = [f for f in SEARCH_FILES if (out / f).exists()]
        if found:
            raise ConfigError(f"{option} {out}: holds a falsification search ({', '.join(found)}) "
                              f"without {IDENTITY_FILE} (written before mpcasv recorded what "
                              "defines a search: its seed is unknown), so it cannot be "
                              "resumed: choose another --out")  # fmt: skip
        return
    try:
        there = json.loads(recorded.read_text())
        if not isinstance(there, dict):
            raise ValueError("not a JSON object")
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ConfigError(f"{option} {out}: its {IDENTITY_FILE} cannot be read ({exc}): choose "
                          "another --out") from None  # fmt: skip
    differs = [f"{k} {there.get(k)!r} there, {v!r} now" for k, v in identity.items()
               if there.get(k) != v]  # fmt: skip
    if differs:
        raise ConfigError(f"{option} {out}: holds another falsification search "
                          f"({'; '.join(differs)}): choose another --out (the same search "
                          "resumes there)")  # fmt: skip


def record_study(out: Path, identity: dict) -> None:
    """Write ``identity`` as ``out/falsify.json`` (before the first trial)."""
    out.mkdir(parents=True, exist_ok=True)
    (out / IDENTITY_FILE).write_text(json.dumps(identity, indent=1) + "\n")
