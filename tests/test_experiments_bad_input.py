"""Bad inputs of ``compare``, ``falsify`` and ``tune controller`` (session 17 attack): each is
refused with one line naming the option, field or file and the value (exit 2) before any job
runs or any file is written; an output folder holding another suite's or search's results is
refused, the same one resumes; a local pool starts no more processes than jobs.

Runs are tiny (the go-to or hybrid controller, 20 s scenarios, one worker unless the pool is
what is tested).
"""

from __future__ import annotations

import json
import sqlite3
import textwrap
from pathlib import Path

import pytest

from mpcasv.cli import main
from mpcasv.experiments import workers as workers_mod

ROOT = Path(__file__).resolve().parents[1]
FAMILY = ROOT / "experiments" / "falsify" / "pursuer-single.toml"

SCENARIO = """
name = "demo"
duration = 20.0
controller = "goto"
preset = "goto"
[asv.start]
N = -50.0
E = -50.0
psi_deg = 45.0
[[auv]]
name = "auv"
start = { N = 0.0, E = 0.0, depth = 20.0, psi_deg = 0.0 }
behaviour = { transit = { heading_deg = 0.0, speed = 1.0, depth = 20.0 } }
"""


def _suite(tmp: Path, name: str = "one", seeds: str = "[0]") -> Path:
    """A suite of ``len(seeds)`` go-to jobs on a 20-s scenario."""
    (tmp / "demo.toml").write_text(SCENARIO)
    path = tmp / f"{name}.toml"
    path.write_text(textwrap.dedent(f"""
        name = "{name}"
        scenarios = ["demo.toml"]
        seeds = {seeds}
        plots = "none"
        [[controllers]]
        label = "goto"
        name = "goto"
        preset = "goto"
    """))  # fmt: skip
    return path


def _one_error_line(capsys, *words: str) -> str:
    """The command's stderr: one line, no traceback, containing every word."""
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    for w in words:
        assert w in err, (w, err)
    return err


@pytest.fixture
def two_cpus(monkeypatch):
    """The machine has 2 CPUs (the limit on --workers is then 8)."""
    monkeypatch.setattr(workers_mod, "cpu_count", lambda: 2)


@pytest.fixture
def no_scheduler(monkeypatch):
    """No Dask scheduler answers: a stand-in for ``dask_runner.connect`` that refuses at once
    (a real connection to a closed port takes Dask's 20 s timeout)."""
    from mpcasv.config import ConfigError
    from mpcasv.experiments import dask_runner

    def refuse(address):
        raise ConfigError(f"--dask {address}: no scheduler (test stand-in)")

    monkeypatch.setattr(dask_runner, "connect", refuse)


# --- --workers -------------------------------------------------------------------------------


@pytest.mark.parametrize("command", ["compare", "falsify", "tune"])
def test_workers_above_four_per_cpu_are_refused_naming_the_cpu_count(command, two_cpus, tmp_path,
                                                                      capsys):  # fmt: skip
    out = tmp_path / "out"
    argv = {
        "compare": ["compare", str(_suite(tmp_path)), "--workers", "9", "--out", str(out)],
        "falsify": ["falsify", str(FAMILY), "--controller", "hybrid-single", "--workers", "9",
                    "--out", str(out)],
        "tune": ["tune", "controller", str(ROOT / "experiments/tuning/hybrid-single.toml"),
                 "--workers", "9", "--out", str(out)],
    }[command]  # fmt: skip
    assert main(argv) == 2
    _one_error_line(capsys, "--workers 9", "2 CPUs", "8")
    assert not out.exists()


def test_workers_default_is_the_cpu_count_and_none_with_dask_is_fine(two_cpus):
    assert workers_mod.check_workers(None) == 2
    assert workers_mod.check_workers(None, dask="tcp://scheduler:8786") == 2


@pytest.mark.parametrize("command, extra", [
    ("compare", ["--workers", "2"]),
    ("compare", ["--job-timeout", "60"]),
    ("tune", ["--workers", "2"]),
])  # fmt: skip
def test_options_dask_would_ignore_are_refused_with_it(command, extra, tmp_path, capsys):
    """``--workers`` and ``--job-timeout`` were silently ignored with ``--dask`` (a Dask sweep
    then had no per-job limit; a new user's walk-through, session 23): refused before anything
    is contacted or written (no scheduler listens at the address)."""
    out = tmp_path / "out"
    dask = "tcp://127.0.0.1:9"
    argv = {
        "compare": ["compare", str(_suite(tmp_path)), "--out", str(out)],
        "tune": ["tune", "controller", str(ROOT / "experiments/tuning/hybrid-single.toml"),
                 "--out", str(out)],
    }[command] + ["--dask", dask, *extra]  # fmt: skip
    assert main(argv) == 2
    _one_error_line(capsys, f"{extra[0]} {extra[1]} with --dask {dask}", "leave it out")
    assert not out.exists()


