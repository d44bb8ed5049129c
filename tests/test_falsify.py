"""`mpcasv falsify` (issue 14): family substitution, the robustness measure, the CMA-ES search
(reproducible, resumable after a kill) and the committed worst cases (regression scenarios)."""

from __future__ import annotations

import json
import math
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mpcasv.cli import main
from mpcasv.config import ConfigError
from mpcasv.experiments.falsify import (
    SearchSetup,
    candidate,
    load_family,
    robustness,
    search,
    set_dotted,
    trials_table,
)

ROOT = Path(__file__).resolve().parents[1]
FAMILIES = ROOT / "experiments" / "falsify"
FALSIFIED = ROOT / "experiments" / "scenarios" / "falsified"


def short_family(tmp_path: Path, duration: float = 60.0) -> Path:
    """pursuer-single, cut to ``duration`` s (cheap runs for the search tests)."""
    text = (FAMILIES / "pursuer-single.toml").read_text()
    text = text.replace("duration = 400.0", f"duration = {duration}", 1)
    path = tmp_path / "short.toml"
    path.write_text(text)
    return path


# --- families ---------------------------------------------------------------------------------


def test_set_dotted_walks_dicts_and_list_indices_and_refuses_missing_items():
    data = {"auv": [{"events": [{"t": 1.0}]}]}
    set_dotted(data, "auv.0.events.0.t", 5.0)
    set_dotted(data, "acoustics.p_good", 0.5)
    assert data["auv"][0]["events"][0]["t"] == 5.0 and data["acoustics"] == {"p_good": 0.5}
    with pytest.raises(ConfigError, match="no item '3'"):
        set_dotted(data, "auv.3.start.N", 1.0)
    with pytest.raises(ConfigError, match="is a value"):
        set_dotted(data, "auv.0.events.0.t.x", 1.0)


def test_candidate_writes_fields_sums_and_polar_pairs_then_validates():
    fam = load_family(FAMILIES / "pursuer-single.toml")
    params = {p.name: p.low for p in fam.spec.param}
    params |= {"approach_deg": 90.0, "t_attack": 50.0, "rise_after": 30.0, "depth": 12.0,
               "current_speed": 0.4, "current_deg": 180.0, "speed": 1.5}  # fmt: skip
    sc, _ = candidate(fam, params, "test")
    auv = sc.auv[0]
    assert (auv.start.N, auv.start.E) == pytest.approx((0.0, 150.0), abs=1e-9)  # polar
    assert [e.t for e in auv.events] == [50.0, 80.0]  # rise_after plus t_attack
    assert auv.start.depth == auv.events[0].pursuer.depth == 12.0  # one value, three fields
    assert auv.events[1].pursuer.depth == 0.0 and auv.events[1].pursuer.speed == 1.5
    assert sc.current == pytest.approx((-0.4, 0.0), abs=1e-9)


def test_family_errors_name_the_file(tmp_path):
    text = (FAMILIES / "pursuer-single.toml").read_text()
    bad = tmp_path / "typo.toml"
    bad.write_text(text.replace('field = "acoustics.p_good"', 'field = "acoustics.p_godo"'))
    with pytest.raises(ConfigError, match=r"typo\.toml.*p_godo"):
        load_family(bad)  # the scenario loader refuses the unknown key
    bad.write_text(text.replace("low = 0.3", "low = 0.99"))
    with pytest.raises(ConfigError, match=r"typo\.toml.*low must be < high"):
        load_family(bad)
    bad.write_text(text + "\nsurprise = 1\n")
    with pytest.raises(ConfigError, match=r"typo\.toml.*surprise"):
        load_family(bad)


# --- the measure ------------------------------------------------------------------------------


