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
    # they run, at u_max ("commands above it are not run", a review): u_ref = min(eq. 3.1,
    # command, u_max) in the execution level
    note = next(n for n in notes if "below --u-cmd-max" in n)
    assert note.endswith("(u_ref = min(eq. 3.1, command, u_max)), so speeds eq. 3.1 asks "
                         "above it are run at u_max"), note  # fmt: skip
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


def test_a_kept_reference_gets_each_runs_recommendation(tmp_path, capsys):
    """A [reference] "kept from --base FILE, origin not recorded" was copied unchanged into
    the next run's file (a review): a second run recommending (0.8, 1.2) wrote the first
    run's "recommends u_ff=0.6, k_u=1.2". The origin (the first base) is kept, the
    recommendation is this run's."""
    base = _base(tmp_path, SpeedReference(u_ff=0.7, k_u=1.5), "")

    def run(b, u_ff, out):
        rc = main(["tune", "speed", "--base", str(b), "--speeds", "1", "--u-ff", u_ff,
                   "--k-u", "1.2", "--distance", "50", "--out", str(tmp_path / out),
                   "--quiet"])  # fmt: skip
        assert rc == 0
        prov = load_execution(tmp_path / out / "execution.toml").provenance
        return next(p for p in prov.split(" | ") if p.startswith("reference: "))

    first = run(base, "0.6", "ch1")
    assert "recommends u_ff=0.6, k_u=1.2 " in first, first
    capsys.readouterr()
    second = run(tmp_path / "ch1" / "execution.toml", "0.8,0.4", "ch2")
    assert "recommended (u_ff, k_u) = (0.8, 1.2)" in capsys.readouterr().out
    assert second.startswith(f"reference: kept from --base {base}, origin not recorded "
                             "(u_ff = 0.7, k_u = 1.5 m/s; the turn grid of mpcasv tune speed "
                             "recommends u_ff=0.8, k_u=1.2 within"), second  # fmt: skip
    assert second.count("recommends") == 1, second


def test_no_provenance_parsing_of_vessel_names_is_left():
    """One parser of the provenance's commands (tune_cli._recorded_out): the vessel-name one
    is gone with the default it decided."""
    from mpcasv.control import tuning_checks

    assert not hasattr(tuning_checks, "reference_vessel")
    assert math.isfinite(_bound("gretha")[0])


def _no_work(monkeypatch):
    """Make any design work fail the test at once (a refusal must come before it: the old
    code ran ``--distance 1e9`` for ever)."""
    from mpcasv.control import tuning_speed

    def started(*a, **k):
        raise AssertionError("the design started: not refused")

    monkeypatch.setattr(tuning_speed, "place_speed_pi", started)


@pytest.mark.parametrize(("argv", "words"), [
    (["--distance", "1e9"], ["--distance 1e+09 m", "above the 1800 s cap",
                             "at 0.4 m/s distances must be at most 660 m"]),
    (["--distance", "50", "--u-ff", "0.01"], ["--distance 50 m", "= 5150 s, above the 1800 s",
                                              "or give a larger --u-ff"]),
    (["--distance", "20,5"], ["--distance 5 m", "at or inside the 5 m arrival circle",
                              "distances must exceed 5 m"]),
])  # fmt: skip
def test_a_distance_outside_the_runs_bounds_is_refused_in_one_line(tmp_path, capsys,
                                                                   monkeypatch, argv, words):
    """``--distance 1e9`` hung (the run lasts 150 s + distance / min(u_ff, u_max), a review):
    a turn's run is capped at TURN_RUN_MAX, refused beyond it before any work, one line,
    exit 2; so is a distance not beyond the arrival radius, in the words the rule uses."""
    _no_work(monkeypatch)
    try:
        rc = main(["tune", "speed", *argv, "--out", str(tmp_path / "o"), "--quiet"])
    except SystemExit as exc:
        rc = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    for w in words:
        assert w in err[0], (w, err[0])


def test_a_waypoint_on_the_arrival_circle_is_inside_it_everywhere(model, shipped):
    """`--distance 5` was refused as "inside" the 5 m circle while arrival() took only
    ``dist < 5`` for reached (a review): the edge is inside for both, one rule
    (tuning_turns.in_circle), and turn() says it in the same words as the refusal."""
    import numpy as np

    from mpcasv.control.tuning_turns import ARRIVAL_RADIUS, arrival, turn

    X = np.zeros((3, 6))
    X[:, 1] = [9.0, ARRIVAL_RADIUS, 1.0]  # east of a waypoint at the origin
    assert arrival(X, (0.0, 0.0))[1] == 1  # the sample on the circle has arrived
    ep = dataclasses.replace(shipped, turn_thrust=0.0)
    with pytest.raises(ValueError, match="waypoint 5 m: at or inside the 5 m arrival circle"):
        turn(model, ep, math.radians(90.0), ARRIVAL_RADIUS)