def test_no_job_limit_with_dask_is_what_dask_has(tmp_path, capsys, no_scheduler):
    """``--job-timeout 0`` (no limit) with ``--dask`` is not refused: the command goes on to
    the scheduler, which is asked before anything is written (here a stand-in refuses at
    once; a real connection to a closed port takes Dask's 20 s timeout)."""
    out = tmp_path / "out"
    dask = "tcp://127.0.0.1:9"
    assert main(["compare", str(_suite(tmp_path)), "--out", str(out), "--dask", dask,
                 "--job-timeout", "0"]) == 2  # fmt: skip
    _one_error_line(capsys, f"--dask {dask}: no scheduler (test stand-in)")
    assert not out.exists()


def test_tune_asks_the_scheduler_before_writing_anything(tmp_path, capsys, no_scheduler):
    """``tune controller --dask`` to a dead scheduler wrote the folder, its lock and study.db
    before its error (a leftover of session 46); now the scheduler is asked first, as by
    ``compare`` (the same stand-in as above)."""
    out = tmp_path / "out"
    dask = "tcp://127.0.0.1:9"
    assert main(["tune", "controller", str(_ranges(tmp_path, '"speed" = { low = 1.0, high = '
                 '2.5 }')), "--out", str(out), "--dask", dask, "--quiet"]) == 2  # fmt: skip
    _one_error_line(capsys, f"--dask {dask}: no scheduler (test stand-in)")
    assert not out.exists()


def test_a_pool_starts_no_more_processes_than_jobs_and_says_so(two_cpus, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["compare", str(_suite(tmp_path)), "--workers", "3", "--out", str(out),
                 "--no-report", "--quiet"]) == 0  # fmt: skip
    sweep = json.loads((out / "sweep.json").read_text())
    assert sweep["workers"] == 1 and sweep["ok"] == 1
    out2 = tmp_path / "out2"
    assert main(["compare", str(_suite(tmp_path, "two", "[0, 1]")), "--workers", "3", "--out",
                 str(out2), "--no-report"]) == 0  # fmt: skip
    assert "--workers 3 reduced to 2" in capsys.readouterr().out
    assert json.loads((out2 / "sweep.json").read_text())["workers"] == 2


# --- compare ---------------------------------------------------------------------------------


@pytest.mark.parametrize("value", ["nan", "inf", "-1"])
def test_job_timeout_must_be_finite_and_not_negative(value, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["compare", str(_suite(tmp_path)), "--job-timeout", value, "--out",
                 str(out)]) == 2  # fmt: skip
    _one_error_line(capsys, f"--job-timeout {float(value)}")
    assert not out.exists()


def test_a_folder_of_another_suite_is_refused_and_the_same_suite_resumes(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["compare", str(_suite(tmp_path, "first")), "--out", str(out), "--workers", "1",
                 "--quiet"]) == 0  # fmt: skip
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    parts = sorted((out / "parts").iterdir())
    capsys.readouterr()
    assert main(["compare", str(_suite(tmp_path, "second")), "--out", str(out), "--workers",
                 "1", "--no-report", "--quiet"]) == 2  # fmt: skip
    _one_error_line(capsys, f"--out {out}", "'first'", "'second'")
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before
    assert sorted((out / "parts").iterdir()) == parts
    # the same suite, with one more seed: resumed (the finished job is not run again)
    assert main(["compare", str(_suite(tmp_path, "first", "[0, 1]")), "--out", str(out),
                 "--workers", "1", "--no-report"]) == 0  # fmt: skip
    assert "2 jobs, 1 already done, 1 to run" in capsys.readouterr().out


def test_a_folder_with_results_but_no_suite_file_is_refused(tmp_path, capsys):
    out = tmp_path / "out"
    (out / "parts").mkdir(parents=True)
    assert main(["compare", str(_suite(tmp_path)), "--out", str(out), "--workers", "1"]) == 2
    _one_error_line(capsys, f"--out {out}", "parts/", "suite.toml")
    assert list(out.iterdir()) == [out / "parts"] and not any((out / "parts").iterdir())


# --- falsify ---------------------------------------------------------------------------------


def _family(tmp: Path, old: str = "", new: str = "", name: str = "fam.toml") -> Path:
    """pursuer-single cut to 20 s, with ``old`` replaced by ``new`` (which must be there)."""
    text = FAMILY.read_text().replace("duration = 400.0", "duration = 20.0", 1)
    assert old in text
    path = tmp / name
    path.write_text(text.replace(old, new, 1))
    return path