def test_robustness_margin_and_longest_stay_from_the_time_series():
    t = np.arange(1.0, 11.0)
    # AUV 0 at the surface, AUV 1 at 40 m (domain radius sqrt(50^2 - 40^2) = 30 m)
    r0 = np.array([80, 60, 45, 40, 45, 60, 80, 45, 80, 80], float)  # inside at 3-5 and 8
    r1 = np.array([90, 90, 90, 90, 90, 90, 90, 90, 25, 90], float)  # inside at 9
    ts = pd.DataFrame({"t": t, "range0": r0, "slant0": r0, "auv0_depth": 0.0, "range1": r1,
                       "slant1": np.hypot(r1, 40.0), "auv1_depth": 40.0})  # fmt: skip
    rob = robustness(ts, 2, 50.0, 1.0)
    assert rob.margin_m == pytest.approx(-10.0) and rob.t_margin_s == 4.0 and rob.auv_margin == 0
    assert rob.longest_stay_s == 3.0  # t = 3, 4, 5; then 8-9 (two AUVs in turn) is 2
    assert rob.time_inside_s == 5.0
    # the surface-domain test and slant < r_sep are one set (Paper 2 eq. 5)
    assert math.hypot(25.0, 40.0) - 50.0 < 0


# --- the search -------------------------------------------------------------------------------


def _finished(db: Path) -> dict[int, tuple]:
    """(params, value) of every COMPLETE trial in a study file (read without Optuna)."""
    # one read transaction: two separate SELECTs could see a trial finish between them
    # (its params without its value: KeyError, seen once in CI)
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, isolation_level=None)
    try:
        con.execute("BEGIN")
        rows = con.execute(
            "SELECT t.number, v.value FROM trials t JOIN trial_values v USING (trial_id) "
            "WHERE t.state = 'COMPLETE'").fetchall()  # fmt: skip
        params = con.execute(
            "SELECT t.number, p.param_name, p.param_value FROM trials t JOIN trial_params p "
            "USING (trial_id) WHERE t.state = 'COMPLETE'").fetchall()  # fmt: skip
    finally:
        con.close()
    out = {n: ({}, v) for n, v in rows}
    for n, name, value in params:
        if n in out:  # a trial with a value (COMPLETE is told with its value)
            out[n][0][name] = value
    return out


def test_search_is_reproducible_whatever_the_number_of_workers(tmp_path):
    fam = load_family(short_family(tmp_path, 40.0))
    tables = []
    for workers in (1, 2):
        setup = SearchSetup(fam, "hybrid-single", "paper1-field", seed=3)
        study = search(setup, tmp_path / f"w{workers}.db", budget=4, workers=workers)
        tables.append(trials_table(study).sort_values("trial").reset_index(drop=True))
    pd.testing.assert_frame_equal(tables[0], tables[1])
    assert len(tables[0]) == 4 and tables[0]["margin_m"].notna().all()


def test_a_search_killed_while_asking_resumes(tmp_path):
    """A search stopped while a batch was being asked leaves a RUNNING trial with some of its
    parameters; a resume draws the rest and runs it (it ended every resume in a traceback,
    KeyError on the first missing parameter: a new user's Ctrl-C, session 47)."""
    fam = load_family(short_family(tmp_path, 40.0))
    setup = SearchSetup(fam, "hybrid-single", "paper1-field", seed=3)
    db = tmp_path / "s.db"
    study = search(setup, db, budget=2)
    first = fam.spec.param[0]
    trial = study.ask()  # as the interrupted ask left it: one parameter drawn
    if first.integer:
        trial.suggest_int(first.name, int(first.low), int(first.high))
    else:
        trial.suggest_float(first.name, first.low, first.high)
    study = search(setup, db, budget=3)
    table = trials_table(study)
    assert len(table) == 3 and table["margin_m"].notna().all()
    resumed = study.trials[trial.number]
    assert resumed.state.name == "COMPLETE"
    assert set(resumed.params) == {p.name for p in fam.spec.param}


def test_a_smaller_budget_than_the_runs_finished_is_refused(tmp_path):
    """A rerun with a smaller ``--budget`` ran nothing and wrote a summary saying that budget
    above more finished runs (session 47's leftover); now refused in one line, as ``tune
    controller`` refuses it."""
    setup = SearchSetup(load_family(short_family(tmp_path, 40.0)), "hybrid-single",
                        "paper1-field", seed=3)  # fmt: skip
    db = tmp_path / "s.db"
    search(setup, db, budget=2)
    with pytest.raises(ConfigError, match=r"holds 2 finished runs already, more than "
                                          r"--budget 1; give at least 2"):  # fmt: skip
        search(setup, db, budget=1)
    assert len(trials_table(search(setup, db, budget=2))) == 2  # the same budget: resumes