@pytest.mark.parametrize("distance", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("u_slow", [None, 0.4])
def test_a_distance_that_is_not_finite_is_refused(model, shipped, distance, u_slow):
    """``distance_refusal`` passed NaN (``NaN <= radius`` is False, and so is the run cap's
    ``>``) and, without a run cap, inf (a review): turn() would have run them. Both are
    refused, by the rule and by turn()."""
    from mpcasv.control.tuning_turns import distance_refusal, turn

    why = distance_refusal(distance, u_slow)
    assert why is not None and "not a finite number" in why, why
    ep = dataclasses.replace(shipped, turn_thrust=0.0)
    with pytest.raises(ValueError, match="not a finite number"):
        turn(model, ep, math.radians(90.0), distance, t_end=1.0)


@pytest.mark.parametrize(("distance", "u_slow", "words"), [
    (660.0001, 0.4, ["660.0001 m: a turn would run 150 s + 660.0001 m / 0.4 m/s",
                     "= 1800.0002 s, above the 1800 s cap", "must be at most 660 m"]),
    (660.06, 0.40002, ["= 1800.1 s", "at 0.40002 m/s distances must be at most 660 m"]),
    (16.5001, 0.01, ["= 1800.01 s", "at 0.01 m/s distances must be at most 16.5 m"]),
    (4.9999999, None, ["4.9999999 m: at or inside the 5 m arrival circle"]),
])  # fmt: skip
def test_the_run_caps_refusal_shows_the_digits_that_differ(distance, u_slow, words):
    """The run cap's refusal rounded with ``:g``: "660 m: ... = 1800 s, above the 1800 s
    cap; ... at most 660 m" for 660.0001 m (a review). It shows the distance as given, the
    run above the cap and a longest distance not above the refused one."""
    import re

    from mpcasv.control.tuning_turns import distance_refusal

    why = distance_refusal(distance, u_slow)
    for w in words:
        assert w in why, (w, why)
    run = re.search(r"= ([0-9.e+]+) s, above", why)
    most = re.search(r"at most ([0-9.e+]+) m", why)
    if run:
        assert float(run.group(1)) > 1800 and float(most.group(1)) < distance, why


def test_the_speed_options_help_says_the_real_defaults_and_bounds(capsys):
    """`--u-cmd-max`'s help said "the base file's own" beside a default that was not; the
    `--distance` help gave no bound (a review). The numbers are the code's."""
    from mpcasv.control.tuning_turns import ARRIVAL_RADIUS, TURN_RUN_MAX, TURN_T_END

    with pytest.raises(SystemExit):
        main(["tune", "speed", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert f"must exceed the {ARRIVAL_RADIUS:g} m arrival radius" in text, text
    assert f"at most {TURN_RUN_MAX:g} s ({TURN_T_END:g} s + distance / min(u_ff, u_max))" in text
    assert ("default: the --base file's own u_ff + k_u pi/2, 3.0976 for Gretha's shipped "
            "file") in text, text


def _pass_and_loop(loops: float = 1.5, wp=(0.0, 30.0), rho: float = 10.0):
    """A synthetic boat heading east straight at the waypoint ``wp`` (m), on course into the
    5 m circle and through it, then looping ``loops`` times round the waypoint ``rho`` m
    away (heading error 90 deg: never heading back for it)."""
    from types import SimpleNamespace

    import numpy as np

    E = np.arange(0.0, wp[1] + rho, 0.1)
    N, psi = np.zeros_like(E), np.full_like(E, np.pi / 2)
    th = np.linspace(np.pi / 2, np.pi / 2 + 2 * np.pi * loops, 2000)[1:]
    N = np.concatenate([N, wp[0] + rho * np.cos(th)])
    E = np.concatenate([E, wp[1] + rho * np.sin(th)])
    psi = np.concatenate([psi, th + np.pi / 2])  # the tangent, anticlockwise on the chart
    X = np.zeros((len(N), 6))
    X[:, 0], X[:, 1], X[:, 2] = N, E, psi
    los = np.arctan2(wp[1] - E, wp[0] - N)
    return SimpleNamespace(X=X, psi_error=(psi - los + np.pi) % (2 * np.pi) - np.pi)


def test_the_turning_after_the_arrival_counts_from_the_first_sample_outside_the_circle():
    """The post-arrival window started at the arrival sample itself, so the heading error
    of that one sample decided the verdict (a review): a boat arriving on course was taken
    as "heading back" at once, and a loop and a half round the waypoint after passing it
    counted 0 deg. The window starts at the first sample back outside the circle."""
    import numpy as np

    from mpcasv.control.tuning_turns import PIROUETTE_TURN, arrival, circling

    run = _pass_and_loop(1.5)
    dist, n = arrival(run.X, (0.0, 30.0))
    assert abs(run.psi_error[n]) < math.radians(1.0)  # on course at the arrival
    c = circling(run, (0.0, 30.0), 0.0)
    assert c > PIROUETTE_TURN, np.degrees(c)  # 1.5 loops (540 deg) + the 90 deg swing
    assert circling(_pass_and_loop(0.5), (0.0, 30.0), 0.0) < PIROUETTE_TURN  # half a loop


def test_no_recommendation_counts_each_pair_once():
    """"of the 1 (u_ff, k_u) pairs ... 1 pirouetted (P) and 1 did not reach (NR)" read as
    two pairs (a review): a pair that pirouetted in one turn and missed the waypoint in
    another is counted once, as both; the counts add up to the pairs."""
    from mpcasv.control.tuning_turns import TurnRow, why_none

    def row(u_ff, *flags):
        return TurnRow(u_ff=u_ff, k_u=1.0, figures={
            a: {"pirouette": "P" in f, "reached": "NR" not in f, "turn_s": 1.0}
            for a, f in zip((90.0, 180.0), flags, strict=True)})  # fmt: skip

    one = why_none([row(0.6, "P", "NR")], 5.0)
    assert one == ("of the 1 (u_ff, k_u) pair of the grid with u_ff + k_u pi/2 <= 5 m/s, 1 did "
                   "both (P and NR): no recommendation"), one
    three = why_none([row(0.4, "P", "NR"), row(0.6, "P", ""), row(0.8, "", "NR")], 5.0)
    assert ("of the 3 (u_ff, k_u) pairs of the grid with u_ff + k_u pi/2 <= 5 m/s, 1 pirouetted "
            "in a turn (P), 1 did not reach a waypoint within the run (NR) and 1 did both (P "
            "and NR): no recommendation") == three, three
