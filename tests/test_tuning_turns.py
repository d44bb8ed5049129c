"""`mpcasv tune speed`'s turn grid (mpcasv/control/tuning_turns.py) and its bound on eq. 3.1's
largest command: the findings of a review of the session that split the turns out."""

from __future__ import annotations

import argparse
import dataclasses
import math

import pytest
from shared_data import CASES
from shared_data import needs_shared as needs_cases

from mpcasv.cli import main
from mpcasv.control.params import SpeedReference, load_execution
from mpcasv.control.tuning_checks import check_u_cmd_max
from mpcasv.models.params import load_vessel
from mpcasv.models.vessel import VesselModel

GRID = {"u_ff": [0.4, 0.6, 0.8], "k_u": [1.2, 1.59, 2.0]}  # the default grid


def _bound(vessel, base: str = "gretha", **grid) -> tuple[float, list[str]]:
    """The ``--u-cmd-max`` defaulted for ``vessel`` (a name, path or VesselParams) and the
    notes said on it."""
    params = vessel if not isinstance(vessel, str) else load_vessel(vessel)
    args = argparse.Namespace(u_cmd_max=None, base=base, vessel=str(vessel), **(GRID | grid))
    notes = check_u_cmd_max(args, load_execution(base), VesselModel(params))
    return args.u_cmd_max, notes


def test_the_default_bound_is_the_base_files_own_for_every_hull():
    """The default --u-cmd-max was the vessel's own u_max when names parsed out of the base
    file's provenance made its [reference] "another vessel's" (a review): an identified
    Gretha ("gretha-identified") got 2.5 m/s and refused the thesis's own field pair, and a
    vessel given by path differed from the same vessel by name. It is the base file's own
    again, for any hull, and the notes say where it came from."""
    gretha = load_vessel("gretha")
    identified = dataclasses.replace(gretha, name="gretha-identified")
    hulls = ("gretha", identified, "dune-otter", "mpcasv/data/vessels/dune-otter.toml")
    said = {getattr(v, "name", v): _bound(v) for v in hulls}
    assert {v: b for v, (b, _) in said.items()} == dict.fromkeys(said, 3.0976)
    for _, notes in said.values():
        assert notes[0].startswith("--u-cmd-max defaulted to the --base file's own u_ff + k_u "
                                   "pi/2 = 3.0976 m/s"), notes
        assert notes[0].endswith("for another hull pass --u-cmd-max"), notes
    # the field pair itself is admitted for the identified Gretha (it was refused, exit 2)
    assert _bound(identified, u_ff=[0.6], k_u=[1.59])[0] == 3.0976


def test_a_top_speed_below_the_bound_is_noted_not_refused():
    """Gretha's u_max 2.5 m/s is below her bound 3.0976 m/s (the execution level caps the
    reference there): said, not refused. dune-otter's 3.48 m/s is above it: not said."""
    _, notes = _bound("gretha")
    assert any("gretha's top speed u_max = 2.5 m/s is below --u-cmd-max 3.0976" in n
               for n in notes), notes  # fmt: skip
    assert not any("below --u-cmd-max" in n for n in _bound("dune-otter")[1])


@needs_cases
def test_a_hull_given_by_path_runs_with_the_default_bound(tmp_path, capsys):
    """`tune speed --vessel .../otter.toml --u-ff 0.6 --k-u 1.59` exited 2 (the field pair
    above the Otter's u_max, taken for the bound): it runs, with a note on its top speed."""
    rc = main(["tune", "speed", "--vessel", str(CASES / "vessels" / "otter.toml"), "--speeds",
               "1", "--u-ff", "0.6", "--k-u", "1.59", "--distance", "50", "--out",
               str(tmp_path / "o"), "--quiet"])  # fmt: skip
    err = capsys.readouterr().err
    assert rc in (0, 1), err
    assert "otter's top speed u_max = 3.086 m/s is below --u-cmd-max 3.0976 m/s" in err, err


def _base(tmp_path, reference: SpeedReference, provenance: str):
    from mpcasv.control.tuning import write_execution_toml

    ep = dataclasses.replace(load_execution("gretha"), reference=reference,
                             provenance=provenance)  # fmt: skip
    path = tmp_path / "base.toml"
    write_execution_toml(path, ep, ["a base file"])
    return path


@pytest.mark.parametrize(("reference", "field"), [(SpeedReference(u_ff=0.7, k_u=1.5), False),
                                                  (SpeedReference(), True)])  # fmt: skip
def test_a_reference_of_unknown_origin_is_not_called_the_field_tuning(tmp_path, reference,
                                                                      field):
    """A base file whose provenance does not say where its [reference] came from had it
    written "field tuning, thesis §3.4.1" (then read as Gretha's next time, a review): that
    label is kept for the shipped values only."""
    base = _base(tmp_path, reference, "")
    rc = main(["tune", "speed", "--base", str(base), "--speeds", "1", "--u-ff", "0.6",
               "--k-u", "1.2", "--distance", "50", "--out", str(tmp_path / "o"),
               "--quiet"])  # fmt: skip
    prov = load_execution(tmp_path / "o" / "execution.toml").provenance
    ref = next(p for p in prov.split(" | ") if p.startswith("reference: "))
    assert rc == 0
    if field:
        assert ref.startswith("reference: field tuning, thesis §3.4.1 (kept;"), ref
    else:
        assert "field tuning" not in ref, ref
        assert ref.startswith(f"reference: kept from --base {base}, origin not recorded "
                              "(u_ff = 0.7, k_u = 1.5 m/s;"), ref  # fmt: skip


def test_no_provenance_parsing_of_vessel_names_is_left():
    """One parser of the provenance's commands (tune_cli._recorded_out): the vessel-name one
    is gone with the default it decided."""
    from mpcasv.control import tuning_checks

    assert not hasattr(tuning_checks, "reference_vessel")
    assert math.isfinite(_bound("gretha")[0])
