"""First run (issue 12 item 8): before a sweep or a simulation starts, the MPC libraries missing
from the cache are named, with 'once' and an estimate, and compiled up front with a progress
line each; the paths listed are the ones the controller then loads."""

from __future__ import annotations

import io
import time
from pathlib import Path

import pytest

from mpcasv.controllers import Boat, make_controller
from mpcasv.controllers.prepare import about, needed_libraries, prepare
from mpcasv.experiments.runner import prepare_controllers
from mpcasv.experiments.suite import expand
from mpcasv.experiments.suite_file import SCENARIOS_DIR
from mpcasv.mpc import codegen
from mpcasv.mpc.derivatives import nlp_functions
from mpcasv.mpc.prepare import RUNTIME_WEIGHTS, Library, compile_estimate, structure_key
from mpcasv.mpc.problem import OCP

CASE3, CASE6 = SCENARIOS_DIR / "case3.toml", SCENARIOS_DIR / "case6.toml"
SUITE = f"""
name = "tiny-mpc"
scenarios = ["{CASE3}", "{CASE6}"]
duration = 10.0
seeds = [0, 1]
current = ["off"]
plots = "none"

[[controllers]]
label = "mpc"
single = "mpc-single"
multi = "mpc-multi"
preset = "default"
grid = {{ "weights.dT" = [0.02, 0.05] }}
"""


def test_compile_estimate_grows_with_the_auvs_and_the_sub_steps():
    one, two, three = (compile_estimate(k) for k in (1, 2, 3))
    assert one < two < three and two == pytest.approx((one + three) / 2)
    assert compile_estimate(4) > three  # extrapolated beyond the measured points
    assert compile_estimate(1, n_sub=8) == pytest.approx(2 * one)  # the stage's code doubles
    assert compile_estimate(1, n_sub=2) == one  # fewer sub-steps are not measured: no less


def test_listed_library_is_the_one_the_controller_loads(monkeypatch):
    """The path needed_libraries computes is the path MPCController loads (same functions and
    key as mpcasv.mpc.codegen.compiled_library). The process's OCP cache is emptied for the
    test: an earlier test in the same process that built this controller (test_mpc_depth's
    first, for one) left it there, and the controller then loaded no library at all."""
    from mpcasv.mpc import controller

    monkeypatch.setattr(controller, "_OCP_CACHE", {})
    boat = Boat.load()
    (lib,) = needed_libraries([("mpc-single", 1, "mpc-single", None, boat)])
    codegen._LOADED.clear()
    make_controller("mpc-single", 1, "mpc-single", boat=boat)  # compiles if not cached
    assert list(codegen._LOADED.values()) == [lib.path]
    assert lib.cached


def test_runtime_weights_do_not_change_the_library():
    """The sweep lists libraries per structure_key (runtime weights left out); changing any
    of those weights must leave the compiled functions' key unchanged."""
    from mpcasv.controllers import load_preset

    base = load_preset("mpc-single", "mpc-single")
    ref = codegen.library_key(nlp_functions(OCP(base, 1, True), "fatrop"), "fatrop", "-O1")
    for name in RUNTIME_WEIGHTS:
        other = load_preset("mpc-single", "mpc-single", {f"weights.{name}": 0.123})
        assert getattr(other.weights, name) != getattr(base.weights, name)
        assert structure_key(other) == structure_key(base)
        key = codegen.library_key(nlp_functions(OCP(other, 1, True), "fatrop"), "fatrop", "-O1")
        assert key == ref, name
    worst = load_preset("mpc-single", "mpc-single", {"weights.worst": 0.5})
    assert structure_key(worst) != structure_key(base)  # adds a variable: another library
    assert codegen.library_key(nlp_functions(OCP(worst, 1, True), "fatrop"), "fatrop",
                               "-O1") != ref  # fmt: skip


@pytest.fixture
def fake_compile(monkeypatch, tmp_path):
    """An empty cache, and a compile that only writes the file (a real one takes ~30 s)."""
    monkeypatch.setenv("MPCASV_CACHE", str(tmp_path / "cache"))
    done = []

    def compile_(self, log=print):
        done.append(self.path)
        self.path.write_bytes(b"")
        return self.path

    monkeypatch.setattr(Library, "compile", compile_)
    return done


def test_a_sweep_names_and_compiles_each_missing_library_once(fake_compile, tmp_path, capsys):
    suite = tmp_path / "tiny-mpc.toml"
    suite.write_text(SUITE)
    jobs = expand(suite).jobs
    assert len(jobs) == 8  # 2 scenarios x 2 dT weights x 2 seeds
    compiled = prepare_controllers(jobs, quiet=True)
    # the dT weight is a parameter of the problem, not compiled in: one library per AUV count
    assert [lib.n_auv for lib in compiled] == [1, 3]
    assert fake_compile == [lib.path for lib in compiled]
    assert all(Path(p).parent == tmp_path / "cache" / "mpc" for p in fake_compile)
    err = capsys.readouterr().err
    assert "first run: 2 MPC libraries to compile" in err and "once per problem" in err
    assert f"about {about(compile_estimate(1) + compile_estimate(3))} on" in err
    assert "mpc-single, 1 AUV, fatrop, vessel gretha" in err
    assert "mpc-multi, 3 AUVs, fatrop, vessel gretha" in err
    assert err.count("  compiled ") == 2
    # the second sweep finds them in the cache: nothing compiled, nothing said
    assert prepare_controllers(jobs, quiet=True) == []
    assert capsys.readouterr().err == ""


def test_the_progress_line_counts_against_the_estimate(fake_compile):
    (lib,) = needed_libraries([("mpc-single", 1, "mpc-single", None, Boat.load())])
    out = io.StringIO()
    prepare([lib], quiet=False, file=out)
    text = out.getvalue()
    assert "compiling 1/1 mpc-single, 1 AUV" in text
    assert f"00:00 (about {about(compile_estimate(1))} on an idle machine)" in text


def test_a_log_file_is_not_flooded_with_progress_frames(fake_compile, monkeypatch):
    """Written to a file that is not a terminal, a compile of 1.5 s gives the bar's first and
    last frames only (on a terminal the bar moves every half second)."""
    fast = Library.compile

    def slow(self, log=print):
        time.sleep(1.5)
        return fast(self, log)

    monkeypatch.setattr(Library, "compile", slow)
    (lib,) = needed_libraries([("mpc-single", 1, "mpc-single", None, Boat.load())])
    out = io.StringIO()
    prepare([lib], quiet=False, file=out)
    assert out.getvalue().count("compiling 1/1") == 2


def test_an_estimate_reads_in_seconds_or_minutes():
    assert about(40.0) == "40 s" and about(119.4) == "119 s"
    assert about(230.0) == "4 min" and about(500.0) == "8 min"


def test_dask_sweeps_only_say_it(fake_compile, tmp_path, capsys):
    suite = tmp_path / "tiny-mpc.toml"
    suite.write_text(SUITE)
    assert prepare_controllers(expand(suite).jobs, dask="tcp://x:8786") == []
    assert fake_compile == []
    assert "each Dask worker machine compiles the 2 it needs once" in capsys.readouterr().out