def _falsify(family: Path, out: Path, *extra: str) -> int:
    return main(["falsify", str(family), "--controller", "hybrid-single", "--budget", "1",
                 "--out", str(out), "--quiet", *extra])  # fmt: skip


def test_a_controller_without_safety_domain_needs_separation_before_any_trial(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["falsify", str(_family(tmp_path)), "--controller", "goto", "--budget", "2",
                 "--out", str(out)]) == 2  # fmt: skip
    _one_error_line(capsys, "--controller goto", "--separation")
    assert not out.exists()


def test_a_controller_for_fewer_auvs_than_the_family_is_refused_before_any_trial(tmp_path,
                                                                                capsys):
    """It ran its whole budget of one-line errors, exited 1 and left a study in --out."""
    out = tmp_path / "out"
    family = ROOT / "experiments" / "falsify" / "crossing-multi.toml"
    assert main(["falsify", str(family), "--controller", "mpc-single", "--budget", "8",
                 "--out", str(out)]) == 2  # fmt: skip
    _one_error_line(capsys, "'mpc-single' handles one AUV", "crossing-multi", "has 3")
    assert not out.exists()


def test_a_second_falsify_on_a_busy_folder_is_refused(tmp_path, capsys):
    """A second search in a folder took the first one's running trials for a killed search's
    and ran them again (Optuna then raised UpdateFinishedTrialError in one of them)."""
    from mpcasv.outputs import folder_lock

    out = tmp_path / "out"
    with folder_lock(out, "mpcasv falsify", "falsify.lock"):  # a first search at work
        assert _falsify(FAMILY, out, "--params", "paper1-field") == 2
    _one_error_line(capsys, "another 'mpcasv falsify' is working in this folder")
    assert not (out / "study.db").exists()


def test_a_range_end_giving_an_invalid_scenario_is_refused(tmp_path, capsys):
    text = FAMILY.read_text()
    start = text.index('name = "p_good"')
    old = text[start:text.index("\n[", start)]
    assert "high = 0.95" in old
    family = _family(tmp_path, old, old.replace("high = 0.95", "high = 1.5"))
    out = tmp_path / "out"
    assert _falsify(family, out) == 2
    _one_error_line(capsys, str(family), "'p_good'", "high end 1.5", "acoustics.p_good")
    assert not out.exists()


def test_ends_valid_alone_but_invalid_together_are_warned_of(tmp_path, capsys):
    """p_good = extra + base: each at its high end with the other at its midpoint is <= 1,
    both at their high ends is not. Said, with the share of such corners, and searched (a
    review: refusing the whole box refused families valid in 97 % of it)."""
    text = FAMILY.read_text()
    start = text.index('name = "p_good"')
    old = text[start:text.index("\n[", start)]
    new = ('name = "p_good"\nlow = 0.3\nhigh = 0.6\nfield = "acoustics.p_good"\nplus = "extra"\n'
           '[[param]]\nname = "extra"\nlow = 0.0\nhigh = 0.5')  # fmt: skip
    family = _family(tmp_path, old, new)
    out = tmp_path / "out"
    assert _falsify(family, out) == 0
    err = capsys.readouterr().err
    # a quarter of the 2**11 corners: those with p_good and extra both high
    assert "512 of 2048 corners" in err and "p_good = 0.6 (high), extra = 0.5 (high)" in err, err


@pytest.mark.parametrize("bad", ["../escape", "", ".hidden", "a/b"])
def test_a_family_name_that_cannot_be_a_path_is_refused(bad, tmp_path, capsys):
    family = _family(tmp_path, 'name = "pursuer-single"', f'name = "{bad}"')
    out = tmp_path / "out"
    assert _falsify(family, out) == 2
    _one_error_line(capsys, str(family), "name")
    assert not out.exists() and not (tmp_path / "escape").exists()


def _n_trials(out: Path) -> int:
    with sqlite3.connect(out / "study.db") as con:
        return con.execute("SELECT COUNT(*) FROM trials").fetchone()[0]


def test_a_folder_of_another_search_is_refused_and_the_same_search_resumes(tmp_path, capsys):
    family, out = _family(tmp_path), tmp_path / "out"
    assert _falsify(family, out) == 0
    identity = json.loads((out / "falsify.json").read_text())
    assert identity["seed"] == 0 and identity["controller"] == "hybrid-single"
    files = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    capsys.readouterr()
    other = _family(tmp_path, "high = 45.0", "high = 40.0", "other.toml")  # same name
    for extra, words in ((["--seed", "1"], ["seed 0 there, 1 now"]),
                         (["--params", "paper1-field"], ["preset 'default' there"]),
                         (["--separation", "25"], ["separation_m None there, 25.0 now"]),
                         (["--objective", "stay"], ["objective 'margin' there"])):  # fmt: skip
        assert _falsify(family, out, *extra) == 2, extra
        _one_error_line(capsys, f"--out {out}", *words)
    assert _falsify(other, out) == 2
    _one_error_line(capsys, f"--out {out}", "family_sha256")
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == files
    assert _n_trials(out) == 1
    # the same search, a larger budget: resumed
    assert main(["falsify", str(family), "--controller", "hybrid-single", "--budget", "2",
                 "--out", str(out), "--quiet"]) == 0  # fmt: skip
    assert _n_trials(out) == 2