def _falsify_cmd(family: Path, out: Path, budget: int) -> list[str]:
    return [sys.executable, "-m", "mpcasv.cli", "falsify", str(family), "--controller",
            "hybrid-single", "--params", "paper1-field", "--budget", str(budget), "--out",
            str(out), "--worst", "1", "--quiet"]  # fmt: skip


def test_killed_search_resumes_without_losing_a_finished_run(tmp_path):
    family, out = short_family(tmp_path, 120.0), tmp_path / "search"
    db = out / "study.db"
    env = os.environ | {"PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
    proc = subprocess.Popen(_falsify_cmd(family, out, 12), env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)  # fmt: skip
    deadline = time.monotonic() + 120
    before: dict = {}
    while time.monotonic() < deadline and proc.poll() is None:
        if db.exists():
            try:
                before = _finished(db)
            except sqlite3.OperationalError:  # schema not created yet / locked
                before = {}
            if len(before) >= 5:
                break
        time.sleep(0.05)
    assert proc.poll() is None, proc.communicate()  # still running: killed mid-search
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    proc.stdout.close()  # (not read: a child it left may still hold them)
    proc.stderr.close()
    before = _finished(db)
    assert 5 <= len(before) < 12
    done = subprocess.run(_falsify_cmd(family, out, 12), env=env, capture_output=True,
                          text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr
    after = _finished(db)
    assert len(after) == 12  # the budget counts finished runs; interrupted ones rerun
    for n, (params, value) in before.items():  # nothing finished was lost or changed
        assert after[n][0] == pytest.approx(params) and after[n][1] == pytest.approx(value)
    table = pd.read_csv(out / "trials.csv")
    assert len(table) == 12 and (table["state"] == "complete").all()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["worst_margin_m"] == pytest.approx(min(v for _, v in after.values()))
    # the killed and resumed search is the search run at once: the interrupted trials are
    # run again under their numbers with their parameters, and each batch's sampler is
    # seeded from the search's seed and the trials before it (until session 44 they were
    # dropped for new ones and the resumed search missed the uninterrupted one's worst case)
    whole = tmp_path / "whole"
    done = subprocess.run(_falsify_cmd(family, whole, 12), env=env, capture_output=True,
                          text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert _finished(whole / "study.db") == after
    once = pd.read_csv(whole / "trials.csv")
    pd.testing.assert_frame_equal(table.drop(columns="state"), once.drop(columns="state"))


def test_ctrl_c_stops_a_search_with_workers_in_one_line(tmp_path):
    """Ctrl-C (SIGINT to the whole process group, as a terminal sends it) while two worker
    processes run: exit 130 with the one 'interrupted' line, no worker's traceback (38-73
    lines of them before: a new user, session 47), and the workers are gone."""
    family, out = short_family(tmp_path, 120.0), tmp_path / "search"
    env = os.environ | {"PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
    # (SIGINT as a terminal leaves it: a test run started in the background of a shell
    # inherits it ignored, and so would the search)
    proc = subprocess.Popen([*_falsify_cmd(family, out, 40), "--workers", "2"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True, preexec_fn=_default_sigint)  # fmt: skip
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            if len(_finished(out / "study.db")) >= 2:  # the pool is up and running runs
                break
        except sqlite3.OperationalError:  # not created yet / locked
            pass
        time.sleep(0.05)
    assert proc.poll() is None, proc.communicate()
    for _ in range(3):  # (a Ctrl-C while the pool starts processes is lost: press again)
        os.killpg(proc.pid, signal.SIGINT)
        try:
            _, err = proc.communicate(timeout=20)
            break
        except subprocess.TimeoutExpired:
            continue
    else:
        os.killpg(proc.pid, signal.SIGKILL)
        raise AssertionError("the search did not stop on Ctrl-C")
    err = err.decode()
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert "interrupted" in err


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_the_search_workers_leave_ctrl_c_to_the_search():
    """The search's worker processes start with SIGINT ignored (the search stops them), so
    a Ctrl-C to the process group interrupts no worker mid-import or between runs."""
    from mpcasv.experiments.falsify_pool import WorkerPool

    # as a terminal leaves it (a test run started in the background of a shell inherits
    # SIGINT ignored, and the restoration below would restore that)
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        _search_workers_ignore_sigint(WorkerPool)
    finally:
        signal.signal(signal.SIGINT, before)


def _search_workers_ignore_sigint(WorkerPool) -> None:
    with WorkerPool(2, None) as pool:
        handlers = [f.result() for f in [pool.pool.submit(signal.getsignal, signal.SIGINT)
                                         for _ in range(4)]]  # fmt: skip
    assert handlers == [signal.SIG_IGN] * 4
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored here


def test_cli_writes_worst_cases_that_load_and_reproduce_their_margin(tmp_path):
    out = tmp_path / "f"
    code = main(["falsify", str(short_family(tmp_path, 60.0)), "--controller", "hybrid-single",
                 "--params", "paper1-field", "--budget", "4", "--out", str(out), "--worst", "2",
                 "--quiet", "--require-margin", "1000"])  # fmt: skip
    assert code == 1  # every margin is below 1000 m: the check fails (exit 1, not 2)
    summary = json.loads((out / "summary.json").read_text())
    assert len(summary["worst_cases"]) == 2
    from mpcasv.sim.scenario import load_scenario

    for name in summary["worst_cases"]:
        sc = load_scenario(out / "worst" / f"{name}.toml")
        assert sc.controller == "hybrid-single" and sc.preset == "paper1-field"
        assert (out / "worst" / name / "range.png").is_file()
        assert (out / "worst" / name / "paths.png").is_file()
    assert "| trial |" in (out / "trials.md").read_text()


def test_simulate_of_a_written_worst_case_is_the_searched_run(tmp_path):
    """The trials run the scenario the worst case is written as (with the preset, whose
    [domain] the world judges by: the escape power turn, the domain metrics), so `mpcasv
    simulate FILE` gives the searched margin. Until session 44 the trials ran the family's
    template without a preset (no domain: no power turn, domain metrics null) and simulate
    of the written file ran another world (-36.72 m searched, -34.28 m simulated)."""
    out = tmp_path / "f"
    assert main(["falsify", str(short_family(tmp_path, 150.0)), "--controller", "hybrid-single",
                 "--params", "paper1-field", "--budget", "4", "--out", str(out), "--worst", "1",
                 "--quiet"]) == 0  # fmt: skip
    summary = json.loads((out / "summary.json").read_text())
    (name,) = summary["worst_cases"]
    run = tmp_path / "sim"
    assert main(["simulate", str(out / "worst" / f"{name}.toml"), "--out", str(run)]) == 0
    rob = robustness(pd.read_parquet(run / "timeseries.parquet"), 1, 50.0, 1.0)
    assert rob.margin_m == pytest.approx(summary["worst_margin_m"], abs=1e-9)
    assert json.loads((out / "worst" / name / "run.json").read_text())["scenario"] == name
    searched = json.loads((out / "worst" / name / "metrics.json").read_text())
    assert searched["collision_domain_s"] is not None  # judged by paper1-field's domain
    from mpcasv.experiments.metric_info import WALL_CLOCK

    simulated = json.loads((run / "metrics.json").read_text())
    for wall in WALL_CLOCK:  # measured, not simulated
        searched.pop(wall, None), simulated.pop(wall, None)
    assert searched == simulated


def test_a_worst_case_found_with_a_seed_says_the_seed(tmp_path, capsys):
    """A scenario file holds no seed: a search with --seed 3 writes its worst case with a
    header naming `--seed 3`, and its last line says to simulate with it; that run is the
    searched one (at the default seed 0 it was another: a new user, session 47)."""
    out = tmp_path / "f"
    assert main(["falsify", str(short_family(tmp_path, 60.0)), "--controller", "hybrid-single",
                 "--params", "paper1-field", "--budget", "2", "--out", str(out), "--worst", "1",
                 "--seed", "3", "--quiet"]) == 0  # fmt: skip
    assert "simulate them with --seed 3" in capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    (name,) = summary["worst_cases"]
    path = out / "worst" / f"{name}.toml"
    assert f"# the searched run: mpcasv simulate {name}.toml --seed 3" in path.read_text()
    run = tmp_path / "sim"
    assert main(["simulate", str(path), "--out", str(run), "--seed", "3"]) == 0
    rob = robustness(pd.read_parquet(run / "timeseries.parquet"), 1, 50.0, 1.0)
    assert rob.margin_m == pytest.approx(summary["worst_margin_m"], abs=1e-9)


def test_a_worst_case_names_a_relative_preset_path_from_its_own_folder(tmp_path, monkeypatch):
    """`--params presets/my.toml` (relative to where the command ran) is written as an
    absolute path: the worst case loads from its own folder (it said "no such file
    .../worst/presets/my.toml")."""
    (tmp_path / "presets").mkdir()
    shipped = ROOT / "mpcasv" / "data" / "presets" / "paper1-field.toml"
    (tmp_path / "presets" / "my.toml").write_text(shipped.read_text())
    monkeypatch.chdir(tmp_path)
    assert main(["falsify", str(short_family(tmp_path, 40.0)), "--controller", "hybrid-single",
                 "--params", "presets/my.toml", "--budget", "1", "--out", "f", "--worst", "1",
                 "--quiet"]) == 0  # fmt: skip
    from mpcasv.sim.scenario import load_scenario

    (written,) = (tmp_path / "f" / "worst").glob("*.toml")
    monkeypatch.chdir(ROOT)
    sc = load_scenario(written)
    assert sc.preset == str(tmp_path / "presets" / "my.toml")


# --- committed worst cases (regression scenarios) ---------------------------------------------
# Today's (margin m, longest stay s) on each, measured by `mpcasv falsify` (docs/safety.md,
# budget 32, seed 0) and rerun from the committed files. The tolerances absorb floating-point
# differences between machines, not behaviour changes.
PINNED: dict[str, tuple[float, float]] = {
    # re-measured at the end of session 4: Gretha's power turn acts in escapes decided from
    # the true ranges (the ASV inside a collision domain), the same for every controller
    # (docs/tuning.md); the MPC rescues and escapes itself (issue 16 item 7) and plans with
    # the estimated current and observed thrust (items 1, 4). These are the committed worst
    # cases' behaviour today, not the searches' margins (docs/safety.md). Session 3's pins
    # in brackets. Session 34: the simulator starts the ASV carried by the current (it was
    # at rest over ground, held against the current): every case has a current, starts
    # differently and takes another path (the four pins re-measured, "was": the value
    # before; the mpc-multi case moved within its envelope, below)
    # Session 48's common random numbers (mpcasv.sim.streams: every run meets other channel
    # and navigation noise than before, ping for ping the same across controllers) moved
    # every pin but the chaotic mpc-multi envelope; "s48 was": the value before
    "falsified-crossing-multi-hybrid-multi-1": (-19.465, 46),  # s48 was -32.461/54;
    # was -19.370/42 [-31.414, 76];
    # search -30.839 m
    # session 13: the exploration's guess goes round the other AUVs (docs/mpc.md, "Controller
    # step" 3): -15.174 m, 49 s on the AVX-512 CPU of sessions 12-13 (-16.072 m, 97 s
    # before); checked against the envelope below, not this value. Session 8's value on
    # the CPU of sessions 8-11 in brackets, session 7's in angle brackets, session 4's in
    # braces. Session 34's start, on that session's CPU: -1.446 m, 8 s (-8.609 m, 24 s on
    # the code before it)
    "falsified-crossing-multi-mpc-multi-1": (-15.174, 49),  # [-14.621, 46] <-15.211, 38>
    # the worst case of the printed eq. 8 (-46.28 m there), run with S1/S2
    # Session 49's USBL fixes on the 3-D line of sight (mpcasv.models.acoustics U1; every
    # fix's error and depth changed) moved the three cases that estimate: "s49 was"; then the
    # estimators' depth filter (mpcasv.estimation.depth: the fixes' USBL depths weighed
    # against the reports' pressure depths) moved them again: "s49a"
    "falsified-crossing-multi-printed-eq8": (-8.752, 28),  # s49a -6.280/22, s49 was -8.097/28;
    # s48 was -10.090/30;
    # was -8.830/28 [-21.073, 42];
    # search -20.622 m
    "falsified-pursuer-single-hybrid-single-1": (-28.249, 54),  # s48 was -27.103/53;
    # was -40.178/76; search -29.681
    # search: -25.858 m, 28 s; session 12: the standing-time term (M7s, off while an AUV
    # threatens the ASV) in the preset, 4.987 m without it; no counterexample until session
    # 25 (3.091 m, 0 s). Session 26's ground-speed bounds widened by the current (0.197 m/s
    # here) moved the run from t = 59 s on (chaotic: another path), and it is one again: in
    # its last 4 s a standby coasting at 0.5-0.6 m/s towards the surfaced AUV ends 2.06 m
    # inside r_inner (the plan predicted it would stop outside; docs/mpc.md "Known problems").
    # Session 28's waypoint for the crab angle (the same current) moved it again: no
    # counterexample, the coasting standby not fixed, only not met on this path. Session 31's
    # observer start (the current found in seconds, not minutes: docs/mpc.md "Known
    # problems", the observer's start) moved it again: 8.664 m, 0 s (with the start's
    # sigma_nu0 = 1 instead of 0.3: -0.945 m, 6 s), the coasting standby still not fixed.
    # Session 34's start carried by the current: 6.109 m, 0 s (8.664 m, 0 s before).
    # Session 39's integral terminal (M7i) with its accrual gated off under a threat: 8.394
    # m, 0 s (ungated: -12.270 m, 24 s; docs/mpc.md "Closed loop ... session 39")
    # Session 46's observer taking the actuators through each period (the current estimate
    # within 1 mm/s of the truth, 5 mm/s off before) moved the path from t = 87 s on: -18.410
    # m, 38 s. An estimation failure, as in the s44 case below: the pursuer was not fixed
    # from t = 135 to 200 s (p_good 0.59, the propeller running), the Kalman estimate's sigma
    # grew to 30 m and it put the pursuer 50-68 m away while it closed from 60 to 25 m
    # Session 48's common random numbers: 6.007 m, 0 s: with the other noise the pursuer
    # was fixed often enough that the estimate did not fail (the kind of failure stands:
    # docs/mpc.md "Known problems", the Kalman estimate's over-confidence)
    # Session 49's 3-D USBL fixes: 2.533 m, 0 s (6.007 before); with the depth filter
    # -7.862 m, 19 s: its depth estimate within 0.6 m of the truth (20.3-27.8 m for a 23.7 m
    # AUV before), the ASV stood by at t = 101-107 s while the Kalman estimate put the closing
    # pursuer 82-85 m away where it was 68-82 m (the horizontal estimate's lag again)
    "falsified-pursuer-single-mpc-single-1": (-7.862, 19),  # s49a 2.533/0, s49 was 6.007/0,
    # s48 -18.410/38
    # before: 8.394/0 6.109/0 8.664/0
    # {0.443, 0}
    # session 44's searches (docs/safety.md "Session 44"), the first whose runs are the
    # written scenarios (the preset's domain and the power turn in every trial): their worst
    # cases as found, the searches' margins exactly. The MPC's is an estimation failure (the
    # Kalman estimate of the pursuer 55-109 m off while it closes to 0.55 m; p_good 0.36):
    # a change that keeps the ASV off the AUV here moves this pin, which is the point
    "falsified-pursuer-single-hybrid-single-s44": (-44.949, 63),  # s48 was -43.003/57
    "falsified-pursuer-single-mpc-single-s44": (-35.732, 177),  # s49a -44.982/181,
    # s49 was -38.370/151;
    # s48 was -43.505/139;
    # -49.155/199 before s46
}
#: chaotic cases: bounds (margin at least, longest stay at most) around the spread of the run
#: over the last bits of the floating point. The mpc-multi case's last bits depend on the CPU
#: (the solver library is compiled with -march=native, and numpy picks its SIMD kernels at run
#: time; docs/mpc.md "Known problems") and its behaviour follows them. Session 13 ran it on
#: one CPU under nine builds: the library -march=native -15.174 m / 49 s, x86-64-v3 the same,
#: x86-64-v2, -O3, -O2 and -O1 -12.554 m / 79 s; numpy's AVX-512 kernels off -2.617 m /
#: 18 s, and with -O2 -8.407 m / 21 s; OpenBLAS as Haswell -15.174 m / 49 s. (The first form
#: of the guess, one disc at a time: -4.5 to -7.7 m, 17 to 56 s.) Before session 13 it ended
#: at -14.621 m / 46 s on the CPU of sessions 8-11 and -16.072 m / 97 s on that of session
#: 12, inside the spread: these bounds catch a large change for the worse (a deeper or
#: longer stay than any build showed, with a margin), not the last session's behaviour. An
#: exact pin held on one kind of CPU only.
#: Session 46's current observer (the actuators through each period) moved it to -21.101 m /
#: 45 s, past the -20 m bound: the hunter, surfaced and closing at 1.62 m/s while the ASV
#: fled at 2-2.5 m/s, came from 50 to 29 m at t = 320-335 s while the Kalman estimate put it
#: 8-12 m further (no fix at the surface); the bound is now -25 m, the spread of the builds
#: not measured again (one CPU, one build)
ENVELOPE: dict[str, tuple[float, float]] = {
    "falsified-crossing-multi-mpc-multi-1": (-25.0, 100.0),
}


@pytest.mark.parametrize("name", sorted(PINNED))
def test_falsified_worst_cases_keep_todays_margin(name):
    from mpcasv.controllers import Boat, make_controller
    from mpcasv.experiments.falsify import required_separation
    from mpcasv.sim.scenario import load_scenario
    from mpcasv.sim.simulator import simulate

    sc = load_scenario(FALSIFIED / f"{name}.toml")
    # the mpc-multi case met 3 fatrop hangs until session 7, none in session 7, one since
    # session 8 (docs/mpc.md "Known problems"): each holds the default hang guard's 10 s of
    # CPU time; its solves take < 0.3 s, so 5 s abandons a hung solve and nothing else
    overrides = {"solver.hang_s": 5.0} if sc.controller.startswith("mpc") else None
    ctrl = make_controller(sc.controller, len(sc.auv), sc.preset, overrides,
                           boat=Boat.of_scenario(sc))  # fmt: skip
    result = simulate(sc, ctrl, 0)
    rob = robustness(result.timeseries, len(sc.auv), required_separation(ctrl), 1.0)
    got = (rob.margin_m, rob.longest_stay_s)
    if name in ENVELOPE:
        low, high = ENVELOPE[name]
        assert got[0] >= low and got[1] <= high, (
            f"margin {got[0]:.3f} m, longest stay {got[1]:.0f} s; envelope: margin >= {low} m,"
            f" stay <= {high} s")
        return
    margin, stay = PINNED[name]
    assert got[0] == pytest.approx(margin, abs=0.5) and got[1] == pytest.approx(stay, abs=3.0), (
        f"margin {got[0]:.3f} m, longest stay {got[1]:.0f} s; measured {PINNED[name]}")


def test_every_committed_worst_case_is_pinned():
    assert sorted(p.stem for p in FALSIFIED.glob("*.toml")) == sorted(PINNED)


def test_a_run_that_does_not_return_is_recorded_as_a_timeout(tmp_path, monkeypatch):
    """A solver that never returns (seen with mpc-multi, docs/safety.md) must not stop the
    search: with --timeout the run is recorded as an error and the search goes on."""
    import mpcasv.experiments.falsify_pool as pool_mod
    from mpcasv.experiments.falsify_pool import WorkerPool, run_batch

    told = []
    with WorkerPool(1, timeout=10.0) as workers:  # the hang sleeps 60 s
        items = [("hang", lambda: ("sleep", 60.0)), ("quick", lambda: ("sleep", 0.0))]
        monkeypatch.setattr(pool_mod, "_guarded", _sleeper)
        t0 = time.monotonic()
        run_batch(items, workers, lambda trial, m, err: told.append((trial, m, err)))
        assert time.monotonic() - t0 < 40
    assert told[0][0] == "hang" and "timeout" in told[0][2]
    assert told[1] == ("quick", {"slept": 0.0}, None)


def _sleeper(args):  # a module-level stand-in for a run (picklable by reference)
    time.sleep(args[1])
    return {"slept": args[1]}, None