def test_a_search_folder_without_its_identity_is_refused(tmp_path, capsys):
    family, out = _family(tmp_path), tmp_path / "out"
    assert _falsify(family, out) == 0
    (out / "falsify.json").unlink()
    capsys.readouterr()
    assert _falsify(family, out) == 2
    _one_error_line(capsys, f"--out {out}", "falsify.json", "study.db")
    assert _n_trials(out) == 1


# --- tune controller -------------------------------------------------------------------------


def _ranges(tmp: Path, params: str) -> Path:
    (tmp / "train.toml").write_text(
        'name = "tiny-train"\nscenarios = ["case3"]\nduration = 20.0\nseeds = [0]\n'
        'plots = "none"\n[[controllers]]\nlabel = "hybrid"\nsingle = "hybrid-single"\n'
        'preset = "scenario"\n'
    )
    path = tmp / "ranges.toml"
    path.write_text('controller = "hybrid-single"\nsuite = "train.toml"\nheldout_seeds = [7]\n'
                    f"trials = 2\nbatch = 2\n[params]\n{params}\n")  # fmt: skip
    return path


@pytest.mark.parametrize("params, words", [
    ('"speed" = { low = -1.0, high = 2.5 }', ["params.'speed'", "low = -1.0",
                                              "outside the allowed range (0, 10] m/s"]),
    ('"domain.alpha_inner" = { low = 0.0, high = 5.0 }', ["params.'domain.alpha_inner'",
                                                         "low = 0.0"]),
    # refused by the preset's cross-field check whatever eps_minus in [2, 10] is
    ('"domain.delta_r" = { low = 1.0, high = 50.0 }\n"domain.eps_minus" = { low = 2.0, high = '
     '10.0 }', ["params.'domain.delta_r'", "low = 1.0", "paper1-field", "eps_minus"]),
])  # fmt: skip
def test_a_range_end_the_preset_refuses_is_refused_before_any_trial(params, words, tmp_path,
                                                                     capsys):  # fmt: skip
    out = tmp_path / "out"
    assert main(["tune", "controller", str(_ranges(tmp_path, params)), "--out", str(out),
                 "--workers", "1", "--quiet"]) == 2  # fmt: skip
    _one_error_line(capsys, str(tmp_path / "ranges.toml"), *words)
    assert not out.exists()


def test_range_ends_valid_with_some_setting_of_the_others_are_kept(tmp_path):
    """delta_r = 5 is refused with the preset's eps_minus (10 m) but not with eps_minus at its
    low end (2 m): the search may run it (combinations are found per trial)."""
    from mpcasv.experiments.tune_jobs import check_presets
    from mpcasv.experiments.tune_space import load_spec

    ranges = _ranges(tmp_path, '"domain.delta_r" = { low = 5.0, high = 50.0 }\n'
                               '"domain.eps_minus" = { low = 2.0, high = 10.0 }')  # fmt: skip
    assert len(check_presets(load_spec(ranges))) == 1


def test_a_family_edited_only_in_its_description_is_the_same_study(tmp_path):
    """A review: the identity hashed the family's description, so rewording it refused the
    resumption of the same search."""
    from mpcasv.controllers.registry import load_preset
    from mpcasv.experiments.falsify_family import load_family
    from mpcasv.experiments.falsify_folder import study_identity

    params = load_preset("hybrid-single", None)
    ids = []
    for i, text in enumerate(("", 'description = "reworded"\n')):
        path = _family(tmp_path, "", "", name=f"f{i}.toml")
        path.write_text(text + path.read_text().replace("\ndescription = ", "\n# ", 1))
        ids.append(study_identity(load_family(path), "hybrid-single", None, params, 0,
                                  "margin", None))  # fmt: skip
    assert ids[0] == ids[1]
    changed = _family(tmp_path, "duration = 20.0", "duration = 21.0", name="f2.toml")
    other = study_identity(load_family(changed), "hybrid-single", None, params, 0, "margin",
                           None)  # fmt: skip
    assert other["family_sha256"] != ids[0]["family_sha256"]
